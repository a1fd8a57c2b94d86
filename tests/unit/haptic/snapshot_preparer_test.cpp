// The snapshot preparer (haptic_server/include/tactus/haptic/snapshot_preparer.h): its thread
// prepares a new snapshot at poses a tick read after the snapshot arrived.
#include "tactus/haptic/snapshot_preparer.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <thread>

#include "tactus/haptic/local_model.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/shared/triple_buffer.h"

namespace tactus::haptic {
namespace {

constexpr int kPreparerContacts = 4;
constexpr int kPreparerRows = 3 * kPreparerContacts;

// Four frictional contacts under one instrument, pressed in by 0.2-0.5 mm, on a coupled W
// (symmetric, positive definite); a device translation dx moves delta_free by -dx.
void writePreparerSnapshot(shared::SnapshotWriter w) {
  ASSERT_TRUE(w.setSize(kPreparerRows, kPreparerContacts));
  auto& h = w.header();
  h.seq = 1;
  h.t_ns = shared::monotonicNs();
  h.instruments = 1;
  h.flags = shared::kSnapshotValid | shared::kSnapshotHasJacobian | shared::kSnapshotSymmetricW;
  const int ld = w.ld();
  for (int c = 0; c <= kPreparerContacts; ++c) w.rowOffset()[c] = 3 * c;
  for (int c = 0; c < kPreparerContacts; ++c) {
    w.contactId()[c] = static_cast<std::uint64_t>(c + 1);
    w.contactInstrument()[c] = 0;
    w.mu()[c] = 0.5;
    for (int k = 0; k < 3; ++k) {
      w.contactPoint()[3 * c + k] = k == 0 ? 1e-3 * c : 0.0;
      w.contactNormal()[3 * c + k] = k == 2 ? 1.0 : 0.0;
      w.contactTangent()[6 * c + k] = k == 0 ? 1.0 : 0.0;
      w.contactTangent()[6 * c + 3 + k] = k == 1 ? 1.0 : 0.0;
    }
  }
  for (int i = 0; i < kPreparerRows; ++i) {
    for (int j = 0; j < kPreparerRows; ++j) {
      const bool same_dir = i % 3 == j % 3;
      w.W()[i * ld + j] =
          same_dir ? 1e-3 * std::exp(-std::abs(i / 3 - j / 3) / 2.0) + (i == j ? 2e-4 : 0.0)
                   : 0.0;
    }
    const int c = i / 3;
    w.deltaFree()[i] = i % 3 == 0 ? -(2e-4 + 1e-4 * c) : 0.0;
    w.f()[i] = 0.0;
    for (int k = 0; k < 6; ++k) w.J()[6 * i + k] = (i % 3 == k && k < 3) ? -1.0 : 0.0;
  }
}

shared::Pose preparerPose(double z) {
  shared::Pose p;
  p.pos_m = Eigen::Vector3d(0.0, 0.0, z);
  return p;
}

// The replay's device jumps to a new snapshot's pose when the snapshot is published: a
// preparation at the poses published before it arrived would linearise where the hand no longer
// is. The thread waits for a tick that read its device after the snapshot arrived. The test waits
// up to 10 s for them (not the daemons' 2 ms), so a loaded machine that delays this thread's next
// "tick" does not decide the outcome.
TEST(SnapshotPreparerTest, TheThreadPreparesANewSnapshotAtPosesReadAfterItArrived) {
  const shared::SnapshotLayout layout =
      shared::SnapshotLayout::forCapacity(kPreparerRows, kPreparerContacts);
  shared::TripleBufferStorage storage(layout.total_bytes);
  shared::TripleBufferWriter writer(storage.control(), storage.slotBytes());
  shared::SnapshotSubscriber subscriber(storage.control(), layout);
  SnapshotPreparer preparer(subscriber, kPreparerRows, kPreparerContacts);
  const shared::Pose before = preparerPose(0.0);
  const shared::Pose after = preparerPose(-1e-4);   // 0.1 mm further in
  const shared::Pose* before_poses[] = {&before};
  const shared::Pose* after_poses[] = {&after};
  preparer.publishPoses(before_poses, shared::monotonicNs());
  LocalModelSettings settings;
  settings.kind = LocalModelKind::kLinearized;
  preparer.start(settings, 0, 10'000'000'000);
  writePreparerSnapshot(shared::SnapshotWriter(writer.buffer(), layout));
  writer.publish();
  // the next tick, half a tick later: its device has moved with the snapshot
  std::this_thread::sleep_for(std::chrono::microseconds(500));
  preparer.publishPoses(after_poses, shared::monotonicNs());
  const auto give_up = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (preparer.prepared() == 0 && std::chrono::steady_clock::now() < give_up) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  preparer.stop();
  ASSERT_EQ(preparer.prepared(), 1u);
  const PreparedSnapshot* prepared = preparer.latest(nullptr);
  ASSERT_EQ(prepared->status(), PrepareStatus::kReady);
  // the same snapshot prepared offline at each pose
  shared::TripleBufferStorage copy(layout.total_bytes);
  writePreparerSnapshot(shared::SnapshotWriter(tripleBufferSlot(copy.control(), 0,
                                                                copy.slotBytes()),
                                               layout));
  const shared::SnapshotView view(tripleBufferSlot(copy.control(), 0, copy.slotBytes()), layout);
  OfflineLocalModel at_after(kPreparerRows, kPreparerContacts, settings);
  OfflineLocalModel at_before(kPreparerRows, kPreparerContacts, settings);
  ASSERT_EQ(at_after.adopt(view, after_poses), PrepareStatus::kReady);
  ASSERT_EQ(at_before.adopt(view, before_poses), PrepareStatus::kReady);
  double moved = 0.0;
  for (int r = 0; r < kPreparerRows; ++r) {
    const double expected = at_after.prepared().preparedForces()[r];
    EXPECT_NEAR(prepared->preparedForces()[r], expected, 1e-9 + 1e-6 * std::abs(expected))
        << "row " << r;
    moved = std::max(moved, std::abs(expected - at_before.prepared().preparedForces()[r]));
  }
  EXPECT_GT(moved, 1e-3);   // the two poses give different solutions
}

TEST(SnapshotPreparerTest, AFreshPoseWaitOutOfRangeIsRefused) {
  const shared::SnapshotLayout layout =
      shared::SnapshotLayout::forCapacity(kPreparerRows, kPreparerContacts);
  shared::TripleBufferStorage storage(layout.total_bytes);
  shared::SnapshotSubscriber subscriber(storage.control(), layout);
  SnapshotPreparer preparer(subscriber, kPreparerRows, kPreparerContacts);
  LocalModelSettings settings;
  EXPECT_THROW(preparer.start(settings, 0, -1), Error);
  EXPECT_THROW(preparer.start(settings, 0, SnapshotPreparer::kMaxFreshPoseWaitNs + 1), Error);
  EXPECT_FALSE(preparer.threaded());
  preparer.start(settings, 0, 0);
  EXPECT_TRUE(preparer.threaded());
  preparer.stop();
}

}  // namespace
}  // namespace tactus::haptic
