// The Schmalz ECBPi vacuum gripper's hardware interface: IO-Link process data through an
// IO-Link master's Modbus TCP interface (libmodbus), unpacked by the same tables the
// simulator serves (models/iolink/schmalz-ecbpi.yaml and the master's map,
// docs/schmalz-ecbpi.md). The same adapter drives a real ECBPi on a real master: give it that
// master's map and the device's table.
//
// Every call has a deadline: each Modbus request's response timeout is the time left (at most
// requestTimeout). A failed request closes the connection; the next call reconnects.
#pragma once

#include <Eigen/Geometry>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "base/result.hpp"
#include "device/gripper/gripper_hardware.hpp"
#include "iolink/process_data.hpp"

namespace pnp::device::ecbpi {

using gripper::Deadline;
using gripper::Done;
using gripper::Error;
using gripper::ErrorKind;
using gripper::Result;

struct EcbpiOptions {
    // The IO-Link master (`--iolink HOST:PORT`) and the device's port on it (`--port N`).
    std::string host = "127.0.0.1";
    std::uint16_t tcpPort = 502;
    std::size_t ioLinkPort = 1;
    // The tables; empty = the installed ones (models/iolink/).
    std::filesystem::path table;      // the device's process data (schmalz-ecbpi.yaml)
    std::filesystem::path masterMap;  // the master's Modbus map (modbus-master.yaml)
    // Grip point: flange -> vacuum point (the published cell's, z 0.1868 m), cup diameter.
    Eigen::Isometry3d offset = Eigen::Isometry3d(Eigen::Translation3d(0.0, 0.0, 0.1868));
    double cupDiameter = 0.03;  // m
    // Timing.
    std::chrono::milliseconds requestTimeout{500};   // one Modbus request at most
    std::chrono::milliseconds pollPeriod{5};         // process data polling while waiting
    std::chrono::milliseconds partTimeout{1000};     // grasp: part present within this
    std::chrono::milliseconds releaseTimeout{1000};  // release: vacuum gone within this
    double releasedVacuum = 20.0;                    // mbar: blow-off ends below this
    std::string serialNumber;  // DI; empty: "unknown" (the process data does not carry it)
};

// "HOST:PORT" (PORT 1..65535; HOST a name or an IPv4 address, [v6] in brackets).
base::Result<EcbpiOptions, std::string> parseIoLinkAddress(std::string_view text,
                                                           EcbpiOptions options = {});

class EcbpiHardware : public gripper::GripperHardware {
  public:
    // Loads the tables and checks them against each other (the fields the adapter needs, the
    // port within the master's ports, the process data within the master's areas).
    static base::Result<std::unique_ptr<EcbpiHardware>, std::string> create(EcbpiOptions options);
    ~EcbpiHardware() override;
    EcbpiHardware(const EcbpiHardware&) = delete;
    EcbpiHardware& operator=(const EcbpiHardware&) = delete;

    Result<Done> connect(Deadline deadline) override;
    void disconnect() override;
    Result<Done> activate(Deadline deadline, const std::atomic<bool>& cancel) override;
    Result<gripper::Status> grasp(const gripper::GraspRequest& request, Deadline deadline,
                                  const std::atomic<bool>& cancel) override;
    Result<gripper::Status> release(Deadline deadline, const std::atomic<bool>& cancel) override;
    Result<gripper::Status> move(const gripper::MoveRequest& request, Deadline deadline,
                                 const std::atomic<bool>& cancel) override;
    void stop(Deadline deadline) override;
    Result<gripper::Status> status(Deadline deadline) override;

    gripper::GripPoint gripPoint() const override;
    std::string manufacturer() const override;
    std::string modelName() const override;
    std::string serialNumber() const override;
    std::string endpoint() const override;

    // The process data in, decoded (for tests and tools).
    struct Inputs {
        iolink::PortState port = iolink::PortState::kNoDevice;
        bool partPresent = false;
        bool inControlRange = false;
        bool partDetached = false;
        double vacuum = 0.0;  // mbar
        int deviceStatus = 0;
        bool suction = false;  // the outputs as the master holds them
        bool blowOff = false;
    };
    Result<Inputs> readInputs(Deadline deadline);

  private:
    EcbpiHardware(EcbpiOptions options, iolink::DeviceTable table, iolink::MasterMap map);

    // All with mutex_ held.
    Result<Done> ensureConnected(Deadline deadline);
    void closeLocked();
    Result<Done> setTimeout(Deadline deadline);
    Error requestFailed(const std::string& what);
    Result<Inputs> readInputsLocked(Deadline deadline);
    Result<Done> writeOutputsLocked(bool suction, bool blowOff, Deadline deadline);
    Result<Done> checkIdentityLocked(Deadline deadline);
    // Switches the outputs off (best effort, bounded by a short deadline of its own).
    void outputsOffLocked(bool suction, bool blowOff);
    Error noDevice(const Inputs& in) const;
    // Reads the inputs every pollPeriod until `step` (called with mutex_ held, on the inputs
    // of an operating port) returns the call's result. A cancel (`cancelled`: its message), a
    // failed read or a port no longer operating switch both outputs off and end the call.
    using PollStep = std::function<std::optional<Result<gripper::Status>>(Inputs& in)>;
    Result<gripper::Status> pollUntil(Deadline deadline, Deadline giveUp,
                                      const std::atomic<bool>& cancel, const std::string& cancelled,
                                      const PollStep& step);
    gripper::Status toStatus(const Inputs& in) const;

    EcbpiOptions options_;
    iolink::DeviceTable table_;
    iolink::MasterMap map_;
    const iolink::Field* partPresent_ = nullptr;
    const iolink::Field* inControlRange_ = nullptr;
    const iolink::Field* partDetached_ = nullptr;
    const iolink::Field* vacuum_ = nullptr;
    const iolink::Field* deviceStatus_ = nullptr;  // optional
    const iolink::Field* suction_ = nullptr;
    const iolink::Field* blowOff_ = nullptr;

    std::mutex mutex_;
    struct Context;  // libmodbus's modbus_t, kept out of this header
    std::unique_ptr<Context> ctx_;
    std::vector<std::uint8_t> pdOut_;  // the outputs as last read / written
    bool pdOutKnown_ = false;
    bool identityChecked_ = false;
};

}  // namespace pnp::device::ecbpi
