// The carried warm start across snapshots (shared/warm_start.h).
#include "tactus/shared/warm_start.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <vector>

namespace tactus::shared {
namespace {

struct WarmStartProblem {
  std::vector<std::int32_t> row_offset{0};
  std::vector<std::uint64_t> ids;
  std::vector<double> f_star;
  void add(std::uint64_t id, std::vector<double> f) {
    ids.push_back(id);
    f_star.insert(f_star.end(), f.begin(), f.end());
    row_offset.push_back(static_cast<std::int32_t>(f_star.size()));
  }
  int contacts() const { return static_cast<int>(ids.size()); }
  int rows() const { return static_cast<int>(f_star.size()); }
};

int adopt(SnapshotWarmStart& w, const WarmStartProblem& p, const double* last,
          std::vector<double>& out) {
  out.assign(static_cast<std::size_t>(p.rows()), -99.0);
  return w.adopt(p.contacts(), p.rows(), p.row_offset.data(), p.ids.data(), p.f_star.data(), last,
                 out.data());
}

TEST(SnapshotWarmStart, TheFirstSnapshotStartsFromItsOwnForces) {
  SnapshotWarmStart w(8, 24);
  WarmStartProblem p;
  p.add(7, {1.0, 0.1, 0.2});
  p.add(9, {2.0});
  const std::vector<double> last = {5.0, 5.0, 5.0, 5.0};
  std::vector<double> f;
  EXPECT_EQ(adopt(w, p, last.data(), f), 0);   // nothing remembered yet: nothing carried
  EXPECT_EQ(f, p.f_star);
}

TEST(SnapshotWarmStart, CarriesEachContactsCorrectionByIdentity) {
  SnapshotWarmStart w(8, 24);
  WarmStartProblem a;
  a.add(7, {1.0, 0.1, 0.2});
  a.add(9, {2.0, 0.0, 0.0});
  a.add(4, {0.5});
  std::vector<double> f;
  adopt(w, a, nullptr, f);
  // the loop's converged solve on a: every contact moved from f*
  const std::vector<double> solved = {1.5, 0.3, 0.2, 2.25, -0.1, 0.0, 0.75};
  // b: the contacts in another order, a new one (11), and 4 with friction rows now
  WarmStartProblem b;
  b.add(9, {3.0, 0.0, 0.5});
  b.add(11, {0.4, 0.0, 0.0});
  b.add(7, {1.2, 0.0, 0.0});
  b.add(4, {0.6, 0.0, 0.0});
  EXPECT_EQ(adopt(w, b, solved.data(), f), 2);
  const std::vector<double> expected = {
      3.0 + 0.25, -0.1, 0.5,        // 9: f* + (2.25, -0.1, 0) - (2, 0, 0)
      0.4, 0.0, 0.0,                // 11: new, f*
      1.2 + 0.5, 0.2, 0.0,          // 7: f* + (0.5, 0.2, 0)
      0.6, 0.0, 0.0};               // 4: its rows changed (1 -> 3), f*
  ASSERT_EQ(f.size(), expected.size());
  for (std::size_t r = 0; r < f.size(); ++r) EXPECT_DOUBLE_EQ(f[r], expected[r]) << "row " << r;
}

TEST(SnapshotWarmStart, WithoutAConvergedSolveNothingIsCarried) {
  SnapshotWarmStart w(4, 12);
  WarmStartProblem a;
  a.add(1, {1.0, 0.0, 0.0});
  std::vector<double> f;
  adopt(w, a, nullptr, f);
  WarmStartProblem b;
  b.add(1, {2.0, 0.0, 0.0});
  EXPECT_EQ(adopt(w, b, nullptr, f), 0);
  EXPECT_EQ(f, b.f_star);
}

TEST(SnapshotWarmStart, TheLastSolveMayBeTheOutputArray) {
  SnapshotWarmStart w(4, 12);
  WarmStartProblem a;
  a.add(1, {1.0, 0.0, 0.0});
  a.add(2, {1.0, 0.0, 0.0});
  std::vector<double> f(6);
  w.adopt(a.contacts(), a.rows(), a.row_offset.data(), a.ids.data(), a.f_star.data(), nullptr,
          f.data());
  f = {1.5, 0.1, 0.0, 0.5, 0.0, 0.0};   // the loop's solve, in place
  WarmStartProblem b;                   // the two contacts swapped
  b.add(2, {2.0, 0.0, 0.0});
  b.add(1, {3.0, 0.0, 0.0});
  EXPECT_EQ(w.adopt(b.contacts(), b.rows(), b.row_offset.data(), b.ids.data(), b.f_star.data(),
                    f.data(), f.data()),
            2);
  EXPECT_EQ(f, (std::vector<double>{1.5, 0.0, 0.0, 3.5, 0.1, 0.0}));
}

TEST(SnapshotWarmStart, ACorruptOrOversizedSnapshotIsNeitherCarriedIntoNorRemembered) {
  SnapshotWarmStart w(2, 6);
  WarmStartProblem a;
  a.add(1, {1.0, 0.0, 0.0});
  std::vector<double> f;
  adopt(w, a, nullptr, f);
  const std::vector<double> solved = {2.0, 0.0, 0.0};
  // row offsets that step by 4 rows: f* only, and forgotten
  WarmStartProblem bad;
  bad.add(1, {1.0, 0.0, 0.0, 0.0});
  EXPECT_EQ(adopt(w, bad, solved.data(), f), 0);
  EXPECT_EQ(f, bad.f_star);
  EXPECT_EQ(adopt(w, a, solved.data(), f), 0);   // nothing remembered to carry from
  // more contacts than the capacity: the rows that fit are f*, nothing carried or remembered
  adopt(w, a, nullptr, f);
  WarmStartProblem big;
  for (std::uint64_t id = 1; id <= 3; ++id) big.add(id, {1.0});
  std::vector<double> out(3, -99.0);
  EXPECT_EQ(w.adopt(big.contacts(), big.rows(), big.row_offset.data(), big.ids.data(),
                    big.f_star.data(), solved.data(), out.data()),
            0);
  EXPECT_EQ(out, big.f_star);
  EXPECT_EQ(adopt(w, a, solved.data(), f), 0);
}

TEST(SnapshotWarmStart, ResetForgetsThePreviousSnapshot) {
  SnapshotWarmStart w(4, 12);
  WarmStartProblem a;
  a.add(1, {1.0, 0.0, 0.0});
  std::vector<double> f;
  adopt(w, a, nullptr, f);
  const std::vector<double> solved = {2.0, 0.0, 0.0};
  w.reset();
  EXPECT_EQ(adopt(w, a, solved.data(), f), 0);
  EXPECT_EQ(f, a.f_star);
  EXPECT_EQ(adopt(w, a, solved.data(), f), 1);   // remembered again
  EXPECT_EQ(f, solved);
}

// Many snapshots of many contacts: the open addressing finds every identity (the ids pack
// indices in few bits, as the simulation's do), with no stale hits from older snapshots.
TEST(SnapshotWarmStart, FindsEveryIdentityOverManySnapshots) {
  constexpr int kContacts = 300;
  SnapshotWarmStart w(kContacts, 3 * kContacts);
  std::vector<double> f;
  std::vector<double> solved;
  for (int s = 0; s < 50; ++s) {
    WarmStartProblem p;
    // half the contacts persist (ids 0..149 << 32), half are new each snapshot
    for (int c = 0; c < kContacts; ++c) {
      const std::uint64_t id = c % 2 == 0 ? (static_cast<std::uint64_t>(c) << 32)
                                          : (static_cast<std::uint64_t>(s) << 40) + c;
      p.add(id, {1.0, 0.0, 0.0});
    }
    const int carried = adopt(w, p, s == 0 ? nullptr : solved.data(), f);
    EXPECT_EQ(carried, s == 0 ? 0 : kContacts / 2) << "snapshot " << s;
    solved = f;
    for (std::size_t r = 0; r < solved.size(); r += 3) solved[r] += 0.01;
  }
}

}  // namespace
}  // namespace tactus::shared
