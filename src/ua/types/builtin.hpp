// OPC UA built-in data types (OPC 10000-6 §5.1, §5.2) as value types.
// Everything here has value semantics: copyable, comparable, no manual memory management.
#pragma once

#include <array>
#include <compare>
#include <cstdint>
#include <cstring>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <variant>
#include <vector>

#include "ua/types/byte_block.hpp"
#include "ua/types/status_code.hpp"

namespace pnp::ua {

using Boolean = bool;
using SByte = std::int8_t;
using Byte = std::uint8_t;
using Int16 = std::int16_t;
using UInt16 = std::uint16_t;
using Int32 = std::int32_t;
using UInt32 = std::uint32_t;
using Int64 = std::int64_t;
using UInt64 = std::uint64_t;
using Float = float;
using Double = double;
// A null String and an empty String both map to "" (decoders accept both encodings).
using String = std::string;

// Built-in type ids as on the wire (Part 6 Table 1).
enum class BuiltinType : std::uint8_t {
    Null = 0,
    Boolean = 1,
    SByte = 2,
    Byte = 3,
    Int16 = 4,
    UInt16 = 5,
    Int32 = 6,
    UInt32 = 7,
    Int64 = 8,
    UInt64 = 9,
    Float = 10,
    Double = 11,
    String = 12,
    DateTime = 13,
    Guid = 14,
    ByteString = 15,
    XmlElement = 16,
    NodeId = 17,
    ExpandedNodeId = 18,
    StatusCode = 19,
    QualifiedName = 20,
    LocalizedText = 21,
    ExtensionObject = 22,
    DataValue = 23,
    Variant = 24,
    DiagnosticInfo = 25,
};
inline constexpr int kBuiltinTypeCount = 26;
std::string_view toString(BuiltinType t);
std::optional<BuiltinType> builtinTypeFromName(std::string_view name);

// 100 ns intervals since 1601-01-01 UTC.
struct DateTime {
    Int64 ticks = 0;

    static constexpr Int64 kUnixEpochTicks = 116444736000000000LL;
    static DateTime now();
    // The wall clock at scheduler-tick resolution (a few ms): ~4 ns instead of ~50 ns for a
    // precise reading on a VM. For header timestamps, never for values' timestamps.
    static DateTime nowCoarse();
    static DateTime fromUnixNanos(Int64 ns) { return {kUnixEpochTicks + ns / 100}; }
    Int64 toUnixNanos() const { return (ticks - kUnixEpochTicks) * 100; }
    std::string toIso8601() const;
    static std::optional<DateTime> parseIso8601(std::string_view s);
    auto operator<=>(const DateTime&) const = default;
};

struct Guid {
    UInt32 data1 = 0;
    UInt16 data2 = 0;
    UInt16 data3 = 0;
    std::array<Byte, 8> data4{};

    std::string toString() const;  // "72962B91-FA75-4AE6-8D28-B404DC7DAF63"
    static std::optional<Guid> parse(std::string_view s);
    auto operator<=>(const Guid&) const = default;
};

// Distinct from String so that a Variant knows which one it holds.
// ByteString: immutable bytes with value semantics. Up to kInline bytes live in the object;
// longer ones in a reference-counted ByteBlock, so a copy is a reference count increment and
// a large ByteString decoded from a message can point into the receive buffer it arrived in
// (shared(); see BinaryDecoder::shareFrom) instead of being copied out of it.
class ByteString {
  public:
    static constexpr std::size_t kInline = 24;

    ByteString() noexcept : small_{}, size_(0), far_(false) {}
    // A copy of the bytes.
    explicit ByteString(std::string_view b)
        : ByteString(reinterpret_cast<const Byte*>(b.data()), b.size()) {}
    ByteString(const Byte* p, std::size_t n);
    // n bytes at p inside `block` (not copied; the ByteString keeps the block alive).
    static ByteString shared(ByteBlock* block, const Byte* p, std::size_t n) noexcept {
        ByteString s;
        block->ref();
        s.far_ = true;
        s.size_ = n;
        s.heap_.data = p;
        s.heap_.block = block;
        return s;
    }

    ByteString(const ByteString& o) noexcept : ByteString() { copyFrom(o); }
    ByteString(ByteString&& o) noexcept : ByteString() { takeFrom(o); }
    ByteString& operator=(const ByteString& o) noexcept {
        if (this != &o) {
            release();
            copyFrom(o);
        }
        return *this;
    }
    ByteString& operator=(ByteString&& o) noexcept {
        if (this != &o) {
            release();
            takeFrom(o);
        }
        return *this;
    }
    ~ByteString() { release(); }

    std::size_t size() const noexcept { return size_; }
    bool empty() const noexcept { return size_ == 0; }
    const Byte* data() const noexcept { return far_ ? heap_.data : small_; }
    const Byte* begin() const noexcept { return data(); }
    const Byte* end() const noexcept { return data() + size_; }
    std::string_view view() const noexcept {
        return {reinterpret_cast<const char*>(data()), size_};
    }
    std::string str() const { return std::string(view()); }
    // Replaces the value with a copy of n bytes at p. Reuses the block when this value is
    // its only holder and it is large enough (a decoder refilling the same request object).
    void assign(const Byte* p, std::size_t n);
    // True when the bytes are in a block another value or a receive buffer may share.
    bool isShared() const noexcept { return far_; }

    std::string toBase64() const;
    static std::optional<ByteString> fromBase64(std::string_view s);

    friend bool operator==(const ByteString& a, const ByteString& b) noexcept {
        return a.view() == b.view();
    }
    friend std::strong_ordering operator<=>(const ByteString& a, const ByteString& b) noexcept {
        return a.view() <=> b.view();
    }

  private:
    void release() noexcept {
        if (far_) heap_.block->unref();
        far_ = false;
        size_ = 0;
    }
    void copyFrom(const ByteString& o) noexcept {
        std::memcpy(static_cast<void*>(this), &o, sizeof *this);
        if (far_) heap_.block->ref();
    }
    void takeFrom(ByteString& o) noexcept {
        std::memcpy(static_cast<void*>(this), &o, sizeof *this);
        o.far_ = false;
        o.size_ = 0;
    }

    struct Heap {
        const Byte* data;
        ByteBlock* block;
    };
    union {
        Byte small_[kInline];
        Heap heap_;
    };
    UInt32 size_;  // a ByteString has at most Int32 max bytes (OPC 10000-6 §5.2.2.7)
    bool far_;
};
static_assert(sizeof(ByteString) == 32);

struct XmlElement {
    std::string xml;
    auto operator<=>(const XmlElement&) const = default;
};

enum class IdType : Byte { Numeric = 0, String = 1, Guid = 2, Opaque = 3 };

class NodeId {
  public:
    NodeId() = default;
    constexpr NodeId(UInt16 ns, UInt32 id) : ns_(ns), id_(id) {}
    NodeId(UInt16 ns, std::string s) : ns_(ns), id_(std::move(s)) {}
    NodeId(UInt16 ns, const char* s) : ns_(ns), id_(std::string(s)) {}
    NodeId(UInt16 ns, Guid g) : ns_(ns), id_(g) {}
    NodeId(UInt16 ns, ByteString b) : ns_(ns), id_(std::move(b)) {}

    UInt16 namespaceIndex() const { return ns_; }
    void setNamespaceIndex(UInt16 ns) { ns_ = ns; }
    // Makes this a String / Opaque NodeId and returns its identifier to fill in place (a
    // decoder reuses the storage instead of building a temporary).
    std::string& setString(UInt16 ns) {
        ns_ = ns;
        if (id_.index() != 1) id_.emplace<1>();
        return std::get<1>(id_);
    }
    ByteString& setOpaque(UInt16 ns) {
        ns_ = ns;
        if (id_.index() != 3) id_.emplace<3>();
        return std::get<3>(id_);
    }
    IdType idType() const { return static_cast<IdType>(id_.index()); }
    bool isNull() const;
    bool isNumeric() const { return id_.index() == 0; }
    UInt32 numeric() const { return std::get<0>(id_); }
    const std::string& string() const { return std::get<1>(id_); }
    const Guid& guid() const { return std::get<2>(id_); }
    const ByteString& opaque() const { return std::get<3>(id_); }

    // "ns=2;s=Demo", "i=85", "ns=1;g=...", "ns=1;b=base64" (Part 6 §5.3.1.10).
    std::string toString() const;
    static std::optional<NodeId> parse(std::string_view s);
    std::size_t hash() const;

    bool operator==(const NodeId&) const = default;
    auto operator<=>(const NodeId&) const = default;

  private:
    UInt16 ns_ = 0;
    std::variant<UInt32, std::string, Guid, ByteString> id_{UInt32{0}};
};

struct ExpandedNodeId {
    NodeId nodeId;
    std::string namespaceUri;  // empty: nodeId's namespace index applies
    UInt32 serverIndex = 0;

    ExpandedNodeId() = default;
    ExpandedNodeId(NodeId id) : nodeId(std::move(id)) {}  // NOLINT: implicit by design
    ExpandedNodeId(NodeId id, std::string uri, UInt32 server)
        : nodeId(std::move(id)), namespaceUri(std::move(uri)), serverIndex(server) {}
    bool isLocal() const { return namespaceUri.empty() && serverIndex == 0; }
    std::string toString() const;
    static std::optional<ExpandedNodeId> parse(std::string_view s);
    auto operator<=>(const ExpandedNodeId&) const = default;
};

struct QualifiedName {
    UInt16 namespaceIndex = 0;
    String name;
    std::string toString() const;  // "2:Name" or "Name"
    static QualifiedName parse(std::string_view s);
    auto operator<=>(const QualifiedName&) const = default;
};

struct LocalizedText {
    String locale;
    String text;
    LocalizedText() = default;
    LocalizedText(String loc, String txt) : locale(std::move(loc)), text(std::move(txt)) {}
    auto operator<=>(const LocalizedText&) const = default;
};

// A structure carried opaquely: the NodeId of its encoding and its encoded body.
// Typed access goes through the generated codecs: toExtensionObject(value) and
// fromExtensionObject<T>(obj) (see ua/types/extension_object.hpp).
struct ExtensionObject {
    enum class Encoding : Byte { None = 0, Binary = 1, Xml = 2 };
    NodeId typeId;  // the DataTypeEncoding node (e.g. i=886 "Range_Encoding_DefaultBinary")
    Encoding encoding = Encoding::None;
    std::string body;  // binary body or XML text
    bool empty() const { return encoding == Encoding::None && typeId.isNull(); }
    auto operator<=>(const ExtensionObject&) const = default;
};

// Deep-copying owning pointer: lets recursive value types (DataValue in Variant,
// DiagnosticInfo in DiagnosticInfo) keep value semantics.
template <class T>
class Box {
  public:
    Box() : p_(std::make_unique<T>()) {}
    Box(T v) : p_(std::make_unique<T>(std::move(v))) {}  // NOLINT
    Box(const Box& o) : p_(std::make_unique<T>(*o.p_)) {}
    Box(Box&&) noexcept = default;
    Box& operator=(const Box& o) {
        if (this != &o) p_ = std::make_unique<T>(*o.p_);
        return *this;
    }
    Box& operator=(Box&&) noexcept = default;
    T& operator*() { return *p_; }
    const T& operator*() const { return *p_; }
    T* operator->() { return p_.get(); }
    const T* operator->() const { return p_.get(); }
    bool operator==(const Box& o) const { return *p_ == *o.p_; }

  private:
    std::unique_ptr<T> p_;
};

struct DiagnosticInfo {
    std::optional<Int32> symbolicId;
    std::optional<Int32> namespaceUri;
    std::optional<Int32> localizedText;
    std::optional<Int32> locale;
    std::optional<String> additionalInfo;
    std::optional<StatusCode> innerStatusCode;
    std::shared_ptr<const DiagnosticInfo> innerDiagnosticInfo;  // immutable once built

    bool operator==(const DiagnosticInfo& o) const;
};

struct DataValue;
class Variant;

namespace detail {
// Placeholder for "a scalar Variant inside a Variant", which the encoding forbids.
struct NoScalarVariant {
    bool operator==(const NoScalarVariant&) const = default;
};
// Index i (1..25) holds a scalar of built-in type i, index 25 + i an array of type i.
using VariantStorage =
    std::variant<std::monostate, Boolean, SByte, Byte, Int16, UInt16, Int32, UInt32, Int64, UInt64,
                 Float, Double, String, DateTime, Guid, ByteString, XmlElement, NodeId,
                 ExpandedNodeId, StatusCode, QualifiedName, LocalizedText, ExtensionObject,
                 Box<DataValue>, NoScalarVariant, Box<DiagnosticInfo>, std::vector<Boolean>,
                 std::vector<SByte>, std::vector<Byte>, std::vector<Int16>, std::vector<UInt16>,
                 std::vector<Int32>, std::vector<UInt32>, std::vector<Int64>, std::vector<UInt64>,
                 std::vector<Float>, std::vector<Double>, std::vector<String>,
                 std::vector<DateTime>, std::vector<Guid>, std::vector<ByteString>,
                 std::vector<XmlElement>, std::vector<NodeId>, std::vector<ExpandedNodeId>,
                 std::vector<StatusCode>, std::vector<QualifiedName>, std::vector<LocalizedText>,
                 std::vector<ExtensionObject>, std::vector<DataValue>, std::vector<Variant>,
                 std::vector<DiagnosticInfo>>;
}  // namespace detail

// X(T) for every built-in type a Variant holds as a scalar (all but Variant), T being both the
// C++ type and its BuiltinType name.
#define PNP_UA_FOR_EACH_SCALAR_TYPE(X) \
    X(Boolean)                         \
    X(SByte)                           \
    X(Byte)                            \
    X(Int16)                           \
    X(UInt16)                          \
    X(Int32)                           \
    X(UInt32)                          \
    X(Int64)                           \
    X(UInt64)                          \
    X(Float)                           \
    X(Double)                          \
    X(String)                          \
    X(DateTime)                        \
    X(Guid)                            \
    X(ByteString)                      \
    X(XmlElement)                      \
    X(NodeId)                          \
    X(ExpandedNodeId)                  \
    X(StatusCode)                      \
    X(QualifiedName)                   \
    X(LocalizedText)                   \
    X(ExtensionObject)                 \
    X(DataValue)                       \
    X(DiagnosticInfo)

// The C++ type that holds a scalar of a built-in type in a Variant.
template <class T>
struct BuiltinTypeOf;
#define PNP_UA_BUILTIN_OF(T, id)                              \
    template <>                                               \
    struct BuiltinTypeOf<T> {                                 \
        static constexpr BuiltinType value = BuiltinType::id; \
    }
#define PNP_UA_BUILTIN_OF_SAME(T) PNP_UA_BUILTIN_OF(T, T);
PNP_UA_FOR_EACH_SCALAR_TYPE(PNP_UA_BUILTIN_OF_SAME)
#undef PNP_UA_BUILTIN_OF_SAME
PNP_UA_BUILTIN_OF(Variant, Variant);
#undef PNP_UA_BUILTIN_OF

// A scalar, a one-dimensional array or a matrix (array + dimensions) of one built-in type.
//
// Compile time: the storage is a std::variant of 51 alternatives, and every function that may
// construct, copy, assign or destroy it visits all of them. Those functions are declared here
// and defined once in builtin.cpp; the templates below only pick the alternative and call
// them, so a file that copies a Variant compiles none of that code itself.
class Variant {
  public:
    Variant() noexcept;
    Variant(const Variant& o);
    Variant(Variant&& o) noexcept;
    Variant& operator=(const Variant& o);
    Variant& operator=(Variant&& o) noexcept;
    ~Variant();

    Variant(const char* s);  // NOLINT
    template <class T, class = decltype(BuiltinTypeOf<std::decay_t<T>>::value),
              class = std::enable_if_t<!std::is_same_v<std::decay_t<T>, Variant>>>
    Variant(T&& v) : Variant() {  // NOLINT: implicit so that `Variant v = 42;` reads naturally
        set(std::forward<T>(v));
    }
    template <class T, class = decltype(BuiltinTypeOf<T>::value)>
    Variant(std::vector<T> v) : Variant() {  // NOLINT
        assignArray(std::move(v));
    }

    bool isEmpty() const { return data_.index() == 0; }
    bool isScalar() const { return !isEmpty() && data_.index() < kBuiltinTypeCount; }
    bool isArray() const { return data_.index() >= kBuiltinTypeCount; }
    BuiltinType type() const {
        auto i = data_.index();
        return static_cast<BuiltinType>(i < kBuiltinTypeCount ? i : i - (kBuiltinTypeCount - 1));
    }
    // Matrix dimensions; empty for scalars and one-dimensional arrays.
    const std::vector<Int32>& arrayDimensions() const { return dims_; }
    void setArrayDimensions(std::vector<Int32> d) { dims_ = std::move(d); }
    std::size_t arrayLength() const;

    template <class T>
    const T* scalar() const {
        return std::get_if<Slot<T>>(&data_) ? &unbox(std::get<Slot<T>>(data_)) : nullptr;
    }
    template <class T>
    const std::vector<T>* array() const {
        return std::get_if<std::vector<T>>(&data_);
    }
    template <class T>
    std::vector<T>* array() {
        return std::get_if<std::vector<T>>(&data_);
    }
    // Replaces the value (and clears the dimensions). T is one of the built-in types.
    template <class T>
    void set(T&& v) {
        using U = std::decay_t<T>;
        static_assert(!std::is_same_v<U, Variant>, "a Variant cannot hold a scalar Variant");
        static_assert(BuiltinTypeOf<U>::value != BuiltinType::Null, "not a built-in type");
        if constexpr (std::is_same_v<T, U>)  // a non-const rvalue
            assignScalar(std::move(v));
        else
            assignScalar(U(v));  // a copy, moved in
    }
    template <class T>
    void setArray(std::vector<T> v) {
        assignArray(std::move(v));
    }

    detail::VariantStorage& storage() { return data_; }
    const detail::VariantStorage& storage() const { return data_; }

    bool operator==(const Variant& o) const;
    std::string toString() const;  // human-readable, for logs and the CLI

  private:
    template <class T>
    using Slot = std::conditional_t<
        std::is_same_v<T, DataValue>, Box<DataValue>,
        std::conditional_t<std::is_same_v<T, DiagnosticInfo>, Box<DiagnosticInfo>, T>>;
    template <class T>
    static const T& unbox(const T& v) {
        return v;
    }
    template <class T>
    static const T& unbox(const Box<T>& v) {
        return *v;
    }

    // One overload per built-in type (arrays: also of Variant), defined in builtin.cpp (see
    // the class comment). Each replaces the value and clears the dimensions.
#define PNP_UA_VARIANT_ASSIGN(T) \
    void assignScalar(T&& v);    \
    void assignArray(std::vector<T>&& v);
    PNP_UA_FOR_EACH_SCALAR_TYPE(PNP_UA_VARIANT_ASSIGN)
#undef PNP_UA_VARIANT_ASSIGN
    void assignArray(std::vector<Variant>&& v);

    detail::VariantStorage data_;
    std::vector<Int32> dims_;
};

struct DataValue {
    std::optional<Variant> value;
    std::optional<StatusCode> status;  // absent means Good
    std::optional<DateTime> sourceTimestamp;
    std::optional<UInt16> sourcePicoseconds;
    std::optional<DateTime> serverTimestamp;
    std::optional<UInt16> serverPicoseconds;

    DataValue() = default;
    DataValue(Variant v) : value(std::move(v)) {}  // NOLINT
    StatusCode statusOrGood() const { return status.value_or(StatusCode{}); }
    bool operator==(const DataValue&) const = default;
};

}  // namespace pnp::ua

template <>
struct std::hash<pnp::ua::NodeId> {
    std::size_t operator()(const pnp::ua::NodeId& n) const noexcept { return n.hash(); }
};
