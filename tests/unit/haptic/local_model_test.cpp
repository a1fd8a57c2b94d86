// The local model (haptic_server/include/tactus/haptic/local_model.h): the linearised model
// against the full re-solve, its active-set correction and fallback when the active set changes,
// passivity on a closed path, the preparation's checks of untrusted snapshots, and recorded problems
// of a real grasp.
#include "tactus/haptic/local_model.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <vector>

#include "../../support/alloc_counter.h"
#include "tactus/shared/error.h"
#include "tactus/shared/snapshot_file.h"

namespace tactus::haptic {
namespace {

// A snapshot slot in process memory (ld = capacity rows).
struct Slot {
  shared::SnapshotLayout layout;
  std::vector<unsigned char> bytes;
  explicit Slot(int rows, int contacts)
      : layout(shared::SnapshotLayout::forCapacity(rows, contacts)),
        bytes(layout.total_bytes + 64, 0) {}
  void* base() {
    const auto p = reinterpret_cast<std::uintptr_t>(bytes.data());
    return bytes.data() + ((64 - p % 64) % 64);
  }
  shared::SnapshotWriter writer() { return shared::SnapshotWriter(base(), layout); }
  shared::SnapshotView view() { return writer().view(); }
};

// A snapshot of one instrument with rows m and contacts nc (valid, with J, W symmetric).
void startSnapshot(shared::SnapshotWriter& w, int m, int nc) {
  ASSERT_TRUE(w.setSize(m, nc));
  auto& h = w.header();
  h.seq = 1;
  h.t_ns = 1;
  h.instruments = 1;
  h.flags = shared::kSnapshotValid | shared::kSnapshotHasJacobian | shared::kSnapshotSymmetricW;
}

// Contact c on instrument 0 at x = 1 mm x c: normal +z, tangents x and y.
void setContact(shared::SnapshotWriter& w, int c, double mu) {
  w.contactId()[c] = static_cast<std::uint64_t>(c + 1);
  w.contactInstrument()[c] = 0;
  w.mu()[c] = mu;
  for (int k = 0; k < 3; ++k) {
    w.contactPoint()[3 * c + k] = k == 0 ? 1e-3 * c : 0.0;
    w.contactNormal()[3 * c + k] = k == 2 ? 1.0 : 0.0;
    w.contactTangent()[6 * c + k] = k == 0 ? 1.0 : 0.0;
    w.contactTangent()[6 * c + 3 + k] = k == 1 ? 1.0 : 0.0;
  }
}

// nc frictional contacts under one tool, W = a smooth tissue compliance (positive definite);
// contact c is pressed in by depth(c) [m] (negative: a gap), its tangential free velocity
// slide(c). Normals +z, tangents x and y; the rows move with the device's translation.
template <class Depth, class Slide>
void fillProblem(Slot& slot, int nc, double mu, Depth depth, Slide slide, double range = 4.0) {
  shared::SnapshotWriter w = slot.writer();
  const int m = 3 * nc;
  startSnapshot(w, m, nc);
  const int ld = w.ld();
  for (int c = 0; c <= nc; ++c) w.rowOffset()[c] = 3 * c;
  for (int c = 0; c < nc; ++c) setContact(w, c, mu);
  for (int i = 0; i < m; ++i) {
    for (int j = 0; j < m; ++j) {
      const int ci = i / 3, cj = j / 3;
      const bool same_dir = i % 3 == j % 3;
      w.W()[i * ld + j] =
          same_dir ? 1e-3 * std::exp(-std::abs(ci - cj) / range) + (i == j ? 2e-4 : 0.0) : 0.0;
    }
    const int c = i / 3;
    w.deltaFree()[i] = i % 3 == 0 ? -depth(c) : slide(c) * (i % 3 == 1 ? 1.0 : 0.3);
    w.f()[i] = 0.0;
    // a device translation dx moves the contact's relative velocity by dx (the tissue is still)
    for (int k = 0; k < 6; ++k) {
      w.J()[6 * i + k] = (i % 3 == 0 && k == 2) || (i % 3 == 1 && k == 0) ||
                                 (i % 3 == 2 && k == 1)
                             ? -1.0
                             : 0.0;
    }
  }
}

LocalModelSettings settingsFor(LocalModelKind kind) {
  LocalModelSettings s;
  s.kind = kind;
  s.tolerance = 1e-9;
  s.max_sweeps = 20'000;
  return s;
}

shared::Pose at(double x, double y, double z) {
  shared::Pose p;
  p.pos_m = Eigen::Vector3d(x, y, z);
  return p;
}

double norm3(const std::array<double, 3>& v) { return std::hypot(v[0], v[1], v[2]); }

// The full problem solved at the pose to a tight tolerance (the reference).
LocalModelResult reference(Slot& slot, const shared::Pose& pose) {
  OfflineLocalModel full(slot.layout.max_rows, slot.layout.max_contacts,
                         settingsFor(LocalModelKind::kFull));
  const shared::Pose* poses[] = {&pose};
  EXPECT_EQ(full.adopt(slot.view(), poses), PrepareStatus::kReady);
  const LocalModelResult r = full.solve(poses);
  EXPECT_TRUE(r.converged());
  return r;
}

// Sticking and separated contacts only: the problem is linear on the active set, so the
// linearisation is the full problem's solution wherever the active set holds.
TEST(LocalModelTest, TheLinearisationIsTheFullSolutionWhileTheActiveSetHolds) {
  Slot slot(60, 20);
  fillProblem(slot, 20, 1.0, [](int c) { return c < 15 ? 2e-4 + 1e-5 * c : -1e-4; },
              [](int c) { return 1e-6 * (c % 3 - 1); });
  OfflineLocalModel lin(60, 20, settingsFor(LocalModelKind::kLinearized));
  const shared::Pose origin = at(0, 0, 0);
  const shared::Pose* start[] = {&origin};
  ASSERT_EQ(lin.adopt(slot.view(), start), PrepareStatus::kReady);
  ASSERT_TRUE(lin.prepared().linearized());
  EXPECT_EQ(lin.prepared().slidingContacts(), 0);
  for (const double dz : {-2e-5, -5e-6, 0.0, 1e-5, 4e-5}) {
    const shared::Pose p = at(3e-6, -2e-6, dz);
    const shared::Pose* poses[] = {&p};
    const LocalModelResult r = lin.solve(poses);
    ASSERT_EQ(r.used, LocalModelUsed::kLinearized) << "dz " << dz;
    EXPECT_TRUE(r.converged());
    const LocalModelResult ref = reference(slot, p);
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(r.force_n[0][k], ref.force_n[0][k], 1e-6 * norm3(ref.force_n[0])) << dz;
      EXPECT_NEAR(r.torque_nm[0][k], ref.torque_nm[0][k], 1e-6 * norm3(ref.force_n[0]) * 0.02);
    }
  }
}

// Sliding contacts: the linearisation is first order; within a micrometre its error is far
// below the 2 % the haptic loop is held to.
TEST(LocalModelTest, WithSlidingContactsTheLinearisationIsFirstOrderAccurate) {
  Slot slot(90, 30);
  fillProblem(slot, 30, 0.3, [](int c) { return 1.5e-4 + 2e-6 * c; },
              [](int c) { return 2e-5 * ((c % 5) - 2) + 1e-6; });
  OfflineLocalModel lin(90, 30, settingsFor(LocalModelKind::kLinearized));
  const shared::Pose origin = at(0, 0, 0);
  const shared::Pose* start[] = {&origin};
  ASSERT_EQ(lin.adopt(slot.view(), start), PrepareStatus::kReady);
  ASSERT_TRUE(lin.prepared().linearized());
  EXPECT_GT(lin.prepared().slidingContacts(), 0);
  double worst = 0.0;
  int linear = 0;
  for (int i = 0; i < 20; ++i) {
    const double a = 0.314 * i;
    const shared::Pose p = at(1e-6 * std::cos(a), 1e-6 * std::sin(a), -5e-7 * std::sin(2 * a));
    const shared::Pose* poses[] = {&p};
    const LocalModelResult r = lin.solve(poses);
    ASSERT_TRUE(r.converged());
    if (r.used == LocalModelUsed::kLinearized) ++linear;
    const LocalModelResult ref = reference(slot, p);
    double d2 = 0.0;
    for (int k = 0; k < 3; ++k) d2 += std::pow(r.force_n[0][k] - ref.force_n[0][k], 2);
    worst = std::max(worst, std::sqrt(d2) / norm3(ref.force_n[0]));
  }
  EXPECT_GT(linear, 10);
  EXPECT_LT(worst, 1e-3);
}

// The preparation's Newton step (LocalModelSettings::prepare_coarse_factor): NSGS stops at the
// coarse tolerance and one or more steps on the solution's active set take it to the tight one.
// With sliding, sticking and separated contacts, whatever the coarse factor (0: NSGS alone;
// 1000: an active set the step may not confirm, where NSGS solves on), the prepared solution is
// at least as close to the problem's solution (NSGS to 1e-11) as NSGS's own at the tight
// tolerance, and the ticks render the full problem's force as the linearisation does.
TEST(LocalModelTest, ThePreparationsNewtonStepIsAtLeastAsAccurateAsNsgsAlone) {
  Slot slot(90, 30);
  fillProblem(slot, 30, 0.3, [](int c) { return c < 24 ? 1.5e-4 + 2e-6 * c : -5e-5; },
              [](int c) { return 2e-5 * ((c % 5) - 2) + 1e-6; });
  const shared::Pose origin = at(0, 0, 0);
  const shared::Pose* start[] = {&origin};
  LocalModelSettings exact = settingsFor(LocalModelKind::kFull);
  exact.tolerance = 1e-10;
  exact.prepare_max_sweeps = 100'000;
  OfflineLocalModel solution(90, 30, exact);
  ASSERT_EQ(solution.adopt(slot.view(), start), PrepareStatus::kReady);
  ASSERT_TRUE(solution.prepared().preparedConverged());
  const double* f_exact = solution.prepared().preparedForces();
  auto distance = [&](const OfflineLocalModel& m) {
    double d2 = 0.0;
    for (int r = 0; r < 90; ++r) d2 += std::pow(m.prepared().preparedForces()[r] - f_exact[r], 2);
    return std::sqrt(d2);
  };
  LocalModelSettings alone = settingsFor(LocalModelKind::kLinearized);
  alone.tolerance = 1e-6;
  alone.max_sweeps = 2000;
  alone.prepare_coarse_factor = 0.0;
  OfflineLocalModel nsgs(90, 30, alone);
  ASSERT_EQ(nsgs.adopt(slot.view(), start), PrepareStatus::kReady);
  ASSERT_TRUE(nsgs.prepared().linearized());
  EXPECT_FALSE(nsgs.prepared().preparedPolished());
  EXPECT_GT(nsgs.prepared().slidingContacts(), 0);
  const double nsgs_distance = distance(nsgs);
  for (const double factor : {1.0, 10.0, 1000.0}) {
    LocalModelSettings s = alone;
    s.prepare_coarse_factor = factor;
    OfflineLocalModel model(90, 30, s);
    ASSERT_EQ(model.adopt(slot.view(), start), PrepareStatus::kReady);
    ASSERT_TRUE(model.prepared().preparedConverged()) << factor;
    ASSERT_TRUE(model.prepared().linearized()) << factor;
    if (factor == 1.0) {
      EXPECT_TRUE(model.prepared().preparedPolished());
    }
    EXPECT_LE(distance(model), 1.5 * nsgs_distance + 1e-12) << "factor " << factor;
    for (int i = 0; i < 10; ++i) {
      const double a = 0.628 * i;
      const shared::Pose p = at(1e-6 * std::cos(a), 1e-6 * std::sin(a), -5e-7 * std::sin(2 * a));
      const shared::Pose* poses[] = {&p};
      const LocalModelResult r = model.solve(poses);
      ASSERT_TRUE(r.converged());
      const LocalModelResult ref = reference(slot, p);
      for (int k = 0; k < 3; ++k) {
        EXPECT_NEAR(r.force_n[0][k], ref.force_n[0][k], 1e-3 * norm3(ref.force_n[0]))
            << "factor " << factor << " pose " << i;
      }
    }
  }
  std::printf("distance to the solution: NSGS alone %.3g, with the Newton step as above\n",
              nsgs_distance);
}

// A contact that separates (or closes) changes the active set: the tick falls back to the full
// re-solve, whose force is the full problem's.
TEST(LocalModelTest, ItFallsBackToTheReSolveWhenTheActiveSetChanges) {
  Slot slot(30, 10);
  // contact 9 is 10 um in, its neighbours 0.2 mm (nearly uncoupled); the device lifted by 30 um
  // (delta_free_n = -depth - dz) separates it
  fillProblem(slot, 10, 1.0, [](int c) { return c == 9 ? 1e-5 : 2e-4; },
              [](int) { return 0.0; }, 0.3);
  OfflineLocalModel lin(30, 10, settingsFor(LocalModelKind::kLinearized));
  const shared::Pose origin = at(0, 0, 0);
  const shared::Pose* start[] = {&origin};
  ASSERT_EQ(lin.adopt(slot.view(), start), PrepareStatus::kReady);
  ASSERT_TRUE(lin.prepared().linearized());
  EXPECT_EQ(lin.prepared().contactStates()[9], ContactState::kSticking);
  const shared::Pose small = at(0, 0, -2e-6);
  const shared::Pose* p1[] = {&small};
  EXPECT_EQ(lin.solve(p1).used, LocalModelUsed::kLinearized);
  const shared::Pose lifted = at(0, 0, -3e-5);
  const shared::Pose* p2[] = {&lifted};
  const LocalModelResult ref = reference(slot, lifted);
  // the active-set correction: contact 9 separates, the others stay; the linear system of that
  // active set is the full problem's
  const LocalModelResult c = lin.solve(p2);
  EXPECT_EQ(c.used, LocalModelUsed::kCorrected);
  EXPECT_EQ(c.fallback, FallbackReason::kContactLifts);
  EXPECT_EQ(c.corrected_contacts, 1);
  ASSERT_TRUE(c.converged());
  EXPECT_EQ(lin.model().forces()[27], 0.0);
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(c.force_n[0][k], ref.force_n[0][k], 1e-6 * norm3(ref.force_n[0]));
  }
  // without it, the re-solve
  lin.settings().active_set_correction = false;
  const LocalModelResult r = lin.solve(p2);
  EXPECT_EQ(r.used, LocalModelUsed::kFallback);
  ASSERT_TRUE(r.converged());
  EXPECT_EQ(lin.model().forces()[27], 0.0);   // contact 9 separated
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(r.force_n[0][k], ref.force_n[0][k], 1e-6 * norm3(ref.force_n[0]));
  }
  // out of the linearisation's range: fallback as well
  lin.settings().max_translation_m = 1e-6;
  const shared::Pose far = at(2e-6, 0, 0);
  const shared::Pose* p3[] = {&far};
  EXPECT_EQ(lin.solve(p3).used, LocalModelUsed::kFallback);
}

// Every contact lifts at once, more than the active-set correction changes: the tick falls back
// to the re-solve, which finds no force.
TEST(LocalModelTest, TheCorrectionFallsBackWhenTooManyContactsChange) {
  constexpr int kContacts = kMaxCorrectedContacts + 4;
  Slot slot(3 * kContacts, kContacts);
  fillProblem(slot, kContacts, 1.0, [](int) { return 1e-4; }, [](int) { return 0.0; }, 0.3);
  OfflineLocalModel lin(3 * kContacts, kContacts, settingsFor(LocalModelKind::kLinearized));
  const shared::Pose origin = at(0, 0, 0);
  const shared::Pose* start[] = {&origin};
  ASSERT_EQ(lin.adopt(slot.view(), start), PrepareStatus::kReady);
  ASSERT_TRUE(lin.prepared().linearized());
  EXPECT_EQ(lin.prepared().activeRows(), 3 * kContacts);
  const shared::Pose off = at(0, 0, -3e-4);
  const shared::Pose* poses[] = {&off};
  const LocalModelResult r = lin.solve(poses);
  EXPECT_EQ(r.used, LocalModelUsed::kFallback);
  EXPECT_EQ(r.fallback, FallbackReason::kContactLifts);
  ASSERT_TRUE(r.converged());
  EXPECT_EQ(norm3(r.force_n[0]), 0.0);
}

// Two normal-only contacts under one tool (W in N^-1 m, rows moving with the device's z): L is
// pressed in by 10 um and lifts as the device rises; S is open by 20 um, held open by L's force
// (W_SL < 0), and closes at 1 m/m of rise once L has lifted, five times faster than while L
// pushes on it (the linearisation's closing rate).
void fillLiftAndClose(Slot& slot) {
  shared::SnapshotWriter w = slot.writer();
  startSnapshot(w, 2, 2);
  const int ld = w.ld();
  const double W[2][2] = {{1e-3, -0.8e-3}, {-0.8e-3, 1e-3}};
  const double q[2] = {-1e-5, 2.8e-5};
  const double dq_dz[2] = {1.0, -1.0};
  for (int c = 0; c < 2; ++c) {
    w.rowOffset()[c] = c;
    setContact(w, c, 0.0);
    for (int j = 0; j < 2; ++j) w.W()[c * ld + j] = W[c][j];
    w.deltaFree()[c] = q[c];
    w.f()[c] = 0.0;
    for (int k = 0; k < 6; ++k) w.J()[6 * c + k] = k == 2 ? dq_dz[c] : 0.0;
  }
  w.rowOffset()[2] = 2;
}

// The reduced fallback solves the contacts the displacement can load; one left out that closes
// all the same (faster than the linearisation says, once the active set has changed) is found by
// the check and taken in. Either way the force is the full problem's.
TEST(LocalModelTest, TheReducedFallbackTakesInAContactLeftOutThatCloses) {
  Slot slot(2, 2);
  fillLiftAndClose(slot);
  OfflineLocalModel lin(2, 2, settingsFor(LocalModelKind::kLinearized));
  lin.settings().active_set_correction = false;
  const shared::Pose origin = at(0, 0, 0);
  const shared::Pose* start[] = {&origin};
  ASSERT_EQ(lin.adopt(slot.view(), start), PrepareStatus::kReady);
  ASSERT_TRUE(lin.prepared().linearized());
  ASSERT_EQ(lin.prepared().orderedCount(), 2);
  EXPECT_EQ(lin.prepared().orderedContacts()[0], 0);   // L, loaded
  EXPECT_EQ(lin.prepared().orderedReach()[0], 0.0);
  // S: open by 2e-5 at the solution, closing at 1 - 0.8 = 0.2 m/m while L is loaded
  EXPECT_NEAR(lin.prepared().orderedReach()[1], 1e-4, 1e-9);
  struct Case {
    double z_m;
    int solved_contacts;
    bool s_loaded;
  };
  // 15 um: L has lifted, S still open, left out; 35 um: S (2.8e-5 - z) has closed, taken in
  for (const Case c : {Case{1.5e-5, 1, false}, Case{3.5e-5, 2, true}}) {
    SCOPED_TRACE(c.z_m);
    ASSERT_LT(kReducedReachFactor * c.z_m, lin.prepared().orderedReach()[1]);   // S left out
    const shared::Pose p = at(0, 0, c.z_m);
    const shared::Pose* poses[] = {&p};
    const LocalModelResult r = lin.solve(poses);
    EXPECT_EQ(r.used, LocalModelUsed::kFallback);
    EXPECT_EQ(r.fallback, FallbackReason::kContactLifts);
    ASSERT_TRUE(r.converged());
    EXPECT_EQ(r.solved_contacts, c.solved_contacts);
    EXPECT_EQ(lin.model().forces()[0], 0.0);
    EXPECT_EQ(lin.model().forces()[1] > 0.0, c.s_loaded);
    const LocalModelResult ref = reference(slot, p);
    EXPECT_EQ(ref.force_n[0][2] > 0.0, c.s_loaded);
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(r.force_n[0][k], ref.force_n[0][k], 1e-9 * (1.0 + norm3(ref.force_n[0])));
    }
  }
  // without the reduction the fallback solves both, to the same force
  lin.settings().reduced_fallback = false;
  const shared::Pose p = at(0, 0, 3.5e-5);
  const shared::Pose* poses[] = {&p};
  const LocalModelResult r = lin.solve(poses);
  EXPECT_EQ(r.solved_contacts, 2);
  EXPECT_NEAR(r.force_n[0][2], reference(slot, p).force_n[0][2], 1e-9);
}

// The same two contacts with the active-set correction: L lifts (one contact changed), then S
// closes once L has lifted (two), found in the correction's second round. Both active sets are
// linear problems: the corrected force is the full problem's.
// (With W marked symmetric the closing contact's column of W is read along its row; unmarked,
// down the column: the same numbers here.)
TEST(LocalModelTest, TheActiveSetCorrectionFollowsAContactThatLiftsAndOneThatCloses) {
  for (const bool marked_symmetric : {true, false}) {
    SCOPED_TRACE(marked_symmetric);
    Slot slot(2, 2);
    fillLiftAndClose(slot);
    if (!marked_symmetric) {
      slot.writer().header().flags &= ~static_cast<std::uint32_t>(shared::kSnapshotSymmetricW);
    }
    OfflineLocalModel lin(2, 2, settingsFor(LocalModelKind::kLinearized));
    const shared::Pose origin = at(0, 0, 0);
    const shared::Pose* start[] = {&origin};
    ASSERT_EQ(lin.adopt(slot.view(), start), PrepareStatus::kReady);
    ASSERT_TRUE(lin.prepared().linearized());
    struct Case {
      double z_m;
      int changed;
      int rounds;
    };
    for (const Case c : {Case{1.5e-5, 1, 1}, Case{3.5e-5, 2, 2}}) {
      SCOPED_TRACE(c.z_m);
      const shared::Pose p = at(0, 0, c.z_m);
      const shared::Pose* poses[] = {&p};
      const LocalModelResult r = lin.solve(poses);
      EXPECT_EQ(r.used, LocalModelUsed::kCorrected);
      EXPECT_EQ(r.fallback, FallbackReason::kContactLifts);
      EXPECT_EQ(r.corrected_contacts, c.changed);
      EXPECT_EQ(r.correction_rounds, c.rounds);
      ASSERT_TRUE(r.converged());
      EXPECT_EQ(lin.model().forces()[0], 0.0);
      EXPECT_EQ(lin.model().forces()[1] > 0.0, c.changed == 2);
      const LocalModelResult ref = reference(slot, p);
      for (int k = 0; k < 3; ++k) {
        EXPECT_NEAR(r.force_n[0][k], ref.force_n[0][k], 1e-9 * (1.0 + norm3(ref.force_n[0])));
      }
    }
  }
}

// 300 frictional contacts (900 rows, 100 of them loaded): the preparation (solve, inversion of the
// active rows' system, reduced fallback's order) allocates nothing, nor does a tick whose active
// set the correction changes in three contacts (they lift), whose force is the full problem's.
TEST(LocalModelTest, ThePreparationAndACorrectedTickOf900RowsAllocateNothing) {
  Slot slot(900, 300);
  // every third contact pressed in (three of them by 30 um only), the others open by 0.1 mm
  fillProblem(slot, 300, 0.5,
              [](int c) { return c % 3 != 0 ? -1e-4 : c % 99 == 9 ? 3e-5 : 2e-4; },
              [](int) { return 0.0; }, 0.3);
  OfflineLocalModel lin(900, 300, settingsFor(LocalModelKind::kLinearized));
  lin.settings().tolerance = 1e-7;
  const shared::Pose origin = at(0, 0, 0);
  const shared::Pose* start[] = {&origin};
  {
    test::AllocScope scope;
    ASSERT_EQ(lin.adopt(slot.view(), start), PrepareStatus::kReady);
    EXPECT_EQ(scope.allocations(), 0);
  }
  ASSERT_TRUE(lin.prepared().linearized());
  EXPECT_EQ(lin.prepared().activeRows(), 300);
  const shared::Pose lifted = at(0, 0, -4e-5);
  const shared::Pose* poses[] = {&lifted};
  LocalModelResult r;
  {
    test::AllocScope scope;
    r = lin.solve(poses);
    EXPECT_EQ(scope.allocations(), 0);
  }
  EXPECT_EQ(r.used, LocalModelUsed::kCorrected);
  EXPECT_EQ(r.corrected_contacts, 3);
  const LocalModelResult ref = reference(slot, lifted);
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(r.force_n[0][k], ref.force_n[0][k], 1e-5 * norm3(ref.force_n[0]));
  }
}

// Work the contact force does on the instrument around a closed path of the device: a passive
// model gives none back (<= 0, up to the path's discretisation).
double closedPathWork(OfflineLocalModel& model, double radius_m, int steps) {
  double work = 0.0;
  std::array<double, 3> last_f{};
  Eigen::Vector3d last_x;
  for (int i = 0; i <= steps; ++i) {
    const double a = 2.0 * M_PI * i / steps;
    const Eigen::Vector3d x(radius_m * std::sin(a), 0.5 * radius_m * std::sin(2 * a),
                            radius_m * (std::cos(a) - 1.0));
    const shared::Pose p = at(x.x(), x.y(), x.z());
    const shared::Pose* poses[] = {&p};
    const LocalModelResult r = model.solve(poses);
    EXPECT_TRUE(r.converged());
    if (i > 0) {
      for (int k = 0; k < 3; ++k) work += 0.5 * (r.force_n[0][k] + last_f[k]) * (x[k] - last_x[k]);
    }
    last_f = r.force_n[0];
    last_x = x;
  }
  return work;
}

// The tissue at rest (no free sliding): a closed path that only sticks stores and returns the
// same energy (the linear model's stiffness J^T A^-1 J is symmetric); one large enough to make
// contacts slide dissipates. Neither gives energy to the hand, in either model.
TEST(LocalModelTest, TheLinearisedModelIsPassiveOnAClosedPath) {
  Slot slot(90, 30);
  fillProblem(slot, 30, 0.3, [](int c) { return 1.5e-4 + 2e-6 * c; }, [](int) { return 0.0; });
  for (const double radius : {2e-6, 1e-4}) {
    double works[2] = {0.0, 0.0};
    int linearized = 0;
    for (const LocalModelKind kind : {LocalModelKind::kLinearized, LocalModelKind::kFull}) {
      OfflineLocalModel model(90, 30, settingsFor(kind));
      const shared::Pose origin = at(0, 0, 0);
      const shared::Pose* start[] = {&origin};
      ASSERT_EQ(model.adopt(slot.view(), start), PrepareStatus::kReady);
      const shared::Pose* none[] = {&origin};
      const LocalModelResult r0 = model.solve(none);
      if (kind == LocalModelKind::kLinearized) linearized = r0.used == LocalModelUsed::kLinearized;
      const double force = norm3(r0.force_n[0]);
      const double work = closedPathWork(model, radius, 400);
      works[kind == LocalModelKind::kFull] = work;
      // against the scale of the work: force x path length
      EXPECT_LE(work, 1e-6 * force * 2.0 * M_PI * radius) << toString(kind) << " " << radius;
    }
    EXPECT_EQ(linearized, 1);
    std::printf("closed path of radius %.0f um: work linearized %.3g J, full %.3g J\n",
                1e6 * radius, works[0], works[1]);
  }
}

// The preparation reads untrusted memory: offsets, instruments and numbers are checked before
// anything is solved.
TEST(LocalModelTest, ThePreparationRefusesCorruptSnapshots) {
  auto fresh = [] {
    auto slot = std::make_unique<Slot>(30, 10);
    fillProblem(*slot, 10, 0.5, [](int) { return 1e-4; }, [](int) { return 0.0; });
    return slot;
  };
  const shared::Pose origin = at(0, 0, 0);
  const shared::Pose* poses[] = {&origin};
  OfflineLocalModel model(30, 10, settingsFor(LocalModelKind::kAutomatic));
  {
    auto slot = fresh();
    slot->writer().rowOffset()[4] = 13;   // a step of 4 rows
    EXPECT_EQ(model.adopt(slot->view(), poses), PrepareStatus::kInconsistent);
    EXPECT_FALSE(model.solve(poses).solved());
  }
  {
    auto slot = fresh();
    slot->writer().contactInstrument()[3] = 2;   // one instrument only
    EXPECT_EQ(model.adopt(slot->view(), poses), PrepareStatus::kInconsistent);
  }
  {
    auto slot = fresh();
    slot->writer().contactTangent()[7] = std::nan("");   // read only by the wrench
    EXPECT_EQ(model.adopt(slot->view(), poses), PrepareStatus::kNonFinite);
  }
  {
    auto slot = fresh();
    slot->writer().mu()[2] = -0.5;
    EXPECT_EQ(model.adopt(slot->view(), poses), PrepareStatus::kNonFinite);
  }
  {
    auto slot = fresh();
    slot->writer().header().rows = 33;   // beyond the capacity
    EXPECT_EQ(model.adopt(slot->view(), poses), PrepareStatus::kTooLarge);
  }
  {
    auto slot = fresh();
    slot->writer().W()[0] = 0.0;   // a zero diagonal
    EXPECT_EQ(model.adopt(slot->view(), poses), PrepareStatus::kIllPosed);
    EXPECT_FALSE(model.solve(poses).solved());
  }
  auto slot = fresh();
  EXPECT_EQ(model.adopt(slot->view(), poses), PrepareStatus::kReady);
  EXPECT_TRUE(model.solve(poses).converged());
}

TEST(LocalModelTest, SettingsAreValidated) {
  LocalModelSettings s;
  EXPECT_NO_THROW(s.validate());
  s.max_translation_m = -1.0;
  EXPECT_THROW(s.validate(), Error);
  s = {};
  s.tolerance = std::nan("");
  EXPECT_THROW(s.validate(), Error);
  s = {};
  s.prepare_coarse_factor = -1.0;
  EXPECT_THROW(s.validate(), Error);
  EXPECT_EQ(parseLocalModelKind("linearized"), LocalModelKind::kLinearized);
  EXPECT_FALSE(parseLocalModelKind("reduced").has_value());
}

// Recorded problems of liver_grasp's hold (tests/data/haptic): the device displaced by up to
// 0.2 mm about each snapshot's pose in a small circle, as the replay's device moves, and by up to
// 0.5 mm in a larger one, where contacts close and start to slide. The model the tick renders
// (linearised, its active set corrected, re-solve where neither holds) against the full problem
// solved to 1e-9: within 2 % of the held force everywhere.
TEST(LocalModelTest, OnRecordedGraspProblemsTheRenderedForceIsTheFullProblemsWithin2Percent) {
  const std::filesystem::path file =
      std::filesystem::path(TACTUS_TEST_DATA_DIR) / "haptic" / "liver_grasp_hold.snap";
  const std::vector<shared::RecordedSnapshot> snaps = shared::readSnapshotFile(file);
  ASSERT_GE(snaps.size(), 2u);
  int max_rows = 0, max_contacts = 0;
  for (const auto& s : snaps) {
    max_rows = std::max(max_rows, s.rows());
    max_contacts = std::max(max_contacts, s.contacts());
  }
  const shared::SnapshotLayout layout = shared::SnapshotLayout::forCapacity(max_rows, max_contacts);
  std::vector<unsigned char> bytes(layout.total_bytes + 64);
  auto* base = bytes.data() + ((64 - reinterpret_cast<std::uintptr_t>(bytes.data()) % 64) % 64);
  LocalModelSettings fast = settingsFor(LocalModelKind::kLinearized);
  fast.tolerance = 1e-6;
  fast.max_sweeps = 500;
  OfflineLocalModel model(max_rows, max_contacts, fast);
  OfflineLocalModel full(max_rows, max_contacts, settingsFor(LocalModelKind::kFull));
  // the same preparation without its Newton step (NSGS to the tight tolerance)
  LocalModelSettings alone = fast;
  alone.prepare_coarse_factor = 0.0;
  OfflineLocalModel nsgs(max_rows, max_contacts, alone);
  int linearized = 0, corrected = 0, ticks = 0, polished = 0, sweeps = 0, sweeps_alone = 0;
  double worst = 0.0, worst_corrected = 0.0, worst_alone = 0.0;
  for (std::size_t i = 0; i < snaps.size(); ++i) {
    shared::SnapshotWriter slot(base, layout);
    ASSERT_TRUE(snaps[i].writeTo(slot, i + 1, 1));
    const shared::SnapshotView view = slot.view();
    shared::Pose centre;
    const auto& dp = snaps[i].header.device_pose;
    centre.pos_m = Eigen::Vector3d(dp.pos_m[0], dp.pos_m[1], dp.pos_m[2]);
    centre.rot = Eigen::Quaterniond(dp.quat_wxyz[0], dp.quat_wxyz[1], dp.quat_wxyz[2],
                                    dp.quat_wxyz[3]);
    const shared::Pose* hint[] = {&centre};
    ASSERT_EQ(model.adopt(view, hint), PrepareStatus::kReady);
    ASSERT_EQ(full.adopt(view, hint), PrepareStatus::kReady);
    ASSERT_EQ(nsgs.adopt(view, hint), PrepareStatus::kReady);
    ASSERT_TRUE(model.prepared().preparedConverged());
    polished += model.prepared().preparedPolished() ? 1 : 0;
    sweeps += model.prepared().preparedSweeps();
    sweeps_alone += nsgs.prepared().preparedSweeps();
    for (int k = 0; k < 20; ++k) {
      const double a = 0.6 * k;
      const double radius = k < 10 ? 2e-4 : 5e-4;
      shared::Pose p = centre;
      p.pos_m += Eigen::Vector3d(radius * (std::cos(a) - 1.0), radius * std::sin(a),
                                 -0.5 * radius * (1.0 - std::cos(a)));
      const shared::Pose* poses[] = {&p};
      const LocalModelResult r = model.solve(poses);
      const LocalModelResult ref = full.solve(poses);
      const LocalModelResult ra = nsgs.solve(poses);
      ASSERT_TRUE(ref.converged());
      ASSERT_TRUE(r.converged());
      ASSERT_TRUE(ra.converged());
      double a2 = 0.0;
      for (int j = 0; j < 3; ++j) a2 += std::pow(ra.force_n[0][j] - ref.force_n[0][j], 2);
      worst_alone = std::max(worst_alone, std::sqrt(a2) / std::max(norm3(ref.force_n[0]), 1e-3));
      ++ticks;
      if (r.used == LocalModelUsed::kLinearized) ++linearized;
      double d2 = 0.0;
      for (int j = 0; j < 3; ++j) d2 += std::pow(r.force_n[0][j] - ref.force_n[0][j], 2);
      const double error = std::sqrt(d2) / std::max(norm3(ref.force_n[0]), 1e-3);
      worst = std::max(worst, error);
      if (r.used == LocalModelUsed::kCorrected) {
        ++corrected;
        worst_corrected = std::max(worst_corrected, error);
      }
    }
  }
  EXPECT_LT(worst, 0.02);
  EXPECT_LT(worst_alone, 0.02);
  EXPECT_GT(polished, 0);   // the Newton step is exercised on real problems
  EXPECT_LT(sweeps, sweeps_alone);
  EXPECT_GT(linearized, 0);
  EXPECT_GT(corrected, 0);   // the active-set correction is exercised on real problems
  std::printf("recorded grasp: %d of %d evaluations linearised, %d corrected; worst force error "
              "%.3g %% (corrected %.3g %%; without the preparation's Newton step %.3g %%); %d of "
              "%zu preparations polished, %d sweeps (%d without the step)\n",
              linearized, ticks, corrected, 100.0 * worst, 100.0 * worst_corrected,
              100.0 * worst_alone, polished, snaps.size(), sweeps, sweeps_alone);
}

}  // namespace
}  // namespace tactus::haptic
