// ua::discovery's TXT / discovery-URL helpers (no network).
#include "ua/discovery/txt_record.hpp"

#include <gtest/gtest.h>

namespace pnp::ua::discovery {
namespace {

TEST(UrlHost, AnIpv4LiteralSrvTargetWinsOverTheARecords) {
    // node-opcua's LDS announces a server registered with it by its URL's host and puts the
    // LDS's own addresses in the A records of that name.
    EXPECT_EQ(urlHost("10.79.0.4", {"10.79.0.1"}), "10.79.0.4");
    EXPECT_EQ(urlHost("10.79.0.4.", {"10.79.0.1"}), "10.79.0.4");
    EXPECT_EQ(urlHost("10.79.0.4", {}), "10.79.0.4");
}

TEST(UrlHost, ANameUsesItsFirstAddressElseTheName) {
    EXPECT_EQ(urlHost("robot-host.local", {"10.0.0.7", "10.0.0.8"}), "10.0.0.7");
    EXPECT_EQ(urlHost("robot-host.local", {}), "robot-host.local");
    // Not quite an address: a name.
    EXPECT_EQ(urlHost("10.79.0", {"10.0.0.7"}), "10.0.0.7");
    EXPECT_EQ(urlHost("10.79.0.4.local", {"10.0.0.7"}), "10.0.0.7");
}

TEST(DiscoveryUrl, FromAnnouncement) {
    const auto a = parseTxt({"path=/DiscoveryServer", "caps=lds"});
    EXPECT_EQ(discoveryUrl(urlHost("10.79.0.1", {"10.79.0.1"}), 4840, a.path),
              "opc.tcp://10.79.0.1:4840/DiscoveryServer");
    EXPECT_TRUE(hasCapability(a.capabilities, "LDS"));
}

}  // namespace
}  // namespace pnp::ua::discovery
