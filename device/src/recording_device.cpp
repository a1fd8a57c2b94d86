#include <chrono>
#include <cstring>

#include "tactus/device/backends.h"
#include "tactus/shared/file_io.h"

namespace tactus::device {

RecordingDevice::RecordingDevice(std::unique_ptr<Device> inner, std::string path,
                                 std::size_t capacity, bool overwrite)
    : inner_(std::move(inner)),
      path_(std::move(path)),
      ring_(std::max<std::size_t>(capacity, 2)),
      overwrite_(overwrite) {}

RecordingDevice::~RecordingDevice() { close(); }

void RecordingDevice::open() {
  if (!file_) {
    try {
      file_ = std::make_unique<shared::OutputFile>(
          path_, "recording",
          shared::OutputOptions{.overwrite = overwrite_,
                                .overwrite_hint = "give device option record_overwrite=1"});
    } catch (const FileError& e) {
      throw DeviceError("cannot record to '" + shared::printable(path_, 256) + "': " + e.what());
    }
    write_error_.clear();
    file_->write(Trajectory::kCsvHeader);
    file_->write("\n");
  }
  inner_->open();
  // the flusher writes the file; read() only fills the ring
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
    try {
      file_->commit();
    } catch (const std::exception& e) {
      try {
        write_error_ = e.what();
      } catch (...) {
        // out of memory: leave the message empty-safe below
      }
      if (write_error_.empty()) write_error_ = "recording failed";
    }
    file_.reset();
  }
  if (inner_) inner_->close();
}

IoStatus RecordingDevice::read(DeviceState* out) noexcept {
  const IoStatus st = inner_->read(out);
  if (st != IoStatus::kOk) return st;
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

std::size_t RecordingDevice::drainToFile() noexcept {
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

void RecordingDevice::flushLoop() noexcept {
  // acquire: pairs with close()'s release of stop_
  while (!stop_.load(std::memory_order_acquire)) {
    if (drainToFile() == 0) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  drainToFile();
  if (file_) file_->flush();
}

}  // namespace tactus::device
