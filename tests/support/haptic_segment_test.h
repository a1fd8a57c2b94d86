#pragma once
// The set-up of the haptic loop's tests: a private segment with the simulation's side (sim_,
// publisher_), a haptic loop on a scripted device (loop_, device_, settings_: 5 N clamp, 10 ms
// fade, no slew limit) and its link to the segment offered (link_), and one-contact problems to
// publish.

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "one_contact_problem.h"
#include "scripted_device.h"
#include "tactus/haptic/haptic_loop.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/segment.h"

namespace tactus::test {

// One frictionless contact below the tool along +z: W = w, delta_free = gap + J dx with
// J = [0 0 1 0 0 0] (moving the device up opens the gap).
class HapticSegmentTest : public ::testing::Test {
 protected:
  void SetUp() override {
    name_ = "tactus_haptic_test_" + std::to_string(::getpid());
    shared::Segment::remove(name_);
    sim_.emplace(shared::Segment::create(name_, shared::SegmentCapacity::forContacts(50, true)));
    publisher_ = sim_->snapshotPublisher();
    settings_.max_force_n = 5.0;
    settings_.slew_n_per_s = 1e6;
    settings_.fade_ms = 10.0;
    loop_.emplace(device_, settings_);
    link_ = std::make_unique<haptic::AttachedSegment>(shared::Segment::open(name_));
    loop_->offerLink(link_.get());
  }
  void TearDown() override {
    loop_->offerLink(nullptr);
    t_ += 1'000'000;
    loop_->tick(t_, t_);   // adopts the null offer: the link is no longer in use
    link_.reset();
    sim_.reset();
    shared::Segment::remove(name_);
  }

  // Publishes the one-contact problem with gap_m at device height z_star.
  void publish(double gap_m, double w_m_per_n, double z_star, std::int64_t t_ns = 0) {
    ASSERT_TRUE(writeOneContactProblem(publisher_.slot(), ++seq_, t_ns != 0 ? t_ns : t_, gap_m,
                                       w_m_per_n, {0.0, 0.0, z_star},
                                       std::max(0.0, -gap_m / w_m_per_n)));
    publisher_.publish();
  }

  std::string name_;
  std::optional<shared::Segment> sim_;
  shared::SnapshotPublisher publisher_;
  ScriptedDevice device_;
  haptic::HapticSettings settings_;
  std::optional<haptic::HapticLoop> loop_;
  std::unique_ptr<haptic::AttachedSegment> link_;
  std::uint64_t seq_ = 0;
  std::int64_t t_ = shared::monotonicNs();
};

}  // namespace tactus::test
