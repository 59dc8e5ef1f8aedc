#include "ua/types/ns0_ids.hpp"

#include <gtest/gtest.h>

namespace pnp::ua {
namespace {

TEST(Ns0Ids, WellKnownNodes) {
    static_assert(ns0::ObjectsFolder == 85);
    static_assert(ns0::HasComponent == 47);
    static_assert(ns0::Server_ServerStatus == 2256);
    static_assert(ns0::Server_ServerStatus_CurrentTime == 2258);
    static_assert(ns0::Server_NamespaceArray == 2255);
    static_assert(ns0::ReadRequest == 629);
    static_assert(ns0::ReadRequest_Encoding_DefaultBinary == 631);
    static_assert(ns0::Range_Encoding_DefaultBinary == 886);
    static_assert(ns0::BaseDataVariableType == 63);
    static_assert(ns0::UInt32 == 7);
    static_assert(ns0::ThreeDVector == 18808);
    static_assert(ns0::OpcUa_BinarySchema == 7617);
    EXPECT_GT(ns0::kNodeIdCount, 6000u);
}

TEST(Ns0Ids, Lookup) {
    EXPECT_EQ(ns0::nameOf(2256), "Server_ServerStatus");
    EXPECT_EQ(ns0::nameOf(631), "ReadRequest_Encoding_DefaultBinary");
    EXPECT_EQ(ns0::nameOf(0), "");
    EXPECT_EQ(ns0::nameOf(0xFFFFFFFF), "");
    EXPECT_EQ(ns0::idOf("ObjectsFolder"), 85u);
    EXPECT_EQ(ns0::idOf("HasComponent"), 47u);
    EXPECT_EQ(ns0::idOf("NoSuchNode"), std::nullopt);
}

}  // namespace
}  // namespace pnp::ua
