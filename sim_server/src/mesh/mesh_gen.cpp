#include "tactus/sim/mesh_gen.h"

#include <Eigen/LU>
#include <array>
#include <string>
#include <utility>

#include "tactus/shared/error.h"

namespace tactus::sim {

namespace {

// Signed volume times 6 of the tet (a, b, c, d).
double orientedVolume6(const Eigen::Matrix3Xd& x, const std::array<int, 4>& t) {
  Eigen::Matrix3d d;
  d << x.col(t[1]) - x.col(t[0]), x.col(t[2]) - x.col(t[0]), x.col(t[3]) - x.col(t[0]);
  return d.determinant();
}

}  // namespace

TetMesh makeBoxTetMesh(int nx, int ny, int nz, const Eigen::Vector3d& size_m,
                       const Eigen::Vector3d& origin_m, HexSplit split) {
  if (nx < 1 || ny < 1 || nz < 1) {
    throw Error("makeBoxTetMesh: cell counts must be >= 1 (got " + std::to_string(nx) + ", " +
                std::to_string(ny) + ", " + std::to_string(nz) + ")");
  }
  if (!(size_m.minCoeff() > 0.0)) {
    throw Error("makeBoxTetMesh: box size must be positive in every axis");
  }
  TetMesh mesh;
  mesh.source = "box(" + std::to_string(nx) + "x" + std::to_string(ny) + "x" +
                std::to_string(nz) + ")";
  const int sx = nx + 1, sy = ny + 1, sz = nz + 1;
  mesh.nodes.resize(3, static_cast<Eigen::Index>(sx) * sy * sz);
  auto id = [&](int i, int j, int k) { return i + sx * (j + sy * k); };
  // nodes on the regular grid
  for (int k = 0; k < sz; ++k)
    for (int j = 0; j < sy; ++j)
      for (int i = 0; i < sx; ++i)
        mesh.nodes.col(id(i, j, k)) =
            origin_m + Eigen::Vector3d(size_m.x() * i / nx, size_m.y() * j / ny,
                                       size_m.z() * k / nz);

  // local corner c = bx + 2 by + 4 bz
  static constexpr int kSixTets[6][4] = {{0, 1, 3, 7}, {0, 1, 5, 7}, {0, 2, 3, 7},
                                         {0, 2, 6, 7}, {0, 4, 5, 7}, {0, 4, 6, 7}};
  static constexpr int kFiveEven[5][4] = {{1, 2, 4, 7}, {0, 1, 2, 4}, {3, 1, 2, 7},
                                          {5, 1, 4, 7}, {6, 2, 4, 7}};
  static constexpr int kFiveOdd[5][4] = {{0, 3, 5, 6}, {1, 0, 3, 5}, {2, 0, 3, 6},
                                         {4, 0, 5, 6}, {7, 3, 5, 6}};
  mesh.tets.reserve(static_cast<std::size_t>(nx) * ny * nz * (split == HexSplit::kSix ? 6 : 5));
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) {
        int corner[8];
        for (int c = 0; c < 8; ++c) corner[c] = id(i + (c & 1), j + ((c >> 1) & 1), k + (c >> 2));
        auto add = [&](const int* local) {
          std::array<int, 4> t{corner[local[0]], corner[local[1]], corner[local[2]],
                               corner[local[3]]};
          // make every tet positively oriented
          if (orientedVolume6(mesh.nodes, t) < 0.0) std::swap(t[2], t[3]);
          mesh.tets.push_back(t);
        };
        if (split == HexSplit::kSix) {
          for (const auto& t : kSixTets) add(t);
        } else {
          const bool even = ((i + j + k) % 2) == 0;
          for (int t = 0; t < 5; ++t) add(even ? kFiveEven[t] : kFiveOdd[t]);
        }
      }
  return mesh;
}

}  // namespace tactus::sim
