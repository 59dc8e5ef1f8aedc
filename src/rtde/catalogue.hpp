// The RTDE variables this implementation knows (a subset of UR's field list, names and types
// as in UR's RTDE guide). Outputs are read by the controller and sent to clients, inputs are
// written by clients into the controller.
#pragma once

#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "rtde/codec.hpp"

namespace pnp::rtde {

enum class VariableKind { output, input };

struct Variable {
    std::string name;
    Type type;
    VariableKind kind;
};

// Every known variable, outputs first; built once, immutable.
const std::vector<Variable>& catalogue();
std::optional<Variable> findVariable(std::string_view name, VariableKind kind);

}  // namespace pnp::rtde
