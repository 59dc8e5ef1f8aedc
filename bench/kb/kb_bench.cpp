// The embedded knowledge base on a thesis-sized KB (~2000 triples generated here): median time
// of the MES's typical queries (a process's steps with their parameters; the skills of a type
// or any subtype, through rdfs:subClassOf*), next to baselines measured in the same run: a
// plain full scan over the same triples (strings in a vector) and the smallest query (ASK {}).
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <vector>

#include "kb/knowledge_base.hpp"
#include "kb/turtle.hpp"

namespace {

using Clock = std::chrono::steady_clock;

double medianMicros(int runs, const std::function<void()>& f) {
    std::vector<double> t;
    t.reserve(static_cast<std::size_t>(runs));
    for (int i = 0; i < runs; ++i) {
        auto a = Clock::now();
        f();
        t.push_back(std::chrono::duration<double, std::micro>(Clock::now() - a).count());
    }
    std::sort(t.begin(), t.end());
    return t[t.size() / 2];
}

// Skill types (a 3-level hierarchy), components with skills, objects, processes with steps.
std::string generateKb() {
    std::string ttl =
        "@prefix pnp: <urn:pnp:kb#> .\n@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n"
        "@prefix c: <urn:pnp:kb:cell#> .\n";
    const char* families[] = {"Move", "Gripper", "ToolChange", "Vision", "Conveyor"};
    std::vector<std::string> leafTypes;
    ttl += "pnp:SkillType a rdfs:Class .\n";
    for (const char* f : families) {
        ttl += std::string("pnp:") + f + "SkillType rdfs:subClassOf pnp:SkillType .\n";
        for (int k = 0; k < 5; ++k) {
            std::string sub = std::string(f) + "Sub" + std::to_string(k) + "SkillType";
            ttl += "pnp:" + sub + " rdfs:subClassOf pnp:" + f + "SkillType .\n";
            for (int m = 0; m < 2; ++m) {
                std::string leaf = sub + "Leaf" + std::to_string(m);
                ttl += "pnp:" + leaf + " rdfs:subClassOf pnp:" + sub + " .\n";
                leafTypes.push_back(leaf);
            }
        }
    }
    for (int c = 0; c < 30; ++c) {
        std::string comp = "c:component" + std::to_string(c);
        ttl += comp +
               " a pnp:Component ; pnp:applicationUri \"urn:pnp:component:" + std::to_string(c) +
               "\" ; pnp:endpoint \"opc.tcp://127.0.0.1:" + std::to_string(4840 + c) + "\" .\n";
        for (int s = 0; s < 8; ++s) {
            std::string skill = "c:skill" + std::to_string(c) + "_" + std::to_string(s);
            const std::string& type =
                leafTypes[static_cast<std::size_t>(c * 8 + s) % leafTypes.size()];
            ttl += skill + " a pnp:" + type + " ; pnp:name \"Skill" + std::to_string(s) +
                   "\" ; pnp:component " + comp +
                   " ; pnp:endpoint \"opc.tcp://127.0.0.1:" + std::to_string(4840 + c) + "\" .\n";
        }
    }
    for (int o = 0; o < 40; ++o) {
        ttl += "c:object" + std::to_string(o) + " a pnp:Cube ; pnp:id \"object" +
               std::to_string(o) +
               "\" ; pnp:pose \"0.4,0.1,0.02,0,0,0\" ; pnp:size \"0.04,0.04,0.04\" .\n";
    }
    ttl += "pnp:Cube rdfs:subClassOf pnp:Object .\n";
    for (int p = 0; p < 12; ++p) {
        std::string proc = "c:process" + std::to_string(p);
        ttl += proc + " a pnp:Process .\n";
        for (int s = 0; s < 10; ++s) {
            std::string step = "c:p" + std::to_string(p) + "step" + std::to_string(s);
            ttl += proc + " pnp:step " + step + " .\n" + step + " pnp:index " +
                   std::to_string(s + 1) + " ; pnp:skillType pnp:" +
                   leafTypes[static_cast<std::size_t>(p + s) % leafTypes.size()] +
                   " ; pnp:parameter [ pnp:name \"Speed\" ; pnp:value 0.25 ] , [ pnp:name "
                   "\"Object\" ; "
                   "pnp:valueFrom c:object" +
                   std::to_string(s) + " ] .\n";
        }
    }
    return ttl;
}

}  // namespace

int main() {
    auto file = std::filesystem::temp_directory_path() /
                ("pnp-kb-bench-" + std::to_string(getpid()) + ".ttl");
    {
        std::ofstream out(file);
        out << generateKb();
    }
    auto deadline = [] { return Clock::now() + std::chrono::seconds(10); };
    auto kb = pnp::kb::open("");
    std::size_t triples = 0;
    double loadUs =
        medianMicros(1, [&] { triples = kb->loadTurtle(file, "urn:pnp:kb:bench", deadline()); });
    std::vector<pnp::kb::TermTriple> plain;
    double parseUs = medianMicros(1, [&] { plain = pnp::kb::parseTurtleFile(file, "b"); });
    std::filesystem::remove(file);

    const std::string prefix = "PREFIX pnp: <urn:pnp:kb#>\nPREFIX c: <urn:pnp:kb:cell#>\n";
    const std::string stepsQuery =
        prefix +
        "SELECT ?step ?index ?type ?name ?value ?from WHERE {\n"
        "  c:process7 pnp:step ?step . ?step pnp:index ?index ; pnp:skillType ?type .\n"
        "  OPTIONAL { ?step pnp:parameter ?p . ?p pnp:name ?name .\n"
        "    OPTIONAL { ?p pnp:value ?value } OPTIONAL { ?p pnp:valueFrom ?from } }\n"
        "} ORDER BY ?index ?name";
    const std::string skillQuery =
        prefix +
        "SELECT ?skill ?endpoint WHERE { ?skill a/rdfs:subClassOf* pnp:GripperSkillType ; "
        "pnp:endpoint ?endpoint }";
    const std::string objectQuery =
        prefix +
        "SELECT ?pose ?size WHERE { ?o a/rdfs:subClassOf* pnp:Object ; pnp:id \"object17\" ; "
        "pnp:pose ?pose ; pnp:size ?size }";

    std::size_t stepRows = kb->select(stepsQuery, deadline()).rows.size();
    std::size_t skillRows = kb->select(skillQuery, deadline()).rows.size();
    std::size_t objectRows = kb->select(objectQuery, deadline()).rows.size();
    const int runs = 2000;
    double steps = medianMicros(runs, [&] { kb->select(stepsQuery, deadline()); });
    double skills = medianMicros(runs, [&] { kb->select(skillQuery, deadline()); });
    double object = medianMicros(runs, [&] { kb->select(objectQuery, deadline()); });
    double ask = medianMicros(runs, [&] { kb->ask("ASK { }", deadline()); });
    std::size_t found = 0;
    double scan = medianMicros(runs, [&] {
        found = 0;
        for (const auto& t : plain) {
            found += t[1].value == "urn:pnp:kb#index" &&
                     t[0].value.starts_with("urn:pnp:kb:cell#p7step");
        }
    });

    std::printf(
        "knowledge base: %zu triples (%s), loaded from Turtle in %.1f ms (parsing: %.1f ms)\n",
        triples, kb->describe().c_str(), loadUs / 1000, parseUs / 1000);
    std::printf("%-58s %10s %6s\n", "query (embedded engine, median of 2000)", "us", "rows");
    std::printf("%-58s %10.1f %6zu\n", "process steps with parameters (OPTIONAL, ORDER BY)", steps,
                stepRows);
    std::printf("%-58s %10.1f %6zu\n", "skills of a type or subtype (a/rdfs:subClassOf*)", skills,
                skillRows);
    std::printf("%-58s %10.1f %6zu\n", "object pose by id (a/rdfs:subClassOf*)", object,
                objectRows);
    std::printf("%-58s %10.1f %6s\n", "baseline: ASK { } (parse + empty evaluation)", ask, "-");
    std::printf("%-58s %10.1f %6zu\n", "baseline: full scan of the triples as strings", scan,
                found);
    std::printf(
        "{\"triples\": %zu, \"load_ms\": %.2f, \"steps_us\": %.2f, \"skills_us\": %.2f, "
        "\"object_us\": %.2f, \"ask_us\": %.2f, \"scan_us\": %.2f}\n",
        triples, loadUs / 1000, steps, skills, object, ask, scan);
    return 0;
}
