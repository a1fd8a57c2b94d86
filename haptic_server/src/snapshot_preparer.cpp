// Per-snapshot preparation off the real-time thread and its wait-free hand-over to the tick.
#include "tactus/haptic/snapshot_preparer.h"

#include <cstring>
#include <string>

#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/shared/rt.h"

namespace tactus::haptic {

SnapshotPreparer::SnapshotPreparer(shared::SnapshotSubscriber& snapshots, int max_rows,
                                   int max_contacts)
    : snapshots_(snapshots),
      preparation_(max_rows, max_contacts),
      slots_{PreparedSnapshot(max_rows, max_contacts), PreparedSnapshot(max_rows, max_contacts),
             PreparedSnapshot(max_rows, max_contacts)},
      handoff_(sizeof(std::int32_t)),
      hints_(sizeof(PoseHint)) {
  for (int i = 0; i < 3; ++i) {
    const std::int32_t index = i;
    std::memcpy(shared::tripleBufferSlot(handoff_.control(), i, handoff_.slotBytes()), &index,
                sizeof(index));
  }
  handoff_writer_ = shared::TripleBufferWriter(handoff_.control(), handoff_.slotBytes());
  handoff_reader_ = shared::TripleBufferReader(handoff_.control(), handoff_.slotBytes());
  hint_writer_ = shared::TripleWriter<PoseHint>(hints_.control());
  hint_reader_ = shared::TripleReader<PoseHint>(hints_.control());
  hint_writer_.publish(PoseHint{});
}

SnapshotPreparer::~SnapshotPreparer() { stop(); }

void SnapshotPreparer::start(const LocalModelSettings& settings, int fifo_priority,
                             std::int64_t fresh_pose_wait_ns) {
  if (thread_.joinable()) return;
  settings.validate();
  if (fresh_pose_wait_ns < 0 || fresh_pose_wait_ns > kMaxFreshPoseWaitNs) {
    throw Error("snapshot preparer: the fresh-pose wait must be 0 to " +
                std::to_string(kMaxFreshPoseWaitNs) + " ns, not " +
                std::to_string(fresh_pose_wait_ns));
  }
  settings_ = settings;
  fresh_pose_wait_ns_ = fresh_pose_wait_ns;
  stop_.store(false, std::memory_order_relaxed);
  thread_ = std::thread([this, fifo_priority] {
    if (fifo_priority > 0) (void)shared::setFifoPriority(fifo_priority);   // best effort
    // relaxed: the stop request only needs to be seen eventually
    while (!stop_.load(std::memory_order_relaxed)) {
      if (!prepareNewest(settings_, true)) {
        shared::sleepUntilNs(shared::monotonicNs() + kPollNs);
      }
    }
  });
}

void SnapshotPreparer::stop() noexcept {
  stop_.store(true, std::memory_order_relaxed);
  if (thread_.joinable()) thread_.join();
}

bool SnapshotPreparer::prepareNewest(const LocalModelSettings& settings,
                                     bool from_thread) noexcept {
  if (!snapshots_.attached()) return false;
  shared::SnapshotView snap;
  if (snapshots_.hasNew()) {
    bool fresh = false;
    snap = snapshots_.latest(&fresh);
    if (!fresh || snap.header().seq == 0 || snap.header().seq == last_seq_) return false;
    if (from_thread) {
      // the poses of a tick that read its devices after the snapshot arrived: the ticks that
      // will use this preparation start from there, not from where the hand was a tick ago
      const std::int64_t seen = shared::monotonicNs();
      for (;;) {
        const std::int64_t now = shared::monotonicNs();
        if (hint_reader_.latest().read_ns >= seen || now - seen >= fresh_pose_wait_ns_ ||
            stop_.load(std::memory_order_relaxed)) {
          break;
        }
        shared::sleepUntilNs(now + kFreshPosePollNs);
      }
    }
  } else if (from_thread && relinearize_.load(std::memory_order_relaxed) && last_seq_ != 0 &&
             shared::monotonicNs() - last_end_ns_ >=
                 kRepeatIdleFactor * last_prepare_ns_.load(std::memory_order_relaxed)) {
    // (at most a third of a core: idle twice as long as the last preparation took)
    snap = snapshots_.current();   // unchanged by the writer until our next latest()
    if (snap.header().seq != last_seq_) return false;
  } else {
    return false;
  }
  relinearize_.store(false, std::memory_order_relaxed);
  last_seq_ = snap.header().seq;
  // the tick's latest poses
  const PoseHint& hint = hint_reader_.latest();
  std::array<shared::Pose, shared::kMaxInstruments> poses;
  std::array<const shared::Pose*, shared::kMaxInstruments> pointers{};
  for (int i = 0; i < hint.count && i < shared::kMaxInstruments; ++i) {
    const auto k = static_cast<std::size_t>(i);
    if (hint.have[k] == 0) continue;
    const auto& s = hint.pose[k];
    poses[k].pos_m = Eigen::Vector3d(s.pos_m[0], s.pos_m[1], s.pos_m[2]);
    poses[k].rot = Eigen::Quaterniond(s.quat_wxyz[0], s.quat_wxyz[1], s.quat_wxyz[2],
                                      s.quat_wxyz[3]);
    pointers[k] = &poses[k];
  }
  std::int32_t index = 0;
  std::memcpy(&index, handoff_writer_.buffer(), sizeof(index));
  PreparedSnapshot& out = slots_[static_cast<std::size_t>(index)];
  (void)preparation_.prepare(snap, settings, DevicePoses(pointers.data(), pointers.size()), out);
  handoff_writer_.publish();
  prepared_count_.fetch_add(1, std::memory_order_relaxed);
  last_prepare_ns_.store(out.prepareNs(), std::memory_order_relaxed);
  last_end_ns_ = shared::monotonicNs();
  return true;
}

const PreparedSnapshot* SnapshotPreparer::latest(bool* fresh) noexcept {
  bool took = false;
  const void* slot = handoff_reader_.latest(&took);
  if (fresh != nullptr) *fresh = took;
  std::int32_t index = 0;
  std::memcpy(&index, slot, sizeof(index));
  return &slots_[static_cast<std::size_t>(index)];
}

void SnapshotPreparer::publishPoses(DevicePoses poses, std::int64_t read_ns) noexcept {
  PoseHint& h = hint_writer_.buffer();
  h.read_ns = read_ns > 0 ? read_ns : shared::monotonicNs();
  h.count = static_cast<std::int32_t>(std::min<std::size_t>(poses.size(), shared::kMaxInstruments));
  for (int i = 0; i < h.count; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const shared::Pose* p = poses[k];
    h.have[k] = p != nullptr ? 1 : 0;
    if (p == nullptr) continue;
    h.pose[k].pos_m = {p->pos_m.x(), p->pos_m.y(), p->pos_m.z()};
    h.pose[k].quat_wxyz = {p->rot.w(), p->rot.x(), p->rot.y(), p->rot.z()};
  }
  hint_writer_.publish();
}

}  // namespace tactus::haptic
