#include "mdns/dns_message.hpp"

#include <map>

namespace pnp::mdns {

namespace {

constexpr std::size_t kHeaderSize = 12;
// More pointer jumps than a 255-byte name can need: a hard stop on pointer chains.
constexpr int kMaxJumps = 128;

char lowerAscii(char c) { return (c >= 'A' && c <= 'Z') ? static_cast<char>(c - 'A' + 'a') : c; }

class Reader {
  public:
    explicit Reader(std::span<const std::uint8_t> b) : b_(b) {}

    std::size_t pos() const { return pos_; }
    std::size_t left() const { return b_.size() - pos_; }
    void need(std::size_t n) const {
        if (n > left()) throw DnsError("truncated message");
    }
    std::uint8_t u8() {
        need(1);
        return b_[pos_++];
    }
    std::uint16_t u16() {
        need(2);
        std::uint16_t v = static_cast<std::uint16_t>((b_[pos_] << 8) | b_[pos_ + 1]);
        pos_ += 2;
        return v;
    }
    std::uint32_t u32() {
        std::uint32_t hi = u16();
        return (hi << 16) | u16();
    }
    void bytes(std::uint8_t* out, std::size_t n) {
        need(n);
        for (std::size_t i = 0; i < n; ++i) out[i] = b_[pos_ + i];
        pos_ += n;
    }
    void skip(std::size_t n) {
        need(n);
        pos_ += n;
    }

    // A name at the current position; follows compression pointers, which must point
    // strictly backwards (no loops, no forward references).
    std::string name() {
        std::vector<std::string> labels;
        std::size_t wireLen = 1;  // the root label
        std::size_t p = pos_;
        std::size_t limit = pos_;  // a pointer must point before this
        bool jumped = false;
        int jumps = 0;
        for (;;) {
            if (p >= b_.size()) throw DnsError("truncated name");
            std::uint8_t len = b_[p];
            if ((len & 0xC0) == 0xC0) {
                if (p + 1 >= b_.size()) throw DnsError("truncated compression pointer");
                std::size_t target = static_cast<std::size_t>(((len & 0x3F) << 8) | b_[p + 1]);
                if (target >= limit) throw DnsError("compression pointer not backwards");
                if (++jumps > kMaxJumps) throw DnsError("too many compression pointers");
                if (!jumped) pos_ = p + 2;
                jumped = true;
                limit = target;
                p = target;
                continue;
            }
            if ((len & 0xC0) != 0) throw DnsError("reserved label type");
            if (len == 0) {
                if (!jumped) pos_ = p + 1;
                break;
            }
            if (p + 1 + len > b_.size()) throw DnsError("truncated label");
            wireLen += 1u + len;
            if (wireLen > kMaxNameLength) throw DnsError("name longer than 255 bytes");
            labels.emplace_back(reinterpret_cast<const char*>(b_.data() + p + 1), len);
            p += 1u + len;
        }
        return joinLabels(labels);
    }

  private:
    std::span<const std::uint8_t> b_;
    std::size_t pos_ = 0;
};

class Writer {
  public:
    std::vector<std::uint8_t> out;

    void u8(std::uint8_t v) { out.push_back(v); }
    void u16(std::uint16_t v) {
        out.push_back(static_cast<std::uint8_t>(v >> 8));
        out.push_back(static_cast<std::uint8_t>(v));
    }
    void u32(std::uint32_t v) {
        u16(static_cast<std::uint16_t>(v >> 16));
        u16(static_cast<std::uint16_t>(v));
    }
    void put16(std::size_t at, std::uint16_t v) {
        out[at] = static_cast<std::uint8_t>(v >> 8);
        out[at + 1] = static_cast<std::uint8_t>(v);
    }

    // compress = false: rdata names compared canonically, and names inside rdata of types
    // a receiver may not know (RFC 3597) are not compressed.
    void name(std::string_view n, bool compress) {
        std::vector<std::string> labels = splitName(n);
        std::size_t wire = 1;
        for (const auto& l : labels) {
            if (l.empty() || l.size() > kMaxLabelLength) throw DnsError("bad label length");
            wire += 1 + l.size();
        }
        if (wire > kMaxNameLength) throw DnsError("name longer than 255 bytes");
        for (std::size_t i = 0; i < labels.size(); ++i) {
            if (compress) {
                // Exact match only: a pointer to a differently cased suffix would change
                // the case the receiver shows (instance names are for humans).
                std::string key = joinLabels(labels, i);
                auto it = suffixes_.find(key);
                if (it != suffixes_.end()) {
                    u16(static_cast<std::uint16_t>(0xC000 | it->second));
                    return;
                }
                if (out.size() < 0x3FFF) suffixes_.emplace(std::move(key), out.size());
            }
            u8(static_cast<std::uint8_t>(labels[i].size()));
            out.insert(out.end(), labels[i].begin(), labels[i].end());
        }
        u8(0);
    }

    void rdata(const ResourceRecord& rr, bool compress) {
        switch (rr.type) {
            case rrtype::A:
                out.insert(out.end(), rr.ipv4.begin(), rr.ipv4.end());
                break;
            case rrtype::AAAA:
                out.insert(out.end(), rr.ipv6.begin(), rr.ipv6.end());
                break;
            case rrtype::PTR:
                name(compress ? rr.ptr : lowerName(rr.ptr), compress);
                break;
            case rrtype::SRV:
                u16(rr.srv.priority);
                u16(rr.srv.weight);
                u16(rr.srv.port);
                // RFC 2782: no compression of the SRV target.
                name(compress ? rr.srv.target : lowerName(rr.srv.target), false);
                break;
            case rrtype::TXT:
                if (rr.txt.empty()) u8(0);  // RFC 6763 §6.1: never empty rdata
                for (const auto& s : rr.txt) {
                    if (s.size() > 255) throw DnsError("TXT string longer than 255 bytes");
                    u8(static_cast<std::uint8_t>(s.size()));
                    out.insert(out.end(), s.begin(), s.end());
                }
                break;
            default:
                out.insert(out.end(), rr.raw.begin(), rr.raw.end());
                break;
        }
    }

    void record(const ResourceRecord& rr) {
        name(rr.name, true);
        u16(rr.type);
        u16(static_cast<std::uint16_t>((rr.rrclass & 0x7FFF) | (rr.cacheFlush ? 0x8000 : 0)));
        u32(rr.ttl);
        std::size_t lenAt = out.size();
        u16(0);
        rdata(rr, true);
        std::size_t len = out.size() - lenAt - 2;
        if (len > 0xFFFF) throw DnsError("rdata longer than 65535 bytes");
        put16(lenAt, static_cast<std::uint16_t>(len));
    }

  private:
    std::map<std::string, std::size_t> suffixes_;
};

// Name, type and class with its top bit (cache-flush in records, QU in questions).
struct Head {
    std::string name;
    std::uint16_t type;
    std::uint16_t cls;
    bool topBit;
};
Head readHead(Reader& r) {
    Head h;
    h.name = r.name();
    h.type = r.u16();
    std::uint16_t cls = r.u16();
    h.cls = cls & 0x7FFF;
    h.topBit = (cls & 0x8000) != 0;
    return h;
}

ResourceRecord record(std::string name, std::uint16_t type, std::uint32_t ttl, bool flush) {
    ResourceRecord rr;
    rr.name = std::move(name);
    rr.type = type;
    rr.ttl = ttl;
    rr.cacheFlush = flush;
    return rr;
}

ResourceRecord readRecord(Reader& r) {
    Head h = readHead(r);
    ResourceRecord rr = record(std::move(h.name), h.type, 0, h.topBit);
    rr.rrclass = h.cls;
    rr.ttl = r.u32();
    std::size_t len = r.u16();
    r.need(len);
    const std::size_t end = r.pos() + len;
    switch (rr.type) {
        case rrtype::A:
            if (len != 4) throw DnsError("A rdata not 4 bytes");
            r.bytes(rr.ipv4.data(), 4);
            break;
        case rrtype::AAAA:
            if (len != 16) throw DnsError("AAAA rdata not 16 bytes");
            r.bytes(rr.ipv6.data(), 16);
            break;
        case rrtype::PTR:
            rr.ptr = r.name();
            break;
        case rrtype::SRV:
            rr.srv.priority = r.u16();
            rr.srv.weight = r.u16();
            rr.srv.port = r.u16();
            rr.srv.target = r.name();
            break;
        case rrtype::TXT:
            while (r.pos() < end) {
                std::size_t n = r.u8();
                if (r.pos() + n > end) throw DnsError("TXT string beyond rdata");
                std::string s(n, '\0');
                r.bytes(reinterpret_cast<std::uint8_t*>(s.data()), n);
                if (!s.empty()) rr.txt.push_back(std::move(s));
            }
            break;
        default:
            rr.raw.resize(len);
            r.bytes(rr.raw.data(), len);
            break;
    }
    if (r.pos() != end) throw DnsError("rdata length does not match its content");
    return rr;
}

}  // namespace

DnsMessage decode(std::span<const std::uint8_t> bytes) {
    Reader r(bytes);
    if (bytes.size() < kHeaderSize) throw DnsError("shorter than a DNS header");
    DnsMessage m;
    m.id = r.u16();
    m.flags = r.u16();
    std::size_t qd = r.u16(), an = r.u16(), ns = r.u16(), ar = r.u16();
    // Cheap plausibility check before any allocation: a question takes at least 5 bytes,
    // a record at least 11.
    if (qd * 5 + (an + ns + ar) * 11 > r.left()) throw DnsError("counts exceed the message");
    m.questions.reserve(qd);
    for (std::size_t i = 0; i < qd; ++i) {
        Head h = readHead(r);
        m.questions.push_back({std::move(h.name), h.type, h.cls, h.topBit});
    }
    auto section = [&r](std::vector<ResourceRecord>& v, std::size_t n) {
        v.reserve(n);
        for (std::size_t i = 0; i < n; ++i) v.push_back(readRecord(r));
    };
    section(m.answers, an);
    section(m.authorities, ns);
    section(m.additionals, ar);
    return m;
}

std::vector<std::uint8_t> encode(const DnsMessage& m) {
    if (m.questions.size() > 0xFFFF || m.answers.size() > 0xFFFF || m.authorities.size() > 0xFFFF ||
        m.additionals.size() > 0xFFFF) {
        throw DnsError("too many entries");
    }
    Writer w;
    w.u16(m.id);
    w.u16(m.flags);
    w.u16(static_cast<std::uint16_t>(m.questions.size()));
    w.u16(static_cast<std::uint16_t>(m.answers.size()));
    w.u16(static_cast<std::uint16_t>(m.authorities.size()));
    w.u16(static_cast<std::uint16_t>(m.additionals.size()));
    for (const auto& q : m.questions) {
        w.name(q.name, true);
        w.u16(q.type);
        w.u16(static_cast<std::uint16_t>((q.qclass & 0x7FFF) | (q.unicastResponse ? 0x8000 : 0)));
    }
    for (const auto* s : {&m.answers, &m.authorities, &m.additionals}) {
        for (const auto& rr : *s) w.record(rr);
    }
    return std::move(w.out);
}

std::vector<std::uint8_t> canonicalRdata(const ResourceRecord& rr) {
    Writer w;
    w.rdata(rr, false);
    return std::move(w.out);
}

bool sameRdata(const ResourceRecord& a, const ResourceRecord& b) {
    return a.type == b.type && canonicalRdata(a) == canonicalRdata(b);
}

ResourceRecord ptrRecord(std::string name, std::string target, std::uint32_t ttl) {
    auto rr = record(std::move(name), rrtype::PTR, ttl, false);  // PTRs are shared
    rr.ptr = std::move(target);
    return rr;
}

ResourceRecord srvRecord(std::string name, SrvData srv, std::uint32_t ttl, bool cacheFlush) {
    auto rr = record(std::move(name), rrtype::SRV, ttl, cacheFlush);
    rr.srv = std::move(srv);
    return rr;
}

ResourceRecord txtRecord(std::string name, std::vector<std::string> txt, std::uint32_t ttl,
                         bool cacheFlush) {
    auto rr = record(std::move(name), rrtype::TXT, ttl, cacheFlush);
    rr.txt = std::move(txt);
    return rr;
}

ResourceRecord aRecord(std::string name, std::array<std::uint8_t, 4> address, std::uint32_t ttl,
                       bool cacheFlush) {
    auto rr = record(std::move(name), rrtype::A, ttl, cacheFlush);
    rr.ipv4 = address;
    return rr;
}

bool namesEqual(std::string_view a, std::string_view b) {
    if (a.size() != b.size()) return false;
    for (std::size_t i = 0; i < a.size(); ++i) {
        if (lowerAscii(a[i]) != lowerAscii(b[i])) return false;
    }
    return true;
}

std::string lowerName(std::string_view name) {
    std::string s(name);
    for (char& c : s) c = lowerAscii(c);
    return s;
}

std::string escapeLabel(std::string_view label) {
    std::string s;
    s.reserve(label.size());
    for (char c : label) {
        if (c == '.' || c == '\\') s.push_back('\\');
        s.push_back(c);
    }
    return s;
}

std::vector<std::string> splitName(std::string_view name) {
    std::vector<std::string> labels;
    std::string cur;
    for (std::size_t i = 0; i < name.size(); ++i) {
        char c = name[i];
        if (c == '\\') {
            if (++i == name.size()) throw DnsError("dangling escape in name");
            cur.push_back(name[i]);
        } else if (c == '.') {
            labels.push_back(std::move(cur));
            cur.clear();
        } else {
            cur.push_back(c);
        }
    }
    // A trailing '.' (fully qualified form) adds no empty label.
    if (!cur.empty()) labels.push_back(std::move(cur));
    return labels;
}

std::string joinLabels(const std::vector<std::string>& labels, std::size_t from) {
    std::string s;
    for (std::size_t i = from; i < labels.size(); ++i) {
        if (i > from) s.push_back('.');
        s += escapeLabel(labels[i]);
    }
    return s;
}

}  // namespace pnp::mdns
