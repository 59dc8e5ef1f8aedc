#include "output.hpp"

#include <algorithm>

namespace pnp::cli {

std::size_t displayWidth(const std::string& s) {
    std::size_t n = 0;
    for (char c : s)
        if ((static_cast<unsigned char>(c) & 0xC0) != 0x80) ++n;  // count lead bytes only
    return n;
}

namespace {
std::string oneLine(std::string s) {
    for (auto& c : s)
        if (c == '\n' || c == '\r' || c == '\t') c = ' ';
    return s;
}
}  // namespace

void Table::print(std::ostream& out) const {
    std::vector<std::size_t> width(headers_.size(), 0);
    auto measure = [&](const std::vector<std::string>& row) {
        for (std::size_t i = 0; i < row.size() && i < width.size(); ++i)
            width[i] = std::max(width[i], displayWidth(oneLine(row[i])));
    };
    measure(headers_);
    for (const auto& r : rows_) measure(r);
    auto line = [&](const std::vector<std::string>& row) {
        std::string s;
        for (std::size_t i = 0; i < width.size(); ++i) {
            std::string cell = i < row.size() ? oneLine(row[i]) : std::string();
            s += cell;
            if (i + 1 < width.size()) s.append(width[i] - displayWidth(cell) + 2, ' ');
        }
        while (!s.empty() && s.back() == ' ') s.pop_back();
        out << s << '\n';
    };
    line(headers_);
    for (const auto& r : rows_) line(r);
}

}  // namespace pnp::cli
