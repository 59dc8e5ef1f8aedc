// Helpers shared by the address-space tests.
#pragma once

#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "ua/server/address_space.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::server::test {

inline NodeId ns0(std::uint32_t id) { return NodeId(0, id); }

inline ReadValueId readId(const NodeId& id, AttributeId a, std::string range = {}) {
    ReadValueId r;
    r.nodeId = id;
    r.attributeId = static_cast<UInt32>(a);
    r.indexRange = std::move(range);
    return r;
}

inline WriteValue writeValue(const NodeId& id, Variant v, std::string range = {}) {
    WriteValue w;
    w.nodeId = id;
    w.attributeId = static_cast<UInt32>(AttributeId::Value);
    w.indexRange = std::move(range);
    w.value = DataValue(std::move(v));
    return w;
}

inline BrowseDescription browseDesc(const NodeId& id,
                                    BrowseDirection dir = BrowseDirection::Forward,
                                    const NodeId& refType = NodeId(0, ns0::References),
                                    bool subtypes = true, UInt32 classMask = 0,
                                    UInt32 resultMask = 63) {
    BrowseDescription d;
    d.nodeId = id;
    d.browseDirection = dir;
    d.referenceTypeId = refType;
    d.includeSubtypes = subtypes;
    d.nodeClassMask = classMask;
    d.resultMask = resultMask;
    return d;
}

inline Argument argument(std::string name, std::uint32_t dataType, Int32 valueRank = -1,
                         std::vector<UInt32> dims = {}) {
    Argument a;
    a.name = std::move(name);
    a.dataType = NodeId(0, dataType);
    a.valueRank = valueRank;
    a.arrayDimensions = std::move(dims);
    return a;
}

inline bool hasTarget(const BrowseResult& r, const NodeId& id) {
    for (const auto& ref : r.references)
        if (ref.nodeId.nodeId == id) return true;
    return false;
}

// A fresh address space with ns=2 "urn:test" (ns0 loaded).
struct AddressSpaceFixture : ::testing::Test {
    AddressSpace space;
    UInt16 ns = space.addNamespace("urn:test");
    NodeId id(const char* s) const { return NodeId(ns, s); }
    QualifiedName name(const char* s) const { return QualifiedName{ns, s}; }

    NodeId addVar(const char* s, std::uint32_t dataType, Variant value, Int32 valueRank = -1,
                  Byte access = access_level::CurrentRead | access_level::CurrentWrite,
                  std::vector<UInt32> dims = {}) {
        VariableAttributes a;
        a.dataType = NodeId(0, dataType);
        a.valueRank = valueRank;
        a.arrayDimensions = std::move(dims);
        a.accessLevel = access;
        a.value = DataValue(std::move(value));
        return space.addVariable(NodeId(0, ns0::ObjectsFolder), id(s), name(s), a);
    }
};

}  // namespace pnp::ua::server::test
