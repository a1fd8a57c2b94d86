// tactus-bench-solver: Tactus' NSGS and Siconos' fc3d NSGS (SICONOS_FRICTION_3D_NSGS) side by
// side on FCLIB problems, generated sphere piles (multi-body, block-sparse W) and recorded
// simulation snapshots (one tissue, dense W): same tolerance, cold start, alternating runs,
// median times; Tactus on the storage of W chooseStorage picks (or the one forced). Benchmark
// tool only: nothing else in the project links Siconos.

#include <spdlog/spdlog.h>

#include "tactus/shared/cli.h"
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <set>
#include <string>
#include <vector>

#include "tactus/shared/delassus_blocks.h"
#include "tactus/shared/error.h"
#include "tactus/shared/fclib.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/percentiles.h"
#include "tactus/shared/snapshot_file.h"
#include "tactus/shared/tool_main.h"
#ifdef TACTUS_HAVE_HDF5
#include "fclib_hdf5.h"
#include "sphere_pile.h"
#endif

#include <siconos/numerics/FrictionContactProblem.h>
#include <siconos/numerics/Friction_cst.h>
#include <siconos/numerics/NonSmoothDrivers.h>
#include <siconos/numerics/NumericsMatrix.h>
#include <siconos/numerics/SolverOptions.h>
#include <siconos/numerics/SparseBlockMatrix.h>

namespace {

namespace fs = std::filesystem;
using tactus::shared::FclibProblem;

constexpr std::uintmax_t kMaxProblemBytes = 512ull << 20;

FclibProblem load(const fs::path& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) throw tactus::Error(path.string() + ": not a regular file");
  if (fs::file_size(path, ec) > kMaxProblemBytes)
    throw tactus::Error(path.string() + ": larger than 512 MiB");
  const std::string name = path.filename().string();
  if (name.ends_with(".hdf5") || name.ends_with(".h5")) {
#ifdef TACTUS_HAVE_HDF5
    return tactus::shared::readFclibHdf5(path);
#else
    throw tactus::Error(path.string() + ": HDF5 input was not compiled in (libhdf5-dev)");
#endif
  }
  return tactus::shared::readFclibText(path);
}

/// The `count` largest frictional problems (3 rows per contact) with at most max_contacts
/// contacts (most contacts first, earliest on ties) of a snapshot file recorded by sim_server
/// --record-snapshots: the simulation's own contact problems (one tissue's dense W), named
/// FILE#INDEX.
std::vector<FclibProblem> loadSnapshots(const fs::path& path, int count, int max_contacts) {
  const std::vector<tactus::shared::RecordedSnapshot> all = tactus::shared::readSnapshotFile(path);
  std::vector<std::size_t> order;
  for (std::size_t k = 0; k < all.size(); ++k) {
    const int nc = all[k].contacts();
    if (nc > 0 && nc <= max_contacts && all[k].rows() == 3 * nc) order.push_back(k);
  }
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    return all[a].contacts() > all[b].contacts();
  });
  if (order.size() > static_cast<std::size_t>(count)) order.resize(static_cast<std::size_t>(count));
  std::vector<FclibProblem> out;
  for (const std::size_t k : order) {
    const tactus::shared::RecordedSnapshot& r = all[k];
    FclibProblem p;
    p.contacts = r.contacts();
    p.mu = r.mu;
    p.q = r.delta_free;
    p.W = r.W;
    p.row_offset.assign(r.row_offset.begin(), r.row_offset.end());
    p.name = path.filename().string() + "#" + std::to_string(k);
    out.push_back(std::move(p));
  }
  return out;
}

bool isText(const fs::path& p) { return p.filename().string().ends_with(".fc3d.txt"); }
bool isHdf5(const fs::path& p) {
  const std::string n = p.filename().string();
  return n.ends_with(".hdf5") || n.ends_with(".h5");
}
std::string stemOf(const fs::path& p) {
  std::string n = p.filename().string();
  for (const char* suffix : {".fc3d.txt", ".hdf5", ".h5"}) {
    const std::string s(suffix);
    if (n.ends_with(s)) return n.substr(0, n.size() - s.size());
  }
  return n;
}

/// Files of a directory (recursive): every .fc3d.txt, and .hdf5 only when no text form of the
/// same problem exists (the test data holds some problems in both forms).
std::vector<fs::path> scanDirectory(const fs::path& dir) {
  std::vector<fs::path> text, hdf5;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    if (!entry.is_regular_file()) continue;
    if (isText(entry.path())) text.push_back(entry.path());
    else if (isHdf5(entry.path())) hdf5.push_back(entry.path());
  }
  std::set<std::string> stems;
  for (const auto& p : text) stems.insert(stemOf(p));
#ifdef TACTUS_HAVE_HDF5
  for (const auto& p : hdf5)
    if (!stems.contains(stemOf(p))) text.push_back(p);
#endif
  std::sort(text.begin(), text.end(),
            [](const fs::path& a, const fs::path& b) { return stemOf(a) < stemOf(b); });
  return text;
}

double median(const std::vector<double>& v) { return tactus::shared::percentile(v, 0.5); }

/// Siconos' copy of a problem: W in column-major dense or 3x3 sparse-block storage.
class SiconosProblem {
 public:
  SiconosProblem(const FclibProblem& p, bool sparse_block) : q_(p.q), mu_(p.mu) {
    const int m = p.rows();
    if (sparse_block) {
      NumericsMatrix* triplet = NM_create(NM_SPARSE, m, m);
      NM_triplet_alloc(triplet, 0);
      for (int i = 0; i < m; ++i)
        for (int j = 0; j < m; ++j) {
          const double w = p.W[static_cast<std::size_t>(i) * m + j];
          if (w != 0.0) NM_entry(triplet, i, j, w);
        }
      matrix_ = NM_create(NM_SPARSE_BLOCK, m, m);
      if (SBM_from_csparse(3, NM_csc(triplet), matrix_->matrix1) != 0) {
        NM_free(triplet);
        NM_free(matrix_);
        throw tactus::Error(p.name + ": Siconos could not build the sparse-block W");
      }
      NM_free(triplet);
    } else {
      matrix_ = NM_create(NM_DENSE, m, m);
      for (int i = 0; i < m; ++i)
        for (int j = 0; j < m; ++j)
          matrix_->matrix0[static_cast<std::size_t>(j) * m + i] =
              p.W[static_cast<std::size_t>(i) * m + j];
    }
    problem_ = frictionContactProblem_new_with_data(3, p.contacts, matrix_, q_.data(), mu_.data());
  }
  ~SiconosProblem() {
    // the problem does not own q and mu here (they are ours): detach before freeing
    problem_->q = nullptr;
    problem_->mu = nullptr;
    frictionContactProblem_free(problem_);  // frees M
  }
  SiconosProblem(const SiconosProblem&) = delete;
  SiconosProblem& operator=(const SiconosProblem&) = delete;
  FrictionContactProblem* get() { return problem_; }

 private:
  std::vector<double> q_, mu_;
  NumericsMatrix* matrix_ = nullptr;
  FrictionContactProblem* problem_ = nullptr;
};

struct Settings {
  double tolerance = 1e-6;
  int max_sweeps = 10000;
  int reps = 5;
  /// Siconos' W: auto (like for like: 3x3 sparse blocks where Tactus solves on blocks, dense
  /// where Tactus solves dense), dense or sparse-block
  std::string siconos_storage = "auto";
  bool light_error = false;
  std::string tactus_storage = "auto";   ///< auto (chooseStorage), dense or blocks
};

/// Siconos NSGS options: same tolerance and iteration cap as Tactus; the full natural-map error
/// (fc3d_compute_error) evaluated after every sweep, as Tactus does (check_every = 1); local
/// solver left at Siconos' default (see --help).
SolverOptions* makeSiconosOptions(const Settings& s) {
  SolverOptions* options = solver_options_create(SICONOS_FRICTION_3D_NSGS);
  options->dparam[SICONOS_DPARAM_TOL] = s.tolerance;
  options->iparam[SICONOS_IPARAM_MAX_ITER] = s.max_sweeps;
  if (!s.light_error) {
    options->iparam[SICONOS_FRICTION_3D_IPARAM_ERROR_EVALUATION] =
        SICONOS_FRICTION_3D_NSGS_ERROR_EVALUATION_FULL;
    options->iparam[SICONOS_FRICTION_3D_IPARAM_ERROR_EVALUATION_FREQUENCY] = 1;
  }
  return options;
}

struct Row {
  std::string name;
  int contacts = 0;
  double t_error = 0, t_ms = 0, s_error = 0, s_reported = 0, s_ms = 0, u_diff = 0;
  double norm_q = 0, norm_r_s = 0, norm_u_s = 0;  ///< 2-norms of q and Siconos' r, u
  int t_sweeps = 0, s_iters = 0;
  bool t_conv = false, s_conv = false;
  double fill = 0;       ///< block fill of W (stored blocks / nc^2)
  bool blocks = false;   ///< Tactus solved on W's blocks
  bool s_blocks = false; ///< Siconos was given W as 3x3 sparse blocks
  /// Siconos not run: Tactus found W ill-posed (a zero, negative or denormal diagonal), on
  /// which Siconos' NSGS stops the whole program on an assertion (Debian keeps them)
  bool s_skipped = false;
  double convert_ms = 0; ///< median time of the block conversion (once per W, untimed in t_ms)
};

Row benchOne(const FclibProblem& p, const Settings& s) {
  using Clock = std::chrono::steady_clock;
  const auto dense = p.view();
  const int m = p.rows();
  tactus::shared::NsgsWorkspace workspace(m, p.contacts);
  // W's storage for Tactus, chosen (converted) once per W like the haptic loop does per snapshot
  tactus::shared::DelassusBlocks blocks(m, p.contacts, 1.0);
  tactus::shared::DelassusBlocks measure(m, p.contacts, 1.0);
  measure.assign(dense, 1.0);
  auto choose = [&] {
    if (s.tactus_storage == "dense") return dense;
    if (s.tactus_storage == "blocks") {
      auto v = dense;
      v.blocks = blocks.assign(dense, 1.0) ? &blocks : nullptr;
      return v;
    }
    return tactus::shared::chooseStorage(dense, blocks);
  };
  auto view = choose();
  std::vector<double> convert_ms;
  tactus::shared::NsgsSettings ts;
  ts.tolerance = s.tolerance;
  ts.max_sweeps = s.max_sweeps;
  Row row;
  row.blocks = view.blocks != nullptr;
  row.s_blocks = s.siconos_storage == "sparse-block" ||
                 (s.siconos_storage == "auto" && row.blocks);
  SiconosProblem sp(p, row.s_blocks);
  SolverOptions* options = makeSiconosOptions(s);

  std::vector<double> r_t(m), r_s(m), u_s(m);
  std::vector<double> t_ms, s_ms;
  tactus::shared::NsgsResult t_result;
  int s_info = 1;
  // rep -1: one untimed warm-up run of each (first-touch page faults, cold caches)
  for (int rep = -1; rep < s.reps; ++rep) {
    const auto tc = Clock::now();
    view = choose();
    const auto tc1 = Clock::now();
    std::fill(r_t.begin(), r_t.end(), 0.0);
    const auto t0 = Clock::now();
    t_result = tactus::shared::solveNsgs(view, ts, workspace, r_t.data());
    const auto t1 = Clock::now();
    // a W Tactus finds ill-posed is never handed to Siconos: its NSGS asserts on it and the
    // whole run would end there, with no figure printed
    row.s_skipped = t_result.status == tactus::shared::NsgsStatus::kIllPosed;
    std::fill(r_s.begin(), r_s.end(), 0.0);
    std::fill(u_s.begin(), u_s.end(), 0.0);
    const auto t2 = Clock::now();
    if (!row.s_skipped) s_info = fc3d_driver(sp.get(), r_s.data(), u_s.data(), options);
    const auto t3 = Clock::now();
    if (rep < 0) continue;
    convert_ms.push_back(std::chrono::duration<double, std::milli>(tc1 - tc).count());
    t_ms.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
    s_ms.push_back(std::chrono::duration<double, std::milli>(t3 - t2).count());
    if (row.s_skipped) break;
  }

  row.name = p.name;
  row.contacts = p.contacts;
  row.fill = measure.fill();
  row.convert_ms = row.blocks ? median(convert_ms) : 0.0;
  // Both solutions scored by one function: the natural-map error normalised by
  // max(|q|, |r|, |u|) (tactus::shared::naturalMapError), u recomputed as W r + q for both.
  std::vector<double> u_t(m), u_s_check(m);
  row.t_error = tactus::shared::naturalMapError(view, r_t.data(), u_t.data());
  row.s_error = tactus::shared::naturalMapError(view, r_s.data(), u_s_check.data());
  row.s_reported = options->dparam[SICONOS_DPARAM_RESIDU];
  for (int i = 0; i < m; ++i) {
    row.norm_q += p.q[i] * p.q[i];
    row.norm_r_s += r_s[i] * r_s[i];
    row.norm_u_s += u_s_check[i] * u_s_check[i];
  }
  row.norm_q = std::sqrt(row.norm_q);
  row.norm_r_s = std::sqrt(row.norm_r_s);
  row.norm_u_s = std::sqrt(row.norm_u_s);
  row.t_sweeps = t_result.sweeps;
  row.s_iters = options->iparam[SICONOS_IPARAM_ITER_DONE];
  row.t_conv = t_result.status == tactus::shared::NsgsStatus::kConverged;
  row.s_conv = s_info == 0 && !row.s_skipped;
  row.t_ms = median(t_ms);
  row.s_ms = median(s_ms);
  // scale: u = W r + q, so |q| is part of it (u itself is ~0 on a resting stack)
  double diff = 0.0, scale = 0.0;
  for (int i = 0; i < m; ++i) {
    diff = std::max(diff, std::abs(u_t[i] - u_s_check[i]));
    scale = std::max({scale, std::abs(u_t[i]), std::abs(u_s_check[i]), std::abs(p.q[i])});
  }
  row.u_diff = scale > 0.0 ? diff / scale : diff;
  solver_options_delete(options);
  return row;
}

double ratio(double a, double b) {
  return b > 0.0 ? a / b : std::numeric_limits<double>::quiet_NaN();
}

int run(int argc, char** argv) {
  namespace cli = tactus::shared::cli;
  cli::App app{
      "Runs Tactus' NSGS (tactus::shared::solveNsgs, default settings) and Siconos' fc3d NSGS "
      "(SICONOS_FRICTION_3D_NSGS through fc3d_driver) alternately on the same FCLIB problems, "
      "cold start (r = 0), one untimed warm-up run then --reps timed runs each, and prints "
      "per problem: error, sweeps, median "
      "time and convergence of both, the time ratio Tactus/Siconos, the per-sweep time ratio "
      "and the u agreement max|u_T - u_S| / max(|u_T|, |u_S|, |q|) (max-norms; u = W r + q; "
      "r is not compared: "
      "it is not unique on redundant problems).\n"
      "Siconos options set: dparam[SICONOS_DPARAM_TOL] = --tol, iparam[SICONOS_IPARAM_MAX_ITER] "
      "= --max-sweeps, iparam[SICONOS_FRICTION_3D_IPARAM_ERROR_EVALUATION] = "
      "SICONOS_FRICTION_3D_NSGS_ERROR_EVALUATION_FULL with "
      "iparam[SICONOS_FRICTION_3D_IPARAM_ERROR_EVALUATION_FREQUENCY] = 1 (fc3d_compute_error "
      "after every sweep, as Tactus checks after every sweep); everything else at Siconos' "
      "defaults (local solver SICONOS_FRICTION_3D_ONECONTACT_NSN_GP_HYBRID, local tolerance "
      "1e-14, 10 local iterations, internal error strategy GIVEN_VALUE, no relaxation, no "
      "shuffle).\n"
      "Error normalisation: both stop on the natural-map residual sqrt(sum_i ||r_i - "
      "P_K(r_i - u_hat_i)||^2) divided by max(|q|, |r|, |u|) (2-norms): Siconos 4.4's NSGS full "
      "evaluation (fc3d_compute_error) and tactus::shared::naturalMapError agree to rounding "
      "(the --csv file holds the error Siconos reported next to the one recomputed here, and "
      "the norms). The error columns score both final solutions with naturalMapError."};
  app.footer(
      "Example:\n"
      "  tactus-bench-solver --reps 5   (scripts/bench-solver installs Siconos and runs it)");
  std::vector<std::string> inputs;
  Settings s;
  std::string csv_path;
  app.addOption("inputs", inputs,
                 "FCLIB problem files (.fc3d.txt, .hdf5), directories (searched recursively "
                 "for .fc3d.txt, and .hdf5 without a text twin) or snapshot files (.snap, "
                 "see --snapshots-per-file); default tests/data/fclib");
  app.addOption("--tol", s.tolerance, "tolerance of both solvers")
      ->captureDefault()
      ->check(cli::range(1e-16, 1.0));
  app.addOption("--max-sweeps", s.max_sweeps, "sweep (iteration) cap of both solvers")
      ->captureDefault()
      ->check(cli::range(1, 1000000));
  app.addOption("--reps", s.reps, "runs of each solver per problem (median time)")
      ->captureDefault()
      ->check(cli::range(1, 1000));
  app.addOption("--siconos-storage", s.siconos_storage,
                 "W's storage for Siconos: auto (like for like: 3x3 sparse blocks on the problems "
                 "Tactus solves on blocks, dense on the others), dense or sparse-block; the "
                 "columns T W and S W say what each side used")
      ->captureDefault()
      ->check(cli::isMember({"auto", "dense", "sparse-block"}));
  app.addFlagCallback("--siconos-sparse-block", [&s] { s.siconos_storage = "sparse-block"; },
                        "the same as --siconos-storage sparse-block");
  app.addFlag("--siconos-light-error", s.light_error,
               "keep Siconos' default error evaluation (incremental, full check at the end)");
  app.addOption("--csv", csv_path, "also write the table to FILE (must not exist)");
  app.addOption("--tactus-storage", s.tactus_storage,
                 "W's storage for Tactus: auto (tactus::shared::chooseStorage: 3x3 blocks when at "
                 "most kBlockSparseMaxFill of the blocks are non-zero), dense or blocks; the "
                 "conversion is done once per problem outside the timed solve (column conv ms)")
      ->captureDefault()
      ->check(cli::isMember({"auto", "dense", "blocks"}));
  int snapshot_count = 3;
  app.addOption("--snapshots-per-file", snapshot_count,
                 "for .snap inputs (sim_server --record-snapshots): how many of the file's "
                 "largest frictional problems to run")
      ->captureDefault()
      ->check(cli::range(1, 100000));
  int snapshot_max_contacts = 100000;
  app.addOption("--snapshot-max-contacts", snapshot_max_contacts,
                 "for .snap inputs: only problems with at most this many contacts")
      ->check(cli::range(1, 100000));
  std::vector<int> piles;
  app.addOption("--sphere-piles", piles,
                 "also generate rigid sphere piles of these sphere counts (tests/support/"
                 "sphere_pile.h: 3 x 3 spheres per layer, seed 1, mu in [0.2, 0.3]; 60 -> 228 "
                 "contacts, 90 -> 354, 150 -> ~590; 4-7 % of W's blocks non-zero)")
      ->delimiter(',')
      ->check(cli::range(2, 400));
  TACTUS_CLI_PARSE(app, argc, argv);

  if (inputs.empty() && piles.empty()) inputs.push_back(TACTUS_DEFAULT_FCLIB_DIR);
  std::vector<fs::path> files, snapshot_files;
  for (const auto& in : inputs) {
    std::error_code ec;
    if (fs::path(in).extension() == ".snap") {
      snapshot_files.emplace_back(in);
    } else if (fs::is_directory(in, ec)) {
      auto found = scanDirectory(in);
      files.insert(files.end(), found.begin(), found.end());
    } else {
      files.emplace_back(in);
    }
  }
  if (files.empty() && piles.empty() && snapshot_files.empty()) {
    throw tactus::Error("no FCLIB problem found in the inputs");
  }
  std::vector<FclibProblem> generated;
  for (const fs::path& f : snapshot_files) {
    for (FclibProblem& p : loadSnapshots(f, snapshot_count, snapshot_max_contacts)) generated.push_back(std::move(p));
  }
  for (const int n : piles) {
    const tactus::test::DenseProblem d = tactus::test::spherePile(n, 1, 0.3);
    FclibProblem p;
    p.contacts = d.contacts();
    p.mu = d.mu;
    p.q = d.q;
    p.W = d.W;
    p.row_offset = d.row_offset;
    p.name = "sphere_pile_" + std::to_string(n);
    generated.push_back(std::move(p));
  }

  std::FILE* csv = nullptr;
  if (!csv_path.empty()) {
    std::error_code ec;
    if (fs::exists(csv_path, ec)) throw tactus::Error(csv_path + ": exists, not overwritten");
    csv = std::fopen(csv_path.c_str(), "wx");
    if (csv == nullptr) throw tactus::Error(csv_path + ": cannot create");
    std::fprintf(csv,
                 "problem,nc,tactus_error,tactus_sweeps,tactus_ms,tactus_converged,"
                 "siconos_error,siconos_reported_error,siconos_iterations,siconos_ms,"
                 "siconos_converged,time_ratio,sweep_time_ratio,u_rel_diff,norm_q,siconos_norm_r,"
                 "siconos_norm_u,block_fill,tactus_blocks,convert_ms,siconos_blocks\n");
  }

  std::printf("tol %.1e, max sweeps %d, %d runs each (median), Tactus W %s, Siconos W %s, "
              "Siconos error evaluation %s\n",
              s.tolerance, s.max_sweeps, s.reps,
              s.tactus_storage == "auto" ? "auto (chooseStorage)" : s.tactus_storage.c_str(),
              s.siconos_storage == "auto" ? "as Tactus (like for like)"
                                          : s.siconos_storage.c_str(),
              s.light_error ? "default (light)" : "full every sweep");
  std::printf("%-44s %5s | %9s %6s %9s %4s | %9s %6s %9s %4s | %7s %7s | %9s | %6s %6s %6s "
              "%7s\n",
              "problem", "nc", "T error", "sweeps", "T ms", "conv", "S error", "iters", "S ms",
              "conv", "t T/S", "swp T/S", "u diff", "fill", "T W", "S W", "conv ms");
  std::vector<double> time_ratios, sweep_ratios;
  double worst_u = 0.0;
  int t_conv = 0, s_conv = 0, both = 0, failed = 0, total = 0, skipped = 0;
  const std::size_t jobs = files.size() + generated.size();
  for (std::size_t job = 0; job < jobs; ++job) {
    Row row;
    try {
      row = job < files.size() ? benchOne(load(files[job]), s)
                               : benchOne(generated[job - files.size()], s);
    } catch (const std::exception& e) {
      spdlog::error("{}", e.what());
      ++failed;
      continue;
    }
    ++total;
    if (row.s_skipped) {
      ++skipped;
      std::printf("%-44s %5d | %9.2e %6d %9.3f %4s | Siconos not run: W is ill-posed (a zero, "
                  "negative or denormal diagonal; Siconos' NSGS asserts on it)\n",
                  row.name.c_str(), row.contacts, row.t_error, row.t_sweeps, row.t_ms,
                  row.t_conv ? "yes" : "no");
      std::fflush(stdout);
      continue;
    }
    const double tr = ratio(row.t_ms, row.s_ms);
    const double sr =
        ratio(row.t_ms / std::max(row.t_sweeps, 1), row.s_ms / std::max(row.s_iters, 1));
    t_conv += row.t_conv;
    s_conv += row.s_conv;
    if (row.t_conv && row.s_conv) {
      ++both;
      time_ratios.push_back(tr);
      sweep_ratios.push_back(sr);
      worst_u = std::max(worst_u, row.u_diff);
    }
    std::printf("%-44s %5d | %9.2e %6d %9.3f %4s | %9.2e %6d %9.3f %4s | %7.2f %7.2f | %9.2e | "
                "%6.3f %6s %6s %7.3f\n",
                row.name.c_str(), row.contacts, row.t_error, row.t_sweeps, row.t_ms,
                row.t_conv ? "yes" : "no", row.s_error, row.s_iters, row.s_ms,
                row.s_conv ? "yes" : "no", tr, sr, row.u_diff, row.fill,
                row.blocks ? "blocks" : "dense", row.s_blocks ? "blocks" : "dense",
                row.convert_ms);
    std::fflush(stdout);
    if (csv != nullptr &&
        std::fprintf(csv,
                     "%s,%d,%.6e,%d,%.6f,%d,%.6e,%.6e,%d,%.6f,%d,%.6f,%.6f,%.6e,%.6e,%.6e,%.6e,"
                     "%.6f,%d,%.6f,%d\n",
                     row.name.c_str(), row.contacts, row.t_error, row.t_sweeps, row.t_ms,
                     row.t_conv, row.s_error, row.s_reported, row.s_iters, row.s_ms, row.s_conv,
                     tr, sr, row.u_diff, row.norm_q, row.norm_r_s, row.norm_u_s, row.fill,
                     row.blocks ? 1 : 0, row.convert_ms, row.s_blocks ? 1 : 0) < 0) {
      std::fclose(csv);
      throw tactus::Error(csv_path + ": write failed");
    }
  }
  if (failed > 0) std::printf("failed: %d file(s) could not be read (above)\n", failed);
  if (skipped > 0) {
    std::printf("skipped: Siconos not run on %d ill-posed problem(s) (above)\n", skipped);
  }
  std::printf("summary: %d problems; tactus converged %d/%d, siconos converged %d/%d, both "
              "converged %d/%d; over those: median time ratio T/S %.2f (min %.2f, max %.2f), "
              "median per-sweep ratio %.2f, worst u diff %.2e\n",
              total, t_conv, total, s_conv, total - skipped, both, total, median(time_ratios),
              time_ratios.empty() ? 0.0 : *std::min_element(time_ratios.begin(), time_ratios.end()),
              time_ratios.empty() ? 0.0 : *std::max_element(time_ratios.begin(), time_ratios.end()),
              median(sweep_ratios), worst_u);
  if (csv != nullptr) {
    if (std::fclose(csv) != 0) throw tactus::Error(csv_path + ": write failed");
    std::printf("csv %s\n", csv_path.c_str());
  }
  return failed == 0 ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) { return tactus::shared::runToolMain(run, argc, argv); }
