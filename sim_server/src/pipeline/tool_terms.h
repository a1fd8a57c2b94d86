#pragma once
// The instrument's part of W on its contact rows (build_w.cpp): H_tool C6 H_tool^T = B B^T with
// B = H_tool L (C6 = L L^T), and a dynamic grip's c_g g g^T, added to the upper triangle of the
// row-major W that buildW assembles in place and mirrors once (docs/design.md, "`W` assembled
// in place").

#include <Eigen/Core>

#include <vector>

namespace tactus::sim {

/// B's rows: one per contact row, the instrument's six DOFs.
using ToolRows = Eigen::Matrix<double, Eigen::Dynamic, 6, Eigen::RowMajor>;

/// a . b over six entries, summed as Eigen's dot of two 1 x 6 rows sums them in the project's
/// build (SSE2 packets of two): (p0 + (p2 + p4)) + (p1 + (p3 + p5)), p_k = a_k b_k. Written out
/// so that every way of adding the terms below gives the same bits whatever the compiler's
/// vector width.
inline double toolDot(const double* a, const double* b) {
  return (a[0] * b[0] + (a[2] * b[2] + a[4] * b[4])) + (a[1] * b[1] + (a[3] * b[3] + a[5] * b[5]));
}

/// The terms W(i, j) += toolDot(B_i, B_j) + (c_grip g_i) g_j (j >= i) of one instrument whose
/// rows are all of W's, a row of W at a time: B is kept by columns, so that adding one row's
/// terms is one pass down contiguous memory that the compiler vectorises, each entry with the
/// bits of that expression. buildW adds each row right after the tissue's block has written it
/// (TissueCompliance::setWLower's WColumnsDone), while the row is still in cache.
class ToolTerms {
 public:
  /// B (rows x 6), g (rows entries) and c_grip, kept by pointer until the last addRow.
  void prepare(const ToolRows& b, const double* grip, double c_grip);
  /// wi[j] += toolDot(B_i, B_j) + (c_grip g_i) g_j for j = i .. rows - 1 (wi: W's row i).
  void addRow(Eigen::Index i, double* wi) const;
  Eigen::Index rows() const { return rows_; }

 private:
  std::vector<double> columns_;   // B by columns: 6 x rows
  const ToolRows* b_ = nullptr;
  const double* grip_ = nullptr;
  double c_grip_ = 0.0;
  Eigen::Index rows_ = 0;
};

}  // namespace tactus::sim
