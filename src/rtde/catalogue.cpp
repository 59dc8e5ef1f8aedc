#include "rtde/catalogue.hpp"

namespace pnp::rtde {

namespace {

std::vector<Variable> build() {
    std::vector<Variable> v;
    auto out = [&](std::string name, Type type) {
        v.push_back({std::move(name), type, VariableKind::output});
    };
    auto in = [&](std::string name, Type type) {
        v.push_back({std::move(name), type, VariableKind::input});
    };
    // Outputs (controller -> client).
    out("timestamp", Type::float64);
    out("target_q", Type::vector6d);
    out("target_qd", Type::vector6d);
    out("target_qdd", Type::vector6d);
    out("target_current", Type::vector6d);
    out("target_moment", Type::vector6d);
    out("actual_q", Type::vector6d);
    out("actual_qd", Type::vector6d);
    out("actual_current", Type::vector6d);
    out("joint_control_output", Type::vector6d);
    out("actual_TCP_pose", Type::vector6d);
    out("actual_TCP_speed", Type::vector6d);
    out("actual_TCP_force", Type::vector6d);
    out("target_TCP_pose", Type::vector6d);
    out("target_TCP_speed", Type::vector6d);
    out("actual_digital_input_bits", Type::uint64);
    out("joint_temperatures", Type::vector6d);
    out("actual_execution_time", Type::float64);
    out("robot_mode", Type::int32);
    out("joint_mode", Type::vector6int32);
    out("safety_mode", Type::int32);
    out("safety_status", Type::int32);
    out("actual_tool_accelerometer", Type::vector3d);
    out("speed_scaling", Type::float64);
    out("target_speed_fraction", Type::float64);
    out("actual_momentum", Type::float64);
    out("actual_main_voltage", Type::float64);
    out("actual_robot_voltage", Type::float64);
    out("actual_robot_current", Type::float64);
    out("actual_joint_voltage", Type::vector6d);
    out("actual_digital_output_bits", Type::uint64);
    out("runtime_state", Type::uint32);
    out("elbow_position", Type::vector3d);
    out("elbow_velocity", Type::vector3d);
    out("robot_status_bits", Type::uint32);
    out("safety_status_bits", Type::uint32);
    out("analog_io_types", Type::uint32);
    out("standard_analog_input0", Type::float64);
    out("standard_analog_input1", Type::float64);
    out("standard_analog_output0", Type::float64);
    out("standard_analog_output1", Type::float64);
    out("tool_mode", Type::uint32);
    out("tool_output_voltage", Type::int32);
    out("tcp_offset", Type::vector6d);
    out("payload", Type::float64);
    out("payload_cog", Type::vector3d);
    out("output_bit_registers0_to_31", Type::uint32);
    out("output_bit_registers32_to_63", Type::uint32);
    for (int i = 64; i <= 127; ++i) out("output_bit_register_" + std::to_string(i), Type::boolean);
    // Registers 0..23 are shared with the fieldbus interfaces, 24..47 are RTDE only.
    for (int i = 0; i <= 47; ++i) out("output_int_register_" + std::to_string(i), Type::int32);
    for (int i = 0; i <= 47; ++i) {
        out("output_double_register_" + std::to_string(i), Type::float64);
    }

    // Inputs (client -> controller).
    in("speed_slider_mask", Type::uint32);
    in("speed_slider_fraction", Type::float64);
    in("standard_digital_output_mask", Type::uint8);
    in("standard_digital_output", Type::uint8);
    in("configurable_digital_output_mask", Type::uint8);
    in("configurable_digital_output", Type::uint8);
    in("tool_digital_output_mask", Type::uint8);
    in("tool_digital_output", Type::uint8);
    in("standard_analog_output_mask", Type::uint8);
    in("standard_analog_output_type", Type::uint8);
    in("standard_analog_output_0", Type::float64);
    in("standard_analog_output_1", Type::float64);
    in("input_bit_registers0_to_31", Type::uint32);
    in("input_bit_registers32_to_63", Type::uint32);
    for (int i = 64; i <= 127; ++i) in("input_bit_register_" + std::to_string(i), Type::boolean);
    for (int i = 0; i <= 47; ++i) in("input_int_register_" + std::to_string(i), Type::int32);
    for (int i = 0; i <= 47; ++i) in("input_double_register_" + std::to_string(i), Type::float64);
    return v;
}

}  // namespace

const std::vector<Variable>& catalogue() {
    static const std::vector<Variable> variables = build();
    return variables;
}

std::optional<Variable> findVariable(std::string_view name, VariableKind kind) {
    // ~400 entries, looked up only at recipe setup: a linear scan is enough.
    for (const Variable& v : catalogue()) {
        if (v.kind == kind && v.name == name) return v;
    }
    return std::nullopt;
}

}  // namespace pnp::rtde
