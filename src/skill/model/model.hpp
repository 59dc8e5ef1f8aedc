// The skill model (docs/skills.md; models/Pnp.Skills*.NodeSet2.xml): what a server, a client
// and the detector agree on. Type ids are numeric ids in the model's own namespace; their
// namespace index differs from server to server, so a type is named by (URI, id) and
// resolved against the server's NamespaceArray.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "ua/types/builtin.hpp"

namespace pnp::skill {

inline constexpr std::string_view kBaseUri = "urn:pnp:ua:skills";
inline constexpr std::string_view kRoboticsUri = "urn:pnp:ua:skills:robotics";
inline constexpr std::string_view kToolChangerUri = "urn:pnp:ua:skills:toolchanger";
inline constexpr std::string_view kCompositeUri = "urn:pnp:ua:skills:composite";
inline constexpr std::string_view kDemoUri = "urn:pnp:ua:skills:demo";
inline constexpr std::string_view kDiUri = "http://opcfoundation.org/UA/DI/";
inline constexpr std::string_view kRoboticsCsUri = "http://opcfoundation.org/UA/Robotics/";

// A node of a model: its namespace URI and numeric id there, and its BrowseName's name.
struct ModelNode {
    std::string_view uri;
    ua::UInt32 id = 0;
    std::string_view name;
    bool operator==(const ModelNode& o) const { return uri == o.uri && id == o.id; }
};

namespace types {
// urn:pnp:ua:skills
inline constexpr ModelNode SkillType{kBaseUri, 1001, "SkillType"};
inline constexpr ModelNode ISkillControllerType{kBaseUri, 1002, "ISkillControllerType"};
inline constexpr ModelNode SkillTransitionEventType{kBaseUri, 1003, "SkillTransitionEventType"};
inline constexpr ModelNode SkillFinalResultDataType{kBaseUri, 1004, "SkillFinalResultDataType"};
inline constexpr ModelNode GripperSkillType{kBaseUri, 1010, "GripperSkillType"};
inline constexpr ModelNode GraspGripperSkillType{kBaseUri, 1011, "GraspGripperSkillType"};
inline constexpr ModelNode ReleaseGripperSkillType{kBaseUri, 1012, "ReleaseGripperSkillType"};
inline constexpr ModelNode MoveGripperSkillType{kBaseUri, 1013, "MoveGripperSkillType"};
inline constexpr ModelNode IGripperType{kBaseUri, 1020, "IGripperType"};
inline constexpr ModelNode GripPointType{kBaseUri, 1021, "GripPointType"};
inline constexpr ModelNode ParallelGripPointType{kBaseUri, 1022, "ParallelGripPointType"};
inline constexpr ModelNode IPowerOffDeviceType{kBaseUri, 1030, "IPowerOffDeviceType"};
inline constexpr ModelNode SkillResultCode{kBaseUri, 3001, "SkillResultCode"};
inline constexpr ModelNode GripPointKind{kBaseUri, 3002, "GripPointKind"};
// urn:pnp:ua:skills:robotics
inline constexpr ModelNode MoveSkillType{kRoboticsUri, 1001, "MoveSkillType"};
inline constexpr ModelNode PtpMoveSkillType{kRoboticsUri, 1002, "PtpMoveSkillType"};
inline constexpr ModelNode LinearMoveSkillType{kRoboticsUri, 1003, "LinearMoveSkillType"};
inline constexpr ModelNode ICartesianMoveSkillParameterType{kRoboticsUri, 1004,
                                                            "ICartesianMoveSkillParameterType"};
inline constexpr ModelNode IJointMoveSkillParameterType{kRoboticsUri, 1005,
                                                        "IJointMoveSkillParameterType"};
inline constexpr ModelNode CartesianPtpMoveSkillType{kRoboticsUri, 1006,
                                                     "CartesianPtpMoveSkillType"};
inline constexpr ModelNode CartesianLinearMoveSkillType{kRoboticsUri, 1007,
                                                        "CartesianLinearMoveSkillType"};
inline constexpr ModelNode JointPtpMoveSkillType{kRoboticsUri, 1008, "JointPtpMoveSkillType"};
inline constexpr ModelNode JointLinearMoveSkillType{kRoboticsUri, 1009, "JointLinearMoveSkillType"};
inline constexpr ModelNode CartesianLinearForceMoveSkillType{kRoboticsUri, 1010,
                                                             "CartesianLinearForceMoveSkillType"};
inline constexpr ModelNode PositionStreamSkillType{kRoboticsUri, 1011, "PositionStreamSkillType"};
inline constexpr ModelNode SkillMotionDeviceType{kRoboticsUri, 1012, "SkillMotionDeviceType"};
// urn:pnp:ua:skills:toolchanger
inline constexpr ModelNode DetachToolSkillType{kToolChangerUri, 1001, "DetachToolSkillType"};
inline constexpr ModelNode AttachToolSkillType{kToolChangerUri, 1002, "AttachToolSkillType"};
inline constexpr ModelNode ChangeToolSkillType{kToolChangerUri, 1003, "ChangeToolSkillType"};
inline constexpr ModelNode DropToolSkillType{kToolChangerUri, 1004, "DropToolSkillType"};
// urn:pnp:ua:skills:composite
inline constexpr ModelNode PickAndPlaceSkillType{kCompositeUri, 1001, "PickAndPlaceSkillType"};
inline constexpr ModelNode ExecuteProcessSkillType{kCompositeUri, 1002, "ExecuteProcessSkillType"};
// urn:pnp:ua:skills:demo
inline constexpr ModelNode DelaySkillType{kDemoUri, 1001, "DelaySkillType"};
}  // namespace types

// Every skill type above, for lookups by name (the CLI's `pnp skill run TYPE`).
const std::vector<ModelNode>& knownTypes();
std::optional<ModelNode> typeByName(std::string_view name);

// FinalResultData/Result (SkillResultCode).
enum class SkillResult : ua::Int32 { None = 0, Completed = 1, Failed = 2, Aborted = 3 };
std::string_view toString(SkillResult r);

// Program states (OPC 10000-10 §5.2.3): BrowseNames in namespace 0.
enum class ProgramState { Ready, Running, Suspended, Halted, Unknown };
std::string_view toString(ProgramState s);
ProgramState programStateFromName(std::string_view name);  // "Ready" ... else Unknown
// State numbers of ProgramStateMachineType (CurrentState/Number).
ProgramState programStateFromNumber(ua::UInt32 number);

// BrowseNames (names only) of a skill's members.
namespace names {
inline constexpr std::string_view ParameterSet = "ParameterSet";  // DI namespace
inline constexpr std::string_view Lock = "Lock";                  // DI namespace
inline constexpr std::string_view FinalResultData = "FinalResultData";
inline constexpr std::string_view Result = "Result";
inline constexpr std::string_view Message = "Message";
inline constexpr std::string_view Skills = "Skills";
inline constexpr std::string_view SkillStep = "SkillStep";
}  // namespace names

// DI LockingServices method results (OPC 10000-100 §7.5–7.8).
namespace lock_status {
inline constexpr ua::Int32 Ok = 0;
inline constexpr ua::Int32 AlreadyLocked = -1;  // InitLock
inline constexpr ua::Int32 NotLocked = -1;      // ExitLock, RenewLock, BreakLock
inline constexpr ua::Int32 LockedByOther = -2;  // RenewLock / ExitLock by another session
}  // namespace lock_status

// The models folder: $PNP_SKILL_MODELS when set, else the source tree's models/ (build time).
std::filesystem::path modelsDirectory();
// The file of a model by namespace URI (models/Pnp.Skills*.NodeSet2.xml), or empty.
std::filesystem::path modelFile(std::string_view uri);

}  // namespace pnp::skill
