#pragma once
// A real haptic loop on a real shared segment with one frictionless contact below the
// instrument along scene +z (W = w, J = [0 0 1 0 0 0]: moving the instrument up opens the gap),
// for tests of what sits between the device and the local model (workspace mapping, backends).

#include <gtest/gtest.h>
#include <unistd.h>

#include <memory>
#include <optional>
#include <string>

#include "one_contact_problem.h"
#include "tactus/haptic/haptic_loop.h"

namespace tactus::test {

class OneContactRig {
 public:
  OneContactRig(device::Device& device, const haptic::HapticSettings& settings,
                const std::string& tag)
      : name_("tactus_" + tag + "_" + std::to_string(::getpid())) {
    shared::Segment::remove(name_);
    sim_.emplace(shared::Segment::create(name_, shared::SegmentCapacity::forContacts(8, true)));
    publisher_ = sim_->snapshotPublisher();
    samples_.emplace(sim_->deviceReader());
    loop_.emplace(device, settings);
    link_ = std::make_unique<haptic::AttachedSegment>(shared::Segment::open(name_));
    loop_->offerLink(link_.get());
  }
  ~OneContactRig() {
    loop_->offerLink(nullptr);
    loop_->tick(1, 1);   // lets the loop drop the link
    loop_.reset();
    link_.reset();
    samples_.reset();
    sim_.reset();
    shared::Segment::remove(name_);
  }
  OneContactRig(const OneContactRig&) = delete;
  OneContactRig& operator=(const OneContactRig&) = delete;

  /// The contact problem with gap_m when the instrument is at scene height z_star, stamped t_ns.
  void publish(double gap_m, double w_m_per_n, double z_star, std::int64_t t_ns) {
    ASSERT_TRUE(writeOneContactProblem(publisher_.slot(), ++seq_, t_ns, gap_m, w_m_per_n,
                                       {0.0, 0.0, z_star}, 0.0));
    publisher_.publish();
  }

  haptic::HapticLoop& loop() { return *loop_; }
  /// n ticks one millisecond apart, advancing t_ns; the last tick's output.
  haptic::TickOutput tickEveryMs(int n, std::int64_t& t_ns) {
    haptic::TickOutput out;
    for (int i = 0; i < n; ++i) {
      t_ns += 1'000'000;
      out = loop_->tick(t_ns, t_ns);
    }
    return out;
  }
  /// The device sample (scene frame) the simulation received last.
  shared::DeviceSample sample() { return samples_->latest(); }

 private:
  std::string name_;
  std::optional<shared::Segment> sim_;
  shared::SnapshotPublisher publisher_;
  std::optional<shared::TripleReader<shared::DeviceSample>> samples_;
  std::optional<haptic::HapticLoop> loop_;
  std::unique_ptr<haptic::AttachedSegment> link_;
  std::uint64_t seq_ = 0;
};

}  // namespace tactus::test
