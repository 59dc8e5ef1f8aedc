// Compact node storage of the address space (OPC 10000-3 §5: the eight NodeClasses and
// their Attributes). Internal to pnp_ua_server: applications use AddressSpace
// (ua/server/address_space.hpp), which owns every object declared here.
//
// Memory layout, chosen so that the full namespace 0 (~5,500 nodes, ~13,000 references)
// takes well under 2 MB:
//  * nodes live in one vector and are addressed by a 32-bit index (NodeIndex);
//  * NodeIds are stored as (namespace, 32-bit value): numeric ids inline, string / GUID /
//    opaque ids as an index into a side table;
//  * strings (BrowseNames, DisplayNames, ...) are interned in a StringPool and referenced
//    by a 32-bit id; the ones of the built-in NodeSet point into the constant blob compiled
//    into the binary and are never copied;
//  * references are 8 bytes (target index, reference-type index, direction flags) and are
//    stored on both ends (forward at the source, inverse at the target). The references
//    of the built-in NodeSet share one array (a borrowed slice per node) until a node's
//    references are modified;
//  * attributes that only some node classes have (Variable/VariableType data, inverse
//    names, DataTypeDefinitions) live in a separately allocated NodeExtra;
//  * values of the built-in NodeSet stay encoded in the blob and are decoded on read.
#pragma once

#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "ua/types/attribute_id.hpp"
#include "ua/types/builtin.hpp"

namespace pnp::ua::server {

using NodeIndex = std::uint32_t;
inline constexpr NodeIndex kNoNode = 0xFFFFFFFFu;

// Node classes as bit values (OPC 10000-3 §8.29, also the Browse nodeClassMask bits).
enum class NodeClassBits : std::uint8_t {
    Unspecified = 0,
    Object = 1,
    Variable = 2,
    Method = 4,
    ObjectType = 8,
    VariableType = 16,
    ReferenceType = 32,
    DataType = 64,
    View = 128,
};

using ua::AttributeId;  // ua/types/attribute_id.hpp

// AccessLevelType bits (OPC 10000-3 §8.57).
namespace access_level {
inline constexpr Byte CurrentRead = 0x01;
inline constexpr Byte CurrentWrite = 0x02;
inline constexpr Byte HistoryRead = 0x04;
inline constexpr Byte HistoryWrite = 0x08;
inline constexpr Byte SemanticChange = 0x10;
inline constexpr Byte StatusWrite = 0x20;
inline constexpr Byte TimestampWrite = 0x40;
}  // namespace access_level

// AttributeWriteMask bits (OPC 10000-3 §8.60).
namespace write_mask {
inline constexpr UInt32 AccessLevel = 1u << 0;
inline constexpr UInt32 ArrayDimensions = 1u << 1;
inline constexpr UInt32 BrowseName = 1u << 2;
inline constexpr UInt32 ContainsNoLoops = 1u << 3;
inline constexpr UInt32 DataType = 1u << 4;
inline constexpr UInt32 Description = 1u << 5;
inline constexpr UInt32 DisplayName = 1u << 6;
inline constexpr UInt32 EventNotifier = 1u << 7;
inline constexpr UInt32 Executable = 1u << 8;
inline constexpr UInt32 Historizing = 1u << 9;
inline constexpr UInt32 InverseName = 1u << 10;
inline constexpr UInt32 IsAbstract = 1u << 11;
inline constexpr UInt32 MinimumSamplingInterval = 1u << 12;
inline constexpr UInt32 NodeClass = 1u << 13;
inline constexpr UInt32 NodeId = 1u << 14;
inline constexpr UInt32 Symmetric = 1u << 15;
inline constexpr UInt32 UserAccessLevel = 1u << 16;
inline constexpr UInt32 UserExecutable = 1u << 17;
inline constexpr UInt32 UserWriteMask = 1u << 18;
inline constexpr UInt32 ValueRank = 1u << 19;
inline constexpr UInt32 WriteMask = 1u << 20;
inline constexpr UInt32 ValueForVariableType = 1u << 21;
inline constexpr UInt32 DataTypeDefinition = 1u << 22;
inline constexpr UInt32 AccessLevelEx = 1u << 25;
}  // namespace write_mask

// ---- strings ---------------------------------------------------------------------------
using StrId = std::uint32_t;  // 0 is always ""

class StringPool {
  public:
    StringPool();
    std::string_view get(StrId id) const { return views_[id]; }
    // Interns a copy of s.
    StrId intern(std::string_view s);
    // Appends a string that lives as long as the pool (e.g. in the constant NodeSet blob)
    // without copying it. Used by the NodeSet loader; not de-duplicated against intern().
    StrId addStatic(std::string_view s) {
        views_.push_back(s);
        return static_cast<StrId>(views_.size() - 1);
    }
    void reserve(std::size_t n) { views_.reserve(n); }
    std::size_t size() const { return views_.size(); }
    std::size_t bytesUsed() const;

  private:
    std::vector<std::string_view> views_;
    std::deque<std::string> owned_;
    std::unordered_map<std::string_view, StrId> index_;  // built lazily on first intern()
    std::size_t indexedUpTo_ = 0;
};

// ---- references ------------------------------------------------------------------------
// One reference as seen from the node that stores it.
struct Ref {
    static constexpr std::uint16_t kInverse = 1;   // stored at the target of the reference
    static constexpr std::uint16_t kExternal = 2;  // target indexes the external-target table
    NodeIndex target = kNoNode;
    std::uint16_t type = 0;  // dense index of the ReferenceType (AddressSpace::refTypes_)
    std::uint16_t flags = 0;
    bool isForward() const { return (flags & kInverse) == 0; }
    bool isExternal() const { return (flags & kExternal) != 0; }
    bool operator==(const Ref&) const = default;
};

// A small array of references that either borrows a slice of a shared array (capacity 0)
// or owns its storage. Appending to a borrowed list copies it first.
class RefList {
  public:
    RefList() = default;
    RefList(Ref* borrowed, std::uint32_t size) : data_(borrowed), size_(size) {}
    RefList(const RefList&) = delete;
    RefList& operator=(const RefList&) = delete;
    RefList(RefList&& o) noexcept : data_(o.data_), size_(o.size_), cap_(o.cap_) {
        o.data_ = nullptr;
        o.size_ = o.cap_ = 0;
    }
    RefList& operator=(RefList&& o) noexcept;
    ~RefList() { release(); }

    const Ref* begin() const { return data_; }
    const Ref* end() const { return data_ + size_; }
    std::uint32_t size() const { return size_; }
    bool empty() const { return size_ == 0; }
    const Ref& operator[](std::uint32_t i) const { return data_[i]; }

    void push_back(const Ref& r);
    // Removes the first reference equal to r; false if none.
    bool erase(const Ref& r);
    void clear() {
        release();
        data_ = nullptr;
        size_ = 0;
    }
    std::size_t heapBytes() const { return cap_ * sizeof(Ref); }

  private:
    void release() {
        if (cap_ != 0) delete[] data_;
        cap_ = 0;
    }
    Ref* data_ = nullptr;
    std::uint32_t size_ = 0;
    std::uint32_t cap_ = 0;  // 0: storage is borrowed (or empty)
};

// ---- values ----------------------------------------------------------------------------
struct ValueCallbacks;

// The Value of a Variable / VariableType, or the DataTypeDefinition of a DataType: encoded
// bytes of the built-in NodeSet (decoded on each read), an owned value, and optional
// application callbacks.
struct ValueSlot {
    const Byte* encoded = nullptr;  // OPC UA Binary Variant (or ExtensionObject)
    std::uint32_t encodedSize = 0;
    std::unique_ptr<DataValue> owned;
    std::shared_ptr<const ValueCallbacks> callbacks;
    bool empty() const { return encoded == nullptr && !owned; }
};

// A NodeId in 8 bytes: numeric ids inline, others as an index into a table of interned ids
// (AddressSpace::Impl::internedIds).
struct CompactNodeId {
    std::uint32_t value = 0;
    std::uint16_t ns = 0;
    std::uint8_t interned = 0;
};

// Data of the node classes that need more than the common attributes.
struct NodeExtra {
    // Variable, VariableType
    std::vector<UInt32> arrayDimensions;
    double minimumSamplingInterval = 0;
    CompactNodeId dataType{24, 0, 0};  // BaseDataType
    Int32 valueRank = -1;
    Byte accessLevel = access_level::CurrentRead;
    Byte userAccessLevel = access_level::CurrentRead;
    // ReferenceType: InverseName, and its dense index in AddressSpace::refTypes_.
    StrId inverseLocale = 0;
    StrId inverseText = 0;
    std::uint16_t refTypeIndex = 0xFFFF;
    bool hasInverseName = false;
    // Variable / VariableType: Value. DataType: DataTypeDefinition.
    ValueSlot value;
};

struct Node {
    // Boolean attributes and bookkeeping flags.
    static constexpr std::uint8_t kIsAbstract = 0x01;
    static constexpr std::uint8_t kSymmetric = 0x02;
    static constexpr std::uint8_t kContainsNoLoops = 0x04;
    static constexpr std::uint8_t kHistorizing = 0x08;
    static constexpr std::uint8_t kExecutable = 0x10;
    static constexpr std::uint8_t kUserExecutable = 0x20;
    static constexpr std::uint8_t kAlive = 0x80;

    // NodeId: numeric value, or (idKind != 0) index into AddressSpace's id table.
    std::uint32_t idValue = 0;
    std::uint16_t ns = 0;
    std::uint8_t idKind = 0;  // 0 numeric, 1 other (string / guid / opaque)
    NodeClassBits nodeClass = NodeClassBits::Unspecified;

    std::uint16_t browseNs = 0;
    std::uint8_t flags = 0;
    Byte eventNotifier = 0;
    StrId browseName = 0;
    StrId displayLocale = 0;
    StrId displayText = 0;
    StrId descriptionLocale = 0;
    StrId descriptionText = 0;
    UInt32 writeMask = 0;
    UInt32 userWriteMask = 0;

    RefList refs;
    std::unique_ptr<NodeExtra> extra;

    bool alive() const { return (flags & kAlive) != 0; }
    bool has(std::uint8_t f) const { return (flags & f) != 0; }
    void set(std::uint8_t f, bool on) { flags = on ? (flags | f) : (flags & ~f); }
};

}  // namespace pnp::ua::server
