// The knowledge-base test suite shared by both backends: kb_suite_test.cpp holds the tests,
// each test program instantiates them for its backend ("embedded" or "virtuoso") and defines
// openBackend().
#pragma once

#include <gtest/gtest.h>

#include <chrono>
#include <memory>
#include <string>
#include <vector>

#include "kb/knowledge_base.hpp"

namespace pnp::kb::test {

// A fresh knowledge base of backend `name` (the Virtuoso one is shared: tests clear their graphs).
std::unique_ptr<KnowledgeBase> openBackend(const std::string& name);

inline const std::string kGraph = "urn:pnp:test:graph:cell";
inline const std::string kOtherGraph = "urn:pnp:test:graph:other";
inline const std::string kUpdateGraph = "urn:pnp:test:graph:updates";
inline const std::string kPrefix = "PREFIX t: <urn:pnp:test#>\n";
inline const std::string kT = "urn:pnp:test#";

inline Deadline soon(std::chrono::seconds s = std::chrono::seconds(20)) {
    return std::chrono::steady_clock::now() + s;
}

inline std::string dataFile(const std::string& name) {
    return std::string(PNP_KB_TEST_DATA) + "/" + name;
}

// The values of `variable` in every row ("-" when unbound).
inline std::vector<std::string> column(const Results& r, const std::string& variable) {
    std::vector<std::string> out;
    for (std::size_t i = 0; i < r.rows.size(); ++i) {
        const Term* t = r.get(i, variable);
        out.push_back(t ? t->value : "-");
    }
    return out;
}

}  // namespace pnp::kb::test
