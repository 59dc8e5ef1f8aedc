// One knowledge base used from several threads (the detector's workers feed it, the MES
// queries it): every call is serialised by one mutex, so a KnowledgeBase implementation
// need not be thread-safe, and one feed update never interleaves with a query.
#pragma once

#include <memory>
#include <mutex>

#include "kb/knowledge_base.hpp"

namespace pnp::mes {

class SharedKb {
  public:
    explicit SharedKb(std::unique_ptr<kb::KnowledgeBase> kb) : kb_(std::move(kb)) {}
    kb::Results select(std::string_view q, kb::Deadline d) {
        std::lock_guard l(mutex_);
        return kb_->select(q, d);
    }
    bool ask(std::string_view q, kb::Deadline d) {
        std::lock_guard l(mutex_);
        return kb_->ask(q, d);
    }
    void update(std::string_view u, kb::Deadline d) {
        std::lock_guard l(mutex_);
        kb_->update(u, d);
    }
    std::size_t loadTurtle(const std::filesystem::path& f, const std::string& g, kb::Deadline d) {
        std::lock_guard l(mutex_);
        return kb_->loadTurtle(f, g, d);
    }
    std::string describe() const {
        std::lock_guard l(mutex_);
        return kb_->describe();
    }

  private:
    mutable std::mutex mutex_;
    std::unique_ptr<kb::KnowledgeBase> kb_;
};

// Standard prefixes prepended to the MES's own queries and to a process's pnp:query texts.
inline constexpr const char* kPrefixes =
    "PREFIX pnp: <urn:pnp:kb#>\n"
    "PREFIX cell: <urn:pnp:kb:cell#>\n"
    "PREFIX proc: <urn:pnp:kb:process#>\n"
    "PREFIX rdf: <http://www.w3.org/1999/02/22-rdf-syntax-ns#>\n"
    "PREFIX rdfs: <http://www.w3.org/2000/01/rdf-schema#>\n"
    "PREFIX xsd: <http://www.w3.org/2001/XMLSchema#>\n";

inline constexpr const char* kLiveGraph = "urn:pnp:kb:live";
inline constexpr const char* kExecutionsGraph = "urn:pnp:kb:executions";
inline constexpr const char* kLearnedGraph = "urn:pnp:kb:learned";

}  // namespace pnp::mes
