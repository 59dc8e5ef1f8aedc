// The Schmalz ECBPi electric vacuum generator on an IO-Link port: its vacuum physics from the
// world and its process data by the table (models/iolink/schmalz-ecbpi.yaml). The model and
// its times are documented in docs/schmalz-ecbpi.md.
//
// Vacuum (mbar below ambient) follows first-order laws towards a target that depends on the
// outputs and on whether the world says the cup is sealed on a flat top face:
//   suction, sealed    pump on: -> maxVacuum (evacuationTau); the pump stops at H1 and starts
//                      again below H1 - h1 (the ECBPi's control function), meanwhile the sealed
//                      cup leaks slowly (sealedLeakTau)
//   suction, open      -> freeFlowVacuum (freeFlowTau): the pump only moves air
//   suction off        -> 0 (ventTau)
//   blow-off           -> 0 (blowOffTau); has priority over suction and releases the part
// Flags: part present (SP2: >= H2 until < H2 - h2), in control range (SP1: >= H1 until
// < H1 - h1), part detached (SP3: part present was lost while suction stayed on; cleared by
// the next suction cycle or blow-off). The world is told: hold(tool, object) when part present
// comes with the cup sealed on that object; release(tool) below holdingVacuum or on blow-off.
//
// Power comes from the world (toolPowered): without it the port sees no device and the
// outputs do nothing; after power-on the device spends startupTime in PREOPERATE.
//
// Threads: everything here runs on the simulator's stepping thread (via IoLinkMaster::step,
// or step() directly in tests). Not thread-safe on its own; the master locks around it.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <span>
#include <vector>

#include "iolink/process_data.hpp"
#include "sim/ecbpi/iolink_master.hpp"
#include "world/world.hpp"

namespace pnp::sim::ecbpi {

struct EcbpiConfig {
    // The process data table; empty (no fields) = models/iolink/schmalz-ecbpi.yaml.
    iolink::DeviceTable table;
    // Switching points (mbar), Schmalz's defaults for its vacuum generators.
    double h1 = 750.0;            // control: the pump stops here ("in control range")
    double h1Hysteresis = 150.0;  // ... and starts again below H1 - h1
    double h2 = 550.0;            // part present
    double h2Hysteresis = 10.0;   // ... until below H2 - h2
    // Physics (mbar, s): see the header comment and docs/schmalz-ecbpi.md.
    double maxVacuum = 800.0;      // the pump's ultimate vacuum on a sealed cup
    double freeFlowVacuum = 40.0;  // suction on, cup open
    double evacuationTau = 0.06;   // sealed: 0 -> H2 (550) in 70 ms, -> H1 (750) in 170 ms
    double freeFlowTau = 0.02;     // cup open (also: a seal lost while under vacuum)
    double sealedLeakTau = 15.0;   // pump stopped at H1, cup sealed: ~50 mbar/s at 750
    double ventTau = 0.3;          // suction off
    double blowOffTau = 0.012;     // blow-off: 750 -> below 5 mbar in 60 ms
    double holdingVacuum = 200.0;  // below it the part drops (world.release)
    double startupTime = 0.2;      // s in PREOPERATE after power-on
    double warningTime = 1.0;      // s of suction without part present: status yellow
};

// What the model is doing (tests, ground truth).
struct EcbpiState {
    iolink::PortState port = iolink::PortState::kNoDevice;
    bool powered = false;
    double vacuum = 0.0;   // mbar
    bool suction = false;  // outputs as the device applies them (false unless operating)
    bool blowOff = false;
    bool pumpRunning = false;
    bool partPresent = false;
    bool inControlRange = false;
    bool partDetached = false;
    int deviceStatus = 0;                // 0 green, 1 yellow
    std::optional<std::size_t> holding;  // the object the world says this tool holds
};

class Ecbpi : public IoLinkDevice {
  public:
    // `tool`: an index in world.description().tools, a vacuum gripper (std::invalid_argument
    // otherwise, or when the table lacks a field the model needs: part-present,
    // in-control-range, part-detached, vacuum in; suction, blow-off out; std::runtime_error
    // when the default table does not load). `world` must outlive the model.
    Ecbpi(world::World& world, std::size_t tool, EcbpiConfig config = {});
    Ecbpi(const Ecbpi&) = delete;  // holds pointers into its own table
    Ecbpi& operator=(const Ecbpi&) = delete;

    std::uint16_t vendorId() const override { return config_.table.vendorId; }
    std::uint32_t deviceId() const override { return config_.table.deviceId; }
    std::size_t pdInBytes() const override { return config_.table.pdInBytes; }
    std::size_t pdOutBytes() const override { return config_.table.pdOutBytes; }
    void setProcessDataOut(std::span<const std::uint8_t> pd) override;
    void step(double dt) override;
    iolink::PortState portState() const override { return state_.port; }
    std::vector<std::uint8_t> processDataIn() const override;

    // Outputs directly (tests without a master): suction / blow-off bits.
    void setOutputs(bool suction, bool blowOff);
    const EcbpiState& state() const { return state_; }
    const EcbpiConfig& config() const { return config_; }

    static std::filesystem::path defaultTablePath();  // models/iolink/schmalz-ecbpi.yaml

  private:
    void updateFlags(bool suctionOn);
    void updateWorld(std::optional<std::size_t> sealedOn);

    world::World& world_;
    std::size_t tool_;
    EcbpiConfig config_;
    // The table's fields (checked at construction).
    const iolink::Field* partPresent_ = nullptr;
    const iolink::Field* inControlRange_ = nullptr;
    const iolink::Field* partDetached_ = nullptr;
    const iolink::Field* vacuum_ = nullptr;
    const iolink::Field* deviceStatus_ = nullptr;  // optional
    const iolink::Field* pumpPower_ = nullptr;     // optional
    const iolink::Field* suction_ = nullptr;
    const iolink::Field* blowOff_ = nullptr;

    bool requestedSuction_ = false;  // the outputs as the master holds them
    bool requestedBlowOff_ = false;
    double sincePowerOn_ = 0.0;
    double suctionWithoutPart_ = 0.0;
    EcbpiState state_;
};

}  // namespace pnp::sim::ecbpi
