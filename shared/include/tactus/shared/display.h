#pragma once
// The display frame: what the simulation shows a live viewer (deformed surface, instrument,
// contacts and their forces), published through its own part of the shared segment.
//
// Two areas, both placed by the segment from a runtime capacity (DisplayLayout):
//
//   topology area   [ DisplayTopologyHeader | uint32 triangles[3 * max_triangles] ]
//                   written once by the simulation (the surface triangles of every tissue,
//                   indices into the concatenated surface vertex list), tagged with a generation.
//   frame buffer    a triple buffer (tactus/shared/triple_buffer.h) whose slots hold
//                   [ DisplayFrameHeader | float positions[3V] | float displacement[V]
//                     | float stress[V] | float contact_point[3C] | float contact_force[3C] ]
//                   one frame per publish (at most ~60 Hz), carrying the topology generation
//                   it refers to.
//
// Readers attach read-only. The simulation publishes through the triple buffer's writer protocol,
// so it never writes into the newest published slot. A reader cannot swap slots on a read-only
// mapping. Instead it copies the newest published (middle) slot and validates the copy seqlock
// style: the writer stores `seq_begin` before it fills a slot and `seq_end` after. The reader
// loads seq_end (acquire), copies, then loads seq_begin after an acquire fence. If they differ,
// the writer came back to that slot during the copy (that needs two more publishes), and the
// copy is discarded and retried. So any number of viewers may watch, and none of them can
// delay or change the simulation. The topology area works the same way with one generation
// word (odd while being written).
//
// Every payload word is accessed with 8-byte relaxed atomic builtins (ordered by the seq words
// and fences), so the protocol is free of data races in the C++ model. A plain mov on x86-64.
// Sizes and offsets are multiples of 8.
//
// Units: metres, pascals, newtons, world frame of the simulation (z up in the shipped scenes).
// Floats are IEEE-754 binary32, little-endian on every platform we build for; the viewer sends
// them to the browser unchanged.
//
// Real-time: nothing here allocates or throws; the writer and reader are noexcept.

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>

#include "tactus/shared/triple_buffer.h"

namespace tactus::shared {

/// Default display capacity of a segment (the simulation may ask for more or less).
inline constexpr std::int32_t kDefaultDisplayVertices = 16384;
inline constexpr std::int32_t kDefaultDisplayTriangles = 32768;
/// Tool primitives (spheres and capsules) carried per frame for drawing the instrument.
inline constexpr int kMaxDisplayToolPrimitives = 32;
/// Tissues whose vertex ranges a frame names (the rest are merged into the last range).
inline constexpr int kMaxDisplayTissues = 8;

/// DisplayFrameHeader::flags bits.
enum DisplayFlags : std::uint32_t {
  kDisplayHasTool = 1u << 0,         ///< tool pose and primitives are valid
  kDisplayHasStress = 1u << 1,       ///< the stress array is filled this frame
  kDisplayTruncated = 1u << 2,       ///< the surface or contacts exceeded the capacity
  kDisplayShuttingDown = 1u << 3,    ///< last frame of a simulation that is stopping
};

/// Instrument type shown by the viewer.
enum class DisplayTool : std::uint32_t { kNone = 0, kProbe = 1, kGrasper = 2 };

/// One drawable tool primitive in world coordinates: a sphere (a == b) or a capsule a..b.
struct DisplayToolPrimitive {
  std::array<float, 3> a_m{};
  std::array<float, 3> b_m{};
  float radius_m = 0.0f;
  std::uint32_t part = 0;            ///< probe 0; grasper jaw 0 or 1
};
static_assert(sizeof(DisplayToolPrimitive) == 32);

/// Fixed part of a display frame at offset 0 of its slot. 8-byte fields or pairs of 4-byte fields.
struct DisplayFrameHeader {
  std::uint64_t seq_begin = 0;       ///< seqlock word: = seq before the slot is filled
  std::uint64_t seq = 0;             ///< frame counter (1, 2, ...); 0 = nothing published
  std::int64_t t_ns = 0;             ///< monotonic time of publication
  std::uint64_t step = 0;            ///< simulation step index
  double sim_time_s = 0.0;
  double step_time_s = 0.0;          ///< wall time of the last simulation step (0: unknown)
  std::uint64_t topology_generation = 0;  ///< the topology these vertices index (even, > 0)
  std::int32_t vertex_count = 0;     ///< V (<= capacity)
  std::int32_t contact_count = 0;    ///< C (<= capacity)
  std::uint32_t flags = 0;           ///< DisplayFlags
  std::uint32_t tool_type = 0;       ///< DisplayTool
  std::int32_t tool_primitive_count = 0;
  std::int32_t solver_sweeps = 0;    ///< NSGS sweeps of the last step
  double solver_error = 0.0;
  std::array<double, 3> tool_pos_m{};
  std::array<double, 4> tool_quat_wxyz{1.0, 0.0, 0.0, 0.0};
  double gripper_opening = 1.0;      ///< 0 closed .. 1 open
  double gripper_angle_rad = 0.0;    ///< jaw half-angle
  std::array<double, 3> tool_force_n{};   ///< wrench rendered on the hand (the coupling force)
  std::array<double, 3> tool_torque_nm{};
  double max_displacement_m = 0.0;   ///< max over the vertices of this frame
  double max_stress_pa = 0.0;        ///< max over the vertices (0 without stress)
  std::array<DisplayToolPrimitive, kMaxDisplayToolPrimitives> tool_primitives{};
  std::uint64_t seq_end = 0;         ///< seqlock word: = seq once the slot is complete
};
static_assert(std::is_trivially_copyable_v<DisplayFrameHeader>);
static_assert(std::is_standard_layout_v<DisplayFrameHeader>);
static_assert(sizeof(DisplayFrameHeader) % 8 == 0);
static_assert(offsetof(DisplayFrameHeader, seq_begin) == 0);

/// Fixed part of the topology area.
struct DisplayTopologyHeader {
  std::uint64_t generation = 0;      ///< seqlock word: odd while written, even (> 0) complete
  std::int32_t vertex_count = 0;     ///< surface vertices (all tissues)
  std::int32_t triangle_count = 0;
  std::int32_t tissue_count = 0;
  std::int32_t reserved = 0;
  /// Tissue i owns vertices [tissue_vertex_begin[i], tissue_vertex_begin[i + 1]).
  std::array<std::int32_t, kMaxDisplayTissues + 2> tissue_vertex_begin{};
};
static_assert(std::is_trivially_copyable_v<DisplayTopologyHeader>);
static_assert(sizeof(DisplayTopologyHeader) % 8 == 0);

/// Display capacity (stored in the segment header).
struct DisplayCapacity {
  std::int32_t max_vertices = 0;
  std::int32_t max_triangles = 0;
  std::int32_t max_contacts = 0;
  bool enabled() const noexcept { return max_vertices > 0 && max_triangles > 0; }
};

/// Byte offsets inside a frame slot and the topology area for a capacity (pure function).
struct DisplayLayout {
  DisplayCapacity capacity;
  // frame slot
  std::size_t positions = 0;         ///< float[3 V]
  std::size_t displacement = 0;      ///< float[V]  |x - x_rest| [m]
  std::size_t stress = 0;            ///< float[V]  von Mises, averaged to vertices [Pa]
  std::size_t contact_point = 0;     ///< float[3 C] contact points on the tissue [m]
  std::size_t contact_force = 0;     ///< float[3 C] force the tool applies to the tissue [N]
  std::size_t frame_bytes = 0;       ///< slot payload
  // topology area
  std::size_t triangles = 0;         ///< uint32[3 T]
  std::size_t topology_bytes = 0;

  static constexpr std::size_t pad8(std::size_t bytes) noexcept { return (bytes + 7) / 8 * 8; }

  /// fn(offset, floats) for each per-frame array, with the floats used by v vertices and c
  /// contacts (the one list the writer's stores and the reader's loads both follow).
  template <class Fn>
  void forEachFrameArray(std::size_t v, std::size_t c, Fn&& fn) const noexcept {
    fn(positions, 3 * v);
    fn(displacement, v);
    fn(stress, v);
    fn(contact_point, 3 * c);
    fn(contact_force, 3 * c);
  }

  static constexpr DisplayLayout forCapacity(DisplayCapacity c) noexcept {
    DisplayLayout l;
    l.capacity = c;
    if (c.max_vertices < 0 || c.max_triangles < 0 || c.max_contacts < 0) return l;
    const auto v = static_cast<std::size_t>(c.max_vertices);
    const auto k = static_cast<std::size_t>(c.max_contacts);
    std::size_t at = pad8(sizeof(DisplayFrameHeader));
    auto place = [&at](std::size_t bytes) {
      const std::size_t here = at;
      at = pad8(at + bytes);
      return here;
    };
    l.positions = place(3 * v * sizeof(float));
    l.displacement = place(v * sizeof(float));
    l.stress = place(v * sizeof(float));
    l.contact_point = place(3 * k * sizeof(float));
    l.contact_force = place(3 * k * sizeof(float));
    l.frame_bytes = at;
    l.triangles = pad8(sizeof(DisplayTopologyHeader));
    l.topology_bytes =
        pad8(l.triangles + 3 * static_cast<std::size_t>(c.max_triangles) * sizeof(std::uint32_t));
    return l;
  }
};

namespace detail {
// Word-wise copies with relaxed 8-byte atomics (bytes: a multiple of 8, both sides 8-aligned).
inline void storeWords(void* dst, const void* src, std::size_t bytes) noexcept {
  auto* d = static_cast<std::uint64_t*>(dst);
  const auto* s = static_cast<const unsigned char*>(src);
  for (std::size_t i = 0; i < bytes / 8; ++i) {
    std::uint64_t w;
    std::memcpy(&w, s + 8 * i, 8);
    __atomic_store_n(d + i, w, __ATOMIC_RELAXED);
  }
}
inline void loadWords(void* dst, const void* src, std::size_t bytes) noexcept {
  auto* d = static_cast<unsigned char*>(dst);
  const auto* s = static_cast<const std::uint64_t*>(src);
  for (std::size_t i = 0; i < bytes / 8; ++i) {
    const std::uint64_t w = __atomic_load_n(s + i, __ATOMIC_RELAXED);
    std::memcpy(d + 8 * i, &w, 8);
  }
}
}  // namespace detail

/// A display frame in process-local memory (the publisher's staging copy, the reader's copy).
/// `bytes` must hold layout.frame_bytes (8-aligned).
class DisplayFrameRef {
 public:
  DisplayFrameRef() = default;
  DisplayFrameRef(void* bytes, const DisplayLayout& layout) noexcept
      : base_(static_cast<unsigned char*>(bytes)), layout_(layout) {}
  bool valid() const noexcept { return base_ != nullptr; }
  const DisplayLayout& layout() const noexcept { return layout_; }
  DisplayFrameHeader& header() const noexcept {
    return *reinterpret_cast<DisplayFrameHeader*>(base_);
  }
  float* positions() const noexcept { return at<float>(layout_.positions); }
  float* displacement() const noexcept { return at<float>(layout_.displacement); }
  float* stress() const noexcept { return at<float>(layout_.stress); }
  float* contactPoint() const noexcept { return at<float>(layout_.contact_point); }
  float* contactForce() const noexcept { return at<float>(layout_.contact_force); }
  unsigned char* data() const noexcept { return base_; }

 private:
  template <class T>
  T* at(std::size_t offset) const noexcept {
    return reinterpret_cast<T*>(base_ + offset);
  }
  unsigned char* base_ = nullptr;
  DisplayLayout layout_;
};

/// Simulation side: writes the topology once and publishes frames. Process-local handle.
class DisplayPublisher {
 public:
  DisplayPublisher() = default;
  DisplayPublisher(TripleBufferControl* frames, unsigned char* topology,
                   const DisplayLayout& layout) noexcept
      : writer_(frames, layout.frame_bytes), topology_(topology), layout_(layout) {}
  bool attached() const noexcept { return writer_.attached() && layout_.capacity.enabled(); }
  const DisplayLayout& layout() const noexcept { return layout_; }

  /// Writes the topology (vertex_count, triangles as 3 * triangle_count indices, tissue vertex
  /// ranges) and returns its generation (even, > 0), or 0 when it exceeds the capacity.
  std::uint64_t writeTopology(std::int32_t vertex_count, const std::uint32_t* triangles,
                              std::int32_t triangle_count, const std::int32_t* tissue_begin,
                              std::int32_t tissue_count) noexcept {
    if (vertex_count > layout_.capacity.max_vertices ||
        triangle_count > layout_.capacity.max_triangles || triangle_count < 0 ||
        vertex_count < 0) {
      return 0;
    }
    auto* h = reinterpret_cast<DisplayTopologyHeader*>(topology_);
    // relaxed: we are the only writer of the generation
    const std::uint64_t old = __atomic_load_n(&h->generation, __ATOMIC_RELAXED);
    const std::uint64_t odd = (old | 1u) + ((old & 1u) ? 2u : 0u);
    // relaxed + release fence: the odd generation is visible no later than any word below
    __atomic_store_n(&h->generation, odd, __ATOMIC_RELAXED);
    std::atomic_thread_fence(std::memory_order_release);
    DisplayTopologyHeader fixed{};
    fixed.generation = odd;
    fixed.vertex_count = vertex_count;
    fixed.triangle_count = triangle_count;
    const int tissues = tissue_count < 0 ? 0
                        : tissue_count > kMaxDisplayTissues ? kMaxDisplayTissues
                                                            : tissue_count;
    fixed.tissue_count = tissues;
    for (int i = 0; i < tissues; ++i) fixed.tissue_vertex_begin[i] = tissue_begin[i];
    fixed.tissue_vertex_begin[tissues] = vertex_count;
    // header words after the generation, then the triangles (padded to whole words)
    detail::storeWords(topology_ + 8, reinterpret_cast<const unsigned char*>(&fixed) + 8,
                       sizeof(fixed) - 8);
    const std::size_t tri_bytes = 3 * static_cast<std::size_t>(triangle_count) * 4;
    const std::size_t whole = tri_bytes / 8 * 8;
    detail::storeWords(topology_ + layout_.triangles, triangles, whole);
    if (whole < tri_bytes) {
      std::uint64_t last = 0;
      std::memcpy(&last, reinterpret_cast<const unsigned char*>(triangles) + whole, 4);
      detail::storeWords(topology_ + layout_.triangles + whole, &last, 8);
    }
    // release: the words above happen-before a reader's acquire of the even generation
    __atomic_store_n(&h->generation, odd + 1, __ATOMIC_RELEASE);
    return odd + 1;
  }

  /// Copies a complete staged frame (frame.layout() == layout()) into the back slot and
  /// publishes it. Sets seq_begin/seq_end itself. Returns false when not attached.
  bool publish(const DisplayFrameRef& frame) noexcept {
    if (!attached()) return false;
    auto* slot = static_cast<unsigned char*>(writer_.buffer());
    DisplayFrameHeader& staged = frame.header();
    const std::uint64_t seq = staged.seq;
    // relaxed + release fence: seq_begin is visible no later than any payload word
    __atomic_store_n(reinterpret_cast<std::uint64_t*>(slot), seq, __ATOMIC_RELAXED);
    std::atomic_thread_fence(std::memory_order_release);
    staged.seq_begin = seq;
    staged.seq_end = 0;
    // everything between the two seq words: header body, then only the used array prefixes
    const std::size_t end_at = offsetof(DisplayFrameHeader, seq_end);
    detail::storeWords(slot + 8, frame.data() + 8, end_at - 8);
    const auto v = static_cast<std::size_t>(staged.vertex_count);
    const auto c = static_cast<std::size_t>(staged.contact_count);
    layout_.forEachFrameArray(v, c, [&](std::size_t offset, std::size_t floats) {
      copyArray(slot, frame, offset, floats);
    });
    // release: the payload happens-before a reader's acquire of seq_end
    __atomic_store_n(reinterpret_cast<std::uint64_t*>(slot + end_at), seq, __ATOMIC_RELEASE);
    writer_.publish();
    return true;
  }

 private:
  void copyArray(unsigned char* slot, const DisplayFrameRef& frame, std::size_t offset,
                 std::size_t floats) noexcept {
    detail::storeWords(slot + offset, frame.data() + offset,
                       DisplayLayout::pad8(floats * sizeof(float)));
  }
  TripleBufferWriter writer_;
  unsigned char* topology_ = nullptr;
  DisplayLayout layout_;
};

/// Outcome of a display read.
enum class DisplayRead : std::uint8_t {
  kOk,          ///< a complete, consistent copy
  kNothing,     ///< nothing published yet (or the topology is being written)
  kUnchanged,   ///< the newest frame is not newer than the one already copied (frames only)
  kBusy,        ///< the writer overtook the copy each try: call again later
};

/// Viewer side: copies the newest frame / the topology out of a (read-only) mapping. Any number
/// of subscribers may read at once; they never write to the segment.
class DisplaySubscriber {
 public:
  static constexpr int kMaxTries = 4;

  DisplaySubscriber() = default;
  DisplaySubscriber(const TripleBufferControl* frames, const unsigned char* topology,
                    const DisplayLayout& layout) noexcept
      : frames_(frames), topology_(topology), layout_(layout) {}
  bool attached() const noexcept { return frames_ != nullptr && layout_.capacity.enabled(); }
  const DisplayLayout& layout() const noexcept { return layout_; }

  /// Generation of the complete topology (0: none yet / being written).
  std::uint64_t topologyGeneration() const noexcept {
    // acquire: pairs with the writer's release of the even generation
    const std::uint64_t g = __atomic_load_n(
        reinterpret_cast<const std::uint64_t*>(topology_), __ATOMIC_ACQUIRE);
    return (g & 1u) ? 0 : g;
  }

  /// Copies the topology header into `header` and the triangles into `triangles` (room for
  /// 3 * max_triangles + 1 indices).
  DisplayRead readTopology(DisplayTopologyHeader* header, std::uint32_t* triangles) const noexcept {
    if (!attached()) return DisplayRead::kNothing;
    for (int attempt = 0; attempt < kMaxTries; ++attempt) {
      const std::uint64_t g1 = topologyGeneration();
      if (g1 == 0) return DisplayRead::kNothing;
      detail::loadWords(reinterpret_cast<unsigned char*>(header) + 8, topology_ + 8,
                        sizeof(DisplayTopologyHeader) - 8);
      header->generation = g1;
      const std::int32_t t = header->triangle_count;
      if (t < 0 || t > layout_.capacity.max_triangles || header->vertex_count < 0 ||
          header->vertex_count > layout_.capacity.max_vertices) {
        continue;
      }
      detail::loadWords(triangles, topology_ + layout_.triangles,
                        DisplayLayout::pad8(3 * static_cast<std::size_t>(t) * 4));
      // acquire fence: the loads above happen before the generation re-load
      std::atomic_thread_fence(std::memory_order_acquire);
      const std::uint64_t g2 =
          __atomic_load_n(reinterpret_cast<const std::uint64_t*>(topology_), __ATOMIC_RELAXED);
      if (g1 == g2) return DisplayRead::kOk;
    }
    return DisplayRead::kBusy;
  }

  /// Copies the newest published frame into `out` (process-local, layout().frame_bytes) unless
  /// its seq is at most `have_seq` (kUnchanged). Seqs never go back: a reader that found the
  /// middle slot and was then preempted may copy that slot after the writer has rotated it to
  /// the back and completed the next frame in it, not yet published; the middle it finds next is
  /// then one frame older, and is not copied (measured: 2 in 450 racing runs of display_test
  /// under load before this check).
  DisplayRead readFrame(const DisplayFrameRef& out, std::uint64_t have_seq = 0) const noexcept {
    if (!attached()) return DisplayRead::kNothing;
    using C = TripleBufferControl;
    for (int attempt = 0; attempt < kMaxTries; ++attempt) {
      // acquire: the middle slot was handed over by the writer's release CAS
      const std::uint8_t s = frames_->state.load(std::memory_order_acquire);
      if (!C::valid(s)) return DisplayRead::kBusy;   // corrupt: never follow it
      const unsigned char* slot = tripleBufferSlot(frames_, C::middle(s), layout_.frame_bytes);
      const auto* words = reinterpret_cast<const std::uint64_t*>(slot);
      const std::size_t end_at = offsetof(DisplayFrameHeader, seq_end) / 8;
      // acquire: pairs with the writer's release of seq_end (payload complete)
      const std::uint64_t e = __atomic_load_n(words + end_at, __ATOMIC_ACQUIRE);
      if (e == 0) return DisplayRead::kNothing;
      if (e <= have_seq) return DisplayRead::kUnchanged;
      detail::loadWords(out.data() + 8, slot + 8, end_at * 8 - 8);
      DisplayFrameHeader& h = out.header();
      const bool sane = h.seq == e && h.vertex_count >= 0 && h.contact_count >= 0 &&
                        h.vertex_count <= layout_.capacity.max_vertices &&
                        h.contact_count <= layout_.capacity.max_contacts &&
                        h.tool_primitive_count >= 0 &&
                        h.tool_primitive_count <= kMaxDisplayToolPrimitives;
      if (sane) {
        const auto v = static_cast<std::size_t>(h.vertex_count);
        const auto c = static_cast<std::size_t>(h.contact_count);
        layout_.forEachFrameArray(v, c, [&](std::size_t offset, std::size_t floats) {
          loadArray(out, slot, offset, floats);
        });
      }
      // acquire fence: every load above happens before the seq_begin re-load
      std::atomic_thread_fence(std::memory_order_acquire);
      const std::uint64_t b = __atomic_load_n(words, __ATOMIC_RELAXED);
      if (sane && b == e) {
        h.seq_begin = b;
        h.seq_end = e;
        return DisplayRead::kOk;
      }
    }
    return DisplayRead::kBusy;
  }

 private:
  static void loadArray(const DisplayFrameRef& out, const unsigned char* slot, std::size_t offset,
                        std::size_t floats) noexcept {
    detail::loadWords(out.data() + offset, slot + offset,
                      DisplayLayout::pad8(floats * sizeof(float)));
  }
  const TripleBufferControl* frames_ = nullptr;
  const unsigned char* topology_ = nullptr;
  DisplayLayout layout_;
};

}  // namespace tactus::shared
