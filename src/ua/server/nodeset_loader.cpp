// Decodes a NodeSet blob produced by tools/nodeset_compiler/nodeset_compiler.py (format
// documented there) into the address space. The blob is constant data compiled into the
// binary: strings and encoded values are referenced in place, never copied.
#include <cstring>
#include <stdexcept>

#include "ua/server/address_space_impl.hpp"

namespace pnp::ua::server {

namespace generated {
extern const unsigned char kNs0Blob[];
extern const std::size_t kNs0BlobSize;
extern const std::size_t kNs0BlobNodeCount;
}  // namespace generated

std::size_t namespaceZeroBlobNodeCount() { return generated::kNs0BlobNodeCount; }

namespace {

class BlobReader {
  public:
    BlobReader(const Byte* p, std::size_t n) : p_(p), end_(p + n) {}

    std::uint64_t varint() {
        std::uint64_t v = 0;
        for (int shift = 0; shift < 64; shift += 7) {
            Byte b = byte();
            v |= static_cast<std::uint64_t>(b & 0x7F) << shift;
            if ((b & 0x80) == 0) return v;
        }
        fail();
    }
    std::uint32_t u32() {
        std::uint64_t v = varint();
        if (v > 0xFFFFFFFFu) fail();
        return static_cast<std::uint32_t>(v);
    }
    std::int64_t svarint() {
        std::uint64_t v = varint();
        return static_cast<std::int64_t>(v >> 1) ^ -static_cast<std::int64_t>(v & 1);
    }
    Byte byte() {
        if (p_ >= end_) fail();
        return *p_++;
    }
    const Byte* take(std::size_t n) {
        if (n > static_cast<std::size_t>(end_ - p_)) fail();
        const Byte* at = p_;
        p_ += n;
        return at;
    }
    std::string_view bytes() {
        std::size_t n = varint();
        return {reinterpret_cast<const char*>(take(n)), n};
    }
    double f64() {
        double d;
        std::memcpy(&d, take(8), 8);
        return d;
    }
    const Byte* position() const { return p_; }
    [[noreturn]] static void fail() {
        throw AddressSpaceError(status::BadDecodingError, "corrupt NodeSet blob");
    }

  private:
    const Byte* p_;
    const Byte* end_;
};

}  // namespace

void AddressSpace::Impl::loadNodeSet(const Byte* blob, std::size_t size) {
    BlobReader in(blob, size);
    if (size < 12 || std::memcmp(in.take(8), "PNPNSET1", 8) != 0) BlobReader::fail();
    std::uint32_t valuesAt;
    std::memcpy(&valuesAt, in.take(4), 4);
    if (valuesAt > size) BlobReader::fail();
    const Byte* values = blob + valuesAt;
    const std::size_t valuesSize = size - valuesAt;
    auto readValue = [&](ValueSlot& slot) {
        std::uint64_t at = in.varint(), len = in.varint();
        if (at > valuesSize || len > valuesSize - at) BlobReader::fail();
        slot.encoded = values + at;
        slot.encodedSize = static_cast<std::uint32_t>(len);
    };
    const std::size_t nodeCount = in.varint();
    const std::size_t refCount = in.varint();

    // Namespace table of the blob -> server namespace indexes.
    std::vector<UInt16> nsMap(in.varint());
    for (auto& m : nsMap) {
        std::string_view uri = in.bytes();
        UInt16 idx = 0;
        bool found = false;
        for (std::size_t i = 0; i < namespaces.size(); ++i) {
            if (namespaces[i] == uri) {
                idx = static_cast<UInt16>(i);
                found = true;
                break;
            }
        }
        if (!found) {
            namespaces.emplace_back(uri);
            idx = static_cast<UInt16>(namespaces.size() - 1);
        }
        m = idx;
    }
    auto mapNs = [&](std::uint64_t ns) -> UInt16 {
        if (ns >= nsMap.size()) BlobReader::fail();
        return nsMap[ns];
    };

    // Strings: referenced in place.
    const std::size_t stringCount = in.varint();
    strings.reserve(strings.size() + stringCount);
    std::vector<StrId> strMap(stringCount);
    for (std::size_t i = 0; i < stringCount; ++i) {
        std::string_view s = in.bytes();
        strMap[i] = s.empty() ? 0 : strings.addStatic(s);
    }
    auto str = [&]() -> StrId {
        std::uint64_t i = in.varint();
        if (i >= strMap.size()) BlobReader::fail();
        return strMap[i];
    };
    auto readNodeId = [&]() -> NodeId {
        Byte kind = in.byte();
        switch (kind) {
            case 0:
                return NodeId(0, in.u32());
            case 1: {
                UInt16 ns = mapNs(in.varint());
                return NodeId(ns, in.u32());
            }
            case 2: {
                UInt16 ns = mapNs(in.varint());
                return NodeId(ns, String(strings.get(str())));
            }
            case 3: {
                UInt16 ns = mapNs(in.varint());
                const Byte* g = in.take(16);
                Guid guid;
                std::memcpy(&guid.data1, g, 4);
                std::memcpy(&guid.data2, g + 4, 2);
                std::memcpy(&guid.data3, g + 6, 2);
                std::memcpy(guid.data4.data(), g + 8, 8);
                return NodeId(ns, guid);
            }
            case 4: {
                UInt16 ns = mapNs(in.varint());
                std::string_view b = in.bytes();
                return NodeId(ns, ByteString(std::string(b)));
            }
            default:
                BlobReader::fail();
        }
    };

    const NodeIndex first = static_cast<NodeIndex>(nodes.size());
    nodes.reserve(nodes.size() + nodeCount);
    for (std::size_t k = 0; k < nodeCount; ++k) {
        const auto cls = static_cast<NodeClassBits>(in.byte());
        NodeId id = readNodeId();
        if (find(id) != kNoNode)
            throw AddressSpaceError(status::BadNodeIdExists, "NodeSet node " + id.toString());
        const auto index = static_cast<NodeIndex>(nodes.size());
        Node& n = nodes.emplace_back();
        n.nodeClass = cls;
        n.flags = Node::kAlive;
        registerId(index, id);
        n.browseNs = mapNs(in.varint());
        n.browseName = str();
        n.displayLocale = str();
        n.displayText = str();
        const std::uint64_t flags = in.varint();
        if (flags & 0x0001) {
            n.descriptionLocale = str();
            n.descriptionText = str();
        }
        if (flags & 0x0002) {
            n.writeMask = in.u32();
            n.userWriteMask = in.u32();
        }
        n.set(Node::kIsAbstract, flags & 0x0004);
        n.set(Node::kSymmetric, flags & 0x0008);
        n.set(Node::kContainsNoLoops, flags & 0x0010);
        n.set(Node::kHistorizing, flags & 0x0020);
        n.set(Node::kExecutable, flags & 0x0040);
        n.set(Node::kUserExecutable, flags & 0x0080);
        switch (cls) {
            case NodeClassBits::Object:
            case NodeClassBits::View:
                n.eventNotifier = in.byte();
                break;
            case NodeClassBits::Variable:
            case NodeClassBits::VariableType: {
                auto x = std::make_unique<NodeExtra>();
                x->dataType = compact(readNodeId());
                x->valueRank = static_cast<Int32>(in.svarint());
                if (cls == NodeClassBits::Variable) {
                    x->accessLevel = in.byte();
                    x->userAccessLevel = in.byte();
                    if (flags & 0x1000) x->minimumSamplingInterval = in.f64();
                }
                if (flags & 0x0800) {
                    x->arrayDimensions.resize(in.varint());
                    for (auto& d : x->arrayDimensions) d = in.u32();
                }
                if (flags & 0x0100) readValue(x->value);
                n.extra = std::move(x);
                break;
            }
            case NodeClassBits::ReferenceType: {
                auto x = std::make_unique<NodeExtra>();
                if (flags & 0x0200) {
                    x->inverseLocale = str();
                    x->inverseText = str();
                    x->hasInverseName = true;
                }
                n.extra = std::move(x);
                addRefType(index);
                break;
            }
            case NodeClassBits::DataType:
                if (flags & 0x0400) {
                    auto x = std::make_unique<NodeExtra>();
                    readValue(x->value);
                    n.extra = std::move(x);
                }
                break;
            default:
                break;
        }
        ++liveNodes;
    }

    // References: one pass counts them per node (both ends), a second one fills the slices
    // of one shared array (no per-node allocation, no temporary copy of the references).
    const Byte* refsAt = in.position();
    std::vector<std::uint32_t> slot(nodeCount + 1, 0);
    for (std::size_t k = 0; k < refCount; ++k) {
        std::uint32_t source = in.u32(), type = in.u32(), target = in.u32();
        if (source >= nodeCount || type >= nodeCount || target >= nodeCount) BlobReader::fail();
        ++slot[source + 1];
        ++slot[target + 1];
    }
    blobBytesTouched += static_cast<std::size_t>(in.position() - blob);
    for (std::size_t k = 0; k < nodeCount; ++k) slot[k + 1] += slot[k];  // start offsets
    std::unique_ptr<Ref[]> pool(new Ref[2 * refCount]);
    BlobReader again(refsAt, static_cast<std::size_t>(in.position() - refsAt));
    for (std::size_t k = 0; k < refCount; ++k) {
        std::uint32_t source = again.u32(), typeNode = again.u32(), target = again.u32();
        std::uint16_t type = refTypeIndexOf(first + typeNode);
        if (type == kNoRefType)
            throw AddressSpaceError(status::BadReferenceTypeIdInvalid, "NodeSet reference");
        pool[slot[source]++] = Ref{first + target, type, 0};
        pool[slot[target]++] = Ref{first + source, type, Ref::kInverse};
    }
    // slot[k] now is the end of node k's slice, i.e. the start of node k + 1's.
    for (std::size_t k = 0; k < nodeCount; ++k) {
        std::uint32_t begin = k == 0 ? 0 : slot[k - 1];
        if (slot[k] != begin) nodes[first + k].refs = RefList(pool.get() + begin, slot[k] - begin);
    }
    referenceCount += refCount;
    refPoolBytes += 2 * refCount * sizeof(Ref);
    refPools.push_back(std::move(pool));
    if (!ns0Index.empty()) ns0Index.shrink_to_fit();

    rememberWellKnownRefTypes();
    rebuildSubtypeClosure();
}

}  // namespace pnp::ua::server
