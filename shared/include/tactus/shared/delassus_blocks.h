#pragma once
// The Delassus operator W stored by contact blocks, for NSGS (see nsgs.h).
//
// W couples two contacts through the block W(rows_i, rows_j) (3x3 for two 3-row contacts, 1x1,
// 1x3 or 3x1 otherwise). One tissue's warped compliance H C H^T couples every contact with every
// other (all blocks non-zero): the dense row-major W suits it. Contacts on several bodies
// (several tissues, instruments, FCLIB's multi-body problems) couple only through a shared body:
// most blocks are zero (4 % non-zero on FCLIB's 225-570-contact problems) and a sweep over the
// dense W streams mostly zeros. DelassusBlocks keeps only the non-zero blocks, compressed by
// block row (CSR over contacts), with a by-column index for the column update.
//
// Layout (after assign): block b (0 <= b < blocks()) is W(rows_i, rows_j) for i its block row,
// j = blockColumn()[b]; its k_i x k_j values are row-major at values() + valueStart()[b].
// Block row i holds blocks [rowStart()[i], rowStart()[i + 1]) in increasing j, always including
// its diagonal block diagonalBlock()[i] (stored even when zero). Block column j lists the blocks
// columnBlock()[t] of rows columnRow()[t] for t in [columnStart()[j], columnStart()[j + 1]).
//
// Choice (chooseStorage): a problem whose block fill (stored blocks / nc^2) is at most
// kBlockSparseMaxFill is solved on the blocks, any other on the dense W; see the constant for the
// measurement behind it. Both storages give the same iterates up to rounding.
//
// Where the conversion happens: the simulation builds W dense (H C H^T) and the shared segment
// carries it dense; the haptic loop converts once per adopted snapshot into its preallocated
// DelassusBlocks (haptic_loop.h, AttachedSegment) - one scan of W, about the entry pass the first
// solve on a new snapshot makes anyway - so the segment format is unchanged.
//
// Real-time: reserve() allocates; assign() and chooseStorage() never allocate, lock or throw.

#include <cstdint>
#include <vector>

namespace tactus::shared {

struct ContactProblemView;

/// Block fill (stored blocks / nc^2) at or below which NSGS uses DelassusBlocks. Measured
/// (tests/bench/nsgs_bench.cpp, BM_NsgsStorage: the dense surface problem with its coupling cut
/// beyond a radius, 450 rows, symmetric row update on both storages, best-of CPU time): a sweep
/// on the blocks costs 0.44x the dense sweep at fill 0.03, 0.52x at 0.11, 0.70x at 0.21,
/// 0.88-0.94x at 0.32, 1.1-1.4x at 0.45 and 1.6-2.0x at 0.7-1 (a sweep has a fixed cost of the
/// 150 local solves, about 15 us, and a block costs about twice a dense row's streaming per
/// value). So the crossover lies between 0.32 and 0.45; 0.3 picks the blocks only where they
/// were measured faster. The conversion costs 51-88 us at fills 0.03-0.21 (1.4-2.4 dense W
/// streams); a fuller W is given up after 17-41 us.
inline constexpr double kBlockSparseMaxFill = 0.3;

class DelassusBlocks {
 public:
  DelassusBlocks() = default;
  DelassusBlocks(int max_rows, int max_contacts, double max_fill = kBlockSparseMaxFill);
  /// Capacity for problems up to max_rows / max_contacts whose fill is at most max_fill
  /// (allocates; not real-time).
  void reserve(int max_rows, int max_contacts, double max_fill = kBlockSparseMaxFill);
  /// Storage for reserve(max_rows, max_contacts, max_fill), written now (its pages the
  /// process's), the capacity reserve() gave left as it is: a later reserve() within these
  /// bounds neither allocates nor touches fresh pages, and assign() decides as it would have
  /// (the capacity it checks is reserve()'s).
  void reserveStorage(int max_rows, int max_contacts, double max_fill = kBlockSparseMaxFill);

  /// Copies the non-zero blocks of dense.W (one pass over W; a NaN counts as non-zero). Returns
  /// false, and then holds no problem, when the view is inconsistent (see solveNsgs' kEmpty),
  /// larger than the capacity, or its block fill exceeds max_fill. Allocation-free.
  bool assign(const ContactProblemView& dense, double max_fill = kBlockSparseMaxFill) noexcept;
  /// Drops the problem held (holds() becomes false).
  void clear() noexcept;

  bool holds() const noexcept { return contacts_ > 0; }
  int contacts() const noexcept { return contacts_; }
  int rows() const noexcept { return rows_; }
  int blocks() const noexcept { return blocks_; }
  /// blocks() / contacts()^2 (0 when empty)
  double fill() const noexcept;

  const int* rowOffset() const noexcept { return row_offset_.data(); }
  const int* rowStart() const noexcept { return row_start_.data(); }
  const int* blockColumn() const noexcept { return block_column_.data(); }
  const std::int64_t* valueStart() const noexcept { return value_start_.data(); }
  const int* diagonalBlock() const noexcept { return diagonal_block_.data(); }
  const int* columnStart() const noexcept { return column_start_.data(); }
  const int* columnBlock() const noexcept { return column_block_.data(); }
  const int* columnRow() const noexcept { return column_row_.data(); }
  const double* values() const noexcept { return values_.data(); }

 private:
  int contacts_ = 0;
  int rows_ = 0;
  int blocks_ = 0;
  int max_rows_ = 0;
  int max_contacts_ = 0;
  std::vector<int> row_offset_;          // nc + 1 (copy of the view's)
  std::vector<int> row_start_;           // nc + 1
  std::vector<int> block_column_;        // per block
  std::vector<std::int64_t> value_start_;  // per block
  std::vector<int> diagonal_block_;      // nc
  std::vector<int> column_start_;        // nc + 1
  std::vector<int> column_block_;        // per block, grouped by column
  std::vector<int> column_row_;          // per block, grouped by column
  std::vector<double> values_;
  std::vector<std::uint64_t> row_bits_;  // scratch of assign(): per column of a block row, m
};

/// The view NSGS should solve: `dense` with .blocks = &storage when storage.assign(dense)
/// succeeds (fill at most kBlockSparseMaxFill, within the capacity), else `dense` unchanged
/// (.blocks null, storage cleared). Allocation-free.
ContactProblemView chooseStorage(const ContactProblemView& dense,
                                 DelassusBlocks& storage) noexcept;

}  // namespace tactus::shared
