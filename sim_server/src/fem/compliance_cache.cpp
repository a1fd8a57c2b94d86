// The compliance cache file: header, payload checksum, checked chunked reads into C0's memory,
// temp + fsync + rename writes (rest_compliance_block.h).
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

} // namespace

std::uint64_t cacheHash(const FemBody &body, double h) {
  const std::uint64_t base = body.restHash();
  return fem_detail::fnv1a(&h, sizeof(h), base);
}

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

} // namespace tactus::sim::c0_detail
