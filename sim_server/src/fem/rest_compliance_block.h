#pragma once
// The rest compliance block C0 on a tissue's surface DOFs (docs/design.md, "Compliance
// warping"): its memory, its precomputation (one rest factorisation, one solve per surface DOF)
// and its on-disk cache (compliance_cache.cpp: checked header, checksum, temp + rename writes).
// Private to the fem module; the models that use it are in compliance.cpp.

#include <sys/mman.h>

#include <Eigen/Core>
#include <cstdint>
#include <filesystem>
#include <new>
#include <string>
#include <vector>

#include "tactus/sim/compliance.h"
#include "tactus/sim/fem.h"

namespace tactus::sim::c0_detail {

// The memory of the large C0 block: either page-aligned anonymous memory, asked for in
// transparent huge pages and populated in one call (filling 1.6 GB through 4 KiB page faults, one
// trap each, cost more than reading the file itself), or a read-only mapping of a checked cache
// file (adopt: no fresh memory to zero, the page cache's own pages; compliance_cache.cpp). Falls
// back silently to ordinary pages where huge pages or MADV_POPULATE_WRITE are not available.
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
    base_ = p;
    data_ = p;
    mapped_ = mapped;
    writable_ = true;
  }
  // Takes over a mapping (mmap) of `mapped` bytes at `base`, unmapped by reset(); the data
  // start `offset` bytes into it.
  void adopt(void *base, std::size_t mapped, std::size_t offset) {
    reset();
    base_ = base;
    data_ = static_cast<char *>(base) + offset;
    mapped_ = mapped;
    writable_ = false;
  }
  void reset() {
    if (base_ != nullptr)
      ::munmap(base_, mapped_);
    base_ = nullptr;
    data_ = nullptr;
    mapped_ = 0;
    writable_ = false;
  }
  const void *data() const { return data_; }
  // allocate's memory; nullptr for an adopted (read-only) mapping or no memory
  void *writableData() const { return writable_ ? data_ : nullptr; }

private:
  void *base_ = nullptr;
  void *data_ = nullptr;
  std::size_t mapped_ = 0;
  bool writable_ = false;
};

// Bytes the dense C0 block of `surface_nodes` nodes takes ((3s)^2 scalars).
inline double restBlockBytes(std::size_t surface_nodes, bool single) {
  const double d = 3.0 * static_cast<double>(surface_nodes);
  return d * d * (single ? 4.0 : 8.0);
}

// Throws NumericalError with the size, what the machine has and what to do when the C0 block of
// `surface_nodes` nodes needs more than the memory available now (MemAvailable), before
// anything is allocated or factorised (it used to end in a bare std::bad_alloc after loading).
void checkRestBlockFits(std::size_t surface_nodes, bool single);

// Rest compliance block on the surface DOFs, with the surface numbering.
struct RestBlock {
  std::vector<int> surface; // sorted surface node indices
  std::vector<int> local;   // node -> surface index, -1 inside the volume
  bool single = false;      // stored in float (c0f) instead of double (c0)
  LargeBuffer storage;      // memory of c0 / c0f
  // C0 for reading (3s x 3s), in one of the two precisions; written only by computeRestBlock,
  // through writableC0 / writableC0f
  Eigen::Map<const Eigen::MatrixXd> c0{nullptr, 0, 0};
  Eigen::Map<const Eigen::MatrixXf> c0f{nullptr, 0, 0};
  std::size_t scalarBytes() const {
    return single ? sizeof(float) : sizeof(double);
  }
  void resize(Eigen::Index d) {
    release();
    storage.allocate(static_cast<std::size_t>(d * d) * scalarBytes());
    seat(d);
  }
  // C0 (d x d) in a read-only mapping of a cache file, `offset` bytes into it (readCache): its
  // values are never written (only computeRestBlock writes C0, into resize's memory).
  void adopt(void *base, std::size_t mapped, std::size_t offset, Eigen::Index d) {
    release();
    storage.adopt(base, mapped, offset);
    seat(d);
  }
  // The maps on the storage's d x d values (re-seating an Eigen::Map is done by placement new).
  void seat(Eigen::Index d) {
    if (single)
      new (&c0f) Eigen::Map<const Eigen::MatrixXf>(
          static_cast<const float *>(storage.data()), d, d);
    else
      new (&c0) Eigen::Map<const Eigen::MatrixXd>(
          static_cast<const double *>(storage.data()), d, d);
  }
  // Writable views of resize's memory for the precomputation; empty (0 x 0) on a C0 adopted
  // from a cache file, whose pages are read-only.
  Eigen::Map<Eigen::MatrixXd> writableC0() {
    auto *p = static_cast<double *>(storage.writableData());
    const Eigen::Index d = p != nullptr && !single ? c0.rows() : 0;
    return {p, d, d};
  }
  Eigen::Map<Eigen::MatrixXf> writableC0f() {
    auto *p = static_cast<float *>(storage.writableData());
    const Eigen::Index d = p != nullptr && single ? c0f.rows() : 0;
    return {p, d, d};
  }
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
    new (&c0) Eigen::Map<const Eigen::MatrixXd>(nullptr, 0, 0);
    new (&c0f) Eigen::Map<const Eigen::MatrixXf>(nullptr, 0, 0);
    storage.reset();
  }
};

/// The cache's identity of a body's C0: FemBody::restHash combined with the time step h.
std::uint64_t cacheHash(const FemBody &body, double h);

/// Reads and validates a cache file into `blk` (whose `single` selects the precision); returns
/// false with a reason (and `blk` empty) unless every check passes. The file must be a regular
/// file of exactly the size the mesh implies (checked before reading). C0 is then the file's
/// read-only mapping (the file read into anonymous memory where it cannot be mapped). Throws
/// tactus::Cancelled on a stop request.
bool readCache(const std::filesystem::path &path, std::uint64_t hash,
               const FemBody &body, RestBlock &blk, std::string &why);

/// Writes the cache through a temporary file (fsync + rename): a reader never sees a
/// half-written file under the final name. Failures only warn.
void writeCache(const std::filesystem::path &path, std::uint64_t hash,
                const FemBody &body, const RestBlock &blk);

/// C0 on the surface DOFs: one rest factorisation, one (batched) solve per surface DOF, with
/// progress on stderr when opt.show_progress; symmetrised. Throws tactus::Cancelled on a stop
/// request.
void computeRestBlock(FemBody &body, const ComplianceOptions &opt, RestBlock &blk);

} // namespace tactus::sim::c0_detail
