#include "component/pickplace/knowledge.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <system_error>

#include "skill/model/model.hpp"
#include "ua/spatial/spatial.hpp"

namespace pnp::component::pickplace {

namespace {

constexpr const char* kPrefixes =
    "PREFIX pnp: <urn:pnp:kb#>\n"
    "PREFIX rdfs: <http://www.w3.org/2000/01/rdf-schema#>\n";

// Comma-separated finite numbers; exactly `count` of them (spaces around each allowed).
std::optional<std::vector<double>> numbers(std::string_view text, std::size_t count) {
    std::vector<double> out;
    for (std::size_t at = 0;;) {
        const std::size_t comma = text.find(',', at);
        std::string_view field =
            text.substr(at, comma == std::string_view::npos ? std::string_view::npos : comma - at);
        while (!field.empty() && field.front() == ' ') field.remove_prefix(1);
        while (!field.empty() && field.back() == ' ') field.remove_suffix(1);
        double v = 0;
        const auto [ptr, ec] = std::from_chars(field.data(), field.data() + field.size(), v);
        if (field.empty() || ec != std::errc() || ptr != field.data() + field.size() ||
            !std::isfinite(v) || out.size() == count)
            return std::nullopt;
        out.push_back(v);
        if (comma == std::string_view::npos) break;
        at = comma + 1;
    }
    if (out.size() != count) return std::nullopt;
    return out;
}

// The binding of `variable` in row `row` (Results::get without pnp_kb's object code).
const kb::Term* binding(const kb::Results& r, std::size_t row, std::string_view variable) {
    for (std::size_t j = 0; j < r.variables.size(); ++j)
        if (r.variables[j] == variable && row < r.rows.size() && j < r.rows[row].size() &&
            r.rows[row][j])
            return &*r.rows[row][j];
    return nullptr;
}

}  // namespace

bool validObjectId(std::string_view id) {
    if (id.empty() || id.size() > 128) return false;
    return std::all_of(id.begin(), id.end(), [](char c) {
        return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
               c == '.' || c == '_' || c == '-';
    });
}

std::optional<Eigen::Isometry3d> parsePose(std::string_view text) {
    auto v = numbers(text, 6);
    if (!v) return std::nullopt;
    ua::ThreeDFrame f;
    f.cartesianCoordinates = {(*v)[0], (*v)[1], (*v)[2]};
    f.orientation = {(*v)[3], (*v)[4], (*v)[5]};
    return ua::spatial::toIsometry(f);
}

std::optional<Eigen::Vector3d> parseSize(std::string_view text) {
    auto v = numbers(text, 3);
    if (!v) return std::nullopt;
    return Eigen::Vector3d((*v)[0], (*v)[1], (*v)[2]);
}

std::string poseText(const Eigen::Isometry3d& pose) {
    const ua::ThreeDFrame f = ua::spatial::toFrame(pose);
    char buf[200];
    std::snprintf(buf, sizeof buf, "%.6f,%.6f,%.6f,%.6f,%.6f,%.6f", f.cartesianCoordinates.x,
                  f.cartesianCoordinates.y, f.cartesianCoordinates.z, f.orientation.a,
                  f.orientation.b, f.orientation.c);
    return buf;
}

std::optional<ObjectInfo> lookupObject(kb::KnowledgeBase& kb, const std::string& id,
                                       kb::Deadline deadline, std::string& error) {
    if (!validObjectId(id)) {
        error = "ObjectId \"" + id.substr(0, 140) +
                "\" is not an object id (1-128 letters, digits, '.', '_', '-')";
        return std::nullopt;
    }
    const std::string query =
        std::string(kPrefixes) +
        "SELECT DISTINCT ?pose ?size WHERE { ?o a/rdfs:subClassOf* pnp:Object ; pnp:id \"" + id +
        "\" ; pnp:pose ?pose ; pnp:size ?size } LIMIT 10";
    kb::Results r;
    try {
        r = kb.select(query, deadline);
    } catch (const std::exception& e) {
        error = "the knowledge base (" + kb.describe() + "): " + e.what();
        return std::nullopt;
    }
    if (r.rows.empty()) {
        error = "no object with pnp:id \"" + id +
                "\" (with pnp:pose and pnp:size) in the knowledge base";
        return std::nullopt;
    }
    if (r.rows.size() > 1) {
        error = "the knowledge base has " + std::to_string(r.rows.size()) +
                " different poses / sizes for object \"" + id + "\"";
        return std::nullopt;
    }
    const kb::Term* pose = binding(r, 0, "pose");
    const kb::Term* size = binding(r, 0, "size");
    if (pose == nullptr || size == nullptr) {
        error = "the knowledge base's answer for \"" + id + "\" has no ?pose / ?size";
        return std::nullopt;
    }
    ObjectInfo o;
    o.id = id;
    auto p = parsePose(pose->value);
    auto s = parseSize(size->value);
    if (!p) {
        error = "pnp:pose of \"" + id + "\" is not \"x,y,z,a,b,c\": \"" +
                pose->value.substr(0, 100) + "\"";
        return std::nullopt;
    }
    if (!s) {
        error =
            "pnp:size of \"" + id + "\" is not \"x,y,z\": \"" + size->value.substr(0, 100) + "\"";
        return std::nullopt;
    }
    o.pose = *p;
    o.size = *s;
    return o;
}

void storeObjectPose(kb::KnowledgeBase& kb, const std::string& id, const Eigen::Isometry3d& pose,
                     kb::Deadline deadline) {
    if (!validObjectId(id)) throw kb::KbError("not an object id: " + id.substr(0, 140));
    const std::string text = poseText(pose);
    // The pose is replaced in the graph it came from (the default graph is the union).
    kb.update(std::string(kPrefixes) +
                  "DELETE { GRAPH ?g { ?o pnp:pose ?old } } INSERT { GRAPH ?g { ?o pnp:pose \"" +
                  text + "\" } } WHERE { ?o pnp:id \"" + id +
                  "\" . GRAPH ?g { ?o pnp:pose ?old } }",
              deadline);
}

std::vector<std::filesystem::path> defaultKnowledgeFiles() {
    std::vector<std::filesystem::path> out;
    std::error_code ec;
    const auto dir = skill::modelsDirectory() / "kb";
    for (const auto& e : std::filesystem::directory_iterator(dir, ec))
        if (e.is_regular_file(ec) && e.path().extension() == ".ttl") out.push_back(e.path());
    std::sort(out.begin(), out.end());
    return out;
}

}  // namespace pnp::component::pickplace
