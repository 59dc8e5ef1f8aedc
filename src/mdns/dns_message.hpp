// DNS message codec for mDNS / DNS-SD (RFC 1035 wire format with the RFC 6762 bits: the
// cache-flush bit in answers, the unicast-response bit in questions).
//
// Names are kept in presentation form: labels joined by '.', a '.' or '\' inside a label
// escaped with '\' (DNS-SD instance labels may contain dots). decode() never trusts the
// wire: every length, count and compression pointer is checked, errors throw DnsError.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace pnp::mdns {

class DnsError : public std::runtime_error {
  public:
    using std::runtime_error::runtime_error;
};

namespace rrtype {
constexpr std::uint16_t A = 1;
constexpr std::uint16_t PTR = 12;
constexpr std::uint16_t TXT = 16;
constexpr std::uint16_t AAAA = 28;
constexpr std::uint16_t SRV = 33;
constexpr std::uint16_t NSEC = 47;
constexpr std::uint16_t ANY = 255;
}  // namespace rrtype

constexpr std::uint16_t kClassIn = 1;
constexpr std::size_t kMaxNameLength = 255;  // wire length, including the root label
constexpr std::size_t kMaxLabelLength = 63;

struct Question {
    std::string name;
    std::uint16_t type = rrtype::PTR;
    std::uint16_t qclass = kClassIn;
    bool unicastResponse = false;  // QU bit (top bit of the class)
};

struct SrvData {
    std::uint16_t priority = 0;
    std::uint16_t weight = 0;
    std::uint16_t port = 0;
    std::string target;
};

// One resource record. Which rdata member is meaningful depends on `type`: A -> ipv4,
// AAAA -> ipv6, PTR -> ptr, SRV -> srv, TXT -> txt, anything else -> raw.
struct ResourceRecord {
    std::string name;
    std::uint16_t type = rrtype::A;
    std::uint16_t rrclass = kClassIn;
    bool cacheFlush = false;  // top bit of the class (answers only)
    std::uint32_t ttl = 0;
    std::array<std::uint8_t, 4> ipv4{};
    std::array<std::uint8_t, 16> ipv6{};
    std::string ptr;
    SrvData srv;
    std::vector<std::string> txt;
    std::vector<std::uint8_t> raw;
};

// Record builders (class IN).
ResourceRecord ptrRecord(std::string name, std::string target, std::uint32_t ttl);
ResourceRecord srvRecord(std::string name, SrvData srv, std::uint32_t ttl, bool cacheFlush);
ResourceRecord txtRecord(std::string name, std::vector<std::string> txt, std::uint32_t ttl,
                         bool cacheFlush);
ResourceRecord aRecord(std::string name, std::array<std::uint8_t, 4> address, std::uint32_t ttl,
                       bool cacheFlush);

struct DnsMessage {
    std::uint16_t id = 0;
    std::uint16_t flags = 0;
    std::vector<Question> questions;
    std::vector<ResourceRecord> answers;
    std::vector<ResourceRecord> authorities;
    std::vector<ResourceRecord> additionals;

    static constexpr std::uint16_t kResponseFlag = 0x8000;
    static constexpr std::uint16_t kAuthoritativeFlag = 0x0400;
    static constexpr std::uint16_t kTruncatedFlag = 0x0200;
    bool isResponse() const { return (flags & kResponseFlag) != 0; }
};

// Throws DnsError on any malformed input; never reads outside `bytes`.
DnsMessage decode(std::span<const std::uint8_t> bytes);
// Encodes with name compression. Throws DnsError for names/labels/strings that do not fit
// the wire format (label > 63, name > 255, TXT string > 255, rdata > 65535).
std::vector<std::uint8_t> encode(const DnsMessage& msg);
// The encoded rdata of one record (uncompressed names, lower-cased): used to compare
// records (conflict tie-break, RFC 6762 §8.2) and to tell rdata apart.
std::vector<std::uint8_t> canonicalRdata(const ResourceRecord& rr);

// ASCII case-insensitive comparison of names (RFC 6762 §16).
bool namesEqual(std::string_view a, std::string_view b);
std::string lowerName(std::string_view name);
// Presentation helpers: escape one label, split a name into raw labels (throws DnsError on
// a bad escape), join raw labels.
std::string escapeLabel(std::string_view label);
std::vector<std::string> splitName(std::string_view name);
std::string joinLabels(const std::vector<std::string>& labels, std::size_t from = 0);

bool sameRdata(const ResourceRecord& a, const ResourceRecord& b);

}  // namespace pnp::mdns
