#include "device/ur/ur_hardware.hpp"

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <utility>
#include <vector>

#include "kinematics/kinematics.hpp"

namespace pnp::device::ur {
namespace {

using robot::Error;

// The output recipe, in this order (indices below).
const std::vector<std::string>& outputNames() {
    static const std::vector<std::string> names{
        "timestamp",       "target_q",         "actual_q",         "actual_qd",
        "actual_TCP_pose", "actual_TCP_speed", "actual_TCP_force", "tcp_offset",
        "robot_mode",      "safety_mode",      "runtime_state"};
    return names;
}
enum Out : std::size_t {
    kTimestamp,
    kTargetQ,
    kActualQ,
    kActualQd,
    kTcpPose,
    kTcpSpeed,
    kTcpForce,
    kTcpOffset,
    kRobotMode,
    kSafetyMode,
    kRuntimeState,
    kOutputs
};

// The servo script's inputs: input_int_register_0 (1 = servo), the six joint targets.
const std::vector<std::string>& inputNames() {
    static const std::vector<std::string> names{
        "input_int_register_0",    "input_double_register_0", "input_double_register_1",
        "input_double_register_2", "input_double_register_3", "input_double_register_4",
        "input_double_register_5", "input_double_register_6"};
    return names;
}

// [x, y, z, rx, ry, rz] (m, rotation vector in rad) -> transform.
Eigen::Isometry3d poseFromUr(const rtde::Vector6d& p) {
    Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
    t.translation() = Eigen::Vector3d(p[0], p[1], p[2]);
    const Eigen::Vector3d r(p[3], p[4], p[5]);
    const double angle = r.norm();
    if (angle > 1e-12) t.linear() = Eigen::AngleAxisd(angle, r / angle).toRotationMatrix();
    return t;
}

std::string lower(std::string_view s) {
    std::string out(s);
    std::transform(out.begin(), out.end(), out.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return out;
}

// Why the controller refused a recipe, one clause per refused variable.
std::string refusedVariables(const rtde::Recipe& recipe) {
    std::string out;
    for (std::size_t i = 0; i < recipe.typeNames.size() && i < recipe.names.size(); ++i) {
        const std::string& t = recipe.typeNames[i];
        std::string why;
        if (t == "NOT_FOUND")
            why = "NOT_FOUND — this controller software does not know the variable";
        else if (t == "IN_USE")
            why = "IN_USE — another RTDE client or the teach pendant program uses it";
        else
            continue;
        if (!out.empty()) out += "; ";
        out += recipe.names[i] + ": " + why;
    }
    return out;
}

template <class T>
const T* get(const std::vector<rtde::Value>& v, std::size_t i) {
    return i < v.size() ? std::get_if<T>(&v[i]) : nullptr;
}

}  // namespace

std::optional<kinematics::RobotModel> modelByName(std::string_view name) {
    std::string n = lower(name);
    if (n.size() > 1 && n.back() == 'e') n.pop_back();  // e-Series: the same kinematics
    if (n == "ur3") return kinematics::ur3();
    if (n == "ur5") return kinematics::ur5();
    if (n == "ur10") return kinematics::ur10();
    return std::nullopt;
}

robot::SafetyState safetyFromUr(std::int32_t mode) {
    using S = robot::SafetyState;
    switch (mode) {
        case 1:
            return S::kNormal;
        case 2:
            return S::kReduced;
        case 3:   // protective stop
        case 5:   // safeguard stop
        case 12:  // automatic mode safeguard stop
        case 13:  // three-position enabling stop
            return S::kProtectiveStop;
        case 6:  // system emergency stop
        case 7:  // robot emergency stop
            return S::kEmergencyStop;
        case 4:   // recovery (a joint beyond its limits)
        case 8:   // violation
        case 9:   // fault
        case 10:  // validating joint ids
            return S::kFault;
        default:
            return S::kUnknown;
    }
}

robot::ProgramState programFromUr(std::uint32_t state) {
    using P = robot::ProgramState;
    switch (state) {
        case 2:
            return P::kRunning;  // playing
        case 3:                  // pausing
        case 4:                  // paused
        case 5:                  // resuming
            return P::kPaused;
        case 0:  // stopping
        case 1:  // stopped
            return P::kStopped;
        default:
            return P::kUnknown;
    }
}

UrHardware::UrHardware(UrConfig config) : config_(std::move(config)) {}

UrHardware::~UrHardware() { disconnect(); }

std::string UrHardware::serialNumber() const {
    return config_.serialNumber.empty() ? "unknown" : config_.serialNumber;
}

std::string UrHardware::endpoint() const {
    return "rtde://" + config_.host + ":" + std::to_string(config_.port);
}

robot::Deadline UrHardware::requestDeadline(robot::Deadline deadline) const {
    return std::min(deadline, robot::Clock::now() + config_.requestTimeout);
}

robot::Error UrHardware::fail(const std::string& what, const rtde::Status& status) const {
    return Error{what + " (" + endpoint() + "): " + std::string(rtde::codeName(status.code)) +
                 (status.message.empty() ? "" : ": " + status.message)};
}

robot::Result<robot::Done> UrHardware::connect(robot::Deadline deadline) {
    disconnect();
    if (!(std::isfinite(config_.frequency) && config_.frequency >= 1.0 &&
          config_.frequency <= 500.0))
        return Error{"UR frequency must be within 1..500 Hz (is " +
                     std::to_string(config_.frequency) + ")"};
    auto r = setup(deadline);
    if (!r) disconnect();
    return r;
}

robot::Result<robot::Done> UrHardware::setup(robot::Deadline deadline) {
    if (auto s = client_.connect(config_.host, config_.port, deadline); !s.ok())
        return fail("cannot reach the UR controller", s);
    if (auto s = client_.negotiateProtocolVersion(requestDeadline(deadline), 2); !s.ok()) {
        if (s.code == rtde::Code::rejected)
            return Error{"the UR controller at " + endpoint() +
                         " refused RTDE protocol version 2 (software older than 3.3?)"};
        return fail("RTDE protocol version", s);
    }
    auto v = client_.getControllerVersion(requestDeadline(deadline));
    if (!v.ok()) return fail("RTDE controller version", v.status());
    version_ = v.value();

    auto out = client_.setupOutputs(config_.frequency, outputNames(), requestDeadline(deadline));
    if (!out.ok()) return fail("RTDE output setup", out.status());
    if (!out->valid()) {
        std::string why = refusedVariables(out.value());
        if (why.empty()) {
            // Every variable is known: the frequency or the state was refused; the controller
            // says why in a text message sent just before its reply.
            why = "refused at " + std::to_string(static_cast<int>(config_.frequency)) +
                  " Hz (a CB3 streams at most 125 Hz)";
            auto m = client_.receive(
                std::min(deadline, robot::Clock::now() + std::chrono::milliseconds(50)));
            if (m.ok())
                if (auto* text = std::get_if<rtde::TextMessage>(&m.value()))
                    why += ": " + text->message;
        }
        return Error{"the UR controller refused the output recipe: " + why};
    }
    outputRecipe_ = out->id;

    auto in = client_.setupInputs(inputNames(), requestDeadline(deadline));
    if (!in.ok()) return fail("RTDE input setup", in.status());
    if (!in->valid()) {
        std::string why = refusedVariables(in.value());
        return Error{"the UR controller refused " +
                     (why.empty() ? std::string("the input recipe") : why)};
    }
    inputRecipe_ = in->id;

    if (auto s = client_.start(requestDeadline(deadline)); !s.ok()) return fail("RTDE start", s);
    // Servo off first: the script's watchdog re-arms on a 0 -> 1 edge of the register, and
    // the controller must not act on whatever targets a previous session left.
    if (auto w = write(robot::Command{}, requestDeadline(deadline)); !w) return w.error();
    sequence_ = 0;
    return robot::Done{};
}

void UrHardware::disconnect() {
    client_.close();
    outputRecipe_ = 0;
    inputRecipe_ = 0;
}

robot::Result<robot::State> UrHardware::read(robot::Deadline deadline) {
    if (!client_.connected() || outputRecipe_ == 0)
        return Error{"not connected to the UR controller at " + endpoint()};
    // Text messages may come between samples: skipped, bounded by the deadline (queued
    // packages are returned without waiting, so the deadline is checked here too).
    for (;;) {
        if (robot::Clock::now() > deadline)
            return Error{"no data from the UR controller at " + endpoint() +
                         " before the deadline"};
        auto r = client_.receive(deadline);
        if (!r.ok()) {
            if (r.status().code == rtde::Code::timeout)
                return Error{"no data from the UR controller at " + endpoint() +
                             " before the deadline"};
            return fail("RTDE receive", r.status());
        }
        if (auto* text = std::get_if<rtde::TextMessage>(&r.value())) {
            lastText_ = text->source + ": " + text->message;
            continue;
        }
        const auto& sample = std::get<rtde::DataSample>(r.value());
        if (sample.recipeId != outputRecipe_) continue;
        const auto& v = sample.values;
        const auto* timestamp = get<double>(v, kTimestamp);
        const auto* targetQ = get<rtde::Vector6d>(v, kTargetQ);
        const auto* q = get<rtde::Vector6d>(v, kActualQ);
        const auto* qd = get<rtde::Vector6d>(v, kActualQd);
        const auto* pose = get<rtde::Vector6d>(v, kTcpPose);
        const auto* speed = get<rtde::Vector6d>(v, kTcpSpeed);
        const auto* force = get<rtde::Vector6d>(v, kTcpForce);
        const auto* offset = get<rtde::Vector6d>(v, kTcpOffset);
        const auto* robotMode = get<std::int32_t>(v, kRobotMode);
        const auto* safety = get<std::int32_t>(v, kSafetyMode);
        const auto* runtime = get<std::uint32_t>(v, kRuntimeState);
        if (v.size() != kOutputs || !timestamp || !targetQ || !q || !qd || !pose || !speed ||
            !force || !offset || !robotMode || !safety || !runtime)
            return Error{"the UR controller at " + endpoint() +
                         " sent a data package that does not match the output recipe"};

        robot::State s;
        s.received = robot::Clock::now();
        s.controllerTime = *timestamp;
        answering_ = *timestamp;
        s.sequence = ++sequence_;
        s.q = *q;
        s.qd = *qd;
        s.targetQ = *targetQ;
        // actual_TCP_pose includes the TCP configured on the pendant: remove it.
        s.flange = poseFromUr(*pose) * poseFromUr(*offset).inverse();
        s.tcpSpeed = *speed;
        s.force = *force;
        s.safety = safetyFromUr(*safety);
        s.program = programFromUr(*runtime);
        s.following = s.program == robot::ProgramState::kRunning &&
                      s.safety == robot::SafetyState::kNormal && *robotMode == kRobotModeRunning;
        return s;
    }
}

robot::Result<robot::Done> UrHardware::write(const robot::Command& command,
                                             robot::Deadline deadline) {
    if (!client_.connected() || inputRecipe_ == 0)
        return Error{"not connected to the UR controller at " + endpoint()};
    std::array<rtde::Value, 8> values;
    values[0] = static_cast<std::int32_t>(command.servo ? 1 : 0);
    for (std::size_t i = 0; i < command.q.size(); ++i) {
        // A non-finite target must never reach servoj; refusing ends the session, and the
        // script's watchdog then stops the arm.
        if (command.servo && !std::isfinite(command.q[i]))
            return Error{"refused to send a non-finite joint target (axis " + std::to_string(i) +
                         ")"};
        values[i + 1] = std::isfinite(command.q[i]) ? command.q[i] : 0.0;
    }
    // The controller time of the state this command answers: a servo program can then tell a
    // late target from a current one (pnp_servo.script and the simulator apply it a fixed
    // number of cycles after that state; a real UR servoj ignores it).
    values[7] = answering_;
    if (auto s = client_.send(inputRecipe_, values, deadline); !s.ok()) return fail("RTDE send", s);
    return robot::Done{};
}

}  // namespace pnp::device::ur
