// A recursive-descent parser of the SPARQL 1.1 subset the engine runs (docs/knowledge-base.md).
#include <algorithm>
#include <cctype>
#include <charconv>
#include <map>
#include <unordered_map>

#include "kb/sparql.hpp"
#include "kb/sparql_ast.hpp"

namespace pnp::kb::sparql {
namespace {

struct Token {
    enum class Kind {
        Iri,
        PName,
        Var,
        String,
        Integer,
        Decimal,
        Double,
        LangTag,
        Blank,
        Word,
        Punct,
        End
    };
    Kind kind = Kind::End;
    std::string text;  // Iri: the IRI; String: the unescaped value; Word: as written
    int line = 1, col = 1;
};

[[noreturn]] void fail(int line, int col, const std::string& what) {
    throw KbError("SPARQL " + std::to_string(line) + ":" + std::to_string(col) + ": " + what);
}

bool isNameChar(unsigned char c) { return std::isalnum(c) || c == '_' || c == '-' || c >= 0x80; }

class Lexer {
  public:
    explicit Lexer(std::string_view text) : text_(text) {}

    std::vector<Token> run() {
        std::vector<Token> out;
        for (;;) {
            skipSpace();
            Token t;
            t.line = line_, t.col = col_;
            if (pos_ >= text_.size()) {
                out.push_back(t);
                return out;
            }
            lexOne(t);
            out.push_back(std::move(t));
        }
    }

  private:
    char peek(std::size_t ahead = 0) const {
        return pos_ + ahead < text_.size() ? text_[pos_ + ahead] : '\0';
    }
    void advance(std::size_t n = 1) {
        for (std::size_t i = 0; i < n && pos_ < text_.size(); ++i, ++pos_) {
            if (text_[pos_] == '\n') {
                ++line_, col_ = 1;
            } else {
                ++col_;
            }
        }
    }
    void skipSpace() {
        while (pos_ < text_.size()) {
            char c = text_[pos_];
            if (c == '#') {
                while (pos_ < text_.size() && text_[pos_] != '\n') advance();
            } else if (std::isspace(static_cast<unsigned char>(c))) {
                advance();
            } else {
                return;
            }
        }
    }

    void lexOne(Token& t) {
        char c = peek();
        if (c == '<' && tryIri(t)) return;
        if (c == '?' || c == '$') {
            if (isNameChar(static_cast<unsigned char>(peek(1)))) {
                advance();
                t.kind = Token::Kind::Var;
                while (isNameChar(static_cast<unsigned char>(peek()))) t.text += peek(), advance();
                return;
            }
        }
        if (c == '"' || c == '\'') return lexString(t);
        if (std::isdigit(static_cast<unsigned char>(c)) ||
            (c == '.' && std::isdigit(static_cast<unsigned char>(peek(1))))) {
            return lexNumber(t);
        }
        if (c == '@' && std::isalpha(static_cast<unsigned char>(peek(1)))) {
            advance();
            t.kind = Token::Kind::LangTag;
            while (std::isalnum(static_cast<unsigned char>(peek())) || peek() == '-') {
                t.text += peek(), advance();
            }
            return;
        }
        if (c == '_' && peek(1) == ':') {
            advance(2);
            t.kind = Token::Kind::Blank;
            while (isNameChar(static_cast<unsigned char>(peek())) || peek() == '.') {
                t.text += peek(), advance();
            }
            while (!t.text.empty() && t.text.back() == '.') t.text.pop_back(), --pos_, --col_;
            return;
        }
        if (std::isalpha(static_cast<unsigned char>(c)) || c == ':' ||
            static_cast<unsigned char>(c) >= 0x80) {
            return lexName(t);
        }
        static const char* const two[] = {"^^", "!=", "<=", ">=", "&&", "||"};
        for (const char* p : two) {
            if (c == p[0] && peek(1) == p[1]) {
                t.kind = Token::Kind::Punct, t.text = p;
                advance(2);
                return;
            }
        }
        if (std::string_view("{}()[].;,*+?/|^!=<>-").find(c) != std::string_view::npos) {
            t.kind = Token::Kind::Punct, t.text = std::string(1, c);
            advance();
            return;
        }
        fail(line_, col_, std::string("unexpected character '") + c + "'");
    }

    bool tryIri(Token& t) {
        std::size_t end = pos_ + 1;
        while (end < text_.size()) {
            unsigned char c = static_cast<unsigned char>(text_[end]);
            if (c == '>') break;
            if (c <= 0x20 || std::string_view("<\"{}|^`\\").find(static_cast<char>(c)) !=
                                 std::string_view::npos) {
                return false;
            }
            ++end;
        }
        if (end >= text_.size()) return false;
        t.kind = Token::Kind::Iri;
        t.text = std::string(text_.substr(pos_ + 1, end - pos_ - 1));
        advance(end - pos_ + 1);
        return true;
    }

    void lexString(Token& t) {
        char quote = peek();
        bool isLong = peek(1) == quote && peek(2) == quote;
        advance(isLong ? 3 : 1);
        t.kind = Token::Kind::String;
        for (;;) {
            if (pos_ >= text_.size()) fail(t.line, t.col, "unterminated string");
            char c = peek();
            if (isLong) {
                if (c == quote && peek(1) == quote && peek(2) == quote) {
                    advance(3);
                    return;
                }
            } else if (c == quote) {
                advance();
                return;
            } else if (c == '\n' || c == '\r') {
                fail(line_, col_, "line break in a short string");
            }
            if (c == '\\') {
                char e = peek(1);
                int line = line_, col = col_;
                advance(2);
                switch (e) {
                    case 't':
                        t.text += '\t';
                        break;
                    case 'n':
                        t.text += '\n';
                        break;
                    case 'r':
                        t.text += '\r';
                        break;
                    case 'b':
                        t.text += '\b';
                        break;
                    case 'f':
                        t.text += '\f';
                        break;
                    case '"':
                        t.text += '"';
                        break;
                    case '\'':
                        t.text += '\'';
                        break;
                    case '\\':
                        t.text += '\\';
                        break;
                    case 'u':
                    case 'U': {
                        std::size_t n = e == 'u' ? 4 : 8;
                        if (pos_ + n > text_.size()) fail(line, col, "bad \\u escape");
                        unsigned long cp = 0;
                        auto hex = text_.substr(pos_, n);
                        auto r = std::from_chars(hex.data(), hex.data() + n, cp, 16);
                        if (r.ptr != hex.data() + n || cp > 0x10FFFF)
                            fail(line, col, "bad \\u escape");
                        appendUtf8(t.text, cp);
                        advance(n);
                        break;
                    }
                    default:
                        fail(line, col, std::string("bad escape '\\") + e + "'");
                }
                continue;
            }
            t.text += c;
            advance();
        }
    }

    static void appendUtf8(std::string& out, unsigned long cp) {
        if (cp < 0x80) {
            out += static_cast<char>(cp);
        } else if (cp < 0x800) {
            out += static_cast<char>(0xC0 | (cp >> 6));
            out += static_cast<char>(0x80 | (cp & 0x3F));
        } else if (cp < 0x10000) {
            out += static_cast<char>(0xE0 | (cp >> 12));
            out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
            out += static_cast<char>(0x80 | (cp & 0x3F));
        } else {
            out += static_cast<char>(0xF0 | (cp >> 18));
            out += static_cast<char>(0x80 | ((cp >> 12) & 0x3F));
            out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
            out += static_cast<char>(0x80 | (cp & 0x3F));
        }
    }

    void lexNumber(Token& t) {
        t.kind = Token::Kind::Integer;
        while (std::isdigit(static_cast<unsigned char>(peek()))) t.text += peek(), advance();
        if (peek() == '.' && std::isdigit(static_cast<unsigned char>(peek(1)))) {
            t.kind = Token::Kind::Decimal;
            t.text += '.', advance();
            while (std::isdigit(static_cast<unsigned char>(peek()))) t.text += peek(), advance();
        }
        if (peek() == 'e' || peek() == 'E') {
            std::size_t n = 1;
            if (peek(1) == '+' || peek(1) == '-') n = 2;
            if (std::isdigit(static_cast<unsigned char>(peek(n)))) {
                t.kind = Token::Kind::Double;
                for (std::size_t i = 0; i < n; ++i) t.text += peek(), advance();
                while (std::isdigit(static_cast<unsigned char>(peek())))
                    t.text += peek(), advance();
            }
        }
    }

    // A keyword or a prefixed name (prefix:local).
    void lexName(Token& t) {
        std::string prefix;
        while (isNameChar(static_cast<unsigned char>(peek())) || peek() == '.') {
            if (peek() == '.' && !isNameChar(static_cast<unsigned char>(peek(1)))) break;
            prefix += peek(), advance();
        }
        if (peek() != ':') {
            t.kind = Token::Kind::Word, t.text = prefix;
            return;
        }
        advance();
        t.kind = Token::Kind::PName;
        t.text = prefix + ":";
        for (;;) {
            char c = peek();
            if (c == '\\' && pos_ + 1 < text_.size()) {
                t.text += peek(1), advance(2);
            } else if (c == '%' && std::isxdigit(static_cast<unsigned char>(peek(1))) &&
                       std::isxdigit(static_cast<unsigned char>(peek(2)))) {
                t.text += text_.substr(pos_, 3), advance(3);
            } else if (isNameChar(static_cast<unsigned char>(c)) || c == ':' ||
                       (c == '.' &&
                        (isNameChar(static_cast<unsigned char>(peek(1))) || peek(1) == ':'))) {
                t.text += c, advance();
            } else {
                return;
            }
        }
    }

    std::string_view text_;
    std::size_t pos_ = 0;
    int line_ = 1, col_ = 1;
};

std::string upper(std::string s) {
    for (auto& c : s) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
    return s;
}

// The deepest nesting of groups, brackets and blank-node property lists (bounds recursion).
constexpr int kMaxNesting = 64;

class Parser {
  public:
    explicit Parser(std::string_view text) {
        if (text.size() > kMaxQueryBytes) {
            throw KbError("SPARQL text of " + std::to_string(text.size()) + " bytes, more than " +
                          std::to_string(kMaxQueryBytes));
        }
        tokens_ = Lexer(text).run();
        // Virtuoso predefines these; queries written for both may use them undeclared.
        prefixes_["rdf"] = std::string(kRdf);
        prefixes_["rdfs"] = "http://www.w3.org/2000/01/rdf-schema#";
        prefixes_["xsd"] = std::string(kXsd);
        prefixes_["owl"] = "http://www.w3.org/2002/07/owl#";
    }

    Query query() {
        Query q;
        prologue();
        const Token& t = peek();
        std::string word = isWord(t) ? upper(t.text) : "";
        if (word == "SELECT") {
            next();
            q.form = Query::Form::Select;
            if (acceptWord("DISTINCT")) {
                q.distinct = true;
            } else if (acceptWord("REDUCED")) {
                // REDUCED allows but does not require removing duplicates: keep them.
            }
            if (acceptPunct("*")) {
                q.selectAll = true;
            } else {
                while (peek().kind == Token::Kind::Var || isPunct(peek(), "(")) {
                    if (peek().kind == Token::Kind::Var) {
                        q.projection.push_back({variable(next().text), nullptr});
                    } else {
                        next();
                        auto e = expression();
                        expectWord("AS");
                        auto& v = expect(Token::Kind::Var, "a variable after AS");
                        q.projection.push_back({variable(v.text), e});
                        expectPunct(")");
                    }
                }
                if (q.projection.empty()) failAt(peek(), "expected variables or * after SELECT");
            }
        } else if (word == "ASK") {
            next();
            q.form = Query::Form::Ask;
        } else if (word == "CONSTRUCT" || word == "DESCRIBE") {
            unsupported(t, word);
        } else {
            failAt(t, "expected SELECT or ASK");
        }
        if (isWord(peek()) && (upper(peek().text) == "FROM")) unsupported(peek(), "FROM");
        acceptWord("WHERE");
        q.where = group();
        // Solution modifiers.
        if (isWord(peek()) && upper(peek().text) == "GROUP") unsupported(peek(), "GROUP BY");
        if (isWord(peek()) && upper(peek().text) == "HAVING") unsupported(peek(), "HAVING");
        if (acceptWord("ORDER")) {
            expectWord("BY");
            do {
                OrderCondition c;
                if (acceptWord("ASC")) {
                    c.expr = bracketted();
                } else if (acceptWord("DESC")) {
                    c.expr = bracketted();
                    c.descending = true;
                } else if (peek().kind == Token::Kind::Var) {
                    c.expr = varExpr(next().text);
                } else if (isPunct(peek(), "(")) {
                    c.expr = bracketted();
                } else if (isWord(peek())) {
                    c.expr = primary();
                } else {
                    failAt(peek(), "expected an ORDER BY condition");
                }
                q.orderBy.push_back(c);
            } while (peek().kind == Token::Kind::Var || isPunct(peek(), "(") ||
                     (isWord(peek()) && upper(peek().text) != "LIMIT" &&
                      upper(peek().text) != "OFFSET" && upper(peek().text) != "VALUES"));
        }
        for (int i = 0; i < 2; ++i) {
            if (acceptWord("LIMIT")) q.limit = count("LIMIT");
            if (acceptWord("OFFSET")) q.offset = count("OFFSET");
        }
        if (isWord(peek()) && upper(peek().text) == "VALUES")
            unsupported(peek(), "VALUES after the query");
        if (peek().kind != Token::Kind::End)
            failAt(peek(), "unexpected '" + peek().text + "' after the query");
        q.variables = variables_;
        return q;
    }

    Update update() {
        Update u;
        for (;;) {
            prologue();
            if (peek().kind == Token::Kind::End) break;
            u.operations.push_back(operation());
            if (!acceptPunct(";")) break;
        }
        if (peek().kind != Token::Kind::End)
            failAt(peek(), "unexpected '" + peek().text + "' after the update");
        if (u.operations.empty()) failAt(peek(), "empty update");
        u.variables = variables_;
        return u;
    }

  private:
    // ---- tokens
    const Token& peek(std::size_t ahead = 0) const {
        return tokens_[std::min(pos_ + ahead, tokens_.size() - 1)];
    }
    const Token& next() {
        const Token& t = tokens_[pos_];
        if (pos_ + 1 < tokens_.size()) ++pos_;
        return t;
    }
    static bool isWord(const Token& t) { return t.kind == Token::Kind::Word; }
    static bool isPunct(const Token& t, std::string_view p) {
        return t.kind == Token::Kind::Punct && t.text == p;
    }
    bool isWordNamed(const Token& t, std::string_view w) const {
        return isWord(t) && upper(t.text) == w;
    }
    bool acceptWord(std::string_view w) {
        if (!isWordNamed(peek(), w)) return false;
        next();
        return true;
    }
    bool acceptPunct(std::string_view p) {
        if (!isPunct(peek(), p)) return false;
        next();
        return true;
    }
    void expectWord(std::string_view w) {
        if (!acceptWord(w)) failAt(peek(), "expected " + std::string(w));
    }
    void expectPunct(std::string_view p) {
        if (!acceptPunct(p)) failAt(peek(), "expected '" + std::string(p) + "'");
    }
    const Token& expect(Token::Kind kind, const std::string& what) {
        if (peek().kind != kind) failAt(peek(), "expected " + what);
        return next();
    }
    [[noreturn]] static void failAt(const Token& t, const std::string& what) {
        if (t.kind == Token::Kind::End) fail(t.line, t.col, what + " (at the end)");
        fail(t.line, t.col, what);
    }
    [[noreturn]] static void unsupported(const Token& t, const std::string& feature) {
        fail(t.line, t.col, "unsupported: " + feature);
    }
    std::size_t count(const char* what) {
        const Token& t = expect(Token::Kind::Integer, std::string("a number after ") + what);
        std::size_t n = 0;
        auto r = std::from_chars(t.text.data(), t.text.data() + t.text.size(), n);
        if (r.ec != std::errc()) failAt(t, std::string(what) + " too large");
        return n;
    }

    // ---- names
    int variable(const std::string& name) {
        auto it = std::find(variables_.begin(), variables_.end(), name);
        if (it != variables_.end()) return static_cast<int>(it - variables_.begin());
        variables_.push_back(name);
        return static_cast<int>(variables_.size() - 1);
    }
    ExprPtr varExpr(const std::string& name) {
        auto e = std::make_shared<Expr>();
        e->op = Expr::Op::Var;
        e->var = variable(name);
        return e;
    }

    void prologue() {
        for (;;) {
            if (acceptWord("PREFIX")) {
                const Token& name = expect(Token::Kind::PName, "a prefix name like 'ex:'");
                if (name.text.back() != ':' || name.text.find(':') != name.text.size() - 1) {
                    failAt(name, "expected a prefix name like 'ex:'");
                }
                const Token& ref = expect(Token::Kind::Iri, "<iri> after the prefix name");
                prefixes_[name.text.substr(0, name.text.size() - 1)] = resolve(ref.text);
            } else if (acceptWord("BASE")) {
                base_ = expect(Token::Kind::Iri, "<iri> after BASE").text;
            } else {
                return;
            }
        }
    }

    std::string resolve(const std::string& ref) const {
        if (base_.empty() || ref.find(':') != std::string::npos) return ref;
        if (ref.empty()) return base_;
        if (ref[0] == '#') {
            auto hash = base_.find('#');
            return base_.substr(0, hash) + ref;
        }
        auto slash = base_.rfind('/');
        return (slash == std::string::npos ? base_ : base_.substr(0, slash + 1)) + ref;
    }

    std::string expandName(const Token& t) const {
        auto colon = t.text.find(':');
        auto prefix = t.text.substr(0, colon);
        auto it = prefixes_.find(prefix);
        if (it == prefixes_.end()) failAt(t, "unknown prefix '" + prefix + ":'");
        return it->second + t.text.substr(colon + 1);
    }

    bool atIri() const {
        return peek().kind == Token::Kind::Iri || peek().kind == Token::Kind::PName;
    }
    std::string iri() {
        const Token& t = next();
        if (t.kind == Token::Kind::Iri) return resolve(t.text);
        if (t.kind == Token::Kind::PName) return expandName(t);
        failAt(t, "expected an IRI");
    }

    // A constant term (IRI, literal, blank node label), or nullopt when the next token is none.
    std::optional<Term> constant() {
        const Token& t = peek();
        switch (t.kind) {
            case Token::Kind::Iri:
            case Token::Kind::PName:
                return Term{Term::Kind::Iri, iri(), "", ""};
            case Token::Kind::String: {
                next();
                Term term{Term::Kind::Literal, t.text, "", ""};
                if (peek().kind == Token::Kind::LangTag) {
                    term.lang = next().text;
                } else if (acceptPunct("^^")) {
                    if (!atIri()) failAt(peek(), "expected a datatype IRI after ^^");
                    term.datatype = iri();
                    if (term.datatype == std::string(kXsd) + "string") term.datatype.clear();
                }
                return term;
            }
            case Token::Kind::Integer:
            case Token::Kind::Decimal:
            case Token::Kind::Double:
                return number(next(), false);
            case Token::Kind::Punct:
                if ((t.text == "-" || t.text == "+") &&
                    (peek(1).kind == Token::Kind::Integer || peek(1).kind == Token::Kind::Decimal ||
                     peek(1).kind == Token::Kind::Double)) {
                    next();
                    return number(next(), t.text == "-");
                }
                return std::nullopt;
            case Token::Kind::Word:
                if (upper(t.text) == "TRUE" || upper(t.text) == "FALSE") {
                    next();
                    return Term{Term::Kind::Literal, upper(t.text) == "TRUE" ? "true" : "false",
                                std::string(kXsd) + "boolean", ""};
                }
                return std::nullopt;
            default:
                return std::nullopt;
        }
    }
    static Term number(const Token& t, bool negative) {
        const char* type = t.kind == Token::Kind::Integer   ? "integer"
                           : t.kind == Token::Kind::Decimal ? "decimal"
                                                            : "double";
        return Term{Term::Kind::Literal, (negative ? "-" : "") + t.text, std::string(kXsd) + type,
                    ""};
    }

    // ---- graph patterns
    GroupPattern group() {
        Nested nested(*this);
        GroupPattern g;
        expectPunct("{");
        if (isWordNamed(peek(), "SELECT")) unsupported(peek(), "subquery");
        for (;;) {
            const Token& t = peek();
            if (acceptPunct("}")) return g;
            if (acceptPunct(".")) continue;
            if (t.kind == Token::Kind::End) failAt(t, "expected '}'");
            std::string word = isWord(t) ? upper(t.text) : "";
            Element e;
            if (word == "OPTIONAL") {
                next();
                e.kind = Element::Kind::Optional;
                e.groups.push_back(group());
            } else if (word == "MINUS") {
                next();
                e.kind = Element::Kind::Minus;
                e.groups.push_back(group());
            } else if (word == "GRAPH") {
                next();
                e.kind = Element::Kind::Graph;
                e.graph = varOrIri();
                e.groups.push_back(group());
            } else if (word == "FILTER") {
                next();
                e.kind = Element::Kind::Filter;
                e.expr = constraint();
            } else if (word == "BIND") {
                next();
                expectPunct("(");
                e.kind = Element::Kind::Bind;
                e.expr = expression();
                expectWord("AS");
                e.var = variable(expect(Token::Kind::Var, "a variable after AS").text);
                expectPunct(")");
            } else if (word == "VALUES") {
                next();
                e.kind = Element::Kind::Values;
                values(e);
            } else if (word == "SERVICE") {
                unsupported(t, "SERVICE");
            } else if (isPunct(t, "{")) {
                auto first = group();
                if (isWordNamed(peek(), "UNION")) {
                    e.kind = Element::Kind::Union;
                    e.groups.push_back(std::move(first));
                    while (acceptWord("UNION")) e.groups.push_back(group());
                } else {
                    e.kind = Element::Kind::Group;
                    e.groups.push_back(std::move(first));
                }
            } else {
                std::vector<TriplePattern> triples;
                triplesSameSubject(triples, true);
                if (!g.elements.empty() && g.elements.back().kind == Element::Kind::Triples) {
                    auto& into = g.elements.back().triples;
                    into.insert(into.end(), triples.begin(), triples.end());
                    continue;
                }
                e.kind = Element::Kind::Triples;
                e.triples = std::move(triples);
            }
            g.elements.push_back(std::move(e));
        }
    }

    void values(Element& e) {
        bool single = peek().kind == Token::Kind::Var;
        if (single) {
            e.vars.push_back(variable(next().text));
        } else {
            expectPunct("(");
            while (peek().kind == Token::Kind::Var) e.vars.push_back(variable(next().text));
            expectPunct(")");
        }
        expectPunct("{");
        while (!acceptPunct("}")) {
            std::vector<std::optional<Term>> row;
            auto one = [&] {
                if (acceptWord("UNDEF")) {
                    row.emplace_back();
                    return;
                }
                auto c = constant();
                if (!c) failAt(peek(), "expected a value or UNDEF in VALUES");
                row.push_back(std::move(*c));
            };
            if (single) {
                one();
            } else {
                expectPunct("(");
                while (!acceptPunct(")")) one();
            }
            if (row.size() != e.vars.size())
                failAt(peek(), "VALUES row with the wrong number of values");
            e.rows.push_back(std::move(row));
        }
    }

    Node varOrIri() {
        if (peek().kind == Token::Kind::Var) return Node{variable(next().text), {}};
        if (!atIri()) failAt(peek(), "expected a variable or an IRI");
        return Node{-1, Term{Term::Kind::Iri, iri(), "", ""}};
    }

    // A subject or object: variable, constant, blank node ([], [ p o ], _:x).
    Node nodeTerm(std::vector<TriplePattern>& out, bool pattern) {
        const Token& t = peek();
        if (t.kind == Token::Kind::Var) return Node{variable(next().text), {}};
        if (t.kind == Token::Kind::Blank) {
            next();
            return blankNode(t.text, pattern);
        }
        if (isPunct(t, "[")) {
            Nested nested(*this);
            next();
            Node b = blankNode("", pattern);
            if (!acceptPunct("]")) {
                propertyList(b, out, pattern);
                expectPunct("]");
            }
            return b;
        }
        if (isPunct(t, "(")) unsupported(t, "RDF collection ( ... )");
        auto c = constant();
        if (!c) failAt(t, "expected a variable or an RDF term, not '" + t.text + "'");
        return Node{-1, std::move(*c)};
    }

    // Blank nodes are variables in patterns and fresh nodes in templates / data.
    Node blankNode(const std::string& label, bool pattern) {
        std::string name = label.empty() ? "anon" + std::to_string(anonCount_++) : label;
        if (pattern) return Node{variable("_:" + name), {}};
        return Node{-1, Term{Term::Kind::Blank, name, "", ""}};
    }

    void triplesSameSubject(std::vector<TriplePattern>& out, bool pattern) {
        bool bracketed = isPunct(peek(), "[");
        Node subject = nodeTerm(out, pattern);
        // "[ p o ] ." alone is a complete triples block.
        if (bracketed && (isPunct(peek(), ".") || isPunct(peek(), "}"))) return;
        propertyList(subject, out, pattern);
    }

    void propertyList(const Node& subject, std::vector<TriplePattern>& out, bool pattern) {
        for (;;) {
            TriplePattern verb;
            verb.s = subject;
            if (peek().kind == Token::Kind::Var) {
                verb.p = Node{variable(next().text), {}};
            } else {
                const Token& at = peek();
                PathPtr p = path();
                if (p->op == Path::Op::Link) {
                    verb.p = Node{-1, p->iri};
                } else if (!pattern) {
                    failAt(at, "a property path in data or a template");
                } else {
                    verb.path = p;
                }
            }
            do {
                TriplePattern t = verb;
                t.o = nodeTerm(out, pattern);
                out.push_back(std::move(t));
            } while (acceptPunct(","));
            if (!acceptPunct(";")) return;
            while (acceptPunct(";")) {
            }
            if (isPunct(peek(), ".") || isPunct(peek(), "}") || isPunct(peek(), "]")) return;
        }
    }

    PathPtr path() {
        std::vector<PathPtr> alternatives{pathSequence()};
        while (acceptPunct("|")) alternatives.push_back(pathSequence());
        if (alternatives.size() == 1) return alternatives[0];
        auto p = std::make_shared<Path>();
        p->op = Path::Op::Alternative;
        p->parts = std::move(alternatives);
        return p;
    }
    PathPtr pathSequence() {
        std::vector<PathPtr> steps{pathEltOrInverse()};
        while (acceptPunct("/")) steps.push_back(pathEltOrInverse());
        if (steps.size() == 1) return steps[0];
        auto p = std::make_shared<Path>();
        p->op = Path::Op::Sequence;
        p->parts = std::move(steps);
        return p;
    }
    PathPtr pathEltOrInverse() {
        if (acceptPunct("^")) {
            auto p = std::make_shared<Path>();
            p->op = Path::Op::Inverse;
            p->parts.push_back(pathElt());
            return p;
        }
        return pathElt();
    }
    PathPtr pathElt() {
        PathPtr primary = pathPrimary();
        Path::Op op;
        if (isPunct(peek(), "*")) {
            op = Path::Op::ZeroOrMore;
        } else if (isPunct(peek(), "+")) {
            op = Path::Op::OneOrMore;
        } else if (isPunct(peek(), "?")) {
            op = Path::Op::ZeroOrOne;
        } else if (isPunct(peek(), "{")) {
            // "{" after a path element here would be the old {n,m} syntax only if a number follows.
            if (peek(1).kind == Token::Kind::Integer) unsupported(peek(), "path length {n,m}");
            return primary;
        } else {
            return primary;
        }
        next();
        auto p = std::make_shared<Path>();
        p->op = op;
        p->parts.push_back(primary);
        return p;
    }
    PathPtr pathPrimary() {
        auto p = std::make_shared<Path>();
        if (isWordNamed(peek(), "A") && peek().text == "a") {
            next();
            p->iri = Term{Term::Kind::Iri, std::string(kRdf) + "type", "", ""};
            return p;
        }
        if (atIri()) {
            p->iri = Term{Term::Kind::Iri, iri(), "", ""};
            return p;
        }
        if (acceptPunct("(")) {
            Nested nested(*this);
            auto inner = path();
            expectPunct(")");
            return inner;
        }
        if (acceptPunct("!")) {
            p->op = Path::Op::Negated;
            auto one = [&] {
                bool inverse = acceptPunct("^");
                if (isWordNamed(peek(), "A") && peek().text == "a") {
                    next();
                    p->negated.push_back(
                        {Term{Term::Kind::Iri, std::string(kRdf) + "type", "", ""}, inverse});
                } else {
                    if (!atIri()) failAt(peek(), "expected an IRI in a negated property set");
                    p->negated.push_back({Term{Term::Kind::Iri, iri(), "", ""}, inverse});
                }
            };
            if (acceptPunct("(")) {
                if (!isPunct(peek(), ")")) {
                    one();
                    while (acceptPunct("|")) one();
                }
                expectPunct(")");
            } else {
                one();
            }
            return p;
        }
        failAt(peek(), "expected a predicate (IRI, 'a', variable or property path), not '" +
                           peek().text + "'");
    }

    // ---- update
    UpdateOperation operation() {
        const Token& t = peek();
        std::string word = isWord(t) ? upper(t.text) : "";
        UpdateOperation op;
        if (word == "INSERT" || word == "DELETE") {
            next();
            if (acceptWord("DATA")) {
                op.kind = word == "INSERT" ? UpdateOperation::Kind::InsertData
                                           : UpdateOperation::Kind::DeleteData;
                (word == "INSERT" ? op.inserts : op.deletes) = quadData(word == "DELETE");
                return op;
            }
            op.kind = UpdateOperation::Kind::Modify;
            if (word == "DELETE" && acceptWord("WHERE")) {
                // DELETE WHERE { quads }: the quads are both the pattern and the template.
                const Token& at = peek();
                op.deletes = quadTemplates(true);
                for (const auto& q : op.deletes) {
                    if (q.triple.s.isVar() && variables_[q.triple.s.var].starts_with("_:")) {
                        failAt(at, "blank nodes in DELETE WHERE");
                    }
                }
                op.where = patternOf(op.deletes);
                return op;
            }
            modify(op, word);
            return op;
        }
        if (word == "WITH") {
            next();
            op.kind = UpdateOperation::Kind::Modify;
            op.with = Term{Term::Kind::Iri, iri(), "", ""};
            std::string w = isWord(peek()) ? upper(peek().text) : "";
            if (w != "INSERT" && w != "DELETE")
                failAt(peek(), "expected INSERT or DELETE after WITH");
            next();
            modify(op, w);
            return op;
        }
        if (word == "CLEAR" || word == "DROP" || word == "CREATE") {
            next();
            op.kind = word == "CLEAR"  ? UpdateOperation::Kind::Clear
                      : word == "DROP" ? UpdateOperation::Kind::Drop
                                       : UpdateOperation::Kind::Create;
            acceptWord("SILENT");
            if (acceptWord("GRAPH")) {
                op.target = UpdateOperation::Target::Graph;
                op.graph = Term{Term::Kind::Iri, iri(), "", ""};
            } else if (word != "CREATE" && acceptWord("DEFAULT")) {
                op.target = UpdateOperation::Target::Default;
            } else if (word != "CREATE" && acceptWord("NAMED")) {
                op.target = UpdateOperation::Target::Named;
            } else if (word != "CREATE" && acceptWord("ALL")) {
                op.target = UpdateOperation::Target::All;
            } else {
                failAt(peek(), "expected GRAPH <iri>" +
                                   std::string(word == "CREATE" ? "" : ", DEFAULT, NAMED or ALL"));
            }
            return op;
        }
        if (word == "LOAD" || word == "ADD" || word == "MOVE" || word == "COPY")
            unsupported(t, word);
        failAt(t,
               "expected an update operation (INSERT, DELETE, CLEAR, DROP), not '" + t.text + "'");
    }

    // After DELETE or INSERT (and WITH): [DELETE {..}] [INSERT {..}] [USING ..] WHERE {..}.
    void modify(UpdateOperation& op, const std::string& first) {
        if (first == "DELETE") {
            op.deletes = quadTemplates(false);
            for (const auto& q : op.deletes) {
                if (q.triple.s.term.kind == Term::Kind::Blank ||
                    q.triple.o.term.kind == Term::Kind::Blank) {
                    failAt(peek(), "blank nodes in a DELETE template");
                }
            }
            if (acceptWord("INSERT")) op.inserts = quadTemplates(false);
        } else {
            op.inserts = quadTemplates(false);
        }
        if (isWordNamed(peek(), "USING")) unsupported(peek(), "USING");
        expectWord("WHERE");
        op.where = group();
    }

    std::vector<QuadTemplate> quadData(bool forDelete) {
        const Token& at = peek();
        auto quads = quadTemplates(false);
        for (const auto& q : quads) {
            if (q.triple.s.isVar() || q.triple.p.isVar() || q.triple.o.isVar() ||
                (q.graph && q.graph->isVar())) {
                failAt(at, "variables in INSERT DATA / DELETE DATA");
            }
            if (forDelete && (q.triple.s.term.kind == Term::Kind::Blank ||
                              q.triple.o.term.kind == Term::Kind::Blank)) {
                failAt(at, "blank nodes in DELETE DATA");
            }
        }
        return quads;
    }

    // { triples GRAPH <g> { triples } ... }
    std::vector<QuadTemplate> quadTemplates(bool pattern) {
        std::vector<QuadTemplate> out;
        expectPunct("{");
        auto block = [&](const std::optional<Node>& graph) {
            while (!isPunct(peek(), "}") && !isWordNamed(peek(), "GRAPH")) {
                if (acceptPunct(".")) continue;
                if (peek().kind == Token::Kind::End) failAt(peek(), "expected '}'");
                std::vector<TriplePattern> triples;
                triplesSameSubject(triples, pattern);
                for (auto& t : triples) out.push_back({graph, std::move(t)});
            }
        };
        for (;;) {
            block(std::nullopt);
            if (acceptPunct("}")) return out;
            expectWord("GRAPH");
            Node g = varOrIri();
            expectPunct("{");
            block(g);
            if (isWordNamed(peek(), "GRAPH")) failAt(peek(), "GRAPH inside GRAPH");
            expectPunct("}");
        }
    }

    static GroupPattern patternOf(const std::vector<QuadTemplate>& quads) {
        GroupPattern g;
        Element plain;
        plain.kind = Element::Kind::Triples;
        for (const auto& q : quads) {
            if (!q.graph) {
                plain.triples.push_back(q.triple);
                continue;
            }
            Element e;
            e.kind = Element::Kind::Graph;
            e.graph = *q.graph;
            GroupPattern inner;
            Element triples;
            triples.kind = Element::Kind::Triples;
            triples.triples.push_back(q.triple);
            inner.elements.push_back(std::move(triples));
            e.groups.push_back(std::move(inner));
            g.elements.push_back(std::move(e));
        }
        if (!plain.triples.empty()) g.elements.insert(g.elements.begin(), std::move(plain));
        return g;
    }

    // ---- expressions
    ExprPtr constraint() {
        if (isPunct(peek(), "(")) return bracketted();
        if (isWord(peek())) return primary();
        failAt(peek(), "expected ( or a function after FILTER");
    }
    ExprPtr bracketted() {
        Nested nested(*this);
        expectPunct("(");
        auto e = expression();
        expectPunct(")");
        return e;
    }
    static ExprPtr binary(Expr::Op op, ExprPtr a, ExprPtr b) {
        auto e = std::make_shared<Expr>();
        e->op = op;
        e->args = {std::move(a), std::move(b)};
        return e;
    }
    ExprPtr expression() {
        auto e = conjunction();
        while (acceptPunct("||")) e = binary(Expr::Op::Or, e, conjunction());
        return e;
    }
    ExprPtr conjunction() {
        auto e = relational();
        while (acceptPunct("&&")) e = binary(Expr::Op::And, e, relational());
        return e;
    }
    ExprPtr relational() {
        auto e = additive();
        static const std::pair<const char*, Expr::Op> ops[] = {
            {"=", Expr::Op::Eq},  {"!=", Expr::Op::Ne}, {"<", Expr::Op::Lt},
            {"<=", Expr::Op::Le}, {">", Expr::Op::Gt},  {">=", Expr::Op::Ge}};
        for (const auto& [text, op] : ops) {
            if (acceptPunct(text)) return binary(op, e, additive());
        }
        bool negated = false;
        if (isWordNamed(peek(), "NOT") && isWordNamed(peek(1), "IN")) {
            next();
            negated = true;
        }
        if (acceptWord("IN")) {
            auto in = std::make_shared<Expr>();
            in->op = negated ? Expr::Op::NotIn : Expr::Op::In;
            in->args.push_back(e);
            expectPunct("(");
            if (!acceptPunct(")")) {
                do {
                    in->args.push_back(expression());
                } while (acceptPunct(","));
                expectPunct(")");
            }
            return in;
        }
        return e;
    }
    ExprPtr additive() {
        auto e = multiplicative();
        for (;;) {
            if (acceptPunct("+")) {
                e = binary(Expr::Op::Add, e, multiplicative());
            } else if (acceptPunct("-")) {
                e = binary(Expr::Op::Sub, e, multiplicative());
            } else {
                return e;
            }
        }
    }
    ExprPtr multiplicative() {
        auto e = unary();
        for (;;) {
            if (acceptPunct("*")) {
                e = binary(Expr::Op::Mul, e, unary());
            } else if (acceptPunct("/")) {
                e = binary(Expr::Op::Div, e, unary());
            } else {
                return e;
            }
        }
    }
    ExprPtr unary() {
        Expr::Op op;
        if (acceptPunct("!")) {
            op = Expr::Op::Not;
        } else if (acceptPunct("-")) {
            op = Expr::Op::Neg;
        } else if (acceptPunct("+")) {
            op = Expr::Op::Plus;
        } else {
            return primary();
        }
        auto e = std::make_shared<Expr>();
        e->op = op;
        e->args.push_back(primary());
        return e;
    }
    ExprPtr primary() {
        Nested nested(*this);
        const Token& t = peek();
        if (isPunct(t, "(")) return bracketted();
        if (t.kind == Token::Kind::Var) return varExpr(next().text);
        if (isWord(t) && upper(t.text) != "TRUE" && upper(t.text) != "FALSE") return call();
        if (atIri() && isPunct(peek(1), "(")) {
            unsupported(
                t, "function call " + (t.kind == Token::Kind::Iri ? "<" + t.text + ">" : t.text));
        }
        auto c = constant();
        if (!c) failAt(t, "expected an expression, not '" + t.text + "'");
        auto e = std::make_shared<Expr>();
        e->op = Expr::Op::Const;
        e->value = std::move(*c);
        return e;
    }
    ExprPtr call() {
        const Token& t = next();
        std::string name = upper(t.text);
        auto e = std::make_shared<Expr>();
        if (name == "EXISTS" || (name == "NOT" && isWordNamed(peek(), "EXISTS"))) {
            if (name == "NOT") next();
            e->op = name == "NOT" ? Expr::Op::NotExists : Expr::Op::Exists;
            e->group = std::make_shared<GroupPattern>(group());
            return e;
        }
        static const std::map<std::string, std::pair<int, int>> arity = {
            {"BOUND", {1, 1}},       {"ISIRI", {1, 1}},    {"ISURI", {1, 1}},
            {"ISLITERAL", {1, 1}},   {"ISBLANK", {1, 1}},  {"ISNUMERIC", {1, 1}},
            {"STR", {1, 1}},         {"LANG", {1, 1}},     {"DATATYPE", {1, 1}},
            {"REGEX", {2, 3}},       {"CONTAINS", {2, 2}}, {"STRSTARTS", {2, 2}},
            {"STRENDS", {2, 2}},     {"STRLEN", {1, 1}},   {"LCASE", {1, 1}},
            {"UCASE", {1, 1}},       {"CONCAT", {0, 64}},  {"SAMETERM", {2, 2}},
            {"LANGMATCHES", {2, 2}}, {"IF", {3, 3}},       {"COALESCE", {0, 64}},
            {"ABS", {1, 1}},         {"IRI", {1, 1}},      {"URI", {1, 1}}};
        static const char* const aggregates[] = {"COUNT", "SUM",    "MIN",         "MAX",
                                                 "AVG",   "SAMPLE", "GROUP_CONCAT"};
        for (const char* a : aggregates) {
            if (name == a) unsupported(t, "aggregate " + name);
        }
        auto it = arity.find(name);
        if (it == arity.end()) {
            if (isPunct(peek(), "(")) unsupported(t, "function " + name);
            failAt(t, "unexpected '" + t.text + "' in an expression");
        }
        e->op = Expr::Op::Call;
        e->function = name;
        expectPunct("(");
        if (name == "BOUND") {
            e->args.push_back(varExpr(expect(Token::Kind::Var, "a variable in BOUND").text));
        } else if (!isPunct(peek(), ")")) {
            do {
                e->args.push_back(expression());
            } while (acceptPunct(","));
        }
        expectPunct(")");
        auto n = static_cast<int>(e->args.size());
        if (n < it->second.first || n > it->second.second) {
            failAt(t, name + " with " + std::to_string(n) + " arguments");
        }
        return e;
    }

    // Counts one level of nesting for as long as it lives.
    struct Nested {
        Nested(Parser& p) : parser(p) {
            if (++parser.depth_ > kMaxNesting) {
                failAt(parser.peek(), "nested more than " + std::to_string(kMaxNesting) + " deep");
            }
        }
        ~Nested() { --parser.depth_; }
        Parser& parser;
    };

    std::vector<Token> tokens_;
    int depth_ = 0;
    std::size_t pos_ = 0;
    std::unordered_map<std::string, std::string> prefixes_;
    std::string base_;
    std::vector<std::string> variables_;
    int anonCount_ = 0;
};

}  // namespace

Query parseQuery(std::string_view text) { return Parser(text).query(); }
Update parseUpdate(std::string_view text) { return Parser(text).update(); }

}  // namespace pnp::kb::sparql
