#pragma once
// Warm start of the haptic re-solve when a new snapshot arrives (docs/design.md, "The haptic
// local model"): the simulation's own forces f* plus the correction the haptic loop's last solve
// made to the previous snapshot's f*, carried contact by contact through the stable contact ids.
//
// Why: the device stands where the hand is, the simulation's problem where the hand was when the
// step began (x_h*), so every tick solves f* moved by J (x_h - x_h*). That offset changes little
// from one snapshot to the next, and so does the force correction it calls for; starting from f*
// alone threw that correction away ten times a second. Measured on a recorded liver_grasp run
// (a 0.2 mm device offset, docs/measurements.md, "The first tick on a snapshot"): sweeps of the first tick
// of a snapshot median 15 -> 6, p90 20 -> 14.
//
// Real-time safe: adopt() neither allocates nor blocks; everything is sized in the constructor.

#include <cstdint>
#include <vector>

#include "tactus/shared/messages.h"

namespace tactus::shared {

class SnapshotWarmStart {
 public:
  SnapshotWarmStart() = default;
  /// Sized for snapshots of up to max_contacts contacts and max_rows rows (allocates).
  SnapshotWarmStart(int max_contacts, int max_rows);

  /// A new snapshot (rows() <= max_rows, contacts() <= max_contacts, else it only resets and
  /// copies what fits): writes its warm start into f_out[0, rows), and remembers its ids, row
  /// offsets and f* for the next call.
  ///  - last_solve: the forces of the last converged solve on the previous snapshot's rows, or
  ///    nullptr (none, or it did not converge): then f_out = f*.
  ///  - otherwise f_out = f* + (last_solve - previous f*) for each contact the previous snapshot
  ///    had under the same id with the same row count; f* for the others.
  /// last_solve may alias f_out. Returns the contacts that took a carried correction.
  int adopt(const SnapshotView& snap, const double* last_solve, double* f_out) noexcept;
  int adopt(int contacts, int rows, const std::int32_t* row_offset, const std::uint64_t* ids,
            const double* f_star, const double* last_solve, double* f_out) noexcept;

  /// Forgets the previous snapshot (the next adopt() starts from f*).
  void reset() noexcept { contacts_ = 0; }

 private:
  int find(std::uint64_t id) const noexcept;

  int max_contacts_ = 0;
  int max_rows_ = 0;
  int contacts_ = 0;                       ///< of the remembered snapshot (0: none)
  std::vector<std::int32_t> row_offset_;   ///< its row offsets (max_contacts + 1)
  std::vector<double> f_star_;             ///< its f*
  std::vector<double> correction_;         ///< last_solve - f*, per its row
  // open addressing over its ids: slot -> contact index, valid while stamp == stamp_
  std::vector<std::uint64_t> keys_;
  std::vector<std::int32_t> values_;
  std::vector<std::uint32_t> stamps_;
  std::uint32_t stamp_ = 0;
  std::uint64_t mask_ = 0;
};

}  // namespace tactus::shared
