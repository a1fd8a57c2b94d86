#pragma once
// The contact solver on ContactProblem (docs/api.md): NSGS (tactus/shared/nsgs.h does the work),
// and the problem files: FCLIB's text form (the frictional contact library's local 3D problems)
// and the snapshot files sim_server --record-snapshots writes (tactus/shared/snapshot_file.h);
// and a problem written into a snapshot slot, the form the haptic process receives
// (tactus/shared/messages.h).
//
// Files are read through the project's checked I/O (a regular file, a size limit, every value
// checked) and written through a temporary file renamed into place, never over an existing file
// unless asked. Errors are exceptions (tactus::Error, FileError) naming the file and the field.

#include <cstdint>
#include <filesystem>
#include <span>
#include <vector>

#include "tactus/shared/messages.h"
#include "tactus/shared/nsgs.h"
#include "tactus/types.h"

namespace tactus {

using shared::NsgsCoupling;
using shared::NsgsResult;
using shared::NsgsSettings;
using shared::NsgsStatus;

/// Throws tactus::Error naming the first thing that keeps `problem` from being solved: counts
/// and sizes that disagree (row_offset has contacts + 1 entries from 0, stepping by 1 or 3 to
/// rows; mu per contact; W rows x rows; delta_free rows; f empty or rows; J empty or rows x 6;
/// the per-contact arrays empty or one per contact), mu < 0, or a value that is not finite.
void checkContactProblem(const ContactProblem& problem);

/// Solves the problem with NSGS: f holds the warm start on entry (an empty f: zeros) and the
/// solution on exit; the result is also kept in problem.solve. Checks the problem first
/// (checkContactProblem). Allocates a workspace per call; a real-time caller keeps one and calls
/// shared::solveNsgs on problem.view().
NsgsResult solveContactProblem(ContactProblem& problem, const NsgsSettings& settings = {});

/// A problem of FCLIB's text form (shared/fclib.h): three rows per contact, W, q (delta_free),
/// mu. The contact frames and J are absent (empty).
ContactProblem readFclib(const std::filesystem::path& path);
/// Writes the problem in FCLIB's text form (every non-zero of W, 17 significant digits, so the
/// values read back are the same bits). FCLIB's local 3D problems have three rows per contact:
/// a one-row contact is refused (tactus::Error).
void writeFclib(const std::filesystem::path& path, const ContactProblem& problem,
                bool overwrite = false);

/// The problems of a snapshot file, in order (their contact frames, J, f and device poses; a
/// gripper opening is read back as an angle: device_gripper in radians, max_opening_rad 1).
std::vector<ContactProblem> readSnapshots(const std::filesystem::path& path);
/// Writes problems to a snapshot file (stamped 0, 1, 2 ... ms on its timeline). Throws FileError
/// (the file exists and not `overwrite`, a write failed, or the problems would take it past a
/// snapshot file's maximum size: then no file is left).
void writeSnapshots(const std::filesystem::path& path, std::span<const ContactProblem> problems,
                    bool overwrite = false);

/// A problem written into a snapshot slot as the simulation publishes it to the haptic process:
/// the header (seq, t_ns, step, h_s, the devices' and tools' poses, openings as angles, the
/// solve's sweeps and error, flags: valid, converged, Jacobian, W exactly symmetric) and the
/// arrays. Openings become angles with `max_opening_rad` per instrument (absent: the problem's
/// InstrumentProblemData::max_opening_rad). Returns false, and writes an empty problem without
/// kSnapshotValid (which the haptic side treats as stale), when it exceeds the slot's capacity.
bool writeSnapshotSlot(const ContactProblem& problem, std::uint64_t seq, std::int64_t t_ns,
                       std::uint64_t device_seq, shared::SnapshotWriter& slot,
                       std::span<const double> max_opening_rad = {});
/// The problem a snapshot slot holds (the inverse of writeSnapshotSlot, but grip, which a
/// snapshot does not carry: zeros).
ContactProblem problemFromSnapshot(const shared::SnapshotView& snapshot);

/// One snapshot slot in memory, sized for a capacity (cache-line aligned).
class SnapshotBuffer {
 public:
  SnapshotBuffer(int max_rows, int max_contacts);
  shared::SnapshotWriter writer() { return shared::SnapshotWriter(bytes(), layout_); }
  shared::SnapshotView view() const { return shared::SnapshotView(bytes(), layout_); }
  const shared::SnapshotLayout& layout() const { return layout_; }

 private:
  unsigned char* bytes() const;
  shared::SnapshotLayout layout_;
  std::vector<unsigned char> storage_;
};

}  // namespace tactus
