#include "device/robot/motion_context.hpp"

#include "ua/types/status_codes.hpp"

namespace pnp::device::robot::detail {

namespace {
bool finite(const Eigen::Isometry3d& t) { return t.matrix().allFinite(); }
}  // namespace

ua::StatusCode MotionContext::setTool(const std::string& name,
                                      const std::optional<Eigen::Isometry3d>& frame) {
    if (name.empty() || name.size() > kMaxToolNameLength) return ua::status::BadInvalidArgument;
    if (frame && !finite(*frame)) return ua::status::BadInvalidArgument;
    std::lock_guard l(frameMutex_);
    auto it = tools_.find(name);
    if (!frame) {
        if (it == tools_.end()) return ua::status::BadInvalidArgument;  // nothing to activate
    } else if (it != tools_.end()) {
        it->second = *frame;
    } else {
        if (tools_.size() >= kMaxTools) return ua::status::BadInvalidArgument;
        tools_.emplace(name, *frame);
    }
    active_ = name;
    return {};
}

ua::StatusCode MotionContext::clearTool(const std::string& name) {
    std::lock_guard l(frameMutex_);
    if (name.empty()) {
        active_.clear();
        return {};
    }
    auto it = tools_.find(name);
    if (it == tools_.end()) return ua::status::BadInvalidArgument;
    tools_.erase(it);
    if (active_ == name) active_.clear();
    return {};
}

std::optional<Eigen::Isometry3d> MotionContext::toolFrame(const std::string& name,
                                                          std::string& error) const {
    std::lock_guard l(frameMutex_);
    const std::string& wanted = name.empty() ? active_ : name;
    if (wanted.empty()) return Eigen::Isometry3d::Identity();  // the flange
    auto it = tools_.find(wanted);
    if (it == tools_.end()) {
        error = "ToolFrame \"" + wanted + "\" is not a tool frame (SetTool registers one)";
        return std::nullopt;
    }
    return it->second;
}

}  // namespace pnp::device::robot::detail
