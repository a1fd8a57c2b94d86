// The compliance cache file: header, payload checksum, C0 checked in chunks where the file is
// mapped (or read into C0's memory), temp + fsync + rename writes (rest_compliance_block.h).
#include <sys/mman.h>
#include <unistd.h>

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstring>

#include "fem_internal.h"
#include "rest_compliance_block.h"
#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"

namespace tactus::sim::c0_detail {

namespace {

constexpr char kMagic[8] = {'T', 'A', 'C', 'T', 'C', '0', '\0', '\1'};
// 2: payload checksum is PayloadChecksum (1 was byte-wise FNV-1a, too slow for GB files)
// 3: C0 starts at a multiple of kPayloadAlign, after zero padding (the file is mapped)
constexpr std::uint32_t kVersion = 3;
// Bytes checksummed and checked per step of a cache load (stays cache-resident).
constexpr std::size_t kLoadChunkBytes = std::size_t{4} << 20;
// C0 starts this many bytes (a page) into the file or a multiple of it: where the file is
// mapped, at a page, its values are aligned.
constexpr std::uint64_t kPayloadAlign = 4096;

struct CacheHeader {
  char magic[8];
  std::uint32_t version;
  std::uint32_t scalar_bytes; // 8: double, 4: float
  std::uint64_t hash;         // FemBody::restHash combined with h
  std::uint64_t node_count;
  std::uint64_t surface_count;
};

// Where the parts of a cache file of s surface nodes and a d x d C0 start: the header, the
// surface node list, zero bytes up to C0 (at a multiple of kPayloadAlign), C0 (column-major),
// the checksum of everything between the header and it (PayloadChecksum; the padding is checked
// only through it: its bytes mean nothing).
struct CacheLayout {
  std::uint64_t nodes_at, padding_at, c0_at, checksum_at, size;
};
CacheLayout cacheLayout(std::uint64_t s, std::uint64_t d, std::uint64_t scalar_bytes) {
  CacheLayout at{};
  at.nodes_at = sizeof(CacheHeader);
  at.padding_at = at.nodes_at + s * sizeof(int);
  at.c0_at = (at.padding_at + kPayloadAlign - 1) / kPayloadAlign * kPayloadAlign;
  at.checksum_at = at.c0_at + d * d * scalar_bytes;
  at.size = at.checksum_at + sizeof(std::uint64_t);
  return at;
}

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

} // namespace

std::uint64_t cacheHash(const FemBody &body, double h) {
  const std::uint64_t base = body.restHash();
  return fem_detail::fnv1a(&h, sizeof(h), base);
}

bool readCache(const std::filesystem::path &path, std::uint64_t hash,
               const FemBody &body, RestBlock &blk, std::string &why) {
  const auto &surface = body.surfaceNodes();
  const std::uint64_t s = surface.size(), d = 3 * s;
  const CacheLayout at = cacheLayout(s, d, blk.scalarBytes());
  try {
    shared::InputFile in(path, "compliance cache", at.size);
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
    if (file_size != at.size) {
      why = "size " + std::to_string(file_size) + " bytes, expected " +
            std::to_string(at.size) + " (truncated or corrupt)";
      return false;
    }
    // C0 stays where the file is mapped (read-only, its pages the page cache's own): reading it
    // into fresh anonymous memory cost the kernel's zeroing of every page first, most of a
    // 1.6 GB load's time on a VM where fresh pages are dear (docs/measurements.md, "Build and test
    // time"). The writer replaces a cache by a rename, never in place, so the file mapped is the
    // one checked here. Where the file cannot be mapped it is read into C0's own memory.
    const auto d_index = static_cast<Eigen::Index>(d);
    void *const map = ::mmap(nullptr, at.size, PROT_READ, MAP_PRIVATE | MAP_POPULATE,
                             in.descriptor(), 0);
    const unsigned char *mapped = nullptr;
    if (map != MAP_FAILED) {
      blk.adopt(map, at.size, at.c0_at, d_index);
      mapped = static_cast<const unsigned char *>(map);
    } else {
      blk.resize(d_index);
    }
    // The bytes after the header in order, `n` at a time: from the mapping (copied to `dest`
    // when given), or read into `dest`.
    std::uint64_t pos = sizeof(hdr);
    const auto next = [&](void *dest, std::size_t n) -> const unsigned char * {
      shared::throwIfStopRequested("reading " + in.name());
      const unsigned char *p = nullptr;
      if (mapped != nullptr) {
        p = mapped + pos;
        if (dest != nullptr)
          std::memcpy(dest, p, n);
      } else {
        in.readExact(dest, n);
        p = static_cast<const unsigned char *>(dest);
      }
      pos += n;
      return p;
    };
    const auto reject = [&](std::string reason) {
      blk.release();
      why = std::move(reason);
      return false;
    };
    // One pass, a chunk at a time: checksum and check it while it is still in the CPU cache.
    PayloadChecksum sum;
    std::vector<int> nodes(s);
    sum.add(next(nodes.data(), s * sizeof(int)), s * sizeof(int));
    // the padding: written as zeros, checked as part of the checksum's bytes
    std::vector<unsigned char> padding(at.c0_at - at.padding_at);
    sum.add(next(padding.data(), padding.size()), padding.size());
    // the read fallback fills resize's memory; a mapped C0 is read where it lies
    auto *payload = static_cast<unsigned char *>(blk.storage.writableData());
    const std::uint64_t payload_bytes = d * d * blk.scalarBytes();
    bool finite = true;
    for (std::uint64_t done = 0; done < payload_bytes;) {
      const std::size_t n = static_cast<std::size_t>(
          std::min<std::uint64_t>(kLoadChunkBytes, payload_bytes - done));
      const unsigned char *chunk = next(mapped != nullptr ? nullptr : payload + done, n);
      sum.add(chunk, n);
      const auto count = static_cast<Eigen::Index>(n / blk.scalarBytes());
      if (blk.single)
        finite = finite && Eigen::Map<const Eigen::ArrayXf>(
                               reinterpret_cast<const float *>(chunk), count)
                               .allFinite();
      else
        finite = finite && Eigen::Map<const Eigen::ArrayXd>(
                               reinterpret_cast<const double *>(chunk), count)
                               .allFinite();
      done += n;
    }
    std::uint64_t checksum = 0;
    next(&checksum, sizeof(checksum));
    if (sum.finish() != checksum)
      return reject("checksum mismatch (corrupt)");
    if (nodes != surface)
      return reject("surface nodes differ");
    if (!finite)
      return reject("non-finite values");
    return true;
  } catch (const FileError &e) {
    blk.release();
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
    const CacheLayout at = cacheLayout(hdr.surface_count, d, blk.scalarBytes());
    const std::string padding(at.c0_at - at.padding_at, '\0');
    PayloadChecksum checksum;
    checksum.add(blk.surface.data(), blk.surface.size() * sizeof(int));
    checksum.add(padding.data(), padding.size());
    checksum.add(blk.data(), d * d * blk.scalarBytes());
    const std::uint64_t sum = checksum.finish();
    const auto bytes = [](const void *p, std::size_t n) {
      return std::string_view(static_cast<const char *>(p), n);
    };
    out.write(bytes(&hdr, sizeof(hdr)));
    out.write(bytes(blk.surface.data(), blk.surface.size() * sizeof(int)));
    out.write(padding);
    out.write(bytes(blk.data(), d * d * blk.scalarBytes()));
    out.write(bytes(&sum, sizeof(sum)));
    out.commit();
  } catch (const FileError &e) {
    spdlog::warn("compliance cache: {} (continuing without cache)", e.what());
  }
}

} // namespace tactus::sim::c0_detail
