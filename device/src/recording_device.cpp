// The recorder wrapper: samples read and commands written, copied into rings on the real-time
// thread and written to CSV files by a background thread (backends.h).
#include <chrono>
#include <cinttypes>
#include <cstdio>
#include <cstring>

#include "tactus/device/backends.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/file_io.h"

namespace tactus::device {

namespace {

std::unique_ptr<shared::OutputFile> openRecording(const std::string& path, bool overwrite,
                                                  const char* what) {
  try {
    return std::make_unique<shared::OutputFile>(
        path, what,
        shared::OutputOptions{.overwrite = overwrite,
                              .overwrite_hint = "give device option record_overwrite=1"});
  } catch (const FileError& e) {
    throw DeviceError("cannot record to '" + shared::printable(path, 256) + "': " + e.what());
  }
}

// Commits `file` (fsync, rename); keeps the first failure in `error`.
void commitRecording(std::unique_ptr<shared::OutputFile>& file, std::string& error) noexcept {
  if (!file) return;
  try {
    file->commit();
  } catch (const std::exception& e) {
    try {
      if (error.empty()) error = e.what();
    } catch (...) {
      // out of memory: the fallback below
    }
    if (error.empty()) error = "recording failed";
  }
  file.reset();
}

}  // namespace

RecordingDevice::RecordingDevice(std::unique_ptr<Device> inner, std::string path,
                                 std::size_t capacity, bool overwrite,
                                 std::string commands_path)
    : inner_(std::move(inner)),
      path_(std::move(path)),
      commands_path_(std::move(commands_path)),
      ring_(path_.empty() ? 0 : std::max<std::size_t>(capacity, 2)),
      command_ring_(commands_path_.empty() ? 0 : std::max<std::size_t>(capacity, 2)),
      overwrite_(overwrite) {}

RecordingDevice::~RecordingDevice() { close(); }

void RecordingDevice::open() {
  if (!path_.empty() && !file_) {
    file_ = openRecording(path_, overwrite_, "recording");
    write_error_.clear();
    file_->write(Trajectory::kCsvHeader);
    file_->write("\n");
  }
  if (!commands_path_.empty() && !commands_file_) {
    commands_file_ = openRecording(commands_path_, overwrite_, "command recording");
    commands_file_->write("t_ns,force_x_n,force_y_n,force_z_n,torque_x_nm,torque_y_nm,"
                          "torque_z_nm\n");
  }
  inner_->open();
  // the flusher writes the files; read() and write() only fill the rings
  if (!flusher_.joinable()) {
    stop_.store(false, std::memory_order_relaxed);
    flusher_ = std::thread([this] { flushLoop(); });
  }
}

void RecordingDevice::close() noexcept {
  // stop the flusher, then write what is left
  if (flusher_.joinable()) {
    // release: pairs with the flusher's acquire; it exits after a last drain
    stop_.store(true, std::memory_order_release);
    flusher_.join();
  }
  if (file_) {
    drainToFile();
    commitRecording(file_, write_error_);
  }
  if (commands_file_) {
    drainCommandsToFile();
    const std::uint64_t lost = commands_dropped_.load(std::memory_order_relaxed);
    if (lost > 0 && write_error_.empty()) {
      try {
        write_error_ = std::to_string(lost) + " commands not recorded in '" + commands_path_ +
                       "' (the recording ring was full): the command recording is incomplete";
      } catch (...) {
        write_error_ = "the command recording is incomplete";
      }
    }
    commitRecording(commands_file_, write_error_);
  }
  if (inner_) inner_->close();
}

IoStatus RecordingDevice::read(DeviceState* out) noexcept {
  const IoStatus st = inner_->read(out);
  if (st != IoStatus::kOk || ring_.empty()) return st;
  // relaxed: only this thread writes head_
  const std::uint64_t head = head_.load(std::memory_order_relaxed);
  // acquire: the flusher's copy out of the slot is complete before we overwrite it
  const std::uint64_t tail = tail_.load(std::memory_order_acquire);
  if (head - tail >= ring_.size()) {
    // relaxed: a statistic
    dropped_.fetch_add(1, std::memory_order_relaxed);
    return st;
  }
  ring_[head % ring_.size()] = *out;
  // release: the sample is visible to the flusher that acquires head_
  head_.store(head + 1, std::memory_order_release);
  return st;
}

IoStatus RecordingDevice::write(const DeviceCommand& cmd) noexcept {
  if (!command_ring_.empty()) {
    // relaxed: only this thread writes command_head_
    const std::uint64_t head = command_head_.load(std::memory_order_relaxed);
    // acquire: the flusher's copy out of the slot is complete before we overwrite it
    const std::uint64_t tail = command_tail_.load(std::memory_order_acquire);
    if (head - tail >= command_ring_.size()) {
      // relaxed: a statistic
      commands_dropped_.fetch_add(1, std::memory_order_relaxed);
    } else {
      command_ring_[head % command_ring_.size()] = {shared::monotonicNs(), cmd};
      // release: the record is visible to the flusher that acquires command_head_
      command_head_.store(head + 1, std::memory_order_release);
    }
  }
  return inner_->write(cmd);
}

std::size_t RecordingDevice::drainToFile() noexcept {
  if (ring_.empty()) return 0;
  std::size_t n = 0;
  // relaxed: only the flusher (or close() after joining it) writes tail_
  std::uint64_t tail = tail_.load(std::memory_order_relaxed);
  // acquire: pairs with read()'s release of head_
  const std::uint64_t head = head_.load(std::memory_order_acquire);
  char line[256];
  for (; tail < head; ++tail, ++n) {
    const DeviceState s = ring_[tail % ring_.size()];
    // release: our copy is done, the slot may be reused
    tail_.store(tail + 1, std::memory_order_release);
    if (first_t_ns_ < 0) first_t_ns_ = s.t_ns;
    if (s.t_ns <= last_t_ns_) continue;  // a repeated sample: the CSV needs increasing times
    last_t_ns_ = s.t_ns;
    TrajectoryPoint p;
    p.t_s = static_cast<double>(s.t_ns - first_t_ns_) * 1e-9;
    p.pos_m = s.pos_m;
    p.quat_wxyz = s.quat_wxyz;
    p.gripper_rad = s.gripper_rad;
    const int len = Trajectory::formatRow(line, sizeof(line), p);
    if (file_ && len > 0) file_->write(std::string_view(line, static_cast<std::size_t>(len)));
    // relaxed: a statistic
    written_.fetch_add(1, std::memory_order_relaxed);
  }
  return n;
}

std::size_t RecordingDevice::drainCommandsToFile() noexcept {
  if (command_ring_.empty()) return 0;
  std::size_t n = 0;
  // relaxed: only the flusher (or close() after joining it) writes command_tail_
  std::uint64_t tail = command_tail_.load(std::memory_order_relaxed);
  // acquire: pairs with write()'s release of command_head_
  const std::uint64_t head = command_head_.load(std::memory_order_acquire);
  char line[256];
  for (; tail < head; ++tail, ++n) {
    const CommandRecord r = command_ring_[tail % command_ring_.size()];
    // release: our copy is done, the slot may be reused
    command_tail_.store(tail + 1, std::memory_order_release);
    // %.17g: the values round-trip exactly (the fault suite compares them)
    const int len = std::snprintf(line, sizeof(line),
                                  "%" PRId64 ",%.17g,%.17g,%.17g,%.17g,%.17g,%.17g\n", r.t_ns,
                                  r.command.force_n[0], r.command.force_n[1],
                                  r.command.force_n[2], r.command.torque_nm[0],
                                  r.command.torque_nm[1], r.command.torque_nm[2]);
    if (commands_file_ && len > 0 && static_cast<std::size_t>(len) < sizeof(line)) {
      commands_file_->write(std::string_view(line, static_cast<std::size_t>(len)));
    }
    // relaxed: a statistic
    commands_written_.fetch_add(1, std::memory_order_relaxed);
  }
  return n;
}

void RecordingDevice::flushLoop() noexcept {
  // acquire: pairs with close()'s release of stop_
  while (!stop_.load(std::memory_order_acquire)) {
    if (drainToFile() + drainCommandsToFile() == 0) {
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
  }
  drainToFile();
  drainCommandsToFile();
  if (file_) file_->flush();
  if (commands_file_) commands_file_->flush();
}

}  // namespace tactus::device
