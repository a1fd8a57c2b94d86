// shared::GrowOnlyMatrix (grow_only_matrix.h): resizing within its storage keeps the storage (no
// allocation), it reads and writes as an Eigen matrix of its storage order, assignment from an
// expression resizes it, copies are deep and moves exchange the storage, reserve keeps size and
// values.
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <utility>

#include "tactus/shared/grow_only_matrix.h"

namespace tactus::shared {
namespace {

TEST(GrowOnlyMatrix, ResizingWithinItsStorageKeepsTheStorage) {
  GrowOnlyMatrix<Eigen::RowMajor> m;
  EXPECT_EQ(m.rows(), 0);
  m.reserve(100);
  EXPECT_EQ(m.capacity(), 100u);
  const double* storage = m.data();
  for (const auto& [r, c] : {std::pair{5, 7}, {10, 10}, {1, 3}, {9, 11}, {0, 0}, {4, 25}}) {
    m.setZero(r, c);
    EXPECT_EQ(m.rows(), r);
    EXPECT_EQ(m.cols(), c);
    EXPECT_EQ(m.capacity(), 100u);
    if (r * c > 0) {
      EXPECT_EQ(m.data(), storage) << r << " x " << c;
    }
    EXPECT_TRUE((m.array() == 0.0).all());
  }
  m.resize(11, 10);   // beyond: grows by at least half
  EXPECT_GE(m.capacity(), 150u);
  EXPECT_EQ(m.size(), 110);
}

TEST(GrowOnlyMatrix, ReadsAndWritesAsAnEigenMatrixOfItsOrder) {
  GrowOnlyMatrix<Eigen::RowMajor> w;
  w.setZero(2, 3);
  w(0, 1) = 5.0;
  w(1, 0) = -2.0;
  EXPECT_EQ(w.data()[1], 5.0);   // row-major
  EXPECT_EQ(w.data()[3], -2.0);
  GrowOnlyMatrix<Eigen::ColMajor> c;
  c.setZero(2, 3);
  c(0, 1) = 5.0;
  EXPECT_EQ(c.data()[2], 5.0);   // column-major

  const Eigen::MatrixXd a = Eigen::MatrixXd::Random(4, 4);
  w = a * a.transpose();   // resized to 4 x 4
  ASSERT_EQ(w.rows(), 4);
  ASSERT_EQ(w.cols(), 4);
  const Eigen::MatrixXd expected = a * a.transpose();
  EXPECT_TRUE(w == expected);
  const Eigen::Vector4d v(1.0, 2.0, 3.0, 4.0);
  EXPECT_TRUE((w * v).isApprox(expected * v));
  w.block(1, 1, 2, 2).setConstant(3.0);
  EXPECT_EQ(w(2, 2), 3.0);
  EXPECT_EQ(w(1, 2), 3.0);
  EXPECT_EQ(w(1, 0), expected(1, 0));   // outside the block: kept
  EXPECT_EQ(w(1, 3), expected(1, 3));
}

TEST(GrowOnlyMatrix, CopiesAreDeepAndMovesExchangeTheStorage) {
  GrowOnlyMatrix<Eigen::RowMajor> a;
  a = Eigen::MatrixXd::Constant(3, 2, 1.5);
  GrowOnlyMatrix<Eigen::RowMajor> b = a;
  EXPECT_NE(b.data(), a.data());
  b(0, 0) = 7.0;
  EXPECT_EQ(a(0, 0), 1.5);
  EXPECT_TRUE(a == Eigen::MatrixXd::Constant(3, 2, 1.5));

  b.reserve(64);
  const double* storage = b.data();
  GrowOnlyMatrix<Eigen::RowMajor> c = std::move(b);
  EXPECT_EQ(c.data(), storage);
  EXPECT_EQ(c.capacity(), 64u);
  EXPECT_EQ(c(0, 0), 7.0);
  EXPECT_EQ(c.rows(), 3);

  a.swap(c);
  EXPECT_EQ(a.data(), storage);
  EXPECT_EQ(a(0, 0), 7.0);
  EXPECT_EQ(c(0, 0), 1.5);

  GrowOnlyMatrix<Eigen::RowMajor> big;
  big.reserve(64);
  const double* big_storage = big.data();
  big = c;   // a copy into storage large enough keeps it
  EXPECT_EQ(big.data(), big_storage);
  EXPECT_TRUE(big == c);
}

// The strict upper triangle copied onto the strict lower one, for sizes around the tile's (32)
// and a row-major map as buildW's W; the diagonal and the upper triangle unchanged.
TEST(GrowOnlyMatrix, MirrorUpperToLowerCopiesTheUpperTriangle) {
  for (int n : {0, 1, 2, 31, 32, 33, 70, 97}) {
    const Eigen::MatrixXd values = Eigen::MatrixXd::Random(n, n);
    GrowOnlyMatrix<Eigen::RowMajor> m;
    m = values;
    mirrorUpperToLower(m.map());
    for (int i = 0; i < n; ++i)
      for (int j = 0; j < n; ++j)
        ASSERT_EQ(m(i, j), i <= j ? values(i, j) : values(j, i))
            << n << ": (" << i << ", " << j << ")";
    Eigen::MatrixXd col = values;
    mirrorUpperToLower(col);
    EXPECT_TRUE(col == Eigen::MatrixXd(m.map())) << n;
  }
}

// reserveWritten gives the storage and keeps the size and values: a resize or assign within it
// keeps the data where it is.
TEST(GrowOnlyMatrix, ReserveWrittenKeepsTheSizeAndTheValues) {
  std::vector<Eigen::Matrix3d> v(3, Eigen::Matrix3d::Identity());
  reserveWritten(v, 1000, Eigen::Matrix3d(Eigen::Matrix3d::Zero()));
  EXPECT_EQ(v.size(), 3u);
  EXPECT_GE(v.capacity(), 1000u);
  for (const Eigen::Matrix3d& x : v) EXPECT_TRUE(x == Eigen::Matrix3d::Identity());
  const Eigen::Matrix3d* storage = v.data();
  v.assign(1000, Eigen::Matrix3d::Constant(2.0));
  EXPECT_EQ(v.data(), storage);
  std::vector<int> empty;
  reserveWritten(empty, 50, 0);
  EXPECT_TRUE(empty.empty());
  EXPECT_GE(empty.capacity(), 50u);
}

TEST(GrowOnlyMatrix, ReserveKeepsTheSizeAndTheValues) {
  GrowOnlyMatrix<Eigen::ColMajor> m;
  const Eigen::MatrixXd values = Eigen::MatrixXd::Random(3, 4);
  m = values;
  m.reserve(1000);
  EXPECT_EQ(m.capacity(), 1000u);
  EXPECT_EQ(m.rows(), 3);
  EXPECT_EQ(m.cols(), 4);
  EXPECT_TRUE(m == values);
}

}  // namespace
}  // namespace tactus::shared
