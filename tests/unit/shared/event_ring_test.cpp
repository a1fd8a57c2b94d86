// The two rings of the real-time thread: the SPSC event ring (RT -> logging thread; drops counted,
// never blocks) and the seqlock stats ring (single writer, lossy readers that count what they
// missed, never a torn record). Both must not allocate on the RT side.

#include "tactus/shared/event_ring.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <memory>
#include <thread>
#include <vector>

#include "../../support/alloc_counter.h"
#include "tactus/shared/stats_ring.h"

namespace tactus::shared {
namespace {

TEST(EventRing, FifoOrderAndDropCounter) {
  auto ring = std::make_unique<SpscRing<RtEvent, 8>>();
  for (int i = 0; i < 8; ++i) EXPECT_TRUE(pushEvent(*ring, i, kEventOverrun, i * 1.5));
  EXPECT_FALSE(pushEvent(*ring, 99, kEventOverrun));  // full: dropped, not blocked
  EXPECT_FALSE(pushEvent(*ring, 100, kEventOverrun));
  EXPECT_EQ(ring->dropped(), 2u);
  EXPECT_EQ(ring->size(), 8u);
  RtEvent e;
  ASSERT_TRUE(ring->tryPop(&e));
  EXPECT_EQ(e.t_ns, 0);
  EXPECT_EQ(e.code, kEventOverrun);
  std::vector<std::int64_t> ts;
  EXPECT_EQ(ring->drain([&](const RtEvent& ev) { ts.push_back(ev.t_ns); }), 7u);
  EXPECT_EQ(ts, (std::vector<std::int64_t>{1, 2, 3, 4, 5, 6, 7}));
  EXPECT_FALSE(ring->tryPop(&e));
  EXPECT_TRUE(pushEvent(*ring, 8, kEventDeviceFault, 1.0, 2.0));  // room again
  ASSERT_TRUE(ring->tryPop(&e));
  EXPECT_DOUBLE_EQ(e.arg1, 2.0);
  EXPECT_STREQ(eventCodeName(e.code), "device_fault");
  EXPECT_STREQ(eventCodeName(12345), "event");
}

TEST(EventRing, PushAndPopNeverAllocate) {
  auto ring = std::make_unique<EventRing>();
  test::AllocScope scope;
  for (int i = 0; i < 5000; ++i) pushEvent(*ring, i, kEventSnapshotStale, i);
  RtEvent e;
  while (ring->tryPop(&e)) {
  }
  EXPECT_EQ(scope.allocations(), 0);
  EXPECT_EQ(ring->dropped(), 5000u - EventRing::kCapacity);
}

TEST(EventRing, ThreadedProducerConsumerLosesNothingButCountedDrops) {
  constexpr std::int64_t kEvents = 200'000;
  auto ring = std::make_unique<SpscRing<RtEvent, 256>>();
  std::int64_t pushed = 0;
  std::thread producer([&] {
    for (std::int64_t i = 0; i < kEvents; ++i) pushed += pushEvent(*ring, i, kEventUser) ? 1 : 0;
  });
  std::int64_t popped = 0, last = -1, disorder = 0;
  auto consume = [&] {
    RtEvent e;
    while (ring->tryPop(&e)) {
      if (e.t_ns <= last) ++disorder;
      last = e.t_ns;
      ++popped;
    }
  };
  while (pushed + static_cast<std::int64_t>(ring->dropped()) < kEvents) consume();
  producer.join();
  consume();
  EXPECT_EQ(disorder, 0);
  EXPECT_EQ(popped, pushed);
  EXPECT_EQ(popped + static_cast<std::int64_t>(ring->dropped()), kEvents);
}

// A heap-backed stats ring of a given capacity.
struct RingMemory {
  explicit RingMemory(std::size_t capacity)
      : bytes(seqRingBytes<StatsRecord>(capacity)),
        mem(static_cast<unsigned char*>(std::aligned_alloc(64, bytes))),
        control(initSeqRing<StatsRecord>(mem, capacity)) {}
  ~RingMemory() { std::free(mem); }
  std::size_t bytes;
  unsigned char* mem;
  SeqRingControl* control;
};

StatsRecord record(std::uint64_t i) {
  StatsRecord r;
  r.tick = i;
  r.scheduled_ns = static_cast<std::int64_t>(i * 1000);
  r.woken_ns = r.scheduled_ns + 7;
  r.sweeps = static_cast<std::int64_t>(i % 50);
  r.residual = static_cast<double>(i) * 1e-3;
  r.flags = i * 3;  // redundant fields: a torn record would not satisfy consistent()
  return r;
}

bool consistent(const StatsRecord& r) {
  return r.scheduled_ns == static_cast<std::int64_t>(r.tick * 1000) &&
         r.woken_ns == r.scheduled_ns + 7 && r.sweeps == static_cast<std::int64_t>(r.tick % 50) &&
         r.residual == static_cast<double>(r.tick) * 1e-3 && r.flags == r.tick * 3;
}

TEST(StatsRing, ReadersFollowAndCountLostRecords) {
  RingMemory m(64);
  StatsRingWriter w(m.control);
  StatsRingReader from_start(m.control, StatsRingReader::Start::kOldest);
  for (std::uint64_t i = 0; i < 10; ++i) w.push(record(i));
  StatsRingReader newest(m.control);  // attaches after 10 records: sees only later ones
  StatsRecord out[200];
  ASSERT_EQ(from_start.poll(out, 200), 10u);
  EXPECT_EQ(out[0].tick, 0u);
  EXPECT_TRUE(consistent(out[9]));
  EXPECT_EQ(newest.poll(out, 200), 0u);

  // the writer laps the idle reader: 2 * 64 + 5 more records
  for (std::uint64_t i = 10; i < 10 + 133; ++i) w.push(record(i));
  const std::size_t n = from_start.poll(out, 200);
  EXPECT_EQ(n, 64u);                       // a full ring's worth survives
  EXPECT_EQ(from_start.lost(), 133u - 64u);  // everything older is counted lost
  EXPECT_EQ(out[0].tick, 143u - 64u);
  EXPECT_EQ(out[63].tick, 142u);
  for (std::size_t i = 0; i < n; ++i) EXPECT_TRUE(consistent(out[i]));
  StatsRecord last;
  ASSERT_TRUE(newest.newest(&last));
  EXPECT_EQ(last.tick, 142u);

  // a restarted writer continues the index
  StatsRingWriter w2(m.control);
  EXPECT_EQ(w2.written(), 143u);
  // reading an overwritten index reports it
  EXPECT_EQ(from_start.read(0, &last), RingRead::kOverwritten);
  EXPECT_EQ(from_start.read(500, &last), RingRead::kNotYet);
}

TEST(StatsRing, PushNeverAllocates) {
  RingMemory m(256);
  StatsRingWriter w(m.control);
  StatsRingReader r(m.control, StatsRingReader::Start::kOldest);
  StatsRecord out[32];
  test::AllocScope scope;
  for (std::uint64_t i = 0; i < 1000; ++i) {
    w.push(record(i));
    if (i % 7 == 0) r.poll(out, 32);
  }
  EXPECT_EQ(scope.allocations(), 0);
}

TEST(StatsRing, ThreadedReaderNeverSeesATornRecord) {
  constexpr std::uint64_t kRecords = 500'000;
  RingMemory m(128);  // small ring: the reader is lapped often
  StatsRingWriter w(m.control);
  StatsRingReader r(m.control, StatsRingReader::Start::kOldest);
  std::thread writer([&] {
    for (std::uint64_t i = 0; i < kRecords; ++i) w.push(record(i));
  });
  std::uint64_t got = 0, torn = 0, disorder = 0;
  std::int64_t last = -1;
  StatsRecord out[64];
  while (r.nextIndex() < kRecords) {
    const std::size_t n = r.poll(out, 64);
    for (std::size_t i = 0; i < n; ++i) {
      if (!consistent(out[i])) ++torn;
      if (static_cast<std::int64_t>(out[i].tick) <= last) ++disorder;
      last = static_cast<std::int64_t>(out[i].tick);
    }
    got += n;
  }
  writer.join();
  EXPECT_EQ(torn, 0u);
  EXPECT_EQ(disorder, 0u);
  EXPECT_EQ(got + r.lost(), kRecords);  // every record is either read or counted lost
  EXPECT_GT(got, 0u);
}

}  // namespace
}  // namespace tactus::shared
