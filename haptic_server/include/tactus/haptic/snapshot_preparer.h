#pragma once
// Prepares each new contact snapshot for the haptic tick off the real-time thread (docs/design.md
// section 4, "The tick's deadline"): copies and checks it, chooses W's storage, finds the reach,
// solves and linearises it (SnapshotPreparation, local_model.h), and hands the tick a ready
// PreparedSnapshot through a wait-free triple buffer. The tick never waits and never touches the
// segment's snapshot slots.
//
// Two ways to run it:
//  - start(settings): a thread polls the subscriber every kPollNs and prepares each new snapshot
//    (haptic_server, tactus-jitter). It owns the subscriber from then on.
//  - without start(): the tick itself calls prepareNewest() before latest() (tests, offline
//    tools driving tick() by hand; then the tick does the preparation's work, not real-time).
//
// The tick publishes its devices' latest poses (publishPoses, wait-free); the preparation solves
// and linearises each snapshot at them, so the tick evaluates the model close to where it was
// prepared. The thread waits (at most kFreshPoseWaitNs) for poses a tick read after a new
// snapshot arrived, not the ones read a tick before it (docs/design.md, "The preparation's
// poses").

#include <array>
#include <atomic>
#include <cstdint>
#include <thread>

#include "tactus/haptic/local_model.h"
#include "tactus/shared/messages.h"
#include "tactus/shared/triple_buffer.h"

namespace tactus::haptic {

class SnapshotPreparer {
 public:
  /// Polling period of the preparer thread [ns].
  static constexpr std::int64_t kPollNs = 200'000;
  /// A snapshot is prepared again (requestRelinearization) only after the thread was idle this
  /// many times the last preparation's duration: at most a third of a core.
  static constexpr std::int64_t kRepeatIdleFactor = 2;
  /// The thread prepares a new snapshot at poses the tick read after the snapshot arrived: it
  /// waits for them (polling every kFreshPosePollNs) at most this long [ns], a tick period at
  /// rates from 500 Hz (docs/design.md, "The preparation's poses").
  static constexpr std::int64_t kFreshPoseWaitNs = 2'000'000;
  static constexpr std::int64_t kFreshPosePollNs = 50'000;
  /// Longest wait start() accepts [ns] (a test that must not depend on its thread's scheduling
  /// waits long; the daemons use kFreshPoseWaitNs).
  static constexpr std::int64_t kMaxFreshPoseWaitNs = 60'000'000'000;

  /// `snapshots` must outlive the preparer. Sizes everything for the capacity (allocates).
  SnapshotPreparer(shared::SnapshotSubscriber& snapshots, int max_rows, int max_contacts);
  ~SnapshotPreparer();
  SnapshotPreparer(const SnapshotPreparer&) = delete;
  SnapshotPreparer& operator=(const SnapshotPreparer&) = delete;

  /// SCHED_FIFO priority the preparer thread asks for: the lowest, above every normal thread
  /// (the simulation's included) and below the real-time loop, so a loaded machine does not make
  /// the prepared snapshots stale; its work is bounded (a preparation per snapshot, repeats at
  /// most a third of a core). Refused without the right: it runs as a normal thread.
  static constexpr int kFifoPriority = 1;

  /// Starts the preparer thread with these settings (validated; throws tactus::Error) at
  /// `fifo_priority` (0: a normal thread), waiting at most `fresh_pose_wait_ns` for fresh poses
  /// (0 to kMaxFreshPoseWaitNs, else throws tactus::Error; stop() ends a wait at once). Not
  /// real-time. Idempotent.
  void start(const LocalModelSettings& settings, int fifo_priority = kFifoPriority,
             std::int64_t fresh_pose_wait_ns = kFreshPoseWaitNs);
  /// Stops and joins the thread (idempotent; the destructor calls it).
  void stop() noexcept;
  bool threaded() const noexcept { return thread_.joinable(); }

  /// Prepares the newest snapshot if the simulation published one since the last call (or the
  /// current one again, at the newest poses, after requestRelinearization()), and publishes it
  /// to latest(). Returns true when it prepared one. Not real-time; call it from
  /// one thread only (the preparer thread when started, else the tick).
  /// `from_thread`: the preparer thread's call, which also honours requestRelinearization()
  /// and, before preparing a new snapshot, waits (at most the wait given to start()) for poses the tick
  /// read after it arrived. A tick preparing inline does neither (it cannot wait for itself, and
  /// a test's tick prepares only new snapshots).
  bool prepareNewest(const LocalModelSettings& settings, bool from_thread = false) noexcept;

  /// The tick: the newest prepared snapshot (seq() 0 before the first); `fresh` tells whether
  /// it is new since the last call. Unchanged until the next call. Wait-free.
  const PreparedSnapshot* latest(bool* fresh) noexcept;

  /// The tick: its devices' poses (nullptr: none), for the next preparation, and when they were
  /// read (CLOCK_MONOTONIC, shared::monotonicNs(); 0: now). Wait-free.
  void publishPoses(DevicePoses poses, std::int64_t read_ns = 0) noexcept;
  /// The tick: the linearisation did not hold; prepare the current snapshot again at the
  /// newest poses when no new snapshot is waiting (wait-free: one relaxed store).
  void requestRelinearization() noexcept {
    relinearize_.store(true, std::memory_order_relaxed);
  }

  /// Snapshots prepared, and the last preparation's wall time [ns] (any thread, relaxed).
  std::uint64_t prepared() const noexcept { return prepared_count_.load(std::memory_order_relaxed); }
  std::int64_t lastPrepareNs() const noexcept {
    return last_prepare_ns_.load(std::memory_order_relaxed);
  }

 private:
  struct PoseHint {
    std::int32_t count = 0;
    std::int64_t read_ns = 0;   ///< when the tick read them (0: never published)
    std::array<std::int32_t, shared::kMaxInstruments> have{};
    std::array<shared::PoseSample, shared::kMaxInstruments> pose{};
  };

  shared::SnapshotSubscriber& snapshots_;
  SnapshotPreparation preparation_;
  std::array<PreparedSnapshot, 3> slots_;
  // hand-over of slot indices: each triple-buffer slot holds its own index (0, 1, 2)
  shared::TripleBufferStorage handoff_;
  shared::TripleBufferWriter handoff_writer_;
  shared::TripleBufferReader handoff_reader_;
  shared::TripleBufferStorage hints_;
  shared::TripleWriter<PoseHint> hint_writer_;
  shared::TripleReader<PoseHint> hint_reader_;
  std::uint64_t last_seq_ = 0;
  std::atomic<bool> relinearize_{false};
  std::int64_t last_end_ns_ = 0;   ///< when the last preparation ended (the thread's)
  std::atomic<std::uint64_t> prepared_count_{0};
  std::atomic<std::int64_t> last_prepare_ns_{0};
  LocalModelSettings settings_;
  std::int64_t fresh_pose_wait_ns_ = kFreshPoseWaitNs;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace tactus::haptic
