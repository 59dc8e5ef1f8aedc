// The tool changer component's view of the Kelvin ADC board (`pnp device kelvin-adc`): an
// OPC UA client that finds the board's KelvinToolChangerType object (by type, in the
// urn:pnp:kelvin namespace) and subscribes to its Voltage, State and ToolId. The latest
// reading is kept; waitFor() blocks until a predicate holds on it.
#pragma once

#include <chrono>
#include <condition_variable>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <stop_token>
#include <string>

#include "device/kelvin/changer_voltage.hpp"
#include "ua/client/client.hpp"
#include "ua/client/subscription.hpp"

namespace pnp::component::toolchanger {

using device::kelvin::ChangerReading;
using device::kelvin::ChangerState;

struct AdcSample {
    bool valid = false;      // Good values received (false: none yet, or the board's link is dead)
    double voltage = 0.0;    // V, 24 V scale
    ChangerReading reading;  // kUnknown unless valid
    std::uint64_t updates = 0;
};
// "tool 2 (6.71 V)", "unknown (no reading)".
std::string describe(const AdcSample& sample);

class AdcMonitor {
  public:
    // Connects, finds the board's object and subscribes; throws ua::client::Error or
    // std::runtime_error ("no KelvinToolChangerType object ...").
    AdcMonitor(const std::string& url, std::chrono::milliseconds timeout);
    ~AdcMonitor();
    AdcMonitor(const AdcMonitor&) = delete;
    AdcMonitor& operator=(const AdcMonitor&) = delete;

    // Whether the server at `url` has a KelvinToolChangerType object (a quick probe).
    static bool isKelvinAdc(const std::string& url, std::chrono::milliseconds timeout);

    const std::string& url() const { return url_; }
    AdcSample latest() const;
    // Until pred(latest()) holds, the timeout passes or stop is requested; the last sample.
    std::optional<AdcSample> waitFor(const std::function<bool(const AdcSample&)>& pred,
                                     std::chrono::milliseconds timeout,
                                     std::stop_token stop = {}) const;

  private:
    void update(std::size_t index, const ua::DataValue& value);

    std::string url_;
    std::shared_ptr<ua::client::Client> client_;
    ua::client::Subscription subscription_;
    std::vector<ua::client::MonitoredItem> items_;
    mutable std::mutex mutex_;
    mutable std::condition_variable cv_;
    // Per item: Voltage, State, ToolId.
    std::optional<double> voltage_;
    std::optional<int> state_, toolId_;
    AdcSample sample_;
};

}  // namespace pnp::component::toolchanger
