#include "ua/types/binary.hpp"

#include <string>

#include "ua/types/status_codes.hpp"

namespace pnp::ua {

void BinaryDecoder::fail(const std::string& what) {
    throw DecodeError(status::BadDecodingError, what);
}

void BinaryDecoder::limit(const std::string& what) {
    throw DecodeError(status::BadEncodingLimitsExceeded, what);
}

std::size_t BinaryDecoder::stringLength() {
    Int32 n = number<Int32>();
    if (n < 0) {
        if (n != -1) fail("negative string length " + std::to_string(n));
        return 0;
    }
    auto len = static_cast<std::size_t>(n);
    if (len > limits_.maxStringLength) limit("string of " + std::to_string(len) + " bytes");
    need(len);
    return len;
}

std::size_t BinaryDecoder::arrayLength(std::size_t minElementSize) {
    Int32 n = number<Int32>();
    if (n < 0) {
        if (n != -1) fail("negative array length " + std::to_string(n));
        return 0;
    }
    auto len = static_cast<std::size_t>(n);
    if (len > limits_.maxArrayLength) limit("array of " + std::to_string(len) + " elements");
    if (len * minElementSize > remaining())
        fail("array of " + std::to_string(len) + " elements exceeds the message");
    return len;
}

BinaryDecoder::Nested::Nested(BinaryDecoder& d) : d_(d) {
    if (++d_.depth_ > d_.limits_.maxDepth) {
        --d_.depth_;
        limit("nesting deeper than " + std::to_string(d_.limits_.maxDepth));
    }
}

// ---- Guid ----------------------------------------------------------------------------
void encode(BinaryEncoder& e, const Guid& v) {
    e.number(v.data1);
    e.number(v.data2);
    e.number(v.data3);
    e.raw(v.data4.data(), 8);
}
void decode(BinaryDecoder& d, Guid& v) {
    v.data1 = d.number<UInt32>();
    v.data2 = d.number<UInt16>();
    v.data3 = d.number<UInt16>();
    d.raw(v.data4.data(), 8);
}

// ---- NodeId (Part 6 §5.2.2.9) ---------------------------------------------------------
namespace {
enum : Byte {
    kTwoByte = 0,
    kFourByte = 1,
    kNumeric = 2,
    kString = 3,
    kGuid = 4,
    kByteString = 5,
    kFlagServerIndex = 0x40,
    kFlagNamespaceUri = 0x80,
};

void encodeNodeId(BinaryEncoder& e, const NodeId& v, Byte flags) {
    switch (v.idType()) {
        case IdType::Numeric: {
            UInt32 id = v.numeric();
            UInt16 ns = v.namespaceIndex();
            if (ns == 0 && id <= 0xFF) {
                e.byte(kTwoByte | flags);
                e.byte(static_cast<Byte>(id));
            } else if (ns <= 0xFF && id <= 0xFFFF) {
                e.byte(kFourByte | flags);
                e.byte(static_cast<Byte>(ns));
                e.number(static_cast<UInt16>(id));
            } else {
                e.byte(kNumeric | flags);
                e.number(ns);
                e.number(id);
            }
            return;
        }
        case IdType::String:
            e.byte(kString | flags);
            e.number(v.namespaceIndex());
            e.lengthPrefixed(v.string());
            return;
        case IdType::Guid:
            e.byte(kGuid | flags);
            e.number(v.namespaceIndex());
            encode(e, v.guid());
            return;
        case IdType::Opaque:
            e.byte(kByteString | flags);
            e.number(v.namespaceIndex());
            e.lengthPrefixed(v.opaque().data(), v.opaque().size());
            return;
    }
}

Byte decodeNodeId(BinaryDecoder& d, NodeId& v) {
    Byte b = d.byte();
    switch (b & 0x3F) {
        case kTwoByte:
            v = NodeId(0, UInt32{d.byte()});
            break;
        case kFourByte: {
            UInt16 ns = d.byte();
            v = NodeId(ns, UInt32{d.number<UInt16>()});
            break;
        }
        case kNumeric: {
            UInt16 ns = d.number<UInt16>();
            v = NodeId(ns, d.number<UInt32>());
            break;
        }
        case kString: {
            UInt16 ns = d.number<UInt16>();
            d.lengthPrefixed(v.setString(ns));
            break;
        }
        case kGuid: {
            UInt16 ns = d.number<UInt16>();
            Guid g;
            decode(d, g);
            v = NodeId(ns, g);
            break;
        }
        case kByteString: {
            UInt16 ns = d.number<UInt16>();
            d.byteString(v.setOpaque(ns), false);  // NodeIds are kept: never share
            break;
        }
        default:
            BinaryDecoder::fail("invalid NodeId encoding byte " + std::to_string(b));
    }
    return b & 0xC0;
}
}  // namespace

void encode(BinaryEncoder& e, const NodeId& v) { encodeNodeId(e, v, 0); }
void decode(BinaryDecoder& d, NodeId& v) {
    if (decodeNodeId(d, v) != 0) BinaryDecoder::fail("NodeId with ExpandedNodeId flags");
}

void encode(BinaryEncoder& e, const ExpandedNodeId& v) {
    Byte flags = (v.namespaceUri.empty() ? 0 : kFlagNamespaceUri) |
                 (v.serverIndex == 0 ? 0 : kFlagServerIndex);
    encodeNodeId(e, v.nodeId, flags);
    if (!v.namespaceUri.empty()) e.lengthPrefixed(v.namespaceUri);
    if (v.serverIndex != 0) e.number(v.serverIndex);
}
void decode(BinaryDecoder& d, ExpandedNodeId& v) {
    Byte flags = decodeNodeId(d, v.nodeId);
    v.namespaceUri.clear();
    v.serverIndex = 0;
    if (flags & kFlagNamespaceUri) d.lengthPrefixed(v.namespaceUri);
    if (flags & kFlagServerIndex) v.serverIndex = d.number<UInt32>();
}

// ---- QualifiedName, LocalizedText -------------------------------------------------------
void encode(BinaryEncoder& e, const QualifiedName& v) {
    e.number(v.namespaceIndex);
    e.lengthPrefixed(v.name);
}
void decode(BinaryDecoder& d, QualifiedName& v) {
    v.namespaceIndex = d.number<UInt16>();
    d.lengthPrefixed(v.name);
}

void encode(BinaryEncoder& e, const LocalizedText& v) {
    Byte mask = (v.locale.empty() ? 0 : 0x01) | (v.text.empty() ? 0 : 0x02);
    e.byte(mask);
    if (mask & 0x01) e.lengthPrefixed(v.locale);
    if (mask & 0x02) e.lengthPrefixed(v.text);
}
void decode(BinaryDecoder& d, LocalizedText& v) {
    Byte mask = d.byte();
    v.locale.clear();
    v.text.clear();
    if (mask & 0x01) d.lengthPrefixed(v.locale);
    if (mask & 0x02) d.lengthPrefixed(v.text);
}

// ---- ExtensionObject (Part 6 §5.2.2.15) -----------------------------------------------------
void encode(BinaryEncoder& e, const ExtensionObject& v) {
    encode(e, v.typeId);
    e.byte(static_cast<Byte>(v.encoding));
    if (v.encoding != ExtensionObject::Encoding::None) e.lengthPrefixed(v.body);
}
void decode(BinaryDecoder& d, ExtensionObject& v) {
    decode(d, v.typeId);
    Byte enc = d.byte();
    if (enc > 2) BinaryDecoder::fail("invalid ExtensionObject encoding " + std::to_string(enc));
    v.encoding = static_cast<ExtensionObject::Encoding>(enc);
    v.body.clear();
    if (enc != 0) d.lengthPrefixed(v.body);
}

// ---- DiagnosticInfo (Part 6 §5.2.2.12) -------------------------------------------------------
void encode(BinaryEncoder& e, const DiagnosticInfo& v) {
    Byte mask = (v.symbolicId ? 0x01 : 0) | (v.namespaceUri ? 0x02 : 0) |
                (v.localizedText ? 0x04 : 0) | (v.locale ? 0x08 : 0) |
                (v.additionalInfo ? 0x10 : 0) | (v.innerStatusCode ? 0x20 : 0) |
                (v.innerDiagnosticInfo ? 0x40 : 0);
    e.byte(mask);
    if (v.symbolicId) e.number(*v.symbolicId);
    if (v.namespaceUri) e.number(*v.namespaceUri);
    if (v.locale) e.number(*v.locale);
    if (v.localizedText) e.number(*v.localizedText);
    if (v.additionalInfo) e.lengthPrefixed(*v.additionalInfo);
    if (v.innerStatusCode) e.number(v.innerStatusCode->value);
    if (v.innerDiagnosticInfo) encode(e, *v.innerDiagnosticInfo);
}
void decode(BinaryDecoder& d, DiagnosticInfo& v) {
    BinaryDecoder::Nested guard(d);
    v = DiagnosticInfo{};
    Byte mask = d.byte();
    if (mask & 0x01) v.symbolicId = d.number<Int32>();
    if (mask & 0x02) v.namespaceUri = d.number<Int32>();
    if (mask & 0x08) v.locale = d.number<Int32>();
    if (mask & 0x04) v.localizedText = d.number<Int32>();
    if (mask & 0x10) {
        v.additionalInfo.emplace();
        d.lengthPrefixed(*v.additionalInfo);
    }
    if (mask & 0x20) v.innerStatusCode = StatusCode{d.number<UInt32>()};
    if (mask & 0x40) {
        auto inner = std::make_shared<DiagnosticInfo>();
        decode(d, *inner);
        v.innerDiagnosticInfo = std::move(inner);
    }
}

// ---- Variant (Part 6 §5.2.2.16) ----------------------------------------------------------
namespace {
constexpr Byte kArrayFlag = 0x80;
constexpr Byte kDimensionsFlag = 0x40;

template <class T>
void encodeScalar(BinaryEncoder& e, const T& v) {
    encode(e, v);
}
template <class T>
void encodeScalar(BinaryEncoder& e, const Box<T>& v) {
    encode(e, *v);
}

template <std::size_t I = 1>
void decodeStorage(BinaryDecoder& d, detail::VariantStorage& s, std::size_t index) {
    if constexpr (I < std::variant_size_v<detail::VariantStorage>) {
        if (index != I) return decodeStorage<I + 1>(d, s, index);
        using Alt = std::variant_alternative_t<I, detail::VariantStorage>;
        if constexpr (std::is_same_v<Alt, detail::NoScalarVariant>) {
            BinaryDecoder::fail("scalar Variant inside a Variant");
        } else if constexpr (std::is_same_v<Alt, Box<DataValue>>) {
            auto& b = s.template emplace<I>();
            decode(d, *b);
        } else if constexpr (std::is_same_v<Alt, Box<DiagnosticInfo>>) {
            auto& b = s.template emplace<I>();
            decode(d, *b);
        } else {
            decode(d, s.template emplace<I>());
        }
    }
}
}  // namespace

void encode(BinaryEncoder& e, const Variant& v) {
    const auto& s = v.storage();
    if (v.isEmpty()) {
        e.byte(0);
        return;
    }
    Byte mask = static_cast<Byte>(v.type());
    if (v.isArray()) {
        mask |= kArrayFlag;
        if (!v.arrayDimensions().empty()) mask |= kDimensionsFlag;
    }
    e.byte(mask);
    std::visit(
        [&](const auto& x) {
            using X = std::decay_t<decltype(x)>;
            if constexpr (std::is_same_v<X, std::monostate> ||
                          std::is_same_v<X, detail::NoScalarVariant>) {
            } else {
                encodeScalar(e, x);
            }
        },
        s);
    if (mask & kDimensionsFlag) encode(e, v.arrayDimensions());
}

void decode(BinaryDecoder& d, Variant& v) {
    BinaryDecoder::Nested guard(d);
    v = Variant{};
    Byte mask = d.byte();
    Byte type = mask & 0x3F;
    if (type == 0) {
        if (mask != 0) BinaryDecoder::fail("null Variant with array flags");
        return;
    }
    if (type >= kBuiltinTypeCount)
        BinaryDecoder::fail("Variant of unknown built-in type " + std::to_string(type));
    bool isArray = (mask & kArrayFlag) != 0;
    if (!isArray && (mask & kDimensionsFlag))
        BinaryDecoder::fail("Variant with dimensions but no array");
    std::size_t index = isArray ? type + (kBuiltinTypeCount - 1) : type;
    decodeStorage(d, v.storage(), index);
    if (mask & kDimensionsFlag) {
        std::vector<Int32> dims;
        decode(d, dims);
        std::size_t product = 1;
        for (Int32 n : dims) {
            if (n < 0) BinaryDecoder::fail("negative array dimension");
            product *= static_cast<std::size_t>(n);
            if (product > d.limits().maxArrayLength) BinaryDecoder::limit("matrix too large");
        }
        if (dims.empty() || product != v.arrayLength())
            BinaryDecoder::fail("array dimensions do not match the array length");
        v.setArrayDimensions(std::move(dims));
    }
}

// ---- DataValue (Part 6 §5.2.2.17) -----------------------------------------------------------
void encode(BinaryEncoder& e, const DataValue& v) {
    Byte mask = (v.value ? 0x01 : 0) | (v.status ? 0x02 : 0) | (v.sourceTimestamp ? 0x04 : 0) |
                (v.serverTimestamp ? 0x08 : 0) | (v.sourcePicoseconds ? 0x10 : 0) |
                (v.serverPicoseconds ? 0x20 : 0);
    e.byte(mask);
    if (v.value) encode(e, *v.value);
    if (v.status) e.number(v.status->value);
    if (v.sourceTimestamp) e.number(v.sourceTimestamp->ticks);
    if (v.sourcePicoseconds) e.number(*v.sourcePicoseconds);
    if (v.serverTimestamp) e.number(v.serverTimestamp->ticks);
    if (v.serverPicoseconds) e.number(*v.serverPicoseconds);
}

void decode(BinaryDecoder& d, DataValue& v) {
    BinaryDecoder::Nested guard(d);
    v = DataValue{};
    Byte mask = d.byte();
    if (mask & 0x01) decode(d, v.value.emplace());
    if (mask & 0x02) v.status = StatusCode{d.number<UInt32>()};
    if (mask & 0x04) v.sourceTimestamp = DateTime{d.number<Int64>()};
    if (mask & 0x10) v.sourcePicoseconds = d.number<UInt16>();
    if (mask & 0x08) v.serverTimestamp = DateTime{d.number<Int64>()};
    if (mask & 0x20) v.serverPicoseconds = d.number<UInt16>();
}

// ---- splices ------------------------------------------------------------------------------
std::size_t splicedSize(const Splices& s) {
    std::size_t n = 0;
    for (const Splice& x : s) n += x.size;
    return n;
}

Buffer joinSplices(Buffer&& b, const Splices& s) {
    if (s.empty()) return std::move(b);
    Buffer out;
    out.resize(b.size() + splicedSize(s));
    std::size_t from = 0;
    Byte* to = out.data();
    for (const Splice& x : s) {
        std::memcpy(to, b.data() + from, x.at - from);
        to += x.at - from;
        from = x.at;
        std::memcpy(to, x.data, x.size);
        to += x.size;
    }
    std::memcpy(to, b.data() + from, b.size() - from);
    return out;
}

}  // namespace pnp::ua
