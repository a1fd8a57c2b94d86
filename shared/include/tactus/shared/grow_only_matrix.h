#pragma once
// GrowOnlyMatrix: a dense matrix of doubles on storage that only grows. Resizing it within the
// largest size it had neither allocates nor touches memory the process has not touched yet.
//
// Why: the contact problem's matrices follow the contact rows, whose count changes at almost
// every step. As Eigen::Matrix (a new allocation at each change of size) they took fresh pages
// from the system whenever the problem outgrew the largest so far, and a first touch of a page
// costs about 18 us of CPU on the VMs measured: up to 1900 minor page faults in one step of
// liver_grasp_23k's grasp (docs/design.md, "The contact buffers, and the rest factorisation,
// made before the first step"). reserve() sizes the storage once, at set-up, for the largest
// problem.
//
// It is an Eigen::Map of its own storage, so every Eigen expression reads and writes it as it
// would an Eigen::Matrix of the same storage order (products, blocks, rows, comparisons,
// assignment from any expression, which resizes it first). Copies are deep (their own storage,
// sized to the values copied); a move exchanges the storage. resize() leaves the values
// unspecified, as Eigen::Matrix's does; like Eigen::Matrix, an assignment whose right-hand side
// reads this matrix and changes its size is an aliasing error.

#include <Eigen/Core>

#include <algorithm>
#include <cstddef>
#include <new>
#include <vector>

namespace tactus::shared {

template <int Order = Eigen::ColMajor>
class GrowOnlyMatrix
    : public Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Order>> {
 public:
  using PlainMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Order>;
  using Map = Eigen::Map<PlainMatrix>;

  GrowOnlyMatrix() : Map(nullptr, 0, 0) {}
  GrowOnlyMatrix(const GrowOnlyMatrix& other) : Map(nullptr, 0, 0) { assign(other); }
  GrowOnlyMatrix(GrowOnlyMatrix&& other) noexcept : Map(nullptr, 0, 0) { swap(other); }
  template <class Derived>
  GrowOnlyMatrix(const Eigen::DenseBase<Derived>& other) : Map(nullptr, 0, 0) {  // NOLINT
    assign(other);
  }
  ~GrowOnlyMatrix() = default;
  GrowOnlyMatrix& operator=(const GrowOnlyMatrix& other) {
    if (this != &other) assign(other);
    return *this;
  }
  GrowOnlyMatrix& operator=(GrowOnlyMatrix&& other) noexcept {
    swap(other);
    return *this;
  }
  template <class Derived>
  GrowOnlyMatrix& operator=(const Eigen::DenseBase<Derived>& other) {
    assign(other);
    return *this;
  }

  /// The matrix resized (its values unspecified); the storage grows by at least half when it
  /// must grow. Returns the map of the new size.
  Map& resize(Eigen::Index rows, Eigen::Index cols) {
    const auto need = static_cast<std::size_t>(rows * cols);
    if (need > buf_.size()) buf_.resize(std::max(need, buf_.size() + buf_.size() / 2));
    seat(rows, cols);
    return *this;
  }
  /// resize, then every value 0.
  Map& setZero(Eigen::Index rows, Eigen::Index cols) {
    resize(rows, cols);
    Map::setZero();
    return *this;
  }
  using Map::setZero;
  /// Storage for `count` values from now on, written once (its pages are the process's); the
  /// size and the values are kept.
  void reserve(std::size_t count) {
    if (count <= buf_.size()) return;
    std::vector<double> grown(count);
    std::copy_n(this->data(), static_cast<std::size_t>(this->size()), grown.data());
    buf_.swap(grown);
    seat(this->rows(), this->cols());
  }
  /// Values the storage holds (the largest rows x cols it can take without allocating).
  std::size_t capacity() const { return buf_.size(); }
  Map& map() { return *this; }
  const Map& map() const { return *this; }
  void swap(GrowOnlyMatrix& other) noexcept {
    const Eigen::Index rows = this->rows(), cols = this->cols();
    buf_.swap(other.buf_);   // the data pointers move with the buffers
    seat(other.rows(), other.cols());
    other.seat(rows, cols);
  }

 private:
  template <class Derived>
  void assign(const Eigen::DenseBase<Derived>& other) {
    resize(other.rows(), other.cols());
    Map::operator=(other.derived());
  }
  // The map over the storage at this size (Eigen's documented way to point a Map elsewhere).
  void seat(Eigen::Index rows, Eigen::Index cols) noexcept {
    new (static_cast<Map*>(this)) Map(buf_.empty() ? nullptr : buf_.data(), rows, cols);
  }
  std::vector<double> buf_;
};

/// Storage for `count` values in `v` from now on, written once with `fill` (its pages are the
/// process's; a default-constructed Eigen matrix would write nothing), its size and values
/// kept: a later resize or assign within `count` neither allocates nor touches memory new to
/// the process. For the step's std::vector buffers, whose first sizing
/// at the first step (or the first contact) took hundreds of first-touch page faults on
/// liver_grasp_23k (docs/design.md, "The step's buffers written at set-up").
template <class T, class A>
void reserveWritten(std::vector<T, A>& v, std::size_t count, const T& fill) {
  if (v.capacity() >= count) return;
  const std::size_t size = v.size();
  v.resize(count, fill);
  v.resize(size);
}

/// m(i, j) = m(j, i) for every i > j of the square matrix m: its strict upper triangle copied
/// onto the strict lower one, tile by tile so that the strided side of the copy stays in the
/// cache (one pass over the triangle, where a copy row by row misses the cache at every value
/// of the strided side once m outgrows it). The diagonal and the upper triangle are unchanged.
template <class Derived>
void mirrorUpperToLower(Eigen::MatrixBase<Derived>& m) {
  constexpr Eigen::Index kTile = 32;
  const Eigen::Index n = m.rows();
  for (Eigen::Index i0 = 0; i0 < n; i0 += kTile) {
    const Eigen::Index i1 = std::min(n, i0 + kTile);
    for (Eigen::Index j0 = 0; j0 <= i0; j0 += kTile) {
      for (Eigen::Index i = i0; i < i1; ++i) {
        const Eigen::Index j1 = std::min(i, j0 + kTile);
        for (Eigen::Index j = j0; j < j1; ++j) m.coeffRef(i, j) = m.coeff(j, i);
      }
    }
  }
}

}  // namespace tactus::shared
