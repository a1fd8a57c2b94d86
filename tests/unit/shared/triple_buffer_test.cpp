// Triple buffer: single-thread semantics, re-attachment of a restarted side, runtime-sized slots
// and a two-thread stress test (checksummed payloads: no torn or out-of-order reads, the reader
// ends on the newest value). Header-only on purpose: tests/integration builds this same file with
// -fsanitize=thread.

#include "tactus/shared/triple_buffer.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <set>
#include <thread>

namespace tactus::shared {
namespace {

#ifndef TACTUS_TB_PUBLISHES
#define TACTUS_TB_PUBLISHES 1'000'000
#endif

struct Payload {
  std::uint64_t seq;
  std::uint64_t words[29];
  std::uint64_t checksum;
};

std::uint64_t mix(std::uint64_t x) {
  x ^= x >> 33;
  x *= 0xff51afd7ed558ccdULL;
  x ^= x >> 33;
  return x;
}

void fill(Payload* p, std::uint64_t seq) {
  p->seq = seq;
  std::uint64_t sum = seq;
  for (int i = 0; i < 29; ++i) {
    p->words[i] = mix(seq * 31 + static_cast<std::uint64_t>(i));
    sum += p->words[i];
  }
  p->checksum = sum;
}

bool intact(const Payload& p) {
  std::uint64_t sum = p.seq;
  for (int i = 0; i < 29; ++i) {
    if (p.words[i] != mix(p.seq * 31 + static_cast<std::uint64_t>(i))) return false;
    sum += p.words[i];
  }
  return sum == p.checksum;
}

TEST(TripleBuffer, LayoutIsCacheLineAlignedForRuntimeSizes) {
  for (std::size_t bytes : {1u, 63u, 64u, 65u, 1000u, 4097u}) {
    TripleBufferStorage storage(bytes);
    TripleBufferControl* c = storage.control();
    EXPECT_EQ(c->slot_bytes, bytes);
    EXPECT_EQ(c->slot_stride % kCacheLineBytes, 0u);
    EXPECT_GE(c->slot_stride, bytes);
    for (int i = 0; i < 3; ++i) {
      EXPECT_EQ(reinterpret_cast<std::uintptr_t>(tripleBufferSlot(c, i, bytes)) %
                    kCacheLineBytes,
                0u);
    }
    EXPECT_EQ(storage.bytes(), tripleBufferBytes(bytes));
    EXPECT_LE(tripleBufferSlot(c, 2, bytes) + bytes,
              reinterpret_cast<unsigned char*>(c) + storage.bytes());
    EXPECT_TRUE(tripleBufferMatches(c, bytes));
    EXPECT_FALSE(tripleBufferMatches(c, bytes + 64));
  }
}

TEST(TripleBuffer, ReaderGetsNewestAndFreshFlag) {
  TripleBufferStorage storage(sizeof(Payload));
  TripleWriter<Payload> w(storage.control());
  TripleReader<Payload> r(storage.control());
  bool fresh = true;
  EXPECT_EQ(r.latest(&fresh).seq, 0u);  // zeroed slots before any publish
  EXPECT_FALSE(fresh);
  EXPECT_FALSE(r.hasNew());

  fill(&w.buffer(), 1);
  EXPECT_FALSE(w.publish());  // nothing overwritten
  EXPECT_TRUE(r.hasNew());
  EXPECT_EQ(r.latest(&fresh).seq, 1u);
  EXPECT_TRUE(fresh);
  EXPECT_EQ(r.latest(&fresh).seq, 1u);  // same value, not fresh
  EXPECT_FALSE(fresh);

  fill(&w.buffer(), 2);
  EXPECT_FALSE(w.publish());
  fill(&w.buffer(), 3);
  EXPECT_TRUE(w.publish());  // 2 was never taken: overwritten
  const Payload& p = r.latest(&fresh);
  EXPECT_TRUE(fresh);
  EXPECT_EQ(p.seq, 3u);
  EXPECT_TRUE(intact(p));
}

TEST(TripleBuffer, WriterNeverTouchesTheReadersSlot) {
  TripleBufferStorage storage(sizeof(Payload));
  TripleBufferWriter w(storage.control(), storage.slotBytes());
  TripleBufferReader r(storage.control(), storage.slotBytes());
  std::set<const void*> seen;
  for (std::uint64_t i = 1; i <= 50; ++i) {
    fill(static_cast<Payload*>(w.buffer()), i);
    w.publish();
    if (i % 3 == 0) r.latest();
    EXPECT_NE(w.buffer(), r.current());
    const std::uint8_t s = storage.control()->state.load();
    EXPECT_TRUE(TripleBufferControl::valid(s));
    seen.insert(w.buffer());
  }
  EXPECT_EQ(seen.size(), 3u);  // the writer rotates through all three slots
}

// The control block lives in shared memory another process can write. Neither endpoint reads
// the slot stride from it (a stride written there after attaching must not move their slots),
// and a state byte that is not a permutation of the slots (an index of 3 would address memory
// past the buffer) is never followed: the writer does not publish, the reader keeps its slot.
TEST(TripleBuffer, ACorruptControlBlockIsNeverFollowed) {
  TripleBufferStorage storage(sizeof(Payload));
  TripleWriter<Payload> w(storage.control());
  TripleReader<Payload> r(storage.control());
  fill(&w.buffer(), 1);
  w.publish();
  const void* slot = &r.latest();
  ASSERT_EQ(r.current().seq, 1u);
  storage.control()->slot_stride = 1 << 30;           // another process writes nonsense
  EXPECT_EQ(static_cast<const void*>(&r.current()), slot);
  EXPECT_TRUE(intact(r.current()));
  const std::uint8_t good = storage.control()->state.load();
  // back = 3: the writer's next slot would lie past the three slots
  storage.control()->state.store(TripleBufferControl::make(3, 0, 1, true));
  fill(&w.buffer(), 2);
  EXPECT_FALSE(w.publish());
  EXPECT_EQ(storage.control()->state.load(), TripleBufferControl::make(3, 0, 1, true));
  bool fresh = true;
  EXPECT_EQ(static_cast<const void*>(&r.latest(&fresh)), slot) << "the reader followed it";
  EXPECT_FALSE(fresh);
  EXPECT_FALSE(tripleBufferMatches(storage.control(), sizeof(Payload)));
  storage.control()->state.store(good);
  storage.control()->slot_stride = roundUpToCacheLine(sizeof(Payload));
  EXPECT_TRUE(tripleBufferMatches(storage.control(), sizeof(Payload)));
}

TEST(TripleBuffer, RestartedSidesReattachToTheirSlots) {
  TripleBufferStorage storage(sizeof(Payload));
  auto* w = new TripleWriter<Payload>(storage.control());
  TripleReader<Payload> r(storage.control());
  for (std::uint64_t i = 1; i <= 7; ++i) {
    fill(&w->buffer(), i);
    w->publish();
    if (i == 4) {
      EXPECT_EQ(r.latest().seq, 4u);
    }
  }
  delete w;
  // a restarted reader takes over the dead reader's slot, then the newest value
  TripleReader<Payload> r2(storage.control());
  EXPECT_EQ(r2.current().seq, 4u);
  EXPECT_EQ(r2.latest().seq, 7u);
  // a restarted writer continues on its own slot, not the reader's
  TripleWriter<Payload> w2(storage.control());
  EXPECT_NE(static_cast<const void*>(&w2.buffer()), static_cast<const void*>(&r2.current()));
  fill(&w2.buffer(), 8);
  w2.publish();
  EXPECT_EQ(r2.current().seq, 7u);
  EXPECT_EQ(r2.latest().seq, 8u);
}

TEST(TripleBuffer, ThreadedPublishesAreNeverTornNorOutOfOrder) {
  constexpr std::uint64_t kPublishes = TACTUS_TB_PUBLISHES;
  TripleBufferStorage storage(sizeof(Payload));
  TripleWriter<Payload> w(storage.control());
  TripleReader<Payload> r(storage.control());

  std::uint64_t torn = 0, backwards = 0, fresh_reads = 0, last_seq = 0;
  std::thread reader([&] {
    while (last_seq < kPublishes) {
      bool fresh = false;
      const Payload& p = r.latest(&fresh);
      if (!fresh) continue;
      ++fresh_reads;
      if (!intact(p)) ++torn;
      if (p.seq <= last_seq) ++backwards;  // a fresh slot is strictly newer
      last_seq = p.seq;
    }
  });
  for (std::uint64_t i = 1; i <= kPublishes; ++i) {
    fill(&w.buffer(), i);
    w.publish();
  }
  reader.join();
  EXPECT_EQ(torn, 0u);
  EXPECT_EQ(backwards, 0u);
  EXPECT_EQ(last_seq, kPublishes);       // the reader ended on the newest value
  EXPECT_GT(fresh_reads, 1u);
  EXPECT_EQ(r.latest().seq, kPublishes);
}

}  // namespace
}  // namespace tactus::shared
