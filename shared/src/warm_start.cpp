// Carried warm start across snapshots (warm_start.h).
#include "tactus/shared/warm_start.h"

#include <algorithm>

namespace tactus::shared {
namespace {

std::uint64_t slotOf(std::uint64_t id) noexcept {
  // splitmix64's finaliser: contact ids pack feature and tissue indices in few bits
  id ^= id >> 30;
  id *= 0xbf58476d1ce4e5b9ULL;
  id ^= id >> 27;
  id *= 0x94d049bb133111ebULL;
  return id ^ (id >> 31);
}

}  // namespace

SnapshotWarmStart::SnapshotWarmStart(int max_contacts, int max_rows)
    : max_contacts_(std::max(max_contacts, 0)),
      max_rows_(std::max(max_rows, 0)),
      row_offset_(static_cast<std::size_t>(max_contacts_) + 1, 0),
      f_star_(static_cast<std::size_t>(max_rows_), 0.0),
      correction_(static_cast<std::size_t>(max_rows_), 0.0) {
  std::size_t slots = 2;   // a power of two, at least twice the contacts: short probes
  while (slots < 2 * static_cast<std::size_t>(max_contacts_)) slots *= 2;
  keys_.assign(slots, 0);
  values_.assign(slots, 0);
  stamps_.assign(slots, 0);
  mask_ = slots - 1;
}

int SnapshotWarmStart::find(std::uint64_t id) const noexcept {
  for (std::uint64_t s = slotOf(id) & mask_;; s = (s + 1) & mask_) {
    if (stamps_[s] != stamp_) return -1;
    if (keys_[s] == id) return values_[s];
  }
}

int SnapshotWarmStart::adopt(const SnapshotView& snap, const double* last_solve,
                             double* f_out) noexcept {
  return adopt(snap.contacts(), snap.rows(), snap.rowOffset(), snap.contactId(), snap.f(),
               last_solve, f_out);
}

int SnapshotWarmStart::adopt(int contacts, int rows, const std::int32_t* row_offset,
                             const std::uint64_t* ids, const double* f_star,
                             const double* last_solve, double* f_out) noexcept {
  rows = std::clamp(rows, 0, max_rows_);
  contacts = std::max(contacts, 0);
  // the previous snapshot's correction first: last_solve may be f_out
  const int prev_rows = contacts_ > 0 ? row_offset_[static_cast<std::size_t>(contacts_)] : 0;
  const bool carry = last_solve != nullptr && contacts_ > 0;
  if (carry) {
    for (int r = 0; r < prev_rows; ++r) {
      correction_[static_cast<std::size_t>(r)] = last_solve[r] - f_star_[static_cast<std::size_t>(r)];
    }
  }
  std::copy_n(f_star, rows, f_out);
  // offsets from 0 to rows in steps of 1-3 rows (a corrupt snapshot is neither carried into nor
  // remembered)
  bool fits = contacts <= max_contacts_ && row_offset[0] == 0 && row_offset[contacts] == rows;
  for (int c = 0; fits && c < contacts; ++c) {
    const int n = row_offset[c + 1] - row_offset[c];
    fits = n >= 1 && n <= 3;
  }
  int carried = 0;
  if (carry && fits) {
    for (int c = 0; c < contacts; ++c) {
      const int j = find(ids[c]);
      if (j < 0) continue;
      const int r0 = row_offset[c], n = row_offset[c + 1] - r0;
      const int q0 = row_offset_[static_cast<std::size_t>(j)];
      if (n != row_offset_[static_cast<std::size_t>(j) + 1] - q0) continue;   // friction changed
      for (int k = 0; k < n; ++k) f_out[r0 + k] += correction_[static_cast<std::size_t>(q0 + k)];
      ++carried;
    }
  }
  // remember this snapshot (one that does not fit is forgotten: the next one starts from f*)
  contacts_ = 0;
  if (!fits) return carried;
  if (++stamp_ == 0) {   // wrapped: clear the stamps once every 2^32 snapshots
    std::fill(stamps_.begin(), stamps_.end(), 0u);
    stamp_ = 1;
  }
  for (int c = 0; c < contacts; ++c) {
    std::uint64_t s = slotOf(ids[c]) & mask_;
    while (stamps_[s] == stamp_ && keys_[s] != ids[c]) s = (s + 1) & mask_;
    stamps_[s] = stamp_;
    keys_[s] = ids[c];
    values_[s] = c;
    row_offset_[static_cast<std::size_t>(c)] = row_offset[c];
  }
  row_offset_[static_cast<std::size_t>(contacts)] = rows;
  std::copy_n(f_star, rows, f_star_.begin());
  contacts_ = contacts;
  return carried;
}

}  // namespace tactus::shared
