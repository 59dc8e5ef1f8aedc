#include "ua/discovery/txt_record.hpp"

#include <arpa/inet.h>

#include <algorithm>
#include <cctype>
#include <cstdlib>

namespace pnp::ua::discovery {
namespace {
constexpr std::size_t kMaxCapabilities = 64;

std::string upper(std::string s) {
    for (auto& c : s) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
    return s;
}
}  // namespace

Announcement parseTxt(const std::vector<std::string>& txt) {
    Announcement a;
    for (const auto& entry : txt) {
        const auto eq = entry.find('=');
        if (eq == std::string::npos) continue;
        const std::string key = upper(entry.substr(0, eq));
        const std::string value = entry.substr(eq + 1);
        if (key == "PATH") {
            a.path = value.empty() || value.front() == '/' ? value : "/" + value;
            if (a.path == "/") a.path.clear();
        } else if (key == "CAPS") {
            std::size_t start = 0;
            while (start <= value.size() && a.capabilities.size() < kMaxCapabilities) {
                auto comma = value.find(',', start);
                if (comma == std::string::npos) comma = value.size();
                std::string cap = upper(value.substr(start, comma - start));
                if (!cap.empty()) a.capabilities.push_back(std::move(cap));
                start = comma + 1;
            }
        } else if (key == "DG") {
            a.group = value;
        } else if (key == "LVL") {
            char* end = nullptr;
            const long v = std::strtol(value.c_str(), &end, 10);
            if (end && *end == '\0' && !value.empty() && v >= 0 && v <= 100)
                a.level = static_cast<int>(v);
        }
    }
    return a;
}

std::vector<std::string> makeTxt(const Announcement& a) {
    std::vector<std::string> txt{"path=" + (a.path.empty() ? std::string("/") : a.path)};
    std::string caps;
    for (const auto& c : a.capabilities) caps += (caps.empty() ? "" : ",") + upper(c);
    txt.push_back("caps=" + caps);
    if (!a.group.empty()) txt.push_back("dg=" + a.group);
    if (a.level) txt.push_back("lvl=" + std::to_string(*a.level));
    return txt;
}

bool hasCapability(const std::vector<std::string>& caps, const std::string& cap) {
    const std::string want = upper(cap);
    return std::any_of(caps.begin(), caps.end(), [&](const auto& c) { return upper(c) == want; });
}

std::string discoveryUrl(const std::string& host, unsigned port, const std::string& path) {
    const bool v6 = host.find(':') != std::string::npos;
    return "opc.tcp://" + (v6 ? "[" + host + "]" : host) + ":" + std::to_string(port) + path;
}

std::string urlHost(const std::string& srvTarget, const std::vector<std::string>& addresses) {
    std::string literal = srvTarget;
    if (!literal.empty() && literal.back() == '.') literal.pop_back();
    in_addr a{};
    if (::inet_pton(AF_INET, literal.c_str(), &a) == 1) return literal;
    return addresses.empty() ? srvTarget : addresses.front();
}

std::string dnsLabel(const std::string& text) {
    std::string out;
    for (unsigned char c : text) {
        if (out.size() >= 63) break;
        out += std::isalnum(c) || c == '-' ? static_cast<char>(c) : '-';
    }
    if (out.empty()) out = "pnp";
    return out;
}

}  // namespace pnp::ua::discovery
