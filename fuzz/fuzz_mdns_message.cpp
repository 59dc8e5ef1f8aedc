// fuzz_mdns_message: the mDNS / DNS-SD message decoder (pnp_mdns, dns_message.hpp).
//
// Input: one UDP payload as received on port 5353.
//
// Checks (abort = a finding):
//   - sanitizers (ASan, UBSan, LSan) and libFuzzer's timeout / rss limits: decode() must
//     reject anything malformed with DnsError, never read outside the input;
//   - a decoded message encodes again (decode only accepts what encode can write), and
//     encoding is stable: encode(decode(encode(m))) == encode(m);
//   - canonicalRdata() of every decoded record works (the engine compares records with it).
//
// Seeds: fuzz_mdns_message -pnp_write_seeds=<dir> (see fuzz_support.hpp): an announcement,
// a browse query with a known answer, a probe and a legacy unicast query.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "fuzz_support.hpp"
#include "mdns/dns_message.hpp"

using namespace pnp::mdns;
using pnp::fuzz::check;

namespace {

void makeSeeds(pnp::fuzz::SeedWriter& w) {
    const std::string type = "_opcua-tcp._tcp.local";
    const std::string inst = "robot-1." + type;
    auto ptr = ptrRecord(type, inst, 120);
    auto srv = srvRecord(inst, {0, 0, 4840, "robot-1-host.local"}, 120, true);
    auto txt = txtRecord(inst, {"path=/", "caps=LDS,DA"}, 120, true);
    auto a = aRecord("robot-1-host.local", {10, 0, 0, 1}, 120, true);
    ResourceRecord aaaa = a;
    aaaa.type = rrtype::AAAA;
    aaaa.ipv6[0] = 0xfe;
    aaaa.ipv6[1] = 0x80;
    ResourceRecord nsec = a;
    nsec.type = rrtype::NSEC;
    nsec.raw = {0xC0, 0x0C, 0x00, 0x01, 0x40};

    DnsMessage announce;
    announce.flags = DnsMessage::kResponseFlag | DnsMessage::kAuthoritativeFlag;
    announce.answers = {ptr, srv, txt, a};
    announce.additionals = {aaaa, nsec};
    w.add("announce", encode(announce));

    DnsMessage query;
    query.questions.push_back({type, rrtype::PTR, kClassIn, true});
    query.answers = {ptr};
    w.add("query-known-answer", encode(query));

    DnsMessage probe;
    probe.questions.push_back({inst, rrtype::ANY, kClassIn, true});
    probe.authorities = {srv, txt};
    w.add("probe", encode(probe));

    DnsMessage legacy;
    legacy.id = 0x4242;
    legacy.questions.push_back({"_services._dns-sd._udp.local", rrtype::PTR, kClassIn, false});
    w.add("legacy-query", encode(legacy));
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int* argc, char*** argv) {
    pnp::fuzz::handleSeedFlag(argc, argv, makeSeeds);
    return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    DnsMessage m;
    try {
        m = decode({data, size});
    } catch (const DnsError&) {
        return 0;
    }
    std::vector<std::uint8_t> once;
    try {
        once = encode(m);
    } catch (const DnsError& e) {
        pnp::fuzz::fail("a decoded message does not encode", e.what());
    }
    for (const auto* s : {&m.answers, &m.authorities, &m.additionals}) {
        for (const auto& r : *s) canonicalRdata(r);
    }
    try {
        check(encode(decode(once)) == once, "encoding is not stable");
    } catch (const DnsError& e) {
        pnp::fuzz::fail("an encoded message does not decode", e.what());
    }
    return 0;
}
