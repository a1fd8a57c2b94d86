#include "tactus/sim/compliance.h"

#include <sys/mman.h>
#include <unistd.h>

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <new>
#include <string>
#include <vector>

#include "fem_internal.h"
#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"

namespace tactus::sim {

namespace {

constexpr char kMagic[8] = {'T', 'A', 'C', 'T', 'C', '0', '\0', '\1'};
// 2: payload checksum is PayloadChecksum (1 was byte-wise FNV-1a, too slow for GB files)
constexpr std::uint32_t kVersion = 2;
// Bytes read, checksummed and checked per step of a cache load (stays cache-resident).
constexpr std::size_t kLoadChunkBytes = std::size_t{4} << 20;

struct CacheHeader {
  char magic[8];
  std::uint32_t version;
  std::uint32_t scalar_bytes; // 8: double, 4: float
  std::uint64_t hash;         // FemBody::restHash combined with h
  std::uint64_t node_count;
  std::uint64_t surface_count;
};

// Checksum of the cache payload (surface node list, then C0), fed in pieces of any
// size. Four interleaved FNV-style lanes over 8-byte words: a change in any one word
// always changes its lane (xor and the odd multiplier are bijections), and the lanes
// run in parallel, so it keeps up with the disk cache where byte-wise FNV-1a did not.
// Lanes, tail bytes and length are folded with FNV-1a.
class PayloadChecksum {
public:
  void add(const void *data, std::size_t n) {
    const auto *p = static_cast<const unsigned char *>(data);
    bytes_ += n;
    if (pending_n_ > 0) {
      const std::size_t take = std::min(kBlock - pending_n_, n);
      std::memcpy(pending_ + pending_n_, p, take);
      pending_n_ += take;
      p += take;
      n -= take;
      if (pending_n_ < kBlock)
        return;
      blocks(pending_, 1);
      pending_n_ = 0;
    }
    blocks(p, n / kBlock);
    p += n / kBlock * kBlock;
    n %= kBlock;
    std::memcpy(pending_, p, n);
    pending_n_ = n;
  }
  std::uint64_t finish() const {
    std::uint64_t h = fem_detail::fnv1a(lane_, sizeof(lane_));
    h = fem_detail::fnv1a(pending_, pending_n_, h);
    return fem_detail::fnv1a(&bytes_, sizeof(bytes_), h);
  }

private:
  static constexpr std::size_t kBlock = 32;
  static constexpr std::uint64_t kPrime = 0x100000001b3ull;
  // Whole blocks; the lanes live in locals (bytes may alias the members).
  void blocks(const unsigned char *p, std::size_t count) {
    std::uint64_t l0 = lane_[0], l1 = lane_[1], l2 = lane_[2], l3 = lane_[3];
    for (std::size_t b = 0; b < count; ++b, p += kBlock) {
      std::uint64_t w[4];
      std::memcpy(w, p, sizeof(w));
      l0 = (l0 ^ w[0]) * kPrime;
      l1 = (l1 ^ w[1]) * kPrime;
      l2 = (l2 ^ w[2]) * kPrime;
      l3 = (l3 ^ w[3]) * kPrime;
    }
    lane_[0] = l0;
    lane_[1] = l1;
    lane_[2] = l2;
    lane_[3] = l3;
  }
  std::uint64_t lane_[4] = {0xcbf29ce484222325ull, 0x84222325cbf29ce4ull,
                            0x9e3779b97f4a7c15ull, 0xc2b2ae3d27d4eb4full};
  unsigned char pending_[kBlock] = {};
  std::size_t pending_n_ = 0;
  std::uint64_t bytes_ = 0;
};

std::uint64_t cacheHash(const FemBody &body, double h) {
  const std::uint64_t base = body.restHash();
  return fem_detail::fnv1a(&h, sizeof(h), base);
}

// Page-aligned anonymous memory for the large C0 block, asked for in transparent
// huge pages and populated in one call: filling 1.6 GB through 4 KiB page faults
// (one trap each) cost more than reading the file itself. Falls back silently to
// ordinary pages where huge pages or MADV_POPULATE_WRITE are not available.
class LargeBuffer {
public:
  LargeBuffer() = default;
  LargeBuffer(const LargeBuffer &) = delete;
  LargeBuffer &operator=(const LargeBuffer &) = delete;
  ~LargeBuffer() { reset(); }
  // Throws std::bad_alloc when the memory cannot be had.
  void allocate(std::size_t bytes) {
    reset();
    if (bytes == 0)
      return;
    constexpr std::size_t kHuge = std::size_t{2} << 20;
    const std::size_t mapped = (bytes + kHuge - 1) / kHuge * kHuge;
    void *p = ::mmap(nullptr, mapped, PROT_READ | PROT_WRITE,
                     MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED)
      throw std::bad_alloc();
#ifdef MADV_HUGEPAGE
    (void)::madvise(p, mapped, MADV_HUGEPAGE);
#endif
#ifdef MADV_POPULATE_WRITE
    (void)::madvise(p, mapped, MADV_POPULATE_WRITE);
#endif
    data_ = p;
    mapped_ = mapped;
  }
  void reset() {
    if (data_ != nullptr)
      ::munmap(data_, mapped_);
    data_ = nullptr;
    mapped_ = 0;
  }
  void *data() const { return data_; }

private:
  void *data_ = nullptr;
  std::size_t mapped_ = 0;
};

// Rest compliance block on the surface DOFs, with the surface numbering.
struct RestBlock {
  std::vector<int> surface; // sorted surface node indices
  std::vector<int> local;   // node -> surface index, -1 inside the volume
  bool single = false;      // stored in float (c0f) instead of double (c0)
  LargeBuffer storage;      // memory of c0 / c0f
  Eigen::Map<Eigen::MatrixXd> c0{nullptr, 0, 0}; // 3s x 3s
  Eigen::Map<Eigen::MatrixXf> c0f{nullptr, 0, 0};
  std::size_t scalarBytes() const {
    return single ? sizeof(float) : sizeof(double);
  }
  void resize(Eigen::Index d) {
    release();
    storage.allocate(static_cast<std::size_t>(d * d) * scalarBytes());
    // re-seating an Eigen::Map is done by placement new
    if (single)
      new (&c0f) Eigen::Map<Eigen::MatrixXf>(
          static_cast<float *>(storage.data()), d, d);
    else
      new (&c0) Eigen::Map<Eigen::MatrixXd>(
          static_cast<double *>(storage.data()), d, d);
  }
  void *data() { return storage.data(); }
  const void *data() const { return storage.data(); }
  Eigen::Matrix3d block(int a, int b) const {
    if (single)
      return c0f.block<3, 3>(3 * a, 3 * b).cast<double>();
    return c0.block<3, 3>(3 * a, 3 * b);
  }
  std::size_t bytes() const {
    return scalarBytes() *
           static_cast<std::size_t>(single ? c0f.size() : c0.size());
  }
  void release() {
    new (&c0) Eigen::Map<Eigen::MatrixXd>(nullptr, 0, 0);
    new (&c0f) Eigen::Map<Eigen::MatrixXf>(nullptr, 0, 0);
    storage.reset();
  }
};

// In-place (A + A^T) / 2 without a full-size temporary.
template <class Mat> void symmetrise(Mat &a) {
  for (Eigen::Index j = 0; j < a.cols(); ++j)
    for (Eigen::Index i = j + 1; i < a.rows(); ++i) {
      const auto v = (a(i, j) + a(j, i)) / 2;
      a(i, j) = v;
      a(j, i) = v;
    }
}

void progress(bool show, int done, int total) {
  if (!show)
    return;
  const int percent = total > 0 ? 100 * done / total : 100;
  if (!isatty(fileno(stderr))) {
    // logs and pipes: one line per quarter instead of a redrawn bar
    static int last_quarter = -1;
    const int quarter = percent / 25;
    if (done == 0) last_quarter = -1;
    if (quarter == last_quarter) return;
    last_quarter = quarter;
    std::fprintf(stderr, "[tactus] C0 precompute %3d%% (%d/%d DOFs)\n", percent, done, total);
    return;
  }
  const int width = 40;
  const int filled = total > 0 ? width * done / total : width;
  std::fprintf(stderr, "\r[tactus] C0 precompute [%s%s] %3d%% (%d/%d DOFs)",
               std::string(filled, '#').c_str(),
               std::string(width - filled, ' ').c_str(), percent, done, total);
  if (done == total)
    std::fprintf(stderr, "\n");
  std::fflush(stderr);
}

// Reads and validates a cache file; returns false (with a reason) unless every
// check passes. The file must be a regular file of exactly the size the mesh
// implies (checked before reading). Throws tactus::Cancelled on a stop request.
bool readCache(const std::filesystem::path &path, std::uint64_t hash,
               const FemBody &body, RestBlock &blk, std::string &why) {
  const auto &surface = body.surfaceNodes();
  const std::uint64_t s = surface.size(), d = 3 * s;
  const std::uint64_t expected =
      sizeof(CacheHeader) + s * sizeof(int) + d * d * blk.scalarBytes() + 8;
  try {
    shared::InputFile in(path, "compliance cache", expected);
    const std::uint64_t file_size = in.size();
    CacheHeader hdr{};
    if (file_size < sizeof(hdr)) {
      why = "truncated header";
      return false;
    }
    in.readExact(&hdr, sizeof(hdr));
    if (std::memcmp(hdr.magic, kMagic, sizeof(kMagic)) != 0) {
      why = "bad magic (not a compliance cache)";
      return false;
    }
    if (hdr.version != kVersion) {
      why = "version " + std::to_string(hdr.version) +
            " != " + std::to_string(kVersion);
      return false;
    }
    if (hdr.hash != hash) {
      why = "stale (mesh, material, fixed nodes or h changed)";
      return false;
    }
    if (hdr.node_count != static_cast<std::uint64_t>(body.nodeCount()) ||
        hdr.surface_count != s) {
      why = "sizes do not match the mesh";
      return false;
    }
    if (hdr.scalar_bytes != blk.scalarBytes()) {
      why = "precision differs (" + std::to_string(hdr.scalar_bytes) +
            "-byte values)";
      return false;
    }
    if (file_size != expected) {
      why = "size " + std::to_string(file_size) + " bytes, expected " +
            std::to_string(expected) + " (truncated or corrupt)";
      return false;
    }
    // One pass: read a chunk straight into C0's storage, checksum it and check it
    // while it is still in the CPU cache (no second copy, no per-element conversion).
    std::vector<int> nodes(s);
    blk.resize(static_cast<Eigen::Index>(d));
    PayloadChecksum sum;
    in.readExact(nodes.data(), s * sizeof(int));
    sum.add(nodes.data(), s * sizeof(int));
    auto *payload = static_cast<unsigned char *>(blk.data());
    const std::uint64_t payload_bytes = d * d * blk.scalarBytes();
    bool finite = true;
    for (std::uint64_t at = 0; at < payload_bytes;) {
      const std::size_t n = static_cast<std::size_t>(
          std::min<std::uint64_t>(kLoadChunkBytes, payload_bytes - at));
      in.readExact(payload + at, n);
      sum.add(payload + at, n);
      const auto count = static_cast<Eigen::Index>(n / blk.scalarBytes());
      if (blk.single)
        finite = finite && Eigen::Map<const Eigen::ArrayXf>(
                               reinterpret_cast<const float *>(payload + at),
                               count)
                               .allFinite();
      else
        finite = finite && Eigen::Map<const Eigen::ArrayXd>(
                               reinterpret_cast<const double *>(payload + at),
                               count)
                               .allFinite();
      at += n;
    }
    std::uint64_t checksum = 0;
    in.readExact(&checksum, sizeof(checksum));
    if (sum.finish() != checksum) {
      why = "checksum mismatch (corrupt)";
      return false;
    }
    if (nodes != surface) {
      why = "surface nodes differ";
      return false;
    }
    if (!finite) {
      why = "non-finite values";
      return false;
    }
    return true;
  } catch (const FileError &e) {
    why = e.what();
    return false;
  }
}

// Writes the cache through a temporary file (fsync + rename): a reader never
// sees a half-written file under the final name. Failures only warn.
void writeCache(const std::filesystem::path &path, std::uint64_t hash,
                const FemBody &body, const RestBlock &blk) {
  std::error_code ec;
  std::filesystem::create_directories(path.parent_path(), ec);
  try {
    shared::OutputFile out(path, "compliance cache",
                           {.overwrite = true, .allow_special = false});
    CacheHeader hdr{};
    std::memcpy(hdr.magic, kMagic, sizeof(kMagic));
    hdr.version = kVersion;
    hdr.scalar_bytes = static_cast<std::uint32_t>(blk.scalarBytes());
    hdr.hash = hash;
    hdr.node_count = static_cast<std::uint64_t>(body.nodeCount());
    hdr.surface_count = blk.surface.size();
    const std::uint64_t d = 3 * hdr.surface_count;
    PayloadChecksum checksum;
    checksum.add(blk.surface.data(), blk.surface.size() * sizeof(int));
    checksum.add(blk.data(), d * d * blk.scalarBytes());
    const std::uint64_t sum = checksum.finish();
    const auto bytes = [](const void *p, std::size_t n) {
      return std::string_view(static_cast<const char *>(p), n);
    };
    out.write(bytes(&hdr, sizeof(hdr)));
    out.write(bytes(blk.surface.data(), blk.surface.size() * sizeof(int)));
    out.write(bytes(blk.data(), d * d * blk.scalarBytes()));
    out.write(bytes(&sum, sizeof(sum)));
    out.commit();
  } catch (const FileError &e) {
    spdlog::warn("compliance cache: {} (continuing without cache)", e.what());
  }
}

// C0 on the surface DOFs: one rest factorisation, one (batched) solve per
// surface DOF.
void computeRestBlock(FemBody &body, const ComplianceOptions &opt,
                      RestBlock &blk) {
  const int n = body.nodeCount();
  const int s = static_cast<int>(blk.surface.size());
  const int d = 3 * s;
  blk.resize(d);
  const int batch = std::max(1, opt.solve_batch);
  Eigen::MatrixXd rhs, sol;
  progress(opt.show_progress, 0, d);
  for (int c0 = 0; c0 < d; c0 += batch) {
    const int k = std::min(batch, d - c0);
    rhs.setZero(3 * n, k);
    for (int j = 0; j < k; ++j) {
      const int col = c0 + j;
      rhs(3 * blk.surface[col / 3] + col % 3, j) = 1.0;
    }
    shared::throwIfStopRequested("precomputing the rest compliance C0");
    body.solveRestComplianceBatch(opt.h_s, rhs, sol);
    for (int j = 0; j < k; ++j)
      for (int a = 0; a < s; ++a) {
        if (blk.single)
          blk.c0f.block<3, 1>(3 * a, c0 + j) =
              sol.block<3, 1>(3 * blk.surface[a], j).cast<float>();
        else
          blk.c0.block<3, 1>(3 * a, c0 + j) =
              sol.block<3, 1>(3 * blk.surface[a], j);
      }
    progress(opt.show_progress, c0 + k, d);
  }
  // remove the solver's round-off asymmetry
  if (blk.single)
    symmetrise(blk.c0f);
  else
    symmetrise(blk.c0);
}

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
      : kind_(kind), body_(&body), opt_(opt) {
    if (!(opt.h_s > 0.0))
      throw Error("makeCompliance: h_s must be > 0");
    const int n = body.nodeCount();
    rot_.assign(n, Eigen::Matrix3d::Identity());
    local_.assign(n, -1);
    if (kind_ != ComplianceKind::kExact)
      buildRest();
  }

  ComplianceKind kind() const override { return kind_; }

  void update(FemBody &body) override {
    body_ = &body;
    if (kind_ == ComplianceKind::kWarped)
      body.nodeRotations(rot_);
  }

  void addW(std::span<const TissueRow> rows,
            Eigen::Ref<Eigen::MatrixXd> w) override {
    const int m = static_cast<int>(rows.size());
    if (m == 0)
      return;
    const int u = collect(rows);
    const int du = 3 * u;
    // G = C_UU P, column by column from 3x3 blocks
    g_.resize(du, m);
    if (kind_ == ComplianceKind::kUncoupled) {
      g_.setZero();
      for (int l = 0; l < m; ++l)
        for (int t = 0; t < terms_[l].count; ++t) {
          const int b = terms_[l].local[t];
          g_.col(l).segment<3>(3 * b) +=
              diag_[blk_.local[touched_[b]]] * terms_[l].p[t];
        }
    } else {
      gatherCuu(u);
      for (int l = 0; l < m;) {
        const int g = sameNodeRun(l, m);
        double *out[3] = {g_.col(l).data(), nullptr, nullptr};
        for (int r = 1; r < g; ++r)
          out[r] = g_.col(l + r).data();
        combineRun(cuu_, l, g, 0, du, out);
        l += g;
      }
    }
    // W = G^T P (symmetric): lower triangle only, through G^T so every column
    // is one fused pass over contiguous memory, then added to both triangles of
    // w
    gt_ = g_.transpose();
    wd_.resize(m, m);
    // (a run of rows shares the start row l; entries above the diagonal are
    // overwritten below)
    for (int l = 0; l < m;) {
      const int g = sameNodeRun(l, m);
      double *out[3] = {wd_.col(l).data() + l, nullptr, nullptr};
      for (int r = 1; r < g; ++r)
        out[r] = wd_.col(l + r).data() + l;
      combineRun(gt_, l, g, l, m - l, out);
      l += g;
    }
    wd_.triangularView<Eigen::StrictlyUpper>() = wd_.transpose();
    w += wd_;
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
    if (opt_.exact_correction && kind_ == ComplianceKind::kWarped)
      for (int node : touched_)
        r_.segment<3>(3 * node) = rot_[node] * r_.segment<3>(3 * node).eval();
    switch (opt_.exact_correction ? ComplianceKind::kExact : kind_) {
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
               static_cast<std::size_t>(cuu_.size() + g_.size() + gt_.size() +
                                        wd_.size() + r_.size());
  }

  ComplianceBuildInfo buildInfo() const override { return info_; }

private:
  void buildRest() {
    FemBody &body = *body_;
    blk_.surface = body.surfaceNodes();
    blk_.single = opt_.c0_single_precision;
    blk_.local.assign(body.nodeCount(), -1);
    for (std::size_t i = 0; i < blk_.surface.size(); ++i)
      blk_.local[blk_.surface[i]] = static_cast<int>(i);
    info_.surface_nodes = static_cast<int>(blk_.surface.size());
    const auto path = complianceCachePath(body, opt_);
    const std::uint64_t hash = cacheHash(body, opt_.h_s);
    bool loaded = false;
    const auto load_t0 = std::chrono::steady_clock::now();
    if (!path.empty() && std::filesystem::exists(path)) {
      std::string why;
      loaded = readCache(path, hash, body, blk_, why);
      if (!loaded) {
        info_.cache_rejected = true;
        info_.cache_message = why;
        spdlog::warn("compliance cache {} rejected: {}; rebuilding",
                     path.string(), why);
      }
    }
    if (loaded) {
      info_.loaded_from_cache = true;
      const double load_s = std::chrono::duration<double>(
                                std::chrono::steady_clock::now() - load_t0)
                                .count();
      spdlog::info("compliance cache {} loaded ({} surface nodes, {:.1f} MB in "
                   "{:.2f} s)",
                   path.string(), blk_.surface.size(),
                   static_cast<double>(blk_.bytes()) / 1e6, load_s);
    } else {
      const auto t0 = std::chrono::steady_clock::now();
      computeRestBlock(body, opt_, blk_);
      info_.precompute_s =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - t0)
              .count();
      if (!path.empty())
        writeCache(path, hash, body, blk_);
    }
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
  void combineRun(const Eigen::MatrixXd &src, int l, int g, int first, int len,
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
    const bool surface_only = kind_ != ComplianceKind::kExact;
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
        if (kind_ == ComplianceKind::kWarped)
          p = rot_[node].transpose() * p;
        rt.local[rt.count] = local_[node];
        rt.p[rt.count] = p;
        ++rt.count;
      }
    }
    return static_cast<int>(touched_.size());
  }

  void release() {
    for (int node : touched_)
      local_[node] = -1;
  }

  // C_UU: from C0 (warped/rest) or from 3|U| solves with the current
  // factorisation (exact).
  void gatherCuu(int u) {
    const int du = 3 * u;
    cuu_.resize(du, du);
    if (kind_ == ComplianceKind::kExact) {
      const int n = body_->nodeCount();
      e_.setZero(3 * n, du);
      for (int a = 0; a < u; ++a)
        for (int c = 0; c < 3; ++c)
          e_(3 * touched_[a] + c, 3 * a + c) = 1.0;
      body_->solveComplianceBatch(e_, x_);
      for (int b = 0; b < u; ++b)
        cuu_.middleRows<3>(3 * b) = x_.middleRows<3>(3 * touched_[b]);
      return;
    }
    for (int b = 0; b < u; ++b) {
      const int sb = blk_.local[touched_[b]];
      for (int a = 0; a < u; ++a) {
        const int sa = blk_.local[touched_[a]];
        cuu_.block<3, 3>(3 * a, 3 * b) = blk_.block(sa, sb);
      }
    }
  }

  ComplianceKind kind_;
  FemBody *body_;
  ComplianceOptions opt_;
  RestBlock blk_;
  std::vector<double> diag_;         // uncoupled: per surface node
  std::vector<Eigen::Matrix3d> rot_; // warped: node rotations rest -> current
  std::vector<int> local_;           // node -> index in touched_, -1 otherwise
  std::vector<int> touched_;
  std::vector<RowTerms> terms_;
  Eigen::MatrixXd cuu_, g_, gt_, wd_, e_, x_;
  Eigen::VectorXd r_;
  ComplianceBuildInfo info_;
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
