// The parsed form of a SPARQL query or update (internal to pnp_kb).
#pragma once

#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "kb/knowledge_base.hpp"

namespace pnp::kb::sparql {

// A variable (index into the query's variable table) or a constant term.
struct Node {
    int var = -1;  // >= 0: a variable
    Term term;
    bool isVar() const { return var >= 0; }
};

struct Path;
using PathPtr = std::shared_ptr<const Path>;
struct Path {
    enum class Op {
        Link,
        Inverse,
        Sequence,
        Alternative,
        ZeroOrMore,
        OneOrMore,
        ZeroOrOne,
        Negated
    };
    Op op = Op::Link;
    Term iri;                    // Link
    std::vector<PathPtr> parts;  // Inverse/ZeroOr../OneOrMore: one; Sequence/Alternative: many
    std::vector<std::pair<Term, bool>> negated;  // Negated: (iri, inverse)
};

struct TriplePattern {
    Node s, p, o;
    PathPtr path;  // set when the predicate is a property path, not a plain IRI or variable
};

struct GroupPattern;
struct Expr;
using ExprPtr = std::shared_ptr<const Expr>;
struct Expr {
    enum class Op {
        Var,
        Const,
        Or,
        And,
        Not,
        Eq,
        Ne,
        Lt,
        Le,
        Gt,
        Ge,
        Add,
        Sub,
        Mul,
        Div,
        Neg,
        Plus,
        In,
        NotIn,
        Call,
        Exists,
        NotExists
    };
    Op op = Op::Const;
    int var = -1;
    Term value;
    std::string function;  // Call: upper-case name
    std::vector<ExprPtr> args;
    std::shared_ptr<const GroupPattern> group;  // Exists / NotExists
};

struct Element {
    enum class Kind { Triples, Filter, Optional, Union, Minus, Bind, Values, Graph, Group };
    Kind kind = Kind::Triples;
    std::vector<TriplePattern> triples;
    ExprPtr expr;                      // Filter, Bind
    int var = -1;                      // Bind
    std::vector<GroupPattern> groups;  // Optional/Minus/Graph/Group: one; Union: many
    std::vector<int> vars;             // Values
    std::vector<std::vector<std::optional<Term>>> rows;  // Values
    Node graph;                                          // Graph
};

struct GroupPattern {
    std::vector<Element> elements;
};

struct OrderCondition {
    ExprPtr expr;
    bool descending = false;
};

struct Projection {
    int var = -1;
    ExprPtr expr;  // (expr AS ?var), else null
};

struct Query {
    enum class Form { Select, Ask };
    Form form = Form::Select;
    std::vector<std::string> variables;  // the variable table; "_:..." are blank nodes
    bool distinct = false;
    bool selectAll = false;
    std::vector<Projection> projection;
    GroupPattern where;
    std::vector<OrderCondition> orderBy;
    std::size_t limit = std::numeric_limits<std::size_t>::max();
    std::size_t offset = 0;
};

struct QuadTemplate {
    std::optional<Node> graph;  // GRAPH <g> / GRAPH ?g { ... }; none: the default graph
    TriplePattern triple;       // never a path
};

struct UpdateOperation {
    enum class Kind { InsertData, DeleteData, Modify, Clear, Drop, Create };
    enum class Target { Graph, Default, Named, All };
    Kind kind = Kind::InsertData;
    std::vector<QuadTemplate> deletes, inserts;  // the data of INSERT/DELETE DATA is in these
    GroupPattern where;
    std::optional<Term> with;  // WITH <g>
    Target target = Target::Graph;
    Term graph;  // CLEAR/DROP/CREATE GRAPH <g>
};

struct Update {
    std::vector<std::string> variables;
    std::vector<UpdateOperation> operations;
};

// Throw KbError "SPARQL line:col: ..." for malformed or unsupported text.
Query parseQuery(std::string_view text);
Update parseUpdate(std::string_view text);

inline constexpr std::string_view kXsd = "http://www.w3.org/2001/XMLSchema#";
inline constexpr std::string_view kRdf = "http://www.w3.org/1999/02/22-rdf-syntax-ns#";

}  // namespace pnp::kb::sparql
