// The evaluator of parsed SPARQL over a QuadStore. Solutions are rows of term ids (one column
// per query variable, kNoTerm = unbound). Groups are evaluated seeded: each element extends the
// solutions so far, which lets a triples block start from the variables already bound.
#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <regex>
#include <unordered_map>
#include <unordered_set>

#include "kb/sparql.hpp"
#include "kb/sparql_ast.hpp"

namespace pnp::kb {
namespace {

using namespace sparql;
using Row = std::vector<TermId>;
using Rows = std::vector<Row>;

// Ids of terms made by the query (constants not in the store, BIND results): above the store's.
constexpr TermId kLocalTermBase = 0x80000000u;

std::string xsd(const char* local) { return std::string(kXsd) + local; }

bool isNumericType(const std::string& dt) {
    static const std::unordered_set<std::string> numeric = {xsd("integer"),
                                                            xsd("decimal"),
                                                            xsd("double"),
                                                            xsd("float"),
                                                            xsd("int"),
                                                            xsd("long"),
                                                            xsd("short"),
                                                            xsd("byte"),
                                                            xsd("nonNegativeInteger"),
                                                            xsd("positiveInteger"),
                                                            xsd("negativeInteger"),
                                                            xsd("nonPositiveInteger"),
                                                            xsd("unsignedInt"),
                                                            xsd("unsignedLong"),
                                                            xsd("unsignedShort"),
                                                            xsd("unsignedByte")};
    return numeric.count(dt) != 0;
}
bool isNumeric(const Term& t) { return t.kind == Term::Kind::Literal && isNumericType(t.datatype); }
bool isIntegerType(const std::string& dt) {
    return isNumericType(dt) && dt != xsd("decimal") && dt != xsd("double") && dt != xsd("float");
}
bool isStringLiteral(const Term& t) {
    return t.kind == Term::Kind::Literal && t.datatype.empty() && t.lang.empty();
}

Term boolean(bool b) { return Term{Term::Kind::Literal, b ? "true" : "false", xsd("boolean"), ""}; }
Term plain(std::string s) { return Term{Term::Kind::Literal, std::move(s), "", ""}; }

std::string formatDouble(double d) {
    char buf[64];
    auto r = std::to_chars(buf, buf + sizeof buf, d);
    return std::string(buf, r.ptr);
}

class Evaluator {
  public:
    Evaluator(const QuadStore& store, const std::vector<std::string>& variables, Deadline deadline)
        : store_(store), width_(variables.size()), deadline_(deadline) {}

    const Term& term(TermId id) const {
        return id >= kLocalTermBase ? local_[id - kLocalTermBase] : store_.term(id);
    }
    TermId id(const Term& t) {
        TermId found = store_.find(t);
        if (found != kNoTerm) return found;
        auto key = termKey(t);
        auto it = localIds_.find(key);
        if (it != localIds_.end()) return it->second;
        auto fresh = static_cast<TermId>(kLocalTermBase + local_.size());
        local_.push_back(t);
        localIds_.emplace(std::move(key), fresh);
        return fresh;
    }
    std::size_t width() const { return width_; }

    Rows group(const GroupPattern& g, Rows input, TermId graph) {
        std::vector<const Expr*> filters;
        for (const auto& e : g.elements) {
            if (input.empty()) break;
            switch (e.kind) {
                case Element::Kind::Triples:
                    input = triples(e.triples, input, graph);
                    break;
                case Element::Kind::Filter:
                    filters.push_back(e.expr.get());
                    break;
                case Element::Kind::Optional: {
                    Rows out;
                    for (auto& row : input) {
                        Rows extended = group(e.groups[0], Rows{row}, graph);
                        if (extended.empty()) {
                            add(out, std::move(row));
                        } else {
                            for (auto& r : extended) add(out, std::move(r));
                        }
                    }
                    input = std::move(out);
                    break;
                }
                case Element::Kind::Union: {
                    Rows out;
                    for (const auto& branch : e.groups) {
                        for (auto& r : group(branch, input, graph)) add(out, std::move(r));
                    }
                    input = std::move(out);
                    break;
                }
                case Element::Kind::Group:
                    input = group(e.groups[0], std::move(input), graph);
                    break;
                case Element::Kind::Minus:
                    input = minus(e.groups[0], std::move(input), graph);
                    break;
                case Element::Kind::Bind: {
                    for (auto& row : input) {
                        if (row[e.var] != kNoTerm) {
                            throw KbError("SPARQL: BIND to ?" + name(e.var) +
                                          ", which is already bound");
                        }
                        auto v = eval(*e.expr, row, graph);
                        if (v) row[e.var] = id(*v);
                    }
                    break;
                }
                case Element::Kind::Values:
                    input = values(e, input);
                    break;
                case Element::Kind::Graph:
                    input = graphPattern(e, input);
                    break;
            }
        }
        if (filters.empty()) return input;
        Rows out;
        for (auto& row : input) {
            bool keep = true;
            for (const Expr* f : filters) {
                if (!ebv(eval(*f, row, graph)).value_or(false)) {
                    keep = false;
                    break;
                }
            }
            if (keep) out.push_back(std::move(row));
        }
        return out;
    }

    std::optional<Term> eval(const Expr& e, const Row& row, TermId graph);
    static std::optional<bool> ebv(const std::optional<Term>& v);
    // The ORDER BY order: unbound < blank < IRI < literal; numbers by value, else lexically.
    int orderCompare(TermId a, TermId b) const;

    void setNames(const std::vector<std::string>* names) { names_ = names; }
    void tick() {
        if (++ticks_ % 1024 == 0 && std::chrono::steady_clock::now() > deadline_) {
            throw KbError("SPARQL: deadline exceeded");
        }
    }
    void add(Rows& rows, Row row) {
        if (rows.size() >= kMaxIntermediateRows) {
            throw KbError("SPARQL: more than " + std::to_string(kMaxIntermediateRows) +
                          " intermediate solutions");
        }
        rows.push_back(std::move(row));
        tick();
    }

  private:
    std::string name(int var) const { return names_ ? (*names_)[var] : std::to_string(var); }

    // ---- triples blocks
    TermId resolve(const Node& n, const Row& row) {
        if (n.isVar()) return row[n.var];
        return id(n.term);
    }

    int score(const TriplePattern& t, const Row& row) {
        bool s = !t.s.isVar() || row[t.s.var] != kNoTerm;
        bool o = !t.o.isVar() || row[t.o.var] != kNoTerm;
        // A path from a bound end is a short search: before a pattern bound by its predicate
        // only, after one bound by a subject or object.
        if (t.path) return (s ? 6 : 0) + (o ? 5 : 0) - 3;
        bool p = !t.p.isVar() || row[t.p.var] != kNoTerm;
        return (s ? 8 : 0) + (o ? 6 : 0) + (p ? 1 : 0);
    }

    Rows triples(const std::vector<TriplePattern>& patterns, const Rows& input, TermId graph) {
        Rows out;
        std::vector<bool> done(patterns.size(), false);
        for (const auto& row : input) {
            Row r = row;
            joinNext(patterns, done, patterns.size(), r, out, graph);
        }
        return out;
    }

    bool bindOrCheck(const Node& n, TermId value, Row& row, std::vector<int>& bound) {
        if (!n.isVar()) return true;
        TermId& slot = row[n.var];
        if (slot == kNoTerm) {
            slot = value;
            bound.push_back(n.var);
            return true;
        }
        return slot == value;
    }

    // Matches the most selective remaining pattern, then recurses on the rest.
    void joinNext(const std::vector<TriplePattern>& patterns, std::vector<bool>& done,
                  std::size_t remaining, Row& row, Rows& out, TermId graph) {
        if (remaining == 0) {
            add(out, row);
            return;
        }
        std::size_t best = patterns.size();
        int bestScore = -1000;
        for (std::size_t i = 0; i < patterns.size(); ++i) {
            if (done[i]) continue;
            int sc = score(patterns[i], row);
            if (sc > bestScore) best = i, bestScore = sc;
        }
        const TriplePattern& t = patterns[best];
        done[best] = true;
        TermId s = resolve(t.s, row), o = resolve(t.o, row);
        if (t.path) {
            for (const auto& [a, b] : path(*t.path, s, o, graph)) {
                std::vector<int> bound;
                if (bindOrCheck(t.s, a, row, bound) && bindOrCheck(t.o, b, row, bound)) {
                    joinNext(patterns, done, remaining - 1, row, out, graph);
                }
                for (int v : bound) row[v] = kNoTerm;
            }
        } else {
            TermId p = resolve(t.p, row);
            // A constant the store has never seen matches nothing.
            bool absent = (s >= kLocalTermBase) || (p >= kLocalTermBase) || (o >= kLocalTermBase);
            if (!absent) {
                std::vector<Quad> matches;
                store_.match(s, p, o, graph, [&](const Quad& q) {
                    matches.push_back(q);
                    return true;
                });
                for (const auto& q : matches) {
                    std::vector<int> bound;
                    if (bindOrCheck(t.s, q.s, row, bound) && bindOrCheck(t.p, q.p, row, bound) &&
                        bindOrCheck(t.o, q.o, row, bound)) {
                        joinNext(patterns, done, remaining - 1, row, out, graph);
                    }
                    for (int v : bound) row[v] = kNoTerm;
                    tick();
                }
            }
        }
        done[best] = false;
    }

    // ---- property paths: the (start, end) pairs of `p` from s to o (kNoTerm = any)
    using Pairs = std::vector<std::pair<TermId, TermId>>;

    Pairs path(const Path& p, TermId s, TermId o, TermId graph) {
        Pairs out;
        switch (p.op) {
            case Path::Op::Link: {
                TermId pid = id(p.iri);
                if (pid >= kLocalTermBase || s >= kLocalTermBase || o >= kLocalTermBase) return out;
                store_.match(s, pid, o, graph, [&](const Quad& q) {
                    out.emplace_back(q.s, q.o);
                    tick();
                    return true;
                });
                return out;
            }
            case Path::Op::Inverse:
                for (const auto& [a, b] : path(*p.parts[0], o, s, graph)) out.emplace_back(b, a);
                return out;
            case Path::Op::Alternative:
                for (const auto& part : p.parts) {
                    auto more = path(*part, s, o, graph);
                    out.insert(out.end(), more.begin(), more.end());
                }
                return out;
            case Path::Op::Sequence:
                return sequence(p, s, o, graph);
            case Path::Op::ZeroOrMore:
            case Path::Op::OneOrMore:
            case Path::Op::ZeroOrOne:
                return closure(p, s, o, graph);
            case Path::Op::Negated: {
                auto excluded = [&](TermId pred, bool inverse) {
                    for (const auto& [iri, inv] : p.negated) {
                        if (inv == inverse && store_.find(iri) == pred) return true;
                    }
                    return false;
                };
                bool anyForward = false, anyInverse = false;
                for (const auto& n : p.negated) (n.second ? anyInverse : anyForward) = true;
                if (anyForward || !anyInverse) {
                    store_.match(s, kNoTerm, o, graph, [&](const Quad& q) {
                        if (!excluded(q.p, false)) out.emplace_back(q.s, q.o);
                        tick();
                        return true;
                    });
                }
                if (anyInverse) {
                    store_.match(o, kNoTerm, s, graph, [&](const Quad& q) {
                        if (!excluded(q.p, true)) out.emplace_back(q.o, q.s);
                        tick();
                        return true;
                    });
                }
                return out;
            }
        }
        return out;
    }

    Pairs sequence(const Path& p, TermId s, TermId o, TermId graph) {
        const auto& parts = p.parts;
        Pairs current;
        if (s == kNoTerm && o != kNoTerm) {
            // Walk backwards from the bound end.
            current = path(*parts.back(), kNoTerm, o, graph);
            for (std::size_t i = parts.size() - 1; i-- > 0;) {
                Pairs next;
                for (const auto& [mid, end] : current) {
                    for (const auto& [start, m] : path(*parts[i], kNoTerm, mid, graph)) {
                        (void)m;
                        next.emplace_back(start, end);
                        bound(next.size());
                    }
                }
                current = std::move(next);
            }
            return current;
        }
        current = path(*parts[0], s, parts.size() == 1 ? o : kNoTerm, graph);
        for (std::size_t i = 1; i < parts.size(); ++i) {
            Pairs next;
            TermId end = i + 1 == parts.size() ? o : kNoTerm;
            for (const auto& [start, mid] : current) {
                for (const auto& [m, e] : path(*parts[i], mid, end, graph)) {
                    (void)m;
                    next.emplace_back(start, e);
                    bound(next.size());
                }
            }
            current = std::move(next);
        }
        return current;
    }

    void bound(std::size_t n) const {
        if (n > kMaxIntermediateRows) {
            throw KbError("SPARQL: a property path with more than " +
                          std::to_string(kMaxIntermediateRows) + " solutions");
        }
    }

    // The nodes reachable from `from` by `step` zero/one-or-more/zero-or-one times (distinct).
    std::vector<TermId> reach(const Path& step, TermId from, bool forward, Path::Op op,
                              TermId graph) {
        std::vector<TermId> found;
        std::unordered_set<TermId> seen;
        if (op != Path::Op::OneOrMore) {
            seen.insert(from);
            found.push_back(from);
        }
        std::vector<TermId> frontier{from};
        std::unordered_set<TermId> expanded;
        while (!frontier.empty()) {
            std::vector<TermId> next;
            for (TermId n : frontier) {
                if (!expanded.insert(n).second) continue;
                Pairs steps =
                    forward ? path(step, n, kNoTerm, graph) : path(step, kNoTerm, n, graph);
                for (const auto& [a, b] : steps) {
                    TermId m = forward ? b : a;
                    if (seen.insert(m).second) {
                        found.push_back(m);
                        next.push_back(m);
                        if (seen.size() > kMaxPathNodes) {
                            throw KbError("SPARQL: a property path search visited more than " +
                                          std::to_string(kMaxPathNodes) + " nodes");
                        }
                    }
                }
            }
            if (op == Path::Op::ZeroOrOne) break;
            frontier = std::move(next);
        }
        return found;
    }

    Pairs closure(const Path& p, TermId s, TermId o, TermId graph) {
        Pairs out;
        const Path& step = *p.parts[0];
        if (s != kNoTerm) {
            for (TermId n : reach(step, s, true, p.op, graph)) {
                if (o == kNoTerm || n == o) out.emplace_back(s, n);
            }
            return out;
        }
        if (o != kNoTerm) {
            for (TermId n : reach(step, o, false, p.op, graph)) out.emplace_back(n, o);
            return out;
        }
        // Neither end bound: from every node of the graph (zero-length paths need them all).
        std::vector<TermId> nodes;
        std::unordered_set<TermId> seen;
        store_.match(kNoTerm, kNoTerm, kNoTerm, graph, [&](const Quad& q) {
            if (seen.insert(q.s).second) nodes.push_back(q.s);
            if (seen.insert(q.o).second) nodes.push_back(q.o);
            tick();
            return true;
        });
        for (TermId start : nodes) {
            for (TermId n : reach(step, start, true, p.op, graph)) {
                out.emplace_back(start, n);
                bound(out.size());
            }
        }
        return out;
    }

    // ---- other elements
    static bool compatible(const Row& a, const Row& b) {
        for (std::size_t i = 0; i < a.size(); ++i) {
            if (a[i] != kNoTerm && b[i] != kNoTerm && a[i] != b[i]) return false;
        }
        return true;
    }

    Rows minus(const GroupPattern& g, Rows input, TermId graph) {
        Rows removed = group(g, Rows{Row(width_, kNoTerm)}, graph);
        Rows out;
        for (auto& row : input) {
            bool drop = false;
            for (const auto& r : removed) {
                bool shared = false;
                for (std::size_t i = 0; i < row.size(); ++i) {
                    if (row[i] != kNoTerm && r[i] != kNoTerm) shared = true;
                }
                if (shared && compatible(row, r)) {
                    drop = true;
                    break;
                }
            }
            if (!drop) out.push_back(std::move(row));
        }
        return out;
    }

    Rows values(const Element& e, const Rows& input) {
        Rows out;
        for (const auto& row : input) {
            for (const auto& data : e.rows) {
                Row r = row;
                bool ok = true;
                for (std::size_t i = 0; i < e.vars.size() && ok; ++i) {
                    if (!data[i]) continue;
                    TermId v = id(*data[i]);
                    TermId& slot = r[e.vars[i]];
                    if (slot == kNoTerm) {
                        slot = v;
                    } else if (slot != v) {
                        ok = false;
                    }
                }
                if (ok) add(out, std::move(r));
            }
        }
        return out;
    }

    Rows graphPattern(const Element& e, const Rows& input) {
        Rows out;
        for (const auto& row : input) {
            TermId g = resolve(e.graph, row);
            if (g != kNoTerm) {
                if (g >= kLocalTermBase) continue;
                for (auto& r : group(e.groups[0], Rows{row}, g)) add(out, std::move(r));
                continue;
            }
            for (TermId name : store_.graphs()) {
                Row seeded = row;
                seeded[e.graph.var] = name;
                for (auto& r : group(e.groups[0], Rows{seeded}, name)) add(out, std::move(r));
            }
        }
        return out;
    }

    std::optional<Term> call(const Expr& e, const Row& row, TermId graph);

    const QuadStore& store_;
    std::size_t width_;
    Deadline deadline_;
    std::vector<Term> local_;
    std::unordered_map<std::string, TermId> localIds_;
    const std::vector<std::string>* names_ = nullptr;
    std::uint64_t ticks_ = 0;
};

std::optional<double> numberOf(const Term& t) {
    if (!isNumeric(t)) return std::nullopt;
    try {
        return t.number();
    } catch (const KbError&) {
        return std::nullopt;
    }
}

std::optional<bool> Evaluator::ebv(const std::optional<Term>& v) {
    if (!v || v->kind != Term::Kind::Literal) return std::nullopt;
    if (v->datatype == xsd("boolean")) return v->value == "true" || v->value == "1";
    if (isNumeric(*v)) {
        auto d = numberOf(*v);
        if (!d) return false;
        return *d != 0 && !std::isnan(*d);
    }
    if (v->datatype.empty()) return !v->value.empty();
    return std::nullopt;
}

// -1/0/1, or nullopt when the two cannot be ordered by < (SPARQL's operator mapping).
std::optional<int> valueCompare(const Term& a, const Term& b) {
    if (isNumeric(a) && isNumeric(b)) {
        auto x = numberOf(a), y = numberOf(b);
        if (!x || !y) return std::nullopt;
        return *x < *y ? -1 : (*x > *y ? 1 : 0);
    }
    bool bothStrings = isStringLiteral(a) && isStringLiteral(b);
    bool sameTyped = a.kind == Term::Kind::Literal && b.kind == Term::Kind::Literal &&
                     a.datatype == b.datatype && a.lang == b.lang &&
                     (a.datatype == xsd("dateTime") || a.datatype == xsd("date") ||
                      a.datatype == xsd("boolean") || !a.lang.empty());
    if (bothStrings || sameTyped) {
        int c = a.value.compare(b.value);
        return c < 0 ? -1 : (c > 0 ? 1 : 0);
    }
    return std::nullopt;
}

std::optional<bool> termEquals(const Term& a, const Term& b) {
    if (isNumeric(a) && isNumeric(b)) {
        auto c = valueCompare(a, b);
        if (!c) return std::nullopt;
        return *c == 0;
    }
    return a == b;
}

Term arithmetic(Expr::Op op, const Term& a, const Term& b, double x, double y) {
    bool integers = isIntegerType(a.datatype) && isIntegerType(b.datatype);
    bool doubles = a.datatype == xsd("double") || a.datatype == xsd("float") ||
                   b.datatype == xsd("double") || b.datatype == xsd("float");
    double r = 0;
    switch (op) {
        case Expr::Op::Add:
            r = x + y;
            break;
        case Expr::Op::Sub:
            r = x - y;
            break;
        case Expr::Op::Mul:
            r = x * y;
            break;
        default:
            r = x / y;
            break;
    }
    if (integers && op != Expr::Op::Div) {
        return Term{Term::Kind::Literal, std::to_string(static_cast<long long>(r)), xsd("integer"),
                    ""};
    }
    if (doubles) return Term{Term::Kind::Literal, formatDouble(r), xsd("double"), ""};
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.15f", r);
    std::string s = buf;
    while (s.size() > 1 && s.back() == '0' && s[s.size() - 2] != '.') s.pop_back();
    return Term{Term::Kind::Literal, s, xsd("decimal"), ""};
}

std::optional<Term> Evaluator::eval(const Expr& e, const Row& row, TermId graph) {
    tick();
    switch (e.op) {
        case Expr::Op::Var:
            if (row[e.var] == kNoTerm) return std::nullopt;
            return term(row[e.var]);
        case Expr::Op::Const:
            return e.value;
        case Expr::Op::Or: {
            auto a = ebv(eval(*e.args[0], row, graph));
            if (a && *a) return boolean(true);
            auto b = ebv(eval(*e.args[1], row, graph));
            if (b && *b) return boolean(true);
            if (a && b) return boolean(false);
            return std::nullopt;
        }
        case Expr::Op::And: {
            auto a = ebv(eval(*e.args[0], row, graph));
            if (a && !*a) return boolean(false);
            auto b = ebv(eval(*e.args[1], row, graph));
            if (b && !*b) return boolean(false);
            if (a && b) return boolean(true);
            return std::nullopt;
        }
        case Expr::Op::Not: {
            auto a = ebv(eval(*e.args[0], row, graph));
            if (!a) return std::nullopt;
            return boolean(!*a);
        }
        case Expr::Op::Eq:
        case Expr::Op::Ne: {
            auto a = eval(*e.args[0], row, graph), b = eval(*e.args[1], row, graph);
            if (!a || !b) return std::nullopt;
            auto eq = termEquals(*a, *b);
            if (!eq) return std::nullopt;
            return boolean(e.op == Expr::Op::Eq ? *eq : !*eq);
        }
        case Expr::Op::Lt:
        case Expr::Op::Le:
        case Expr::Op::Gt:
        case Expr::Op::Ge: {
            auto a = eval(*e.args[0], row, graph), b = eval(*e.args[1], row, graph);
            if (!a || !b) return std::nullopt;
            auto c = valueCompare(*a, *b);
            if (!c) return std::nullopt;
            switch (e.op) {
                case Expr::Op::Lt:
                    return boolean(*c < 0);
                case Expr::Op::Le:
                    return boolean(*c <= 0);
                case Expr::Op::Gt:
                    return boolean(*c > 0);
                default:
                    return boolean(*c >= 0);
            }
        }
        case Expr::Op::Add:
        case Expr::Op::Sub:
        case Expr::Op::Mul:
        case Expr::Op::Div: {
            auto a = eval(*e.args[0], row, graph), b = eval(*e.args[1], row, graph);
            if (!a || !b) return std::nullopt;
            auto x = numberOf(*a), y = numberOf(*b);
            if (!x || !y) return std::nullopt;
            if (e.op == Expr::Op::Div && *y == 0 && isIntegerType(b->datatype) &&
                a->datatype != xsd("double")) {
                return std::nullopt;
            }
            return arithmetic(e.op, *a, *b, *x, *y);
        }
        case Expr::Op::Neg:
        case Expr::Op::Plus: {
            auto a = eval(*e.args[0], row, graph);
            if (!a) return std::nullopt;
            auto x = numberOf(*a);
            if (!x) return std::nullopt;
            if (e.op == Expr::Op::Plus) return a;
            Term zero{Term::Kind::Literal, "0", xsd("integer"), ""};
            return arithmetic(Expr::Op::Sub, zero, *a, 0, *x);
        }
        case Expr::Op::In:
        case Expr::Op::NotIn: {
            auto a = eval(*e.args[0], row, graph);
            if (!a) return std::nullopt;
            bool error = false;
            for (std::size_t i = 1; i < e.args.size(); ++i) {
                auto b = eval(*e.args[i], row, graph);
                if (!b) {
                    error = true;
                    continue;
                }
                auto eq = termEquals(*a, *b);
                if (eq && *eq) return boolean(e.op == Expr::Op::In);
                if (!eq) error = true;
            }
            if (error) return std::nullopt;
            return boolean(e.op == Expr::Op::NotIn);
        }
        case Expr::Op::Exists:
        case Expr::Op::NotExists: {
            bool found = !group(*e.group, Rows{row}, graph).empty();
            return boolean(e.op == Expr::Op::Exists ? found : !found);
        }
        case Expr::Op::Call:
            return call(e, row, graph);
    }
    return std::nullopt;
}

std::optional<Term> Evaluator::call(const Expr& e, const Row& row, TermId graph) {
    const std::string& f = e.function;
    if (f == "BOUND") return boolean(row[e.args[0]->var] != kNoTerm);
    if (f == "IF") {
        auto c = ebv(eval(*e.args[0], row, graph));
        if (!c) return std::nullopt;
        return eval(*e.args[*c ? 1 : 2], row, graph);
    }
    if (f == "COALESCE") {
        for (const auto& a : e.args) {
            if (auto v = eval(*a, row, graph)) return v;
        }
        return std::nullopt;
    }
    std::vector<Term> args;
    for (const auto& a : e.args) {
        auto v = eval(*a, row, graph);
        if (!v) return std::nullopt;
        args.push_back(std::move(*v));
    }
    const Term& a = args.empty() ? Term{} : args[0];
    auto stringArg = [](const Term& t) -> std::optional<std::string> {
        if (t.kind != Term::Kind::Literal) return std::nullopt;
        if (!t.datatype.empty()) return std::nullopt;
        return t.value;
    };
    if (f == "ISIRI" || f == "ISURI") return boolean(a.kind == Term::Kind::Iri);
    if (f == "ISLITERAL") return boolean(a.kind == Term::Kind::Literal);
    if (f == "ISBLANK") return boolean(a.kind == Term::Kind::Blank);
    if (f == "ISNUMERIC") return boolean(isNumeric(a) && numberOf(a).has_value());
    if (f == "STR") {
        if (a.kind == Term::Kind::Blank) return std::nullopt;
        return plain(a.value);
    }
    if (f == "LANG") {
        if (a.kind != Term::Kind::Literal) return std::nullopt;
        return plain(a.lang);
    }
    if (f == "DATATYPE") {
        if (a.kind != Term::Kind::Literal) return std::nullopt;
        std::string dt = !a.lang.empty()      ? std::string(kRdf) + "langString"
                         : a.datatype.empty() ? xsd("string")
                                              : a.datatype;
        return Term{Term::Kind::Iri, dt, "", ""};
    }
    if (f == "SAMETERM") return boolean(args[0] == args[1]);
    if (f == "IRI" || f == "URI") {
        if (a.kind == Term::Kind::Iri) return a;
        if (!isStringLiteral(a)) return std::nullopt;
        return Term{Term::Kind::Iri, a.value, "", ""};
    }
    if (f == "ABS") {
        auto x = numberOf(a);
        if (!x) return std::nullopt;
        if (*x >= 0) return a;
        Term zero{Term::Kind::Literal, "0", xsd("integer"), ""};
        return arithmetic(Expr::Op::Sub, zero, a, 0, *x);
    }
    // String functions: simple literals and language-tagged strings.
    auto text = [](const Term& t) -> std::optional<std::string> {
        if (t.kind != Term::Kind::Literal || !t.datatype.empty()) return std::nullopt;
        return t.value;
    };
    if (f == "CONCAT") {
        std::string out;
        for (const auto& t : args) {
            auto s = text(t);
            if (!s) return std::nullopt;
            out += *s;
        }
        return plain(out);
    }
    auto s0 = text(a);
    if (!s0) return std::nullopt;
    if (f == "STRLEN") {
        long long n = 0;
        for (unsigned char c : *s0) n += (c & 0xC0) != 0x80;
        return Term{Term::Kind::Literal, std::to_string(n), xsd("integer"), ""};
    }
    if (f == "LCASE" || f == "UCASE") {
        Term out = a;
        for (auto& c : out.value) {
            c = static_cast<char>(f == "LCASE" ? std::tolower(static_cast<unsigned char>(c))
                                               : std::toupper(static_cast<unsigned char>(c)));
        }
        return out;
    }
    if (f == "LANGMATCHES") {
        auto range = stringArg(args[1]);
        if (!range) return std::nullopt;
        std::string tag = *s0, r = *range;
        for (auto& c : tag) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
        for (auto& c : r) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
        if (r == "*") return boolean(!tag.empty());
        return boolean(tag == r ||
                       (tag.size() > r.size() && tag.starts_with(r) && tag[r.size()] == '-'));
    }
    auto s1 = args.size() > 1 ? text(args[1]) : std::nullopt;
    if (f == "CONTAINS" || f == "STRSTARTS" || f == "STRENDS") {
        if (!s1) return std::nullopt;
        if (f == "CONTAINS") return boolean(s0->find(*s1) != std::string::npos);
        if (f == "STRSTARTS") return boolean(s0->starts_with(*s1));
        return boolean(s0->ends_with(*s1));
    }
    if (f == "REGEX") {
        if (!s1) return std::nullopt;
        auto flags = std::regex::ECMAScript;
        if (args.size() == 3) {
            auto fl = stringArg(args[2]);
            if (!fl) return std::nullopt;
            for (char c : *fl) {
                if (c == 'i') {
                    flags |= std::regex::icase;
                } else {
                    throw KbError(std::string("SPARQL: unsupported REGEX flag '") + c + "'");
                }
            }
        }
        if (s1->size() > 1024) throw KbError("SPARQL: REGEX pattern longer than 1024 characters");
        try {
            return boolean(std::regex_search(*s0, std::regex(*s1, flags)));
        } catch (const std::regex_error& err) {
            throw KbError("SPARQL: bad REGEX pattern '" + *s1 + "': " + err.what());
        }
    }
    throw KbError("SPARQL: unsupported function " + f);
}

int kindRank(const Term& t) {
    switch (t.kind) {
        case Term::Kind::Blank:
            return 1;
        case Term::Kind::Iri:
            return 2;
        default:
            return 3;
    }
}

int Evaluator::orderCompare(TermId a, TermId b) const {
    if (a == b) return 0;
    if (a == kNoTerm) return -1;
    if (b == kNoTerm) return 1;
    const Term& x = term(a);
    const Term& y = term(b);
    if (kindRank(x) != kindRank(y)) return kindRank(x) < kindRank(y) ? -1 : 1;
    if (auto c = valueCompare(x, y); c && *c != 0) return *c;
    if (int c = x.value.compare(y.value); c != 0) return c < 0 ? -1 : 1;
    if (int c = x.datatype.compare(y.datatype); c != 0) return c < 0 ? -1 : 1;
    int c = x.lang.compare(y.lang);
    return c < 0 ? -1 : (c > 0 ? 1 : 0);
}

Rows solve(Evaluator& ev, const Query& q) {
    return ev.group(q.where, Rows{Row(ev.width(), kNoTerm)}, kNoTerm);
}

}  // namespace

Results runSelect(const QuadStore& store, std::string_view text, Deadline deadline) {
    Query q = parseQuery(text);
    if (q.form != Query::Form::Select) throw KbError("SPARQL: select() needs a SELECT query");
    Evaluator ev(store, q.variables, deadline);
    ev.setNames(&q.variables);
    Rows rows = solve(ev, q);
    // Projection expressions, then ORDER BY (which may use them), then project.
    for (const auto& p : q.projection) {
        if (!p.expr) continue;
        for (auto& row : rows) {
            if (auto v = ev.eval(*p.expr, row, kNoTerm)) row[p.var] = ev.id(*v);
        }
    }
    if (!q.orderBy.empty()) {
        std::vector<std::pair<std::vector<TermId>, std::size_t>> keys;
        keys.reserve(rows.size());
        for (std::size_t i = 0; i < rows.size(); ++i) {
            std::vector<TermId> k;
            for (const auto& c : q.orderBy) {
                auto v = ev.eval(*c.expr, rows[i], kNoTerm);
                k.push_back(v ? ev.id(*v) : kNoTerm);
            }
            keys.emplace_back(std::move(k), i);
        }
        std::stable_sort(keys.begin(), keys.end(), [&](const auto& a, const auto& b) {
            for (std::size_t j = 0; j < q.orderBy.size(); ++j) {
                int c = ev.orderCompare(a.first[j], b.first[j]);
                if (c != 0) return q.orderBy[j].descending ? c > 0 : c < 0;
            }
            return false;
        });
        Rows sorted;
        sorted.reserve(rows.size());
        for (const auto& k : keys) sorted.push_back(std::move(rows[k.second]));
        rows = std::move(sorted);
    }
    std::vector<int> columns;
    if (q.selectAll) {
        for (std::size_t i = 0; i < q.variables.size(); ++i) {
            if (!q.variables[i].starts_with("_:")) columns.push_back(static_cast<int>(i));
        }
    } else {
        for (const auto& p : q.projection) columns.push_back(p.var);
    }
    Results results;
    for (int c : columns) results.variables.push_back(q.variables[c]);
    std::vector<std::vector<TermId>> projected;
    std::set<std::vector<TermId>> seen;
    std::size_t skipped = 0;
    for (const auto& row : rows) {
        std::vector<TermId> out;
        out.reserve(columns.size());
        for (int c : columns) out.push_back(row[c]);
        if (q.distinct && !seen.insert(out).second) continue;
        if (skipped < q.offset) {
            ++skipped;
            continue;
        }
        if (projected.size() >= q.limit) break;
        if (projected.size() >= kMaxResultRows) {
            throw KbError("SPARQL: more than " + std::to_string(kMaxResultRows) +
                          " results (add a LIMIT)");
        }
        projected.push_back(std::move(out));
    }
    results.rows.reserve(projected.size());
    for (const auto& p : projected) {
        std::vector<std::optional<Term>> r;
        r.reserve(p.size());
        for (TermId id : p) {
            if (id == kNoTerm) {
                r.emplace_back();
            } else {
                r.emplace_back(ev.term(id));
            }
        }
        results.rows.push_back(std::move(r));
    }
    return results;
}

bool runAsk(const QuadStore& store, std::string_view text, Deadline deadline) {
    Query q = parseQuery(text);
    if (q.form != Query::Form::Ask) throw KbError("SPARQL: ask() needs an ASK query");
    Evaluator ev(store, q.variables, deadline);
    ev.setNames(&q.variables);
    return !solve(ev, q).empty();
}

namespace {

// A template's term for one solution; nullopt when it names an unbound variable.
std::optional<Term> instantiate(const Node& n, const Row& row, Evaluator& ev,
                                const std::string& blankScope) {
    if (n.isVar()) {
        if (row[n.var] == kNoTerm) return std::nullopt;
        return ev.term(row[n.var]);
    }
    if (n.term.kind == Term::Kind::Blank) {
        return Term{Term::Kind::Blank, blankScope + n.term.value, "", ""};
    }
    return n.term;
}

struct TermQuad {
    Term s, p, o;
    std::optional<Term> g;  // none: the default graph
};

std::vector<TermQuad> instantiateAll(const std::vector<QuadTemplate>& templates, const Rows& rows,
                                     Evaluator& ev, const std::optional<Term>& with,
                                     std::uint64_t* blankCounter) {
    std::vector<TermQuad> out;
    for (const auto& row : rows) {
        std::string scope = blankCounter ? "u" + std::to_string(++*blankCounter) + "_" : "";
        for (const auto& t : templates) {
            auto s = instantiate(t.triple.s, row, ev, scope);
            auto p = instantiate(t.triple.p, row, ev, scope);
            auto o = instantiate(t.triple.o, row, ev, scope);
            std::optional<Term> g = with;
            if (t.graph) {
                g = instantiate(*t.graph, row, ev, scope);
                if (!g) continue;
            }
            if (!s || !p || !o) continue;
            if (s->kind == Term::Kind::Literal || p->kind != Term::Kind::Iri) continue;
            if (g && g->kind != Term::Kind::Iri) continue;
            out.push_back({std::move(*s), std::move(*p), std::move(*o), std::move(g)});
        }
    }
    return out;
}

}  // namespace

void runUpdate(QuadStore& store, std::string_view text, Deadline deadline,
               std::uint64_t& blankCounter) {
    Update u = parseUpdate(text);
    const Term defaultGraph{Term::Kind::Iri, std::string(kDefaultGraphName), "", ""};
    for (const auto& op : u.operations) {
        if (std::chrono::steady_clock::now() > deadline) throw KbError("SPARQL: deadline exceeded");
        switch (op.kind) {
            case UpdateOperation::Kind::InsertData:
            case UpdateOperation::Kind::DeleteData:
            case UpdateOperation::Kind::Modify: {
                Evaluator ev(store, u.variables, deadline);
                ev.setNames(&u.variables);
                Rows rows{Row(u.variables.size(), kNoTerm)};
                if (op.kind == UpdateOperation::Kind::Modify) {
                    TermId graph = kNoTerm;
                    if (op.with) {
                        graph = store.find(*op.with);
                        if (graph == kNoTerm) rows.clear();
                    }
                    if (!rows.empty()) rows = ev.group(op.where, std::move(rows), graph);
                }
                auto deletes = instantiateAll(op.deletes, rows, ev, op.with, nullptr);
                auto inserts = instantiateAll(op.inserts, rows, ev, op.with, &blankCounter);
                for (const auto& q : deletes) {
                    TermId s = store.find(q.s), p = store.find(q.p), o = store.find(q.o);
                    if (s == kNoTerm || p == kNoTerm || o == kNoTerm) continue;
                    if (q.g) {
                        TermId g = store.find(*q.g);
                        if (g != kNoTerm) store.erase({s, p, o, g});
                    } else {
                        // The default graph is the union: the triple leaves every graph.
                        for (TermId g : store.graphs()) store.erase({s, p, o, g});
                    }
                }
                for (const auto& q : inserts) {
                    Quad quad{store.intern(q.s), store.intern(q.p), store.intern(q.o),
                              store.intern(q.g ? *q.g : defaultGraph)};
                    store.insert(quad);
                }
                break;
            }
            case UpdateOperation::Kind::Clear:
            case UpdateOperation::Kind::Drop:
                switch (op.target) {
                    case UpdateOperation::Target::Graph: {
                        TermId g = store.find(op.graph);
                        if (g != kNoTerm) store.clearGraph(g);
                        break;
                    }
                    case UpdateOperation::Target::Default: {
                        TermId g = store.find(defaultGraph);
                        if (g != kNoTerm) store.clearGraph(g);
                        break;
                    }
                    case UpdateOperation::Target::Named: {
                        TermId keep = store.find(defaultGraph);
                        for (TermId g : store.graphs()) {
                            if (g != keep) store.clearGraph(g);
                        }
                        break;
                    }
                    case UpdateOperation::Target::All:
                        store.clearAll();
                        break;
                }
                break;
            case UpdateOperation::Kind::Create:
                break;  // graphs exist while they hold triples
        }
    }
}

}  // namespace pnp::kb
