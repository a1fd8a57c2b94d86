#pragma once
// The viewer's side of the segment: attaches read-only, follows the display frames and the
// haptic stats ring, re-attaches when the simulation is restarted, and turns what it reads into
// the messages the page understands (binary topology/frame messages, JSON status).
//
// Binary messages (little-endian, 4-byte words, so the page maps them with typed arrays):
//   topology: u32 [kind = 1, generation lo, generation hi, V, T, tissues, 0, 0]
//             then u32 triangles[3T]
//   frame:    u32 [kind = 2, seq lo, topology generation lo, V, C, P, flags, tool type]
//             f32 [sim time s, max displacement m, max stress Pa, gripper opening 0..1,
//                  tool pos xyz m, tool quat wxyz, rendered force xyz N, step time ms]
//             u32 [step lo]                                     (24 header words in all)
//             then f32 positions[3V], displacement[V], stress[V],
//                  primitives[8P] (a xyz, b xyz, radius, part), contact points[3C],
//                  contact forces[3C] (force the tool applies to the tissue, N)
// Status (text): one JSON object, see statusJson().
//
// Not real-time (allocates); it reads the segment without writing to it.

#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <vector>

#include "tactus/shared/display.h"
#include "tactus/shared/segment.h"

namespace tactus::viewer {

inline constexpr std::uint32_t kMsgTopology = 1;
inline constexpr std::uint32_t kMsgFrame = 2;
inline constexpr int kFrameHeaderWords = 24;

/// Histogram bins of the haptic period error (wake - deadline) [us]: upper edges; the last bin
/// is open.
inline constexpr double kPeriodErrorEdgesUs[] = {1, 2, 5, 10, 20, 50, 100, 200, 500, 1000};

class SegmentWatcher {
 public:
  explicit SegmentWatcher(std::string segment_name);

  /// Attaches / re-attaches as needed and reads what is new. Call at the frame rate.
  void poll(std::int64_t now_ns);

  /// A topology message when the topology changed (or after a re-attach) since the last call.
  std::optional<std::string> takeTopologyMessage();
  /// The last topology message (for a client that connects later); empty when none.
  const std::string& topologyMessage() const { return topology_msg_; }
  /// A frame message when a new frame was read since the last call.
  std::optional<std::string> takeFrameMessage();
  /// The status JSON at `now_ns`; hands over the haptic force samples gathered since the last
  /// call.
  std::string takeStatusJson(std::int64_t now_ns);

  bool attached() const { return segment_.has_value(); }
  std::uint64_t framesRead() const { return frames_read_; }
  std::uint64_t attachCount() const { return attach_count_; }

 private:
  void attach(std::int64_t now_ns);
  void detach(const std::string& why);
  void readTopology();
  void readFrame(std::int64_t now_ns);
  void readStats(std::int64_t now_ns);

  std::string name_;
  std::optional<shared::Segment> segment_;
  shared::DisplaySubscriber display_;
  std::optional<shared::StatsRingReader> stats_;
  std::int64_t next_check_ns_ = 0;
  std::string state_ = "waiting";             ///< waiting | running | stalled | stopped
  std::string message_;                       ///< shown on the page
  std::uint64_t attach_count_ = 0;
  std::uint64_t generation_ = 0;
  bool shutting_down_ = false;

  // display
  std::vector<std::uint64_t> frame_words_;
  shared::DisplayFrameRef frame_;
  std::vector<std::uint32_t> triangles_;
  std::uint64_t topology_generation_ = 0;
  std::string topology_msg_;
  bool topology_new_ = false;
  std::uint64_t last_seq_ = 0;
  bool frame_new_ = false;
  std::uint64_t frames_read_ = 0;
  std::int64_t last_frame_ns_ = 0;            ///< when the last new frame was read
  std::deque<std::pair<std::int64_t, std::uint64_t>> step_history_;  ///< (t_ns, step)

  // haptic stats
  std::vector<shared::StatsRecord> records_;
  std::deque<std::int64_t> tick_times_;       ///< woken_ns of the last second's ticks
  std::deque<double> period_error_us_;        ///< last kWindow ticks
  std::deque<std::pair<double, double>> force_series_;  ///< (t s since attach, |F| N), new
  std::int64_t last_force_sample_ns_ = 0;
  shared::StatsRecord newest_{};
  bool have_stats_ = false;
  std::int64_t attach_ns_ = 0;
};

}  // namespace tactus::viewer
