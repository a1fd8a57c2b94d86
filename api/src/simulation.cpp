// tactus::Simulation: the public face of the simulation pipeline (simulation.h); the work is
// sim::Simulation's (sim_server/include/tactus/sim/pipeline.h).
#include "tactus/simulation.h"

#include <fmt/format.h>

#include <stdexcept>

#include "model_data.h"
#include "tactus/shared/error.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/pipeline.h"

namespace tactus {

struct Simulation::Impl {
  Model model;
  sim::Simulation sim;
  Impl(const Model& m, std::shared_ptr<const sim::SimulationModel> compiled)
      : model(m), sim(std::move(compiled)) {}

  void checkTissue(int t) const {
    if (t < 0 || t >= sim.tissueCount()) {
      throw std::out_of_range(fmt::format("{}: no tissue {} (the model has {})", model.name(), t,
                                          sim.tissueCount()));
    }
  }
  void checkInstrument(int i) const {
    if (i < 0 || i >= sim.instrumentCount()) {
      throw std::out_of_range(fmt::format("{}: no instrument {} (the model has {})",
                                          model.name(), i, sim.instrumentCount()));
    }
  }
};

Simulation::Simulation(const Model& model)
    : impl_(std::make_unique<Impl>(model, model.data_->model)) {}
Simulation::~Simulation() = default;
Simulation::Simulation(Simulation&&) noexcept = default;
Simulation& Simulation::operator=(Simulation&&) noexcept = default;

const Model& Simulation::model() const { return impl_->model; }

StepReport Simulation::step() { return impl_->sim.step(); }

void Simulation::setDeviceTarget(int instrument, const DeviceTarget& target) {
  impl_->checkInstrument(instrument);
  impl_->sim.setDeviceTarget(instrument, target);
}

DeviceTarget Simulation::scriptedTarget(int instrument, double t_s) const {
  impl_->checkInstrument(instrument);
  return impl_->sim.scriptedTarget(instrument, t_s);
}

void Simulation::followScript() {
  sim::Simulation& s = impl_->sim;
  for (int i = 0; i < s.instrumentCount(); ++i) s.setDeviceTarget(i, s.scriptedTarget(i, s.time()));
}

double Simulation::time() const { return impl_->sim.time(); }
long Simulation::stepIndex() const { return impl_->sim.stepIndex(); }
int Simulation::instrumentCount() const { return impl_->sim.instrumentCount(); }

InstrumentState Simulation::instrument(int i) const {
  impl_->checkInstrument(i);
  const sim::Instrument& tool = impl_->sim.instrument(i);
  InstrumentState out;
  out.pose = tool.pose();
  out.twist = tool.twist();
  out.gripper_opening = tool.gripperOpening();
  out.grip_rate_radps = tool.gripRate();
  out.target = impl_->sim.deviceTarget(i);
  out.rendered_wrench = tool.couplingWrench();
  out.contact_wrench = impl_->sim.contactWrench(i);
  return out;
}

Eigen::Map<const Eigen::Matrix3Xd> Simulation::positions(int tissue) const {
  impl_->checkTissue(tissue);
  const Eigen::VectorXd& q = impl_->sim.tissue(tissue).positions();
  return {q.data(), 3, q.size() / 3};
}

Eigen::Map<const Eigen::Matrix3Xd> Simulation::velocities(int tissue) const {
  impl_->checkTissue(tissue);
  const Eigen::VectorXd& v = impl_->sim.tissue(tissue).velocities();
  return {v.data(), 3, v.size() / 3};
}

const ContactProblem& Simulation::lastProblem() const { return impl_->sim.lastProblem(); }
ReactionForces Simulation::reactions() { return impl_->sim.reactions(); }
double Simulation::totalEnergy() const { return impl_->sim.totalEnergy(); }
std::vector<std::string> Simulation::stages() const { return impl_->sim.stages(); }

State Simulation::state() const { return State::fromBytes(impl_->sim.saveState()); }

void Simulation::setState(const State& state) {
  if (state.empty()) throw StateError("setState: an empty State (nothing was saved in it)");
  impl_->sim.restoreState(state.bytes(), state.source_);
}

}  // namespace tactus
