#include "device/kelvin/kelvin_adc_device.hpp"

#include <modbus.h>

#include <array>
#include <cerrno>
#include <condition_variable>
#include <cstdlib>
#include <mutex>
#include <optional>
#include <stop_token>
#include <thread>
#include <utility>
#include <vector>

#include "skill/model/model.hpp"
#include "ua/server/nodeset_xml.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::device::kelvin {

using ua::NodeId;
using ua::QualifiedName;
using Clock = std::chrono::steady_clock;

std::pair<std::string, std::uint16_t> parseModbusAddress(const std::string& text) {
    std::string host = text;
    std::string port;
    if (!text.empty() && text.front() == '[') {
        const auto close = text.find(']');
        if (close == std::string::npos)
            throw KelvinDeviceError("missing ']' in the address \"" + text + "\"");
        host = text.substr(1, close - 1);
        if (close + 1 < text.size()) {
            if (text[close + 1] != ':')
                throw KelvinDeviceError("bad address \"" + text + "\" (HOST[:PORT])");
            port = text.substr(close + 2);
        }
    } else if (const auto colon = text.rfind(':');
               colon != std::string::npos && text.find(':') == colon) {
        host = text.substr(0, colon);
        port = text.substr(colon + 1);
    }
    if (host.empty()) throw KelvinDeviceError("expected HOST[:PORT], got \"" + text + "\"");
    if (port.empty()) return {host, kDefaultModbusPort};
    char* end = nullptr;
    const long p = std::strtol(port.c_str(), &end, 10);
    if (*end != '\0' || p < 1 || p > 65535)
        throw KelvinDeviceError("bad port \"" + port + "\" in \"" + text + "\"");
    return {host, static_cast<std::uint16_t>(p)};
}

std::string kelvinModelFile() {
    return (skill::modelsDirectory() / "Pnp.Kelvin.NodeSet2.xml").string();
}

// ---- the Modbus link to the board (polling thread only) ---------------------------------
namespace {

class ModbusLink {
  public:
    ModbusLink(std::string host, std::uint16_t port, int unitId, std::chrono::milliseconds timeout)
        : host_(std::move(host)), port_(std::to_string(port)), unitId_(unitId), timeout_(timeout) {}
    ~ModbusLink() { close(); }
    ModbusLink(const ModbusLink&) = delete;
    ModbusLink& operator=(const ModbusLink&) = delete;

    bool connected() const { return ctx_ != nullptr; }

    // false with `error` set when the board cannot be reached.
    bool connect(std::string& error) {
        close();
        modbus_t* ctx = modbus_new_tcp_pi(host_.c_str(), port_.c_str());
        if (ctx == nullptr) {
            error = "cannot create a Modbus TCP context for " + host_ + ":" + port_;
            return false;
        }
        const auto us = std::chrono::duration_cast<std::chrono::microseconds>(timeout_).count();
        const auto sec = static_cast<std::uint32_t>(us / 1000000);
        const auto usec = static_cast<std::uint32_t>(us % 1000000);
        // The response timeout also bounds libmodbus' connect (non-blocking connect + select).
        modbus_set_response_timeout(ctx, sec, usec);
        modbus_set_byte_timeout(ctx, sec, usec);
        modbus_set_slave(ctx, unitId_);
        if (modbus_connect(ctx) == -1) {
            error = "Modbus TCP " + host_ + ":" + port_ + ": " + modbus_strerror(errno);
            modbus_free(ctx);
            return false;
        }
        ctx_ = ctx;
        return true;
    }

    // The pin voltage register (mV); nullopt with `error` on any failure (the link is then
    // closed: a late answer must not be taken for the next one's).
    std::optional<std::uint16_t> readPinMillivolts(std::string& error) {
        if (ctx_ == nullptr) return std::nullopt;
        std::array<std::uint16_t, kAdcInputRegisterCount> regs{};
        const int n = modbus_read_input_registers(ctx_, kAdcRegPinMillivolts,
                                                  static_cast<int>(regs.size()), regs.data());
        if (n != static_cast<int>(regs.size())) {
            error = "Modbus TCP " + host_ + ":" + port_ + ": read input registers: " +
                    (n == -1 ? std::string(modbus_strerror(errno)) : "short answer");
            close();
            return std::nullopt;
        }
        return regs[kAdcRegPinMillivolts];
    }

    void close() {
        if (ctx_ == nullptr) return;
        modbus_close(ctx_);
        modbus_free(ctx_);
        ctx_ = nullptr;
    }

  private:
    std::string host_;
    std::string port_;
    int unitId_;
    std::chrono::milliseconds timeout_;
    modbus_t* ctx_ = nullptr;
};

}  // namespace

struct KelvinAdcDevice::Impl {
    ua::server::Server& server;
    KelvinAdcDeviceOptions options;
    NodeId device, voltage, state, toolId;
    ua::server::AddressSpace::VariableGroup values;  // polling thread only

    mutable std::mutex mutex;
    AdcStatus status;
    std::jthread poller;

    Impl(ua::server::Server& s, KelvinAdcDeviceOptions o) : server(s), options(std::move(o)) {}

    void build();
    void poll(std::stop_token stop);
    void publish(bool linkUp, double volts, ChangerReading reading, bool first);
};

void KelvinAdcDevice::Impl::build() {
    auto& space = server.addressSpace();
    if (!ua::server::isModelLoaded(space, kKelvinUri)) {
        auto searchPath = ua::server::defaultNodeSetSearchPath();
        searchPath.insert(searchPath.begin(), skill::modelsDirectory());
        ua::server::loadNodeSetXml(space, kelvinModelFile(), searchPath);
    }
    const auto kelvin = space.namespaceIndex(kKelvinUri);
    const auto di = space.namespaceIndex(skill::kDiUri);
    if (!kelvin || !di) throw KelvinDeviceError("the Kelvin model did not load (urn:pnp:kelvin)");
    const NodeId type(*kelvin, kKelvinToolChangerTypeId);
    const NodeId deviceSet(*di, 5001);
    if (!space.contains(type) || !space.contains(deviceSet))
        throw KelvinDeviceError("KelvinToolChangerType or DI DeviceSet missing after loading " +
                                kelvinModelFile());
    const ua::UInt16 ns = options.namespaceIndex;
    device = space.addObject(deviceSet, NodeId(ns, options.name), QualifiedName(ns, options.name),
                             {}, type);
    auto child = [&](ua::UInt16 index, const char* name) {
        const QualifiedName path[] = {QualifiedName(index, name)};
        auto id = space.resolvePath(device, path);
        if (!id) throw KelvinDeviceError(std::string("the instance has no ") + name);
        return *id;
    };
    voltage = child(*kelvin, "Voltage");
    state = child(*kelvin, "State");
    toolId = child(*kelvin, "ToolId");
    values = ua::server::AddressSpace::VariableGroup({voltage, state, toolId});
    // DI identification (Mandatory in DeviceType; set where present).
    auto setIf = [&](const char* name, ua::Variant v) {
        const QualifiedName path[] = {QualifiedName(*di, name)};
        if (auto id = space.resolvePath(device, path)) (void)space.setValue(*id, ua::DataValue(v));
    };
    setIf("Manufacturer", ua::Variant(ua::LocalizedText("", "pnp")));
    setIf("Model", ua::Variant(ua::LocalizedText("", "Kelvin tool changer ADC board")));
    setIf("SerialNumber", ua::Variant(ua::String(options.serialNumber)));
    setIf("HardwareRevision", ua::Variant(ua::String("1")));
    setIf("SoftwareRevision", ua::Variant(ua::String("1.0.0")));
    setIf("DeviceRevision", ua::Variant(ua::String("1")));
    setIf("DeviceManual", ua::Variant(ua::String("src/device/kelvin/README.md")));
    setIf("RevisionCounter", ua::Variant(ua::Int32{0}));
    // Nothing read yet: the link is not up.
    publish(false, 0.0, {}, true);
}

void KelvinAdcDevice::Impl::publish(bool linkUp, double volts, ChangerReading reading, bool first) {
    ua::DataValue v{ua::Variant(volts)};
    ua::DataValue s{ua::Variant(ua::Int32{static_cast<int>(reading.state)})};
    ua::DataValue t{ua::Variant(ua::Int32{reading.toolId})};
    if (!linkUp) {
        const ua::StatusCode bad(first ? ua::status::BadWaitingForInitialData
                                       : ua::status::BadNoCommunication);
        v.status = bad;
        t.status = bad;
    }
    (void)server.addressSpace().setValues(values, {{0, v}, {1, s}, {2, t}});
}

void KelvinAdcDevice::Impl::poll(std::stop_token stop) {
    ModbusLink link(options.adcHost, options.adcPort, options.unitId, options.responseTimeout);
    std::mutex sleepMutex;
    std::condition_variable_any wake;
    auto sleepUntil = [&](Clock::time_point t) {
        std::unique_lock l(sleepMutex);
        wake.wait_until(l, stop, t, [] { return false; });
    };
    int consecutiveFailures = 0;
    bool published = false;  // a value was published by this thread
    bool linkUp = false;
    ChangerReading lastReading{};
    double lastVolts = 0.0;
    Clock::time_point nextConnect = Clock::now();
    Clock::time_point next = Clock::now();
    while (!stop.stop_requested()) {
        std::string error;
        std::optional<std::uint16_t> mv;
        const auto now = Clock::now();
        if (!link.connected() && now >= nextConnect) {
            if (!link.connect(error)) nextConnect = now + options.reconnectInterval;
        }
        if (link.connected()) mv = link.readPinMillivolts(error);
        if (mv) {
            consecutiveFailures = 0;
            const double volts = *mv / 1000.0 / kAdcDividerRatio;
            const ChangerReading reading = classify(volts);
            if (!published || !linkUp || volts != lastVolts || reading != lastReading)
                publish(true, volts, reading, false);
            published = true;
            linkUp = true;
            lastVolts = volts;
            lastReading = reading;
            std::lock_guard l(mutex);
            status.linkUp = true;
            status.voltage = volts;
            status.reading = reading;
            ++status.reads;
        } else if (!error.empty() || !link.connected()) {
            ++consecutiveFailures;
            const bool dead = consecutiveFailures >= options.failuresBeforeBad;
            if (dead && (linkUp || !published)) {
                publish(false, lastVolts, {}, false);
                published = true;
                linkUp = false;
            }
            std::lock_guard l(mutex);
            if (!error.empty()) {
                ++status.failures;
                status.error = error;
            }
            if (dead) {
                status.linkUp = false;
                status.reading = {};
            }
        }
        next += options.pollPeriod;
        const auto after = Clock::now();
        if (next < after) next = after;  // no catching up after a slow call
        sleepUntil(next);
    }
}

KelvinAdcDevice::KelvinAdcDevice(ua::server::Server& server, KelvinAdcDeviceOptions options)
    : impl_(std::make_unique<Impl>(server, std::move(options))) {
    if (impl_->options.name.empty()) throw KelvinDeviceError("the device needs a name");
    if (impl_->options.pollPeriod.count() <= 0 || impl_->options.responseTimeout.count() <= 0)
        throw KelvinDeviceError("poll period and response timeout must be positive");
    if (impl_->options.failuresBeforeBad < 1) impl_->options.failuresBeforeBad = 1;
    impl_->build();
}

KelvinAdcDevice::~KelvinAdcDevice() { stop(); }

void KelvinAdcDevice::start() {
    if (impl_->poller.joinable()) return;
    impl_->poller = std::jthread([this](std::stop_token stop) { impl_->poll(stop); });
}

void KelvinAdcDevice::stop() {
    if (!impl_->poller.joinable()) return;
    impl_->poller.request_stop();
    impl_->poller.join();
}

const NodeId& KelvinAdcDevice::deviceNode() const { return impl_->device; }
const NodeId& KelvinAdcDevice::voltageNode() const { return impl_->voltage; }
const NodeId& KelvinAdcDevice::stateNode() const { return impl_->state; }
const NodeId& KelvinAdcDevice::toolIdNode() const { return impl_->toolId; }

AdcStatus KelvinAdcDevice::status() const {
    std::lock_guard l(impl_->mutex);
    return impl_->status;
}

std::string KelvinAdcDevice::adcEndpoint() const {
    return impl_->options.adcHost + ":" + std::to_string(impl_->options.adcPort);
}

}  // namespace pnp::device::kelvin
