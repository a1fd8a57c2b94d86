// Where each part of the shared-memory segment lies (docs/design.md section 3, "Layout"): the
// header, the snapshot and device triple buffers, the stats ring and the optional display frames,
// each on its own cache lines.
#include <algorithm>
#include "tactus/shared/segment.h"

namespace tactus::shared {

SegmentLayout SegmentLayout::forCapacity(SegmentCapacity capacity) noexcept {
  SegmentLayout l;
  l.snapshot = SnapshotLayout::forCapacity(capacity.max_rows, capacity.max_contacts);
  if (l.snapshot.total_bytes == SnapshotLayout::kNoLayout || capacity.devices < 0 ||
      capacity.devices > kMaxInstruments) {
    l.total_bytes = SnapshotLayout::kNoLayout;   // no layout: refused by create and attach
    return l;
  }
  std::size_t at = roundUpToCacheLine(sizeof(SegmentHeader));
  l.snapshot_offset = at;
  l.snapshot_bytes = tripleBufferBytes(l.snapshot.total_bytes);
  at = roundUpToCacheLine(at + l.snapshot_bytes);
  l.device_offset = at;
  l.device_stride_bytes = roundUpToCacheLine(tripleBufferBytes(sizeof(DeviceSample)));
  l.device_bytes = static_cast<std::size_t>(std::max(capacity.devices, 0)) * l.device_stride_bytes;
  at = roundUpToCacheLine(at + l.device_bytes);
  l.stats_offset = at;
  l.stats_bytes = seqRingBytes<StatsRecord>(kStatsRingCapacity);
  at = roundUpToCacheLine(at + l.stats_bytes);
  const DisplayCapacity dc = capacity.display();
  if (dc.enabled() && dc.max_contacts >= 0) {
    l.display = DisplayLayout::forCapacity(dc);
    l.display_offset = at;
    l.display_bytes = tripleBufferBytes(l.display.frame_bytes);
    at = roundUpToCacheLine(at + l.display_bytes);
    l.topology_offset = at;
    l.topology_bytes = l.display.topology_bytes;
    at = roundUpToCacheLine(at + l.topology_bytes);
  }
  l.total_bytes = at;
  return l;
}

}  // namespace tactus::shared
