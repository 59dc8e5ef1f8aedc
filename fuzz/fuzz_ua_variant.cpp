// fuzz_ua_variant: the bounded binary codec of the recursive built-in types and of the
// generated namespace-0 structures.
//
// Input: byte 0 % 6 selects what the rest is decoded as:
//   0 Variant   1 DataValue   2 DiagnosticInfo   3 ExtensionObject (re-encoded through the
//   ns0 codec registry when its type is known)   4 an ns0 structure body: bytes 1-2 pick the
//   codec (little endian, modulo the number of codecs), the rest is the body   5 the
//   NodeId-like types (NodeId, ExpandedNodeId, QualifiedName, LocalizedText)
// Whatever decodes (with small DecodeLimits, so that the limits are reached) must encode,
// decode again to an equal value (NaN aside) and encode to the same bytes. The JSON /
// text renderings must not crash.
//
// Seeds: fuzz_ua_variant -pnp_write_seeds=<dir> (see fuzz_support.hpp).
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "fuzz_support.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_types.hpp"
#include "ua/types/status_codes.hpp"

using namespace pnp::ua;
using pnp::fuzz::append;
using pnp::fuzz::check;

namespace {

enum Mode : Byte {
    kVariant = 0,
    kDataValue = 1,
    kDiagnosticInfo = 2,
    kExtensionObject = 3,
    kStructure = 4,
    kNodeIds = 5,
    kModeCount = 6,
};

DecodeLimits limits() {
    DecodeLimits l;
    l.maxStringLength = 4096;
    l.maxArrayLength = 4096;
    l.maxDepth = 12;
    return l;
}

// NaN != NaN: values holding one are compared by their encoding only.
bool hasNaN(const Variant& v);
bool hasNaN(const DataValue& v) { return v.value && hasNaN(*v.value); }
bool hasNaN(const Variant& v) {
    if (auto f = v.scalar<Float>()) return std::isnan(*f);
    if (auto d = v.scalar<Double>()) return std::isnan(*d);
    if (auto dv = v.scalar<DataValue>()) return hasNaN(*dv);
    if (auto a = v.array<Float>())
        for (Float x : *a)
            if (std::isnan(x)) return true;
    if (auto a = v.array<Double>())
        for (Double x : *a)
            if (std::isnan(x)) return true;
    if (auto a = v.array<Variant>())
        for (const auto& x : *a)
            if (hasNaN(x)) return true;
    if (auto a = v.array<DataValue>())
        for (const auto& x : *a)
            if (hasNaN(x)) return true;
    return false;
}
template <class T>
bool hasNaNOf(const T& v) {
    if constexpr (std::is_same_v<T, Variant> || std::is_same_v<T, DataValue>) {
        return hasNaN(v);
    } else if constexpr (std::is_same_v<T, std::vector<DataValue>>) {
        for (const auto& x : v)
            if (hasNaN(x)) return true;
        return false;
    } else {
        return false;
    }
}

// decode -> encode -> decode -> encode; both encodings equal, both values equal.
template <class T>
void roundTrip(const Byte* p, std::size_t n) {
    T v{};
    try {
        BinaryDecoder d(p, n, limits());
        decode(d, v);
    } catch (const DecodeError& e) {
        const auto s = e.status();
        check(s == status::BadDecodingError || s == status::BadEncodingLimitsExceeded,
              "DecodeError with an unexpected status", s.toString());
        return;
    }
    const Buffer first = encodeToBuffer(v);
    T again{};
    try {
        again = decodeFromBuffer<T>(first.data(), first.size(), true, limits());
    } catch (const DecodeError& e) {
        pnp::fuzz::fail("a re-encoded value does not decode", e.what());
    }
    const Buffer second = encodeToBuffer(again);
    check(first == second, "encoding is not stable");
    if (!hasNaNOf(v)) check(v == again, "decode(encode(v)) != v");
    if constexpr (std::is_same_v<T, Variant>) (void)v.toString();
}

void structure(const Byte* p, std::size_t n) {
    if (n < 2) return;
    auto codecs = allDataTypeCodecs();
    const auto& codec = codecs[(p[0] | (std::size_t{p[1]} << 8)) % codecs.size()];
    p += 2;
    n -= 2;
    Buffer first;
    try {
        BinaryDecoder d(p, n, limits());
        BinaryEncoder e(first);
        codec.reencode(d, e);
    } catch (const DecodeError&) {
        return;
    }
    Buffer second;
    try {
        BinaryDecoder d(first.data(), first.size(), limits());
        BinaryEncoder e(second);
        codec.reencode(d, e);
        check(d.remaining() == 0, "re-encoded structure has trailing bytes",
              std::string(codec.name));
        BinaryDecoder j(first.data(), first.size(), limits());
        (void)codec.toJson(j);
    } catch (const DecodeError& e) {
        pnp::fuzz::fail("a re-encoded structure does not decode",
                        std::string(codec.name) + ": " + e.what());
    }
    check(first == second, "structure encoding is not stable", std::string(codec.name));
}

void extensionObject(const Byte* p, std::size_t n) {
    roundTrip<ExtensionObject>(p, n);
    ExtensionObject x;
    try {
        x = decodeFromBuffer<ExtensionObject>(p, n, false, limits());
    } catch (const DecodeError&) {
        return;
    }
    (void)toJson(x);
    std::optional<ExtensionObject> once;
    try {
        once = reencodeExtensionObject(x, limits());
    } catch (const DecodeError&) {
        return;
    }
    if (!once) return;
    try {
        auto twice = reencodeExtensionObject(*once, limits());
        check(twice.has_value() && *twice == *once, "ExtensionObject re-encoding is not stable");
    } catch (const DecodeError& e) {
        pnp::fuzz::fail("a re-encoded ExtensionObject does not decode", e.what());
    }
}

// ---- seeds -------------------------------------------------------------------------------
void makeSeeds(pnp::fuzz::SeedWriter& w) {
    using pnp::fuzz::encoded;
    std::vector<std::pair<std::string, Variant>> variants = {
        {"null", Variant()},
        {"boolean", Variant(true)},
        {"sbyte", Variant(SByte{-3})},
        {"byte", Variant(Byte{200})},
        {"int16", Variant(Int16{-300})},
        {"uint16", Variant(UInt16{60000})},
        {"int32", Variant(Int32{-70000})},
        {"uint32", Variant(UInt32{4000000000u})},
        {"int64", Variant(Int64{-1})},
        {"uint64", Variant(UInt64{1} << 63)},
        {"float", Variant(Float{1.5f})},
        {"double", Variant(Double{-2.25})},
        {"string", Variant(String("hello"))},
        {"datetime", Variant(DateTime{133'000'000'000'000'000LL})},
        {"guid", Variant(Guid{1, 2, 3, {4, 5, 6, 7, 8, 9, 10, 11}})},
        {"bytestring", Variant(ByteString(std::string("\x00\x01\xff", 3)))},
        {"xml", Variant(XmlElement{"<a/>"})},
        {"nodeid-string", Variant(NodeId(3, "node"))},
        {"nodeid-guid", Variant(NodeId(1, Guid{9, 8, 7, {}}))},
        {"nodeid-opaque", Variant(NodeId(1, ByteString(std::string("op"))))},
        {"nodeid-numeric", Variant(NodeId(300, 70000))},
        {"expandednodeid", Variant(ExpandedNodeId(NodeId(0, 85), "urn:x", 2))},
        {"statuscode", Variant(StatusCode(status::BadNodeIdUnknown))},
        {"qualifiedname", Variant(QualifiedName{2, "name"})},
        {"localizedtext", Variant(LocalizedText("en", "text"))},
        {"array-int32", Variant(std::vector<Int32>{1, 2, 3})},
        {"array-string", Variant(std::vector<String>{"a", "", "c"})},
        {"array-boolean", Variant(std::vector<Boolean>{true, false})},
        {"array-variant",
         Variant(std::vector<Variant>{Variant(Int32{1}), Variant(std::vector<Byte>{1, 2})})},
        {"array-localizedtext", Variant(std::vector<LocalizedText>{LocalizedText("", "x")})},
    };
    Range range;
    range.low = -1;
    range.high = 1;
    variants.emplace_back("extensionobject", Variant(toExtensionObject(range)));
    DataValue dv(Variant(Double{4}));
    dv.status = StatusCode(status::BadOutOfRange);
    dv.sourceTimestamp = DateTime{133'000'000'000'000'000LL};
    dv.sourcePicoseconds = 10;
    dv.serverTimestamp = DateTime{133'000'000'000'000'001LL};
    dv.serverPicoseconds = 20;
    variants.emplace_back("datavalue", Variant(dv));
    DiagnosticInfo inner;
    inner.symbolicId = 1;
    inner.additionalInfo = "inner";
    DiagnosticInfo di;
    di.symbolicId = 2;
    di.namespaceUri = 3;
    di.localizedText = 4;
    di.locale = 5;
    di.additionalInfo = "outer";
    di.innerStatusCode = StatusCode(status::BadInternalError);
    di.innerDiagnosticInfo = std::make_shared<DiagnosticInfo>(inner);
    variants.emplace_back("diagnosticinfo", Variant(di));
    {
        Variant matrix(std::vector<Double>{1, 2, 3, 4, 5, 6});
        matrix.setArrayDimensions({3, 2});
        variants.emplace_back("matrix", matrix);
    }
    {
        Variant nested(Int32{0});
        for (int i = 0; i < 8; ++i) nested = Variant(std::vector<Variant>{nested});
        variants.emplace_back("nested", nested);
    }
    for (const auto& [name, v] : variants) w.add("variant-" + name, kVariant, encoded(v));
    w.add("datavalue", kDataValue, encoded(dv));
    w.add("diagnosticinfo", kDiagnosticInfo, encoded(di));
    w.add("extensionobject-range", kExtensionObject, encoded(toExtensionObject(range)));
    BuildInfo build;
    build.productUri = "urn:pnp";
    build.softwareVersion = "1";
    w.add("extensionobject-buildinfo", kExtensionObject, encoded(toExtensionObject(build)));
    ExtensionObject xml;
    xml.typeId = NodeId(0, 885);
    xml.encoding = ExtensionObject::Encoding::Xml;
    xml.body = "<Range/>";
    w.add("extensionobject-xml", kExtensionObject, encoded(xml));
    // Every ns0 structure: the value that an all-zero body decodes to.
    const std::vector<Byte> zeros(512, 0);
    auto codecs = allDataTypeCodecs();
    for (std::size_t i = 0; i < codecs.size(); ++i) {
        Buffer body;
        try {
            BinaryDecoder d(zeros.data(), zeros.size());
            BinaryEncoder e(body);
            codecs[i].reencode(d, e);
        } catch (const DecodeError&) {
            continue;
        }
        Buffer b{static_cast<Byte>(i & 0xFF), static_cast<Byte>(i >> 8)};
        b.insert(b.end(), body.begin(), body.end());
        w.add("structure-" + std::string(codecs[i].name), kStructure, b);
    }
    w.add("nodeid", kNodeIds, encoded(NodeId(2, "x")));
    Buffer mixed = encoded(ExpandedNodeId(NodeId(1, 5), "urn:y", 0));
    append(mixed, encoded(QualifiedName{1, "q"}));
    append(mixed, encoded(LocalizedText("de", "t")));
    w.add("nodeids", kNodeIds, mixed);
}

void nodeIds(const Byte* p, std::size_t n) {
    // The same bytes as each of the types, and as the sequence NodeId, ExpandedNodeId, ...
    roundTrip<NodeId>(p, n);
    roundTrip<ExpandedNodeId>(p, n);
    roundTrip<QualifiedName>(p, n);
    roundTrip<LocalizedText>(p, n);
    roundTrip<Guid>(p, n);
    roundTrip<std::vector<String>>(p, n);
    roundTrip<std::vector<DataValue>>(p, n);
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int* argc, char*** argv) {
    pnp::fuzz::handleSeedFlag(argc, argv, makeSeeds);
    return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    if (size < 1) return 0;
    const Byte* p = data + 1;
    const std::size_t n = size - 1;
    switch (data[0] % kModeCount) {
        case kVariant:
            roundTrip<Variant>(p, n);
            break;
        case kDataValue:
            roundTrip<DataValue>(p, n);
            break;
        case kDiagnosticInfo:
            roundTrip<DiagnosticInfo>(p, n);
            break;
        case kExtensionObject:
            extensionObject(p, n);
            break;
        case kStructure:
            structure(p, n);
            break;
        case kNodeIds:
            nodeIds(p, n);
            break;
    }
    return 0;
}
