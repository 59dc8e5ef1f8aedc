#include "skill/model/model.hpp"

#include <cstdlib>

namespace pnp::skill {

const std::vector<ModelNode>& knownTypes() {
    using namespace types;
    static const std::vector<ModelNode> all = {SkillType,
                                               GripperSkillType,
                                               GraspGripperSkillType,
                                               ReleaseGripperSkillType,
                                               MoveGripperSkillType,
                                               MoveSkillType,
                                               PtpMoveSkillType,
                                               LinearMoveSkillType,
                                               CartesianPtpMoveSkillType,
                                               CartesianLinearMoveSkillType,
                                               JointPtpMoveSkillType,
                                               JointLinearMoveSkillType,
                                               CartesianLinearForceMoveSkillType,
                                               PositionStreamSkillType,
                                               DetachToolSkillType,
                                               AttachToolSkillType,
                                               ChangeToolSkillType,
                                               DropToolSkillType,
                                               PickAndPlaceSkillType,
                                               ExecuteProcessSkillType,
                                               DelaySkillType};
    return all;
}

std::optional<ModelNode> typeByName(std::string_view name) {
    for (const ModelNode& t : knownTypes())
        if (t.name == name) return t;
    // "MoveGripperSkill" or "MoveGripper" for "MoveGripperSkillType".
    for (const ModelNode& t : knownTypes()) {
        std::string_view n = t.name;
        if (n.substr(0, n.size() - 4) == name || n.substr(0, n.size() - 9) == name) return t;
    }
    return std::nullopt;
}

std::string_view toString(SkillResult r) {
    switch (r) {
        case SkillResult::None:
            return "None";
        case SkillResult::Completed:
            return "Completed";
        case SkillResult::Failed:
            return "Failed";
        case SkillResult::Aborted:
            return "Aborted";
    }
    return "Unknown";
}

std::string_view toString(ProgramState s) {
    switch (s) {
        case ProgramState::Ready:
            return "Ready";
        case ProgramState::Running:
            return "Running";
        case ProgramState::Suspended:
            return "Suspended";
        case ProgramState::Halted:
            return "Halted";
        case ProgramState::Unknown:
            break;
    }
    return "Unknown";
}

ProgramState programStateFromName(std::string_view name) {
    for (ProgramState s : {ProgramState::Ready, ProgramState::Running, ProgramState::Suspended,
                           ProgramState::Halted})
        if (toString(s) == name) return s;
    return ProgramState::Unknown;
}

ProgramState programStateFromNumber(ua::UInt32 number) {
    // ProgramStateMachineType: Halted 11, Ready 12, Running 13, Suspended 14.
    switch (number) {
        case 11:
            return ProgramState::Halted;
        case 12:
            return ProgramState::Ready;
        case 13:
            return ProgramState::Running;
        case 14:
            return ProgramState::Suspended;
        default:
            return ProgramState::Unknown;
    }
}

std::filesystem::path modelsDirectory() {
    if (const char* env = std::getenv("PNP_SKILL_MODELS"); env != nullptr && *env != '\0')
        return env;
    return PNP_SKILL_MODELS_DIR;
}

std::filesystem::path modelFile(std::string_view uri) {
    const char* file = uri == kBaseUri          ? "Pnp.Skills.NodeSet2.xml"
                       : uri == kRoboticsUri    ? "Pnp.Skills.Robotics.NodeSet2.xml"
                       : uri == kToolChangerUri ? "Pnp.Skills.ToolChanger.NodeSet2.xml"
                       : uri == kCompositeUri   ? "Pnp.Skills.Composite.NodeSet2.xml"
                       : uri == kDemoUri        ? "Pnp.Skills.Demo.NodeSet2.xml"
                                                : nullptr;
    if (file == nullptr) return {};
    return modelsDirectory() / file;
}

}  // namespace pnp::skill
