// Framing, secure chunk parsing, sequence numbers, chunk assembly and chunk writing.
#include "ua/transport/chunks.hpp"

#include <gtest/gtest.h>

#include <deque>
#include <numeric>
#include <random>

#include "transport_test_util.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::transport {
namespace {

using test_util::pattern;
using test_util::statusOf;

// A MSG message buffer holding `body`.
Buffer message(const Buffer& body) {
    Buffer m = newMessageBuffer();
    m.insert(m.end(), body.begin(), body.end());
    return m;
}

// A hand-made symmetric chunk.
Buffer symmetricChunk(MessageType t, ChunkType ct, UInt32 channel, UInt32 token, UInt32 seq,
                      UInt32 req, const Buffer& body) {
    Buffer c(kSymmetricHeaderSize);
    encodeMessageHeader(c.data(), t, ct, static_cast<UInt32>(kSymmetricHeaderSize + body.size()));
    putUInt32(c.data() + 8, channel);
    putUInt32(c.data() + 12, token);
    putUInt32(c.data() + 16, seq);
    putUInt32(c.data() + 20, req);
    c.insert(c.end(), body.begin(), body.end());
    return c;
}

TEST(ChunkReader, FedByteByByte) {
    // HEL, a 3-chunk MSG, ERR in one stream, fed one byte at a time.
    Buffer stream = encodeMessage(Hello{0, 8192, 8192, 0, 0, "opc.tcp://a:1"});
    Buffer msg = message(pattern(20000));
    SequenceGenerator seq;
    writeSymmetricChunks(msg, MessageType::Message, 7, 1, 99, seq, 8192);
    stream.insert(stream.end(), msg.begin(), msg.end());
    Buffer err = encodeMessage(ErrorMessage{status::BadTimeout, "x"});
    stream.insert(stream.end(), err.begin(), err.end());

    ChunkReader r(8192 + 100, 8192);
    std::vector<MessageType> types;
    std::vector<std::size_t> sizes;
    for (Byte x : stream) {
        ASSERT_EQ(r.append(&x, 1), 1u);
        while (auto c = r.next()) {
            types.push_back(c->header.type);
            sizes.push_back(c->size);
        }
    }
    EXPECT_EQ(r.buffered(), 0u);
    ASSERT_EQ(types.size(), 5u);
    EXPECT_EQ(types[0], MessageType::Hello);
    EXPECT_EQ(types[1], MessageType::Message);
    EXPECT_EQ(types[3], MessageType::Message);
    EXPECT_EQ(types[4], MessageType::Error);
    EXPECT_EQ(sizes[1], 8192u);
    EXPECT_EQ(sizes[2], 8192u);
    EXPECT_EQ(std::accumulate(sizes.begin(), sizes.end(), std::size_t{0}), stream.size());
}

TEST(ChunkReader, ArbitrarySlices) {
    Buffer stream;
    SequenceGenerator seq;
    for (int i = 0; i < 20; ++i) {
        Buffer m = message(pattern(1000 + i * 777, i));
        writeSymmetricChunks(m, MessageType::Message, 1, 1, i + 1, seq, 8192);
        stream.insert(stream.end(), m.begin(), m.end());
    }
    std::mt19937 rng(5);
    ChunkReader r(8192 + 16384, 8192);
    MessageAssembler a;
    SequenceValidator v;
    std::size_t off = 0;
    int messages = 0;
    while (off < stream.size()) {
        std::size_t n = std::min<std::size_t>(rng() % 9000 + 1, stream.size() - off);
        while (n > 0) {
            std::size_t k = r.append(stream.data() + off, n);
            off += k;
            n -= k;
            while (auto c = r.next()) {
                SecureChunk s = parseSecureChunk(*c);
                v.check(s.sequenceNumber);
                auto ev = a.add(s);
                if (ev.result == MessageAssembler::Result::Complete) {
                    EXPECT_EQ(ev.requestId, static_cast<UInt32>(messages + 1));
                    Buffer expect = pattern(1000 + messages * 777, messages);
                    ASSERT_EQ(ev.size, expect.size());
                    EXPECT_EQ(0, std::memcmp(ev.body, expect.data(), ev.size));
                    ++messages;
                }
            }
        }
    }
    EXPECT_EQ(messages, 20);
}

// Large ByteStrings decoded as references into the receive buffer keep their bytes while the
// reader goes on (it continues in a new block instead of overwriting them); when nothing
// holds the buffer any more, it is reused.
TEST(ChunkReader, DecodedValuesKeepTheBytesTheyShare) {
    auto payload = [](int i) {
        Buffer p = pattern(16384 + static_cast<std::size_t>(i) * 1000, static_cast<unsigned>(i));
        return ByteString(p.data(), p.size());
    };
    Buffer stream;
    SequenceGenerator seq;
    for (int i = 0; i < 12; ++i) {
        Buffer m = newMessageBuffer();
        BinaryEncoder e(m);
        encode(e, payload(i));
        writeSymmetricChunks(m, MessageType::Message, 1, 1, static_cast<UInt32>(i + 1), seq, 65536);
        stream.insert(stream.end(), m.begin(), m.end());
    }
    ChunkReader r(65536 + 4096, 65536);
    std::vector<ByteString> kept;
    std::mt19937 rng(3);
    std::size_t off = 0;
    while (off < stream.size()) {
        std::size_t n = std::min<std::size_t>(rng() % 50000 + 1, stream.size() - off);
        while (n > 0) {
            std::size_t k = r.append(stream.data() + off, n);
            off += k;
            n -= k;
            while (auto c = r.next()) {
                SecureChunk sc = parseSecureChunk(*c);
                BinaryDecoder d(sc.body, sc.bodySize);
                d.shareFrom(r.block());
                ByteString v;
                decode(d, v);
                EXPECT_TRUE(v.isShared());
                kept.push_back(std::move(v));
            }
        }
    }
    ASSERT_EQ(kept.size(), 12u);
    for (int i = 0; i < 12; ++i) EXPECT_EQ(kept[i], payload(i)) << i;

    // Nothing else holds the current block: reading on reuses it.
    kept.clear();
    ByteBlock* before = r.block();
    Buffer m = newMessageBuffer();
    BinaryEncoder e(m);
    encode(e, payload(0));
    writeSymmetricChunks(m, MessageType::Message, 1, 1, 13, seq, 65536);
    for (int round = 0; round < 3; ++round) {
        ASSERT_EQ(r.append(m.data(), m.size()), m.size());
        ASSERT_TRUE(r.next());
    }
    EXPECT_EQ(r.block(), before);
}

TEST(ChunkReader, LyingLengthRejectedFromHeader) {
    ChunkReader r(65536, 65536);
    Byte h[8];
    encodeMessageHeader(h, MessageType::Hello, ChunkType::Final, 0x80000000u);  // 2 GiB
    r.append(h, 8);
    EXPECT_EQ(statusOf([&] { r.next(); }), status::BadTcpMessageTooLarge);
    // Exactly the maximum passes the check and waits for the bytes.
    ChunkReader r2(65536, 8192);
    encodeMessageHeader(h, MessageType::Message, ChunkType::Final, 8192);
    r2.append(h, 8);
    EXPECT_FALSE(r2.next().has_value());
    encodeMessageHeader(h, MessageType::Message, ChunkType::Final, 8193);
    ChunkReader r3(65536, 8192);
    r3.append(h, 8);
    EXPECT_EQ(statusOf([&] { r3.next(); }), status::BadTcpMessageTooLarge);
}

TEST(ChunkReader, Garbage) {
    ChunkReader r(65536, 65536);
    const char* http = "GET / HTTP/1.1\r\n\r\n";
    r.append(reinterpret_cast<const Byte*>(http), std::strlen(http));
    EXPECT_EQ(statusOf([&] { r.next(); }), status::BadTcpMessageTypeInvalid);
}

TEST(SecureChunk, ParseSymmetricAndAsymmetric) {
    Buffer body = pattern(10);
    Buffer c = symmetricChunk(MessageType::Message, ChunkType::Final, 5, 6, 7, 8, body);
    SecureChunk s = parseSecureChunk(RawChunk{decodeMessageHeader(c.data()), c.data(), c.size()});
    EXPECT_EQ(s.channelId, 5u);
    EXPECT_EQ(s.tokenId, 6u);
    EXPECT_EQ(s.sequenceNumber, 7u);
    EXPECT_EQ(s.requestId, 8u);
    ASSERT_EQ(s.bodySize, 10u);
    EXPECT_EQ(0, std::memcmp(s.body, body.data(), 10));

    Buffer o = makeOpenChunk(9, 1, 2, body.data(), body.size());
    s = parseSecureChunk(RawChunk{decodeMessageHeader(o.data()), o.data(), o.size()});
    EXPECT_EQ(s.type, MessageType::OpenSecureChannel);
    EXPECT_EQ(s.channelId, 9u);
    EXPECT_EQ(s.securityPolicyUri, kSecurityPolicyNone);
    EXPECT_EQ(s.senderCertificateSize, 0u);
    EXPECT_EQ(s.sequenceNumber, 1u);
    EXPECT_EQ(s.requestId, 2u);
    EXPECT_EQ(s.bodySize, 10u);

    // Policy URI length pointing past the chunk.
    Buffer bad = o;
    putUInt32(bad.data() + 12, 100000);
    EXPECT_EQ(
        statusOf([&] {
            parseSecureChunk(RawChunk{decodeMessageHeader(bad.data()), bad.data(), bad.size()});
        }),
        status::BadDecodingError);
}

TEST(Sequence, ValidatorRules) {
    SequenceValidator v;
    v.check(51);  // first: anything
    v.check(52);
    EXPECT_EQ(statusOf([&] { v.check(52); }), status::BadSequenceNumberInvalid);  // repeat
    SequenceValidator gap;
    gap.check(1);
    EXPECT_EQ(statusOf([&] { gap.check(3); }), status::BadSequenceNumberInvalid);
    SequenceValidator back;
    back.check(10);
    EXPECT_EQ(statusOf([&] { back.check(9); }), status::BadSequenceNumberInvalid);
    // Legacy wrap: above UInt32.MaxValue - 1024 the next may be any number below 1024.
    SequenceValidator wrap;
    wrap.check(SequenceGenerator::kWrapAbove + 1);
    wrap.check(3);
    wrap.check(4);
    SequenceValidator wrapMax;
    wrapMax.check(0xFFFFFFFFu);
    wrapMax.check(0);
    SequenceValidator early;
    early.check(1000);
    EXPECT_EQ(statusOf([&] { early.check(5); }), status::BadSequenceNumberInvalid);
    SequenceValidator high;
    high.check(SequenceGenerator::kWrapAbove + 5);
    EXPECT_EQ(statusOf([&] { high.check(1024); }), status::BadSequenceNumberInvalid);
}

TEST(Sequence, GeneratorWraps) {
    SequenceGenerator g(SequenceGenerator::kWrapAbove);
    EXPECT_EQ(g.next(), SequenceGenerator::kWrapAbove);
    EXPECT_EQ(g.next(), SequenceGenerator::kWrapAbove + 1);
    EXPECT_EQ(g.next(), 1u);
    EXPECT_EQ(g.next(), 2u);
    // What a generator produces a validator accepts, across the wrap.
    SequenceGenerator g2(SequenceGenerator::kWrapAbove - 2);
    SequenceValidator v;
    for (int i = 0; i < 10; ++i) v.check(g2.next());
}

TEST(ChunkWriter, SingleChunkInPlaceWithoutCopy) {
    Buffer m = message(pattern(100));
    const Byte* before = m.data();
    SequenceGenerator seq(41);
    writeSymmetricChunks(m, MessageType::Message, 3, 4, 5, seq, 8192);
    EXPECT_EQ(m.data(), before);
    ASSERT_EQ(m.size(), 124u);
    auto h = decodeMessageHeader(m.data());
    EXPECT_EQ(h.type, MessageType::Message);
    EXPECT_EQ(h.chunkType, ChunkType::Final);
    EXPECT_EQ(h.size, 124u);
    EXPECT_EQ(getUInt32(m.data() + 8), 3u);
    EXPECT_EQ(getUInt32(m.data() + 12), 4u);
    EXPECT_EQ(getUInt32(m.data() + 16), 41u);
    EXPECT_EQ(getUInt32(m.data() + 20), 5u);
    EXPECT_EQ(seq.peek(), 42u);
}

TEST(ChunkWriter, SplitBoundaries) {
    const std::size_t maxChunk = 8192, maxBody = maxChunk - kSymmetricHeaderSize;
    for (std::size_t n : {std::size_t{0}, std::size_t{1}, maxBody - 1, maxBody, maxBody + 1,
                          2 * maxBody, 2 * maxBody + 1, 10 * maxBody + 17}) {
        Buffer body = pattern(n, static_cast<unsigned>(n));
        Buffer m = message(body);
        SequenceGenerator seq(1);
        writeSymmetricChunks(m, MessageType::Message, 1, 1, 77, seq, maxChunk);
        std::size_t expectChunks = chunkCount(n, maxChunk);
        EXPECT_EQ(m.size(), n + expectChunks * kSymmetricHeaderSize) << n;

        ChunkReader r(maxChunk + 1000, maxChunk);
        MessageAssembler a;
        SequenceValidator v;
        std::size_t off = 0, chunks = 0;
        bool complete = false;
        while (off < m.size()) {
            off += r.append(m.data() + off, m.size() - off);
            while (auto c = r.next()) {
                ++chunks;
                EXPECT_LE(c->size, maxChunk);
                SecureChunk s = parseSecureChunk(*c);
                v.check(s.sequenceNumber);
                EXPECT_EQ(s.sequenceNumber, chunks);
                auto ev = a.add(s);
                if (ev.result == MessageAssembler::Result::Complete) {
                    complete = true;
                    ASSERT_EQ(ev.size, n);
                    if (n) {
                        EXPECT_EQ(0, std::memcmp(ev.body, body.data(), n));
                    }
                }
            }
        }
        EXPECT_TRUE(complete) << n;
        EXPECT_EQ(chunks, expectChunks) << n;
    }
}

class AssemblerTest : public ::testing::Test {
  protected:
    SecureChunk chunk(ChunkType ct, UInt32 req, const Buffer& body,
                      MessageType t = MessageType::Message) {
        storage_.push_back(body);
        SecureChunk s;
        s.type = t;
        s.chunkType = ct;
        s.requestId = req;
        s.body = storage_.back().data();
        s.bodySize = storage_.back().size();
        return s;
    }
    std::deque<Buffer> storage_;
};

TEST_F(AssemblerTest, SingleChunkIsNotCopied) {
    MessageAssembler a;
    auto c = chunk(ChunkType::Final, 1, pattern(50));
    auto ev = a.add(c);
    EXPECT_EQ(ev.result, MessageAssembler::Result::Complete);
    EXPECT_EQ(ev.body, c.body);
    EXPECT_FALSE(ev.assembled);
}

// Partial messages of several connections share one budget; what they hold comes back when
// a message completes, is aborted, fails, or the assembler goes away.
TEST_F(AssemblerTest, SharedBudgetForIncompleteMessages) {
    MemoryBudget budget(10000);
    MessageAssembler a, b;
    a.setBudget(&budget);
    b.setBudget(&budget);
    EXPECT_EQ(a.add(chunk(ChunkType::Intermediate, 1, pattern(6000))).result,
              MessageAssembler::Result::Incomplete);
    EXPECT_EQ(budget.used(), 6000u);
    EXPECT_EQ(statusOf([&] { b.add(chunk(ChunkType::Intermediate, 2, pattern(6000))); }),
              status::BadTcpNotEnoughResources);
    EXPECT_EQ(budget.used(), 6000u);  // b took nothing
    auto ev = a.add(chunk(ChunkType::Final, 1, pattern(3000)));
    EXPECT_EQ(ev.result, MessageAssembler::Result::Complete);
    EXPECT_EQ(ev.size, 9000u);
    EXPECT_EQ(budget.used(), 0u);  // complete: handed out
    // Now b fits; an abort chunk gives its bytes back.
    EXPECT_EQ(b.add(chunk(ChunkType::Intermediate, 3, pattern(6000))).result,
              MessageAssembler::Result::Incomplete);
    Buffer abortBody(8, 0);
    EXPECT_EQ(b.add(chunk(ChunkType::Abort, 3, abortBody)).result,
              MessageAssembler::Result::Aborted);
    EXPECT_EQ(budget.used(), 0u);
    // A single-chunk message never touches the budget.
    EXPECT_EQ(b.add(chunk(ChunkType::Final, 4, pattern(20000))).result,
              MessageAssembler::Result::Complete);
    EXPECT_EQ(budget.used(), 0u);
    {
        MessageAssembler c;
        c.setBudget(&budget);
        c.add(chunk(ChunkType::Intermediate, 5, pattern(4000)));
        EXPECT_EQ(budget.used(), 4000u);
    }
    EXPECT_EQ(budget.used(), 0u);  // destroyed with an incomplete message
    a.add(chunk(ChunkType::Intermediate, 6, pattern(4000)));
    a.leaveBudget();
    EXPECT_EQ(budget.used(), 0u);
}

TEST_F(AssemblerTest, MessageSizeLimit) {
    MessageAssembler a({1000, 0});
    EXPECT_EQ(a.add(chunk(ChunkType::Intermediate, 1, pattern(600))).result,
              MessageAssembler::Result::Incomplete);
    EXPECT_EQ(statusOf([&] { a.add(chunk(ChunkType::Final, 1, pattern(401))); }),
              status::BadTcpMessageTooLarge);
    MessageAssembler single({1000, 0});
    EXPECT_EQ(statusOf([&] { single.add(chunk(ChunkType::Final, 1, pattern(1001))); }),
              status::BadTcpMessageTooLarge);
    MessageAssembler exact({1000, 0});
    exact.add(chunk(ChunkType::Intermediate, 1, pattern(600)));
    EXPECT_EQ(exact.add(chunk(ChunkType::Final, 1, pattern(400))).size, 1000u);
}

TEST_F(AssemblerTest, ChunkCountLimit) {
    MessageAssembler a({0, 3});
    a.add(chunk(ChunkType::Intermediate, 1, pattern(1)));
    a.add(chunk(ChunkType::Intermediate, 1, pattern(1)));
    EXPECT_EQ(statusOf([&] { a.add(chunk(ChunkType::Intermediate, 1, pattern(1))); }),
              StatusCode{});
    EXPECT_EQ(statusOf([&] { a.add(chunk(ChunkType::Final, 1, pattern(1))); }),
              status::BadTcpMessageTooLarge);
}

TEST_F(AssemblerTest, AbortDiscardsPartialMessage) {
    MessageAssembler a;
    a.add(chunk(ChunkType::Intermediate, 1, pattern(100)));
    EXPECT_TRUE(a.inProgress());
    Buffer abortBody(8);
    putUInt32(abortBody.data(), status::BadRequestInterrupted.value);
    std::string reason = "stop";
    putUInt32(abortBody.data() + 4, static_cast<UInt32>(reason.size()));
    abortBody.insert(abortBody.end(), reason.begin(), reason.end());
    auto ev = a.add(chunk(ChunkType::Abort, 1, abortBody));
    EXPECT_EQ(ev.result, MessageAssembler::Result::Aborted);
    EXPECT_EQ(ev.abortStatus, status::BadRequestInterrupted);
    EXPECT_EQ(ev.abortReason, "stop");
    EXPECT_FALSE(a.inProgress());
    // The next message is unaffected.
    Buffer b = pattern(10, 9);
    auto ok = a.add(chunk(ChunkType::Final, 2, b));
    EXPECT_EQ(ok.result, MessageAssembler::Result::Complete);
    EXPECT_EQ(ok.size, 10u);
    EXPECT_EQ(statusOf([&] { a.add(chunk(ChunkType::Abort, 3, Buffer(3))); }),
              status::BadDecodingError);
}

TEST_F(AssemblerTest, RequestIdsAndTypesMustNotInterleave) {
    MessageAssembler a;
    a.add(chunk(ChunkType::Intermediate, 1, pattern(10)));
    EXPECT_EQ(statusOf([&] { a.add(chunk(ChunkType::Final, 2, pattern(10))); }),
              status::BadDecodingError);
    MessageAssembler b;
    b.add(chunk(ChunkType::Intermediate, 1, pattern(10)));
    EXPECT_EQ(statusOf([&] {
                  b.add(chunk(ChunkType::Final, 1, pattern(10), MessageType::CloseSecureChannel));
              }),
              status::BadTcpMessageTypeInvalid);
}

TEST_F(AssemblerTest, AssembledBodyCanBeMovedOut) {
    MessageAssembler a;
    Buffer p1 = pattern(100, 1), p2 = pattern(50, 2);
    a.add(chunk(ChunkType::Intermediate, 4, p1));
    auto ev = a.add(chunk(ChunkType::Final, 4, p2));
    ASSERT_TRUE(ev.assembled);
    Buffer owned = std::move(a.assemblyBuffer());
    ASSERT_EQ(owned.size(), 150u);
    EXPECT_EQ(0, std::memcmp(owned.data(), p1.data(), 100));
    EXPECT_EQ(0, std::memcmp(owned.data() + 100, p2.data(), 50));
    // The assembler keeps working after its buffer was taken.
    a.add(chunk(ChunkType::Intermediate, 5, p1));
    EXPECT_EQ(a.add(chunk(ChunkType::Final, 5, p2)).size, 150u);
}

}  // namespace
}  // namespace pnp::ua::transport
