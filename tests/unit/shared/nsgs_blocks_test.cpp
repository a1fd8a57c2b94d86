// NSGS on W's block storage (DelassusBlocks) against the dense storage, on the same problems: the
// FCLIB set, generated multi-body sphere piles (block-sparse W) and mixed 1-/3-row problems.
// Same status, sweeps (within rounding), relaxations and solution u; the storage holds W exactly;
// the automatic choice follows the block fill; the faults and the no-allocation guarantee hold
// on the block path too.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "tactus/shared/delassus_blocks.h"
#include "tactus/shared/fclib.h"
#include "tactus/shared/nsgs.h"

#include "../../support/alloc_counter.h"
#include "../../support/sphere_pile.h"

namespace tactus::shared {
namespace {

namespace fs = std::filesystem;
using test::DenseProblem;
using test::spherePile;

const fs::path kBlocksFclibDir = fs::path(TACTUS_TEST_DATA_DIR) / "fclib";

std::vector<std::pair<std::string, FclibProblem>> fclibSet() {
  std::vector<fs::path> paths;
  for (const auto& e : fs::directory_iterator(kBlocksFclibDir / "problems"))
    paths.push_back(e.path());
  std::sort(paths.begin(), paths.end());
  std::vector<std::pair<std::string, FclibProblem>> out;
  for (const fs::path& p : paths) out.emplace_back(p.filename().string(), readFclibText(p));
  return out;
}

// Several tissues: `patches` groups of `per_patch` contacts, dense SPD coupling inside a group
// (a smooth kernel of random positions, as one tissue's compliance), none across groups.
DenseProblem tissues(int patches, int per_patch, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  const int nc = patches * per_patch, m = 3 * nc;
  DenseProblem p;
  std::vector<double> px(nc), py(nc);
  for (int i = 0; i < nc; ++i) {
    px[i] = u01(rng);
    py[i] = u01(rng);
    p.row_offset.push_back(3 * (i + 1));
    p.mu.push_back(0.2 + 0.5 * u01(rng));
  }
  p.W.assign(static_cast<std::size_t>(m) * m, 0.0);
  const double s[3][3] = {{1.0, 0.1, 0.0}, {0.1, 0.6, 0.0}, {0.0, 0.0, 0.6}};
  for (int i = 0; i < nc; ++i) {
    for (int j = 0; j < nc; ++j) {
      if (i / per_patch != j / per_patch) continue;
      const double c = std::exp(-std::hypot(px[i] - px[j], py[i] - py[j]) / 0.15) +
                       (i == j ? 0.5 : 0.0);
      for (int a = 0; a < 3; ++a) {
        for (int b = 0; b < 3; ++b) {
          p.W[static_cast<std::size_t>(3 * i + a) * m + 3 * j + b] = c * s[a][b];
        }
      }
    }
  }
  for (int i = 0; i < nc; ++i) {
    const double d2 = (px[i] - 0.5) * (px[i] - 0.5) + (py[i] - 0.5) * (py[i] - 0.5);
    p.q.push_back(-(1.0 - d2 / 0.3));
    p.q.push_back(0.3 * (u01(rng) - 0.5));
    p.q.push_back(0.3 * (u01(rng) - 0.5));
  }
  return p;
}

// 1- and 3-row contacts on several bodies: a random SPD W masked to a block pattern.
DenseProblem mixedRows(unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  DenseProblem p;
  const int kinds[] = {3, 1, 3, 3, 1, 1, 3, 1, 3, 3};
  for (const int k : kinds) {
    p.row_offset.push_back(p.row_offset.back() + k);
    p.mu.push_back(0.4);
  }
  const int nc = p.contacts(), m = p.rows();
  // H: each contact touches body (i % 4) and body ((i + 1) % 4), 6 dof each
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(m, 24);
  for (int i = 0; i < nc; ++i) {
    for (int r = p.row_offset[i]; r < p.row_offset[i + 1]; ++r) {
      for (int d = 0; d < 6; ++d) {
        H(r, 6 * (i % 4) + d) = g(rng);
        if (i % 3 != 0) H(r, 6 * ((i + 1) % 4) + d) = g(rng);
      }
    }
  }
  const Eigen::MatrixXd W = H * H.transpose() + 0.1 * Eigen::MatrixXd::Identity(m, m);
  p.W.resize(static_cast<std::size_t>(m) * m);
  for (int r = 0; r < m; ++r) {
    for (int c = 0; c < m; ++c) p.W[static_cast<std::size_t>(r) * m + c] = W(r, c);
    p.q.push_back(g(rng));
  }
  return p;
}

struct SolvedOnBlocks {
  NsgsResult result;
  std::vector<double> f, u;
};

SolvedOnBlocks run(const ContactProblemView& v, const NsgsSettings& s,
                   std::vector<double> warm = {}) {
  SolvedOnBlocks out;
  out.f = warm.empty() ? std::vector<double>(v.rows, 0.0) : std::move(warm);
  NsgsWorkspace ws(v.rows, v.contacts);
  out.result = solveNsgs(v, s, ws, out.f.data());
  out.u.assign(ws.delta.begin(), ws.delta.begin() + v.rows);
  return out;
}

// max |u_a - u_b| / max(|u|, |q|, 1e-300)
double uDiff(const std::vector<double>& a, const std::vector<double>& b, const double* q) {
  double diff = 0.0, scale = 1e-300;
  for (std::size_t k = 0; k < a.size(); ++k) {
    diff = std::max(diff, std::abs(a[k] - b[k]));
    scale = std::max({scale, std::abs(a[k]), std::abs(b[k]), std::abs(q[k])});
  }
  return diff / scale;
}

// Dense and block storage of the same problem: same outcome.
void expectSameOnBothStorages(const std::string& name, const ContactProblemView& dense,
                              NsgsSettings s, int* compared) {
  DelassusBlocks blocks(dense.rows, dense.contacts, 1.0);
  ASSERT_TRUE(blocks.assign(dense, 1.0)) << name;
  ContactProblemView sparse = dense;
  sparse.blocks = &blocks;
  sparse.W = nullptr;   // the block path must not read the dense W
  const SolvedOnBlocks a = run(dense, s);
  const SolvedOnBlocks b = run(sparse, s);
  SCOPED_TRACE(name + " tol " + std::to_string(s.tolerance));
  EXPECT_EQ(a.result.status, b.result.status);
  // rounding differs (other summation order): a sweep more or less near the tolerance
  EXPECT_LE(std::abs(a.result.sweeps - b.result.sweeps),
            std::max(1, static_cast<int>(0.02 * a.result.sweeps)))
      << a.result.sweeps << " vs " << b.result.sweeps;
  EXPECT_EQ(a.result.relaxations, b.result.relaxations);
  if (a.result.status == NsgsStatus::kConverged) {
    EXPECT_LE(b.result.error, s.tolerance);
    // u is unique; both are within the tolerance of it
    EXPECT_LE(uDiff(a.u, b.u, dense.delta_free), 1e3 * s.tolerance);
    ++*compared;
  }
  // the error function agrees on both storages
  std::vector<double> d1(dense.rows), d2(dense.rows);
  const double e1 = naturalMapError(dense, b.f.data(), d1.data());
  const double e2 = naturalMapError(sparse, b.f.data(), d2.data());
  const double e3 = naturalMapError(sparse, b.f.data());
  EXPECT_NEAR(e1, e2, 1e-12 * std::max(1.0, e1) + 1e-15);
  EXPECT_NEAR(e2, e3, 1e-12 * std::max(1.0, e2) + 1e-15);
  EXPECT_LE(uDiff(d1, d2, dense.delta_free), 1e-13);
}

TEST(NsgsBlocks, StorageHoldsWExactly) {
  for (const DenseProblem& p : {spherePile(60, 2, 0.8, 6), mixedRows(5), tissues(3, 20, 7)}) {
    const ContactProblemView v = p.view();
    DelassusBlocks blocks(v.rows, v.contacts, 1.0);
    ASSERT_TRUE(blocks.assign(v, 1.0));
    const int nc = v.contacts, m = v.rows;
    std::vector<double> rebuilt(static_cast<std::size_t>(m) * m, 0.0);
    int nonzero_blocks = 0;
    std::vector<int> per_column(nc, 0);
    for (int i = 0; i < nc; ++i) {
      const int ri = v.row_offset[i], ki = v.row_offset[i + 1] - ri;
      int previous = -1;
      bool diagonal_seen = false;
      for (int b = blocks.rowStart()[i]; b < blocks.rowStart()[i + 1]; ++b) {
        const int j = blocks.blockColumn()[b];
        EXPECT_GT(j, previous);   // increasing columns
        previous = j;
        diagonal_seen = diagonal_seen || (j == i && blocks.diagonalBlock()[i] == b);
        ++per_column[j];
        const int rj = v.row_offset[j], kj = v.row_offset[j + 1] - rj;
        const double* w = blocks.values() + blocks.valueStart()[b];
        for (int a = 0; a < ki; ++a) {
          for (int c = 0; c < kj; ++c) {
            rebuilt[static_cast<std::size_t>(ri + a) * m + rj + c] = w[a * kj + c];
          }
        }
      }
      EXPECT_TRUE(diagonal_seen) << i;
      for (int j = 0; j < nc; ++j) {
        const int rj = v.row_offset[j], kj = v.row_offset[j + 1] - rj;
        bool nz = false;
        for (int a = 0; a < ki; ++a) {
          for (int c = 0; c < kj; ++c) {
            nz = nz || p.W[static_cast<std::size_t>(ri + a) * m + rj + c] != 0.0;
          }
        }
        nonzero_blocks += (nz || i == j) ? 1 : 0;
      }
    }
    EXPECT_EQ(rebuilt, p.W);                      // every entry, zeros included
    EXPECT_EQ(blocks.blocks(), nonzero_blocks);   // and no zero block besides diagonals
    EXPECT_DOUBLE_EQ(blocks.fill(), static_cast<double>(nonzero_blocks) / (nc * nc));
    // the by-column index lists every block of its column once, with its row
    for (int j = 0; j < nc; ++j) {
      EXPECT_EQ(blocks.columnStart()[j + 1] - blocks.columnStart()[j], per_column[j]);
      for (int t = blocks.columnStart()[j]; t < blocks.columnStart()[j + 1]; ++t) {
        const int b = blocks.columnBlock()[t], i = blocks.columnRow()[t];
        EXPECT_EQ(blocks.blockColumn()[b], j);
        EXPECT_GE(b, blocks.rowStart()[i]);
        EXPECT_LT(b, blocks.rowStart()[i + 1]);
      }
    }
  }
}

// The automatic choice follows the block fill: one tissue (every contact coupled) and small
// FCLIB problems stay dense, several tissues and multi-body piles go to the blocks.
TEST(NsgsBlocks, ChooseStorageFollowsTheBlockFill) {
  struct Case {
    std::string name;
    DenseProblem p;
    bool blocks_expected;
  };
  std::vector<Case> cases;
  cases.push_back({"one tissue", tissues(1, 60, 1), false});
  cases.push_back({"two tissues", tissues(2, 30, 2), false});       // fill 0.5
  cases.push_back({"four tissues", tissues(4, 15, 3), true});       // fill 0.25
  cases.push_back({"pile 60 x 6", spherePile(60, 2, 0.8, 6), true});
  for (const Case& c : cases) {
    const ContactProblemView v = c.p.view();
    DelassusBlocks storage(v.rows, v.contacts);
    const ContactProblemView chosen = chooseStorage(v, storage);
    DelassusBlocks all(v.rows, v.contacts, 1.0);
    ASSERT_TRUE(all.assign(v, 1.0));
    EXPECT_EQ(chosen.blocks != nullptr, c.blocks_expected) << c.name << " fill " << all.fill();
    EXPECT_EQ(storage.holds(), c.blocks_expected) << c.name;
    if (c.blocks_expected) {
      EXPECT_LE(storage.fill(), kBlockSparseMaxFill) << c.name;
    }
    EXPECT_EQ(chosen.W, v.W);   // the dense W stays in the view
  }
  // the FCLIB set: the choice is the fill rule
  for (const auto& [name, p] : fclibSet()) {
    DelassusBlocks storage(p.rows(), p.contacts);
    const ContactProblemView chosen = chooseStorage(p.view(), storage);
    if (chosen.blocks != nullptr) {
      EXPECT_LE(storage.fill(), kBlockSparseMaxFill) << name;
    }
    DelassusBlocks all(p.rows(), p.contacts, 1.0);
    ASSERT_TRUE(all.assign(p.view(), 1.0));
    EXPECT_EQ(chosen.blocks != nullptr, all.fill() <= kBlockSparseMaxFill) << name;
  }
  // too large for the capacity: dense
  const DenseProblem big = spherePile(60, 2, 0.8, 6);
  DelassusBlocks small(big.rows() - 3, big.contacts() - 1);
  EXPECT_EQ(chooseStorage(big.view(), small).blocks, nullptr);
  EXPECT_FALSE(small.holds());
}

// Storage written ahead for larger problems (reserveStorage, the Simulation's set-up) changes
// no choice of chooseStorage and no block it holds, and a reserve() within it allocates
// nothing: mixed 1-/3-row problems (where the value capacity can decide), block-sparse and
// dense ones, the FCLIB set.
TEST(NsgsBlocks, StorageReservedAheadChangesNoChoice) {
  std::vector<std::pair<std::string, DenseProblem>> cases;
  cases.emplace_back("mixed rows", mixedRows(7));
  cases.emplace_back("one tissue", tissues(1, 40, 4));
  cases.emplace_back("four tissues", tissues(4, 15, 3));
  cases.emplace_back("pile 60 x 6", spherePile(60, 2, 0.8, 6));
  std::vector<std::pair<std::string, ContactProblemView>> views;
  for (const auto& [name, p] : cases) views.emplace_back(name, p.view());
  const auto fclib = fclibSet();
  for (const auto& [name, p] : fclib) views.emplace_back(name, p.view());
  for (const auto& [name, v] : views) {
    DelassusBlocks plain(v.rows, v.contacts);
    DelassusBlocks ahead;
    ahead.reserveStorage(4 * v.rows, 4 * v.contacts);
    test::AllocScope scope;
    ahead.reserve(v.rows, v.contacts);
    EXPECT_EQ(scope.allocations(), 0) << name;
    const bool on_blocks = chooseStorage(v, plain).blocks != nullptr;
    ASSERT_EQ(chooseStorage(v, ahead).blocks != nullptr, on_blocks) << name;
    if (!on_blocks) continue;
    ASSERT_EQ(ahead.blocks(), plain.blocks()) << name;
    for (int b = 0; b < plain.blocks(); ++b) {
      ASSERT_EQ(ahead.blockColumn()[b], plain.blockColumn()[b]) << name;
      ASSERT_EQ(ahead.valueStart()[b], plain.valueStart()[b]) << name;
    }
    const int nc = v.contacts;
    const int last = plain.rowStart()[nc] - 1;
    const int lr = plain.rowOffset()[nc] - plain.rowOffset()[nc - 1];
    const int lj = plain.blockColumn()[last];
    const int lc = v.row_offset[lj + 1] - v.row_offset[lj];
    const std::int64_t values = plain.valueStart()[last] + lr * lc;
    for (std::int64_t k = 0; k < values; ++k) {
      ASSERT_EQ(ahead.values()[k], plain.values()[k]) << name;
    }
  }
}

TEST(NsgsBlocks, SameSolutionAndSweepsOnTheFclibSet) {
  int compared = 0;
  for (const auto& [name, p] : fclibSet()) {
    for (const double tol : {1e-6, 1e-10}) {
      NsgsSettings s;
      s.tolerance = tol;
      s.max_sweeps = 5000;
      expectSameOnBothStorages(name, p.view(), s, &compared);
    }
  }
  EXPECT_EQ(compared, 50);
}

TEST(NsgsBlocks, SameSolutionAndSweepsOnGeneratedProblemsForEveryCoupling) {
  std::vector<std::pair<std::string, DenseProblem>> set;
  set.emplace_back("pile 40", spherePile(40, 1, 0.8));
  set.emplace_back("pile 60", spherePile(60, 1, 0.3));
  set.emplace_back("pile 20 mu 2", spherePile(20, 4, 2.0));
  set.emplace_back("mixed rows", mixedRows(5));
  set.emplace_back("four tissues", tissues(4, 15, 3));
  int compared = 0;
  for (const auto& [name, p] : set) {
    for (const NsgsCoupling coupling : {NsgsCoupling::kColumnUpdate, NsgsCoupling::kRowGather,
                                        NsgsCoupling::kSymmetricRowUpdate}) {
      for (const double sor : {1.0, 1.3}) {
        NsgsSettings s;
        s.tolerance = 1e-6;
        s.max_sweeps = 5000;
        s.coupling = coupling;   // every W here is exactly symmetric (H M^-1 H^T, kernels)
        s.sor = sor;
        expectSameOnBothStorages(name + " coupling " + std::to_string(static_cast<int>(coupling)) +
                                     " sor " + std::to_string(sor),
                                 p.view(), s, &compared);
      }
    }
  }
  // all but the mu = 2 pile converge; that one stops at the 5000-sweep cap after the stall rule
  // lowered sor 5-6 times, alike on both storages (status, sweeps, relaxations checked above)
  EXPECT_EQ(compared, 24);
}

// Warm start and the haptic loop's current-delta shortcut on the blocks.
TEST(NsgsBlocks, WarmStartsAndCurrentDeltaOnTheBlocks) {
  DenseProblem p = spherePile(90, 1, 0.3);   // 354 contacts, 4.6 % of the blocks
  const ContactProblemView dense = p.view();
  DelassusBlocks blocks(dense.rows, dense.contacts);
  const ContactProblemView sparse = chooseStorage(dense, blocks);
  ASSERT_NE(sparse.blocks, nullptr);
  NsgsSettings s;
  s.tolerance = 1e-6;
  s.max_sweeps = 5000;
  s.coupling = NsgsCoupling::kSymmetricRowUpdate;
  NsgsWorkspace ws(dense.rows, dense.contacts);
  std::vector<double> f(dense.rows, 0.0);
  const NsgsResult cold = solveNsgs(sparse, s, ws, f.data());
  ASSERT_EQ(cold.status, NsgsStatus::kConverged);
  // unchanged problem, warm: one sweep
  const NsgsResult again = solveNsgs(sparse, s, ws, f.data());
  EXPECT_EQ(again.status, NsgsStatus::kConverged);
  EXPECT_EQ(again.sweeps, 1);
  // shift q, keep delta current by the shift (as the haptic tick does), versus a full entry pass
  std::vector<double> f2 = f;
  NsgsWorkspace ws2(dense.rows, dense.contacts);
  for (int j = 0; j < dense.rows; ++j) {
    const double dq = 1e-3 * std::sin(0.7 * j);
    p.q[j] += dq;
    ws.delta[j] += dq;
  }
  NsgsSettings current = s;
  current.delta_is_current = true;
  const NsgsResult shifted = solveNsgs(sparse, current, ws, f.data());
  const NsgsResult fresh = solveNsgs(sparse, s, ws2, f2.data());
  EXPECT_EQ(shifted.status, NsgsStatus::kConverged);
  EXPECT_EQ(fresh.status, NsgsStatus::kConverged);
  EXPECT_LE(std::abs(shifted.sweeps - fresh.sweeps), 1);
  std::vector<double> u1(ws.delta.begin(), ws.delta.begin() + dense.rows);
  std::vector<double> u2(ws2.delta.begin(), ws2.delta.begin() + dense.rows);
  EXPECT_LE(uDiff(u1, u2, p.q.data()), 1e-5);
}

TEST(NsgsBlocks, FaultsAreTheSameOnTheBlocks) {
  // ill-posed: a zero normal diagonal, held at zero on both storages
  const FclibProblem ill =
      readFclibText(kBlocksFclibDir / "ill_posed" / "zero_normal_diagonal_2c.fc3d.txt");
  DelassusBlocks blocks(ill.rows(), ill.contacts, 1.0);
  ASSERT_TRUE(blocks.assign(ill.view(), 1.0));
  ContactProblemView sparse = ill.view();
  sparse.blocks = &blocks;
  const SolvedOnBlocks a = run(ill.view(), NsgsSettings{});
  const SolvedOnBlocks b = run(sparse, NsgsSettings{});
  EXPECT_EQ(a.result.status, NsgsStatus::kIllPosed);
  EXPECT_EQ(b.result.status, NsgsStatus::kIllPosed);
  EXPECT_EQ(a.result.ill_posed_contacts, b.result.ill_posed_contacts);
  EXPECT_EQ(a.f, b.f);
  // NaN in W: stored (a NaN block is non-zero) and reported as non-finite, f zeroed
  DenseProblem p = spherePile(40, 1, 0.8, 6);
  p.W[5 * p.rows() + 7] = std::numeric_limits<double>::quiet_NaN();
  DelassusBlocks nan_blocks(p.rows(), p.contacts(), 1.0);
  ASSERT_TRUE(nan_blocks.assign(p.view(), 1.0));
  ContactProblemView nan_view = p.view();
  nan_view.blocks = &nan_blocks;
  const SolvedOnBlocks c = run(nan_view, NsgsSettings{}, std::vector<double>(p.rows(), 1.0));
  EXPECT_EQ(c.result.status, NsgsStatus::kNonFinite);
  EXPECT_TRUE(std::all_of(c.f.begin(), c.f.end(), [](double x) { return x == 0.0; }));
  // blocks of another problem (other sizes or row offsets): refused, f untouched
  const DenseProblem other = spherePile(41, 1, 0.8, 6);
  DelassusBlocks other_blocks(other.rows(), other.contacts(), 1.0);
  ASSERT_TRUE(other_blocks.assign(other.view(), 1.0));
  const DenseProblem q = spherePile(40, 2, 0.8, 6);
  ContactProblemView mismatched = q.view();
  mismatched.blocks = &other_blocks;
  const SolvedOnBlocks d = run(mismatched, NsgsSettings{}, std::vector<double>(q.rows(), 2.0));
  EXPECT_EQ(d.result.status, NsgsStatus::kEmpty);
  EXPECT_TRUE(std::all_of(d.f.begin(), d.f.end(), [](double x) { return x == 2.0; }));
  // inconsistent views are not converted
  ContactProblemView broken = q.view();
  broken.ld = broken.rows - 1;
  DelassusBlocks any(q.rows(), q.contacts(), 1.0);
  EXPECT_FALSE(any.assign(broken, 1.0));
  EXPECT_FALSE(any.holds());
}

TEST(NsgsBlocks, ConversionSolveAndErrorNeverAllocate) {
  const DenseProblem p = spherePile(60, 2, 0.8, 6);
  const ContactProblemView dense = p.view();
  DelassusBlocks blocks(dense.rows, dense.contacts);
  NsgsWorkspace ws(dense.rows, dense.contacts);
  std::vector<double> f(dense.rows, 0.0), u(dense.rows);
  NsgsSettings s;
  s.max_sweeps = 50;
  test::AllocScope scope;
  const ContactProblemView sparse = chooseStorage(dense, blocks);
  for (const NsgsCoupling coupling : {NsgsCoupling::kColumnUpdate, NsgsCoupling::kRowGather,
                                      NsgsCoupling::kSymmetricRowUpdate}) {
    s.coupling = coupling;
    std::fill(f.begin(), f.end(), 0.0);
    solveNsgs(sparse, s, ws, f.data());
  }
  naturalMapError(sparse, f.data(), u.data());
  naturalMapError(sparse, f.data());
  EXPECT_EQ(scope.allocations(), 0);
  EXPECT_NE(sparse.blocks, nullptr);
}

}  // namespace
}  // namespace tactus::shared
