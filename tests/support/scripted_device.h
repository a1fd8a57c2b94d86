#pragma once
// A device backend for tests: read() returns the state the test sets (or a fault on request),
// write() records the last command. Real-time safe like a real backend (no allocation).

#include "tactus/device/device.h"

namespace tactus::test {

class ScriptedDevice : public device::Device {
 public:
  device::DeviceInfo info() const override { return {"scripted", 20.0, true, true}; }
  void open() override {}
  void calibrate() override {}
  void enableForces(bool) override {}
  void close() noexcept override {}
  device::IoStatus read(device::DeviceState* out) noexcept override {
    if (fault) return device::IoStatus::kFault;
    if (no_data) return device::IoStatus::kNoData;
    *out = state;
    return device::IoStatus::kOk;
  }
  device::IoStatus write(const device::DeviceCommand& cmd) noexcept override {
    last = cmd;
    return device::IoStatus::kOk;
  }
  device::DeviceState state{};       ///< what read() returns
  device::DeviceCommand last{};      ///< the last command written
  bool fault = false;                ///< read() reports a fault
  bool no_data = false;              ///< read() reports no new data (state unchanged)
};

}  // namespace tactus::test
