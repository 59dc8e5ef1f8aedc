// The skill detector feeds the knowledge base live (graph urn:pnp:kb:live): each component
// (by ApplicationUri: name, endpoint) and each skill it offers (name, type IRI, node,
// controller) is inserted when the detector finds it and deleted when it goes, so a SPARQL
// query sees the cell as it is now. The feed also keeps the detector's view of each skill by
// its IRI, for the MES to connect to the one the knowledge base chose.
#pragma once

#include <chrono>
#include <map>
#include <mutex>
#include <optional>
#include <string>

#include "mes/shared_kb.hpp"
#include "skill/detector/skill_detector.hpp"

namespace pnp::mes {

class KbFeed {
  public:
    // Clears the live graph (this MES owns it).
    KbFeed(SharedKb& kb, std::chrono::milliseconds timeout);

    // From the detector's change callback.
    void changed(const skill::detector::DetectedSkill& skill, bool added);

    std::optional<skill::detector::DetectedSkill> skill(const std::string& iri) const;
    std::size_t skills() const;
    // Updates that failed (the KB's error is logged through `log`).
    std::size_t errors() const;
    std::function<void(const std::string&)> log;

    static std::string componentIri(const std::string& applicationUri);
    static std::string skillIri(const skill::detector::DetectedSkill& skill);

  private:
    void run(const std::string& update);
    SharedKb& kb_;
    std::chrono::milliseconds timeout_;
    mutable std::mutex mutex_;
    std::map<std::string, skill::detector::DetectedSkill> skills_;  // by skill IRI
    std::map<std::string, std::size_t> perComponent_;               // skills per component IRI
    std::size_t errors_ = 0;
};

}  // namespace pnp::mes
