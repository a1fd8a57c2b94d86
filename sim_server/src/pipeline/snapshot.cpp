// The last step's contact problem written into a snapshot slot, as sim_server publishes it
// (pipeline.h writeSnapshot; the conversion is tactus::writeSnapshotSlot's, tactus/contact.h).
#include <algorithm>
#include <array>

#include "tactus/contact.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {

bool writeSnapshot(const Simulation& sim, double max_opening_rad, std::uint64_t seq,
                   std::int64_t t_ns, std::uint64_t device_seq, shared::SnapshotWriter& slot) {
  std::array<double, shared::kMaxInstruments> full_rad{};
  full_rad[0] = max_opening_rad;
  for (int i = 1; i < std::min(sim.instrumentCount(), shared::kMaxInstruments); ++i) {
    full_rad[static_cast<std::size_t>(i)] = instrumentSpec(sim.spec(), i).max_opening_rad;
  }
  return writeSnapshotSlot(sim.lastProblem(), seq, t_ns, device_seq, slot, full_rad);
}

}  // namespace tactus::sim
