// Contact compliance models: exact against a dense inverse, warped against exact (rest and
// rotated), the disk cache (round trip, stale, corrupt, truncated) and the constrained-motion
// correction's consistency with W.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <filesystem>
#include <fstream>
#include <random>
#include <unistd.h>

#include "tactus/sim/compliance.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/mesh_gen.h"

namespace tactus::sim {
namespace {

/// Options for a model built for time step h, without the progress bar.
ComplianceOptions quietOptions(double h) {
  ComplianceOptions o;
  o.h_s = h;
  o.show_progress = false;
  return o;
}

namespace fs = std::filesystem;

FemMaterial liverMaterial() {
  FemMaterial m;
  m.law = MaterialLaw::kCorotational;
  m.young_pa = 5000.0;
  m.poisson = 0.4;
  m.density_kgpm3 = 1000.0;
  m.damping = RayleighSpec{0.1, 0.01};
  return m;
}

TetMesh liver() {
  TetMesh mesh = loadTetMesh(fs::path(TACTUS_TEST_DATA_DIR) / "meshes" / "liver2.msh");
  transformMesh(mesh, 0.1, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero());  // dm -> m
  return mesh;
}

// Rows n, t1, t2 of `contacts` random contact points on surface triangles built from surface
// nodes (triples of nearby surface nodes are enough for H).
std::vector<TissueRow> randomRows(const FemBody& body, int contacts, unsigned seed) {
  const auto& surf = body.surfaceNodes();
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> pick(0, static_cast<int>(surf.size()) - 1);
  std::uniform_real_distribution<double> unit(0.05, 1.0);
  std::vector<TissueRow> rows;
  for (int c = 0; c < contacts; ++c) {
    std::array<int, 3> nodes{surf[pick(rng)], surf[pick(rng)], surf[pick(rng)]};
    if (nodes[1] == nodes[0]) nodes[1] = -1;
    if (nodes[2] == nodes[0] || nodes[2] == nodes[1]) nodes[2] = -1;
    std::array<double, 3> w{unit(rng), unit(rng), unit(rng)};
    const double sum = w[0] + w[1] + w[2];
    for (double& x : w) x /= sum;
    const Eigen::Vector3d n = Eigen::Vector3d(unit(rng) - 0.5, unit(rng) - 0.5, 1.0).normalized();
    const Eigen::Vector3d t1 = n.unitOrthogonal(), t2 = n.cross(t1);
    for (const Eigen::Vector3d& d : {n, t1, t2}) {
      TissueRow r;
      r.node = nodes;
      r.weight = w;
      r.dir = d;
      rows.push_back(r);
    }
  }
  return rows;
}

// Dense H (m x 3n).
Eigen::MatrixXd denseH(const FemBody& body, const std::vector<TissueRow>& rows) {
  Eigen::MatrixXd h = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(rows.size()),
                                            body.dofCount());
  for (std::size_t k = 0; k < rows.size(); ++k)
    for (int t = 0; t < 3; ++t)
      if (rows[k].node[t] >= 0)
        h.block<1, 3>(static_cast<Eigen::Index>(k), 3 * rows[k].node[t]) +=
            rows[k].weight[t] * rows[k].dir.transpose();
  return h;
}

Eigen::MatrixXd buildW(TissueCompliance& model, const std::vector<TissueRow>& rows) {
  const auto m = static_cast<Eigen::Index>(rows.size());
  Eigen::MatrixXd w = Eigen::MatrixXd::Zero(m, m);
  model.addW(rows, w);
  return w;
}

double relErr(const Eigen::MatrixXd& a, const Eigen::MatrixXd& ref) {
  return (a - ref).norm() / ref.norm();
}

struct TempDir {
  fs::path path = fs::temp_directory_path() /
                  ("tactus_compliance_test_" + std::to_string(::getpid()));
  TempDir() { fs::create_directories(path); }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
};

// Exact compliance against the dense inverse of M/h^2 + K, with K by central differences of the
// elastic force (exact for the linear law).
TEST(Compliance, ExactMatchesDenseInverse) {
  const TetMesh mesh = makeBoxTetMesh(3, 2, 2, Eigen::Vector3d(0.06, 0.04, 0.04));
  FemMaterial mat = liverMaterial();
  mat.law = MaterialLaw::kLinear;
  mat.damping.reset();
  std::vector<int> fixed;
  for (int i = 0; i < mesh.nodeCount(); ++i)
    if (mesh.nodes(0, i) < 1e-12) fixed.push_back(i);
  FemBody body(mesh, mat, fixed, nullptr);
  const double h = 0.02;
  ASSERT_TRUE(body.freeMotion(h).ok);  // at rest: factorises A at the rest shape
  const int n3 = body.dofCount();
  Eigen::MatrixXd k(n3, n3);
  const double eps = 1e-6;
  Eigen::VectorXd fp, fm;
  for (int j = 0; j < n3; ++j) {
    Eigen::VectorXd q = body.restPositions();
    q[j] += eps;
    body.elasticForce(q, fp);
    q[j] -= 2 * eps;
    body.elasticForce(q, fm);
    k.col(j) = -(fp - fm) / (2 * eps);
  }
  Eigen::MatrixXd a = k;
  a.diagonal() += body.lumpedMass() / (h * h);
  // eliminate fixed DOFs
  std::vector<int> free_dofs;
  for (int i = 0; i < body.nodeCount(); ++i)
    if (!body.fixedMask()[i])
      for (int c = 0; c < 3; ++c) free_dofs.push_back(3 * i + c);
  const auto nf = static_cast<Eigen::Index>(free_dofs.size());
  Eigen::MatrixXd af(nf, nf);
  for (Eigen::Index r = 0; r < nf; ++r)
    for (Eigen::Index c = 0; c < nf; ++c) af(r, c) = a(free_dofs[r], free_dofs[c]);
  const Eigen::MatrixXd cf = af.inverse();
  Eigen::MatrixXd c_dense = Eigen::MatrixXd::Zero(n3, n3);
  for (Eigen::Index r = 0; r < nf; ++r)
    for (Eigen::Index c = 0; c < nf; ++c) c_dense(free_dofs[r], free_dofs[c]) = cf(r, c);

  // column by column through solveCompliance
  Eigen::VectorXd e, x;
  for (int j : {3 * 5, 3 * 5 + 1, n3 - 1}) {
    e.setZero(n3);
    e[j] = 1.0;
    body.solveCompliance(e, x);
    EXPECT_LT((x - c_dense.col(j)).norm(), 1e-6 * c_dense.col(j).norm()) << "column " << j;
  }
  // W through the exact model, on rows that include interior and fixed nodes
  auto model = makeCompliance(ComplianceKind::kExact, body, quietOptions(h));
  std::vector<TissueRow> rows;
  for (int node : {0, 5, 11, 23, mesh.nodeCount() - 1}) {
    for (int c = 0; c < 3; ++c) {
      TissueRow r;
      r.node = {node, (node + 7) % mesh.nodeCount(), -1};
      r.weight = {0.7, 0.3, 0.0};
      r.dir = Eigen::Vector3d::Unit(c) + 0.2 * Eigen::Vector3d::Ones();
      rows.push_back(r);
    }
  }
  const Eigen::MatrixXd hm = denseH(body, rows);
  const Eigen::MatrixXd w_ref = hm * c_dense * hm.transpose();
  EXPECT_LT(relErr(buildW(*model, rows), w_ref), 1e-6);
}

class LiverCompliance : public ::testing::Test {
 protected:
  void SetUp() override {
    mesh_ = liver();
    // fix the nodes of the left lobe's tip (lowest x) so the problem is anchored
    std::vector<std::pair<double, int>> by_x;
    for (int i = 0; i < mesh_.nodeCount(); ++i) by_x.emplace_back(mesh_.nodes(0, i), i);
    std::sort(by_x.begin(), by_x.end());
    for (int i = 0; i < 15; ++i) fixed_.push_back(by_x[i].second);
  }
  std::unique_ptr<FemBody> makeBody(const FemMaterial& mat = liverMaterial()) {
    return std::make_unique<FemBody>(mesh_, mat, fixed_, nullptr);
  }
  /// A body after ten steps under a downward load, so its rotations are not trivial.
  std::unique_ptr<FemBody> deformedBody() {
    auto body = makeBody();
    Eigen::VectorXd load = Eigen::VectorXd::Zero(body->dofCount());
    for (int i = 0; i < body->nodeCount(); ++i) load[3 * i + 2] = -0.02;
    for (int s = 0; s < 10; ++s) EXPECT_TRUE(body->freeMotion(h_, &load).ok);
    return body;
  }
  /// Row forces uniform in [-1, 1].
  static Eigen::VectorXd randomForces(std::size_t count, unsigned seed) {
    Eigen::VectorXd f(static_cast<Eigen::Index>(count));
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    for (auto& x : f) x = u(rng);
    return f;
  }
  TetMesh mesh_;
  std::vector<int> fixed_;
  double h_ = 0.01;
};

TEST_F(LiverCompliance, WarpedEqualsExactAtRest) {
  auto body = makeBody();
  ASSERT_TRUE(body->freeMotion(h_).ok);  // from rest, no gravity: stays at rest
  const auto rows = randomRows(*body, 40, 1);
  auto exact = makeCompliance(ComplianceKind::kExact, *body, quietOptions(h_));
  auto warped = makeCompliance(ComplianceKind::kWarped, *body, quietOptions(h_));
  auto rest = makeCompliance(ComplianceKind::kRest, *body, quietOptions(h_));
  exact->update(*body);
  warped->update(*body);
  rest->update(*body);
  const Eigen::MatrixXd w_exact = buildW(*exact, rows);
  EXPECT_GT(w_exact.norm(), 0.0);
  EXPECT_LT(relErr(buildW(*warped, rows), w_exact), 1e-9);
  EXPECT_LT(relErr(buildW(*rest, rows), w_exact), 1e-9);
  // W is symmetric positive definite
  EXPECT_LT((w_exact - w_exact.transpose()).norm(), 1e-12 * w_exact.norm());
  EXPECT_GT(Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(w_exact).eigenvalues().minCoeff(),
            0.0);
  EXPECT_GT(warped->memoryBytes(), sizeof(double) * 9 * body->surfaceNodes().size() *
                                       body->surfaceNodes().size());
  EXPECT_LT(exact->memoryBytes(), warped->memoryBytes());
}

TEST_F(LiverCompliance, WarpedBeatsRestUnderLargeRotation) {
  // no fixed nodes here: a free organ rotated rigidly by 75 degrees about an oblique axis, then
  // squashed a little so the state is not a pure rotation
  fixed_.clear();
  auto body = makeBody();
  const Eigen::Matrix3d rot =
      Eigen::AngleAxisd(75.0 * M_PI / 180.0, Eigen::Vector3d(1, 2, -1).normalized())
          .toRotationMatrix();
  Eigen::Vector3d centre = mesh_.nodes.rowwise().mean();
  const Eigen::Vector3d squash(1.0, 1.0, 0.93);
  for (int i = 0; i < mesh_.nodeCount(); ++i)
    body->positions().segment<3>(3 * i) =
        centre + rot * squash.cwiseProduct(mesh_.nodes.col(i) - centre);
  ASSERT_TRUE(body->freeMotion(h_).ok);
  auto exact = makeCompliance(ComplianceKind::kExact, *body, quietOptions(h_));
  auto warped = makeCompliance(ComplianceKind::kWarped, *body, quietOptions(h_));
  auto rest = makeCompliance(ComplianceKind::kRest, *body, quietOptions(h_));
  auto uncoupled = makeCompliance(ComplianceKind::kUncoupled, *body, quietOptions(h_));
  for (auto* m : {exact.get(), warped.get(), rest.get(), uncoupled.get()}) m->update(*body);
  const auto rows = randomRows(*body, 40, 2);
  const Eigen::MatrixXd w_exact = buildW(*exact, rows);
  const double e_warped = relErr(buildW(*warped, rows), w_exact);
  const double e_rest = relErr(buildW(*rest, rows), w_exact);
  const double e_uncoupled = relErr(buildW(*uncoupled, rows), w_exact);
  RecordProperty("err_warped", std::to_string(e_warped));
  RecordProperty("err_rest", std::to_string(e_rest));
  RecordProperty("err_uncoupled", std::to_string(e_uncoupled));
  EXPECT_LT(e_warped, e_rest);
  EXPECT_LT(e_warped, 0.2);
  EXPECT_GT(e_rest, 0.3);  // rotation by 75 degrees: the rest model is badly wrong
}

// W from C0's blocks is the same, bit for bit, whether the nodes the rows touch were gathered
// by an earlier call (addW keeps the last C_UU) or not: calls whose row sets overlap, grow,
// shrink and change order give a fresh model's W.
TEST_F(LiverCompliance, WarpedWDoesNotDependOnTheCallsBefore) {
  auto body = deformedBody();
  auto kept = makeCompliance(ComplianceKind::kWarped, *body, quietOptions(h_));
  kept->update(*body);
  const auto a = randomRows(*body, 30, 11);
  auto b = randomRows(*body, 20, 12);
  b.insert(b.end(), a.begin(), a.begin() + 45);          // half of a's contacts, after new ones
  const std::vector<TissueRow> c(a.begin() + 30, a.end()); // a subset of a
  const std::array<const std::vector<TissueRow>*, 5> calls = {&a, &b, &c, &a, &b};
  for (const std::vector<TissueRow>* rows : calls) {
    auto fresh = makeCompliance(ComplianceKind::kWarped, *body, quietOptions(h_));
    fresh->update(*body);
    const Eigen::MatrixXd w_fresh = buildW(*fresh, *rows);
    EXPECT_GT(w_fresh.norm(), 0.0);
    EXPECT_EQ(buildW(*kept, *rows), w_fresh);
  }
}

// setWLower (buildW's assembly in place) gives the lower triangle of addW's W into a zero
// matrix bit for bit, for every model, in a column-major block of a larger matrix (W's rows of
// one tissue among others) and over calls whose rows change (the warped model's kept C_UU), and
// writes nothing outside the block.
TEST_F(LiverCompliance, SetWLowerIsAddWsLowerTriangleBitForBit) {
  auto body = deformedBody();
  const auto a = randomRows(*body, 30, 21);
  auto b = randomRows(*body, 12, 22);
  b.insert(b.end(), a.begin(), a.begin() + 36);
  const std::array<const std::vector<TissueRow>*, 3> calls = {&a, &b, &a};
  for (ComplianceKind kind : {ComplianceKind::kExact, ComplianceKind::kWarped,
                              ComplianceKind::kRest, ComplianceKind::kUncoupled}) {
    auto model = makeCompliance(kind, *body, quietOptions(h_));
    auto reference = makeCompliance(kind, *body, quietOptions(h_));
    model->update(*body);
    reference->update(*body);
    for (const std::vector<TissueRow>* rows : calls) {
      const auto m = static_cast<Eigen::Index>(rows->size());
      const Eigen::MatrixXd w_ref = buildW(*reference, *rows);
      Eigen::MatrixXd big = Eigen::MatrixXd::Constant(m + 7, m + 9, -3.5);
      model->setWLower(*rows, big.block(4, 5, m, m));
      const Eigen::MatrixXd got = big.block(4, 5, m, m);
      for (Eigen::Index j = 0; j < m; ++j)
        for (Eigen::Index i = j; i < m; ++i)
          ASSERT_EQ(got(i, j), w_ref(i, j)) << "kind " << static_cast<int>(kind) << " at ("
                                            << i << ", " << j << ")";
      // outside the block: untouched
      Eigen::MatrixXd outside = big;
      outside.block(4, 5, m, m).setConstant(-3.5);
      EXPECT_TRUE((outside.array() == -3.5).all()) << "kind " << static_cast<int>(kind);
    }
  }
}

// setWLower's WColumnsDone (buildW adds the instrument's terms to W's rows as they are
// completed): called for every column once, in order, each group of columns already holding
// its final values from the diagonal down when it is called, for every model; what is added
// there by the callee stays (nothing writes those entries afterwards).
TEST_F(LiverCompliance, SetWLowerReportsEachColumnOnceWhenItIsFinal) {
  auto body = deformedBody();
  const auto rows = randomRows(*body, 30, 23);
  const auto m = static_cast<Eigen::Index>(rows.size());
  struct Seen {
    Eigen::Ref<Eigen::MatrixXd>* w = nullptr;
    Eigen::MatrixXd at_call;   // each column's entries from its diagonal down when reported
    std::vector<int> order;
  };
  for (ComplianceKind kind : {ComplianceKind::kExact, ComplianceKind::kWarped,
                              ComplianceKind::kRest, ComplianceKind::kUncoupled}) {
    auto model = makeCompliance(kind, *body, quietOptions(h_));
    model->update(*body);
    Eigen::MatrixXd big = Eigen::MatrixXd::Constant(m + 7, m + 9, -3.5);
    Eigen::Ref<Eigen::MatrixXd> w = big.block(4, 5, m, m);
    Seen seen;
    seen.w = &w;
    seen.at_call = Eigen::MatrixXd::Zero(m, m);
    const WColumnsDone done{
        [](void* context, int first, int count) {
          auto& s = *static_cast<Seen*>(context);
          for (int c = first; c < first + count; ++c) {
            s.order.push_back(c);
            for (Eigen::Index i = c; i < s.w->rows(); ++i) {
              s.at_call(i, c) = (*s.w)(i, c);
              (*s.w)(i, c) += 1.0;   // a term added there, as buildW adds the instrument's
            }
          }
        },
        &seen};
    model->setWLower(rows, w, done);
    ASSERT_EQ(static_cast<Eigen::Index>(seen.order.size()), m) << "kind " << static_cast<int>(kind);
    for (Eigen::Index c = 0; c < m; ++c) ASSERT_EQ(seen.order[static_cast<std::size_t>(c)], c);
    const Eigen::MatrixXd w_ref = buildW(*model, rows);
    for (Eigen::Index j = 0; j < m; ++j)
      for (Eigen::Index i = j; i < m; ++i) {
        ASSERT_EQ(seen.at_call(i, j), w_ref(i, j))
            << "kind " << static_cast<int>(kind) << " at (" << i << ", " << j << ")";
        ASSERT_EQ(w(i, j), w_ref(i, j) + 1.0)
            << "kind " << static_cast<int>(kind) << " at (" << i << ", " << j << ")";
      }
  }
}

TEST_F(LiverCompliance, CorrectionIsConsistentWithW) {
  auto body = deformedBody();
  const auto rows = randomRows(*body, 30, 3);
  const Eigen::MatrixXd hm = denseH(*body, rows);
  const Eigen::VectorXd f = randomForces(rows.size(), 4);
  for (ComplianceKind kind : {ComplianceKind::kExact, ComplianceKind::kWarped,
                              ComplianceKind::kRest, ComplianceKind::kUncoupled}) {
    auto model = makeCompliance(kind, *body, quietOptions(h_));
    model->update(*body);
    const Eigen::MatrixXd w = buildW(*model, rows);
    Eigen::VectorXd dq;
    model->correction(*body, rows, f.data(), dq);
    ASSERT_EQ(dq.size(), body->dofCount());
    const Eigen::VectorXd lhs = hm * dq, rhs = w * f;
    EXPECT_LT((lhs - rhs).norm(), 1e-8 * rhs.norm()) << "kind " << static_cast<int>(kind);
    for (int i : fixed_) EXPECT_EQ(dq.segment<3>(3 * i).norm(), 0.0);
  }
}

// exact_correction: whatever model builds W, the constrained motion is the exact model's
// dq = C H^T f (and it is not what the approximate W predicts, so the option is observable).
TEST_F(LiverCompliance, ExactCorrectionUsesTheFreeMotionCompliance) {
  auto body = deformedBody();
  const auto rows = randomRows(*body, 30, 3);
  const Eigen::MatrixXd hm = denseH(*body, rows);
  const Eigen::VectorXd f = randomForces(rows.size(), 5);
  auto exact = makeCompliance(ComplianceKind::kExact, *body, quietOptions(h_));
  exact->update(*body);
  Eigen::VectorXd dq_exact;
  exact->correction(*body, rows, f.data(), dq_exact);
  for (ComplianceKind kind : {ComplianceKind::kWarped, ComplianceKind::kRest}) {
    ComplianceOptions opt = quietOptions(h_);
    opt.exact_correction = true;
    auto model = makeCompliance(kind, *body, opt);
    model->update(*body);
    Eigen::VectorXd dq;
    model->correction(*body, rows, f.data(), dq);
    EXPECT_LT((dq - dq_exact).norm(), 1e-10 * dq_exact.norm()) << "kind " << static_cast<int>(kind);
    const Eigen::VectorXd predicted = buildW(*model, rows) * f;
    EXPECT_GT((hm * dq - predicted).norm(), 1e-4 * predicted.norm())
        << "the model's W predicts the exact motion: the case cannot tell the options apart";
  }
}

TEST_F(LiverCompliance, CacheRoundTripStaleCorruptTruncated) {
  TempDir dir;
  ComplianceOptions opt{h_, dir.path, false, "liver", 64};
  auto body = makeBody();
  const auto rows = randomRows(*body, 20, 5);
  const fs::path file = complianceCachePath(*body, opt);
  ASSERT_EQ(file, dir.path / "liver.c0.bin");

  auto first = makeCompliance(ComplianceKind::kWarped, *body, opt);
  EXPECT_FALSE(first->buildInfo().loaded_from_cache);
  EXPECT_GT(first->buildInfo().precompute_s, 0.0);
  ASSERT_TRUE(fs::exists(file));
  const Eigen::MatrixXd w_ref = buildW(*first, rows);

  // round trip: loaded, identical
  auto second = makeCompliance(ComplianceKind::kWarped, *body, opt);
  EXPECT_TRUE(second->buildInfo().loaded_from_cache);
  EXPECT_FALSE(second->buildInfo().cache_rejected);
  EXPECT_EQ(buildW(*second, rows), w_ref);

  // stale: different h, then different material -> rejected and rebuilt (file rewritten)
  {
    ComplianceOptions other = opt;
    other.h_s = 2 * h_;
    auto m = makeCompliance(ComplianceKind::kWarped, *body, other);
    EXPECT_TRUE(m->buildInfo().cache_rejected);
    EXPECT_FALSE(m->buildInfo().loaded_from_cache);
    EXPECT_GT(relErr(buildW(*m, rows), w_ref), 1e-3);
  }
  {
    FemMaterial stiff = liverMaterial();
    stiff.young_pa *= 2;
    auto stiff_body = makeBody(stiff);
    auto m = makeCompliance(ComplianceKind::kWarped, *stiff_body, opt);
    EXPECT_TRUE(m->buildInfo().cache_rejected);
    EXPECT_FALSE(m->buildInfo().loaded_from_cache);
  }
  // file now holds the stiff material's C0: the original body rebuilds and rewrites it
  {
    auto m = makeCompliance(ComplianceKind::kWarped, *body, opt);
    EXPECT_TRUE(m->buildInfo().cache_rejected);
    EXPECT_LT(relErr(buildW(*m, rows), w_ref), 1e-12);
  }
  const auto size = fs::file_size(file);
  // corrupt: one byte of the payload flipped
  {
    std::fstream io(file, std::ios::in | std::ios::out | std::ios::binary);
    io.seekp(static_cast<std::streamoff>(size / 2));
    char c = 0;
    io.read(&c, 1);
    io.seekp(static_cast<std::streamoff>(size / 2));
    c = static_cast<char>(c ^ 0x5a);
    io.write(&c, 1);
  }
  {
    auto m = makeCompliance(ComplianceKind::kWarped, *body, opt);
    EXPECT_TRUE(m->buildInfo().cache_rejected);
    EXPECT_NE(m->buildInfo().cache_message.find("checksum"), std::string::npos)
        << m->buildInfo().cache_message;
    EXPECT_LT(relErr(buildW(*m, rows), w_ref), 1e-12);
  }
  // truncated
  fs::resize_file(file, size - 100);
  {
    auto m = makeCompliance(ComplianceKind::kRest, *body, opt);
    EXPECT_TRUE(m->buildInfo().cache_rejected);
    EXPECT_FALSE(m->buildInfo().loaded_from_cache);
  }
  EXPECT_EQ(fs::file_size(file), size);  // rewritten whole
  // garbage file of the right size with a bad magic
  {
    std::ofstream out(file, std::ios::binary | std::ios::trunc);
    out << std::string(size, 'x');
  }
  {
    auto m = makeCompliance(ComplianceKind::kUncoupled, *body, opt);
    EXPECT_TRUE(m->buildInfo().cache_rejected);
  }
  auto last = makeCompliance(ComplianceKind::kWarped, *body, opt);
  EXPECT_TRUE(last->buildInfo().loaded_from_cache);
  EXPECT_EQ(buildW(*last, rows), w_ref);
}

TEST_F(LiverCompliance, SinglePrecisionC0MatchesDouble) {
  TempDir dir;
  auto body = makeBody();
  for (int s = 0; s < 3; ++s) ASSERT_TRUE(body->freeMotion(h_).ok);
  const auto rows = randomRows(*body, 30, 6);
  ComplianceOptions opt{h_, dir.path, false, "liver", 64};
  auto dbl = makeCompliance(ComplianceKind::kWarped, *body, opt);
  opt.c0_single_precision = true;
  auto flt = makeCompliance(ComplianceKind::kWarped, *body, opt);
  // the double cache is not trusted for a float model (and vice versa)
  EXPECT_TRUE(flt->buildInfo().cache_rejected);
  dbl->update(*body);
  flt->update(*body);
  const Eigen::MatrixXd w_d = buildW(*dbl, rows);
  const double err = relErr(buildW(*flt, rows), w_d);
  EXPECT_LT(err, 1e-6);
  EXPECT_GT(err, 0.0);
  EXPECT_LT(flt->memoryBytes(), dbl->memoryBytes() * 0.6);
  auto flt2 = makeCompliance(ComplianceKind::kWarped, *body, opt);
  EXPECT_TRUE(flt2->buildInfo().loaded_from_cache);
}

TEST_F(LiverCompliance, UncoupledCouplesOnlyRowsSharingNodes) {
  auto body = makeBody();
  auto model = makeCompliance(ComplianceKind::kUncoupled, *body, quietOptions(h_));
  const auto& surf = body->surfaceNodes();
  std::vector<TissueRow> rows(2);
  rows[0].node = {surf[0], -1, -1};
  rows[0].weight = {1, 0, 0};
  rows[0].dir = Eigen::Vector3d::UnitX();
  rows[1].node = {surf[1], -1, -1};
  rows[1].weight = {1, 0, 0};
  rows[1].dir = Eigen::Vector3d::UnitX();
  const Eigen::MatrixXd w = buildW(*model, rows);
  EXPECT_GT(w(0, 0), 0.0);
  EXPECT_GT(w(1, 1), 0.0);
  EXPECT_EQ(w(0, 1), 0.0);
  EXPECT_LT(model->memoryBytes(), 100 * sizeof(double) * surf.size() + 200000);
}

}  // namespace
}  // namespace tactus::sim
