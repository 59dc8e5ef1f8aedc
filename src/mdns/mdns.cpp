#include "mdns/mdns.hpp"

#include <arpa/inet.h>
#include <ifaddrs.h>
#include <linux/netlink.h>
#include <linux/rtnetlink.h>
#include <net/if.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <map>
#include <mutex>
#include <random>
#include <set>
#include <stdexcept>
#include <system_error>
#include <thread>
#include <tuple>
#include <utility>

#include "mdns/dns_message.hpp"

namespace pnp::mdns {

namespace {

using Clock = std::chrono::steady_clock;
using TimePoint = Clock::time_point;
using std::chrono::milliseconds;
using std::chrono::seconds;

constexpr std::size_t kMaxPayload = 1440;       // RFC 6762 §17 without jumbo frames
constexpr std::size_t kMaxCacheRecords = 4096;  // oldest dropped beyond this
constexpr std::size_t kMaxPacketsPerWake = 64;  // bounded receive loop
constexpr std::size_t kMaxSentHashes = 256;
constexpr std::size_t kMaxRecentProbes = 256;
// Delayed responses waiting for their 20-120 ms: a query flood must not queue without end.
constexpr std::size_t kMaxOutgoing = 512;
constexpr std::uint32_t kLegacyTtl = 10;  // RFC 6762 §6.7
constexpr int kProbeCount = 3;
constexpr milliseconds kProbeInterval{250};
constexpr seconds kGoodbyeGrace{1};  // RFC 6762 §10.1
constexpr seconds kFlushGrace{1};    // RFC 6762 §10.2
constexpr seconds kMaxQueryInterval{3600};
// A peer whose probe came this recently is still probing (its probes are 250 ms apart).
constexpr milliseconds kPeerProbeWindow{300};
const char* const kServicesName = "_services._dns-sd._udp.local";

[[noreturn]] void throwErrno(const char* what) {
    throw std::system_error(errno, std::generic_category(), what);
}

std::string ipv4Text(const std::array<std::uint8_t, 4>& a) {
    return std::to_string(a[0]) + "." + std::to_string(a[1]) + "." + std::to_string(a[2]) + "." +
           std::to_string(a[3]);
}

std::array<std::uint8_t, 4> ipv4Bytes(in_addr a) {
    std::array<std::uint8_t, 4> b{};
    std::memcpy(b.data(), &a.s_addr, 4);  // s_addr is in network order already
    return b;
}

bool sameRecord(const ResourceRecord& a, const ResourceRecord& b) {
    return a.type == b.type && namesEqual(a.name, b.name) && sameRdata(a, b);
}

void addUnique(std::vector<ResourceRecord>& v, const ResourceRecord& rr) {
    for (const auto& x : v) {
        if (sameRecord(x, rr)) return;
    }
    v.push_back(rr);
}

// "base (n)", the base shortened (at a UTF-8 character boundary) to keep within a label.
std::string renamed(const std::string& base, int n) {
    std::string suffix = " (" + std::to_string(n) + ")";
    std::size_t keep = std::min(base.size(), kMaxLabelLength - suffix.size());
    while (keep > 0 && keep < base.size() &&
           (static_cast<unsigned char>(base[keep]) & 0xC0) == 0x80) {
        --keep;
    }
    return base.substr(0, keep) + suffix;
}

struct Interface {
    std::string name;
    int index = 0;
    in_addr addr{};
};

struct Publication {
    Mdns::PublicationId id = 0;
    ServiceRecord rec;
    std::string baseInstance;
    int renames = 1;
    std::function<void(const std::string&)> onRename;
    int probesSent = 0;
    TimePoint nextProbe{};
    TimePoint probeEnd{};     // 250 ms after the last probe
    TimePoint lastDefence{};  // defending announcements are rate-limited
    // Pending announcements: (time, interface index; 0 = every interface).
    std::vector<std::pair<TimePoint, int>> announcements;

    std::string typeName() const { return rec.type + ".local"; }
    std::string instanceName() const { return escapeLabel(rec.instance) + "." + typeName(); }
    std::string hostName() const { return escapeLabel(rec.host) + ".local"; }
    bool probing() const { return probesSent < kProbeCount || Clock::now() < probeEnd; }
};

struct CacheEntry {
    int ifIndex = 0;
    ResourceRecord rr;
    TimePoint received{};
    TimePoint expires{};
    int refreshStage = 0;  // refresh queries sent so far (80/85/90/95 %)
    bool goodbye = false;  // TTL 0 seen: gone for browsing, kept 1 s for corrections
    bool flushed = false;  // superseded through the cache-flush bit
};

struct Browse {
    Mdns::BrowseId id = 0;
    std::string type;      // as given
    std::string typeName;  // lower-cased "type.local"
    std::function<void(const DiscoveredService&, bool)> callback;
    TimePoint nextQuery{};
    milliseconds interval{1000};
    bool asked = false;  // the first query went out (it asks for unicast answers)
    std::map<std::string, DiscoveredService> reported;  // key: ifIndex|instance name
};

struct Outgoing {
    TimePoint at;
    int ifIndex;
    sockaddr_in dest;
    std::vector<std::uint8_t> bytes;
    std::vector<Mdns::PublicationId> from;  // whose records it carries
};

}  // namespace

std::string DiscoveredService::txtValue(std::string_view key) const {
    for (const auto& t : txt) {
        auto eq = t.find('=');
        std::string_view k = std::string_view(t).substr(0, eq);
        if (namesEqual(k, key)) return eq == std::string::npos ? "" : t.substr(eq + 1);
    }
    return "";
}

struct Mdns::Impl {
    explicit Impl(MdnsConfig c) : cfg(std::move(c)), rng(std::random_device{}()) {
        if (::inet_pton(AF_INET, cfg.group.c_str(), &group) != 1 ||
            !IN_MULTICAST(ntohl(group.s_addr))) {
            throw std::invalid_argument("mdns: bad multicast group " + cfg.group);
        }
    }

    MdnsConfig cfg;
    in_addr group{};
    mutable std::mutex mu;
    std::thread thread;
    bool running = false;
    bool stopping = false;
    int sock = -1;
    int netlink = -1;
    int wake = -1;

    std::vector<Interface> ifaces;
    std::map<PublicationId, Publication> pubs;
    std::map<BrowseId, Browse> browses;
    std::vector<CacheEntry> cache;
    std::vector<Outgoing> outgoing;  // delayed (shared) answers
    std::set<std::string> oneShotQueries;
    // (interface, name) -> next resolve query and its back-off.
    std::map<std::pair<int, std::string>, std::pair<TimePoint, milliseconds>> resolving;
    std::deque<std::pair<std::size_t, TimePoint>> sentHashes;  // to ignore our own packets
    // Probes seen: lower-cased name -> (SRV rdata, time); tells a newcomer from a peer.
    std::deque<std::tuple<std::string, std::vector<std::uint8_t>, TimePoint>> recentProbes;
    std::uint64_t nextId = 1;
    TimePoint nextIfaceCheck{};
    TimePoint nextWake{};
    std::mt19937 rng;
    // Callbacks run after the lock is released, each only while its owner (browse or
    // publication id) still exists; stopBrowse()/withdraw() wait for a running batch.
    std::vector<std::pair<std::uint64_t, std::function<void()>>> callbacks;
    bool delivering = false;
    std::condition_variable delivered;
    std::thread::id threadId;

    // ---- records -------------------------------------------------------------------
    // PTR is shared, SRV / TXT / A are unique to us (cache-flush bit set).
    ResourceRecord ptrRecord(const Publication& p) const {
        return mdns::ptrRecord(p.typeName(), p.instanceName(), cfg.otherTtl);
    }
    ResourceRecord srvRecord(const Publication& p) const {
        return mdns::srvRecord(p.instanceName(), {0, 0, p.rec.port, p.hostName()}, cfg.otherTtl,
                               true);
    }
    ResourceRecord txtRecord(const Publication& p) const {
        return mdns::txtRecord(p.instanceName(), p.rec.txt, cfg.otherTtl, true);
    }
    ResourceRecord aRecord(const Publication& p, const Interface& i) const {
        in_addr a = i.addr;
        if (p.rec.address) ::inet_pton(AF_INET, p.rec.address->c_str(), &a);
        return mdns::aRecord(p.hostName(), ipv4Bytes(a), cfg.hostTtl, true);
    }
    std::vector<ResourceRecord> allRecords(const Publication& p, const Interface& i) const {
        return {ptrRecord(p), srvRecord(p), txtRecord(p), aRecord(p, i)};
    }

    // ---- sending -------------------------------------------------------------------
    sockaddr_in groupAddr() const {
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_port = htons(cfg.port);
        a.sin_addr = group;
        return a;
    }

    const Interface* iface(int index) const {
        for (const auto& i : ifaces) {
            if (i.index == index) return &i;
        }
        return nullptr;
    }

    void sendRaw(int ifIndex, const sockaddr_in& dest, const std::vector<std::uint8_t>& bytes) {
        if (sock < 0 || iface(ifIndex) == nullptr) return;
        ip_mreqn m{};
        m.imr_ifindex = ifIndex;
        ::setsockopt(sock, IPPROTO_IP, IP_MULTICAST_IF, &m, sizeof m);
        ::sendto(sock, bytes.data(), bytes.size(), MSG_DONTWAIT,
                 reinterpret_cast<const sockaddr*>(&dest), sizeof dest);
        sentHashes.emplace_back(hashOf(bytes), Clock::now());
        if (sentHashes.size() > kMaxSentHashes) sentHashes.pop_front();
    }

    static std::size_t hashOf(std::span<const std::uint8_t> b) {
        return std::hash<std::string_view>{}(
            std::string_view(reinterpret_cast<const char*>(b.data()), b.size()));
    }

    bool ours(std::span<const std::uint8_t> b) {
        auto now = Clock::now();
        while (!sentHashes.empty() && now - sentHashes.front().second > seconds(5)) {
            sentHashes.pop_front();
        }
        std::size_t h = hashOf(b);
        return std::any_of(sentHashes.begin(), sentHashes.end(),
                           [h](const auto& e) { return e.first == h; });
    }

    // Encodes the message, split into packets of at most kMaxPayload bytes: answers are
    // spread over several packets, additionals go where they fit (or are left out).
    std::vector<std::vector<std::uint8_t>> packets(DnsMessage m) const {
        std::vector<std::vector<std::uint8_t>> out;
        std::vector<ResourceRecord> answers = std::move(m.answers);
        std::vector<ResourceRecord> additionals = std::move(m.additionals);
        m.answers.clear();
        m.additionals.clear();
        std::size_t a = 0;
        do {
            DnsMessage p = m;
            auto bytes = encode(p);
            while (a < answers.size()) {
                p.answers.push_back(answers[a]);
                auto next = encode(p);
                if (next.size() > kMaxPayload && p.answers.size() > 1) {
                    p.answers.pop_back();
                    break;
                }
                bytes = std::move(next);
                ++a;
            }
            for (const auto& rr : additionals) {
                p.additionals.push_back(rr);
                auto next = encode(p);
                if (next.size() > kMaxPayload) {
                    p.additionals.pop_back();
                    continue;
                }
                bytes = std::move(next);
            }
            out.push_back(std::move(bytes));
            m.questions.clear();  // questions only in the first packet
        } while (a < answers.size());
        return out;
    }

    // at > now: delayed (a shared answer); `from` names the publications in it, so that a
    // goodbye can cancel it (else it would bring the records back after the goodbye).
    void send(int ifIndex, const sockaddr_in& dest, DnsMessage m, TimePoint at = {},
              const std::vector<PublicationId>& from = {}) {
        std::vector<std::vector<std::uint8_t>> ps;
        try {
            ps = packets(std::move(m));
        } catch (const DnsError&) {
            return;  // publish() validated our records; nothing else can fail here
        }
        for (auto& p : ps) {
            if (at <= Clock::now()) {
                sendRaw(ifIndex, dest, p);
            } else if (outgoing.size() < kMaxOutgoing) {
                outgoing.push_back({at, ifIndex, dest, std::move(p), from});
            }
        }
    }

    static DnsMessage response(std::vector<ResourceRecord> answers,
                               std::vector<ResourceRecord> additionals = {}) {
        DnsMessage m;
        m.flags = DnsMessage::kResponseFlag | DnsMessage::kAuthoritativeFlag;
        m.answers = std::move(answers);
        m.additionals = std::move(additionals);
        return m;
    }

    void announce(const Publication& p, int ifIndex) {
        for (const auto& i : ifaces) {
            if (ifIndex != 0 && i.index != ifIndex) continue;
            send(i.index, groupAddr(), response(allRecords(p, i)));
        }
    }

    void goodbye(const Publication& p, bool withPtr) {
        std::erase_if(outgoing, [&p](const Outgoing& o) {
            return std::find(o.from.begin(), o.from.end(), p.id) != o.from.end();
        });
        for (const auto& i : ifaces) {
            auto rs = allRecords(p, i);
            // After a conflict the PTR is the winner's too: its goodbye would remove that.
            if (!withPtr) rs.erase(rs.begin());
            for (auto& rr : rs) rr.ttl = 0;
            send(i.index, groupAddr(), response(std::move(rs)));
        }
    }

    void probe(const Publication& p) {
        for (const auto& i : ifaces) {
            DnsMessage m;
            m.questions.push_back({p.instanceName(), rrtype::ANY, kClassIn, false});
            m.authorities = {srvRecord(p), txtRecord(p)};
            for (auto& rr : m.authorities) rr.cacheFlush = false;
            send(i.index, groupAddr(), std::move(m));
        }
    }

    void scheduleAnnouncements(Publication& p, int ifIndex) {
        auto now = Clock::now();
        // Immediately, then after 1 s and 2 s more (RFC 6762 §8.3: at least two).
        p.announcements.emplace_back(now, ifIndex);
        p.announcements.emplace_back(now + seconds(1), ifIndex);
        p.announcements.emplace_back(now + seconds(3), ifIndex);
    }

    void wakeUp() const {
        if (wake < 0) return;
        std::uint64_t one = 1;
        [[maybe_unused]] auto r = ::write(wake, &one, sizeof one);
    }

    // ---- interfaces ----------------------------------------------------------------
    std::vector<Interface> scanInterfaces() const {
        std::vector<Interface> found;
        ifaddrs* list = nullptr;
        if (::getifaddrs(&list) != 0) return ifaces;  // keep what we have
        for (ifaddrs* a = list; a != nullptr; a = a->ifa_next) {
            if (a->ifa_addr == nullptr || a->ifa_addr->sa_family != AF_INET) continue;
            std::string name = a->ifa_name;
            bool named = std::find(cfg.interfaces.begin(), cfg.interfaces.end(), name) !=
                         cfg.interfaces.end();
            if (!cfg.interfaces.empty() && !named) continue;
            unsigned f = a->ifa_flags;
            if (!(f & IFF_UP) || !(f & IFF_MULTICAST)) continue;
            if ((f & IFF_LOOPBACK) && !named) continue;
            int index = static_cast<int>(::if_nametoindex(a->ifa_name));
            if (index == 0) continue;
            bool dup = std::any_of(found.begin(), found.end(),
                                   [index](const Interface& i) { return i.index == index; });
            if (dup) continue;  // first IPv4 address of an interface
            Interface i;
            i.name = name;
            i.index = index;
            i.addr = reinterpret_cast<const sockaddr_in*>(a->ifa_addr)->sin_addr;
            found.push_back(i);
        }
        ::freeifaddrs(list);
        return found;
    }

    void membership(const Interface& i, int op) const {
        ip_mreqn m{};
        m.imr_multiaddr = group;
        m.imr_address = i.addr;
        m.imr_ifindex = i.index;
        ::setsockopt(sock, IPPROTO_IP, op, &m, sizeof m);
    }

    void updateInterfaces() {
        auto found = scanInterfaces();
        auto same = [](const Interface& a, const Interface& b) {
            return a.index == b.index && a.name == b.name && a.addr.s_addr == b.addr.s_addr;
        };
        for (const auto& old : ifaces) {
            if (std::none_of(found.begin(), found.end(),
                             [&](const Interface& n) { return same(n, old); })) {
                membership(old, IP_DROP_MEMBERSHIP);  // may fail: the link is gone
                dropInterfaceCache(old.index);
            }
        }
        std::vector<Interface> added;
        for (const auto& n : found) {
            if (std::none_of(ifaces.begin(), ifaces.end(),
                             [&](const Interface& o) { return same(n, o); })) {
                added.push_back(n);
            }
        }
        ifaces = std::move(found);
        auto now = Clock::now();
        for (const auto& n : added) {
            membership(n, IP_ADD_MEMBERSHIP);
            for (auto& [id, p] : pubs) scheduleAnnouncements(p, n.index);
            for (auto& [id, b] : browses) {
                b.nextQuery = now;
                b.interval = milliseconds(1000);
                b.asked = false;
            }
        }
    }

    void dropInterfaceCache(int index) {
        std::erase_if(cache, [index](const CacheEntry& e) { return e.ifIndex == index; });
        std::erase_if(resolving, [index](const auto& kv) { return kv.first.first == index; });
    }

    void drainNetlink() {
        char buf[8192];
        for (std::size_t n = 0; n < kMaxPacketsPerWake; ++n) {
            if (::recv(netlink, buf, sizeof buf, MSG_DONTWAIT) < 0) break;
        }
    }

    // ---- receiving -----------------------------------------------------------------
    void receive() {
        std::uint8_t buf[9000];  // RFC 6762 §17: up to 9000 bytes on jumbo-frame links
        for (std::size_t n = 0; n < kMaxPacketsPerWake; ++n) {
            sockaddr_in src{};
            char control[CMSG_SPACE(sizeof(in_pktinfo))];
            iovec iov{buf, sizeof buf};
            msghdr mh{};
            mh.msg_name = &src;
            mh.msg_namelen = sizeof src;
            mh.msg_iov = &iov;
            mh.msg_iovlen = 1;
            mh.msg_control = control;
            mh.msg_controllen = sizeof control;
            ssize_t len = ::recvmsg(sock, &mh, MSG_DONTWAIT);
            if (len < 0) return;
            if (mh.msg_flags & MSG_TRUNC) continue;
            int ifIndex = 0;
            for (cmsghdr* c = CMSG_FIRSTHDR(&mh); c != nullptr; c = CMSG_NXTHDR(&mh, c)) {
                if (c->cmsg_level == IPPROTO_IP && c->cmsg_type == IP_PKTINFO) {
                    in_pktinfo pi;
                    std::memcpy(&pi, CMSG_DATA(c), sizeof pi);
                    ifIndex = pi.ipi_ifindex;
                }
            }
            const Interface* i = iface(ifIndex);
            if (i == nullptr) continue;
            std::span<const std::uint8_t> bytes(buf, static_cast<std::size_t>(len));
            DnsMessage m;
            try {
                m = decode(bytes);
            } catch (const DnsError&) {
                continue;  // malformed: dropped
            }
            if (m.isResponse()) {
                if (!ours(bytes)) onResponse(m, *i);
            } else {
                onQuery(m, *i, src);
            }
        }
    }

    // ---- responder -----------------------------------------------------------------
    void onQuery(const DnsMessage& q, const Interface& i, const sockaddr_in& src) {
        const bool legacy = ntohs(src.sin_port) != cfg.port;
        bool unicast = legacy;
        bool shared = false;
        std::vector<ResourceRecord> answers, additionals;
        std::vector<PublicationId> from;
        notePeerProbes(q);
        for (const auto& qu : q.questions) {
            if (qu.qclass != kClassIn && qu.qclass != 255) continue;
            std::size_t before = answers.size();
            auto match = [&qu](const std::string& name, std::uint16_t type) {
                return (qu.type == type || qu.type == rrtype::ANY) && namesEqual(qu.name, name);
            };
            for (const auto& [id, p] : pubs) {
                const std::size_t had = answers.size() + additionals.size();
                if (match(kServicesName, rrtype::PTR)) {
                    addUnique(answers, mdns::ptrRecord(kServicesName, p.typeName(), cfg.otherTtl));
                    shared = true;
                }
                if (match(p.typeName(), rrtype::PTR)) {
                    addUnique(answers, ptrRecord(p));
                    addUnique(additionals, srvRecord(p));
                    addUnique(additionals, txtRecord(p));
                    addUnique(additionals, aRecord(p, i));
                    shared = true;
                }
                if (match(p.instanceName(), rrtype::SRV)) {
                    addUnique(answers, srvRecord(p));
                    addUnique(additionals, aRecord(p, i));
                }
                if (match(p.instanceName(), rrtype::TXT)) addUnique(answers, txtRecord(p));
                if (match(p.hostName(), rrtype::A)) addUnique(answers, aRecord(p, i));
                if (answers.size() + additionals.size() > had) from.push_back(id);
            }
            if (answers.size() > before && qu.unicastResponse) unicast = true;
        }
        // Known-answer suppression (RFC 6762 §7.1).
        std::erase_if(answers, [&q](const ResourceRecord& rr) {
            return std::any_of(q.answers.begin(), q.answers.end(), [&rr](const auto& k) {
                return sameRecord(k, rr) && k.ttl >= rr.ttl / 2;
            });
        });
        if (answers.empty()) return;
        std::erase_if(additionals, [&answers](const ResourceRecord& rr) {
            return std::any_of(answers.begin(), answers.end(),
                               [&rr](const auto& a) { return sameRecord(a, rr); });
        });
        DnsMessage r = response(std::move(answers), std::move(additionals));
        if (legacy) {
            // RFC 6762 §6.7: same ID, question repeated, short TTLs, no cache-flush bits.
            r.id = q.id;
            r.questions = q.questions;
            for (auto* s : {&r.answers, &r.additionals}) {
                for (auto& rr : *s) {
                    rr.ttl = std::min(rr.ttl, kLegacyTtl);
                    rr.cacheFlush = false;
                }
            }
            for (auto& qu : r.questions) qu.unicastResponse = false;
        }
        if (unicast) {
            send(i.index, src, std::move(r));
            return;
        }
        TimePoint at{};
        if (shared) {
            std::uniform_int_distribution<int> d(20, 120);  // RFC 6762 §6
            at = Clock::now() + milliseconds(d(rng));
        }
        send(i.index, groupAddr(), std::move(r), at, from);
    }

    // Remembers the SRV records in others' probes (authority section) for a while.
    void notePeerProbes(const DnsMessage& q) {
        for (const auto& rr : q.authorities) {
            if (rr.type != rrtype::SRV) continue;
            recentProbes.emplace_back(lowerName(rr.name), canonicalRdata(rr), Clock::now());
            if (recentProbes.size() > kMaxRecentProbes) recentProbes.pop_front();
            checkConflict(rr, true);
        }
    }

    bool recentlyProbed(const ResourceRecord& rr) {
        auto now = Clock::now();
        auto name = lowerName(rr.name);
        auto data = canonicalRdata(rr);
        return std::any_of(recentProbes.begin(), recentProbes.end(), [&](const auto& e) {
            return std::get<0>(e) == name && std::get<1>(e) == data &&
                   now - std::get<2>(e) < kPeerProbeWindow;
        });
    }

    // Another host uses one of our instance names with other SRV data (RFC 6762 §8.2, §9).
    // A probing side loses to an established one; otherwise the lexicographically later
    // SRV rdata wins. Differing TXT alone is not a conflict (see README).
    void checkConflict(const ResourceRecord& theirs, bool isProbe) {
        if (theirs.type != rrtype::SRV || theirs.ttl == 0) return;
        for (auto& [id, p] : pubs) {
            if (!namesEqual(theirs.name, p.instanceName())) continue;
            auto mine = canonicalRdata(srvRecord(p));
            auto other = canonicalRdata(theirs);
            if (mine == other) return;
            bool theyProbe = isProbe || recentlyProbed(theirs);
            bool lose = false;
            if (p.probing() && !theyProbe) {
                lose = true;
            } else if (!p.probing() && theyProbe) {
                // Defend at once, but not once per packet of a probe flood.
                if (Clock::now() - p.lastDefence >= kProbeInterval) {
                    p.lastDefence = Clock::now();
                    announce(p, 0);
                }
            } else {
                lose = std::lexicographical_compare(mine.begin(), mine.end(), other.begin(),
                                                    other.end());
            }
            if (lose) rename(p);
            return;
        }
    }

    void rename(Publication& p) {
        goodbye(p, false);
        p.rec.instance = renamed(p.baseInstance, ++p.renames);
        p.probesSent = 0;
        p.nextProbe = Clock::now();
        p.announcements.clear();
        scheduleAnnouncements(p, 0);
        if (p.onRename) {
            callbacks.emplace_back(p.id, [f = p.onRename, n = p.rec.instance] { f(n); });
        }
    }

    // ---- cache ---------------------------------------------------------------------
    void onResponse(const DnsMessage& m, const Interface& i) {
        auto now = Clock::now();
        for (const auto* s : {&m.answers, &m.additionals}) {
            for (const auto& rr : *s) {
                if (rr.rrclass != kClassIn) continue;
                checkConflict(rr, false);
                store(rr, i.index, now);
            }
        }
    }

    void store(const ResourceRecord& rr, int ifIndex, TimePoint now) {
        auto key = [&](const CacheEntry& e) {
            return e.ifIndex == ifIndex && e.rr.type == rr.type && namesEqual(e.rr.name, rr.name);
        };
        bool found = false;
        for (auto& e : cache) {
            if (!key(e)) continue;
            if (sameRdata(e.rr, rr)) {
                found = true;
                if (rr.ttl == 0) {
                    e.goodbye = true;
                    e.expires = std::min(e.expires, now + kGoodbyeGrace);
                } else {
                    e.rr.ttl = rr.ttl;
                    e.received = now;
                    e.expires = now + seconds(rr.ttl);
                    e.refreshStage = 0;
                    e.goodbye = e.flushed = false;
                }
            } else if (rr.cacheFlush && rr.ttl != 0 && now - e.received > kFlushGrace) {
                e.flushed = true;
                e.expires = std::min(e.expires, now + kFlushGrace);
            }
        }
        if (found || rr.ttl == 0) return;
        if (cache.size() >= kMaxCacheRecords) {
            auto oldest = std::min_element(cache.begin(), cache.end(), [](auto& a, auto& b) {
                return a.received < b.received;
            });
            cache.erase(oldest);
        }
        CacheEntry e;
        e.ifIndex = ifIndex;
        e.rr = rr;
        e.received = now;
        e.expires = now + seconds(rr.ttl);
        cache.push_back(std::move(e));
    }

    // Live SRV / TXT / A entries by (interface, lower-cased name, type): resolve() stays
    // O(n log n) with a full cache.
    using Index =
        std::map<std::tuple<int, std::string, std::uint16_t>, std::vector<const CacheEntry*>>;
    Index liveIndex() const {
        Index idx;
        for (const auto& e : cache) {
            if (e.goodbye || e.flushed) continue;
            if (e.rr.type != rrtype::SRV && e.rr.type != rrtype::TXT && e.rr.type != rrtype::A) {
                continue;
            }
            idx[{e.ifIndex, lowerName(e.rr.name), e.rr.type}].push_back(&e);
        }
        return idx;
    }

    static std::vector<const CacheEntry*> lookup(const Index& idx, int ifIndex,
                                                 const std::string& name, std::uint16_t type) {
        auto it = idx.find({ifIndex, lowerName(name), type});
        return it == idx.end() ? std::vector<const CacheEntry*>{} : it->second;
    }

    // The newest live entry for (interface, name, type), or null.
    static const CacheEntry* newest(const Index& idx, int ifIndex, const std::string& name,
                                    std::uint16_t type) {
        const CacheEntry* best = nullptr;
        for (const auto* e : lookup(idx, ifIndex, name, type)) {
            if (best == nullptr || e->received > best->received) best = e;
        }
        return best;
    }

    std::string ifaceName(int index) const {
        const Interface* i = iface(index);
        return i ? i->name : std::string();
    }

    // Every resolved service of `typeName` in the cache, keyed by interface|instance.
    // Also reports the PTR targets that still lack SRV, TXT or A (to be asked for).
    std::map<std::string, DiscoveredService> resolve(
        const std::string& type, const std::string& typeName,
        std::vector<std::pair<int, Question>>* missing = nullptr) const {
        std::map<std::string, DiscoveredService> out;
        const Index idx = liveIndex();
        for (const auto& e : cache) {
            if (e.rr.type != rrtype::PTR || e.goodbye || !namesEqual(e.rr.name, typeName)) {
                continue;
            }
            std::vector<std::string> labels;
            try {
                labels = splitName(e.rr.ptr);
            } catch (const DnsError&) {
                continue;
            }
            if (labels.size() < 2) continue;
            const std::string& inst = e.rr.ptr;
            const CacheEntry* srv = newest(idx, e.ifIndex, inst, rrtype::SRV);
            const CacheEntry* txt = newest(idx, e.ifIndex, inst, rrtype::TXT);
            if (missing && (!srv || !txt)) {
                missing->push_back({e.ifIndex, Question{inst, rrtype::ANY, kClassIn, false}});
            }
            if (!srv || !txt) continue;
            DiscoveredService s;
            for (const auto* a : lookup(idx, e.ifIndex, srv->rr.srv.target, rrtype::A)) {
                s.addresses.push_back(ipv4Text(a->rr.ipv4));
            }
            if (s.addresses.empty()) {
                if (missing) {
                    missing->push_back(
                        {e.ifIndex, Question{srv->rr.srv.target, rrtype::A, kClassIn, false}});
                }
                continue;
            }
            std::sort(s.addresses.begin(), s.addresses.end());
            s.instance = labels[0];
            s.type = type;
            s.host = srv->rr.srv.target;
            s.port = srv->rr.srv.port;
            s.txt = txt->rr.txt;
            s.interfaceIndex = e.ifIndex;
            s.interfaceName = ifaceName(e.ifIndex);
            out[std::to_string(e.ifIndex) + "|" + lowerName(inst)] = std::move(s);
        }
        return out;
    }

    static bool sameService(const DiscoveredService& a, const DiscoveredService& b) {
        return a.host == b.host && a.port == b.port && a.txt == b.txt &&
               a.addresses == b.addresses && a.instance == b.instance;
    }

    // ---- timers --------------------------------------------------------------------
    void at(TimePoint t) { nextWake = std::min(nextWake, t); }

    void tick() {
        auto now = Clock::now();
        nextWake = now + seconds(1);
        if (now >= nextIfaceCheck) {
            updateInterfaces();
            // At least 10 ms: an interval of 0 would make the loop spin.
            nextIfaceCheck = now + std::max(cfg.interfaceCheckInterval, milliseconds(10));
        }
        at(nextIfaceCheck);
        tickPublications(now);
        tickOutgoing(now);
        std::erase_if(cache, [now](const CacheEntry& e) { return e.expires <= now; });
        for (const auto& e : cache) at(e.expires);
        tickQueries(now);
        report();
    }

    void tickPublications(TimePoint now) {
        for (auto& [id, p] : pubs) {
            // Probe first: a newcomer's probe must reach an established owner before the
            // announcement does (see checkConflict).
            if (p.probing() && now >= p.nextProbe) {
                probe(p);
                ++p.probesSent;
                p.nextProbe = now + kProbeInterval;
                if (p.probesSent == kProbeCount) p.probeEnd = p.nextProbe;
            }
            if (p.probesSent < kProbeCount) at(p.nextProbe);
            std::vector<int> due;
            std::erase_if(p.announcements, [&](const auto& a) {
                if (a.first > now) return false;
                if (std::find(due.begin(), due.end(), a.second) == due.end()) {
                    due.push_back(a.second);
                }
                return true;
            });
            if (std::find(due.begin(), due.end(), 0) != due.end()) due = {0};
            for (int i : due) announce(p, i);
            for (const auto& a : p.announcements) at(a.first);
        }
    }

    void tickOutgoing(TimePoint now) {
        std::vector<Outgoing> due;
        std::erase_if(outgoing, [&](Outgoing& o) {
            if (o.at > now) return false;
            due.push_back(std::move(o));
            return true;
        });
        for (const auto& o : due) sendRaw(o.ifIndex, o.dest, o.bytes);
        for (const auto& o : outgoing) at(o.at);
    }

    void query(int ifIndex, std::vector<Question> qs, std::vector<ResourceRecord> known) {
        DnsMessage m;
        m.questions = std::move(qs);
        m.answers = std::move(known);
        // Known answers that do not fit are left out (no TC continuation: see README).
        auto ps = packets(std::move(m));
        if (!ps.empty()) sendRaw(ifIndex, groupAddr(), ps.front());
    }

    void tickQueries(TimePoint now) {
        // A browse's first query and queryNow() set the QU bit (RFC 6762 §5.4: the first
        // query after start-up should): responders answer those at once by unicast, instead
        // of after the 20-120 ms delay of multicast answers to shared records — that delay
        // would be most of a Plug & Produce device's time to find its LDS-ME.
        std::set<std::string> types = std::move(oneShotQueries);
        std::set<std::string> unicastTypes = types;
        oneShotQueries.clear();
        for (auto& [id, b] : browses) {
            if (now >= b.nextQuery) {
                types.insert(b.typeName);
                if (!std::exchange(b.asked, true)) unicastTypes.insert(b.typeName);
                b.nextQuery = now + b.interval;
                b.interval = std::min<milliseconds>(b.interval * 2, kMaxQueryInterval);
            }
            at(b.nextQuery);
        }
        std::map<int, std::vector<Question>> questions;
        std::map<int, std::vector<ResourceRecord>> known;
        for (const auto& t : types) {
            for (const auto& i : ifaces) {
                questions[i.index].push_back({t, rrtype::PTR, kClassIn, unicastTypes.count(t) > 0});
                for (const auto& e : cache) {
                    if (e.ifIndex != i.index || e.rr.type != rrtype::PTR || e.goodbye ||
                        !namesEqual(e.rr.name, t)) {
                        continue;
                    }
                    // RFC 6762 §7.1: only answers with more than half their TTL left.
                    auto left = e.expires - now;
                    if (left > seconds(e.rr.ttl) / 2) {
                        auto k = e.rr;
                        k.ttl = static_cast<std::uint32_t>(
                            std::chrono::duration_cast<seconds>(left).count());
                        k.cacheFlush = false;
                        known[i.index].push_back(std::move(k));
                    }
                }
            }
        }
        tickRefreshAndResolve(now, questions);
        for (auto& [ifIndex, qs] : questions) query(ifIndex, std::move(qs), known[ifIndex]);
    }

    // Refresh queries at 80/85/90/95 % of the TTL (RFC 6762 §5.2) for the records browses
    // use, and resolve queries for browsed instances that lack SRV/TXT/A.
    void tickRefreshAndResolve(TimePoint now, std::map<int, std::vector<Question>>& qs) {
        std::set<std::tuple<int, std::string, std::uint16_t>> wanted;
        std::set<std::pair<int, std::string>> stillMissing;
        for (auto& [id, b] : browses) {
            std::vector<std::pair<int, Question>> missing;
            auto found = resolve(b.type, b.typeName, &missing);
            for (const auto& e : cache) {
                if (e.rr.type == rrtype::PTR && namesEqual(e.rr.name, b.typeName)) {
                    wanted.insert({e.ifIndex, lowerName(e.rr.name), rrtype::PTR});
                }
            }
            for (const auto& [key, s] : found) {
                (void)s;
                auto inst = key.substr(key.find('|') + 1);
                wanted.insert({s.interfaceIndex, inst, rrtype::SRV});
                wanted.insert({s.interfaceIndex, inst, rrtype::TXT});
                wanted.insert({s.interfaceIndex, lowerName(s.host), rrtype::A});
            }
            for (auto& [ifIndex, q] : missing) {
                auto key = std::make_pair(ifIndex, lowerName(q.name));
                stillMissing.insert(key);
                auto [it, fresh] = resolving.try_emplace(key, now, milliseconds(1000));
                if (now >= it->second.first) {
                    qs[ifIndex].push_back(q);
                    it->second.first = now + it->second.second;
                    it->second.second =
                        std::min<milliseconds>(it->second.second * 2, kMaxQueryInterval);
                }
                at(it->second.first);
            }
        }
        std::erase_if(resolving, [&](const auto& kv) { return !stillMissing.count(kv.first); });
        std::uniform_int_distribution<int> jitter(0, 20);  // 0-2 % of the TTL
        for (auto& e : cache) {
            if (e.goodbye || e.refreshStage >= 4) continue;
            if (!wanted.count({e.ifIndex, lowerName(e.rr.name), e.rr.type})) continue;
            auto ttl = std::chrono::duration_cast<milliseconds>(seconds(e.rr.ttl));
            auto due = e.received + ttl * (800 + 50 * e.refreshStage + jitter(rng)) / 1000;
            if (now >= due) {
                qs[e.ifIndex].push_back({e.rr.name, e.rr.type, kClassIn, false});
                ++e.refreshStage;
            } else {
                at(due);
            }
        }
        for (auto& [ifIndex, v] : qs) {
            std::vector<Question> unique;
            for (auto& q : v) {
                if (std::none_of(unique.begin(), unique.end(), [&](const Question& u) {
                        return u.type == q.type && namesEqual(u.name, q.name);
                    })) {
                    unique.push_back(std::move(q));
                }
            }
            v = std::move(unique);
        }
    }

    // Compares each browse's resolved services with what it reported; queues callbacks.
    void report() {
        for (auto& [id, b] : browses) {
            auto now = resolve(b.type, b.typeName);
            for (const auto& [key, s] : b.reported) {
                if (!now.count(key)) {
                    callbacks.emplace_back(b.id, [f = b.callback, s] { f(s, false); });
                }
            }
            for (const auto& [key, s] : now) {
                auto it = b.reported.find(key);
                if (it == b.reported.end() || !sameService(it->second, s)) {
                    callbacks.emplace_back(b.id, [f = b.callback, s] { f(s, true); });
                }
            }
            b.reported = std::move(now);
        }
    }

    // ---- thread --------------------------------------------------------------------
    void run() {
        std::unique_lock lock(mu);
        threadId = std::this_thread::get_id();
        while (!stopping) {
            tick();
            deliver(lock);
            auto wait = std::max<milliseconds>(
                milliseconds(0), std::chrono::ceil<milliseconds>(nextWake - Clock::now()));
            lock.unlock();
            pollfd fds[3] = {{sock, POLLIN, 0}, {wake, POLLIN, 0}, {netlink, POLLIN, 0}};
            int r = ::poll(fds, netlink >= 0 ? 3 : 2, static_cast<int>(wait.count()));
            lock.lock();
            if (r <= 0) continue;
            if (fds[1].revents) {
                std::uint64_t v;
                [[maybe_unused]] auto n = ::read(wake, &v, sizeof v);
            }
            if (netlink >= 0 && fds[2].revents) {
                drainNetlink();
                nextIfaceCheck = Clock::now();  // rescan at once
            }
            if (fds[0].revents) receive();
        }
        for (const auto& [id, p] : pubs) goodbye(p, true);
        outgoing.clear();  // delayed answers would bring the records back
        deliver(lock);
    }

    // Runs the queued callbacks without the lock (held on entry and on return).
    void deliver(std::unique_lock<std::mutex>& lock) {
        if (callbacks.empty()) return;
        auto cbs = std::move(callbacks);
        callbacks.clear();
        delivering = true;
        for (auto& [owner, f] : cbs) {
            if (!pubs.count(owner) && !browses.count(owner)) continue;
            lock.unlock();
            f();
            lock.lock();
        }
        delivering = false;
        delivered.notify_all();
    }

    // After a browse or publication is removed: no callback of it runs after this returns
    // (unless called from a callback, which cannot wait for itself).
    void waitForDelivery(std::unique_lock<std::mutex>& lock) {
        if (std::this_thread::get_id() == threadId) return;
        delivered.wait(lock, [this] { return !delivering; });
    }

    void openSockets() {
        sock = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
        if (sock < 0) throwErrno("mdns: socket");
        int one = 1, zero = 0, ttl = 255;
        // Shared port: avahi-daemon or another process may listen on it too.
        ::setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
        ::setsockopt(sock, SOL_SOCKET, SO_REUSEPORT, &one, sizeof one);
        ::setsockopt(sock, IPPROTO_IP, IP_PKTINFO, &one, sizeof one);
        ::setsockopt(sock, IPPROTO_IP, IP_MULTICAST_TTL, &ttl, sizeof ttl);
        ::setsockopt(sock, IPPROTO_IP, IP_TTL, &ttl, sizeof ttl);
        // Loop on: two processes on one host see each other (our own copies are ignored).
        ::setsockopt(sock, IPPROTO_IP, IP_MULTICAST_LOOP, &one, sizeof one);
        // Only the groups joined on this socket, not every group any socket joined.
        ::setsockopt(sock, IPPROTO_IP, IP_MULTICAST_ALL, &zero, sizeof zero);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_port = htons(cfg.port);
        a.sin_addr.s_addr = htonl(INADDR_ANY);
        if (::bind(sock, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
            int e = errno;
            closeSockets();
            errno = e;
            throwErrno("mdns: bind");
        }
        wake = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
        if (wake < 0) {
            closeSockets();
            throwErrno("mdns: eventfd");
        }
        // Netlink for immediate interface/address changes; the periodic scan remains.
        netlink = ::socket(AF_NETLINK, SOCK_RAW | SOCK_CLOEXEC | SOCK_NONBLOCK, NETLINK_ROUTE);
        if (netlink >= 0) {
            sockaddr_nl nl{};
            nl.nl_family = AF_NETLINK;
            nl.nl_groups = RTMGRP_LINK | RTMGRP_IPV4_IFADDR;
            if (::bind(netlink, reinterpret_cast<sockaddr*>(&nl), sizeof nl) != 0) {
                ::close(netlink);
                netlink = -1;
            }
        }
    }

    void closeSockets() {
        for (int* fd : {&sock, &wake, &netlink}) {
            if (*fd >= 0) ::close(*fd);
            *fd = -1;
        }
    }
};

// ---- public API ----------------------------------------------------------------------

Mdns::Mdns(MdnsConfig config) : impl_(std::make_unique<Impl>(std::move(config))) {}

Mdns::~Mdns() { stop(); }

void Mdns::start() {
    std::lock_guard lock(impl_->mu);
    if (impl_->running) return;
    impl_->openSockets();
    impl_->stopping = false;
    impl_->ifaces.clear();
    impl_->nextIfaceCheck = Clock::now();
    for (auto& [id, p] : impl_->pubs) {
        p.probesSent = 0;
        p.nextProbe = Clock::now();
        p.announcements.clear();
        impl_->scheduleAnnouncements(p, 0);
    }
    for (auto& [id, b] : impl_->browses) {
        b.nextQuery = Clock::now();
        b.interval = milliseconds(1000);
        b.asked = false;
    }
    impl_->running = true;
    impl_->thread = std::thread([this] { impl_->run(); });
}

void Mdns::stop() {
    {
        std::lock_guard lock(impl_->mu);
        if (!impl_->running || impl_->stopping) return;  // not started, or another stop()
        impl_->stopping = true;
        impl_->wakeUp();
    }
    impl_->thread.join();
    std::lock_guard lock(impl_->mu);
    impl_->running = false;
    impl_->closeSockets();
    impl_->ifaces.clear();
    impl_->cache.clear();
    impl_->outgoing.clear();
    for (auto& [id, b] : impl_->browses) b.reported.clear();
}

Mdns::PublicationId Mdns::publish(ServiceRecord record,
                                  std::function<void(const std::string&)> onRename) {
    Publication p;
    p.rec = std::move(record);
    p.baseInstance = p.rec.instance;
    p.onRename = std::move(onRename);
    if (p.rec.address) {
        in_addr a;
        if (::inet_pton(AF_INET, p.rec.address->c_str(), &a) != 1) {
            throw std::invalid_argument("mdns: bad IPv4 address " + *p.rec.address);
        }
    }
    // Labels of 1-63 bytes (a rename shortens the base to fit " (n)"); the rest must encode.
    if (p.rec.instance.empty() || p.rec.instance.size() > kMaxLabelLength || p.rec.host.empty() ||
        p.rec.host.size() > kMaxLabelLength) {
        throw std::invalid_argument("mdns: instance or host label empty or too long");
    }
    try {
        Interface none;
        DnsMessage m = Impl::response(impl_->allRecords(p, none));
        encode(m);
    } catch (const DnsError& e) {
        throw std::invalid_argument(std::string("mdns: record cannot be encoded: ") + e.what());
    }
    std::lock_guard lock(impl_->mu);
    p.id = impl_->nextId++;
    p.nextProbe = Clock::now();
    impl_->scheduleAnnouncements(p, 0);
    auto id = p.id;
    impl_->pubs.emplace(id, std::move(p));
    impl_->wakeUp();
    return id;
}

void Mdns::update(PublicationId id, std::vector<std::string> txt) {
    std::lock_guard lock(impl_->mu);
    auto it = impl_->pubs.find(id);
    if (it == impl_->pubs.end()) return;
    auto old = it->second.rec.txt;
    it->second.rec.txt = std::move(txt);
    try {
        encode(Impl::response({impl_->txtRecord(it->second)}));
    } catch (const DnsError& e) {
        it->second.rec.txt = std::move(old);
        throw std::invalid_argument(std::string("mdns: TXT cannot be encoded: ") + e.what());
    }
    impl_->scheduleAnnouncements(it->second, 0);
    impl_->wakeUp();
}

void Mdns::withdraw(PublicationId id) {
    std::unique_lock lock(impl_->mu);
    auto it = impl_->pubs.find(id);
    if (it == impl_->pubs.end()) return;
    // Sent from this thread: sends are non-blocking and made under the lock, like the
    // engine thread's.
    impl_->goodbye(it->second, true);
    impl_->pubs.erase(it);
    impl_->wakeUp();
    impl_->waitForDelivery(lock);
}

Mdns::BrowseId Mdns::browse(std::string type,
                            std::function<void(const DiscoveredService&, bool)> callback) {
    std::lock_guard lock(impl_->mu);
    Browse b;
    b.id = impl_->nextId++;
    b.typeName = lowerName(type + ".local");
    b.type = std::move(type);
    b.callback = std::move(callback);
    b.nextQuery = Clock::now();
    auto id = b.id;
    impl_->browses.emplace(id, std::move(b));
    impl_->wakeUp();
    return id;
}

void Mdns::stopBrowse(BrowseId id) {
    std::unique_lock lock(impl_->mu);
    impl_->browses.erase(id);
    impl_->waitForDelivery(lock);
}

std::vector<DiscoveredService> Mdns::services(const std::string& type) const {
    std::lock_guard lock(impl_->mu);
    std::vector<DiscoveredService> out;
    for (auto& [key, s] : impl_->resolve(type, lowerName(type + ".local"))) out.push_back(s);
    return out;
}

void Mdns::queryNow(const std::string& type) {
    std::lock_guard lock(impl_->mu);
    impl_->oneShotQueries.insert(lowerName(type + ".local"));
    for (auto& [id, b] : impl_->browses) {
        if (namesEqual(b.type, type)) b.interval = milliseconds(1000);
    }
    impl_->wakeUp();
}

std::vector<std::string> Mdns::interfaceNames() const {
    std::lock_guard lock(impl_->mu);
    std::vector<std::string> out;
    for (const auto& i : impl_->ifaces) out.push_back(i.name);
    return out;
}

}  // namespace pnp::mdns
