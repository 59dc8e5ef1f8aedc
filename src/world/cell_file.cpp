#include "world/cell_file.hpp"

#include <yaml-cpp/yaml.h>

#include <cctype>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <initializer_list>
#include <map>
#include <numbers>
#include <optional>
#include <sstream>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

namespace pnp::world {
namespace {

// Limits beyond which a number is a mistake rather than a cell (a typo in the exponent, cm
// written as m ...). Documented in docs/cell-file.md.
constexpr double kMaxCoordinate = 100.0;  // m, |x|, |y|, |z| of any position
constexpr double kMaxAngle = 2.0 * std::numbers::pi + 1e-9;
constexpr double kMaxSize = 100.0;         // m, box edges
constexpr double kMaxToolMass = 50.0;      // kg
constexpr double kMaxObjectMass = 1000.0;  // kg
constexpr double kMaxGripperSpan = 1.0;    // m, stroke and cup diameter
constexpr std::size_t kMaxNameLength = 64;

// The first problem found; thrown inside the parser only, caught at the API boundary.
struct Failure {
    Error error;
};

[[noreturn]] void failAt(const std::string& file, ErrorCode code, int line,
                         const std::string& what) {
    std::string message = file;
    if (line > 0) message += ":" + std::to_string(line);
    throw Failure{Error{code, message + ": " + what, line}};
}

int lineOf(const YAML::Node& node) {
    const int line = node.Mark().line;  // 0-based; -1 for nodes without a position
    return line >= 0 ? line + 1 : 1;
}

// Text from the file quoted in a message, shortened: a message stays readable (and small)
// whatever the file holds.
std::string clip(const std::string& text) {
    constexpr std::size_t kMax = 40;
    return text.size() <= kMax ? text : text.substr(0, kMax) + "...";
}

std::string describe(const YAML::Node& node) {
    switch (node.Type()) {
        case YAML::NodeType::Null:
            return "nothing";
        case YAML::NodeType::Sequence:
            return "a list";
        case YAML::NodeType::Map:
            return "a mapping";
        case YAML::NodeType::Scalar:
            return "'" + clip(node.Scalar()) + "'";
        default:
            return "an undefined node";
    }
}

std::string withArticle(const std::string& noun) {
    const bool vowel =
        !noun.empty() && std::string_view("aeiou").find(noun[0]) != std::string_view::npos;
    return (vowel ? "an " : "a ") + noun;
}

std::string joined(std::initializer_list<std::string_view> words) {
    std::string out;
    for (std::string_view w : words) {
        if (!out.empty()) out += ", ";
        out += w;
    }
    return out;
}

std::string formatNumber(double v) {
    std::ostringstream s;
    s << v;
    return s.str();
}

// A value in the file with where it is, for messages.
struct Field {
    YAML::Node node;
    int line = 1;
    std::string path;  // e.g. robots[0].home
};

class Parser {
  public:
    explicit Parser(std::string file) : file_(std::move(file)) {}

    CellDescription parse(std::string_view text);

  private:
    // The keys of one mapping, in file order. Repeated keys fail here: yaml-cpp keeps both
    // and a lookup would silently take one.
    class Mapping {
      public:
        Mapping(const Parser& p, Field field) : p_(p), field_(std::move(field)) {
            if (!field_.node.IsMap()) {
                p.fail(ErrorCode::kWrongType, field_,
                       "expected a mapping, got " + describe(field_.node));
            }
            std::map<std::string, int, std::less<>> keyLines;
            for (const auto& kv : field_.node) {
                if (!kv.first.IsScalar()) {
                    p.fail(ErrorCode::kWrongType, lineOf(kv.first),
                           where() + "keys must be plain words, got " + describe(kv.first));
                }
                const std::string key = kv.first.Scalar();
                // A map, not a scan: a hostile file may hold 10^5 keys in one mapping.
                auto [it, inserted] = keyLines.try_emplace(key, lineOf(kv.first));
                if (!inserted) {
                    p.fail(ErrorCode::kUnknownKey, lineOf(kv.first),
                           where() + "key '" + clip(key) + "' repeated (first at line " +
                               std::to_string(it->second) + ")");
                }
                entries_.push_back({key, lineOf(kv.first), kv.second});
            }
        }

        // Typo protection: every key must be one the format has here.
        void allowOnly(std::initializer_list<std::string_view> allowed) const {
            for (const Entry& e : entries_) {
                bool known = false;
                for (std::string_view a : allowed) known = known || a == e.key;
                if (!known) {
                    p_.fail(ErrorCode::kUnknownKey, e.keyLine,
                            where() + "unknown key '" + clip(e.key) +
                                "' (allowed: " + joined(allowed) + ")");
                }
            }
        }

        std::optional<Field> get(std::string_view key) const {
            for (const Entry& e : entries_) {
                if (e.key == key) {
                    // A key with nothing after it has no useful position of its own.
                    const int line = e.value.IsNull() ? e.keyLine : lineOf(e.value);
                    return Field{e.value, line, sub(key)};
                }
            }
            return std::nullopt;
        }

        Field require(std::string_view key) const {
            if (auto f = get(key)) return *f;
            p_.fail(ErrorCode::kMissingKey, field_.line,
                    where() + "missing key '" + std::string(key) + "'");
        }

        struct Entry {
            std::string key;
            int keyLine;
            YAML::Node value;
        };
        const std::vector<Entry>& entries() const { return entries_; }
        std::string sub(std::string_view key) const {
            return field_.path.empty() ? std::string(key) : field_.path + "." + std::string(key);
        }

      private:
        std::string where() const { return field_.path.empty() ? "" : field_.path + ": "; }

        const Parser& p_;
        Field field_;
        std::vector<Entry> entries_;
    };

    [[noreturn]] void fail(ErrorCode code, int line, const std::string& what) const {
        failAt(file_, code, line, what);
    }
    [[noreturn]] void fail(ErrorCode code, const Field& f, const std::string& what) const {
        fail(code, f.line, f.path + ": " + what);
    }

    std::string readString(const Field& f) const {
        if (!f.node.IsScalar()) {
            fail(ErrorCode::kWrongType, f, "expected a string, got " + describe(f.node));
        }
        return f.node.Scalar();
    }

    double readNumber(const Field& f) const {
        double v = 0.0;
        if (!f.node.IsScalar() || !YAML::convert<double>::decode(f.node, v)) {
            fail(ErrorCode::kWrongType, f, "expected a number, got " + describe(f.node));
        }
        if (!std::isfinite(v)) fail(ErrorCode::kOutOfRange, f, "must be a finite number");
        return v;
    }

    double readNumberIn(const Field& f, double min, double max, bool minExclusive) const {
        const double v = readNumber(f);
        if (v > max || v < min || (minExclusive && v == min)) {
            fail(ErrorCode::kOutOfRange, f,
                 formatNumber(v) + " is out of range " + (minExclusive ? "(" : "[") +
                     formatNumber(min) + ", " + formatNumber(max) + "]");
        }
        return v;
    }

    long long readInteger(const Field& f, long long min, long long max) const {
        long long v = 0;
        if (!f.node.IsScalar() || !YAML::convert<long long>::decode(f.node, v)) {
            fail(ErrorCode::kWrongType, f, "expected an integer, got " + describe(f.node));
        }
        if (v < min || v > max) {
            fail(ErrorCode::kOutOfRange, f,
                 std::to_string(v) + " is out of range [" + std::to_string(min) + ", " +
                     std::to_string(max) + "]");
        }
        return v;
    }

    // The elements of a list of exactly `count` (0 = any) items.
    std::vector<Field> readList(const Field& f, std::size_t count) const {
        if (!f.node.IsSequence()) {
            fail(ErrorCode::kWrongType, f, "expected a list, got " + describe(f.node));
        }
        if (count != 0 && f.node.size() != count) {
            fail(ErrorCode::kWrongType, f,
                 "expected " + std::to_string(count) + " values, got " +
                     std::to_string(f.node.size()));
        }
        std::vector<Field> items;
        std::size_t i = 0;
        for (const auto& n : f.node) {
            items.push_back({n, lineOf(n), f.path + "[" + std::to_string(i++) + "]"});
        }
        return items;
    }

    Eigen::Vector3d readVector3(const Field& f, double min, double max, bool minExclusive) const {
        const std::vector<Field> items = readList(f, 3);
        return {readNumberIn(items[0], min, max, minExclusive),
                readNumberIn(items[1], min, max, minExclusive),
                readNumberIn(items[2], min, max, minExclusive)};
    }

    Eigen::Vector3d readSize(const Field& f) const { return readVector3(f, 0.0, kMaxSize, true); }

    Eigen::Isometry3d readPose(const Field& f) const {
        Mapping m(*this, f);
        m.allowOnly({"xyz", "rpy"});
        const Eigen::Vector3d xyz =
            readVector3(m.require("xyz"), -kMaxCoordinate, kMaxCoordinate, false);
        Eigen::Vector3d rpy = Eigen::Vector3d::Zero();
        if (auto r = m.get("rpy")) rpy = readVector3(*r, -kMaxAngle, kMaxAngle, false);
        return poseFromXyzRpy(xyz, rpy);
    }

    // Names identify things across the whole cell (skills refer to them: "cube-green").
    std::string readName(const Field& f, const std::string& kind) {
        std::string name = readString(f);
        checkNameSyntax(f, name);
        auto [it, inserted] = names_.try_emplace(name, Named{kind, f.line});
        if (!inserted) {
            fail(ErrorCode::kDuplicateName, f,
                 "name '" + name + "' already used by the " + it->second.kind + " at line " +
                     std::to_string(it->second.line));
        }
        return name;
    }

    void checkNameSyntax(const Field& f, const std::string& name) const {
        bool ok = !name.empty() && name.size() <= kMaxNameLength;
        for (std::size_t i = 0; ok && i < name.size(); ++i) {
            const unsigned char c = static_cast<unsigned char>(name[i]);
            ok = std::isalnum(c) || (i > 0 && (c == '-' || c == '_' || c == '.'));
        }
        if (!ok) {
            fail(ErrorCode::kOutOfRange, f,
                 "'" + clip(name) + "' is not a valid name (1 to " +
                     std::to_string(kMaxNameLength) +
                     " letters, digits, '-', '_', '.', starting with a letter or digit)");
        }
    }

    // An optional reference to another thing by name; null is the same as absent.
    std::optional<std::string> readReference(const Mapping& m, std::string_view key,
                                             int& line) const {
        auto f = m.get(key);
        if (!f || f->node.IsNull()) return std::nullopt;
        std::string name = readString(*f);
        checkNameSyntax(*f, name);
        line = f->line;
        return name;
    }

    std::vector<Field> readSection(const Field& f, std::size_t max) const {
        if (f.node.IsNull()) return {};  // `objects:` with nothing is an empty list
        std::vector<Field> items = readList(f, 0);
        if (items.size() > max) {
            fail(ErrorCode::kTooMany, f,
                 std::to_string(items.size()) + " entries, at most " + std::to_string(max));
        }
        return items;
    }

    void parseRobot(const Field& f, CellDescription& cell);
    void parseTable(const Field& f, CellDescription& cell);
    void parseTool(const Field& f, CellDescription& cell);
    void parseDock(const Field& f, CellDescription& cell);
    void parseObject(const Field& f, CellDescription& cell);
    void checkReferences(const CellDescription& cell) const;

    struct Named {
        std::string kind;
        int line;
    };
    struct Reference {
        int line;
        std::string path;
    };

    std::string file_;
    std::map<std::string, Named, std::less<>> names_;
    std::vector<Reference> robotTool_, dockTool_, objectOn_;  // parallel to the cell's lists
};

void Parser::parseRobot(const Field& f, CellDescription& cell) {
    Mapping m(*this, f);
    m.allowOnly({"name", "model", "base", "home", "controller", "tool"});
    RobotDescription r;
    r.line = f.line;
    r.name = readName(m.require("name"), "robot");

    const Field model = m.require("model");
    r.modelName = readString(model);
    if (r.modelName == "ur3") {
        r.model = kinematics::ur3();
    } else if (r.modelName == "ur5") {
        r.model = kinematics::ur5();
    } else if (r.modelName == "ur10") {
        r.model = kinematics::ur10();
    } else {
        fail(ErrorCode::kOutOfRange, model,
             "unknown robot model '" + clip(r.modelName) + "' (known: ur3, ur5, ur10)");
    }

    r.base = readPose(m.require("base"));

    const std::vector<Field> home = readList(m.require("home"), kinematics::kAxes);
    for (int i = 0; i < kinematics::kAxes; ++i) {
        const double q = readNumber(home[i]);
        const kinematics::JointLimits& lim = r.model.limits[i];
        if (q < lim.minPosition || q > lim.maxPosition) {
            fail(ErrorCode::kOutOfRange, home[i],
                 formatNumber(q) + " rad is outside the joint limits of " + r.modelName + " [" +
                     formatNumber(lim.minPosition) + ", " + formatNumber(lim.maxPosition) + "]");
        }
        r.home[i] = q;
    }

    const Field controller = m.require("controller");
    Mapping c(*this, controller);
    c.allowOnly({"protocol", "port"});
    const Field protocol = c.require("protocol");
    r.controller.protocol = readString(protocol);
    if (r.controller.protocol != "rtde") {
        fail(ErrorCode::kOutOfRange, protocol,
             "unknown protocol '" + clip(r.controller.protocol) + "' (known: rtde)");
    }
    const Field port = c.require("port");
    r.controller.port = static_cast<std::uint16_t>(readInteger(port, 0, 65535));
    // Each simulated controller listens on its port; 0 lets the system choose, so repeats.
    for (const RobotDescription& other : cell.robots) {
        if (r.controller.port != 0 && other.controller.port == r.controller.port) {
            fail(ErrorCode::kConflict, port,
                 "port " + std::to_string(r.controller.port) + " already used by robot '" +
                     other.name + "' at line " + std::to_string(other.line));
        }
    }

    int toolLine = 0;
    r.tool = readReference(m, "tool", toolLine);
    robotTool_.push_back({toolLine, m.sub("tool")});
    cell.robots.push_back(std::move(r));
}

void Parser::parseTable(const Field& f, CellDescription& cell) {
    Mapping m(*this, f);
    m.allowOnly({"name", "pose", "size"});
    TableDescription t;
    t.line = f.line;
    t.name = readName(m.require("name"), "table");
    t.pose = readPose(m.require("pose"));
    t.size = readSize(m.require("size"));
    cell.tables.push_back(std::move(t));
}

void Parser::parseTool(const Field& f, CellDescription& cell) {
    Mapping m(*this, f);
    ToolDescription t;
    t.line = f.line;
    // The kind decides which keys are allowed, so it is read before the key check.
    const Field kind = m.require("kind");
    const std::string kindName = readString(kind);
    if (kindName == "parallel-gripper") {
        t.kind = ToolKind::kParallelGripper;
        m.allowOnly({"name", "kind", "device", "changer-id", "mass", "tcp", "stroke"});
    } else if (kindName == "vacuum-gripper") {
        t.kind = ToolKind::kVacuumGripper;
        m.allowOnly({"name", "kind", "device", "changer-id", "mass", "tcp", "cup-diameter"});
    } else {
        fail(
            ErrorCode::kOutOfRange, kind,
            "unknown tool kind '" + clip(kindName) + "' (known: parallel-gripper, vacuum-gripper)");
    }
    t.name = readName(m.require("name"), "tool");
    const Field device = m.require("device");
    t.device = readString(device);
    checkNameSyntax(device, t.device);

    const Field changerId = m.require("changer-id");
    t.changerId = static_cast<int>(readInteger(changerId, 1, 10));
    // The changer reports the tool by this number only: two tools with one number would be
    // indistinguishable.
    for (const ToolDescription& other : cell.tools) {
        if (other.changerId == t.changerId) {
            fail(ErrorCode::kConflict, changerId,
                 "changer-id " + std::to_string(t.changerId) + " already used by tool '" +
                     other.name + "' at line " + std::to_string(other.line));
        }
    }

    t.mass = readNumberIn(m.require("mass"), 0.0, kMaxToolMass, true);
    t.tcp = readPose(m.require("tcp"));
    if (t.kind == ToolKind::kParallelGripper) {
        t.stroke = readNumberIn(m.require("stroke"), 0.0, kMaxGripperSpan, true);
    } else {
        t.cupDiameter = readNumberIn(m.require("cup-diameter"), 0.0, kMaxGripperSpan, true);
    }
    cell.tools.push_back(std::move(t));
}

void Parser::parseDock(const Field& f, CellDescription& cell) {
    Mapping m(*this, f);
    m.allowOnly({"name", "pose", "tool"});
    DockDescription d;
    d.line = f.line;
    d.name = readName(m.require("name"), "dock");
    d.pose = readPose(m.require("pose"));
    int toolLine = 0;
    d.tool = readReference(m, "tool", toolLine);
    dockTool_.push_back({toolLine, m.sub("tool")});
    cell.docks.push_back(std::move(d));
}

void Parser::parseObject(const Field& f, CellDescription& cell) {
    Mapping m(*this, f);
    m.allowOnly({"name", "shape", "size", "mass", "color", "pose", "on"});
    ObjectDescription o;
    o.line = f.line;
    o.name = readName(m.require("name"), "object");
    const Field shape = m.require("shape");
    if (const std::string s = readString(shape); s != "box") {
        fail(ErrorCode::kOutOfRange, shape, "unknown shape '" + clip(s) + "' (known: box)");
    }
    o.shape = Shape::kBox;
    o.size = readSize(m.require("size"));
    o.mass = readNumberIn(m.require("mass"), 0.0, kMaxObjectMass, true);

    const Field color = m.require("color");
    o.color = readString(color);
    bool colorOk = false;
    if (o.color.size() == 7 && o.color[0] == '#') {
        colorOk = true;
        for (std::size_t i = 1; i < 7; ++i) {
            colorOk = colorOk && std::isxdigit(static_cast<unsigned char>(o.color[i]));
        }
    } else if (!o.color.empty() && o.color.size() <= 32) {
        colorOk = true;
        for (char c : o.color) colorOk = colorOk && c >= 'a' && c <= 'z';
    }
    if (!colorOk) {
        fail(ErrorCode::kOutOfRange, color,
             "'" + clip(o.color) + "' is not a colour (a lower-case name like green, or #rrggbb)");
    }

    o.pose = readPose(m.require("pose"));
    int onLine = 0;
    o.on = readReference(m, "on", onLine);
    objectOn_.push_back({onLine, m.sub("on")});
    cell.objects.push_back(std::move(o));
}

void Parser::checkReferences(const CellDescription& cell) const {
    auto requireKind = [&](const std::string& name, const Reference& ref, const char* kind,
                           bool found) {
        if (found) return;
        auto it = names_.find(name);
        fail(ErrorCode::kUnknownName, ref.line,
             ref.path + ": '" + name + "' " +
                 (it == names_.end() ? std::string("does not exist")
                                     : "is " + withArticle(it->second.kind) + ", not " + kind));
    };

    // Where each tool is at start: at most one place (a flange or a dock).
    std::map<std::string, std::string, std::less<>> placed;
    auto place = [&](const std::string& tool, const Reference& ref, const std::string& where) {
        auto [it, inserted] = placed.try_emplace(tool, where);
        if (!inserted) {
            fail(ErrorCode::kConflict, ref.line,
                 ref.path + ": tool '" + tool + "' is already " + it->second);
        }
    };

    for (std::size_t i = 0; i < cell.robots.size(); ++i) {
        const RobotDescription& r = cell.robots[i];
        if (!r.tool) continue;
        requireKind(*r.tool, robotTool_[i], "a tool", cell.findTool(*r.tool) != nullptr);
        place(*r.tool, robotTool_[i], "on the flange of robot '" + r.name + "'");
    }
    for (std::size_t i = 0; i < cell.docks.size(); ++i) {
        const DockDescription& d = cell.docks[i];
        if (!d.tool) continue;
        requireKind(*d.tool, dockTool_[i], "a tool", cell.findTool(*d.tool) != nullptr);
        place(*d.tool, dockTool_[i], "parked in dock '" + d.name + "'");
    }
    // Objects by name, for the `on` chains (up to 1024 objects: no quadratic scans).
    std::map<std::string_view, std::size_t, std::less<>> objectIndex;
    for (std::size_t i = 0; i < cell.objects.size(); ++i) objectIndex[cell.objects[i].name] = i;
    for (std::size_t i = 0; i < cell.objects.size(); ++i) {
        const ObjectDescription& o = cell.objects[i];
        if (!o.on) continue;
        requireKind(*o.on, objectOn_[i], "a table or an object",
                    cell.findTable(*o.on) != nullptr || objectIndex.count(*o.on) != 0);
    }
    // A chain of `on` must end at a table or a free object, not come back: colour each
    // object by the walk that first reached it; meeting the current walk's colour is a loop.
    constexpr std::size_t kUnvisited = static_cast<std::size_t>(-1);
    std::vector<std::size_t> walkOf(cell.objects.size(), kUnvisited);
    for (std::size_t start = 0; start < cell.objects.size(); ++start) {
        for (std::size_t cur = start; walkOf[cur] == kUnvisited;) {
            walkOf[cur] = start;
            const ObjectDescription& o = cell.objects[cur];
            if (!o.on) break;
            auto next = objectIndex.find(*o.on);
            if (next == objectIndex.end()) break;  // on a table
            if (walkOf[next->second] == start) {
                fail(ErrorCode::kConflict, objectOn_[cur].line,
                     objectOn_[cur].path + ": the objects under object '" + o.name +
                         "' go round in a loop (through '" + *o.on + "')");
            }
            cur = next->second;
        }
    }
}

CellDescription Parser::parse(std::string_view text) {
    if (text.size() > kMaxCellFileBytes) {
        fail(ErrorCode::kTooLarge, 0,
             "file is " + std::to_string(text.size()) + " bytes, more than the limit of " +
                 std::to_string(kMaxCellFileBytes) + " (1 MiB)");
    }
    std::vector<YAML::Node> documents;
    try {
        documents = YAML::LoadAll(std::string(text));
    } catch (const YAML::Exception& e) {
        fail(ErrorCode::kSyntax, e.mark.line >= 0 ? e.mark.line + 1 : 1,
             "YAML syntax error: " + e.msg);
    }
    if (documents.empty() || documents[0].IsNull()) {
        fail(ErrorCode::kMissingKey, 1, "empty file: expected a mapping with 'pnp-cell: 1'");
    }
    if (documents.size() > 1) {
        // The mark of a document's root is its first content line.
        fail(ErrorCode::kSyntax, lineOf(documents[1]),
             "more than one YAML document (a cell file holds one)");
    }

    const Field root{documents[0], lineOf(documents[0]), ""};
    Mapping top(*this, root);
    // The version first: a file of another version may have other keys.
    const Field version = top.require("pnp-cell");
    long long v = 0;
    if (!version.node.IsScalar() || !YAML::convert<long long>::decode(version.node, v) ||
        v != kCellFormatVersion) {
        fail(ErrorCode::kVersion, version,
             "unsupported format version " + describe(version.node) + " (this program reads " +
                 std::to_string(kCellFormatVersion) + ")");
    }
    top.allowOnly({"pnp-cell", "name", "robots", "tables", "tools", "docks", "objects"});

    CellDescription cell;
    cell.version = kCellFormatVersion;
    const Field name = top.require("name");
    cell.name = readString(name);
    checkNameSyntax(name, cell.name);

    // Sections in file order, so a duplicate name is reported where it occurs second.
    for (const auto& e : top.entries()) {
        const Field section{e.value, e.value.IsNull() ? e.keyLine : lineOf(e.value), e.key};
        auto each = [&](std::size_t max, void (Parser::*parseOne)(const Field&, CellDescription&)) {
            for (const Field& item : readSection(section, max)) (this->*parseOne)(item, cell);
        };
        if (e.key == "robots") {
            each(kMaxRobots, &Parser::parseRobot);
        } else if (e.key == "tables") {
            each(kMaxTables, &Parser::parseTable);
        } else if (e.key == "tools") {
            each(kMaxTools, &Parser::parseTool);
        } else if (e.key == "docks") {
            each(kMaxDocks, &Parser::parseDock);
        } else if (e.key == "objects") {
            each(kMaxObjects, &Parser::parseObject);
        }
    }
    checkReferences(cell);
    return cell;
}

}  // namespace

Result<CellDescription> parseCellDescription(std::string_view text,
                                             std::string_view fileNameForErrors) {
    const std::string file(fileNameForErrors);
    try {
        return Parser(file).parse(text);
    } catch (const Failure& f) {
        return f.error;
    } catch (const std::exception& e) {
        // yaml-cpp conversions we did not guard, or memory: still no exception escapes.
        return Error{ErrorCode::kSyntax, file + ": cannot read the cell description: " + e.what()};
    } catch (...) {
        return Error{ErrorCode::kSyntax, file + ": cannot read the cell description"};
    }
}

Result<CellDescription> loadCellFile(const std::filesystem::path& path) {
    const std::string file = path.string();
    std::error_code ec;
    if (!std::filesystem::is_regular_file(path, ec)) {
        return Error{
            ErrorCode::kUnreadable,
            file + ": " +
                (std::filesystem::exists(path, ec) ? "not a regular file" : "no such file")};
    }
    const std::uintmax_t size = std::filesystem::file_size(path, ec);
    if (ec) return Error{ErrorCode::kUnreadable, file + ": cannot read: " + ec.message()};
    if (size > kMaxCellFileBytes) {
        return Error{ErrorCode::kTooLarge, file + ": file is " + std::to_string(size) +
                                               " bytes, more than the limit of " +
                                               std::to_string(kMaxCellFileBytes) + " (1 MiB)"};
    }
    std::ifstream in(path, std::ios::binary);
    if (!in) return Error{ErrorCode::kUnreadable, file + ": cannot open for reading"};
    // Read at most one byte past the limit: the file may have grown since file_size.
    std::string text(kMaxCellFileBytes + 1, '\0');
    in.read(text.data(), static_cast<std::streamsize>(text.size()));
    if (in.bad()) return Error{ErrorCode::kUnreadable, file + ": read error"};
    text.resize(static_cast<std::size_t>(in.gcount()));
    return parseCellDescription(text, file);
}

}  // namespace pnp::world
