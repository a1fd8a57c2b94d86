#pragma once
// FCLIB local 3D frictional contact problems (u = W r + q, Coulomb cone per contact) read into
// the dense form the NSGS solver takes (see nsgs.h; FCLIB's r is our f, u our delta).
//
// Text format (tests/data/fclib/problems/*.fc3d.txt): lines starting with '#' are comments;
// then `nc`; `nc` values of mu; `3 nc` values of q; `nnz`; `nnz` triplets `row col value` of W
// (0-based; duplicates are summed). Values are whitespace-separated, any layout across lines.
// Reference solutions (reference/*.ref.txt): `3 nc` lines `r u`; an optional comment
// "... error <value> ..." gives the reference's own error.
//
// Not real-time: these functions allocate and throw tactus::Error whose message names the file
// and, for malformed content, the line. HDF5 input (FCLIB's native layout) lives in the
// command-line tool (tools/common/fclib_hdf5.h) so that tactus_shared never links HDF5.

#include <filesystem>
#include <string>
#include <vector>

#include "tactus/shared/nsgs.h"

namespace tactus::shared {

struct FclibProblem {
  int contacts = 0;                  ///< nc (every contact has 3 rows: n, t1, t2)
  std::vector<double> mu;            ///< nc
  std::vector<double> q;             ///< m = 3 nc, free velocity (delta_free)
  std::vector<double> W;             ///< m x m, dense row-major (ld = m)
  std::vector<int> row_offset;       ///< nc + 1: 0, 3, 6, ...
  std::string name;                  ///< file stem without .fc3d.txt / .hdf5

  int rows() const { return static_cast<int>(q.size()); }
  /// Non-owning view for solveNsgs / naturalMapError (valid while *this lives, unmodified).
  ContactProblemView view() const;
};

struct FclibReference {
  std::vector<double> r;             ///< m reaction (force) values
  std::vector<double> u;             ///< m local velocities
  double error = -1.0;               ///< error stated in the header comment, -1 if none
};

/// Builds a problem from triplets (0-based row/col, duplicates summed). Throws tactus::Error
/// (prefixed with `source`) on sizes that do not match (mu: nc, q: 3 nc) or indices out of range.
FclibProblem assembleFclibProblem(const std::string& source, std::string name,
                                  std::vector<double> mu, std::vector<double> q,
                                  const std::vector<int>& row, const std::vector<int>& col,
                                  const std::vector<double>& value);

/// Reads problems/*.fc3d.txt. Throws tactus::Error "FILE:LINE: ..." when malformed (missing or
/// non-numeric value, non-finite value, nc < 1, negative mu, nnz < 0, index out of range,
/// trailing content) and "FILE: cannot open" when unreadable.
FclibProblem readFclibText(const std::filesystem::path& path);

/// Reads reference/*.ref.txt (`r u` per line). Throws tactus::Error "FILE:LINE: ..." on a line
/// that is not two finite numbers. The number of rows is the number of lines read.
FclibReference readFclibReference(const std::filesystem::path& path);

/// Writes `r u` per row (17 significant digits) in the reference format, with `comment` (may
/// hold several lines) as '#' lines first, through a checked temporary file. Throws
/// tactus::Error when the file cannot be written, or exists and `overwrite` is false.
void writeFclibSolution(const std::filesystem::path& path, const std::vector<double>& r,
                        const std::vector<double>& u, const std::string& comment,
                        bool overwrite = false);

}  // namespace tactus::shared
