// The compliance models (exact, warped, rest, uncoupled) and W = H C H^T; C0 and its cache are in
// rest_compliance_block.h.
#include "tactus/sim/compliance.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <new>
#include <string>
#include <vector>

#include "fem_internal.h"
#include "rest_compliance_block.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"
#include "tactus/shared/grow_only_matrix.h"
#include "tactus/sim/state_archive.h"

namespace tactus::sim {

using c0_detail::RestBlock;

namespace {

// addW's products on storage that only grows (grow_only_matrix.h): they follow the contact
// rows, whose count changes at almost every step.
using GrowOnlyMatrix = shared::GrowOnlyMatrix<Eigen::ColMajor>;

// Row-to-node expansion of H: (local node, 3-vector p) pairs per row.
struct RowTerms {
  int count = 0;
  std::array<int, 3> local{};
  std::array<Eigen::Vector3d, 3> p;
};

class ComplianceModel final : public TissueCompliance {
public:
  ComplianceModel(ComplianceKind kind, FemBody &body,
                  const ComplianceOptions &opt)
      : kind_(kind), opt_(opt), body_(&body) {
    if (!(opt.h_s > 0.0))
      throw Error("makeCompliance: h_s must be > 0");
    if (opt.rotation_smoothing_passes < 0 ||
        opt.rotation_smoothing_passes > kMaxRotationSmoothingPasses)
      throw Error("makeCompliance: rotation_smoothing_passes must be in [0, " +
                  std::to_string(kMaxRotationSmoothingPasses) + "]");
    const int n = body.nodeCount();
    rot_.assign(n, Eigen::Matrix3d::Identity());
    local_.assign(n, -1);
    if (kind_ != ComplianceKind::kExact)
      buildRest();
  }

  ComplianceKind kind() const override { return kind_; }

  void update(FemBody &body) override {
    body_ = &body;
    active_ = kind_;
    if (kind_ != ComplianceKind::kWarped)
      return;
    // the rotations closest to the free state's deformation gradients: the element loop's polar
    // decomposition stays the step's only one per element (docs/design.md, "The warped
    // compliance's rotations from the deformation gradients"); the coherence bound reads the
    // element rotations' spread, which costs their decompositions again
    if (opt_.exact_below_coherence > 0.0)
      body.nodeRotations(coherence_rot_, &coherence_, opt_.rotation_smoothing_passes);
    body.fittedNodeRotations(rot_, opt_.rotation_smoothing_passes);
  }

  void addW(std::span<const TissueRow> rows,
            Eigen::Ref<Eigen::MatrixXd> w) override {
    const int m = static_cast<int>(rows.size());
    if (m == 0)
      return;
    buildGt(rows);
    // W = G^T P (symmetric): lower triangle only, then added to both triangles of w
    GrowOnlyMatrix::Map &wdm = wd_.resize(m, m);
    writeLower(m, wdm.data(), wdm.outerStride(), WColumnsDone{});
    wdm.triangularView<Eigen::StrictlyUpper>() = wdm.transpose();
    w += wdm;
    release();
  }

  void setWLower(std::span<const TissueRow> rows, Eigen::Ref<Eigen::MatrixXd> w,
                 WColumnsDone done) override {
    const int m = static_cast<int>(rows.size());
    if (m == 0)
      return;
    buildGt(rows);
    // straight into w's columns: no m x m scratch, no mirror, no second pass (addW's values:
    // combine's sums start at +0.0 and so are never -0.0, and 0.0 + x is x for every other x)
    writeLower(m, w.data(), w.outerStride(), done);
    release();
  }

  void correction(FemBody &body, std::span<const TissueRow> rows,
                  const double *f, Eigen::VectorXd &dq) override {
    body_ = &body;
    const int n = body.nodeCount();
    const int m = static_cast<int>(rows.size());
    collect(rows);
    // r0 = (H R)^T f on the touched nodes
    r_.setZero(3 * n);
    for (int k = 0; k < m; ++k)
      for (int t = 0; t < terms_[k].count; ++t)
        r_.segment<3>(3 * touched_[terms_[k].local[t]]) +=
            f[k] * terms_[k].p[t];
    // exact correction of a warped model: back to world axes, r = H^T f
    if (opt_.exact_correction && active_ == ComplianceKind::kWarped)
      for (int node : touched_)
        r_.segment<3>(3 * node) = rot_[node] * r_.segment<3>(3 * node).eval();
    switch (opt_.exact_correction ? ComplianceKind::kExact : active_) {
    case ComplianceKind::kExact:
      body.solveCompliance(r_, dq);
      break;
    case ComplianceKind::kRest:
      body.solveRestCompliance(opt_.h_s, r_, dq);
      break;
    case ComplianceKind::kWarped:
      body.solveRestCompliance(opt_.h_s, r_, dq);
      for (int i = 0; i < n; ++i)
        dq.segment<3>(3 * i) = rot_[i] * dq.segment<3>(3 * i).eval();
      break;
    case ComplianceKind::kUncoupled:
      dq.setZero(3 * n);
      for (int node : touched_)
        dq.segment<3>(3 * node) =
            diag_[blk_.local[node]] * r_.segment<3>(3 * node);
      break;
    }
    // fixed DOFs stay at rest
    const auto &fixed = body.fixedMask();
    for (int i = 0; i < n; ++i)
      if (fixed[i])
        dq.segment<3>(3 * i).setZero();
    release();
  }

  std::size_t memoryBytes() const override {
    return blk_.bytes() +
           sizeof(int) *
               (blk_.surface.size() + blk_.local.size() + local_.size()) +
           sizeof(double) * diag_.size() +
           sizeof(Eigen::Matrix3d) * rot_.size() +
           sizeof(double) *
               static_cast<std::size_t>(cuu_.capacity() + prev_cuu_.capacity() +
                                        g_.capacity() + gt_.capacity() + wd_.capacity() +
                                        r_.size());
  }

  ComplianceBuildInfo buildInfo() const override { return info_; }

  // addW's G (3|U| x m), G^T, H C H^T (m x m) and the two C_UU (3|U| square), sized for 3|U| =
  // m (liver_grasp_23k holds 873 rows on 191 nodes, 3|U| = 573; a problem with more nodes per
  // row grows the storage as it needs)
  void reserve(int rows) override {
    if (rows <= 0)
      return;
    const auto m = static_cast<std::size_t>(rows);
    const std::size_t du =
        std::min(m, 3 * static_cast<std::size_t>(body_->nodeCount()));
    g_.reserve(du * m);
    gt_.reserve(du * m);
    wd_.reserve(m * m);
    cuu_.reserve(du * du);
    prev_cuu_.reserve(du * du);
    // correction's r = H^T f over the body, written now rather than at the first contact
    r_.setZero(3 * body_->nodeCount());
  }

  // The state of the model (state_archive.h): the rotations and coherences of the last update()
  // and the model it chose. update() recomputes them at every step before they are read; they
  // are kept so that a restored state also answers addW / correction as the original did.
  void transferState(StateArchive &ar) override {
    ar("rotations", rot_);
    ar.resizable("coherence", coherence_, rot_.size());
    ar("active", active_);
  }

private:
  void buildRest() {
    FemBody &body = *body_;
    blk_.surface = body.surfaceNodes();
    blk_.single = opt_.c0_single_precision;
    // C0 is dense (3s x 3s): say before anything is allocated or factorised when it cannot fit
    c0_detail::checkRestBlockFits(blk_.surface.size(), blk_.single);
    blk_.local.assign(body.nodeCount(), -1);
    for (std::size_t i = 0; i < blk_.surface.size(); ++i)
      blk_.local[blk_.surface[i]] = static_cast<int>(i);
    info_.surface_nodes = static_cast<int>(blk_.surface.size());
    const auto path = complianceCachePath(body, opt_);
    const std::uint64_t hash = c0_detail::cacheHash(body, opt_.h_s);
    bool loaded = false;
    const std::int64_t load_t0 = shared::monotonicNs();
    if (!path.empty() && std::filesystem::exists(path)) {
      std::string why;
      loaded = c0_detail::readCache(path, hash, body, blk_, why);
      if (!loaded) {
        info_.cache_rejected = true;
        info_.cache_message = why;
        spdlog::warn("compliance cache {} rejected: {}; rebuilding",
                     path.string(), why);
      }
    }
    if (loaded) {
      info_.loaded_from_cache = true;
      const double load_s = shared::secondsSinceNs(load_t0);
      spdlog::info("compliance cache {} loaded ({} surface nodes, {:.1f} MB in "
                   "{:.2f} s)",
                   path.string(), blk_.surface.size(),
                   static_cast<double>(blk_.bytes()) / 1e6, load_s);
    } else {
      const std::int64_t t0 = shared::monotonicNs();
      c0_detail::computeRestBlock(body, opt_, blk_);
      info_.precompute_s = shared::secondsSinceNs(t0);
      if (!path.empty())
        c0_detail::writeCache(path, hash, body, blk_);
    }
    // the corrections solve with the rest factorisation: made now, not at the first contact
    // (computeRestBlock has made it; a C0 read from the cache has not)
    if ((kind_ == ComplianceKind::kWarped || kind_ == ComplianceKind::kRest) &&
        !opt_.exact_correction)
      body.prepareRestCompliance(opt_.h_s);
    if (kind_ == ComplianceKind::kUncoupled) {
      // isotropic per node: mean of the diagonal of the node's 3x3 block; drop
      // the dense block
      const int s = static_cast<int>(blk_.surface.size());
      diag_.resize(s);
      for (int a = 0; a < s; ++a)
        diag_[a] = blk_.block(a, a).trace() / 3.0;
      blk_.release();
    }
  }

  // addW's first part: chooses the model, collects the rows' nodes, and leaves G^T (m x 3|U|,
  // G = C_UU P) in gt_.
  void buildGt(std::span<const TissueRow> rows) {
    const int m = static_cast<int>(rows.size());
    chooseModel(rows);
    const int u = collect(rows);
    const int du = 3 * u;
    if (active_ != ComplianceKind::kUncoupled) {
      gatherCuu(u);
      // G's columns a few runs at a time into a tile that stays in L1 (du x at most kGTile),
      // transposed from there into G^T: the values of G = C_UU P column by column, without G
      // itself going through memory
      GrowOnlyMatrix::Map &gtm = gt_.resize(m, du);
      GrowOnlyMatrix::Map &tile = g_.resize(du, kGTile);
      for (int l = 0; l < m;) {
        const int first = l;
        int cols = 0;
        while (l < m && cols + 3 <= kGTile) {
          const int g = sameNodeRun(l, m);
          double *out[3] = {tile.col(cols).data(), nullptr, nullptr};
          for (int r = 1; r < g; ++r)
            out[r] = tile.col(cols + r).data();
          combineRun(cuu_.map(), l, g, 0, du, out);
          cols += g;
          l += g;
        }
        for (int i = 0; i < du; ++i) {
          double *dst = gtm.data() + static_cast<Eigen::Index>(i) * m + first;
          for (int c = 0; c < cols; ++c)
            dst[c] = tile(i, c);
        }
      }
      return;
    }
    // uncoupled: G = C_UU P, column by column from the diagonal blocks
    GrowOnlyMatrix::Map &gm = g_.setZero(du, m);
    for (int l = 0; l < m; ++l)
      for (int t = 0; t < terms_[l].count; ++t) {
        const int b = terms_[l].local[t];
        gm.col(l).segment<3>(3 * b) += diag_[blk_.local[touched_[b]]] * terms_[l].p[t];
      }
    // through G^T so every column of W below is one fused pass over contiguous memory
    GrowOnlyMatrix::Map &gtm = gt_.resize(m, du);
    gtm = gm.transpose();
  }

  // The lower triangle (diagonal included) of W = G^T P into the column-major m x m matrix at
  // `w` with column stride `ld`, from buildGt's G^T. A run of rows shares its start row l, so
  // the run's later columns also get entries just above the diagonal (at most two a column):
  // the strict upper triangle is left unspecified. `done` is called after each run's columns.
  void writeLower(int m, double *w, Eigen::Index ld, WColumnsDone done) const {
    const GrowOnlyMatrix::Map &gtm = gt_.map();
    for (int l = 0; l < m;) {
      const int g = sameNodeRun(l, m);
      double *out[3] = {w + l * ld + l, nullptr, nullptr};
      for (int r = 1; r < g; ++r)
        out[r] = w + (l + r) * ld + l;
      combineRun(gtm, l, g, l, m - l, out);
      if (done.call != nullptr)
        done.call(done.context, l, g);
      l += g;
    }
  }

  // Rows l .. l + g - 1 (g <= 3) that touch the same nodes (a contact's n, t1,
  // t2 rows): returns g, the size of the run starting at l.
  int sameNodeRun(int l, int m) const {
    int g = 1;
    while (g < 3 && l + g < m && terms_[l + g].count == terms_[l].count &&
           terms_[l + g].local == terms_[l].local)
      ++g;
    return g;
  }

  // For each row r of the run starting at l (size g): out_r[0..len) = sum over
  // r's terms t and components j of p_t[j] * src(first + ., 3 a_t + j). One
  // fused pass reads each of the (up to 9) source columns once for the whole
  // run; vectorisable over the output.
  void combineRun(const GrowOnlyMatrix::Map &src, int l, int g, int first, int len,
                  double *const *out) const {
    const double *col[9];
    double coef[3][9];
    int nc = 0;
    for (int t = 0; t < terms_[l].count; ++t)
      for (int j = 0; j < 3; ++j) {
        col[nc] =
            src.data() + (3 * terms_[l].local[t] + j) * src.rows() + first;
        for (int r = 0; r < g; ++r)
          coef[r][nc] = terms_[l + r].p[t][j];
        ++nc;
      }
    if (nc == 0) {
      for (int r = 0; r < g; ++r)
        std::fill(out[r], out[r] + len, 0.0);
      return;
    }
    const int key = 10 * g + nc / 3;
    switch (key) {
    case 11:
      combine<1, 3>(col, coef, len, out);
      break;
    case 12:
      combine<1, 6>(col, coef, len, out);
      break;
    case 13:
      combine<1, 9>(col, coef, len, out);
      break;
    case 21:
      combine<2, 3>(col, coef, len, out);
      break;
    case 22:
      combine<2, 6>(col, coef, len, out);
      break;
    case 23:
      combine<2, 9>(col, coef, len, out);
      break;
    case 31:
      combine<3, 3>(col, coef, len, out);
      break;
    case 32:
      combine<3, 6>(col, coef, len, out);
      break;
    case 33:
      combine<3, 9>(col, coef, len, out);
      break;
    default:
      break;
    }
  }
  template <int G, int N>
  static void combine(const double *const *col, const double (*coef)[9],
                      int len, double *const *out) {
    for (int i = 0; i < len; ++i) {
      double acc[G] = {};
      for (int q = 0; q < N; ++q) {
        const double x = col[q][i];
        for (int r = 0; r < G; ++r)
          acc[r] += coef[r][q] * x;
      }
      for (int r = 0; r < G; ++r)
        out[r][i] = acc[r];
    }
  }

  // Fills touched_ / terms_ for the rows; returns |U|. Warped/rest/uncoupled
  // keep only surface nodes (others are counted and skipped).
  int collect(std::span<const TissueRow> rows) {
    touched_.clear();
    terms_.resize(rows.size());
    const bool surface_only = active_ != ComplianceKind::kExact;
    const int n = body_->nodeCount();
    for (std::size_t k = 0; k < rows.size(); ++k) {
      RowTerms &rt = terms_[k];
      rt.count = 0;
      for (int t = 0; t < 3; ++t) {
        const int node = rows[k].node[t];
        if (node < 0 || rows[k].weight[t] == 0.0)
          continue;
        if (node >= n)
          throw Error("TissueCompliance: row node " + std::to_string(node) +
                      " out of range");
        if (surface_only && blk_.local[node] < 0) {
          ++info_.skipped_row_nodes;
          continue;
        }
        if (local_[node] < 0) {
          local_[node] = static_cast<int>(touched_.size());
          touched_.push_back(node);
        }
        Eigen::Vector3d p = rows[k].weight[t] * rows[k].dir;
        if (active_ == ComplianceKind::kWarped)
          p = rot_[node].transpose() * p;
        rt.local[rt.count] = local_[node];
        rt.p[rt.count] = p;
        ++rt.count;
      }
    }
    return static_cast<int>(touched_.size());
  }

  // Warped with a coherence bound: this call (and the correction after it) uses the exact
  // compliance when a node the rows touch has its element rotations spread below the bound.
  void chooseModel(std::span<const TissueRow> rows) {
    active_ = kind_;
    if (kind_ != ComplianceKind::kWarped || !(opt_.exact_below_coherence > 0.0) ||
        coherence_.empty())
      return;
    for (const TissueRow &row : rows)
      for (int t = 0; t < 3; ++t) {
        const int node = row.node[t];
        if (node >= 0 && row.weight[t] != 0.0 &&
            node < static_cast<int>(coherence_.size()) &&
            coherence_[node] < opt_.exact_below_coherence) {
          active_ = ComplianceKind::kExact;
          ++info_.exact_fallbacks;
          return;
        }
      }
  }

  void release() {
    for (int node : touched_)
      local_[node] = -1;
  }

  // C_UU: from C0 (warped/rest) or from 3|U| solves with the current
  // factorisation (exact).
  void gatherCuu(int u) {
    const int du = 3 * u;
    if (active_ == ComplianceKind::kExact) {
      forgetPreviousCuu();
      GrowOnlyMatrix::Map &cuu = cuu_.resize(du, du);
      const int n = body_->nodeCount();
      e_.setZero(3 * n, du);
      for (int a = 0; a < u; ++a)
        for (int c = 0; c < 3; ++c)
          e_(3 * touched_[a] + c, 3 * a + c) = 1.0;
      body_->solveComplianceBatch(e_, x_);
      for (int b = 0; b < u; ++b)
        cuu.middleRows<3>(3 * b) = x_.middleRows<3>(3 * touched_[b]);
      return;
    }
    // C0's blocks of the nodes the previous call touched too come from that call's C_UU (kept
    // in prev_cuu_: small, in cache), the others from C0 itself (a 3x3 block is three cache
    // lines in three columns of a matrix of gigabytes): the touched nodes change little from
    // one contact pass or step to the next. The same values either way.
    // (swapped before any resize: the previous values are read below)
    cuu_.swap(prev_cuu_);
    GrowOnlyMatrix::Map &cuu = cuu_.resize(du, du);
    const GrowOnlyMatrix::Map &prev_cuu = prev_cuu_.map();
    prev_index_.resize(static_cast<std::size_t>(u));
    for (int a = 0; a < u; ++a)
      prev_index_[a] = prev_local_.empty() ? -1 : prev_local_[touched_[a]];
    for (int b = 0; b < u; ++b) {
      const int sb = blk_.local[touched_[b]];
      const int pb = prev_index_[b];
      for (int a = 0; a < u; ++a) {
        const int pa = prev_index_[a];
        if (pa >= 0 && pb >= 0)
          cuu.block<3, 3>(3 * a, 3 * b) =
              prev_cuu.block<3, 3>(3 * pa, 3 * pb);
        else
          cuu.block<3, 3>(3 * a, 3 * b) =
              blk_.block(blk_.local[touched_[a]], sb);
      }
    }
    // this call's nodes for the next one
    if (prev_local_.empty())
      prev_local_.assign(static_cast<std::size_t>(body_->nodeCount()), -1);
    for (int node : prev_touched_)
      prev_local_[node] = -1;
    prev_touched_ = touched_;
    for (int a = 0; a < u; ++a)
      prev_local_[touched_[a]] = a;
  }

  // The exact model's C_UU is not C0's: the next gather starts afresh.
  void forgetPreviousCuu() {
    for (int node : prev_touched_)
      prev_local_[node] = -1;
    prev_touched_.clear();
  }

  // Model, state and scratch (docs/design.md, "Model, state, scratch"):
  // model: fixed once built (the kind, the options, the rest block C0 on the surface or its
  // diagonal), with how it was built (info_, whose skipped_row_nodes is a running statistic).
  ComplianceKind kind_;
  ComplianceOptions opt_;
  RestBlock blk_;
  std::vector<double> diag_;         // uncoupled: per surface node
  ComplianceBuildInfo info_;
  // state: what update() refreshes once per step and addW/correction read
  FemBody *body_;                    // the body whose state (and exact compliance) is read
  std::vector<Eigen::Matrix3d> rot_; // warped: node rotations rest -> current
  std::vector<double> coherence_;    // warped with the bound: per node
  ComplianceKind active_ = kind_;    // this step's model (kind_, or exact: chooseModel)
  // scratch: per call of addW/correction; local_ is kept all -1 between calls
  std::vector<int> local_;           // node -> index in touched_, -1 otherwise
  std::vector<int> touched_;
  std::vector<RowTerms> terms_;
  std::vector<Eigen::Matrix3d> coherence_rot_;  // update(): the rotations coherence_ reads
  // C_UU, G (the uncoupled model's; the others' tile of G's columns), G^T and H C H^T of addW
  GrowOnlyMatrix cuu_, g_, gt_, wd_;
  // G's columns per tile (buildGt): 3|U| x 8 doubles, in L1 for the 23k's 573
  static constexpr int kGTile = 8;
  Eigen::MatrixXd e_, x_;              // the exact model's unit loads and their solves
  // the previous gather of C0's blocks (gatherCuu): its C_UU, its nodes and their index in it
  // (node -> index, -1 otherwise; empty before the first gather), and the current nodes' index
  GrowOnlyMatrix prev_cuu_;
  std::vector<int> prev_touched_, prev_local_, prev_index_;
  Eigen::VectorXd r_;
};

} // namespace

std::filesystem::path complianceCachePath(const FemBody &body,
                                          const ComplianceOptions &options) {
  if (options.cache_dir.empty())
    return {};
  std::string name = options.cache_name;
  if (name.empty())
    name = std::filesystem::path(body.mesh().source).stem().string();
  if (name.empty())
    name = "tissue";
  return options.cache_dir / (name + ".c0.bin");
}

std::unique_ptr<TissueCompliance>
makeCompliance(ComplianceKind kind, FemBody &body,
               const ComplianceOptions &options) {
  return std::make_unique<ComplianceModel>(kind, body, options);
}

} // namespace tactus::sim
