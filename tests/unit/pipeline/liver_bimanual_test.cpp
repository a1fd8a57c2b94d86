// scenes/liver_bimanual.yaml: the flat-pad grasper holds and lifts the right
// lobe's tip while a probe presses on the lobe 2.5 cm beside it; both instruments' contacts are
// one contact problem. The grasp holds through the lift (the lobe rises with the jaws, by more
// than half of their rise: held down by the probe it slips partly; measured 12.5 of 19.4 mm, all
// of it without the probe), the probe presses throughout, and lifting the lobe under the probe
// loads the probe (the tissue couples the hands). The live view's frame draws both instruments.
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "../../../sim_server/src/app/display_publisher.h"
#include "../../support/liver_lobe.h"
#include "tactus/shared/segment.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {
namespace {

const std::string kLiverBimanualScene =
    std::string(TACTUS_SOURCE_DIR) + "/scenes/liver_bimanual.yaml";

TEST(LiverBimanualTest, TheGraspLiftsTheLobeWhileTheProbePressesBesideIt) {
  SceneSpec spec = loadScene(kLiverBimanualScene);
  spec.haptics.enabled = false;
  for (auto& t : spec.tissues) t.compliance_cache_dir.clear();
  ASSERT_EQ(instrumentCount(spec), 2);
  Simulation sim(spec);
  const test_support::LiverLobe lobe(sim.tissue(0));
  double lobe_before = 0.0, grasper_before = 0.0, probe_force_before = 0.0;
  double worst_reported_m = 0.0;
  int probe_contact_steps = 0;
  int grasper_contacts_held = 0;
  StepReport r;
  const int steps = static_cast<int>(std::lround(5.8 / spec.time_step_s));
  for (int k = 0; k < steps; ++k) {
    for (int i = 0; i < 2; ++i) sim.setDeviceTarget(i, sim.scriptedTarget(i, sim.time()));
    r = sim.step();
    ASSERT_TRUE(r.finite) << "step " << k;
    worst_reported_m = std::max(worst_reported_m, r.geometric_penetration_m);
    const ContactProblemData& p = sim.lastProblem();
    int per[2] = {0, 0};
    for (int c = 0; c < p.contacts; ++c) ++per[p.contact_instrument[c]];
    if (sim.time() > 3.5) {   // the probe is down
      probe_contact_steps += per[1] > 0 ? 1 : 0;
    }
    if (std::abs(sim.time() - 2.95) < 0.5 * spec.time_step_s) {   // jaws closed, before the lift
      lobe_before = lobe.meanZ();
      grasper_before = sim.instrument(0).pose().pos_m.z();
    }
    if (std::abs(sim.time() - 3.5) < 0.5 * spec.time_step_s) {   // probe down, lift half done
      probe_force_before = r.tool_wrenches[1][2];
    }
    if (sim.time() > 5.7) grasper_contacts_held = per[0];
  }
  const double grasper_rise = sim.instrument(0).pose().pos_m.z() - grasper_before;
  const double lobe_rise = lobe.meanZ() - lobe_before;
  const double probe_force_held = r.tool_wrenches[1][2];
  std::printf("grasper rose %.1f mm, the lobe tip %.1f mm; the probe's upward force %.3f N "
              "half-way up, %.3f N held; grasper force %.3f N; %d grasper contacts; worst "
              "penetration %.3f mm\n",
              1e3 * grasper_rise, 1e3 * lobe_rise, probe_force_before, probe_force_held,
              r.tool_wrenches[0].head<3>().norm(), grasper_contacts_held, 1e3 * worst_reported_m);
  EXPECT_GT(grasper_rise, 0.018);
  EXPECT_GT(lobe_rise, 0.5 * grasper_rise) << "the grasp let the lobe go";
  EXPECT_GT(grasper_contacts_held, 4);
  EXPECT_EQ(probe_contact_steps, static_cast<int>(std::lround((5.8 - 3.5) / spec.time_step_s)))
      << "the probe lost the lobe";
  EXPECT_GT(probe_force_before, 0.1);                          // it presses on the lobe
  EXPECT_GT(probe_force_held, probe_force_before + 0.1);       // the lift pushes the lobe into it
  // (the pads' contact compliance lets them sink by c f_n: the geometric penetration is
  // printed, not bounded by the passes' tolerance here)

  // the live view's frame draws both instruments: the grasper's pads and the probe's shaft
  const std::string name = "tactus_test_" + std::to_string(::getpid()) + "_bimanual_view";
  shared::Segment::remove(name);
  shared::Segment segment = shared::Segment::create(
      name, shared::SegmentCapacity::forContacts(problemContactCapacity(spec), true));
  DisplayLink link(name, sim, DisplayOptions{});
  ASSERT_TRUE(link.enabled());
  ASSERT_TRUE(link.publishNow(sim, &r));
  shared::Segment viewer = shared::Segment::open(name, shared::Access::kReadOnly);
  shared::DisplaySubscriber sub = viewer.displaySubscriber();
  std::vector<std::uint64_t> words(sub.layout().frame_bytes / 8 + 1);
  shared::DisplayFrameRef frame(words.data(), sub.layout());
  ASSERT_EQ(sub.readFrame(frame), shared::DisplayRead::kOk);
  const shared::DisplayFrameHeader& h = frame.header();
  const Eigen::Vector3d grasper = sim.instrument(0).pose().pos_m;
  const Eigen::Vector3d probe = sim.instrument(1).pose().pos_m;
  int near_grasper = 0, near_probe = 0;
  for (int i = 0; i < h.tool_primitive_count; ++i) {
    const auto& q = h.tool_primitives[static_cast<std::size_t>(i)];
    const Eigen::Vector3d a(q.a_m[0], q.a_m[1], q.a_m[2]);
    if ((a - grasper).norm() < 0.03) ++near_grasper;
    if ((a - probe).norm() < 0.035 && std::abs(q.radius_m - 0.004f) < 1e-6f) ++near_probe;
  }
  EXPECT_GT(near_grasper, 0);
  EXPECT_GT(near_probe, 0);
  shared::Segment::remove(name);
}

}  // namespace
}  // namespace tactus::sim
