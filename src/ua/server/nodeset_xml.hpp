// Run-time loader of NodeSet2 XML files (OPC 10000-6 Annex F) into an AddressSpace.
//
// loadNodeSetXml() loads one file and, first, the models it requires (<RequiredModel
// ModelUri=...>) that the address space does not hold yet, found by ModelUri in the files
// of a search path. The file's namespace indexes are remapped onto the server's namespace
// array, aliases resolved, every node class and reference (either direction, stored once
// per pair of ends) created, <Value> elements decoded into typed values (ExtensionObjects
// get a binary body built from the DataType's StructureDefinition, see structure_codec.hpp),
// and <Definition>s become DataTypeDefinition attributes (StructureDefinition /
// EnumDefinition).
//
// Errors throw NodeSetError, whose message names the file, the node and the problem; the
// nodes of the failing file are removed again (models it required, loaded before, stay). Bounds:
// files up to 256 MiB, XML nesting inside a value up to 32 levels.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "ua/server/address_space.hpp"

namespace pnp::ua::server {

class NodeSetError : public AddressSpaceError {
  public:
    using AddressSpaceError::AddressSpaceError;
};

struct NodeSetLoadReport {
    std::filesystem::path file;
    std::string modelUri;   // first <Model> of the file
    std::size_t nodes = 0;  // nodes created from the file
    std::size_t references = 0;
    double loadMs = 0;  // parse + create, this file alone
    // Problems that do not stop the load (e.g. a reference to a node that is absent).
    std::vector<std::string> warnings;
};

// Directories searched for required models: the official NodeSets of node-opcua-nodesets
// found at build time (PNP_NODESET_DIR), then $PNP_NODESET_PATH (colon-separated).
std::vector<std::filesystem::path> defaultNodeSetSearchPath();

// Loads `file` and what it requires; returns one report per file loaded, dependencies first.
// A model that is already loaded (namespace 0 from the compiled blob included) is skipped.
std::vector<NodeSetLoadReport> loadNodeSetXml(
    AddressSpace& space, const std::filesystem::path& file,
    const std::vector<std::filesystem::path>& searchPath = defaultNodeSetSearchPath());

// Whether the address space already holds the nodes of the model with this URI.
bool isModelLoaded(const AddressSpace& space, std::string_view modelUri);

}  // namespace pnp::ua::server
