#include "kb/store.hpp"

#include <cstdio>

namespace pnp::kb {

std::string escapeString(std::string_view s) {
    std::string out;
    out.reserve(s.size() + 2);
    for (unsigned char c : s) {
        switch (c) {
            case '\\':
                out += "\\\\";
                break;
            case '"':
                out += "\\\"";
                break;
            case '\n':
                out += "\\n";
                break;
            case '\r':
                out += "\\r";
                break;
            case '\t':
                out += "\\t";
                break;
            default:
                if (c < 0x20 || c == 0x7f) {
                    char buf[12];
                    std::snprintf(buf, sizeof buf, "\\u%04X", c);
                    out += buf;
                } else {
                    out += static_cast<char>(c);
                }
        }
    }
    return out;
}

std::string toNTriples(const Term& term) {
    switch (term.kind) {
        case Term::Kind::Iri:
            return "<" + term.value + ">";
        case Term::Kind::Blank:
            return "_:" + term.value;
        case Term::Kind::Literal: {
            std::string out = "\"" + escapeString(term.value) + "\"";
            if (!term.lang.empty()) {
                out += "@" + term.lang;
            } else if (!term.datatype.empty()) {
                out += "^^<" + term.datatype + ">";
            }
            return out;
        }
    }
    return {};
}

std::string termKey(const Term& term) {
    std::string key;
    key.reserve(term.value.size() + term.datatype.size() + term.lang.size() + 3);
    key += static_cast<char>('0' + static_cast<int>(term.kind));
    key += term.value;
    if (term.kind == Term::Kind::Literal) {
        key += '\x1f';
        key += term.datatype;
        key += '\x1f';
        key += term.lang;
    }
    return key;
}

QuadStore::QuadStore() { terms_.emplace_back(); }

TermId QuadStore::intern(const Term& term) {
    auto key = termKey(term);
    auto it = ids_.find(key);
    if (it != ids_.end()) return it->second;
    auto id = static_cast<TermId>(terms_.size());
    terms_.push_back(term);
    ids_.emplace(std::move(key), id);
    return id;
}

TermId QuadStore::find(const Term& term) const {
    auto it = ids_.find(termKey(term));
    return it == ids_.end() ? kNoTerm : it->second;
}

bool QuadStore::insert(const Quad& q) {
    if (!spog_.insert({q.s, q.p, q.o, q.g}).second) return false;
    posg_.insert({q.p, q.o, q.s, q.g});
    ospg_.insert({q.o, q.s, q.p, q.g});
    ++graphSizes_[q.g];
    return true;
}

bool QuadStore::erase(const Quad& q) {
    if (spog_.erase({q.s, q.p, q.o, q.g}) == 0) return false;
    posg_.erase({q.p, q.o, q.s, q.g});
    ospg_.erase({q.o, q.s, q.p, q.g});
    if (--graphSizes_[q.g] == 0) graphSizes_.erase(q.g);
    return true;
}

std::size_t QuadStore::clearGraph(TermId g) {
    std::vector<Quad> doomed;
    for (const auto& k : spog_) {
        if (k[3] == g) doomed.push_back({k[0], k[1], k[2], k[3]});
    }
    for (const auto& q : doomed) erase(q);
    return doomed.size();
}

void QuadStore::clearAll() {
    spog_.clear();
    posg_.clear();
    ospg_.clear();
    graphSizes_.clear();
}

std::vector<TermId> QuadStore::graphs() const {
    std::vector<TermId> out;
    out.reserve(graphSizes_.size());
    for (const auto& [g, n] : graphSizes_) out.push_back(g);
    return out;
}

void QuadStore::match(TermId s, TermId p, TermId o, TermId g,
                      const std::function<bool(const Quad&)>& visit) const {
    // Pick the index whose key starts with the most bound positions.
    const std::set<Key>* index = &spog_;
    Key lo{0, 0, 0, 0};
    int prefix = 0;
    int order = 0;  // 0 spog, 1 posg, 2 ospg
    if (s != kNoTerm && p != kNoTerm) {
        lo = {s, p, o, 0};
        prefix = o != kNoTerm ? 3 : 2;
    } else if (s != kNoTerm && o != kNoTerm) {
        index = &ospg_, order = 2, lo = {o, s, 0, 0}, prefix = 2;
    } else if (s != kNoTerm) {
        lo = {s, 0, 0, 0}, prefix = 1;
    } else if (p != kNoTerm) {
        index = &posg_, order = 1, lo = {p, o, 0, 0}, prefix = o != kNoTerm ? 2 : 1;
    } else if (o != kNoTerm) {
        index = &ospg_, order = 2, lo = {o, 0, 0, 0}, prefix = 1;
    }
    Quad previous{};
    bool havePrevious = false;
    for (auto it = index->lower_bound(lo); it != index->end(); ++it) {
        const Key& k = *it;
        bool inRange = true;
        for (int i = 0; i < prefix; ++i) {
            if (k[i] != lo[i]) {
                inRange = false;
                break;
            }
        }
        if (!inRange) break;
        Quad q;
        if (order == 0) q = {k[0], k[1], k[2], k[3]};
        if (order == 1) q = {k[2], k[0], k[1], k[3]};
        if (order == 2) q = {k[1], k[2], k[0], k[3]};
        if ((s != kNoTerm && q.s != s) || (p != kNoTerm && q.p != p) ||
            (o != kNoTerm && q.o != o)) {
            continue;
        }
        if (g != kNoTerm) {
            if (q.g != g) continue;
        } else if (havePrevious && previous.s == q.s && previous.p == q.p && previous.o == q.o) {
            continue;  // the same triple in another graph: the union holds it once
        }
        previous = q;
        havePrevious = true;
        if (!visit(q)) return;
    }
}

}  // namespace pnp::kb
