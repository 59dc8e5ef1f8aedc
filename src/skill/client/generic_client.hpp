// A skill client driven by text (the CLI's `pnp skill run TYPE name=value ...`): values are
// coerced to each parameter's DataType / ValueRank as the server declares them.
//
//   GenericSkillClient skill(ua, node);
//   std::cout << skill.describe();                      // parameters, types, current values
//   skill.run(skill.parse({"DurationMs=50", "FailWith="}), 5s);
//
// Text forms: Boolean true/false/1/0; integers and Float/Double in C++ syntax; String as is;
// LocalizedText as is (or "locale:text" is NOT split: the text is taken literally); arrays
// `[1,2,3]` or `1,2,3`; ThreeDFrame `x,y,z,a,b,c`; ThreeDVector `x,y,z`; Range `low,high`;
// arrays of those as a flat list (`0,1,2,3` = two Ranges) with optional brackets.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "skill/client/skill_client.hpp"

namespace pnp::skill::client {

// "Double", "Double[]", "ThreeDFrame", ... for a DataType NodeId and ValueRank.
std::string typeName(const ua::NodeId& dataType, ua::Int32 valueRank);
// The value as text in the forms parsed above (structures decoded).
std::string formatValue(const ua::Variant& value);
// Text -> Variant for this parameter. Throws Error(BadTypeMismatch) naming the parameter and
// the expected type.
ua::Variant coerce(const ParameterInfo& parameter, std::string_view text);

class GenericSkillClient : public SkillClient {
  public:
    using SkillClient::SkillClient;

    // "name=value" assignments -> typed values. Throws Error (BadNotFound: unknown
    // parameter; BadTypeMismatch: value; BadSyntaxError: no '=').
    NamedValues parse(const std::vector<std::string>& assignments) const;
    ua::Variant coerce(std::string_view name, std::string_view text) const;
    void setParametersFromText(const std::vector<std::string>& assignments, Deadline deadline = {});
    // One line per parameter: "  Name: Type = value" (" (read-only)" when not writable).
    std::string describe(Deadline deadline = {});
};

}  // namespace pnp::skill::client
