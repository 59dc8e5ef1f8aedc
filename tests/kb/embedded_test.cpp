// The embedded engine alone: unsupported syntax refused with its position, the bounds, the
// union default graph, helpers. (The shared query suite is kb_suite_test.cpp.)
#include <unistd.h>

#include <fstream>

#include "kb_suite.hpp"

namespace pnp::kb::test {

std::unique_ptr<KnowledgeBase> openBackend(const std::string& name) {
    EXPECT_EQ(name, "embedded");
    return open("");
}

namespace {

std::string errorOf(const std::function<void()>& f) {
    try {
        f();
    } catch (const KbError& e) {
        return e.what();
    }
    return "(no error)";
}

class EmbeddedKb : public ::testing::Test {
  protected:
    void SetUp() override { kb->loadTurtle(dataFile("cell.ttl"), kGraph, soon()); }
    std::string selectError(const std::string& q) {
        return errorOf([&] { kb->select(q, soon()); });
    }
    std::unique_ptr<KnowledgeBase> kb = open("embedded");
};

TEST(KbOpen, LocationsAndHelpers) {
    EXPECT_EQ(open("")->describe(), "embedded (0 triples)");
    EXPECT_THROW(open("ftp://x/sparql"), KbError);
    EXPECT_THROW(open("https://x/sparql"), KbError);
    EXPECT_THROW(open("http://host:99999/sparql"), KbError);
    EXPECT_THROW(open("http://:80/sparql"), KbError);
    EXPECT_EQ(open("http://127.0.0.1:8890/sparql")->describe(), "http://127.0.0.1:8890/sparql");
    EXPECT_EQ(iri("urn:a#b"), "<urn:a#b>");
    EXPECT_THROW(iri("urn:a>b"), KbError);
    EXPECT_THROW(iri("urn:a b"), KbError);
    EXPECT_THROW(iri(""), KbError);
    EXPECT_EQ(literal("a\"b\\c\nd"), "\"a\\\"b\\\\c\\nd\"");
    Term t{Term::Kind::Literal, "1.5", "http://www.w3.org/2001/XMLSchema#decimal", ""};
    EXPECT_DOUBLE_EQ(t.number(), 1.5);
    EXPECT_THROW((Term{Term::Kind::Literal, "1.5", "", ""}.number()), KbError);
    EXPECT_THROW(
        (Term{Term::Kind::Literal, "x", "http://www.w3.org/2001/XMLSchema#integer", ""}.number()),
        KbError);
}

TEST(KbEndpoint, DeadServerIsAClearError) {
    // A port nothing listens on: the connection is refused at once.
    auto kb = open("http://127.0.0.1:1/sparql");
    auto what = errorOf([&] { kb->select("SELECT ?s WHERE { ?s ?p ?o }", soon()); });
    EXPECT_NE(what.find("http://127.0.0.1:1/sparql"), std::string::npos) << what;
    EXPECT_NE(what.find("connect"), std::string::npos) << what;  // "Couldn't connect to server"
}

TEST_F(EmbeddedKb, DescribeCountsTriples) { EXPECT_EQ(kb->describe(), "embedded (50 triples)"); }

TEST_F(EmbeddedKb, UnsupportedSyntaxIsRefusedWithPosition) {
    EXPECT_EQ(selectError("SELECT (COUNT(?s) AS ?n) WHERE { ?s ?p ?o }"),
              "SPARQL 1:9: unsupported: aggregate COUNT");
    EXPECT_EQ(selectError("CONSTRUCT { ?s ?p ?o } WHERE { ?s ?p ?o }"),
              "SPARQL 1:1: unsupported: CONSTRUCT");
    EXPECT_EQ(selectError("DESCRIBE <urn:a>"), "SPARQL 1:1: unsupported: DESCRIBE");
    EXPECT_EQ(selectError("SELECT ?s WHERE { ?s ?p ?o }\nGROUP BY ?s"),
              "SPARQL 2:1: unsupported: GROUP BY");
    EXPECT_EQ(selectError("SELECT ?s FROM <urn:g> WHERE { ?s ?p ?o }"),
              "SPARQL 1:11: unsupported: FROM");
    EXPECT_EQ(selectError("SELECT ?s WHERE {\n  SERVICE <http://x/> { ?s ?p ?o } }"),
              "SPARQL 2:3: unsupported: SERVICE");
    EXPECT_EQ(selectError("SELECT ?s WHERE { { SELECT ?s WHERE { ?s ?p ?o } } }"),
              "SPARQL 1:21: unsupported: subquery");
    EXPECT_EQ(selectError("SELECT ?s WHERE { ?s ?p (1 2) }"),
              "SPARQL 1:25: unsupported: RDF collection ( ... )");
    EXPECT_EQ(selectError("SELECT ?s WHERE { ?s ?p ?o FILTER(<urn:f>(?o)) }"),
              "SPARQL 1:35: unsupported: function call <urn:f>");
    EXPECT_EQ(selectError("SELECT ?s WHERE { ?s ?p ?o FILTER(STRBEFORE(?o, \"x\")) }"),
              "SPARQL 1:35: unsupported: function STRBEFORE");
    EXPECT_EQ(errorOf([&] { kb->update("LOAD <http://x/y.ttl>", soon()); }),
              "SPARQL 1:1: unsupported: LOAD");
    EXPECT_EQ(errorOf([&] {
                  kb->update("DELETE { ?s ?p ?o } USING <urn:g> WHERE { ?s ?p ?o }", soon());
              }),
              "SPARQL 1:21: unsupported: USING");
}

TEST_F(EmbeddedKb, SyntaxErrorsNameThePosition) {
    EXPECT_EQ(selectError("SELECT ?s WHERE { ?s x:p ?o }"), "SPARQL 1:22: unknown prefix 'x:'");
    EXPECT_EQ(selectError("SELECT ?s WHERE {\n ?s <urn:p> ?o"),
              "SPARQL 2:15: expected '}' (at the end)");
    EXPECT_EQ(selectError("SELECT ?s WHERE { ?s <urn:p> \"open }"),
              "SPARQL 1:30: unterminated string");
    EXPECT_EQ(selectError("SELECT WHERE { ?s ?p ?o }"),
              "SPARQL 1:8: expected variables or * after SELECT");
    EXPECT_EQ(selectError("ASK { ?s ?p ?o }"), "SPARQL: select() needs a SELECT query");
    EXPECT_EQ(errorOf([&] { kb->ask("SELECT * WHERE { ?s ?p ?o }", soon()); }),
              "SPARQL: ask() needs an ASK query");
    EXPECT_EQ(errorOf([&] { kb->update("INSERT DATA { ?s <urn:p> 1 }", soon()); }),
              "SPARQL 1:13: variables in INSERT DATA / DELETE DATA");
}

TEST_F(EmbeddedKb, SelectStarAndProjectionExpressions) {
    auto r = kb->select(kPrefix + "SELECT * WHERE { t:grasp t:force ?f ; rdfs:label ?l }", soon());
    EXPECT_EQ(r.variables, (std::vector<std::string>{"f", "l"}));
    r = kb->select(kPrefix + "SELECT ?s (?f + 1 AS ?g) WHERE { ?s t:force ?f } ORDER BY DESC(?g)",
                   soon());
    ASSERT_EQ(r.rows.size(), 2u);
    EXPECT_EQ(r.get(0, "g")->value, "41");
    EXPECT_EQ(r.get(1, "g")->value, "13.5");
}

TEST_F(EmbeddedKb, UnionDefaultGraphHoldsATripleOnce) {
    kb->loadTurtle(dataFile("other.ttl"), kOtherGraph, soon());
    auto r =
        kb->select(kPrefix + "SELECT ?c WHERE { t:GraspSkillType rdfs:subClassOf ?c }", soon());
    EXPECT_EQ(r.rows.size(), 1u);
    // Deleting without GRAPH removes it from the union, i.e. from every graph.
    kb->update(kPrefix + "DELETE DATA { t:GraspSkillType rdfs:subClassOf t:GripperSkillType }",
               soon());
    EXPECT_FALSE(
        kb->ask(kPrefix + "ASK { GRAPH ?g { t:GraspSkillType rdfs:subClassOf ?c } }", soon()));
    // Inserting without GRAPH goes to the default graph, part of the union.
    kb->update(kPrefix + "INSERT DATA { t:a t:b t:c }", soon());
    EXPECT_TRUE(
        kb->ask(kPrefix + "ASK { GRAPH <urn:pnp:kb:default-graph> { t:a t:b t:c } }", soon()));
}

TEST_F(EmbeddedKb, BlankNodesInInsertTemplatesAreFreshPerSolution) {
    kb->update(
        kPrefix + "INSERT { GRAPH <urn:g> { ?s t:tag [ t:of ?s ] } } WHERE { ?s t:force ?f }",
        soon());
    auto r = kb->select(kPrefix + "SELECT ?b WHERE { ?s t:tag ?b . ?b t:of ?s }", soon());
    ASSERT_EQ(r.rows.size(), 2u);
    EXPECT_EQ(r.get(0, "b")->kind, Term::Kind::Blank);
    EXPECT_NE(r.get(0, "b")->value, r.get(1, "b")->value);
}

TEST_F(EmbeddedKb, WithNegatedPathsAndNestedGroups) {
    kb->update(kPrefix + "WITH <" + kGraph +
                   "> DELETE { ?s t:force ?f } INSERT { ?s t:force 1 } "
                   "WHERE { ?s t:force ?f FILTER(?f > 20) }",
               soon());
    auto r = kb->select(
        kPrefix + "SELECT ?f WHERE { GRAPH <" + kGraph + "> { t:grasp t:force ?f } }", soon());
    ASSERT_EQ(r.rows.size(), 1u);
    EXPECT_EQ(r.get(0, "f")->value, "1");
    // Everything t:moveL points to except through rdf:type and rdfs:label.
    r = kb->select(kPrefix + "SELECT ?o WHERE { t:moveL !(a|rdfs:label) ?o }", soon());
    EXPECT_EQ(column(r, "o"), (std::vector<std::string>{"opc.tcp://127.0.0.1:4841"}));
    EXPECT_TRUE(
        kb->ask(kPrefix + "ASK { { { t:moveL a ?c } } { ?c rdfs:subClassOf ?d } }", soon()));
    kb->update("DROP ALL", soon());
    EXPECT_EQ(kb->describe(), "embedded (0 triples)");
}

TEST_F(EmbeddedKb, QueryTextAndNestingAreBounded) {
    std::string big = "SELECT ?s WHERE { ?s ?p ?o } #" + std::string(70000, 'x');
    EXPECT_NE(selectError(big).find("more than 65536"), std::string::npos);
    auto repeat = [](const std::string& s, int n) {
        std::string out;
        for (int i = 0; i < n; ++i) out += s;
        return out;
    };
    for (const auto& q : {"SELECT * WHERE " + repeat("{", 5000),
                          "SELECT * WHERE { ?s ?p ?o FILTER" + repeat("(", 5000),
                          kPrefix + "SELECT * WHERE { ?s t:p " + repeat("[ t:p ", 5000)}) {
        auto what = selectError(q);
        EXPECT_NE(what.find("nested more than 64 deep"), std::string::npos) << what;
    }
}

TEST_F(EmbeddedKb, DeadlineInThePastIsAnError) {
    auto past = std::chrono::steady_clock::now() - std::chrono::seconds(1);
    // Enough work to reach a deadline check.
    std::string q = "SELECT * WHERE { ?a ?b ?c . ?d ?e ?f }";
    EXPECT_THROW(kb->select(q, past), KbError);
    EXPECT_THROW(kb->update("CLEAR ALL", past), KbError);
}

TEST(KbBounds, ResultRowsAndIntermediateSolutionsAreBounded) {
    auto kb = open("");
    // 400 x 300 = 120000 combinations from 700 triples.
    std::string data;
    for (int i = 0; i < 400; ++i) data += "<urn:a" + std::to_string(i) + "> <urn:p> 1 . ";
    for (int i = 0; i < 300; ++i) data += "<urn:b" + std::to_string(i) + "> <urn:q> 2 . ";
    kb->update("INSERT DATA { GRAPH <urn:g> { " + data + " } }", soon());
    const std::string cross = "SELECT ?a ?b WHERE { ?a <urn:p> 1 . ?b <urn:q> 2 }";
    auto what = errorOf([&] { kb->select(cross, soon()); });
    EXPECT_NE(what.find("more than 100000 results"), std::string::npos) << what;
    EXPECT_EQ(kb->select(cross + " LIMIT 10", soon()).rows.size(), 10u);
    // Three-way: 400 x 300 x 400 > 1,000,000 intermediate solutions.
    what = errorOf([&] {
        kb->select("SELECT * WHERE { ?a <urn:p> 1 . ?b <urn:q> 2 . ?c <urn:p> 1 }", soon());
    });
    EXPECT_NE(what.find("intermediate solutions"), std::string::npos) << what;
}

TEST(KbBounds, PropertyPathSearchIsBounded) {
    // A chain of 100001 links: rdfs:subClassOf* from its start visits every node.
    auto file = std::filesystem::temp_directory_path() /
                ("pnp-kb-chain-" + std::to_string(getpid()) + ".ttl");
    {
        std::ofstream out(file);
        for (int i = 0; i <= 100001; ++i)
            out << "<urn:n" << i << "> <urn:next> <urn:n" << i + 1 << "> .\n";
    }
    auto kb = open("");
    EXPECT_EQ(kb->loadTurtle(file, "urn:g", soon()), 100002u);
    std::filesystem::remove(file);
    auto what = errorOf([&] { kb->select("SELECT ?x WHERE { <urn:n0> <urn:next>* ?x }", soon()); });
    EXPECT_NE(what.find("visited more than 100000 nodes"), std::string::npos) << what;
    EXPECT_TRUE(kb->ask("ASK { <urn:n99990> <urn:next>+ <urn:n100000> }", soon()));
}

TEST(KbBounds, TurtleFileSizeIsBounded) {
    auto file = std::filesystem::temp_directory_path() /
                ("pnp-kb-big-" + std::to_string(getpid()) + ".ttl");
    { std::ofstream out(file); }
    std::filesystem::resize_file(file, (16u << 20) + 1);  // sparse: nothing is written
    auto kb = open("");
    auto what = errorOf([&] { kb->loadTurtle(file, "urn:g", soon()); });
    std::filesystem::remove(file);
    EXPECT_NE(what.find("more than the 16777216"), std::string::npos) << what;
}

}  // namespace
}  // namespace pnp::kb::test
