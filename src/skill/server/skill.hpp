// A skill on the server side (docs/skills.md): a C++ class (or a set of callbacks) with typed
// parameters, run as an OPC UA Program (OPC 10000-10) whose type comes from the skill model.
//
//   class MoveGripper : public Skill {
//     public:
//       MoveGripper() : Skill(types::MoveGripperSkillType) {}
//       Param<double> width = parameter<double>("Width");
//       Param<double> force = parameter<double>("Force", 20.0);
//       Outcome execute(Execution& run) override {
//           if (!run.sleepFor(10ms)) return Outcome::aborted("halted");  // Halt interrupts
//           return run.get(width) > 0.1 ? Outcome::failed("too wide") : Outcome::completed();
//       }
//   };
//   controller.add("MoveGripper", std::make_shared<MoveGripper>());   // see controller.hpp
//
// Parameters are declared in C++ and checked, when the skill is added to a controller,
// against the ParameterSet of the skill's type in the address space: a missing parameter or a
// DataType / ValueRank that does not match the C++ type is a start-up error (SkillError)
// naming the parameter. Their values are taken once, at Start, so a Write during a run never
// changes it.
//
// Execution. execute() runs on the skill's own worker thread, never on the network thread.
// Start takes Ready -> Running (event) and only then hands the run to the worker, so even an
// execute() that returns at once goes Ready -> Running -> Ready with both events. The outcome
// ends the run through the state machine: Completed -> Ready, Failed -> Halted (Message says
// why), with FinalResultData/Result, /Message and the type-specific results set first. Halt
// takes the skill to Halted at once (FinalResultData Aborted) and requests the stop
// (Execution::stopRequested / sleepFor / checkpoint see it); the worker's late outcome is
// dropped, and a Reset waits until execute() has returned, so two runs never overlap.
// Suspend / Resume pause a run at its next checkpoint() or sleepFor().
#pragma once

#include <any>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <stop_token>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "skill/model/model.hpp"
#include "ua/types/extension_object.hpp"

namespace pnp::skill::server {

// A start-up error: model not loaded, parameter missing or mistyped, ...
class SkillError : public std::runtime_error {
  public:
    using std::runtime_error::runtime_error;
};

// How a C++ parameter type maps onto OPC UA: DataType (ns0) and ValueRank.
template <class T>
struct ParamTraits;
#define PNP_SKILL_PARAM_BUILTIN(T, Id)                                                   \
    template <>                                                                          \
    struct ParamTraits<T> {                                                              \
        static constexpr ua::UInt32 dataType = Id;                                       \
        static constexpr ua::Int32 valueRank = -1;                                       \
        static ua::Variant toVariant(const T& v) { return ua::Variant(v); }              \
        static bool fromVariant(const ua::Variant& v, T& out) {                          \
            if (const T* p = v.scalar<T>()) return out = *p, true;                       \
            return false;                                                                \
        }                                                                                \
    };                                                                                   \
    template <>                                                                          \
    struct ParamTraits<std::vector<T>> {                                                 \
        static constexpr ua::UInt32 dataType = Id;                                       \
        static constexpr ua::Int32 valueRank = 1;                                        \
        static ua::Variant toVariant(const std::vector<T>& v) { return ua::Variant(v); } \
        static bool fromVariant(const ua::Variant& v, std::vector<T>& out) {             \
            if (const auto* p = v.array<T>()) return out = *p, true;                     \
            if (v.isEmpty()) return out.clear(), true;                                   \
            return false;                                                                \
        }                                                                                \
    }
PNP_SKILL_PARAM_BUILTIN(bool, 1);
PNP_SKILL_PARAM_BUILTIN(ua::Int32, 6);
PNP_SKILL_PARAM_BUILTIN(ua::UInt32, 7);
PNP_SKILL_PARAM_BUILTIN(ua::Int64, 8);
PNP_SKILL_PARAM_BUILTIN(double, 11);
PNP_SKILL_PARAM_BUILTIN(ua::String, 12);
PNP_SKILL_PARAM_BUILTIN(ua::LocalizedText, 21);
#undef PNP_SKILL_PARAM_BUILTIN

// ns0 structures (ThreeDFrame, ThreeDVector, Range, ...): ExtensionObjects in a Variant.
template <class T>
requires requires { ua::DataTypeInfo<T>::dataTypeId; }
struct ParamTraits<T> {
    static constexpr ua::UInt32 dataType = ua::DataTypeInfo<T>::dataTypeId;
    static constexpr ua::Int32 valueRank = -1;
    static ua::Variant toVariant(const T& v) { return ua::Variant(ua::toExtensionObject(v)); }
    static bool fromVariant(const ua::Variant& v, T& out) {
        const auto* x = v.scalar<ua::ExtensionObject>();
        if (x == nullptr) return false;
        try {
            auto t = ua::fromExtensionObject<T>(*x);
            if (!t) return false;
            out = std::move(*t);
            return true;
        } catch (const ua::DecodeError&) {
            return false;
        }
    }
};
template <class T>
requires requires { ua::DataTypeInfo<T>::dataTypeId; }
struct ParamTraits<std::vector<T>> {
    static constexpr ua::UInt32 dataType = ua::DataTypeInfo<T>::dataTypeId;
    static constexpr ua::Int32 valueRank = 1;
    static ua::Variant toVariant(const std::vector<T>& v) {
        std::vector<ua::ExtensionObject> xs;
        xs.reserve(v.size());
        for (const T& t : v) xs.push_back(ua::toExtensionObject(t));
        return ua::Variant(std::move(xs));
    }
    static bool fromVariant(const ua::Variant& v, std::vector<T>& out) {
        out.clear();
        if (v.isEmpty()) return true;
        const auto* xs = v.array<ua::ExtensionObject>();
        if (xs == nullptr) return false;
        for (const auto& x : *xs) {
            T t;
            if (!ParamTraits<T>::fromVariant(ua::Variant(x), t)) return false;
            out.push_back(std::move(t));
        }
        return true;
    }
};

// A declared parameter: what the skill type's ParameterSet must hold.
struct ParameterDeclaration {
    std::string name;     // BrowseName's name below ParameterSet
    ua::NodeId dataType;  // ns0 DataType
    ua::Int32 valueRank = -1;
    bool optional = false;     // Optional in the type: created on the instance because declared
    ua::Variant defaultValue;  // written into the instance when it has no value
};

// A typed handle on a declared parameter (index into the skill's declarations).
template <class T>
struct Param {
    std::size_t index = 0;
};

// How a run ended; the type-specific FinalResultData values go with it.
struct Outcome {
    SkillResult result = SkillResult::Completed;
    std::string message;
    std::vector<std::pair<std::string, ua::Variant>> results;  // FinalResultData/<name>

    static Outcome completed(std::string message = {}) {
        return {SkillResult::Completed, std::move(message), {}};
    }
    static Outcome failed(std::string reason) {
        return {SkillResult::Failed, std::move(reason), {}};
    }
    static Outcome aborted(std::string reason) {
        return {SkillResult::Aborted, std::move(reason), {}};
    }
    Outcome& with(std::string name, ua::Variant value) {
        results.emplace_back(std::move(name), std::move(value));
        return *this;
    }
};

class SkillRuntime;  // controller.cpp: one skill instance in the address space

// One run of a skill, as execute() sees it (worker thread).
class Execution {
  public:
    // The parameter's value at Start.
    template <class T>
    T get(Param<T> p) const {
        T out{};
        if (!ParamTraits<T>::fromVariant(value(p.index), out))
            throw SkillError("parameter " + declarationName(p.index) + " has the wrong type");
        return out;
    }
    const ua::Variant& value(std::size_t index) const;
    const ua::Variant* value(std::string_view name) const;  // by name; nullptr if not declared

    // Halt (or the server's shutdown) asked this run to stop.
    bool stopRequested() const { return stop_.stop_requested(); }
    std::stop_token stopToken() const { return stop_; }
    // Waits while the skill is Suspended. false: stop requested (return from execute()).
    bool checkpoint();
    // Sleeps `d` of Running time (Suspended time does not count). false: stop requested.
    bool sleepFor(std::chrono::nanoseconds d);
    // Progress: the IntermediateResult of the following transition events, and the skill's
    // SkillStep variable when it has one (a String; e.g. Pick-and-Place's current step).
    void progress(ua::Variant intermediateResult);

    Execution(SkillRuntime& runtime, std::vector<ua::Variant> values, std::stop_token stop)
        : runtime_(runtime), values_(std::move(values)), stop_(std::move(stop)) {}

  private:
    std::string declarationName(std::size_t index) const;
    SkillRuntime& runtime_;
    std::vector<ua::Variant> values_;
    std::stop_token stop_;
};

class Skill {
  public:
    explicit Skill(ModelNode type) : type_(type) {}
    virtual ~Skill() = default;
    Skill(const Skill&) = delete;
    Skill& operator=(const Skill&) = delete;

    const ModelNode& type() const { return type_; }
    const std::vector<ParameterDeclaration>& parameters() const { return parameters_; }

    // The run (worker thread). An exception ends it as Failed with its message.
    virtual Outcome execute(Execution& run) = 0;
    // Requests of clients, on the network thread (must be quick). A Bad status refuses the
    // request and nothing changes. onHalt is told after the stop was requested.
    virtual ua::StatusCode onSuspend() { return ua::StatusCode{}; }
    virtual ua::StatusCode onResume() { return ua::StatusCode{}; }
    virtual ua::StatusCode onReset() { return ua::StatusCode{}; }
    virtual void onHalt() {}

  protected:
    // Declares a parameter of the skill's type (call in member initialisers).
    template <class T>
    Param<T> parameter(std::string name, T defaultValue = T{}) {
        return declare<T>(std::move(name), false, std::move(defaultValue));
    }
    // A parameter that is Optional in the type (created on the instance all the same).
    template <class T>
    Param<T> optionalParameter(std::string name, T defaultValue = T{}) {
        return declare<T>(std::move(name), true, std::move(defaultValue));
    }

    // An untyped declaration (the callbacks form).
    void declareRaw(ParameterDeclaration declaration) {
        parameters_.push_back(std::move(declaration));
    }

  private:
    template <class T>
    Param<T> declare(std::string name, bool optional, T defaultValue) {
        parameters_.push_back({std::move(name), ua::NodeId(0, ParamTraits<T>::dataType),
                               ParamTraits<T>::valueRank, optional,
                               ParamTraits<T>::toVariant(defaultValue)});
        return Param<T>{parameters_.size() - 1};
    }
    ModelNode type_;
    std::vector<ParameterDeclaration> parameters_;
};

// The callbacks form: a skill without a class of its own.
struct SkillCallbacks {
    std::function<Outcome(Execution&)> execute = {};
    std::function<ua::StatusCode()> suspend = {};
    std::function<ua::StatusCode()> resume = {};
    std::function<ua::StatusCode()> reset = {};
    std::function<void()> halt = {};
};
std::shared_ptr<Skill> makeSkill(ModelNode type, std::vector<ParameterDeclaration> parameters,
                                 SkillCallbacks callbacks);
// A declaration for makeSkill.
template <class T>
ParameterDeclaration declareParameter(std::string name, T defaultValue = T{},
                                      bool optional = false) {
    return {std::move(name), ua::NodeId(0, ParamTraits<T>::dataType), ParamTraits<T>::valueRank,
            optional, ParamTraits<T>::toVariant(defaultValue)};
}

}  // namespace pnp::skill::server
