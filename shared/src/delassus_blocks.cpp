#include "tactus/shared/delassus_blocks.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "tactus/shared/grow_only_matrix.h"
#include "tactus/shared/nsgs.h"

namespace tactus::shared {
namespace {

// Whether the k_i x k_j block at (r_i, r_j) of the row-major W holds a non-zero (or NaN).
bool blockNonZero(const double* w, std::ptrdiff_t ld, int ri, int ki, int rj, int kj) noexcept {
  for (int a = 0; a < ki; ++a) {
    const double* row = w + (ri + a) * ld + rj;
    for (int c = 0; c < kj; ++c) {
      if (row[c] != 0.0) return true;   // NaN != 0 as well
    }
  }
  return false;
}

// The capacity in blocks for nc contacts at a fill (at least the diagonal blocks).
std::int64_t blockLimit(int nc, double max_fill) noexcept {
  const double limit = std::floor(max_fill * static_cast<double>(nc) * static_cast<double>(nc));
  return std::max<std::int64_t>(nc, static_cast<std::int64_t>(std::min(limit, 4e18)));
}

// The storage reserve() and reserveStorage() size: bounds clamped, blocks and values.
struct StorageSize {
  int rows = 0;
  int contacts = 0;
  std::size_t blocks = 0;
  std::size_t values = 0;   // fill x m^2 for uniform contacts, plus the diagonal blocks
};

StorageSize storageSize(int max_rows, int max_contacts, double max_fill) noexcept {
  StorageSize size;
  size.rows = std::max(max_rows, 0);
  size.contacts = std::max(max_contacts, 0);
  max_fill = std::clamp(std::isfinite(max_fill) ? max_fill : 1.0, 0.0, 1.0);
  size.blocks = static_cast<std::size_t>(blockLimit(size.contacts, max_fill));
  size.values = static_cast<std::size_t>(
      static_cast<std::int64_t>(std::floor(max_fill * static_cast<double>(size.rows) *
                                           static_cast<double>(size.rows))) +
      9 * static_cast<std::int64_t>(size.contacts));
  return size;
}

}  // namespace

DelassusBlocks::DelassusBlocks(int max_rows, int max_contacts, double max_fill) {
  reserve(max_rows, max_contacts, max_fill);
}

void DelassusBlocks::reserve(int max_rows, int max_contacts, double max_fill) {
  const StorageSize size = storageSize(max_rows, max_contacts, max_fill);
  const auto n1 = static_cast<std::size_t>(size.contacts) + 1;
  row_offset_.assign(n1, 0);
  row_start_.assign(n1, 0);
  column_start_.assign(n1, 0);
  diagonal_block_.assign(static_cast<std::size_t>(size.contacts), 0);
  row_bits_.assign(static_cast<std::size_t>(size.rows), 0);
  block_column_.assign(size.blocks, 0);
  value_start_.assign(size.blocks, 0);
  column_block_.assign(size.blocks, 0);
  column_row_.assign(size.blocks, 0);
  values_.assign(size.values, 0.0);
  max_rows_ = size.rows;
  max_contacts_ = size.contacts;
  clear();
}

void DelassusBlocks::reserveStorage(int max_rows, int max_contacts, double max_fill) {
  const StorageSize size = storageSize(max_rows, max_contacts, max_fill);
  const auto n1 = static_cast<std::size_t>(size.contacts) + 1;
  for (auto* v : {&row_offset_, &row_start_, &column_start_}) reserveWritten(*v, n1, 0);
  reserveWritten(diagonal_block_, static_cast<std::size_t>(size.contacts), 0);
  reserveWritten(row_bits_, static_cast<std::size_t>(size.rows), std::uint64_t{0});
  for (auto* v : {&block_column_, &column_block_, &column_row_}) reserveWritten(*v, size.blocks, 0);
  reserveWritten(value_start_, size.blocks, std::int64_t{0});
  reserveWritten(values_, size.values, 0.0);
}

void DelassusBlocks::clear() noexcept {
  contacts_ = 0;
  rows_ = 0;
  blocks_ = 0;
}

double DelassusBlocks::fill() const noexcept {
  if (contacts_ == 0) return 0.0;
  return static_cast<double>(blocks_) /
         (static_cast<double>(contacts_) * static_cast<double>(contacts_));
}

bool DelassusBlocks::assign(const ContactProblemView& dense, double max_fill) noexcept {
  clear();
  const int nc = dense.contacts;
  const int m = dense.rows;
  const int* ro = dense.row_offset;
  if (nc <= 0 || m <= 0 || ro == nullptr || dense.W == nullptr || dense.ld < m) return false;
  if (nc > max_contacts_ || m > max_rows_) return false;
  if (ro[0] != 0 || ro[nc] != m) return false;
  for (int i = 0; i < nc; ++i) {
    const int k = ro[i + 1] - ro[i];
    if (k != 1 && k != 3) return false;
  }
  // the fill rule (stored blocks <= max_fill nc^2, diagonals included) and the capacity
  const double fill_limit =
      std::floor((std::isfinite(max_fill) ? max_fill : 1.0) * static_cast<double>(nc) * nc);
  const std::int64_t max_blocks = std::min<std::int64_t>(
      static_cast<std::int64_t>(std::clamp(fill_limit, 0.0, 4e18)),
      static_cast<std::int64_t>(block_column_.size()));
  const auto max_values = static_cast<std::int64_t>(values_.size());
  const std::ptrdiff_t ld = dense.ld;
  // pass 1: the non-zero blocks' columns (a dense W stops here after max_fill of its blocks,
  // one comparison each, without copying values)
  std::int64_t nb = 0;
  std::int64_t nv = 0;
  const bool all3 = m == 3 * nc;
  std::uint64_t* bits = row_bits_.data();
  for (int i = 0; i < nc; ++i) {
    const int ri = ro[i], ki = ro[i + 1] - ri;
    row_offset_[static_cast<std::size_t>(i)] = ri;
    row_start_[static_cast<std::size_t>(i)] = static_cast<int>(nb);
    if (all3) {
      // 3 rows per contact: per column, the OR of the 3 rows' bit patterns without the sign
      // bit (non-zero for any value but +-0, NaN included), in one contiguous branch-free pass
      const double* w0 = dense.W + ri * ld;
      const double* w1 = w0 + ld;
      const double* w2 = w1 + ld;
      for (int k = 0; k < m; ++k) {
        bits[k] = (std::bit_cast<std::uint64_t>(w0[k]) | std::bit_cast<std::uint64_t>(w1[k]) |
                   std::bit_cast<std::uint64_t>(w2[k])) << 1;
      }
    }
    for (int j = 0; j < nc; ++j) {
      const int rj = ro[j], kj = ro[j + 1] - rj;
      const bool stored =
          j == i || (all3 ? (bits[rj] | bits[rj + 1] | bits[rj + 2]) != 0
                          : blockNonZero(dense.W, ld, ri, ki, rj, kj));
      if (!stored) continue;
      if (nb >= max_blocks || nv + ki * kj > max_values) return false;   // too full: dense
      if (j == i) diagonal_block_[static_cast<std::size_t>(i)] = static_cast<int>(nb);
      block_column_[static_cast<std::size_t>(nb)] = j;
      value_start_[static_cast<std::size_t>(nb)] = nv;
      nv += ki * kj;
      ++nb;
    }
  }
  row_offset_[static_cast<std::size_t>(nc)] = m;
  row_start_[static_cast<std::size_t>(nc)] = static_cast<int>(nb);
  // pass 2: their values
  for (int i = 0; i < nc; ++i) {
    const int ri = ro[i], ki = ro[i + 1] - ri;
    for (int b = row_start_[i]; b < row_start_[i + 1]; ++b) {
      const int j = block_column_[static_cast<std::size_t>(b)];
      const int rj = ro[j], kj = ro[j + 1] - rj;
      double* out = values_.data() + value_start_[static_cast<std::size_t>(b)];
      for (int a = 0; a < ki; ++a) {
        const double* row = dense.W + (ri + a) * ld + rj;
        for (int c = 0; c < kj; ++c) out[a * kj + c] = row[c];
      }
    }
  }
  // by-column index (counting sort of the blocks by column; rows stay increasing)
  std::fill_n(column_start_.begin(), nc + 1, 0);
  for (std::int64_t b = 0; b < nb; ++b) {
    ++column_start_[static_cast<std::size_t>(block_column_[static_cast<std::size_t>(b)]) + 1];
  }
  for (int j = 0; j < nc; ++j) column_start_[j + 1] += column_start_[j];
  for (int i = 0; i < nc; ++i) {
    for (int b = row_start_[i]; b < row_start_[i + 1]; ++b) {
      // column_start_[j] serves as the cursor of column j, restored below
      const int t = column_start_[block_column_[b]]++;
      column_block_[t] = b;
      column_row_[t] = i;
    }
  }
  for (int j = nc; j > 0; --j) column_start_[j] = column_start_[j - 1];
  column_start_[0] = 0;
  contacts_ = nc;
  rows_ = m;
  blocks_ = static_cast<int>(nb);
  return true;
}

ContactProblemView chooseStorage(const ContactProblemView& dense,
                                 DelassusBlocks& storage) noexcept {
  ContactProblemView view = dense;
  view.blocks = storage.assign(dense) ? &storage : nullptr;
  return view;
}

}  // namespace tactus::shared
