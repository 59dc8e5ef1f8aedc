// `pnp device`: placeholder until the command lands.
#include <CLI/CLI.hpp>
#include <functional>

namespace pnp::cli {

std::function<int()> addDeviceCommands(CLI::App& /*app*/) {
    return [] { return -1; };
}

}  // namespace pnp::cli
