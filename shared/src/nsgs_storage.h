#pragma once
// The two storages of W as the NSGS driver (nsgs.cpp) reads them: dense rows (DenseW) and contact
// blocks (BlockW, over DelassusBlocks). Each gives, for contact i owning rows [r, r + k):
//   diagonalBlock(i, r, k, buf)         W(rows_i, rows_i), k x k row-major (buf or in place)
//   gatherRows(i, r, k, f, d)           d = W(rows_i, :) f
//   addColumns(i, r, k, df, delta)      delta += W(:, rows_i) df
//   addRowsTransposed(i, r, k, df, delta)  delta += W(rows_i, :)^T df (= the columns when W = W^T)
//   computeDelta(f, delta)              delta = W f + q, returns ||delta||^2
// and computeDeltaSymmetric(p, w, f, delta) below forms the same delta from rows when W = W^T.
// Not installed: only shared/src includes it.

#include <cstddef>

#include "tactus/shared/delassus_blocks.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/nsgs_kernels.h"

namespace tactus::shared::detail {

// x . y with four independent partial sums (a single chain is add-latency bound).
inline double dot(const double* x, const double* y, int n) noexcept {
  double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
  int k = 0;
  for (; k + 4 <= n; k += 4) {
    s0 += x[k] * y[k];
    s1 += x[k + 1] * y[k + 1];
    s2 += x[k + 2] * y[k + 2];
    s3 += x[k + 3] * y[k + 3];
  }
  for (; k < n; ++k) s0 += x[k] * y[k];
  return (s0 + s1) + (s2 + s3);
}

// (x0 . y, x1 . y, x2 . y) in one pass over y, two partial sums per row.
inline void dot3(const double* x0, const double* x1, const double* x2, const double* y, int n,
                 double* out) noexcept {
  double a0 = 0.0, a1 = 0.0, b0 = 0.0, b1 = 0.0, c0 = 0.0, c1 = 0.0;
  int k = 0;
  for (; k + 2 <= n; k += 2) {
    a0 += x0[k] * y[k];
    b0 += x1[k] * y[k];
    c0 += x2[k] * y[k];
    a1 += x0[k + 1] * y[k + 1];
    b1 += x1[k + 1] * y[k + 1];
    c1 += x2[k + 1] * y[k + 1];
  }
  if (k < n) {
    a0 += x0[k] * y[k];
    b0 += x1[k] * y[k];
    c0 += x2[k] * y[k];
  }
  out[0] = a0 + a1;
  out[1] = b0 + b1;
  out[2] = c0 + c1;
}

// y += B x for a rows x cols block B (row-major; 3x3 unrolled).
inline void addBlockTimes(const double* w, int rows, int cols, const double* x,
                          double* y) noexcept {
  if (rows == 3 && cols == 3) {
    y[0] += w[0] * x[0] + w[1] * x[1] + w[2] * x[2];
    y[1] += w[3] * x[0] + w[4] * x[1] + w[5] * x[2];
    y[2] += w[6] * x[0] + w[7] * x[1] + w[8] * x[2];
    return;
  }
  for (int a = 0; a < rows; ++a) {
    for (int c = 0; c < cols; ++c) y[a] += w[a * cols + c] * x[c];
  }
}

// y += B^T x for a rows x cols block B (row-major; 3x3 unrolled).
inline void addBlockTransposedTimes(const double* w, int rows, int cols, const double* x,
                                    double* y) noexcept {
  if (rows == 3 && cols == 3) {
    y[0] += w[0] * x[0] + w[3] * x[1] + w[6] * x[2];
    y[1] += w[1] * x[0] + w[4] * x[1] + w[7] * x[2];
    y[2] += w[2] * x[0] + w[5] * x[1] + w[8] * x[2];
    return;
  }
  for (int c = 0; c < cols; ++c) {
    for (int a = 0; a < rows; ++a) y[c] += w[a * cols + c] * x[a];
  }
}

class DenseW {
 public:
  explicit DenseW(const ContactProblemView& p) noexcept
      : w_(p.W), ld_(p.ld), m_(p.rows), q_(p.delta_free) {}

  const double* diagonalBlock(int /*i*/, int r, int k, double* buf) const noexcept {
    for (int a = 0; a < k; ++a) {
      for (int b = 0; b < k; ++b) buf[a * k + b] = w_[(r + a) * ld_ + r + b];
    }
    return buf;
  }

  void gatherRows(int /*i*/, int r, int k, const double* f, double* d) const noexcept {
    const double* w = w_ + r * ld_;
    if (k == 1) {
      d[0] = dot(w, f, m_);
    } else {
      dot3(w, w + ld_, w + 2 * ld_, f, m_, d);
    }
  }

  void addColumns(int /*i*/, int r, int k, const double* df, double* delta) const noexcept {
    const double* w = w_ + r;   // strided columns of the row-major W
    if (k == 1) {
      for (int j = 0; j < m_; ++j) delta[j] += w[j * ld_] * df[0];
      return;
    }
    for (int j = 0; j < m_; ++j) {
      const double* wj = w + j * ld_;
      delta[j] += wj[0] * df[0] + wj[1] * df[1] + wj[2] * df[2];
    }
  }

  void addRowsTransposed(int /*i*/, int r, int k, const double* df,
                         double* delta) const noexcept {
    // contiguous rows, in the CPU's widest kernel (nsgs_kernels.h; bit-identical to scalar)
    addRowsScaled(w_ + r * ld_, ld_, k, df, delta, m_);
  }

  double computeDelta(const double* f, double* delta) const noexcept {
    double nrm2 = 0.0;
    int j = 0;
    // three rows per pass over f (one load of f feeds three rows)
    for (; j + 3 <= m_; j += 3) {
      const double* w = w_ + j * ld_;
      dot3(w, w + ld_, w + 2 * ld_, f, m_, delta + j);
      for (int a = j; a < j + 3; ++a) {
        delta[a] += q_[a];
        nrm2 += delta[a] * delta[a];
      }
    }
    for (; j < m_; ++j) {
      delta[j] = dot(w_ + j * ld_, f, m_) + q_[j];
      nrm2 += delta[j] * delta[j];
    }
    return nrm2;
  }

 private:
  const double* w_;
  std::ptrdiff_t ld_;
  int m_;
  const double* q_;
};

class BlockW {
 public:
  BlockW(const ContactProblemView& p, const DelassusBlocks& b) noexcept
      : nc_(b.contacts()), ro_(b.rowOffset()), row_start_(b.rowStart()),
        column_(b.blockColumn()), value_start_(b.valueStart()), diag_(b.diagonalBlock()),
        column_start_(b.columnStart()), column_block_(b.columnBlock()),
        column_row_(b.columnRow()), v_(b.values()), q_(p.delta_free) {}

  const double* diagonalBlock(int i, int /*r*/, int /*k*/, double* /*buf*/) const noexcept {
    return v_ + value_start_[diag_[i]];
  }

  void gatherRows(int i, int /*r*/, int k, const double* f, double* d) const noexcept {
    d[0] = d[1] = d[2] = 0.0;
    for (int b = row_start_[i]; b < row_start_[i + 1]; ++b) {
      const int j = column_[b];
      addBlockTimes(v_ + value_start_[b], k, ro_[j + 1] - ro_[j], f + ro_[j], d);
    }
  }

  void addColumns(int i, int /*r*/, int k, const double* df, double* delta) const noexcept {
    for (int t = column_start_[i]; t < column_start_[i + 1]; ++t) {
      const int j = column_row_[t];   // block W(rows_j, rows_i), kj x k
      addBlockTimes(v_ + value_start_[column_block_[t]], ro_[j + 1] - ro_[j], k, df,
                    delta + ro_[j]);
    }
  }

  void addRowsTransposed(int i, int /*r*/, int k, const double* df,
                         double* delta) const noexcept {
    for (int b = row_start_[i]; b < row_start_[i + 1]; ++b) {
      const int j = column_[b];   // block W(rows_i, rows_j), k x kj
      addBlockTransposedTimes(v_ + value_start_[b], k, ro_[j + 1] - ro_[j], df, delta + ro_[j]);
    }
  }

  double computeDelta(const double* f, double* delta) const noexcept {
    double nrm2 = 0.0;
    for (int i = 0; i < nc_; ++i) {
      const int r = ro_[i], k = ro_[i + 1] - r;
      double d[3];
      gatherRows(i, r, k, f, d);
      for (int a = 0; a < k; ++a) {
        delta[r + a] = d[a] + q_[r + a];
        nrm2 += delta[r + a] * delta[r + a];
      }
    }
    return nrm2;
  }

 private:
  int nc_;
  const int* ro_;
  const int* row_start_;
  const int* column_;
  const std::int64_t* value_start_;
  const int* diag_;
  const int* column_start_;
  const int* column_block_;
  const int* column_row_;
  const double* v_;
  const double* q_;
};

// delta = W f + q for an exactly symmetric W, as q plus the rows of the contacts with a
// nonzero force (W f = sum_i W(rows_i, :)^T f_i): contiguous rows, and contacts at zero force
// (often most of them) cost nothing. Returns ||delta||^2.
template <class Storage>
double computeDeltaSymmetric(const ContactProblemView& p, const Storage& w, const double* f,
                             double* delta) noexcept {
  const int m = p.rows;
  for (int j = 0; j < m; ++j) delta[j] = p.delta_free[j];
  for (int i = 0; i < p.contacts; ++i) {
    const int r = p.row_offset[i];
    const int k = p.row_offset[i + 1] - r;
    bool any = false;
    for (int a = 0; a < k; ++a) any = any || f[r + a] != 0.0;
    if (any) w.addRowsTransposed(i, r, k, f + r, delta);
  }
  double nrm2 = 0.0;
  for (int j = 0; j < m; ++j) nrm2 += delta[j] * delta[j];
  return nrm2;
}

}  // namespace tactus::shared::detail
