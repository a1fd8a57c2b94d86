// Saving and restoring a Simulation's state (Simulation::saveState / restoreState; docs/design.md,
// "State: copy, save, restore"). The walk below names every member of SimulationState and
// TissueState, as state or not with the reason; the objects inside walk their own
// (FemBody, TissueCompliance, Collision, Instrument: their transferState).
#include <fmt/format.h>

#include <cstring>

#include "simulation_impl.h"
#include "step_stages.h"
#include "tactus/sim/state_archive.h"

namespace tactus::sim {

// A member added to these structs stops the build here until the walk below names it.
static_assert(kAggregateFields<SimulationState> == 9,
              "SimulationState gained or lost a member: walk it in transferState "
              "(simulation_state.cpp) and update this count");
static_assert(kAggregateFields<TissueState> == 7,
              "TissueState gained or lost a member: walk it in transferState "
              "(simulation_state.cpp) and update this count");

namespace {

constexpr char kMagic[8] = {'T', 'A', 'C', 'T', 'S', 'T', 'A', 'T'};
constexpr std::size_t kFixedHeaderBytes = 8 + 4 + 4 + 8 + 8 + 8;
constexpr std::uint32_t kMaxModelNameBytes = 4096;

void transferTissue(StateArchive& ar, TissueState& ts) {
  ar("fem", *ts.body);
  if (ts.compliance) ar("compliance", *ts.compliance);
  for (std::size_t i = 0; i < ts.collisions.size(); ++i) {
    ar(fmt::format("collision[{}]", i), *ts.collisions[i]);
  }
  // Not state: the last detection's contacts (found, merged, obstacle_found, obstacle_overflow)
  // are the step's output, found again before the next step reads them; a restore clears them.
  if (ar.loading()) {
    ts.found = nullptr;
    ts.merged.clear();
    ts.obstacle_found.clear();
    ts.obstacle_overflow = 0;
  }
}

void transferState(StateArchive& ar, SimulationState& s) {
  ar("t", s.t_s);
  ar("step", s.step);
  for (std::size_t t = 0; t < s.tissues.size(); ++t) {
    StateArchive::Scope scope(ar, fmt::format("tissues[{}]", t));
    transferTissue(ar, s.tissues[t]);
  }
  ar("instruments", s.instruments);
  for (std::size_t i = 0; i < s.targets.size(); ++i) {
    StateArchive::Scope scope(ar, fmt::format("targets[{}]", i));
    DeviceTarget& d = s.targets[i];
    ar("pose", d.pose);
    ar("twist", d.twist);
    ar("gripper_opening", d.gripper_opening);
  }
  ar("target_rejected", s.target_rejected);
  ar.resizable("warm_start_f", s.warm_start_f, std::size_t{1} << 24);
  // Not state: the obstacles (placed geometry: model) and the contacts between tissues (surfaces
  // refit and contacts found at every detection); their scratch is rewritten before it is read.
}

template <class T>
void put(std::string& out, const T& value) {
  out.append(reinterpret_cast<const char*>(&value), sizeof value);
}

template <class T>
T get(std::string_view bytes, std::size_t at) {
  T value;
  std::memcpy(&value, bytes.data() + at, sizeof value);
  return value;
}

}  // namespace

std::uint64_t Simulation::modelIdentity() const { return sim::modelIdentity(impl_->model); }

std::uint64_t modelIdentity(const SimulationModel& m) {
  std::uint64_t h = 0xcbf29ce484222325ull;
  const auto mix = [&h](const void* data, std::size_t n) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < n; ++i) {
      h ^= p[i];
      h *= 0x100000001b3ull;
    }
  };
  mix(&m.spec.text_hash, sizeof m.spec.text_hash);
  mix(&m.h_s, sizeof m.h_s);
  for (const TissueModel& t : m.tissues) {
    mix(t.mesh.nodes.data(), sizeof(double) * static_cast<std::size_t>(t.mesh.nodes.size()));
    mix(t.mesh.tets.data(), sizeof(t.mesh.tets[0]) * t.mesh.tets.size());
    mix(t.fixed_nodes.data(), sizeof(int) * t.fixed_nodes.size());
  }
  return h;
}

std::string Simulation::saveState() const {
  const std::string name = impl_->model.spec.source.empty()
                               ? std::string("scene")
                               : impl_->model.spec.source.filename().string();
  std::string out;
  out.append(kMagic, sizeof kMagic);
  put(out, kStateFormatVersion);
  put(out, static_cast<std::uint32_t>(std::min<std::size_t>(name.size(), kMaxModelNameBytes)));
  put(out, modelIdentity());
  put(out, static_cast<std::int64_t>(impl_->state.step));
  put(out, impl_->state.t_s);
  out.append(name, 0, kMaxModelNameBytes);
  // the compliance's rotations are state: those of the last step's free state even when that
  // step had no contact rows and left them for later (ensureCompliance)
  ensureCompliance(impl_->state, impl_->scratch, nullptr);
  StateArchive ar(out);
  // the writer only reads the members
  transferState(ar, const_cast<SimulationState&>(impl_->state));
  return out;
}

StateHeader readStateHeader(std::string_view bytes, const std::string& source) {
  if (bytes.size() < kFixedHeaderBytes || std::memcmp(bytes.data(), kMagic, sizeof kMagic) != 0) {
    throw StateError(source + ": not a Tactus simulation state (no TACTSTAT header)");
  }
  StateHeader h;
  h.version = get<std::uint32_t>(bytes, 8);
  if (h.version != kStateFormatVersion) {
    throw StateError(fmt::format("{}: a state of format version {}; this Tactus reads version {}",
                                 source, h.version, kStateFormatVersion));
  }
  const auto name_bytes = get<std::uint32_t>(bytes, 12);
  h.model_identity = get<std::uint64_t>(bytes, 16);
  h.step = static_cast<long>(get<std::int64_t>(bytes, 24));
  h.t_s = get<double>(bytes, 32);
  if (name_bytes > kMaxModelNameBytes || bytes.size() - kFixedHeaderBytes < name_bytes) {
    throw StateError(source + ": the state's header is truncated or corrupt");
  }
  h.model_name.assign(bytes.data() + kFixedHeaderBytes, name_bytes);
  h.body_offset = kFixedHeaderBytes + name_bytes;
  return h;
}

void Simulation::restoreState(std::string_view bytes, const std::string& source) {
  const StateHeader h = readStateHeader(bytes, source);
  const std::uint64_t identity = modelIdentity();
  if (h.model_identity != identity) {
    throw StateError(fmt::format(
        "{}: a state of another model (saved from '{}', model {:016x}; this simulation runs '{}', "
        "model {:016x}): a state continues only the model it was saved from (same scene text, "
        "meshes and time step)",
        source, h.model_name, h.model_identity,
        impl_->model.spec.source.empty() ? std::string("scene")
                                         : impl_->model.spec.source.filename().string(),
        identity));
  }
  // A failure part way leaves the objects half restored: put the current state back then.
  const std::string before = saveState();
  try {
    StateArchive ar(bytes.substr(h.body_offset), source);
    transferState(ar, impl_->state);
    if (ar.remaining() != 0) ar.fail("", "bytes left after the last field (corrupt)");
  } catch (...) {
    StateArchive back(std::string_view(before).substr(readStateHeader(before, "").body_offset),
                      "the state before the restore");
    transferState(back, impl_->state);
    throw;
  }
  // the last step's outputs belong to the run the state left
  impl_->scratch = buildScratch(impl_->model);
}

}  // namespace tactus::sim
