// The robot geometry the page draws (GET /api/robot/<model>): the DH table of a model of
// src/kinematics, so that no length is written twice (never in JavaScript).
#pragma once

#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace pnp::dashboard {

// {"model":"UR5","convention":"standard DH: Rz(q+theta)·Tz(d)·Tx(a)·Rx(alpha)",
//  "dh":[{"a":..,"d":..,"alpha":..,"theta":..}, x6], "limits":[{"min":..,"max":..}, x6]}
// for a model name (case-insensitive, an e-Series suffix "e" accepted); nullopt if unknown.
std::optional<nlohmann::json> robotDescription(std::string_view model);
// The names robotDescription() knows.
std::vector<std::string> robotModels();

}  // namespace pnp::dashboard
