// The instrument's terms of W added a row at a time down B's columns (tool_terms.h, buildW's
// assembly when one instrument owns every row): each entry of W's upper triangle gets the bits
// of the row-by-row sum W(i, j) += toolDot(B_i, B_j) + (c_grip g_i) g_j, the lower triangle is
// left alone, in rows of a W wider than the problem (a leading dimension above its size).
#include <gtest/gtest.h>

#include <cstring>
#include <random>
#include <vector>

#include "../../../sim_server/src/pipeline/tool_terms.h"

namespace tactus::sim {
namespace {

TEST(ToolTermsTest, RowsDownTheColumnsGiveTheRowByRowSumsBitForBit) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  for (const int m : {1, 2, 7, 37, 64}) {
    SCOPED_TRACE(m);
    ToolRows b(m, 6);
    std::vector<double> grip(static_cast<std::size_t>(m));
    for (int r = 0; r < m; ++r) {
      for (int k = 0; k < 6; ++k) b(r, k) = unit(rng) * (k < 3 ? 1.0 : 1e-2);
      grip[static_cast<std::size_t>(r)] = r % 4 == 0 ? 0.0 : unit(rng) * 3e-3;
    }
    const double c_grip = 0.37;
    const Eigen::Index ld = m + 5;
    std::vector<double> w(static_cast<std::size_t>(m * ld));
    for (double& x : w) x = unit(rng) * 1e-3;
    std::vector<double> expected = w;
    for (int i = 0; i < m; ++i) {
      const double gi = c_grip * grip[static_cast<std::size_t>(i)];
      for (int j = i; j < m; ++j) {
        expected[static_cast<std::size_t>(i * ld + j)] +=
            toolDot(b.row(i).data(), b.row(j).data()) + gi * grip[static_cast<std::size_t>(j)];
      }
    }
    ToolTerms terms;
    terms.prepare(b, grip.data(), c_grip);
    EXPECT_EQ(terms.rows(), m);
    for (int i = 0; i < m; ++i) terms.addRow(i, w.data() + i * ld);
    EXPECT_EQ(std::memcmp(w.data(), expected.data(), sizeof(double) * w.size()), 0);
  }
}

// toolDot is a . b (the order of its sums aside) and symmetric to the bit.
TEST(ToolTermsTest, ToolDotIsTheSymmetricDotProduct) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  for (int k = 0; k < 100; ++k) {
    Eigen::Matrix<double, 6, 1> a, c;
    for (int i = 0; i < 6; ++i) {
      a[i] = unit(rng);
      c[i] = unit(rng);
    }
    EXPECT_EQ(toolDot(a.data(), c.data()), toolDot(c.data(), a.data()));
    EXPECT_NEAR(toolDot(a.data(), c.data()), a.dot(c), 1e-15);
  }
}

}  // namespace
}  // namespace tactus::sim
