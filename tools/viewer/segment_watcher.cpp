// Reading the display part and the stats ring of a running segment for the viewer.
#include "segment_watcher.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <sstream>

#include "tactus/shared/clock.h"
#include "tactus/shared/percentiles.h"

namespace tactus::viewer {
namespace {

constexpr std::int64_t kCheckEveryNs = 250 * shared::kNsPerMs;
constexpr std::int64_t kStallAfterNs = 1500 * shared::kNsPerMs;
constexpr std::size_t kPeriodWindow = 2000;        // ticks in the histogram (2 s at 1 kHz)
constexpr std::int64_t kForceSampleNs = 10 * shared::kNsPerMs;

void putU32(std::string& s, std::uint32_t v) { s.append(reinterpret_cast<const char*>(&v), 4); }
void putF32(std::string& s, double v) {
  const auto f = static_cast<float>(v);
  s.append(reinterpret_cast<const char*>(&f), 4);
}
void putFloats(std::string& s, const float* p, std::size_t n) {
  s.append(reinterpret_cast<const char*>(p), n * sizeof(float));
}

std::string jsonEscape(const std::string& in) {
  std::string out;
  for (char c : in) {
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (static_cast<unsigned char>(c) < 0x20) {
      out += ' ';
    } else {
      out += c;
    }
  }
  return out;
}


}  // namespace

SegmentWatcher::SegmentWatcher(std::string segment_name)
    : name_(std::move(segment_name)), records_(8192) {
  message_ = "waiting for simulation (segment '" + name_ + "')";
}

void SegmentWatcher::attach(std::int64_t now_ns) {
  shared::TryOpenResult r = shared::Segment::tryOpen(name_, shared::Access::kReadOnly);
  if (!r.ok()) {
    if (r.status != shared::OpenStatus::kAbsent && r.status != shared::OpenStatus::kInitializing) {
      message_ = r.message;
    }
    return;
  }
  segment_.emplace(std::move(*r.segment));
  display_ = segment_->displaySubscriber();
  stats_.emplace(segment_->statsReader(shared::StatsRingReader::Start::kNewest));
  ++attach_count_;
  generation_ = segment_->generation();
  attach_ns_ = now_ns;
  shutting_down_ = false;
  last_seq_ = 0;
  last_frame_ns_ = now_ns;
  topology_generation_ = 0;
  step_history_.clear();
  tick_times_.clear();
  period_error_us_.clear();
  force_series_.clear();
  have_stats_ = false;
  if (display_.attached()) {
    const shared::DisplayLayout& l = display_.layout();
    frame_words_.assign(l.frame_bytes / 8 + 1, 0);
    frame_ = shared::DisplayFrameRef(frame_words_.data(), l);
    triangles_.assign(3 * static_cast<std::size_t>(l.capacity.max_triangles) + 2, 0);
    state_ = "running";
    message_ = "attached to segment '" + name_ + "' (generation " + std::to_string(generation_) +
               ")";
  } else {
    state_ = "running";
    message_ = "segment '" + name_ + "' has no display part (older simulation?)";
  }
  std::fprintf(stderr, "tactus-viewer: attached to segment '%s' (generation %llu)\n",
               name_.c_str(), static_cast<unsigned long long>(generation_));
}

void SegmentWatcher::detach(const std::string& why) {
  std::fprintf(stderr, "tactus-viewer: detached: %s\n", why.c_str());
  display_ = {};
  stats_.reset();
  segment_.reset();
  state_ = "stopped";
  message_ = why;
}

void SegmentWatcher::poll(std::int64_t now_ns) {
  // liveness: re-created or removed segment, dead or silent simulation
  if (now_ns >= next_check_ns_) {
    next_check_ns_ = now_ns + kCheckEveryNs;
    if (segment_ && !segment_->stillCurrent()) {
      detach("simulation stopped; waiting for it to restart (segment '" + name_ + "')");
    }
    if (!segment_) attach(now_ns);
    if (segment_ && !segment_->creatorAlive(kStallAfterNs)) {
      if (state_ != "stopped") {
        state_ = "stopped";
        message_ = "simulation not running (no heartbeat); waiting for a restart";
      }
    }
  }
  if (!segment_) return;
  if (display_.attached()) {
    if (display_.topologyGeneration() != topology_generation_) readTopology();
    readFrame(now_ns);
  }
  readStats(now_ns);
  if (segment_->creatorAlive(kStallAfterNs)) {
    if (shutting_down_) {
      state_ = "stopped";
      message_ = "simulation stopping; waiting for a restart";
    } else if (display_.attached() && last_seq_ > 0 && now_ns - last_frame_ns_ > kStallAfterNs) {
      state_ = "stalled";
      message_ = "no new frame for " + std::to_string((now_ns - last_frame_ns_) / shared::kNsPerMs) +
                 " ms";
    } else if (state_ != "running") {
      state_ = "running";
      message_ = "attached to segment '" + name_ + "' (generation " +
                 std::to_string(generation_) + ")";
    }
  }
}

void SegmentWatcher::readTopology() {
  shared::DisplayTopologyHeader h{};
  if (display_.readTopology(&h, triangles_.data()) != shared::DisplayRead::kOk) return;
  topology_generation_ = h.generation;
  std::string m;
  m.reserve(32 + 12 * static_cast<std::size_t>(h.triangle_count));
  putU32(m, kMsgTopology);
  putU32(m, static_cast<std::uint32_t>(h.generation & 0xffffffffu));
  putU32(m, static_cast<std::uint32_t>(h.generation >> 32));
  putU32(m, static_cast<std::uint32_t>(h.vertex_count));
  putU32(m, static_cast<std::uint32_t>(h.triangle_count));
  putU32(m, static_cast<std::uint32_t>(h.tissue_count));
  putU32(m, 0);
  putU32(m, 0);
  m.append(reinterpret_cast<const char*>(triangles_.data()),
           3 * static_cast<std::size_t>(h.triangle_count) * 4);
  topology_msg_ = std::move(m);
  topology_new_ = true;
}

void SegmentWatcher::readFrame(std::int64_t now_ns) {
  if (display_.readFrame(frame_, last_seq_) != shared::DisplayRead::kOk) return;
  const shared::DisplayFrameHeader& h = frame_.header();
  last_seq_ = h.seq;
  last_frame_ns_ = now_ns;
  ++frames_read_;
  frame_new_ = true;
  shutting_down_ = (h.flags & shared::kDisplayShuttingDown) != 0;
  step_history_.emplace_back(h.t_ns, h.step);
  while (step_history_.size() > 2 && step_history_.back().first - step_history_.front().first >
                                         shared::kNsPerS) {
    step_history_.pop_front();
  }
}

void SegmentWatcher::readStats(std::int64_t now_ns) {
  for (std::size_t got; (got = stats_->poll(records_.data(), records_.size())) > 0;) {
    for (std::size_t i = 0; i < got; ++i) {
      const shared::StatsRecord& r = records_[i];
      tick_times_.push_back(r.woken_ns);
      period_error_us_.push_back(1e-3 * static_cast<double>(r.woken_ns - r.scheduled_ns));
      if (r.woken_ns - last_force_sample_ns_ >= kForceSampleNs) {
        last_force_sample_ns_ = r.woken_ns;
        force_series_.emplace_back(shared::nsToSeconds(r.woken_ns), r.force_norm_n);
      }
    }
    newest_ = records_[got - 1];
    have_stats_ = true;
  }
  while (!tick_times_.empty() && now_ns - tick_times_.front() > shared::kNsPerS) {
    tick_times_.pop_front();
  }
  while (period_error_us_.size() > kPeriodWindow) period_error_us_.pop_front();
  while (force_series_.size() > 400) force_series_.pop_front();
}

std::optional<std::string> SegmentWatcher::takeTopologyMessage() {
  if (!topology_new_) return std::nullopt;
  topology_new_ = false;
  return topology_msg_;
}

std::optional<std::string> SegmentWatcher::takeFrameMessage() {
  if (!frame_new_) return std::nullopt;
  frame_new_ = false;
  const shared::DisplayFrameHeader& h = frame_.header();
  const auto v = static_cast<std::size_t>(h.vertex_count);
  const auto c = static_cast<std::size_t>(h.contact_count);
  const auto p = static_cast<std::size_t>(h.tool_primitive_count);
  std::string m;
  m.reserve(4 * (kFrameHeaderWords + 5 * v + 8 * p + 6 * c));
  putU32(m, kMsgFrame);
  putU32(m, static_cast<std::uint32_t>(h.seq & 0xffffffffu));
  putU32(m, static_cast<std::uint32_t>(h.topology_generation & 0xffffffffu));
  putU32(m, static_cast<std::uint32_t>(v));
  putU32(m, static_cast<std::uint32_t>(c));
  putU32(m, static_cast<std::uint32_t>(p));
  putU32(m, h.flags);
  putU32(m, h.tool_type);
  putF32(m, h.sim_time_s);
  putF32(m, h.max_displacement_m);
  putF32(m, h.max_stress_pa);
  putF32(m, h.gripper_opening);
  for (double x : h.tool_pos_m) putF32(m, x);
  for (double x : h.tool_quat_wxyz) putF32(m, x);
  for (double x : h.tool_force_n) putF32(m, x);
  putF32(m, 1e3 * h.step_time_s);
  putU32(m, static_cast<std::uint32_t>(h.step & 0xffffffffu));
  putFloats(m, frame_.positions(), 3 * v);
  putFloats(m, frame_.displacement(), v);
  putFloats(m, frame_.stress(), v);
  for (std::size_t i = 0; i < p; ++i) {
    const shared::DisplayToolPrimitive& q = h.tool_primitives[i];
    putFloats(m, q.a_m.data(), 3);
    putFloats(m, q.b_m.data(), 3);
    putF32(m, q.radius_m);
    putF32(m, static_cast<double>(q.part));
  }
  putFloats(m, frame_.contactPoint(), 3 * c);
  putFloats(m, frame_.contactForce(), 3 * c);
  return m;
}

std::string SegmentWatcher::takeStatusJson(std::int64_t now_ns) {
  std::ostringstream o;
  o.setf(std::ios::fixed);
  o.precision(6);
  const bool attached = segment_.has_value();
  o << "{\"type\":\"status\",\"segment\":\"" << jsonEscape(name_) << "\",\"attached\":"
    << (attached ? "true" : "false") << ",\"state\":\"" << state_ << "\",\"message\":\""
    << jsonEscape(message_) << "\",\"generation\":" << generation_
    << ",\"attach_count\":" << attach_count_ << ",\"frames_read\":" << frames_read_
    << ",\"now_s\":" << shared::nsToSeconds(now_ns);
  // simulation: from the frames
  double sim_hz = 0.0;
  if (step_history_.size() >= 2) {
    const auto& a = step_history_.front();
    const auto& b = step_history_.back();
    if (b.first > a.first) {
      sim_hz = static_cast<double>(b.second - a.second) / shared::nsToSeconds(b.first - a.first);
    }
  }
  const bool have_frame = attached && last_seq_ > 0;
  const shared::DisplayFrameHeader* h = have_frame ? &frame_.header() : nullptr;
  o << ",\"sim\":{\"hz\":" << sim_hz;
  if (h != nullptr) {
    const double f = std::sqrt(h->tool_force_n[0] * h->tool_force_n[0] +
                               h->tool_force_n[1] * h->tool_force_n[1] +
                               h->tool_force_n[2] * h->tool_force_n[2]);
    o << ",\"step\":" << h->step << ",\"time_s\":" << h->sim_time_s
      << ",\"step_ms\":" << 1e3 * h->step_time_s << ",\"contacts\":" << h->contact_count
      << ",\"sweeps\":" << h->solver_sweeps << ",\"force_n\":" << f
      << ",\"frame_seq\":" << h->seq << ",\"frame_age_ms\":"
      << 1e-6 * static_cast<double>(now_ns - h->t_ns)
      << ",\"max_displacement_mm\":" << 1e3 * h->max_displacement_m
      << ",\"max_stress_kpa\":" << 1e-3 * h->max_stress_pa;
  }
  o << "}";
  // haptic loop: from the stats ring
  o << ",\"haptic\":{\"active\":" << (have_stats_ && !tick_times_.empty() ? "true" : "false")
    << ",\"hz\":" << static_cast<double>(tick_times_.size());
  if (have_stats_) {
    std::vector<double> err(period_error_us_.begin(), period_error_us_.end());
    o << ",\"contacts\":" << newest_.contacts << ",\"force_n\":" << newest_.force_norm_n
      << ",\"sweeps\":" << newest_.sweeps << ",\"stale\":"
      << ((newest_.flags & shared::kStatsSnapshotStale) ? "true" : "false")
      << ",\"period_error_us\":{\"p50\":" << shared::percentile(err, 0.5)
      << ",\"p99\":" << shared::percentile(err, 0.99) << ",\"max\":"
      << (err.empty() ? 0.0 : *std::max_element(err.begin(), err.end())) << ",\"n\":"
      << err.size() << ",\"edges\":[";
    constexpr std::size_t kBins = std::size(kPeriodErrorEdgesUs) + 1;
    std::size_t counts[kBins] = {};
    for (double e : err) {
      std::size_t b = 0;
      while (b < kBins - 1 && e > kPeriodErrorEdgesUs[b]) ++b;
      ++counts[b];
    }
    for (std::size_t i = 0; i < std::size(kPeriodErrorEdgesUs); ++i) {
      o << (i ? "," : "") << kPeriodErrorEdgesUs[i];
    }
    o << "],\"counts\":[";
    for (std::size_t i = 0; i < kBins; ++i) o << (i ? "," : "") << counts[i];
    o << "]},\"force_series\":[";
    bool first = true;
    for (const auto& [t, f] : force_series_) {
      o << (first ? "" : ",") << "[" << t << "," << f << "]";
      first = false;
    }
    o << "]";
    force_series_.clear();
  }
  o << "}}";
  return o.str();
}

}  // namespace tactus::viewer
