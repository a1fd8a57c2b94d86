// Display part of the segment: topology and frames round trip through a real segment to a
// read-only subscriber, "nothing yet" and "unchanged" answers, capacity stored and checked,
// a corrupted display offset refused, no display part when its capacity is zero, and a writer
// thread racing a reader never yields a torn frame.

#include "tactus/shared/display.h"

#include <fcntl.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/mman.h>
#include <unistd.h>

#include <atomic>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "tactus/shared/error.h"
#include "tactus/shared/segment.h"

namespace tactus::shared {
namespace {

std::string uniqueDisplayName(const char* tag) {
  return "tactus_test_" + std::to_string(::getpid()) + "_display_" + tag;
}

struct DisplayNameGuard {
  std::string name;
  explicit DisplayNameGuard(std::string n) : name(std::move(n)) { Segment::remove(name); }
  ~DisplayNameGuard() { Segment::remove(name); }
};

SegmentCapacity smallCapacity() {
  SegmentCapacity c = SegmentCapacity::forContacts(4);
  c.display_vertices = 10;
  c.display_triangles = 7;
  return c;
}

// Process-local frame storage for a layout.
struct FrameBuffer {
  std::vector<std::uint64_t> words;
  DisplayFrameRef ref;
  explicit FrameBuffer(const DisplayLayout& l) : words(l.frame_bytes / 8 + 1, 0) {
    ref = DisplayFrameRef(words.data(), l);
  }
};

TEST(Display, LayoutIsPaddedAndGrowsWithCapacity) {
  const DisplayLayout a = DisplayLayout::forCapacity({10, 7, 4});
  const DisplayLayout b = DisplayLayout::forCapacity({100, 70, 4});
  for (const DisplayLayout& l : {a, b}) {
    EXPECT_EQ(l.positions % 8, 0u);
    EXPECT_LT(l.positions, l.displacement);
    EXPECT_LT(l.displacement, l.stress);
    EXPECT_LE(l.contact_force + 3 * 4 * sizeof(float), l.frame_bytes);
    EXPECT_EQ(l.frame_bytes % 8, 0u);
    EXPECT_EQ(l.topology_bytes % 8, 0u);
  }
  EXPECT_GE(a.displacement - a.positions, 3 * 10 * sizeof(float));
  EXPECT_GT(b.frame_bytes, a.frame_bytes);
  EXPECT_GT(b.topology_bytes, a.topology_bytes);
}

TEST(Display, TopologyAndFrameRoundTripToReadOnlySubscriber) {
  DisplayNameGuard g(uniqueDisplayName("rt"));
  Segment sim = Segment::create(g.name, smallCapacity());
  Segment viewer = Segment::open(g.name, Access::kReadOnly);
  EXPECT_EQ(viewer.capacity().display_vertices, 10);
  EXPECT_EQ(viewer.capacity().display_triangles, 7);

  DisplayPublisher pub = sim.displayPublisher();
  DisplaySubscriber sub = viewer.displaySubscriber();
  ASSERT_TRUE(pub.attached());
  ASSERT_TRUE(sub.attached());

  FrameBuffer in(pub.layout()), out(sub.layout());
  // nothing published yet
  EXPECT_EQ(sub.topologyGeneration(), 0u);
  EXPECT_EQ(sub.readFrame(out.ref), DisplayRead::kNothing);

  const std::uint32_t tris[] = {0, 1, 2, 2, 1, 3, 3, 4, 0};
  const std::int32_t begins[] = {0, 3};
  const std::uint64_t gen = pub.writeTopology(5, tris, 3, begins, 2);
  EXPECT_GT(gen, 0u);
  EXPECT_EQ(gen % 2, 0u);
  EXPECT_EQ(sub.topologyGeneration(), gen);
  DisplayTopologyHeader th{};
  std::vector<std::uint32_t> got(3 * 7 + 1, 99);
  ASSERT_EQ(sub.readTopology(&th, got.data()), DisplayRead::kOk);
  EXPECT_EQ(th.vertex_count, 5);
  EXPECT_EQ(th.triangle_count, 3);
  EXPECT_EQ(th.tissue_count, 2);
  EXPECT_EQ(th.tissue_vertex_begin[1], 3);
  EXPECT_EQ(th.tissue_vertex_begin[2], 5);
  for (int i = 0; i < 9; ++i) EXPECT_EQ(got[i], tris[i]) << i;
  // a second write bumps the generation
  EXPECT_GT(pub.writeTopology(5, tris, 2, begins, 1), gen);
  // over capacity: refused, topology unchanged
  std::vector<std::uint32_t> big(3 * 8, 0);
  EXPECT_EQ(pub.writeTopology(5, big.data(), 8, begins, 1), 0u);

  DisplayFrameHeader& h = in.ref.header();
  h.seq = 1;
  h.step = 42;
  h.vertex_count = 5;
  h.contact_count = 2;
  h.tool_primitive_count = 1;
  h.tool_primitives[0].radius_m = 0.002f;
  h.tool_force_n = {0.5, -1.0, 2.0};
  for (int i = 0; i < 15; ++i) in.ref.positions()[i] = 0.1f * static_cast<float>(i);
  for (int i = 0; i < 5; ++i) in.ref.displacement()[i] = static_cast<float>(i);
  for (int i = 0; i < 6; ++i) in.ref.contactForce()[i] = -static_cast<float>(i);
  ASSERT_TRUE(pub.publish(in.ref));

  ASSERT_EQ(sub.readFrame(out.ref), DisplayRead::kOk);
  const DisplayFrameHeader& o = out.ref.header();
  EXPECT_EQ(o.seq, 1u);
  EXPECT_EQ(o.seq_begin, 1u);
  EXPECT_EQ(o.seq_end, 1u);
  EXPECT_EQ(o.step, 42u);
  EXPECT_EQ(o.vertex_count, 5);
  EXPECT_EQ(o.contact_count, 2);
  EXPECT_FLOAT_EQ(o.tool_primitives[0].radius_m, 0.002f);
  EXPECT_DOUBLE_EQ(o.tool_force_n[2], 2.0);
  for (int i = 0; i < 15; ++i) EXPECT_FLOAT_EQ(out.ref.positions()[i], 0.1f * i) << i;
  for (int i = 0; i < 5; ++i) EXPECT_FLOAT_EQ(out.ref.displacement()[i], i) << i;
  for (int i = 0; i < 6; ++i) EXPECT_FLOAT_EQ(out.ref.contactForce()[i], -i) << i;
  // the same frame again: unchanged; a newer one: taken
  EXPECT_EQ(sub.readFrame(out.ref, 1), DisplayRead::kUnchanged);
  h.seq = 2;
  in.ref.positions()[0] = 7.0f;
  pub.publish(in.ref);
  ASSERT_EQ(sub.readFrame(out.ref, 1), DisplayRead::kOk);
  EXPECT_EQ(out.ref.header().seq, 2u);
  EXPECT_FLOAT_EQ(out.ref.positions()[0], 7.0f);
}

TEST(Display, ZeroCapacityMeansNoDisplayPart) {
  DisplayNameGuard g(uniqueDisplayName("none"));
  SegmentCapacity c = SegmentCapacity::forContacts(2);
  c.display_vertices = 0;
  Segment sim = Segment::create(g.name, c);
  EXPECT_FALSE(sim.displayPublisher().attached());
  Segment viewer = Segment::open(g.name, Access::kReadOnly);
  EXPECT_FALSE(viewer.displaySubscriber().attached());
  EXPECT_EQ(viewer.header().display_bytes, 0u);
  // smaller than with the default display capacity
  DisplayNameGuard g2(uniqueDisplayName("default"));
  Segment with = Segment::create(g2.name, SegmentCapacity::forContacts(2));
  EXPECT_GT(with.sizeBytes(), sim.sizeBytes());
  EXPECT_TRUE(with.displayPublisher().attached());
}

TEST(Display, CorruptedDisplayOffsetIsRefused) {
  DisplayNameGuard g(uniqueDisplayName("bad"));
  Segment sim = Segment::create(g.name, smallCapacity());
  // rewrite display_offset through a private mapping
  const int fd = ::shm_open(("/" + g.name).c_str(), O_RDWR, 0);
  ASSERT_GE(fd, 0);
  void* p = ::mmap(nullptr, 4096, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
  ASSERT_NE(p, MAP_FAILED);
  auto* h = static_cast<SegmentHeader*>(p);
  h->display_offset += 64;
  ::munmap(p, 4096);
  ::close(fd);
  try {
    Segment::open(g.name, Access::kReadOnly);
    FAIL() << "a wrong display offset must be refused";
  } catch (const SegmentError& e) {
    EXPECT_THAT(e.what(), ::testing::HasSubstr("display_offset"));
  }
}

// A writer publishing as fast as it can against a read-only reader: every frame the reader
// accepts is internally consistent (all values derive from one seq) and seqs never go back. The
// writer publishes at least 20000 frames and goes on until the reader has accepted 50 (so the
// count does not depend on how the two threads are scheduled); a check that fails stops both
// threads before the test returns.
TEST(Display, RacingWriterNeverYieldsATornFrame) {
  DisplayNameGuard g(uniqueDisplayName("race"));
  SegmentCapacity c = SegmentCapacity::forContacts(8);
  c.display_vertices = 2000;
  c.display_triangles = 10;
  Segment sim = Segment::create(g.name, c);
  Segment viewer = Segment::open(g.name, Access::kReadOnly);
  DisplayPublisher pub = sim.displayPublisher();
  DisplaySubscriber sub = viewer.displaySubscriber();
  constexpr long kWantedFrames = 50;
  constexpr std::uint64_t kMinPublishes = 20000, kMaxPublishes = 5'000'000;
  std::atomic<bool> done{false}, stop{false};
  std::atomic<long> accepted{0};
  std::atomic<std::uint64_t> published{0};
  std::thread writer([&] {
    FrameBuffer in(pub.layout());
    for (std::uint64_t seq = 1; seq <= kMaxPublishes && !stop.load(); ++seq) {
      if (seq > kMinPublishes && accepted.load() >= kWantedFrames) break;
      DisplayFrameHeader& h = in.ref.header();
      h.seq = seq;
      h.step = seq * 3;
      h.vertex_count = 2000;
      h.contact_count = 8;
      const float v = static_cast<float>(seq % 100000);
      for (int i = 0; i < 6000; ++i) in.ref.positions()[i] = v;
      for (int i = 0; i < 2000; ++i) in.ref.stress()[i] = v;
      for (int i = 0; i < 24; ++i) in.ref.contactForce()[i] = v;
      pub.publish(in.ref);
      published.store(seq);
    }
    done.store(true);
  });
  FrameBuffer out(sub.layout());
  std::uint64_t last = 0;
  long busy = 0;
  std::string failure;
  while (!done.load() && failure.empty()) {
    const DisplayRead r = sub.readFrame(out.ref, last);
    if (r == DisplayRead::kBusy) ++busy;
    if (r != DisplayRead::kOk) continue;
    const DisplayFrameHeader& h = out.ref.header();
    const float v = static_cast<float>(h.seq % 100000);
    if (h.seq <= last) failure = "seq went back";
    if (h.step != h.seq * 3) failure = "step torn";
    for (int i = 0; i < 6000 && failure.empty(); ++i) {
      if (out.ref.positions()[i] != v) failure = "positions torn at " + std::to_string(i);
    }
    for (int i = 0; i < 2000 && failure.empty(); ++i) {
      if (out.ref.stress()[i] != v) failure = "stress torn at " + std::to_string(i);
    }
    for (int i = 0; i < 24 && failure.empty(); ++i) {
      if (out.ref.contactForce()[i] != v) failure = "contact force torn at " + std::to_string(i);
    }
    last = h.seq;
    accepted.fetch_add(1);
  }
  stop.store(true);
  writer.join();
  ASSERT_TRUE(failure.empty()) << failure << " (frame " << last << ")";
  EXPECT_GE(accepted.load(), kWantedFrames);
  const std::uint64_t final_seq = published.load();
  ASSERT_EQ(sub.readFrame(out.ref, last),
            last == final_seq ? DisplayRead::kUnchanged : DisplayRead::kOk);
  EXPECT_EQ(out.ref.header().seq, final_seq);
  std::printf("reader: %ld consistent frames of %llu published, %ld busy retries\n",
              accepted.load(), static_cast<unsigned long long>(final_seq), busy);
}

}  // namespace
}  // namespace tactus::shared
