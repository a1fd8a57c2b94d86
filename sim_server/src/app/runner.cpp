// The simulation daemon's loop and its statistics.
#include "tactus/sim/runner.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <functional>
#include <cmath>
#include <memory>
#include <sstream>
#include <vector>

#include "display_publisher.h"
#include "output_writer.h"
#include "obstacle_stage.h"
#include "segment_host.h"
#include "tactus/sim/instrument.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"
#include "tactus/shared/percentiles.h"
#include "tactus/shared/segment.h"
#include "tactus/shared/snapshot_file.h"

namespace tactus::sim {
namespace {

StageSummary summarise(const std::string& name, const std::vector<double>& v) {
  const shared::Percentiles p = shared::summarize(v);
  return {name, p.p50, p.p90, p.p99, p.max, p.mean};
}

// A JSON string's content: quotes, backslashes and control characters escaped.
std::string jsonEscape(const std::string& s) {
  std::string out;
  for (const char c : s) {
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (static_cast<unsigned char>(c) < 0x20) {
      out += fmt::format("\\u{:04x}", static_cast<int>(c));
    } else {
      out += c;
    }
  }
  return out;
}

}  // namespace

void RunStatistics::add(const StepReport& r) {
  free_motion_.push_back(r.times.free_motion_s);
  detect_collisions_.push_back(r.times.detect_collisions_s);
  update_compliance_.push_back(r.times.update_compliance_s);
  build_w_.push_back(r.times.build_w_s);
  solve_contacts_.push_back(r.times.solve_contacts_s);
  constrained_motion_.push_back(r.times.constrained_motion_s);
  output_.push_back(r.times.output_s);
  total_.push_back(r.times.total_s);
  contacts_.push_back(r.contacts);
  sweeps_.push_back(r.nsgs.sweeps);
  max_penetration_m_ = std::max(max_penetration_m_, r.max_penetration_m);
  max_inverted_ = std::max(max_inverted_, r.inverted_elements);
  last_inverted_ = r.inverted_elements;
}

std::vector<StageSummary> RunStatistics::stages() const {
  return {summarise("free_motion", free_motion_),
          summarise("detect_collisions", detect_collisions_),
          summarise("update_compliance", update_compliance_),
          summarise("build_w", build_w_),
          summarise("solve_contacts", solve_contacts_),
          summarise("constrained_motion", constrained_motion_),
          summarise("output", output_),
          summarise("total", total_)};
}

double RunStatistics::medianContacts() const { return shared::percentile(contacts_, 0.5); }
double RunStatistics::medianSweeps() const { return shared::percentile(sweeps_, 0.5); }
int RunStatistics::maxContacts() const {
  return contacts_.empty() ? 0 : static_cast<int>(*std::max_element(contacts_.begin(), contacts_.end()));
}

std::string RunStatistics::table() const {
  std::string out = fmt::format("{:<19} {:>10} {:>10} {:>10} {:>10}   ({} steps)\n", "stage [ms]",
                                "median", "p90", "p99", "max", steps());
  for (const auto& s : stages()) {
    out += fmt::format("{:<19} {:>10.3f} {:>10.3f} {:>10.3f} {:>10.3f}\n", s.name,
                       1e3 * s.median_s, 1e3 * s.p90_s, 1e3 * s.p99_s, 1e3 * s.max_s);
  }
  out += fmt::format("contacts: median {:.0f}, max {}; NSGS sweeps median {:.0f}; max penetration "
                     "{:.3g} mm\n",
                     medianContacts(), maxContacts(), medianSweeps(), 1e3 * max_penetration_m_);
  return out;
}

// The reactions at the end of the run [N] (reactions.h).
static std::string reactionsJson(const ReactionForces& r) {
  const auto vec = [](const Eigen::Vector3d& v) {
    return fmt::format("[{:.9g}, {:.9g}, {:.9g}]", v.x(), v.y(), v.z());
  };
  std::string obstacles;
  for (std::size_t i = 0; i < r.obstacle_names.size(); ++i) {
    obstacles += fmt::format("{}\"{}\": {}", i ? ", " : "", jsonEscape(r.obstacle_names[i]),
                             vec(r.obstacle_force_n[i]));
  }
  return fmt::format("{{\"weight_n\": {}, \"loads_n\": {}, \"fixed_n\": {}, "
                     "\"obstacles_n\": {{{}}}, \"instrument_n\": {}, \"imbalance_n\": {}}}",
                     vec(r.weight_n), vec(r.applied_load_n), vec(r.fixed_total_n), obstacles,
                     vec(r.instrument_force_n), vec(r.imbalance_n()));
}

std::string RunStatistics::json(const std::string& scene) const {
  std::string out = fmt::format("{{\n  \"scene\": \"{}\",\n  \"steps\": {},\n  \"stages_ms\": {{\n",
                                jsonEscape(scene), steps());
  const auto st = stages();
  for (std::size_t i = 0; i < st.size(); ++i) {
    out += fmt::format("    \"{}\": {{\"median\": {:.6f}, \"p90\": {:.6f}, \"p99\": {:.6f}, "
                       "\"max\": {:.6f}, \"mean\": {:.6f}}}{}\n",
                       st[i].name, 1e3 * st[i].median_s, 1e3 * st[i].p90_s, 1e3 * st[i].p99_s,
                       1e3 * st[i].max_s, 1e3 * st[i].mean_s, i + 1 < st.size() ? "," : "");
  }
  out += fmt::format("  }},\n  \"contacts_median\": {:.1f},\n  \"contacts_max\": {},\n"
                     "  \"sweeps_median\": {:.1f},\n  \"max_penetration_mm\": {:.6f},\n"
                     "  \"inverted_elements_max\": {},\n  \"inverted_elements_last\": {}",
                     medianContacts(), maxContacts(), medianSweeps(), 1e3 * max_penetration_m_,
                     max_inverted_, last_inverted_);
  if (reactions_) out += ",\n  \"reactions\": " + reactionsJson(*reactions_);
  out += "\n}\n";
  return out;
}

// A VTK series replaces its own files as it grows; an earlier run's series in the same folder is
// only replaced when asked (--overwrite).
static void refuseExistingSeries(const std::filesystem::path& dir) {
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec)) return;
  for (const auto& entry : std::filesystem::directory_iterator(dir, ec)) {
    const auto ext = entry.path().extension();
    if (entry.path().filename() == "series.pvd" || ext == ".vtu") {
      throw FileError(fmt::format(
          "{}: holds a VTK series from an earlier run ({}); choose another --output folder or "
          "pass --overwrite", shared::printable(dir.string(), 200),
          shared::printable(entry.path().filename().string())));
    }
  }
}

void exportTrajectory(const SceneSpec& spec, const std::filesystem::path& csv, double dt_s,
                      bool overwrite, int instrument) {
  if (!spec.instrument.present) throw SceneError(spec.source.string() + ": no instrument to export");
  if (instrument < 0 || instrument >= instrumentCount(spec)) {
    throw SceneError(fmt::format("{}: no instrument {} to export (the scene has {})",
                                 spec.source.string(), instrument, instrumentCount(spec)));
  }
  const InstrumentSpec& in = instrumentSpec(spec, instrument);
  // a Simulation is not needed: interpolate the keys directly
  SceneSpec light = spec;
  light.tissues.clear();
  Simulation sim(light);
  const auto& keys = in.trajectory;
  const double end = keys.empty() ? 0.0 : keys.back().t_s;
  shared::OutputFile out(csv, "trajectory CSV",
                         {.overwrite = overwrite, .overwrite_hint = "pass --overwrite"});
  out.write("t_s,x,y,z,qw,qx,qy,qz,gripper\n");
  // this instrument's device mapping: its haptics.workspaces entry, else haptics.workspace
  const shared::WorkspaceMappingParams& mapping =
      static_cast<std::size_t>(instrument) < spec.haptics.workspaces.size()
          ? spec.haptics.workspaces[static_cast<std::size_t>(instrument)]
          : spec.haptics.workspace;
  const long n = static_cast<long>(std::ceil(end / dt_s));
  for (long k = 0; k <= n && out.ok(); ++k) {
    const double t = std::min(end, static_cast<double>(k) * dt_s);
    const DeviceTarget d = sim.scriptedTarget(instrument, t);
    // the hand replays it in the device frame: the workspace mapping takes it back to the scene
    std::array<double, 3> p{d.pose.pos_m.x(), d.pose.pos_m.y(), d.pose.pos_m.z()};
    std::array<double, 4> q{d.pose.rot.w(), d.pose.rot.x(), d.pose.rot.y(), d.pose.rot.z()};
    if (!mapping.isIdentity()) mapping.sceneToDevice(p, q);
    out.write(fmt::format("{:.6f},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g},{:.9g}\n", t,
                          p[0], p[1], p[2], q[0], q[1], q[2], q[3],
                          d.gripper_opening * in.max_opening_rad));
  }
  out.commit();
}

SnapshotRecorder::SnapshotRecorder(const SceneSpec& spec, const SnapshotRecordingOptions& options)
    : options_(options), max_opening_rad_(spec.instrument.max_opening_rad) {
  if (options.max_mb < 1 || options.max_mb > kMaxRecordingMiB) {
    throw Error(fmt::format("--record-snapshots-max-mb {}: must be 1..{} (what tactus-jitter "
                            "--replay reads)",
                            options.max_mb, kMaxRecordingMiB));
  }
  if (options.first_step < 1) {
    throw Error(fmt::format("--record-snapshots-from-step {}: must be 1 or more (the first step "
                            "is 1)",
                            options.first_step));
  }
  writer_ = std::make_unique<shared::SnapshotFileWriter>(
      options.path,
      shared::OutputOptions{.overwrite = options.overwrite,
                            .overwrite_hint = "pass --overwrite to replace it"},
      static_cast<std::uint64_t>(options.max_mb) << 20);
  // a private slot of the capacity the segment has (instruments', obstacles', tissue pairs')
  const shared::SegmentCapacity cap = problemCapacity(spec);
  layout_ = shared::SnapshotLayout::forCapacity(cap.max_rows, cap.max_contacts);
  slot_.assign(layout_.total_bytes / sizeof(double) + 1, 0.0);
}

SnapshotRecorder::~SnapshotRecorder() = default;

std::uint64_t SnapshotRecorder::count() const { return writer_->count(); }

void SnapshotRecorder::record(const Simulation& sim, std::uint64_t seq) {
  if (full_ || !sim.hasInstrument()) return;
  if (seq < static_cast<std::uint64_t>(options_.first_step)) return;
  const std::int64_t t_ns = std::llround(sim.time() * 1e9);
  shared::SnapshotWriter slot(slot_.data(), layout_);
  writeSnapshot(sim, max_opening_rad_, seq, t_ns, 0, slot);
  if (!writer_->append(slot.view(), t_ns)) {
    // bounded: a daemon in contact writes tens of MB per simulated second
    spdlog::warn("--record-snapshots reached its cap of {} MiB after {} snapshots ({:.2f} s "
                 "simulated): recording stopped, the run goes on; the file keeps them "
                 "(--record-snapshots-max-mb sets the cap)",
                 options_.max_mb, writer_->count(), sim.time());
    full_ = true;
  }
}

void SnapshotRecorder::commit() {
  writer_->commit();
  spdlog::info("{} snapshots recorded to {}", writer_->count(), options_.path.string());
}

HeadlessResult runHeadless(Simulation& sim, const HeadlessRun& run) {
  HeadlessResult result;
  for (long k = 0; k < run.steps; ++k) {
    if (run.stop != nullptr && run.stop->load(std::memory_order_relaxed)) {
      result.end = RunEnd::kStopped;
      return result;
    }
    for (int i = 0; i < sim.instrumentCount(); ++i) {
      sim.setDeviceTarget(i, sim.scriptedTarget(i, sim.time()));
    }
    StepReport report = sim.step();
    ++result.steps;
    if (!report.finite) {
      if (run.statistics != nullptr) run.statistics->add(report);
      result.end = RunEnd::kNonFinite;
      return result;
    }
    if (run.recorder != nullptr) run.recorder->record(sim, static_cast<std::uint64_t>(k + 1));
    if (run.after_step) run.after_step(k, report);
    if (run.statistics != nullptr) run.statistics->add(report);
  }
  return result;
}

// The daemon: paced to real time until `stop` or --duration, publishing to the haptic process
// when the scene enables haptics. Returns the exit code.
static int runPaced(const RunOptions& options, const SceneSpec& spec, Simulation& sim,
                    SnapshotRecorder* recorder, RunStatistics& stats,
                    const std::function<void(StepReport&)>& write_output,
                    const std::atomic<bool>& stop) {
  std::unique_ptr<SegmentHost> link;
  if (spec.haptics.enabled && sim.hasInstrument()) {
    std::vector<BoxSpec> workspaces;
    for (int i = 0; i < sim.instrumentCount(); ++i) {
      workspaces.push_back(sim.instrument(i).workspace());
    }
    link = std::make_unique<SegmentHost>(options.segment, spec, std::move(workspaces));
  }
  auto display = link ? std::make_unique<DisplayLink>(options.segment, sim) : nullptr;
  const double h = spec.time_step_s;
  // a daemon runs until stopped (or --duration); the scene's duration is for offline tools
  const double duration = options.duration_s;
  const std::int64_t t0 = shared::monotonicNs();
  long late_steps = 0;
  std::int64_t last_report_ns = t0;
  std::int64_t last_status_ns = t0;
  for (long k = 0; !stop.load(std::memory_order_relaxed); ++k) {
    if (duration > 0.0 && sim.time() >= duration - 1e-12) break;
    // device target: the newest haptic sample when fresh, else the scene's script
    for (int i = 0; i < sim.instrumentCount(); ++i) {
      DeviceTarget target = sim.scriptedTarget(i, sim.time());
      if (link) link->deviceTarget(i, target);
      sim.setDeviceTarget(i, target);
    }
    StepReport report = sim.step();
    if (link) {
      // a simulation whose segment was removed or replaced publishes into nothing: stop
      if (const std::string why = link->displacedReason(shared::monotonicNs()); !why.empty()) {
        spdlog::error("{}", why);
        stats.add(report);
        return 3;
      }
      link->publish(sim);
    }
    if (display) display->publish(sim, report);
    if (recorder != nullptr) recorder->record(sim, static_cast<std::uint64_t>(k + 1));
    write_output(report);
    stats.add(report);
    if (!report.finite) {
      spdlog::error("step {}: the state became non-finite; stopping", k);
      return 2;
    }
    if (options.status && shared::monotonicNs() - last_status_ns >= 1'000'000'000LL) {
      last_status_ns = shared::monotonicNs();
      if (sim.hasInstrument()) {
        const Eigen::Vector3d p = sim.instrument()->pose().pos_m;
        spdlog::info("status t={:.2f} s tool=({:.4f}, {:.4f}, {:.4f}) m contacts={} |F|={:.3f} N "
                     "inverted={}",
                     sim.time(), p.x(), p.y(), p.z(), report.contacts,
                     sim.renderedWrench().head<3>().norm(), report.inverted_elements);
      } else {
        spdlog::info("status t={:.2f} s inverted={}", sim.time(), report.inverted_elements);
      }
    }
    // pace to real time; report when the step cannot keep up
    const std::int64_t deadline = t0 + static_cast<std::int64_t>(std::llround((k + 1) * h * 1e9));
    const std::int64_t now = shared::monotonicNs();
    if (now > deadline) {
      ++late_steps;
    } else {
      shared::sleepUntilNs(deadline);
    }
    if (now - last_report_ns > 5'000'000'000LL) {
      last_report_ns = now;
      if (late_steps > 0) {
        spdlog::warn("cannot keep up with real time: {} of the last steps overran h = {} ms",
                     late_steps, 1e3 * h);
        late_steps = 0;
      }
      if (link) link->logStatus();
    }
  }
  return 0;
}

int runSimulation(const RunOptions& options, const std::atomic<bool>& stop) {
  SceneSpec spec = loadScene(options.scene_path);
  // refuse an existing statistics file now, not after the run
  std::unique_ptr<shared::OutputFile> stats_file;
  if (!options.stats_json.empty() && options.export_trajectory.empty()) {
    stats_file = std::make_unique<shared::OutputFile>(
        options.stats_json, "statistics file",
        shared::OutputOptions{.overwrite = options.overwrite,
                              .overwrite_hint = "pass --overwrite"});
  }
  if (!options.export_trajectory.empty()) {
    exportTrajectory(spec, options.export_trajectory, 0.01, options.overwrite,
                     options.export_instrument);
    spdlog::info("trajectory written to {}", options.export_trajectory);
    return 0;
  }
  if (!options.output_dir.empty()) {
    spec.output.enabled = true;
    spec.output.directory = options.output_dir;
  }
  if (options.output_every > 0) spec.output.every_n_steps = options.output_every;
  if (spec.output.enabled && !options.overwrite) refuseExistingSeries(spec.output.directory);
  const bool offline = options.steps > 0;
  if (offline || options.no_haptics) spec.haptics.enabled = false;
  // --record-snapshots: the target is checked now, before the scene is built
  std::unique_ptr<SnapshotRecorder> recorder;
  if (!options.record_snapshots.empty()) {
    recorder = std::make_unique<SnapshotRecorder>(
        spec, SnapshotRecordingOptions{.path = options.record_snapshots,
                                       .max_mb = options.record_snapshots_max_mb,
                                       .overwrite = options.overwrite,
                                       .first_step = options.record_snapshots_from_step});
  }

  Simulation sim(spec);
  OutputWriter output;
  shared::throwIfStopRequested("loading the scene");
  spdlog::info("scene {}: stages:", spec.source.string());
  for (const auto& s : sim.stages()) spdlog::info("  - {}", s);

  RunStatistics stats;
  const std::int64_t t0 = shared::monotonicNs();
  int exit_code = 0;
  // VTK output after the snapshot is published (the haptic side does not wait for it), timed
  // into the step's statistics outside total_s
  const auto writeOutput = [&](StepReport& report) {
    const std::int64_t t_output = shared::monotonicNs();
    output.writeIfDue(sim);
    report.times.output_s = shared::secondsSinceNs(t_output);
  };
  if (offline) {
    // --steps: the headless runner
    const HeadlessResult run = runHeadless(
        sim, {.steps = options.steps, .stop = &stop, .recorder = recorder.get(),
              .statistics = &stats, .after_step = [&](long, StepReport& r) { writeOutput(r); }});
    if (run.end == RunEnd::kNonFinite) {
      spdlog::error("step {}: the state became non-finite; stopping", run.steps - 1);
      exit_code = 2;
    }
  } else {
    exit_code = runPaced(options, spec, sim, recorder.get(), stats, writeOutput, stop);
  }
  output.finish(spec);
  if (recorder) recorder->commit();
  const double wall_s = 1e-9 * static_cast<double>(shared::monotonicNs() - t0);
  spdlog::info("{} steps, simulated {:.3f} s in {:.3f} s wall", stats.steps(), sim.time(), wall_s);
  std::printf("%s", stats.table().c_str());
  if (stats_file) {
    stats.setReactions(sim.reactions());
    stats_file->write(stats.json(spec.source.string()));
    stats_file->commit();
    spdlog::info("statistics written to {}", options.stats_json);
  }
  return exit_code;
}

}  // namespace tactus::sim
