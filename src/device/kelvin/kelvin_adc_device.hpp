// The Kelvin tool changer's ADC board as an OPC UA device (`pnp device kelvin-adc`; the
// thesis's TinyUA board that reads the changer's state voltage): it polls the board's analog
// input over Modbus TCP (libmodbus; input register 0 = pin voltage in mV, see
// sim/kelvin/kelvin_adc_input.hpp) every 10 ms, each call with its own deadline, and serves
//
//   Objects/DeviceSet/<name>           KelvinToolChangerType (urn:pnp:kelvin; a DI DeviceType)
//     Voltage  Double  V, 24 V scale
//     State    KelvinChangerState: Ready, Intermediate, NoTool, Tool, Unknown
//     ToolId   Int32   1..10, 0 = none
//
// A dead link (no answer, connection refused, an exception) makes State Unknown and gives
// Voltage and ToolId the status Bad_NoCommunication; the next good read restores them. The
// type comes from models/Pnp.Kelvin.NodeSet2.xml, so clients find the board by type.
//
//   ua::server::Server server(config);
//   KelvinAdcDevice adc(server, {.adcHost = "127.0.0.1", .adcPort = 1502});
//   server.start();
//   adc.start();
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>

#include "device/kelvin/changer_voltage.hpp"
#include "ua/server/server.hpp"

namespace pnp::device::kelvin {

inline constexpr std::string_view kKelvinUri = "urn:pnp:kelvin";
inline constexpr ua::UInt32 kKelvinToolChangerTypeId = 1001;  // in kKelvinUri
inline constexpr ua::UInt32 kKelvinChangerStateTypeId = 3001;
inline constexpr std::uint16_t kDefaultModbusPort = 502;

// The board's register map (input registers, FC04) and divider, as the board documents them
// (the simulator, sim/kelvin, serves the same): 0 = pin voltage in mV, 1 = raw 12-bit count
// (3.3 V reference). The pin sees the 24 V-scale voltage through 10 kΩ / 1.5 kΩ.
inline constexpr std::uint16_t kAdcRegPinMillivolts = 0;
inline constexpr std::uint16_t kAdcRegRawCount = 1;
inline constexpr int kAdcInputRegisterCount = 2;
inline constexpr double kAdcDividerRatio = 1500.0 / (10000.0 + 1500.0);

// A set-up error (model file missing, bad options).
class KelvinDeviceError : public std::runtime_error {
  public:
    using std::runtime_error::runtime_error;
};

// "host", "host:port", "[v6]:port" (default port 502); throws KelvinDeviceError.
std::pair<std::string, std::uint16_t> parseModbusAddress(const std::string& text);
// models/Pnp.Kelvin.NodeSet2.xml ($PNP_SKILL_MODELS or the source tree's models/).
std::string kelvinModelFile();

struct KelvinAdcDeviceOptions {
    std::string name = "ToolChanger";  // BrowseName below DeviceSet
    std::string adcHost = "127.0.0.1";
    std::uint16_t adcPort = kDefaultModbusPort;
    int unitId = 0xFF;  // Modbus TCP unit id ("this device")
    std::chrono::milliseconds pollPeriod{10};
    std::chrono::milliseconds responseTimeout{50};  // per Modbus call (connect included)
    // Consecutive failed reads before the values go Bad (one lost answer is no dead link).
    int failuresBeforeBad = 3;
    std::chrono::milliseconds reconnectInterval{100};  // between connection attempts
    std::string serialNumber = "kelvin-adc-1";
    ua::UInt16 namespaceIndex = 1;
};

// What the device shows now (thread-safe copy).
struct AdcStatus {
    bool linkUp = false;         // the last reads succeeded (false before the first one)
    double voltage = 0.0;        // V, 24 V scale (the last good one)
    ChangerReading reading;      // kUnknown while the link is down
    std::uint64_t reads = 0;     // good reads
    std::uint64_t failures = 0;  // failed reads and connection attempts
    std::string error;           // the last failure, for people
};

class KelvinAdcDevice {
  public:
    // Loads the model (and DI) and builds the nodes: call before Server::start(). Throws
    // KelvinDeviceError / ua::server::NodeSetError.
    KelvinAdcDevice(ua::server::Server& server, KelvinAdcDeviceOptions options);
    ~KelvinAdcDevice();  // stop()
    KelvinAdcDevice(const KelvinAdcDevice&) = delete;
    KelvinAdcDevice& operator=(const KelvinAdcDevice&) = delete;

    void start();  // the polling thread
    void stop();

    const ua::NodeId& deviceNode() const;
    const ua::NodeId& voltageNode() const;
    const ua::NodeId& stateNode() const;
    const ua::NodeId& toolIdNode() const;
    AdcStatus status() const;
    std::string adcEndpoint() const;  // "host:port"

    struct Impl;

  private:
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::device::kelvin
