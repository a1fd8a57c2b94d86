#pragma once
// Small hand-built tissue surfaces for the contact tests (no mesh files, no extractSurface).

#include <Eigen/Core>
#include <array>
#include <vector>

#include "tactus/sim/mesh.h"

namespace tactus::sim::test {

struct TestSurface {
  SurfaceMesh surface;
  Eigen::VectorXd q;   ///< 3n, node-major
};

/// Flat grid in the plane z = z0 over [x0, x0 + nx dx] x [y0, y0 + ny dx], normals +z.
inline TestSurface flatGrid(int nx, int ny, double dx, double x0 = 0.0, double y0 = 0.0,
                            double z0 = 0.0) {
  TestSurface s;
  const int n = (nx + 1) * (ny + 1);
  s.q.resize(3 * n);
  auto id = [&](int i, int j) { return j * (nx + 1) + i; };
  for (int j = 0; j <= ny; ++j) {
    for (int i = 0; i <= nx; ++i) {
      s.q.segment<3>(3 * id(i, j)) = Eigen::Vector3d(x0 + i * dx, y0 + j * dx, z0);
    }
  }
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      // counter-clockwise seen from +z
      s.surface.triangles.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
      s.surface.triangles.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
    }
  }
  for (int i = 0; i < n; ++i) s.surface.nodes.push_back(i);
  return s;
}

/// Boundary of the box [lo, hi] split into (nx, ny, nz) cells, outward normals. All grid nodes
/// (interior ones too) are in q, like a tetrahedral mesh's nodes.
inline TestSurface boxSurface(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, int nx, int ny,
                              int nz) {
  TestSurface s;
  const std::array<int, 3> cells{nx, ny, nz};
  auto id = [&](int i, int j, int k) { return (k * (ny + 1) + j) * (nx + 1) + i; };
  const int n = (nx + 1) * (ny + 1) * (nz + 1);
  s.q.resize(3 * n);
  for (int k = 0; k <= nz; ++k) {
    for (int j = 0; j <= ny; ++j) {
      for (int i = 0; i <= nx; ++i) {
        const Eigen::Vector3d t(double(i) / nx, double(j) / ny, double(k) / nz);
        s.q.segment<3>(3 * id(i, j, k)) = lo + t.cwiseProduct(hi - lo);
      }
    }
  }
  auto pos = [&](int node) { return Eigen::Vector3d(s.q.segment<3>(3 * node)); };
  const Eigen::Vector3d centre = 0.5 * (lo + hi);
  // each face: fixed axis `a` at index 0 or cells[a]; quads over the two other axes
  for (int a = 0; a < 3; ++a) {
    const int b = (a + 1) % 3, c = (a + 2) % 3;
    for (int side = 0; side < 2; ++side) {
      const int fixed = side == 0 ? 0 : cells[a];
      for (int u = 0; u < cells[b]; ++u) {
        for (int v = 0; v < cells[c]; ++v) {
          auto node = [&](int du, int dv) {
            std::array<int, 3> ijk{};
            ijk[a] = fixed;
            ijk[b] = u + du;
            ijk[c] = v + dv;
            return id(ijk[0], ijk[1], ijk[2]);
          };
          std::array<std::array<int, 3>, 2> tris{{{node(0, 0), node(1, 0), node(1, 1)},
                                                  {node(0, 0), node(1, 1), node(0, 1)}}};
          for (auto& t : tris) {
            const Eigen::Vector3d nrm = (pos(t[1]) - pos(t[0])).cross(pos(t[2]) - pos(t[0]));
            if (nrm.dot(pos(t[0]) - centre) < 0.0) std::swap(t[1], t[2]);
            s.surface.triangles.push_back(t);
          }
        }
      }
    }
  }
  return s;
}

}  // namespace tactus::sim::test
