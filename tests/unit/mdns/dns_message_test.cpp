// DNS codec: round trips of every record type the engine uses, compression, the mDNS bits,
// and malformed packets, which must all be rejected with DnsError.
#include "mdns/dns_message.hpp"

#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <vector>

using namespace pnp::mdns;
using Bytes = std::vector<std::uint8_t>;

namespace {

DnsMessage sample() {
    DnsMessage m;
    m.id = 0x1234;
    m.flags = DnsMessage::kResponseFlag | DnsMessage::kAuthoritativeFlag;
    m.questions.push_back({"_opcua-tcp._tcp.local", rrtype::PTR, kClassIn, true});
    const std::string inst = "robot\\.1 (2)._opcua-tcp._tcp.local";
    m.answers.push_back(ptrRecord("_opcua-tcp._tcp.local", inst, 120));
    m.additionals.push_back(srvRecord(inst, {1, 2, 4840, "robot-1-host.local"}, 120, true));
    m.additionals.push_back(txtRecord(inst, {"path=/", "caps=LDS,DA"}, 4500, true));
    m.additionals.push_back(aRecord("robot-1-host.local", {10, 0, 0, 7}, 120, true));
    ResourceRecord aaaa;
    aaaa.name = "robot-1-host.local";
    aaaa.type = rrtype::AAAA;
    aaaa.ttl = 120;
    aaaa.ipv6[0] = 0xfe;
    aaaa.ipv6[15] = 1;
    m.additionals.push_back(aaaa);
    ResourceRecord nsec = aaaa;
    nsec.type = rrtype::NSEC;
    nsec.raw = {0xC0, 0x0C, 0x00, 0x01, 0x40};
    m.authorities.push_back(nsec);
    return m;
}

Bytes header(std::uint16_t qd, std::uint16_t an, std::uint16_t ns = 0, std::uint16_t ar = 0) {
    return {0,    0,
            0x84, 0,
            0,    static_cast<std::uint8_t>(qd),
            0,    static_cast<std::uint8_t>(an),
            0,    static_cast<std::uint8_t>(ns),
            0,    static_cast<std::uint8_t>(ar)};
}

}  // namespace

TEST(DnsMessage, RoundTripAllTypes) {
    DnsMessage m = sample();
    Bytes b = encode(m);
    DnsMessage d = decode(b);
    EXPECT_EQ(d.id, 0x1234);
    EXPECT_TRUE(d.isResponse());
    ASSERT_EQ(d.questions.size(), 1u);
    EXPECT_TRUE(d.questions[0].unicastResponse);
    EXPECT_EQ(d.questions[0].qclass, kClassIn);
    ASSERT_EQ(d.answers.size(), 1u);
    EXPECT_EQ(d.answers[0].ptr, "robot\\.1 (2)._opcua-tcp._tcp.local");
    EXPECT_FALSE(d.answers[0].cacheFlush);
    ASSERT_EQ(d.additionals.size(), 4u);
    EXPECT_TRUE(d.additionals[0].cacheFlush);
    EXPECT_EQ(d.additionals[0].rrclass, kClassIn);
    EXPECT_EQ(d.additionals[0].srv.port, 4840);
    EXPECT_EQ(d.additionals[0].srv.priority, 1);
    EXPECT_EQ(d.additionals[0].srv.weight, 2);
    EXPECT_EQ(d.additionals[0].srv.target, "robot-1-host.local");
    EXPECT_EQ(d.additionals[1].txt, (std::vector<std::string>{"path=/", "caps=LDS,DA"}));
    EXPECT_EQ(d.additionals[1].ttl, 4500u);
    EXPECT_EQ(d.additionals[2].ipv4, (std::array<std::uint8_t, 4>{10, 0, 0, 7}));
    EXPECT_EQ(d.additionals[3].ipv6, m.additionals[3].ipv6);
    ASSERT_EQ(d.authorities.size(), 1u);
    EXPECT_EQ(d.authorities[0].raw, m.authorities[0].raw);
    // Re-encoding the decoded message gives the same bytes.
    EXPECT_EQ(encode(d), b);
}

TEST(DnsMessage, CompressionShrinksRepeatedNames) {
    DnsMessage m = sample();
    Bytes b = encode(m);
    // Without compression the instance name alone (36 bytes) appears four times.
    EXPECT_LT(b.size(), 260u);
    auto labels = splitName(m.answers[0].ptr);
    ASSERT_EQ(labels.size(), 4u);
    EXPECT_EQ(labels[0], "robot.1 (2)");
}

TEST(DnsMessage, NamesCompareCaseInsensitive) {
    EXPECT_TRUE(namesEqual("Robot-1._OPCUA-tcp._tcp.LOCAL", "robot-1._opcua-tcp._tcp.local"));
    EXPECT_FALSE(namesEqual("robot-1.local", "robot-2.local"));
    EXPECT_EQ(lowerName("AbC.Local"), "abc.local");
}

TEST(DnsMessage, EmptyTxtEncodesOneEmptyString) {
    ResourceRecord t;
    t.name = "x.local";
    t.type = rrtype::TXT;
    EXPECT_EQ(canonicalRdata(t), Bytes{0});
}

TEST(DnsMessage, EncodeRejectsOversizedNames) {
    DnsMessage m;
    m.questions.push_back({std::string(64, 'a') + ".local", rrtype::A, kClassIn, false});
    EXPECT_THROW(encode(m), DnsError);
    std::string longName;
    for (int i = 0; i < 5; ++i) longName += std::string(60, 'b') + ".";
    m.questions[0].name = longName + "local";
    EXPECT_THROW(encode(m), DnsError);
    m.questions[0].name = "a..local";
    EXPECT_THROW(encode(m), DnsError);
}

TEST(DnsMessage, RejectsTruncatedAtEveryLength) {
    Bytes b = encode(sample());
    for (std::size_t n = 0; n < b.size(); ++n) {
        Bytes t(b.begin(), b.begin() + static_cast<std::ptrdiff_t>(n));
        EXPECT_THROW(decode(t), DnsError) << "length " << n;
    }
}

TEST(DnsMessage, RejectsCompressionLoops) {
    // Question name = pointer to itself (offset 12).
    Bytes self = header(1, 0);
    self.insert(self.end(), {0xC0, 12, 0, 1, 0, 1});
    EXPECT_THROW(decode(self), DnsError);
    // Two names pointing at each other: label then pointer forward to the second name.
    Bytes mutual = header(2, 0);
    mutual.insert(mutual.end(), {1, 'a', 0xC0, 20, 0, 1, 0, 1});  // name at 12, ptr -> 20
    mutual.insert(mutual.end(), {1, 'b', 0xC0, 12, 0, 1, 0, 1});  // name at 20, ptr -> 12
    EXPECT_THROW(decode(mutual), DnsError);
    // Forward pointer.
    Bytes fwd = header(1, 0);
    fwd.insert(fwd.end(), {0xC0, 18, 0, 1, 0, 1, 0});
    EXPECT_THROW(decode(fwd), DnsError);
    // Reserved label types 0x40 / 0x80.
    Bytes reserved = header(1, 0);
    reserved.insert(reserved.end(), {0x41, 'a', 0, 0, 1, 0, 1});
    EXPECT_THROW(decode(reserved), DnsError);
}

TEST(DnsMessage, AcceptsBackwardPointerChain) {
    Bytes b = header(2, 0);
    b.insert(b.end(), {5, 'l', 'o', 'c', 'a', 'l', 0, 0, 1, 0, 1});  // "local" at 12
    b.insert(b.end(), {1, 'x', 0xC0, 12, 0, 1, 0, 1});               // "x.local"
    DnsMessage m = decode(b);
    ASSERT_EQ(m.questions.size(), 2u);
    EXPECT_EQ(m.questions[1].name, "x.local");
}

TEST(DnsMessage, RejectsCountsLargerThanThePacket) {
    Bytes b = header(0, 0);
    b[6] = 0xFF;  // 65280 answers in a 12-byte packet
    b[7] = 0xFF;
    EXPECT_THROW(decode(b), DnsError);
    Bytes q = header(3, 0);
    q.insert(q.end(), {0, 0, 1, 0, 1});  // only one question present
    EXPECT_THROW(decode(q), DnsError);
}

TEST(DnsMessage, RejectsOversizedNamesOnTheWire) {
    Bytes b = header(1, 0);
    // 5 labels of 60 bytes: 305 bytes > 255.
    for (int i = 0; i < 5; ++i) {
        b.push_back(60);
        b.insert(b.end(), 60, 'x');
    }
    b.insert(b.end(), {0, 0, 1, 0, 1});
    EXPECT_THROW(decode(b), DnsError);
    // A long name built from pointers: each name adds one label in front of the previous.
    Bytes c = header(0, 0);
    std::size_t prev = 0;
    int count = 0;
    for (int i = 0; i < 40; ++i) {
        std::size_t at = c.size();
        c.push_back(10);
        c.insert(c.end(), 10, 'y');
        if (prev == 0) {
            c.push_back(0);
        } else {
            c.push_back(static_cast<std::uint8_t>(0xC0 | (prev >> 8)));
            c.push_back(static_cast<std::uint8_t>(prev));
        }
        c.insert(c.end(), {0, 1, 0, 1});
        prev = at;
        ++count;
    }
    c[5] = static_cast<std::uint8_t>(count);
    EXPECT_THROW(decode(c), DnsError);
}

TEST(DnsMessage, RejectsBadRdata) {
    // A record with rdlength 5.
    Bytes a = header(0, 1);
    a.insert(a.end(), {0, 0, 1, 0, 1, 0, 0, 0, 10, 0, 5, 1, 2, 3, 4, 5});
    EXPECT_THROW(decode(a), DnsError);
    // rdlength beyond the packet.
    Bytes big = header(0, 1);
    big.insert(big.end(), {0, 0, 16, 0, 1, 0, 0, 0, 10, 0xFF, 0xFF, 1});
    EXPECT_THROW(decode(big), DnsError);
    // TXT string running past its rdata (but inside the packet).
    Bytes txt = header(0, 1);
    txt.insert(txt.end(), {0, 0, 16, 0, 1, 0, 0, 0, 10, 0, 2, 5, 'a', 'b', 'c', 'd', 'e'});
    EXPECT_THROW(decode(txt), DnsError);
    // SRV whose target ends outside its rdata.
    Bytes srv = header(0, 1);
    srv.insert(srv.end(), {0, 0, 33, 0, 1, 0, 0, 0, 10, 0, 7, 0, 0, 0, 0, 0, 0, 1, 'a', 0});
    EXPECT_THROW(decode(srv), DnsError);
}

TEST(DnsMessage, RandomMutationsNeverCrash) {
    Bytes b = encode(sample());
    std::mt19937 rng(42);
    for (int i = 0; i < 20000; ++i) {
        Bytes t = b;
        int flips = 1 + static_cast<int>(rng() % 4);
        for (int f = 0; f < flips; ++f) t[rng() % t.size()] = static_cast<std::uint8_t>(rng());
        if (rng() % 4 == 0) t.resize(rng() % t.size());
        try {
            DnsMessage m = decode(t);
            encode(m);  // may throw DnsError (e.g. decoded label with a '.' is fine)
        } catch (const DnsError&) {
        }
    }
}
