#include "ua/types/binary.hpp"

#include <gtest/gtest.h>

#include <cstring>

#include "ua/types/status_codes.hpp"

using namespace pnp::ua;

namespace {
template <class T>
Buffer enc(const T& v) {
    return encodeToBuffer(v);
}
template <class T>
T roundTrip(const T& v) {
    Buffer b = enc(v);
    return decodeFromBuffer<T>(b.data(), b.size());
}
StatusCode decodeStatus(const Buffer& b, const DecodeLimits& limits = {}) {
    try {
        decodeFromBuffer<Variant>(b.data(), b.size(), true, limits);
    } catch (const DecodeError& e) {
        return e.status();
    }
    return status::Good;
}
}  // namespace

// Byte sequences from OPC 10000-6 §5.2.2.
TEST(BinaryEncoding, NodeIdFormsMatchTheSpec) {
    EXPECT_EQ(enc(NodeId(0, 72u)), (Buffer{0x00, 0x48}));
    EXPECT_EQ(enc(NodeId(5, 1025u)), (Buffer{0x01, 0x05, 0x01, 0x04}));
    EXPECT_EQ(enc(NodeId(1, "Hot水")), (Buffer{0x03, 0x01, 0x00, 0x06, 0x00, 0x00, 0x00, 0x48, 0x6F,
                                               0x74, 0xE6, 0xB0, 0xB4}));
    EXPECT_EQ(enc(NodeId(2, 70000u)), (Buffer{0x02, 0x02, 0x00, 0x70, 0x11, 0x01, 0x00}));
    auto g = *Guid::parse("72962B91-FA75-4AE6-8D28-B404DC7DAF63");
    EXPECT_EQ(enc(g), (Buffer{0x91, 0x2B, 0x96, 0x72, 0x75, 0xFA, 0xE6, 0x4A, 0x8D, 0x28, 0xB4,
                              0x04, 0xDC, 0x7D, 0xAF, 0x63}));
}

TEST(BinaryEncoding, StringsAndNulls) {
    EXPECT_EQ(enc(String("水Boy")), (Buffer{0x06, 0, 0, 0, 0xE6, 0xB0, 0xB4, 0x42, 0x6F, 0x79}));
    Buffer null{0xFF, 0xFF, 0xFF, 0xFF};
    EXPECT_EQ(decodeFromBuffer<String>(null.data(), null.size()), "");
    EXPECT_EQ(enc(LocalizedText("", "")), (Buffer{0x00}));
    EXPECT_EQ(enc(Variant()), (Buffer{0x00}));
}

TEST(BinaryEncoding, EveryBuiltinScalarAndArrayRoundTrips) {
    DiagnosticInfo inner;
    inner.additionalInfo = "inner";
    DiagnosticInfo diag;
    diag.symbolicId = 1;
    diag.namespaceUri = 2;
    diag.locale = 3;
    diag.localizedText = 4;
    diag.additionalInfo = "info";
    diag.innerStatusCode = StatusCode(0x80340000);
    diag.innerDiagnosticInfo = std::make_shared<DiagnosticInfo>(inner);
    DataValue dv(Variant(Int16(-3)));
    dv.status = StatusCode(0x40000000);
    dv.sourceTimestamp = DateTime::now();
    dv.sourcePicoseconds = 10;
    dv.serverTimestamp = DateTime::now();
    dv.serverPicoseconds = 20;
    ExtensionObject xo{NodeId(0, 886u), ExtensionObject::Encoding::Binary, std::string(16, 'x')};

    std::vector<Variant> values = {
        Variant(true),
        Variant(SByte(-5)),
        Variant(Byte(200)),
        Variant(Int16(-300)),
        Variant(UInt16(60000)),
        Variant(Int32(-70000)),
        Variant(UInt32(4000000000u)),
        Variant(Int64(-1) << 40),
        Variant(UInt64(1) << 63),
        Variant(Float(1.5f)),
        Variant(Double(-2.25)),
        Variant(String("hello")),
        Variant(DateTime::now()),
        Variant(*Guid::parse("72962B91-FA75-4AE6-8D28-B404DC7DAF63")),
        Variant(ByteString(std::string("\x00\x01\x02", 3))),
        Variant(XmlElement{"<a/>"}),
        Variant(NodeId(3, "n")),
        Variant(ExpandedNodeId(NodeId(0, 5u), "urn:x", 2)),
        Variant(StatusCode(0x80340000)),
        Variant(QualifiedName{2, "q"}),
        Variant(LocalizedText("en", "t")),
        Variant(xo),
        Variant(dv),
        Variant(diag),
        Variant(std::vector<Int32>{1, 2, 3}),
        Variant(std::vector<Boolean>{true, false}),
        Variant(std::vector<String>{"a", "", "c"}),
        Variant(std::vector<Variant>{Variant(1.0), Variant(std::vector<Byte>{1, 2})}),
        Variant(std::vector<DataValue>{dv, DataValue()}),
        Variant(std::vector<DiagnosticInfo>{diag}),
        Variant(std::vector<ExtensionObject>{xo, ExtensionObject{}}),
    };
    for (const auto& v : values) EXPECT_EQ(roundTrip(v), v) << v.toString();

    Variant matrix(std::vector<Float>{1, 2, 3, 4, 5, 6});
    matrix.setArrayDimensions({3, 2});
    EXPECT_EQ(roundTrip(matrix), matrix);
    EXPECT_EQ(roundTrip(dv), dv);
}

TEST(BinaryDecoding, RejectsMalformedInput) {
    // Truncated Int32 array: length 3, one element.
    EXPECT_EQ(decodeStatus({0x86, 3, 0, 0, 0, 1, 0, 0, 0}), status::BadDecodingError);
    // Unknown built-in type id 30.
    EXPECT_EQ(decodeStatus({30, 0, 0, 0, 0}), status::BadDecodingError);
    // Lying String length (2 GiB).
    EXPECT_EQ(decodeStatus({12, 0xFF, 0xFF, 0xFF, 0x7F, 'a'}), status::BadEncodingLimitsExceeded);
    // String length beyond the message.
    EXPECT_EQ(decodeStatus({12, 10, 0, 0, 0, 'a'}), status::BadDecodingError);
    // Array count far beyond the bytes present: rejected before allocation.
    EXPECT_EQ(decodeStatus({0x8B, 0x00, 0x00, 0x0F, 0x00}), status::BadDecodingError);
    // Negative length other than -1.
    EXPECT_EQ(decodeStatus({12, 0xFE, 0xFF, 0xFF, 0xFF}), status::BadDecodingError);
    // Matrix whose dimensions do not match the element count.
    EXPECT_EQ(decodeStatus({0xC3, 2, 0, 0, 0, 1, 2, 1, 0, 0, 0, 3, 0, 0, 0}),
              status::BadDecodingError);
    // Scalar Variant inside a Variant.
    EXPECT_EQ(decodeStatus({24, 0}), status::BadDecodingError);
    // Invalid NodeId encoding byte inside a NodeId variant.
    EXPECT_EQ(decodeStatus({17, 0x07, 0}), status::BadDecodingError);
    // Trailing bytes.
    EXPECT_EQ(decodeStatus({1, 1, 0}), status::BadDecodingError);
}

TEST(BinaryDecoding, NestingDepthIsBounded) {
    // DataValue containing a Variant holding a DataValue ... 1000 levels deep.
    Buffer b;
    for (int i = 0; i < 1000; ++i) {
        b.push_back(23);    // Variant: DataValue
        b.push_back(0x01);  // DataValue: has value
    }
    b.push_back(0);
    EXPECT_EQ(decodeStatus(b), status::BadEncodingLimitsExceeded);
    // Within the limit it decodes.
    Buffer ok;
    for (int i = 0; i < 5; ++i) {
        ok.push_back(23);
        ok.push_back(0x01);
    }
    ok.push_back(0);
    EXPECT_EQ(decodeStatus(ok), status::Good);
}

TEST(BinaryDecoding, LimitsAreConfigurable) {
    Buffer b = enc(Variant(std::vector<Int32>(100, 7)));
    DecodeLimits small;
    small.maxArrayLength = 10;
    EXPECT_EQ(decodeStatus(b, small), status::BadEncodingLimitsExceeded);
    EXPECT_EQ(decodeStatus(b), status::Good);
}

TEST(BinaryDecoding, EveryTruncationOfAValidMessageFailsCleanly) {
    DataValue dv(Variant(std::vector<String>{"alpha", "beta"}));
    dv.sourceTimestamp = DateTime::now();
    Buffer full = enc(Variant(std::vector<Variant>{Variant(dv), Variant(NodeId(1, "x"))}));
    for (std::size_t n = 0; n < full.size(); ++n) {
        Buffer cut(full.begin(), full.begin() + static_cast<std::ptrdiff_t>(n));
        EXPECT_TRUE(decodeStatus(cut).isBad()) << n;
    }
}

// An encoder with Splices references long byte runs instead of copying them; joined back in,
// the message is byte for byte the plain encoding.
TEST(BinarySplices, JoinedEqualsPlainEncoding) {
    const std::size_t k = kDefaultSpliceMin;
    std::vector<Variant> values{
        Variant(ByteString(std::string(k + 904, 'x'))), Variant(Int32(3)),
        Variant(String(std::string(k, 's'))), Variant(ByteString(std::string(k - 1, 'y'))),
        Variant(std::vector<ByteString>{ByteString(std::string(2 * k + 808, 'z')),
                                        ByteString("short")})};
    Buffer plain;
    {
        BinaryEncoder e(plain);
        encode(e, values);
    }
    Buffer withHoles;
    Splices splices;
    {
        BinaryEncoder e(withHoles, &splices);
        encode(e, values);
    }
    ASSERT_EQ(splices.size(), 3u);  // k + 904, k and 2k + 808 bytes; k - 1 is copied
    EXPECT_EQ(withHoles.size() + splicedSize(splices), plain.size());
    EXPECT_EQ(joinSplices(std::move(withHoles), splices), plain);
    // Without Splices nothing changes.
    Buffer again;
    {
        BinaryEncoder e(again, nullptr);
        encode(e, values);
    }
    EXPECT_EQ(again, plain);
}

// BinaryDecoder::shareFrom: ByteStrings of at least the minimum size point into the block
// (values equal to a copying decode); shorter ones, Strings and opaque NodeIds are copied.
TEST(BinaryDecoding, LargeByteStringsShareTheBlockTheyAreDecodedFrom) {
    const std::size_t k = kDefaultShareMin;
    std::vector<Variant> values{
        Variant(ByteString(std::string(k, 'a'))), Variant(ByteString(std::string(k - 1, 'b'))),
        Variant(String(std::string(k, 's'))), Variant(NodeId(2, ByteString(std::string(k, 'n')))),
        Variant(std::vector<ByteString>{ByteString(std::string(k + 5, 'c')), ByteString("d")})};
    Buffer b = enc(values);
    ByteBlockRef block(b.size());
    std::memcpy(block->data(), b.data(), b.size());

    std::vector<Variant> shared;
    {
        BinaryDecoder d(block->data(), b.size());
        d.shareFrom(block.get(), k);
        decode(d, shared);
        EXPECT_EQ(d.remaining(), 0u);
    }
    EXPECT_EQ(shared, values);
    auto inBlock = [&](const ByteString& s) {
        return s.data() >= block->data() && s.data() + s.size() <= block->data() + b.size();
    };
    EXPECT_TRUE(inBlock(*shared[0].scalar<ByteString>()));
    EXPECT_FALSE(inBlock(*shared[1].scalar<ByteString>()));
    EXPECT_FALSE(inBlock(shared[3].scalar<NodeId>()->opaque()));
    EXPECT_TRUE(inBlock((*shared[4].array<ByteString>())[0]));
    EXPECT_FALSE(block->unique());
    // The values keep the block: dropping the first reference does not free it (ASan).
    block = ByteBlockRef();
    EXPECT_EQ(shared[0].scalar<ByteString>()->view(), std::string(k, 'a'));
    shared.clear();

    // By default a value must be a fifth of the block: here all of the encoded bytes.
    {
        ByteBlockRef big(5 * b.size());
        std::memcpy(big->data(), b.data(), b.size());
        BinaryDecoder d(big->data(), b.size());
        d.shareFrom(big.get());
        std::vector<Variant> copied;
        decode(d, copied);
        EXPECT_EQ(copied, values);
        EXPECT_TRUE(big->unique());
    }
    // Without a block, nothing is shared.
    auto plain = decodeFromBuffer<std::vector<Variant>>(b.data(), b.size());
    EXPECT_EQ(plain, values);
}
