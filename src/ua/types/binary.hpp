// OPC UA Binary encoding (OPC 10000-6 §5.2) of the built-in types.
// Every type T has the overloads   encode(BinaryEncoder&, const T&)
//                                  decode(BinaryDecoder&, T&)
// so generic code (arrays, generated structures) composes them. Decoding is bounds-checked:
// any length, count or nesting depth beyond DecodeLimits, or beyond the bytes actually
// present, throws DecodeError carrying BadDecodingError / BadEncodingLimitsExceeded.
#pragma once

#include <algorithm>
#include <bit>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

#include "ua/types/buffer.hpp"
#include "ua/types/builtin.hpp"

namespace pnp::ua {

static_assert(std::endian::native == std::endian::little,
              "the binary codec copies numbers as they are in memory");

struct DecodeLimits {
    std::size_t maxStringLength = 16u << 20;  // bytes of one String / ByteString / XmlElement
    std::size_t maxArrayLength = 1u << 20;    // elements of one array
    int maxDepth = 32;                        // nested Variant / DataValue / DiagnosticInfo
};

class DecodeError : public std::runtime_error {
  public:
    DecodeError(StatusCode s, const std::string& what) : std::runtime_error(what), status_(s) {}
    StatusCode status() const { return status_; }

  private:
    StatusCode status_;
};

static_assert(std::is_same_v<Buffer::value_type, Byte>);

// Bytes an encoder referenced instead of copying them (see BinaryEncoder): they belong at
// position `at` of the encoded Buffer, before the byte that is there. Whoever sends the
// Buffer writes them from where they are (scatter-gather), or joins them in (joinSplices).
struct Splice {
    std::size_t at;
    const Byte* data;
    std::size_t size;
};
using Splices = std::vector<Splice>;
// Length-prefixed runs at least this long are worth referencing: below it a copy into the
// buffer costs less than a splice (sendmsg() over several pieces, the keep-alive of the
// message). Measured with bench/run.sh: Call Echo of 4 and 8 KiB 0.01 faster copied, 16 KiB
// even, 32 KiB 0.03 faster spliced (ratios to raw TCP).
inline constexpr std::size_t kDefaultSpliceMin = 16384;
// ByteStrings at least this long are decoded as references into the receive buffer when the
// decoder is given one (BinaryDecoder::shareFrom): the copy they save is the one the splice
// saves on the way out.
inline constexpr std::size_t kDefaultShareMin = 16384;
std::size_t splicedSize(const Splices& s);
// The Buffer with the spliced bytes copied in at their places.
Buffer joinSplices(Buffer&& b, const Splices& s);

class BinaryEncoder {
  public:
    explicit BinaryEncoder(Buffer& out) : out_(out) {}
    // Length-prefixed byte runs (String, ByteString, XmlElement, ExtensionObject bodies) of at
    // least minSize bytes are appended to *splices instead of copied: the referenced bytes
    // must stay where they are, unchanged, until the Buffer has been sent.
    BinaryEncoder(Buffer& out, Splices* splices, std::size_t minSize = kDefaultSpliceMin)
        : out_(out), splices_(splices), spliceMin_(minSize) {}

    void raw(const void* p, std::size_t n) {
        if (n == 0) return;
        if (out_.capacity() - out_.size() < n) reserveFor(n);
        std::memcpy(out_.append(n), p, n);
    }
    template <class T>
    void number(T v) {
        static_assert(std::is_arithmetic_v<T>);
        std::memcpy(out_.append(sizeof(T)), &v, sizeof(T));
    }
    void byte(Byte b) { out_.push_back(b); }
    // Length-prefixed bytes (String, ByteString, XmlElement).
    void lengthPrefixed(const Byte* p, std::size_t n) {
        number<Int32>(static_cast<Int32>(n));
        if (splices_ != nullptr && n >= spliceMin_) {
            splices_->push_back({out_.size(), p, n});
            return;
        }
        raw(p, n);
    }
    void lengthPrefixed(std::string_view s) {
        lengthPrefixed(reinterpret_cast<const Byte*>(s.data()), s.size());
    }
    Buffer& buffer() { return out_; }
    std::size_t size() const { return out_.size(); }

  private:
    // Room for n more bytes and what usually follows a large field (the rest of the
    // message), so a big ByteString is not copied again by the next small write.
    void reserveFor(std::size_t n) {
        out_.reserve(std::max(out_.capacity() * 2, out_.size() + n + 1024));
    }
    Buffer& out_;
    Splices* splices_ = nullptr;
    std::size_t spliceMin_ = kDefaultSpliceMin;
};

class BinaryDecoder {
  public:
    BinaryDecoder(const Byte* data, std::size_t size, const DecodeLimits& limits = {})
        : p_(data), end_(data + size), limits_(limits) {}

    std::size_t remaining() const { return static_cast<std::size_t>(end_ - p_); }
    const Byte* position() const { return p_; }
    const DecodeLimits& limits() const { return limits_; }

    void raw(void* out, std::size_t n) {
        need(n);
        if (n == 0) return;  // out is null for an empty array: memcpy(nullptr, ..., 0) is UB
        std::memcpy(out, p_, n);
        p_ += n;
    }
    void skip(std::size_t n) {
        need(n);
        p_ += n;
    }
    template <class T>
    T number() {
        static_assert(std::is_arithmetic_v<T>);
        T v;
        raw(&v, sizeof(T));
        return v;
    }
    Byte byte() {
        need(1);
        return *p_++;
    }
    // Reads a String-like length; -1 (null) reads as 0.
    std::size_t stringLength();
    void lengthPrefixed(std::string& s) {
        std::size_t n = stringLength();
        s.assign(reinterpret_cast<const char*>(p_), n);
        p_ += n;
    }
    // A ByteString: shared with the block set by shareFrom() when it is at least the block's
    // minimum size and mayShare, else copied.
    void byteString(ByteString& v, bool mayShare = true) {
        std::size_t n = stringLength();
        if (mayShare && share_ != nullptr && n >= shareMin_) {
            v = ByteString::shared(share_, p_, n);
        } else {
            v.assign(p_, n);
        }
        p_ += n;
    }
    // The bytes being decoded lie in `block` (a receive buffer): ByteStrings of at least
    // minSize bytes become references into it (ByteString::shared) instead of copies. Each
    // keeps the whole block alive, so by default minSize is kDefaultShareMin or a fifth of
    // the block, whichever is larger: a kept value holds at most five times its size.
    void shareFrom(ByteBlock* block) {
        shareFrom(block, std::max(kDefaultShareMin, block->capacity() / 5));
    }
    void shareFrom(ByteBlock* block, std::size_t minSize) {
        share_ = block;
        shareMin_ = minSize;
    }
    // Reads an array length; -1 (null) reads as 0. Each element takes at least
    // minElementSize bytes, so a count the remaining bytes cannot hold is rejected
    // before anything is allocated.
    std::size_t arrayLength(std::size_t minElementSize);

    // RAII guard for recursion through Variant / DataValue / DiagnosticInfo.
    class Nested {
      public:
        explicit Nested(BinaryDecoder& d);
        ~Nested() { --d_.depth_; }
        Nested(const Nested&) = delete;
        Nested& operator=(const Nested&) = delete;

      private:
        BinaryDecoder& d_;
    };

    [[noreturn]] static void fail(const std::string& what);
    [[noreturn]] static void limit(const std::string& what);

  private:
    void need(std::size_t n) const {
        if (n > remaining()) fail("message truncated");
    }

    const Byte* p_;
    const Byte* end_;
    DecodeLimits limits_;
    int depth_ = 0;
    ByteBlock* share_ = nullptr;
    std::size_t shareMin_ = 0;
};

// ---- numbers -------------------------------------------------------------------------
#define PNP_UA_NUMBER_CODEC(T)                                    \
    inline void encode(BinaryEncoder& e, T v) { e.number<T>(v); } \
    inline void decode(BinaryDecoder& d, T& v) { v = d.number<T>(); }
PNP_UA_NUMBER_CODEC(SByte)
PNP_UA_NUMBER_CODEC(Byte)
PNP_UA_NUMBER_CODEC(Int16)
PNP_UA_NUMBER_CODEC(UInt16)
PNP_UA_NUMBER_CODEC(Int32)
PNP_UA_NUMBER_CODEC(UInt32)
PNP_UA_NUMBER_CODEC(Int64)
PNP_UA_NUMBER_CODEC(UInt64)
PNP_UA_NUMBER_CODEC(Float)
PNP_UA_NUMBER_CODEC(Double)
#undef PNP_UA_NUMBER_CODEC

inline void encode(BinaryEncoder& e, Boolean v) { e.byte(v ? 1 : 0); }
inline void decode(BinaryDecoder& d, Boolean& v) { v = d.byte() != 0; }
inline void encode(BinaryEncoder& e, const String& v) { e.lengthPrefixed(v); }
inline void decode(BinaryDecoder& d, String& v) { d.lengthPrefixed(v); }
inline void encode(BinaryEncoder& e, const DateTime& v) { e.number<Int64>(v.ticks); }
inline void decode(BinaryDecoder& d, DateTime& v) { v.ticks = d.number<Int64>(); }
inline void encode(BinaryEncoder& e, const ByteString& v) { e.lengthPrefixed(v.data(), v.size()); }
inline void decode(BinaryDecoder& d, ByteString& v) { d.byteString(v); }
inline void encode(BinaryEncoder& e, const XmlElement& v) { e.lengthPrefixed(v.xml); }
inline void decode(BinaryDecoder& d, XmlElement& v) { d.lengthPrefixed(v.xml); }
inline void encode(BinaryEncoder& e, StatusCode v) { e.number<UInt32>(v.value); }
inline void decode(BinaryDecoder& d, StatusCode& v) { v.value = d.number<UInt32>(); }

void encode(BinaryEncoder& e, const Guid& v);
void decode(BinaryDecoder& d, Guid& v);
void encode(BinaryEncoder& e, const NodeId& v);
void decode(BinaryDecoder& d, NodeId& v);
void encode(BinaryEncoder& e, const ExpandedNodeId& v);
void decode(BinaryDecoder& d, ExpandedNodeId& v);
void encode(BinaryEncoder& e, const QualifiedName& v);
void decode(BinaryDecoder& d, QualifiedName& v);
void encode(BinaryEncoder& e, const LocalizedText& v);
void decode(BinaryDecoder& d, LocalizedText& v);
void encode(BinaryEncoder& e, const ExtensionObject& v);
void decode(BinaryDecoder& d, ExtensionObject& v);
void encode(BinaryEncoder& e, const DiagnosticInfo& v);
void decode(BinaryDecoder& d, DiagnosticInfo& v);
void encode(BinaryEncoder& e, const Variant& v);
void decode(BinaryDecoder& d, Variant& v);
void encode(BinaryEncoder& e, const DataValue& v);
void decode(BinaryDecoder& d, DataValue& v);

// Smallest encoded size of one element, used to reject impossible array counts early.
template <class T>
constexpr std::size_t minEncodedSize() {
    if constexpr (std::is_arithmetic_v<T>)
        return sizeof(T);
    else if constexpr (std::is_same_v<T, Guid>)
        return 16;
    else if constexpr (std::is_same_v<T, DateTime> || std::is_same_v<T, StatusCode>)
        return sizeof(T);
    else if constexpr (std::is_same_v<T, String> || std::is_same_v<T, ByteString> ||
                       std::is_same_v<T, XmlElement>)
        return 4;
    else
        return 1;
}

// ---- arrays --------------------------------------------------------------------------
template <class T>
void encode(BinaryEncoder& e, const std::vector<T>& v) {
    e.number<Int32>(static_cast<Int32>(v.size()));
    if constexpr (std::is_arithmetic_v<T> && !std::is_same_v<T, bool>) {
        e.raw(v.data(), v.size() * sizeof(T));
    } else {
        for (const auto& x : v) encode(e, x);
    }
}

template <class T>
void decode(BinaryDecoder& d, std::vector<T>& v) {
    std::size_t n = d.arrayLength(minEncodedSize<T>());
    if constexpr (std::is_arithmetic_v<T> && !std::is_same_v<T, bool>) {
        v.resize(n);
        d.raw(v.data(), n * sizeof(T));
    } else if constexpr (std::is_same_v<T, bool>) {
        v.resize(n);
        for (std::size_t i = 0; i < n; ++i) v[i] = d.byte() != 0;
    } else {
        // Appended as they are decoded: the count is only checked against the bytes left,
        // and nested arrays (Variant arrays of Variant arrays ...) all check it against the
        // same bytes, so sizing every level up front multiplied memory with the depth.
        v.clear();
        v.reserve(n < 1024 ? n : 1024);
        for (std::size_t i = 0; i < n; ++i) decode(d, v.emplace_back());
    }
}

// ---- optional fields (structures with optional fields, Part 6 §5.2.7) ------------------
template <class T>
void encode(BinaryEncoder& e, const std::optional<T>& v) {
    if (v) encode(e, *v);
}

// Encodes a value into a fresh buffer / decodes a whole buffer (must be consumed exactly
// when `exact` is set).
template <class T>
Buffer encodeToBuffer(const T& v) {
    Buffer b;
    BinaryEncoder e(b);
    encode(e, v);
    return b;
}
template <class T>
T decodeFromBuffer(const Byte* p, std::size_t n, bool exact = true,
                   const DecodeLimits& limits = {}) {
    BinaryDecoder d(p, n, limits);
    T v{};
    decode(d, v);
    if (exact && d.remaining() != 0) BinaryDecoder::fail("trailing bytes after value");
    return v;
}

}  // namespace pnp::ua
