// The JSON objects a process printed, one per line (the harnesses' and the CLI's --json
// output): lines that are not an object are skipped.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

namespace pnp::testing {

inline std::vector<nlohmann::json> jsonLines(const std::string& text) {
    std::vector<nlohmann::json> v;
    std::size_t pos = 0;
    while (pos < text.size()) {
        std::size_t nl = text.find('\n', pos);
        if (nl == std::string::npos) nl = text.size();
        const std::string line = text.substr(pos, nl - pos);
        pos = nl + 1;
        if (line.empty() || line[0] != '{') continue;
        nlohmann::json j = nlohmann::json::parse(line, nullptr, false);
        if (j.is_object()) v.push_back(std::move(j));
    }
    return v;
}

}  // namespace pnp::testing
