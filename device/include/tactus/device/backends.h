#pragma once
// The bundled device backends, exposed for tests and for programs that want one directly
// (normal code goes through loadDevice()). Also the trajectory CSV used by `replay`, by the
// `simulated` backend's scripted set point and by the recorder:
//
//   t_s,x,y,z,qw,qx,qy,qz,gripper
//   0.000,0.0,0.0,0.05,1,0,0,0,0.0
//   ...
//
// t_s strictly increasing seconds from the start, positions in m, a quaternion (normalised on
// load), gripper opening in rad. '#' lines and blank lines are ignored.

#include <atomic>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "tactus/device/device.h"

namespace tactus::shared {
class OutputFile;  // tactus/shared/file_io.h
}

namespace tactus::device {

/// Reads typed options and rejects unknown ones (non-RT helper for backend constructors).
class OptionReader {
 public:
  OptionReader(std::string backend, const DeviceConfig& config);
  double number(const std::string& key, double fallback);
  /// Same, and the value must lie in [lo, hi] (throws DeviceError naming key, value and range).
  double number(const std::string& key, double fallback, double lo, double hi);
  /// vec3 whose components each lie in [-max_abs, max_abs].
  std::array<double, 3> vec3(const std::string& key, const std::array<double, 3>& fallback,
                             double max_abs);
  std::array<double, 3> vec3(const std::string& key, const std::array<double, 3>& fallback);
  std::string text(const std::string& key, const std::string& fallback = "");
  bool flag(const std::string& key, bool fallback);
  bool has(const std::string& key) const;
  /// Throws DeviceError naming any option not read so far and the known ones.
  void rejectUnknown() const;

 private:
  std::string backend_;
  const DeviceConfig& config_;
  std::set<std::string> known_;
};

struct TrajectoryPoint {
  double t_s = 0.0;
  std::array<double, 3> pos_m{};
  std::array<double, 4> quat_wxyz{1.0, 0.0, 0.0, 0.0};
  double gripper_rad = 0.0;
};

/// Timed poses with linear (position, gripper) and normalised-lerp (orientation) interpolation.
class Trajectory {
 public:
  static constexpr const char* kCsvHeader = "t_s,x,y,z,qw,qx,qy,qz,gripper";

  /// Parses a CSV file; throws DeviceError naming file, line and column.
  static Trajectory loadCsv(const std::string& path);
  /// Same from text (`origin` names it in messages).
  static Trajectory parseCsv(const std::string& text, const std::string& origin);

  explicit Trajectory(std::vector<TrajectoryPoint> points = {});
  bool empty() const noexcept { return points_.empty(); }
  double durationS() const noexcept;
  const std::vector<TrajectoryPoint>& points() const noexcept { return points_; }

  /// Pose at t_s (clamped to the ends), with the segment's velocity. Allocation-free.
  void sample(double t_s, DeviceState* out) const noexcept;

  /// Formats one CSV row (with '\n') into buf; returns the length (snprintf semantics).
  static int formatRow(char* buf, std::size_t size, const TrajectoryPoint& p) noexcept;

 private:
  std::vector<TrajectoryPoint> points_;
};

/// `null`: no device. Returns kNoData, or a fixed pose with option pose=x,y,z (each within 10 m).
/// Writes are accepted and discarded.
class NullDevice final : public Device {
 public:
  explicit NullDevice(const DeviceConfig& config = {});
  DeviceInfo info() const override;
  void open() override {}
  void calibrate() override {}
  void enableForces(bool) override {}
  void close() noexcept override {}
  IoStatus read(DeviceState* out) noexcept override;
  IoStatus write(const DeviceCommand& cmd) noexcept override;

 private:
  bool has_pose_ = false;
  std::array<double, 3> pose_{};
};

/// `simulated` (the default): a virtual hand. A point mass (option mass, kg) pulled by a
/// spring-damper (stiffness N/m, damping N s/m) toward a scripted set point, and pushed by the
/// force commanded through write() while forces are enabled. The set point follows
/// trajectory=FILE.csv (option loop=true|false), else a built-in press-and-release: it moves
/// from origin=x,y,z by amplitude (m) along axis=x,y,z (default 0,0,-1) and back, with
/// period (s). read() integrates the motion over the elapsed monotonic time since the previous
/// read (semi-implicit Euler, 0.25 ms sub-steps, at most 50 ms per read), so the rendered force
/// changes the motion exactly as a hand holding a real device would feel it. Orientation and
/// gripper follow the set point. Other options: max_force (N) reported by info().
/// Ranges (DeviceError otherwise): mass [1e-3, 100] kg, stiffness [0, 1e6] N/m, damping
/// [0, 1e4] N s/m, with stiffness/mass <= 1/0.25ms^2 and damping/mass <= 1/0.25ms (a stable
/// integration), max_force [1e-3, 100] N, origin/axis components and amplitude within 10 m,
/// period [1e-3, 1e5] s.
class SimulatedDevice final : public Device {
 public:
  explicit SimulatedDevice(const DeviceConfig& config = {});
  DeviceInfo info() const override;
  void open() override;
  void calibrate() override {}
  void enableForces(bool on) override { forces_on_ = on; }
  void close() noexcept override { opened_ = false; }
  IoStatus read(DeviceState* out) noexcept override;
  IoStatus write(const DeviceCommand& cmd) noexcept override;

  /// read() at an explicit time (deterministic tests). t_ns must not go backwards.
  IoStatus readAt(std::int64_t t_ns, DeviceState* out) noexcept;
  /// open() with an explicit start time.
  void openAt(std::int64_t t_ns);
  /// The set point at t_s seconds after open.
  void setPoint(double t_s, DeviceState* out) const noexcept;

  double mass() const noexcept { return mass_; }
  double stiffness() const noexcept { return stiffness_; }
  double damping() const noexcept { return damping_; }

 private:
  double mass_, stiffness_, damping_, max_force_;
  std::array<double, 3> origin_{}, axis_{0.0, 0.0, -1.0};
  double amplitude_m_, period_s_;
  Trajectory trajectory_;
  bool loop_ = true;
  bool opened_ = false;
  bool forces_on_ = false;
  std::int64_t t0_ns_ = 0, last_ns_ = 0;
  std::array<double, 3> x_{}, v_{}, force_{};
};

/// `replay`: plays file=FILE.csv from open() on (options loop=true|false, speed=factor in
/// [1e-3, 1e3]).
/// read() interpolates at the elapsed monotonic time; after the end it holds the last pose (or
/// loops). Writes are accepted and ignored (a replay cannot render force).
class ReplayDevice final : public Device {
 public:
  explicit ReplayDevice(const DeviceConfig& config);
  DeviceInfo info() const override;
  void open() override;
  void calibrate() override {}
  void enableForces(bool) override {}
  void close() noexcept override { opened_ = false; }
  IoStatus read(DeviceState* out) noexcept override;
  IoStatus write(const DeviceCommand& cmd) noexcept override;

  IoStatus readAt(std::int64_t t_ns, DeviceState* out) noexcept;
  void openAt(std::int64_t t_ns);
  const Trajectory& trajectory() const noexcept { return trajectory_; }

 private:
  Trajectory trajectory_;
  bool loop_ = false;
  double speed_ = 1.0;
  bool opened_ = false;
  std::int64_t t0_ns_ = 0;
};

/// Wraps any device and records every sample its read() returns with kOk into a CSV in the
/// replay format, and (with a `commands_path`, device option record_commands=FILE.csv) every
/// command its write() receives into a second CSV:
///
///   t_ns,force_x_n,force_y_n,force_z_n,torque_x_nm,torque_y_nm,torque_z_nm
///
/// one row per write, t_ns the CLOCK_MONOTONIC time of the write, in order. read() and write()
/// only copy into preallocated single-producer rings (capacity entries each; full => the entry
/// is dropped and counted, and close() reports the recording incomplete in writeError()); a
/// background thread writes the files, and close() drains the rings and closes them. No file
/// I/O on the real-time thread. The files are written through a temporary file in the same
/// folder and renamed into place by close() (after fsync); an existing file is never replaced
/// unless `overwrite` (device option record_overwrite=1). open() throws DeviceError when a
/// target exists or cannot be created; a later write, fsync or rename failure is kept in
/// writeError() (the file is then not created).
class RecordingDevice final : public Device {
 public:
  RecordingDevice(std::unique_ptr<Device> inner, std::string path, std::size_t capacity = 1 << 16,
                  bool overwrite = false, std::string commands_path = {});
  ~RecordingDevice() override;
  DeviceInfo info() const override { return inner_->info(); }
  void open() override;
  void calibrate() override { inner_->calibrate(); }
  void enableForces(bool on) override { inner_->enableForces(on); }
  void close() noexcept override;
  IoStatus read(DeviceState* out) noexcept override;
  IoStatus write(const DeviceCommand& cmd) noexcept override;
  bool halt() noexcept override { return inner_->halt(); }
  std::string takeDiagnostics() override { return inner_->takeDiagnostics(); }

  Device& inner() noexcept { return *inner_; }
  std::uint64_t recorded() const noexcept { return written_.load(std::memory_order_relaxed); }
  std::uint64_t dropped() const noexcept { return dropped_.load(std::memory_order_relaxed); }
  std::uint64_t recordedCommands() const noexcept {
    return commands_written_.load(std::memory_order_relaxed);
  }
  std::uint64_t droppedCommands() const noexcept {
    return commands_dropped_.load(std::memory_order_relaxed);
  }
  /// Empty while the recording is intact; else why the file was not (completely) written. Valid
  /// after close().
  const std::string& writeError() const noexcept { return write_error_; }

 private:
  /// One recorded command.
  struct CommandRecord {
    std::int64_t t_ns = 0;
    DeviceCommand command;
  };
  void flushLoop() noexcept;
  std::size_t drainToFile() noexcept;
  std::size_t drainCommandsToFile() noexcept;

  std::unique_ptr<Device> inner_;
  std::string path_;                 ///< samples (empty: not recorded)
  std::string commands_path_;        ///< commands (empty: not recorded)
  std::vector<DeviceState> ring_;
  alignas(64) std::atomic<std::uint64_t> head_{0};
  alignas(64) std::atomic<std::uint64_t> tail_{0};
  std::atomic<std::uint64_t> dropped_{0};
  std::atomic<std::uint64_t> written_{0};
  std::vector<CommandRecord> command_ring_;
  alignas(64) std::atomic<std::uint64_t> command_head_{0};
  alignas(64) std::atomic<std::uint64_t> command_tail_{0};
  std::atomic<std::uint64_t> commands_dropped_{0};
  std::atomic<std::uint64_t> commands_written_{0};
  std::atomic<bool> stop_{false};
  std::unique_ptr<shared::OutputFile> file_;
  std::unique_ptr<shared::OutputFile> commands_file_;
  bool overwrite_ = false;
  std::string write_error_;
  std::thread flusher_;
  std::int64_t first_t_ns_ = -1;     ///< flusher thread only
  std::int64_t last_t_ns_ = -1;      ///< flusher thread only (samples must move forward)
};

}  // namespace tactus::device
