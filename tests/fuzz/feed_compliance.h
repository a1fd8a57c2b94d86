#pragma once
// Fuzz target for the compliance cache loader (sim_server/src/fem/compliance.cpp, readCache),
// reached through makeCompliance with a cache file written into a temporary directory for a tiny
// box mesh (8 nodes). Shared by the libFuzzer harness (compliance_cache_fuzz.cpp) and the
// regression test (tests/unit/fem).
//
// Input layout: byte 0 holds flags, the rest is the cache file.
//   bit 0: overwrite the header hash (bytes 16..23 of the file) with this body's valid hash;
//   bit 1: recompute the trailing payload checksum (bytes 40..size-8; see checksum());
//   bit 2: ask for a single-precision (float) model instead of double.
// Without bits 0/1 almost every mutation stops at the hash or checksum check; with them the
// fuzzer reaches the size, node-list and finiteness checks behind.
//
// Contract checked: a cache file of any content is either loaded or rejected and rebuilt; it
// never throws (not even tactus::Error: the documented behaviour is "rebuilt, never trusted"),
// and the resulting model gives a finite W.

#include <unistd.h>

#include <Eigen/Core>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "tactus/sim/compliance.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/mesh_gen.h"

namespace tactus::fuzz {

/// A tiny FEM body and a private temporary cache directory (removed by the destructor).
class ComplianceCacheTarget {
 public:
  static constexpr std::size_t kHashOffset = 16;   ///< CacheHeader::hash
  static constexpr std::size_t kHeaderBytes = 40;  ///< sizeof(CacheHeader)
  static constexpr unsigned char kStampHash = 1, kFixChecksum = 2, kSingle = 4;

  ComplianceCacheTarget() {
    std::string templ = (std::filesystem::temp_directory_path() / "tactus_fuzz_XXXXXX").string();
    if (::mkdtemp(templ.data()) == nullptr) throw std::runtime_error("mkdtemp failed");
    dir_ = templ;
    mesh_ = sim::makeBoxTetMesh(1, 1, 1, Eigen::Vector3d(0.02, 0.02, 0.02));
    sim::FemMaterial material;
    material.young_pa = 5000.0;
    material.poisson = 0.4;
    body_ = std::make_unique<sim::FemBody>(mesh_, material, std::vector<int>{0, 1}, nullptr);
    // one clean build per precision: gives the valid file (and so the hash) to start from
    for (int single = 0; single < 2; ++single) {
      const auto opt = options(single != 0);
      std::filesystem::remove(sim::complianceCachePath(*body_, opt));
      sim::makeCompliance(sim::ComplianceKind::kWarped, *body_, opt);
      valid_[single] = readFile(sim::complianceCachePath(*body_, opt));
      if (valid_[single].size() < kHeaderBytes + 8) throw std::runtime_error("no cache written");
    }
  }
  ~ComplianceCacheTarget() {
    std::error_code ec;
    std::filesystem::remove_all(dir_, ec);
  }
  ComplianceCacheTarget(const ComplianceCacheTarget&) = delete;
  ComplianceCacheTarget& operator=(const ComplianceCacheTarget&) = delete;

  /// The cache file a clean build writes (double or float), as a fuzz input with `flags`.
  std::string validInput(bool single, unsigned char flags) const {
    return std::string(1, static_cast<char>(flags)) + valid_[single ? 1 : 0];
  }

  /// Writes the cache from `input` (layout above), builds a warped model and checks it. Returns
  /// true when the model was loaded from the cache; throws std::logic_error on a broken contract.
  bool feed(const std::string& input) {
    if (input.empty()) return false;
    const auto flags = static_cast<unsigned char>(input[0]);
    const bool single = (flags & kSingle) != 0;
    std::string file = input.substr(1);
    const std::string& valid = valid_[single ? 1 : 0];
    if ((flags & kStampHash) && file.size() >= kHashOffset + 8) {
      std::memcpy(file.data() + kHashOffset, valid.data() + kHashOffset, 8);
    }
    if ((flags & kFixChecksum) && file.size() >= kHeaderBytes + 8) {
      const std::uint64_t sum = checksum(file.data() + kHeaderBytes, file.size() - kHeaderBytes - 8);
      std::memcpy(file.data() + file.size() - 8, &sum, 8);
    }
    const auto opt = options(single);
    {
      std::ofstream out(sim::complianceCachePath(*body_, opt), std::ios::binary | std::ios::trunc);
      out.write(file.data(), static_cast<std::streamsize>(file.size()));
      if (!out) throw std::runtime_error("cannot write the fuzz cache file");
    }
    std::unique_ptr<sim::TissueCompliance> model;
    try {
      model = sim::makeCompliance(sim::ComplianceKind::kWarped, *body_, opt);
    } catch (const std::exception& e) {
      throw std::logic_error(std::string("makeCompliance threw on a cache file: ") + e.what());
    }
    const sim::ComplianceBuildInfo info = model->buildInfo();
    if (info.loaded_from_cache == info.cache_rejected) {
      throw std::logic_error("cache neither loaded nor rejected (or both)");
    }
    // one row on the corner opposite the fixed nodes: W must be finite and positive
    std::array<sim::TissueRow, 1> rows{};
    rows[0].node = {7, -1, -1};
    rows[0].weight = {1.0, 0.0, 0.0};
    rows[0].dir = Eigen::Vector3d(0.0, 0.0, 1.0);
    model->update(*body_);
    Eigen::MatrixXd w = Eigen::MatrixXd::Zero(1, 1);
    model->addW(rows, w);
    if (!std::isfinite(w(0, 0))) throw std::logic_error("W not finite after loading the cache");
    return info.loaded_from_cache;
  }

 private:
  sim::ComplianceOptions options(bool single) const {
    sim::ComplianceOptions opt;
    opt.h_s = 0.01;
    opt.cache_dir = dir_;
    opt.show_progress = false;
    opt.cache_name = single ? "fuzz_f" : "fuzz_d";
    opt.c0_single_precision = single;
    return opt;
  }
  static std::string readFile(const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  // 64-bit FNV-1a
  static std::uint64_t fnv1a(const void* data, std::size_t bytes,
                             std::uint64_t h = 0xcbf29ce484222325ull) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < bytes; ++i) {
      h ^= p[i];
      h *= 0x100000001b3ull;
    }
    return h;
  }
  // The cache's payload checksum (formats 2 and 3; in 3 it covers the padding before C0 too):
  // four lanes over 8-byte words, lane i taking words i, i + 4, ...; the 0-31 tail bytes, and the
  // byte count, folded in with FNV-1a.
  static std::uint64_t checksum(const char* data, std::size_t bytes) {
    std::uint64_t lane[4] = {0xcbf29ce484222325ull, 0x84222325cbf29ce4ull, 0x9e3779b97f4a7c15ull,
                             0xc2b2ae3d27d4eb4full};
    const std::size_t whole = bytes / 32 * 32;
    for (std::size_t at = 0; at < whole; at += 8) {
      std::uint64_t w = 0;
      std::memcpy(&w, data + at, 8);
      auto& l = lane[(at / 8) % 4];
      l = (l ^ w) * 0x100000001b3ull;
    }
    std::uint64_t h = fnv1a(lane, sizeof(lane));
    h = fnv1a(data + whole, bytes - whole, h);
    const std::uint64_t count = bytes;
    return fnv1a(&count, sizeof(count), h);
  }

  std::filesystem::path dir_;
  sim::TetMesh mesh_;
  std::unique_ptr<sim::FemBody> body_;
  std::array<std::string, 2> valid_;
};

}  // namespace tactus::fuzz
