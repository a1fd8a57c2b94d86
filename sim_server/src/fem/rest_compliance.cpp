// The rest compliance block's precomputation (rest_compliance_block.h).
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <string>

#include <fmt/format.h>

#include "rest_compliance_block.h"
#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"

namespace tactus::sim::c0_detail {

namespace {

// In-place (A + A^T) / 2 without a full-size temporary.
template <class Mat> void symmetrise(Mat &a) {
  for (Eigen::Index j = 0; j < a.cols(); ++j)
    for (Eigen::Index i = j + 1; i < a.rows(); ++i) {
      const auto v = (a(i, j) + a(j, i)) / 2;
      a(i, j) = v;
      a(j, i) = v;
    }
}

void progress(bool show, int done, int total) {
  if (!show)
    return;
  const int percent = total > 0 ? 100 * done / total : 100;
  if (!isatty(fileno(stderr))) {
    // logs and pipes: one line per quarter instead of a redrawn bar
    static int last_quarter = -1;
    const int quarter = percent / 25;
    if (done == 0) last_quarter = -1;
    if (quarter == last_quarter) return;
    last_quarter = quarter;
    std::fprintf(stderr, "[tactus] C0 precompute %3d%% (%d/%d DOFs)\n", percent, done, total);
    return;
  }
  const int width = 40;
  const int filled = total > 0 ? width * done / total : width;
  std::fprintf(stderr, "\r[tactus] C0 precompute [%s%s] %3d%% (%d/%d DOFs)",
               std::string(filled, '#').c_str(),
               std::string(width - filled, ' ').c_str(), percent, done, total);
  if (done == total)
    std::fprintf(stderr, "\n");
  std::fflush(stderr);
}

} // namespace

namespace {

// The memory this process can still have [bytes]: MemAvailable of /proc/meminfo, and no more
// than its address-space limit (ulimit -v) leaves; a negative value when unknown.
double availableMemoryBytes() {
  double have = -1.0;
  if (std::FILE *f = std::fopen("/proc/meminfo", "r"); f != nullptr) {
    char line[256];
    double kb = -1.0;
    while (std::fgets(line, sizeof(line), f) != nullptr) {
      if (std::sscanf(line, "MemAvailable: %lf kB", &kb) == 1)
        break;
    }
    std::fclose(f);
    if (kb >= 0.0)
      have = kb * 1024.0;
  }
  rlimit as{};
  if (::getrlimit(RLIMIT_AS, &as) == 0 && as.rlim_cur != RLIM_INFINITY) {
    double used = 0.0;
    if (std::FILE *f = std::fopen("/proc/self/statm", "r"); f != nullptr) {
      double pages = 0.0;
      if (std::fscanf(f, "%lf", &pages) == 1)
        used = pages * static_cast<double>(::sysconf(_SC_PAGESIZE));
      std::fclose(f);
    }
    const double left = std::max(0.0, static_cast<double>(as.rlim_cur) - used);
    have = have < 0.0 ? left : std::min(have, left);
  }
  return have;
}

} // namespace

void checkRestBlockFits(std::size_t surface_nodes, bool single) {
  const double need = restBlockBytes(surface_nodes, single);
  const double have = availableMemoryBytes();
  if (have < 0.0 || need <= have)
    return;
  throw NumericalError(fmt::format(
      "the rest compliance block C0 of this tissue's {} surface nodes needs {:.1f} GB ({} x {} "
      "{}s, dense) and this machine has {:.1f} GB available: use compliance.model: exact (no C0 "
      "block){}, or a mesh with fewer surface nodes",
      surface_nodes, need / 1e9, 3 * surface_nodes, 3 * surface_nodes,
      single ? "float" : "double", have / 1e9,
      single ? "" : fmt::format(", compliance.c0_precision: float ({:.1f} GB)", need / 2e9)));
}

void computeRestBlock(FemBody &body, const ComplianceOptions &opt,
                      RestBlock &blk) {
  const int n = body.nodeCount();
  const int s = static_cast<int>(blk.surface.size());
  const int d = 3 * s;
  blk.resize(d);
  Eigen::Map<Eigen::MatrixXd> c0_out = blk.writableC0();
  Eigen::Map<Eigen::MatrixXf> c0f_out = blk.writableC0f();
  const int batch = std::max(1, opt.solve_batch);
  Eigen::MatrixXd rhs, sol;
  progress(opt.show_progress, 0, d);
  for (int c0 = 0; c0 < d; c0 += batch) {
    const int k = std::min(batch, d - c0);
    rhs.setZero(3 * n, k);
    for (int j = 0; j < k; ++j) {
      const int col = c0 + j;
      rhs(3 * blk.surface[col / 3] + col % 3, j) = 1.0;
    }
    shared::throwIfStopRequested("precomputing the rest compliance C0");
    body.solveRestComplianceBatch(opt.h_s, rhs, sol);
    for (int j = 0; j < k; ++j)
      for (int a = 0; a < s; ++a) {
        if (blk.single)
          c0f_out.block<3, 1>(3 * a, c0 + j) =
              sol.block<3, 1>(3 * blk.surface[a], j).cast<float>();
        else
          c0_out.block<3, 1>(3 * a, c0 + j) =
              sol.block<3, 1>(3 * blk.surface[a], j);
      }
    progress(opt.show_progress, c0 + k, d);
  }
  // remove the solver's round-off asymmetry
  if (blk.single)
    symmetrise(c0f_out);
  else
    symmetrise(c0_out);
}

} // namespace tactus::sim::c0_detail
