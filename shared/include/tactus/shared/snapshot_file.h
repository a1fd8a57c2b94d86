#pragma once
// Recorded contact snapshots: a binary file holding the sequence of contact problems a run
// published (what messages.h's ContactSnapshot carries), so the haptic loop can replay a real
// problem later (tactus-jitter --replay FILE). Written by sim_server --record-snapshots FILE.
//
// Format (native byte order, little-endian hosts; every count checked when reading):
//   file header (24 bytes): magic "TACTSNAP", uint32 version (2), uint32 sizeof(record header),
//                           uint64 reserved (0); then snapshots up to the end of the file
//   per snapshot: uint64 t_ns (the run's timeline, from its first snapshot or any origin),
//                 ContactSnapshotHeader (raw), then with m = rows, nc = contacts, packed (ld = m):
//                 int32 row_offset[nc + 1], uint64 contact_id[nc], double mu[nc],
//                 double W[m * m] (row-major), double delta_free[m], double f[m],
//                 double J[m * 6], double contact_point_m[nc * 3], double contact_normal[nc * 3],
//                 double contact_tangent[nc * 6], int32 contact_instrument[nc]
// (version 2: the header's instrument blocks and contact_instrument; version 1 files, written
// before several instruments, are refused with their version)
// The reader rejects a file that is not a regular file, larger than kMaxSnapshotFileBytes, has a
// wrong magic/version/record size, a count or size that does not fit the bytes left (checked
// before allocating), inconsistent row offsets, non-finite values, a negative friction
// coefficient, or trailing bytes; every error is a tactus::FileError naming the file and the
// snapshot.

#include <cstdint>
#include <filesystem>
#include <string_view>
#include <vector>

#include "tactus/shared/file_io.h"
#include "tactus/shared/messages.h"

namespace tactus::shared {

/// Largest snapshot file the reader accepts [bytes].
inline constexpr std::uint64_t kMaxSnapshotFileBytes = std::uint64_t{2} << 30;  // 2 GiB
/// Largest problem a recorded snapshot may hold.
inline constexpr std::int32_t kMaxRecordedRows = 6000;
inline constexpr std::int32_t kMaxRecordedContacts = 6000;
inline constexpr std::uint32_t kSnapshotFileVersion = 2;

/// One recorded snapshot, arrays packed with ld = rows.
struct RecordedSnapshot {
  std::int64_t t_ns = 0;  ///< time on the recording's timeline [ns]
  ContactSnapshotHeader header;  ///< rows/contacts give the array sizes
  std::vector<std::int32_t> row_offset;
  std::vector<std::uint64_t> contact_id;
  std::vector<double> mu, W, delta_free, f, J, contact_point_m, contact_normal, contact_tangent;
  std::vector<std::int32_t> contact_instrument;   ///< per contact (0 with one instrument; -1: an obstacle's; -2: unreachable, messages.h)

  int rows() const noexcept { return header.rows; }
  int contacts() const noexcept { return header.contacts; }
  /// Copies the problem into a snapshot slot (its header too, with seq and t_ns replaced).
  /// Returns false (and writes nothing) when the slot's capacity is too small.
  bool writeTo(SnapshotWriter slot, std::uint64_t seq, std::int64_t t_ns) const noexcept;
};

/// Writes snapshots to a file through OutputFile (never replaces an existing file unless
/// options.overwrite; the target is checked when the writer is made). Nothing is in place
/// before commit(): a run that stops early without commit() leaves no file. The file never
/// grows beyond `max_bytes` (at most kMaxSnapshotFileBytes, what the reader accepts): a snapshot
/// that would take it there is not written.
class SnapshotFileWriter {
 public:
  SnapshotFileWriter(const std::filesystem::path& path, OutputOptions options = {},
                     std::uint64_t max_bytes = kMaxSnapshotFileBytes);
  /// Appends one snapshot read from a slot (arrays taken with the slot's ld); t_ns is the time on
  /// the recording's timeline. Returns false, writing nothing, when the snapshot would take the
  /// file past its maximum size (the caller stops recording). Throws FileError when a write
  /// failed.
  [[nodiscard]] bool append(const SnapshotView& snapshot, std::int64_t t_ns);
  /// Snapshots appended so far.
  std::uint64_t count() const noexcept { return count_; }
  /// Bytes of the file so far.
  std::uint64_t bytes() const noexcept { return bytes_; }
  /// Writes the file into place. Throws FileError.
  void commit();

 private:
  OutputFile out_;
  std::uint64_t count_ = 0;
  std::uint64_t bytes_ = 0;
  std::uint64_t max_bytes_ = kMaxSnapshotFileBytes;
};

/// Reads and validates a whole snapshot file (see the header comment). Throws FileError.
std::vector<RecordedSnapshot> readSnapshotFile(const std::filesystem::path& path);

}  // namespace tactus::shared
