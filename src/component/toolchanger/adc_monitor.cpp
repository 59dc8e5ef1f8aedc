#include "component/toolchanger/adc_monitor.hpp"

#include <cstdio>
#include <stdexcept>

#include "device/kelvin/kelvin_adc_device.hpp"
#include "skill/model/model.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"

namespace pnp::component::toolchanger {

using ua::NodeId;
namespace kelvin = device::kelvin;

std::string describe(const AdcSample& s) {
    if (!s.valid) return "unknown (no reading from the ADC)";
    char volts[32];
    std::snprintf(volts, sizeof volts, "%.2f V", s.voltage);
    return kelvin::describe(s.reading) + " (" + volts + ")";
}

namespace {

struct BoardNodes {
    NodeId object, voltage, state, toolId;
};

// The first object below DI DeviceSet (or Objects) whose type is KelvinToolChangerType.
std::optional<BoardNodes> findBoard(ua::client::Client& c, ua::client::Deadline deadline) {
    const auto uris = c.namespaceArray(deadline);
    std::optional<ua::UInt16> kelvinNs, diNs;
    for (std::size_t i = 0; i < uris.size() && i < 0xFFFF; ++i) {
        if (uris[i] == kelvin::kKelvinUri) kelvinNs = static_cast<ua::UInt16>(i);
        if (uris[i] == skill::kDiUri) diNs = static_cast<ua::UInt16>(i);
    }
    if (!kelvinNs) return std::nullopt;
    const NodeId type(*kelvinNs, kelvin::kKelvinToolChangerTypeId);
    std::vector<NodeId> parents;
    if (diNs) parents.emplace_back(*diNs, 5001);  // DeviceSet
    parents.emplace_back(0, ua::ns0::ObjectsFolder);
    for (const NodeId& parent : parents) {
        ua::client::BrowseOptions o;
        o.nodeClassMask = 1;  // Objects
        std::vector<ua::ReferenceDescription> refs;
        try {
            refs = c.browse(parent, o, deadline);
        } catch (const ua::client::Error&) {
            continue;  // no DeviceSet on this server
        }
        for (const auto& r : refs) {
            if (r.typeDefinition.nodeId != type || r.nodeId.serverIndex != 0) continue;
            BoardNodes b;
            b.object = r.nodeId.nodeId;
            auto child = [&](const char* name) {
                return c.resolve(b.object, "/" + std::to_string(*kelvinNs) + ":" + name, deadline);
            };
            b.voltage = child("Voltage");
            b.state = child("State");
            b.toolId = child("ToolId");
            return b;
        }
    }
    return std::nullopt;
}

ua::client::ClientConfig clientConfig(std::chrono::milliseconds timeout) {
    ua::client::ClientConfig cc;
    cc.applicationName = "pnp tool changer";
    cc.applicationUri = "urn:pnp:component:toolchanger:adc-client";
    cc.requestTimeout = timeout;
    cc.connectTimeout = timeout;
    return cc;
}

}  // namespace

bool AdcMonitor::isKelvinAdc(const std::string& url, std::chrono::milliseconds timeout) {
    try {
        ua::client::Client c(clientConfig(timeout));
        c.connect(url);
        return findBoard(c, timeout).has_value();
    } catch (const std::exception&) {
        return false;
    }
}

AdcMonitor::AdcMonitor(const std::string& url, std::chrono::milliseconds timeout)
    : url_(url), client_(std::make_shared<ua::client::Client>(clientConfig(timeout))) {
    client_->connect(url);
    auto board = findBoard(*client_, timeout);
    if (!board) throw std::runtime_error("no KelvinToolChangerType object on " + url);
    client_->startBackgroundThread();
    subscription_ = ua::client::Subscription(*client_, {.publishingInterval = 10}, {}, timeout);
    ua::client::DataChangeOptions o;
    o.samplingInterval = 0;  // as fast as the server samples (its values are pushed)
    o.queueSize = 1;
    items_ = subscription_.monitorValues(
        {board->voltage, board->state, board->toolId},
        [this](std::size_t index, const ua::DataValue& v) { update(index, v); }, o, nullptr,
        timeout);
    for (const auto& item : items_)
        if (!item.valid()) throw std::runtime_error("cannot monitor the ADC's values on " + url);
}

AdcMonitor::~AdcMonitor() {
    items_.clear();
    subscription_ = ua::client::Subscription();
    client_->stopBackgroundThread();
}

void AdcMonitor::update(std::size_t index, const ua::DataValue& v) {
    const bool good = !v.statusOrGood().isBad() && v.value.has_value();
    std::lock_guard l(mutex_);
    switch (index) {
        case 0:
            voltage_.reset();
            if (good)
                if (const auto* d = v.value->scalar<double>()) voltage_ = *d;
            break;
        case 1:
            state_.reset();
            if (good)
                if (const auto* i = v.value->scalar<ua::Int32>()) state_ = *i;
            break;
        case 2:
            toolId_.reset();
            if (good)
                if (const auto* i = v.value->scalar<ua::Int32>()) toolId_ = *i;
            break;
        default:
            return;
    }
    AdcSample s;
    s.updates = sample_.updates + 1;
    if (voltage_ && state_ && toolId_) {
        s.voltage = *voltage_;
        // The board's classification; our own of its voltage must agree, else the values
        // are from different samples (one notification each) and the newer one follows.
        const ChangerReading board{kelvin::changerStateFromValue(*state_),
                                   *state_ == static_cast<int>(ChangerState::kTool) ? *toolId_ : 0};
        s.reading = board;
        s.valid = board.state != ChangerState::kUnknown && kelvin::classify(*voltage_) == board;
    }
    if (!s.valid) s.reading = {};
    sample_ = s;
    cv_.notify_all();
}

AdcSample AdcMonitor::latest() const {
    std::lock_guard l(mutex_);
    return sample_;
}

std::optional<AdcSample> AdcMonitor::waitFor(const std::function<bool(const AdcSample&)>& pred,
                                             std::chrono::milliseconds timeout,
                                             std::stop_token stop) const {
    const auto end = std::chrono::steady_clock::now() + timeout;
    std::unique_lock l(mutex_);
    while (!pred(sample_)) {
        if (stop.stop_requested()) return std::nullopt;
        const auto now = std::chrono::steady_clock::now();
        if (now >= end) return std::nullopt;
        // Slices: a stop request is seen within 20 ms.
        cv_.wait_until(l, std::min(end, now + std::chrono::milliseconds(20)));
    }
    return sample_;
}

}  // namespace pnp::component::toolchanger
