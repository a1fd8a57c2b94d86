// tactus-fc3d-solve: solves one FCLIB frictional contact problem with the project's NSGS and
// prints contacts, sweeps, error (Siconos normalisation, recomputed from the returned forces),
// status and time. Exit status 0 only when the solver converged; 2 otherwise (including a
// problem with an unusable diagonal of W, status ill_posed).

#include <spdlog/spdlog.h>

#include "tactus/shared/cli.h"
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "tactus/shared/error.h"
#include "tactus/shared/fclib.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/tool_main.h"
#ifdef TACTUS_HAVE_HDF5
#include "fclib_hdf5.h"
#endif

namespace {

using tactus::shared::FclibProblem;

FclibProblem load(const std::filesystem::path& path) {
  if (path.extension() == ".hdf5" || path.extension() == ".h5") {
#ifdef TACTUS_HAVE_HDF5
    return tactus::shared::readFclibHdf5(path);
#else
    throw tactus::Error(path.string() +
                        ": HDF5 input was not compiled in (install libhdf5-dev, re-run cmake) - "
                        "use the .fc3d.txt form instead");
#endif
  }
  return tactus::shared::readFclibText(path);
}

int run(int argc, char** argv) {
  namespace cli = tactus::shared::cli;
  cli::App app{
      "Solves an FCLIB local 3D frictional contact problem (u = W r + q, Coulomb cones) with "
      "Tactus' nonsmooth Gauss-Seidel. The error is Siconos' fc3d_compute_error: "
      "sqrt(sum_i ||r_i - P_K(r_i - u_hat_i)||^2) / max(||q||, ||r||, ||u||), "
      "u_hat = u + mu ||u_T|| n."};
  app.footer(
      "Example:\n"
      "  tactus-fc3d-solve tests/data/fclib/problems/Box_Stacks-i0035-31-0.local.fc3d.txt --tol 1e-9");
  std::string problem_path;
  std::string output_path;
  tactus::shared::NsgsSettings settings;
  settings.max_sweeps = 10000;
  double budget_ms = 0.0;
  bool row_gather = false;
  app.addOption("problem", problem_path, "problem file (.fc3d.txt, or .hdf5 in FCLIB layout)")
      ->required();
  app.addOption("--tol", settings.tolerance, "tolerance on the normalised error")
      ->captureDefault();
  app.addOption("--max-sweeps", settings.max_sweeps, "maximum number of sweeps")
      ->captureDefault()
      ->check(cli::positiveNumber());
  app.addOption("--sor", settings.sor, "over-relaxation factor in (0, 2)")
      ->captureDefault()
      ->check(cli::range(0.01, 1.99));
  app.addOption("--check-every", settings.check_every, "compute the error every k sweeps")
      ->captureDefault()
      ->check(cli::positiveNumber());
  app.addOption("--time-budget-ms", budget_ms, "stop after the sweep that crosses it (0: none)")
      ->captureDefault();
  app.addFlag("--row-gather", row_gather, "gather b_i from W's rows instead of column updates");
  app.addOption("--output", output_path, "write `r u` per row (reference format) to FILE");
  bool overwrite = false;
  app.addFlag("--overwrite", overwrite, "replace an existing --output file");
  TACTUS_CLI_PARSE(app, argc, argv);

  settings.time_budget_ns = static_cast<std::int64_t>(budget_ms * 1e6);
  if (row_gather) settings.coupling = tactus::shared::NsgsCoupling::kRowGather;
  const FclibProblem problem = load(problem_path);
  const auto view = problem.view();
  tactus::shared::NsgsWorkspace workspace(problem.rows(), problem.contacts);
  std::vector<double> r(problem.rows(), 0.0);
  const auto result = tactus::shared::solveNsgs(view, settings, workspace, r.data());
  std::vector<double> u(problem.rows(), 0.0);
  const double error = tactus::shared::naturalMapError(view, r.data(), u.data());

  std::printf("problem   %s\n", problem.name.c_str());
  std::printf("contacts  %d (rows %d)\n", problem.contacts, problem.rows());
  std::printf("sweeps    %d\n", result.sweeps);
  std::printf("error     %.3e (Siconos fc3d error, normalised by max(|q|,|r|,|u|))\n", error);
  std::printf("status    %s (tol %.1e)\n", std::string(toString(result.status)).c_str(),
              settings.tolerance);
  if (result.ill_posed_contacts > 0) {
    std::printf("ill-posed %d contacts (W diagonal zero, negative, denormal or negligible: held at "
                "zero force)\n",
                result.ill_posed_contacts);
  }
  std::printf("time      %.3f ms\n", static_cast<double>(result.elapsed_ns) * 1e-6);
  if (!output_path.empty()) {
    char comment[256];
    std::snprintf(comment, sizeof comment,
                  "tactus NSGS solution of %s, natural-map error %.3e (normalised by "
                  "max(|q|,|r|,|u|)), %d sweeps, status %s; columns: r u",
                  problem.name.c_str(), error, result.sweeps,
                  std::string(toString(result.status)).c_str());
    tactus::shared::writeFclibSolution(output_path, r, u, comment, overwrite);
    std::printf("output    %s\n", output_path.c_str());
  }
  return result.status == tactus::shared::NsgsStatus::kConverged ? 0 : 2;
}

}  // namespace

int main(int argc, char** argv) { return tactus::shared::runToolMain(run, argc, argv); }
