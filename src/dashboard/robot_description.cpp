#include "dashboard/robot_description.hpp"

#include <algorithm>
#include <cctype>

#include "kinematics/robot_model.hpp"

namespace pnp::dashboard {

namespace {

// The arms src/kinematics describes (it has no registry of its own).
std::vector<kinematics::RobotModel> knownModels() {
    return {kinematics::ur3(), kinematics::ur5(), kinematics::ur10()};
}

std::string lower(std::string_view s) {
    std::string out(s);
    std::transform(out.begin(), out.end(), out.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return out;
}

}  // namespace

std::optional<nlohmann::json> robotDescription(std::string_view model) {
    if (model.empty() || model.size() > 64) return std::nullopt;
    std::string wanted = lower(model);
    for (int pass = 0; pass < 2; ++pass) {
        for (const auto& m : knownModels()) {
            if (lower(m.name) != wanted) continue;
            nlohmann::json dh = nlohmann::json::array();
            nlohmann::json limits = nlohmann::json::array();
            for (const auto& row : m.dh)
                dh.push_back(
                    {{"a", row.a}, {"d", row.d}, {"alpha", row.alpha}, {"theta", row.thetaOffset}});
            for (const auto& l : m.limits)
                limits.push_back({{"min", l.minPosition}, {"max", l.maxPosition}});
            return nlohmann::json{{"model", m.name},
                                  {"convention", "standard DH: Rz(q+theta) Tz(d) Tx(a) Rx(alpha)"},
                                  {"dh", dh},
                                  {"limits", limits}};
        }
        // e-Series arms ("UR5e") share their kinematics with the CB-Series ones.
        if (wanted.size() > 1 && wanted.back() == 'e')
            wanted.pop_back();
        else
            break;
    }
    return std::nullopt;
}

std::vector<std::string> robotModels() {
    std::vector<std::string> names;
    for (const auto& m : knownModels()) names.push_back(m.name);
    return names;
}

}  // namespace pnp::dashboard
