// Every NodeSet2 file shipped in node-opcua-nodesets loads (with the models it requires)
// into a fresh address space, with as many nodes per namespace as the file declares; the
// load time of each file is printed. Namespace 0 also loads from XML and then holds the same
// values as the compiled-in blob.
#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <iostream>
#include <map>
#include <pugixml.hpp>

#include "ua/server/nodeset_xml.hpp"
#include "ua/types/binary.hpp"
#include "ua/types/ns0_ids_variables.hpp"
#include "ua/types/ns0_types.hpp"

namespace pnp::ua::server {
namespace {

namespace fs = std::filesystem;

// Readable form of a value for failure messages (structures decoded by the generated codecs).
std::string show(const std::optional<Variant>& v) {
    if (!v) return "(none)";
    if (const auto* x = v->scalar<ExtensionObject>()) return toJson(*x);
    if (const auto* xs = v->array<ExtensionObject>()) {
        std::string out = "[";
        for (const auto& x : *xs) out += toJson(x) + ",";
        return out + "]";
    }
    return v->toString();
}

std::vector<fs::path> officialFiles() {
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(PNP_NODESET_DIR))
        if (e.path().extension() == ".xml") files.push_back(e.path());
    std::sort(files.begin(), files.end());
    return files;
}

// NodeIds of the file's nodes by namespace URI, read independently of the loader.
std::map<std::string, std::vector<std::string>> nodesByNamespace(const fs::path& file) {
    pugi::xml_document doc;
    EXPECT_TRUE(doc.load_file(file.c_str()));
    pugi::xml_node root = doc.document_element();
    std::vector<std::string> uris{"http://opcfoundation.org/UA/"};
    for (pugi::xml_node u : root.child("NamespaceUris").children("Uri"))
        uris.push_back(u.child_value());
    std::map<std::string, std::vector<std::string>> out;
    for (pugi::xml_node el : root.children()) {
        std::string tag = el.name();
        if (tag.rfind("UA", 0) != 0 || tag == "UANodeSet") continue;
        std::string id = el.attribute("NodeId").value();
        std::size_t ns = 0;
        std::string local = id;
        if (id.rfind("ns=", 0) == 0) {
            ns = std::stoul(id.substr(3));
            local = id.substr(id.find(';') + 1);
        }
        out[uris.at(ns)].push_back(local);
    }
    return out;
}

TEST(OfficialNodeSets, EveryFileLoadsWithItsDependencies) {
    const auto files = officialFiles();
    ASSERT_GE(files.size(), 30u);
    std::size_t loaded = 0;
    for (const fs::path& file : files) {
        SCOPED_TRACE(file.filename().string());
        AddressSpace space;
        std::vector<NodeSetLoadReport> reports;
        try {
            reports = loadNodeSetXml(space, file);
        } catch (const std::exception& e) {
            ADD_FAILURE() << e.what();
            continue;
        }
        if (file.filename() == "Opc.Ua.NodeSet2.xml") {
            EXPECT_TRUE(reports.empty());  // namespace 0 is compiled in already
            continue;
        }
        ASSERT_FALSE(reports.empty());
        const NodeSetLoadReport& own = reports.back();
        EXPECT_EQ(own.file, file);
        std::cout << "[ nodeset  ] " << file.filename().string() << ": " << own.nodes << " nodes, "
                  << own.references << " references, " << own.loadMs << " ms"
                  << " (+" << reports.size() - 1 << " required models";
        double deps = 0;
        for (std::size_t k = 0; k + 1 < reports.size(); ++k) deps += reports[k].loadMs;
        std::cout << ", " << deps << " ms)";
        if (!own.warnings.empty())
            std::cout << ", " << own.warnings.size() << " warnings, first: " << own.warnings[0];
        std::cout << "\n";
        // Node count per namespace equals the file's: every node of the file is there.
        std::size_t total = 0;
        for (const auto& [uri, ids] : nodesByNamespace(file)) {
            auto ns = space.namespaceIndex(uri);
            ASSERT_TRUE(ns) << uri;
            std::size_t found = 0;
            for (const std::string& local : ids) {
                auto id = NodeId::parse("ns=" + std::to_string(*ns) + ";" + local);
                if (id && space.contains(*id)) ++found;
            }
            EXPECT_EQ(found, ids.size()) << uri;
            total += ids.size();
        }
        EXPECT_EQ(own.nodes, total);
        ++loaded;
    }
    std::cout << "[ nodeset  ] " << loaded << " of " << files.size()
              << " files loaded from XML (namespace 0 is compiled in; see the next test)\n";
}

TEST(OfficialNodeSets, NamespaceZeroFromXmlEqualsTheCompiledBlob) {
    AddressSpace::Options o;
    o.loadNamespaceZero = false;
    AddressSpace xml(o);
    auto reports = loadNodeSetXml(xml, fs::path(PNP_NODESET_DIR) / "Opc.Ua.NodeSet2.xml");
    ASSERT_EQ(reports.size(), 1u);
    AddressSpace blob;
    EXPECT_EQ(xml.statistics().nodes, blob.statistics().nodes);
    EXPECT_EQ(xml.statistics().references, blob.statistics().references);
    // Every value and DataTypeDefinition decoded from XML equals the one the build-time
    // compiler produced (ExtensionObjects included, byte for byte).
    std::size_t values = 0, definitions = 0;
    for (UInt32 i = 0; i < 40000; ++i) {
        NodeId id(0, i);
        auto cls = blob.nodeClass(id);
        if (!cls) continue;
        ASSERT_EQ(xml.nodeClass(id), cls) << id.toString();
        EXPECT_EQ(xml.readAttribute(id, AttributeId::BrowseName).value,
                  blob.readAttribute(id, AttributeId::BrowseName).value);
        if (*cls == NodeClass::Variable || *cls == NodeClass::VariableType) {
            auto a = xml.readAttribute(id, AttributeId::Value).value;
            auto b = blob.readAttribute(id, AttributeId::Value).value;
            if (id.numeric() == ns0::Server_ServerStatus_CurrentTime ||
                id.numeric() == ns0::Server_ServerStatus_StartTime ||
                id.numeric() == ns0::Server_ServerStatus)
                continue;
            EXPECT_EQ(a, b) << id.toString() << "\n xml:  " << show(a) << "\n blob: " << show(b);
            if (b && !b->isEmpty()) ++values;
            EXPECT_EQ(xml.readAttribute(id, AttributeId::DataType).value,
                      blob.readAttribute(id, AttributeId::DataType).value);
        }
        if (*cls == NodeClass::DataType) {
            auto a = xml.readAttribute(id, AttributeId::DataTypeDefinition).value;
            auto b = blob.readAttribute(id, AttributeId::DataTypeDefinition).value;
            EXPECT_EQ(a, b) << id.toString() << "\n xml:  " << show(a) << "\n blob: " << show(b);
            if (b && !b->isEmpty()) ++definitions;
        }
    }
    std::cout << "[ nodeset  ] ns0 from XML: " << reports[0].nodes << " nodes in "
              << reports[0].loadMs << " ms; " << values << " values and " << definitions
              << " definitions equal to the compiled blob's\n";
    EXPECT_GT(values, 1000u);
    EXPECT_GT(definitions, 200u);
}

TEST(OfficialNodeSets, NamespaceZeroDiAndRoboticsFromXml) {
    auto t0 = std::chrono::steady_clock::now();
    AddressSpace::Options o;
    o.loadNamespaceZero = false;
    AddressSpace space(o);
    std::vector<NodeSetLoadReport> all =
        loadNodeSetXml(space, fs::path(PNP_NODESET_DIR) / "Opc.Ua.NodeSet2.xml");
    auto more = loadNodeSetXml(space, fs::path(PNP_NODESET_DIR) / "Opc.Ua.Robotics.NodeSet2.xml");
    all.insert(all.end(), more.begin(), more.end());
    const double total =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    ASSERT_EQ(all.size(), 4u);  // ns0, DI, IA, Robotics
    for (const auto& r : all)
        std::cout << "[ nodeset  ] " << r.file.filename().string() << ": " << r.nodes << " nodes, "
                  << r.loadMs << " ms\n";
    std::cout << "[ nodeset  ] ns0 + DI + IA + Robotics from XML: " << total << " ms, "
              << space.statistics().nodes << " nodes\n";
    EXPECT_TRUE(isModelLoaded(space, "http://opcfoundation.org/UA/Robotics/"));
    EXPECT_TRUE(isModelLoaded(space, "http://opcfoundation.org/UA/DI/"));
}

}  // namespace
}  // namespace pnp::ua::server
