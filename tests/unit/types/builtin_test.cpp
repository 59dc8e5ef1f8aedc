#include "ua/types/builtin.hpp"

#include <gtest/gtest.h>

#include <cstring>

using namespace pnp::ua;

TEST(NodeId, ParsesAndPrintsEveryIdType) {
    for (std::string s : {"i=85", "ns=2;s=Demo.Echo", "ns=1;g=72962B91-FA75-4AE6-8D28-B404DC7DAF63",
                          "ns=3;b=AQID", "ns=65535;i=4294967295"}) {
        auto id = NodeId::parse(s);
        ASSERT_TRUE(id) << s;
        EXPECT_EQ(id->toString(), s);
    }
    EXPECT_EQ(NodeId::parse("ns=2;s=a;b=c")->string(), "a;b=c");
    for (std::string bad : {"", "x=1", "i=", "i=abc", "ns=;i=1", "ns=70000;i=1", "g=123"})
        EXPECT_FALSE(NodeId::parse(bad)) << bad;
}

TEST(NodeId, NullAndHash) {
    EXPECT_TRUE(NodeId().isNull());
    EXPECT_FALSE(NodeId(1, 0u).isNull());
    EXPECT_EQ(NodeId(2, "x").hash(), NodeId(2, "x").hash());
    EXPECT_NE(NodeId(0, 85u), NodeId(1, 85u));
}

TEST(ExpandedNodeId, ParsesNamespaceUri) {
    auto id = ExpandedNodeId::parse("nsu=urn:pnp:demo;s=Demo");
    ASSERT_TRUE(id);
    EXPECT_EQ(id->namespaceUri, "urn:pnp:demo");
    EXPECT_EQ(id->nodeId.string(), "Demo");
    EXPECT_EQ(id->toString(), "nsu=urn:pnp:demo;s=Demo");
    auto svr = ExpandedNodeId::parse("svr=2;ns=1;i=7");
    ASSERT_TRUE(svr);
    EXPECT_EQ(svr->serverIndex, 2u);
}

TEST(DateTime, Iso8601RoundTrip) {
    DateTime t{DateTime::kUnixEpochTicks + 1234567890123LL};
    auto s = t.toIso8601();
    EXPECT_EQ(s, "1970-01-02T10:17:36.7890123Z");
    EXPECT_EQ(DateTime::parseIso8601(s), t);
    EXPECT_FALSE(DateTime::parseIso8601("yesterday"));
    auto now = DateTime::now();
    EXPECT_GT(now.ticks, DateTime::kUnixEpochTicks);
}

TEST(Guid, ParseAndPrint) {
    auto g = Guid::parse("72962B91-FA75-4AE6-8D28-B404DC7DAF63");
    ASSERT_TRUE(g);
    EXPECT_EQ(g->data1, 0x72962B91u);
    EXPECT_EQ(g->data4[7], 0x63);
    EXPECT_EQ(g->toString(), "72962B91-FA75-4AE6-8D28-B404DC7DAF63");
    EXPECT_FALSE(Guid::parse("72962B91-FA75-4AE6-8D28-B404DC7DAF6X"));
}

TEST(ByteString, Base64) {
    for (std::string raw :
         std::vector<std::string>{"", "a", "ab", "abc", "abcd", std::string("\0\xff\x10", 3)}) {
        ByteString b(raw);
        auto back = ByteString::fromBase64(b.toBase64());
        ASSERT_TRUE(back);
        EXPECT_EQ(back->view(), raw);
    }
    EXPECT_EQ(ByteString(std::string("abc")).toBase64(), "YWJj");
}

TEST(ByteString, ValueSemanticsInlineAndInABlock) {
    for (std::size_t n : {std::size_t{0}, std::size_t{1}, ByteString::kInline,
                          ByteString::kInline + 1, std::size_t{100000}}) {
        std::string raw(n, '\0');
        for (std::size_t i = 0; i < n; ++i) raw[i] = static_cast<char>(i * 7 + 1);
        ByteString a(raw);
        EXPECT_EQ(a.size(), n);
        EXPECT_EQ(a.view(), raw);
        EXPECT_EQ(a.isShared(), n > ByteString::kInline);
        ByteString b = a;  // a copy of a long one shares its block
        EXPECT_EQ(b, a);
        EXPECT_EQ(b.view(), raw);
        if (n > ByteString::kInline) {
            EXPECT_EQ(b.data(), a.data());
        }
        ByteString c = std::move(a);
        EXPECT_TRUE(a.empty());  // NOLINT(bugprone-use-after-move): moved-from is empty
        EXPECT_EQ(c.view(), raw);
        a = c;
        c = ByteString();
        EXPECT_EQ(a.view(), raw);
        const ByteString& same = a;
        a = same;  // self-assignment keeps the value
        EXPECT_EQ(a.view(), raw);
    }
    // Ordering is that of the bytes as unsigned values, like std::string's.
    EXPECT_LT(ByteString(std::string("\x01")), ByteString(std::string("\xff")));
    EXPECT_LT(ByteString(std::string("ab")), ByteString(std::string("abc")));
    EXPECT_EQ(ByteString(std::string(40, 'x')), ByteString(std::string(40, 'x')));
}

TEST(ByteString, AssignNeverChangesAnotherValue) {
    const std::string a(40, 'a'), b(36, 'b'), c(60, 'c');
    ByteString x(a);
    const Byte* block = x.data();
    x.assign(reinterpret_cast<const Byte*>(b.data()), b.size());  // sole holder: reused
    EXPECT_EQ(x.view(), b);
    EXPECT_EQ(x.data(), block);
    ByteString y = x;  // now shared: assign makes a new block
    x.assign(reinterpret_cast<const Byte*>(a.data()), a.size());
    EXPECT_EQ(y.view(), b);
    EXPECT_EQ(x.view(), a);
    x.assign(reinterpret_cast<const Byte*>(c.data()), c.size());  // larger than the block
    EXPECT_EQ(x.view(), c);
    x.assign(reinterpret_cast<const Byte*>("xy"), 2);
    EXPECT_EQ(x.view(), "xy");
    EXPECT_FALSE(x.isShared());
}

TEST(ByteString, SharedKeepsItsBlockAlive) {
    ByteBlock* block = ByteBlock::create(64);
    std::memset(block->data(), 'q', 64);
    ByteString s = ByteString::shared(block, block->data() + 8, 32);
    EXPECT_FALSE(block->unique());
    block->unref();  // the creator lets go: s still holds it (ASan checks the reads below)
    EXPECT_EQ(s.view(), std::string(32, 'q'));
    ByteString t = s;
    s = ByteString();
    EXPECT_EQ(t.view(), std::string(32, 'q'));
}

TEST(Variant, HoldsScalarsArraysAndMatrices) {
    Variant v = Int32(7);
    EXPECT_TRUE(v.isScalar());
    EXPECT_EQ(v.type(), BuiltinType::Int32);
    ASSERT_NE(v.scalar<Int32>(), nullptr);
    EXPECT_EQ(*v.scalar<Int32>(), 7);
    EXPECT_EQ(v.scalar<UInt32>(), nullptr);

    Variant a(std::vector<Double>{1, 2, 3, 4, 5, 6});
    a.setArrayDimensions({2, 3});
    EXPECT_TRUE(a.isArray());
    EXPECT_EQ(a.type(), BuiltinType::Double);
    EXPECT_EQ(a.arrayLength(), 6u);

    Variant dv = DataValue(Variant(String("x")));
    EXPECT_EQ(dv.type(), BuiltinType::DataValue);
    EXPECT_EQ(*dv.scalar<DataValue>()->value->scalar<String>(), "x");

    Variant nested(std::vector<Variant>{Variant(true), Variant("s")});
    EXPECT_EQ(nested.type(), BuiltinType::Variant);
    Variant copy = nested;
    EXPECT_EQ(copy, nested);
    EXPECT_EQ(Variant().type(), BuiltinType::Null);
}
