// Shared-memory segment: create/open round trip through every part, name validation, mismatch
// refusals with their messages (ABI, size, layout, foreign object), a stale segment of a dead
// creator replaced, a live creator refused, read-only attach, re-creation detection.

#include "tactus/shared/segment.h"

#include <fcntl.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <csignal>
#include <unistd.h>

#include <cstring>
#include <limits>
#include <string>

#include "tactus/shared/error.h"

namespace tactus::shared {
namespace {

using ::testing::HasSubstr;

std::string uniqueName(const char* tag) {
  return "tactus_test_" + std::to_string(::getpid()) + "_" + tag;
}

// Removes the name at scope exit whatever happens.
struct NameGuard {
  std::string name;
  explicit NameGuard(std::string n) : name(std::move(n)) { Segment::remove(name); }
  ~NameGuard() { Segment::remove(name); }
};

// Writes raw bytes into an existing segment through a private mapping of our own.
void pokeU64(const std::string& name, std::size_t offset, std::uint64_t value, int bytes = 8) {
  const int fd = ::shm_open(("/" + name).c_str(), O_RDWR, 0);
  ASSERT_GE(fd, 0);
  void* p = ::mmap(nullptr, 4096, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
  ASSERT_NE(p, MAP_FAILED);
  std::memcpy(static_cast<unsigned char*>(p) + offset, &value, static_cast<std::size_t>(bytes));
  ::munmap(p, 4096);
  ::close(fd);
}

std::string openError(const std::string& name) {
  try {
    Segment::open(name, Access::kReadOnly);
  } catch (const SegmentError& e) {
    return e.what();
  }
  return "";
}

TEST(Segment, NameValidation) {
  EXPECT_TRUE(Segment::isValidName("tactus"));
  EXPECT_TRUE(Segment::isValidName("scene-1.liver_A"));
  EXPECT_FALSE(Segment::isValidName(""));
  EXPECT_FALSE(Segment::isValidName("a/b"));
  EXPECT_FALSE(Segment::isValidName("/tactus"));
  EXPECT_FALSE(Segment::isValidName(".."));
  EXPECT_FALSE(Segment::isValidName("has space"));
  EXPECT_FALSE(Segment::isValidName(std::string(65, 'a')));
  EXPECT_TRUE(Segment::isValidName(std::string(64, 'a')));
  try {
    Segment::create("../etc", SegmentCapacity::forContacts(4));
    FAIL() << "invalid name accepted";
  } catch (const SegmentError& e) {
    EXPECT_THAT(e.what(), HasSubstr("invalid segment name '../etc'"));
    EXPECT_THAT(e.what(), HasSubstr("[A-Za-z0-9_.-]"));
  }
}

TEST(Segment, LayoutIsAlignedAndSizedFromCapacity) {
  const SegmentLayout a = SegmentLayout::forCapacity(SegmentCapacity::forContacts(8));
  const SegmentLayout b = SegmentLayout::forCapacity(SegmentCapacity::forContacts(64));
  for (const SegmentLayout& l : {a, b}) {
    EXPECT_EQ(l.snapshot_offset % 64, 0u);
    EXPECT_EQ(l.device_offset % 64, 0u);
    EXPECT_EQ(l.stats_offset % 64, 0u);
    EXPECT_EQ(l.snapshot.W % 64, 0u);
    EXPECT_GE(l.snapshot.delta_free, l.snapshot.W + sizeof(double) * l.snapshot.max_rows *
                                                        l.snapshot.max_rows);
    EXPECT_LE(l.stats_offset + l.stats_bytes, l.total_bytes);
  }
  EXPECT_GT(b.total_bytes, a.total_bytes);
  EXPECT_EQ(b.snapshot.max_rows, 192);
}

// A capacity too large for any layout (W alone is rows^2 doubles: 2^31 rows would wrap the byte
// count to a small number) has none: the count saturates, and creators and attachers refuse it.
TEST(Segment, LayoutOfAnAbsurdCapacitySaturates) {
  constexpr std::int32_t kMax = std::numeric_limits<std::int32_t>::max();
  EXPECT_EQ(SnapshotLayout::forCapacity(kMax, kMax).total_bytes, SnapshotLayout::kNoLayout);
  EXPECT_EQ(SnapshotLayout::forCapacity(1'518'500'250, 1).total_bytes,
            SnapshotLayout::kNoLayout);   // its W would wrap to 277 MiB
  EXPECT_EQ(SnapshotLayout::forCapacity(-3, 1).total_bytes, SnapshotLayout::kNoLayout);
  SegmentCapacity c;
  c.max_rows = kMax;
  c.max_contacts = kMax;
  EXPECT_EQ(SegmentLayout::forCapacity(c).total_bytes, SnapshotLayout::kNoLayout);
  EXPECT_THROW(Segment::create("tactus_absurd_capacity", c), SegmentError);
  const SnapshotLayout fine = SnapshotLayout::forCapacity(900, 300);
  EXPECT_GT(fine.total_bytes, 900u * 900u * 8u);
  EXPECT_LT(fine.total_bytes, 8u << 20);
}

TEST(Segment, CreateOpenRoundTripThroughEveryPart) {
  NameGuard g(uniqueName("roundtrip"));
  Segment sim = Segment::create(g.name, SegmentCapacity::forContacts(4));
  EXPECT_TRUE(Segment::exists(g.name));
  struct stat st {};
  ASSERT_EQ(::stat(Segment::pathOf(g.name).c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);  // owner-only

  Segment hap = Segment::open(g.name);
  EXPECT_EQ(hap.capacity().max_rows, 12);
  EXPECT_EQ(hap.capacity().max_contacts, 4);
  EXPECT_EQ(hap.generation(), 1u);
  EXPECT_EQ(hap.header().creator_pid, ::getpid());
  EXPECT_EQ(hap.sizeBytes(), sim.sizeBytes());

  // snapshot: sim fills a 2-contact problem, haptic views it in place
  SnapshotPublisher pub = sim.snapshotPublisher();
  SnapshotSubscriber sub = hap.snapshotSubscriber();
  SnapshotWriter s = pub.slot();
  ASSERT_TRUE(s.setSize(4, 2));
  EXPECT_FALSE(s.setSize(13, 2));
  s.header().seq = 1;
  s.rowOffset()[0] = 0;
  s.rowOffset()[1] = 3;
  s.rowOffset()[2] = 4;
  for (int i = 0; i < 4; ++i) {
    s.deltaFree()[i] = -0.1 * (i + 1);
    for (int j = 0; j < 4; ++j) s.W()[i * s.ld() + j] = (i == j) ? 2.0 : 0.1;
  }
  s.mu()[0] = 0.3;
  s.J()[3 * 6 + 2] = 1.0;
  pub.publish();
  bool fresh = false;
  const SnapshotView v = sub.latest(&fresh);
  ASSERT_TRUE(fresh);
  EXPECT_EQ(v.header().seq, 1u);
  const ContactProblemView p = v.problem();
  EXPECT_EQ(p.contacts, 2);
  EXPECT_EQ(p.rows, 4);
  EXPECT_EQ(p.ld, 12);
  EXPECT_EQ(p.row_offset[2], 4);
  EXPECT_DOUBLE_EQ(p.W[1 * 12 + 1], 2.0);
  EXPECT_DOUBLE_EQ(p.delta_free[3], -0.4);
  EXPECT_DOUBLE_EQ(p.mu[0], 0.3);
  EXPECT_DOUBLE_EQ(v.J()[3 * 6 + 2], 1.0);
  // zero copy: the problem points into the mapping
  const auto* lo = static_cast<const unsigned char*>(hap.data());
  const auto* w = reinterpret_cast<const unsigned char*>(p.W);
  EXPECT_GE(w, lo);
  EXPECT_LT(w, lo + hap.sizeBytes());

  // device sample: haptic -> sim
  TripleWriter<DeviceSample> dw = hap.deviceWriter();
  TripleReader<DeviceSample> dr = sim.deviceReader();
  DeviceSample d;
  d.seq = 9;
  d.pos_m = {0.01, 0.02, 0.03};
  d.force_n = {0.0, 0.0, 1.5};
  dw.publish(d);
  EXPECT_EQ(dr.latest().seq, 9u);
  EXPECT_DOUBLE_EQ(dr.latest().force_n[2], 1.5);

  // stats: haptic writes, a read-only tool follows
  Segment tool = Segment::open(g.name, Access::kReadOnly);
  StatsRingReader reader = tool.statsReader();
  StatsRingWriter sw = hap.statsWriter();
  for (std::uint64_t i = 0; i < 10; ++i) {
    StatsRecord rec;
    rec.tick = i;
    rec.sweeps = static_cast<std::int64_t>(i * 2);
    sw.push(rec);
  }
  StatsRecord out[16];
  ASSERT_EQ(reader.poll(out, 16), 10u);
  EXPECT_EQ(out[9].tick, 9u);
  EXPECT_EQ(out[9].sweeps, 18);
  EXPECT_EQ(reader.lost(), 0u);

  // heartbeats and shutdown flags cross over
  hap.beat(Side::kHaptic, 12345);
  EXPECT_EQ(sim.heartbeatNs(Side::kHaptic), 12345);
  EXPECT_FALSE(hap.shutdownRequested(Side::kHaptic));
  sim.requestShutdown(Side::kHaptic);
  EXPECT_TRUE(hap.shutdownRequested(Side::kHaptic));
  EXPECT_TRUE(tool.shutdownRequested(Side::kHaptic));
  EXPECT_TRUE(hap.creatorAlive());
}

TEST(Segment, HapticCanStartFirst) {
  NameGuard g(uniqueName("first"));
  TryOpenResult r = Segment::tryOpen(g.name);
  EXPECT_EQ(r.status, OpenStatus::kAbsent);
  EXPECT_THAT(r.message, HasSubstr("does not exist yet"));
  EXPECT_FALSE(r.segment.has_value());
  EXPECT_THAT(openError(g.name), HasSubstr("does not exist yet"));
  Segment sim = Segment::create(g.name, SegmentCapacity::forContacts(2));
  r = Segment::tryOpen(g.name);
  ASSERT_TRUE(r.ok()) << r.message;
  EXPECT_EQ(r.segment->capacity().max_contacts, 2);
}

TEST(Segment, WrongAbiVersionIsRefusedWithWhatToDo) {
  NameGuard g(uniqueName("abi"));
  Segment sim = Segment::create(g.name, SegmentCapacity::forContacts(2));
  pokeU64(g.name, offsetof(SegmentHeader, abi_version), kSegmentAbiVersion + 1, 4);
  TryOpenResult r = Segment::tryOpen(g.name);
  EXPECT_EQ(r.status, OpenStatus::kMismatch);
  const std::string msg = openError(g.name);
  EXPECT_THAT(msg, HasSubstr("segment '" + g.name + "' has ABI version " +
                             std::to_string(kSegmentAbiVersion + 1)));
  EXPECT_THAT(msg, HasSubstr("expects " + std::to_string(kSegmentAbiVersion)));
  EXPECT_THAT(msg, HasSubstr("rebuild both daemons from the same checkout or remove /dev/shm/" +
                             g.name));
}

TEST(Segment, WrongSizeIsRefused) {
  NameGuard g(uniqueName("size"));
  Segment sim = Segment::create(g.name, SegmentCapacity::forContacts(2));
  const std::uint64_t real = sim.sizeBytes();
  pokeU64(g.name, offsetof(SegmentHeader, total_bytes), real + 4096);
  const std::string msg = openError(g.name);
  EXPECT_THAT(msg, HasSubstr("says it is " + std::to_string(real + 4096) + " bytes"));
  EXPECT_THAT(msg, HasSubstr("object is " + std::to_string(real) + " bytes"));
  pokeU64(g.name, offsetof(SegmentHeader, total_bytes), real);
  EXPECT_EQ(openError(g.name), "");
}

TEST(Segment, LayoutMismatchNamesTheField) {
  NameGuard g(uniqueName("layout"));
  Segment sim = Segment::create(g.name, SegmentCapacity::forContacts(2));
  pokeU64(g.name, offsetof(SegmentHeader, snapshot_slot_bytes), 1234);
  const std::string msg = openError(g.name);
  EXPECT_THAT(msg, HasSubstr("layout differs"));
  EXPECT_THAT(msg, HasSubstr("snapshot_slot_bytes 1234 (expected"));
}

TEST(Segment, ForeignObjectIsNeitherOpenedNorReplaced) {
  NameGuard g(uniqueName("foreign"));
  const int fd = ::shm_open(("/" + g.name).c_str(), O_RDWR | O_CREAT | O_EXCL, 0600);
  ASSERT_GE(fd, 0);
  ASSERT_EQ(::ftruncate(fd, 4096), 0);
  ::close(fd);
  pokeU64(g.name, 0, 0x1122334455667788ULL);
  EXPECT_THAT(openError(g.name), HasSubstr("is not a Tactus segment"));
  try {
    Segment::create(g.name, SegmentCapacity::forContacts(2));
    FAIL() << "foreign object replaced";
  } catch (const SegmentError& e) {
    EXPECT_THAT(e.what(), HasSubstr("is not a Tactus segment"));
  }
}

TEST(Segment, SecondLiveCreatorIsRefused) {
  NameGuard g(uniqueName("live"));
  Segment first = Segment::create(g.name, SegmentCapacity::forContacts(2));
  first.beat(Side::kSim);
  try {
    Segment::create(g.name, SegmentCapacity::forContacts(2));
    FAIL() << "second creator accepted";
  } catch (const SegmentError& e) {
    EXPECT_THAT(e.what(), HasSubstr("is in use by a live simulation (pid " +
                                    std::to_string(::getpid())));
    EXPECT_THAT(e.what(), HasSubstr("another --segment name"));
  }
  EXPECT_TRUE(first.stillCurrent());  // untouched
}

TEST(Segment, StaleSegmentOfADeadCreatorIsReplaced) {
  NameGuard g(uniqueName("stale"));
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    // create and vanish without any cleanup
    try {
      CreateOptions o;
      o.remove_on_destroy = false;
      Segment s = Segment::create(g.name, SegmentCapacity::forContacts(2), o);
      s.beat(Side::kSim);
      ::_exit(0);
    } catch (...) {
      ::_exit(3);
    }
  }
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);  // reaped: the pid no longer exists
  ASSERT_TRUE(WIFEXITED(status));
  ASSERT_EQ(WEXITSTATUS(status), 0);
  ASSERT_TRUE(Segment::exists(g.name));
  {
    Segment old = Segment::open(g.name, Access::kReadOnly);
    EXPECT_FALSE(old.creatorAlive());
    Segment fresh = Segment::create(g.name, SegmentCapacity::forContacts(3));
    EXPECT_EQ(fresh.generation(), 2u);
    EXPECT_THAT(fresh.creationNote(), HasSubstr("replaced a stale segment"));
    EXPECT_THAT(fresh.creationNote(), HasSubstr("dead process " + std::to_string(child)));
    EXPECT_EQ(fresh.header().creator_pid, ::getpid());
    EXPECT_FALSE(old.stillCurrent());  // an attached side can tell it was re-created
    EXPECT_TRUE(fresh.stillCurrent());
    EXPECT_EQ(Segment::open(g.name).capacity().max_contacts, 3);
  }
  EXPECT_FALSE(Segment::exists(g.name));  // the creator removed it on destruction
}

TEST(Segment, LiveButSilentCreatorIsNeverReplaced) {
  NameGuard g(uniqueName("hung"));
  int ready[2];
  ASSERT_EQ(::pipe(ready), 0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    // a creator that stays alive but stops beating (hung)
    CreateOptions o;
    o.remove_on_destroy = false;
    Segment s = Segment::create(g.name, SegmentCapacity::forContacts(1), o);
    s.beat(Side::kSim);
    const char c = 1;
    if (::write(ready[1], &c, 1) != 1) ::_exit(3);
    for (;;) ::pause();
  }
  char c = 0;
  ASSERT_EQ(::read(ready[0], &c, 1), 1);
  ::close(ready[0]);
  ::close(ready[1]);
  // fresh heartbeat: refused
  EXPECT_THROW(Segment::create(g.name, SegmentCapacity::forContacts(1)), SegmentError);
  ::usleep(100'000);
  // silent past the stale threshold but alive (it holds the ownership lock): still refused
  CreateOptions impatient;
  impatient.stale_after_ns = 50 * kNsPerMs;
  try {
    Segment::create(g.name, SegmentCapacity::forContacts(1), impatient);
    ADD_FAILURE() << "the segment of a live creator was replaced";
  } catch (const SegmentError& e) {
    EXPECT_THAT(e.what(), HasSubstr("in use by a live simulation (pid " + std::to_string(child) +
                                    ") that has been silent for"));
  }
  // once it is gone (SIGKILL: no cleanup), its segment is stale and replaced
  ::kill(child, SIGKILL);
  ::waitpid(child, nullptr, 0);
  Segment fresh = Segment::create(g.name, SegmentCapacity::forContacts(1), impatient);
  EXPECT_EQ(fresh.generation(), 2u);
  EXPECT_THAT(fresh.creationNote(), HasSubstr("dead process " + std::to_string(child)));
}

TEST(Segment, ReadOnlyAttachCannotWrite) {
  NameGuard g(uniqueName("ro"));
  Segment sim = Segment::create(g.name, SegmentCapacity::forContacts(2));
  Segment ro = Segment::open(g.name, Access::kReadOnly);
  EXPECT_EQ(ro.access(), Access::kReadOnly);
  EXPECT_THROW(ro.snapshotPublisher(), SegmentError);
  EXPECT_THROW(ro.deviceWriter(), SegmentError);
  EXPECT_THROW(ro.statsWriter(), SegmentError);
  try {
    ro.snapshotSubscriber();
  } catch (const SegmentError& e) {
    EXPECT_THAT(e.what(), HasSubstr("attached read-only"));
  }
  ro.beat(Side::kHaptic, 42);  // silently ignored, no crash
  EXPECT_EQ(sim.heartbeatNs(Side::kHaptic), 0);
  // the mapping itself is read-only: a write faults. "fast" (fork) style: the child inherits
  // this mapping and dies in it; the threadsafe style would re-run the test in a new process
  // that creates (and, killed, leaks) a segment of its own.
  GTEST_FLAG_SET(death_test_style, "fast");
  EXPECT_DEATH(
      {
        auto* p = const_cast<unsigned char*>(static_cast<const unsigned char*>(ro.data()));
        p[100] = 1;
      },
      "");
}

TEST(Segment, CreatorRemovesNameOnDestructionOnlyIfStillItsOwn) {
  NameGuard g(uniqueName("owner"));
  {
    Segment a = Segment::create(g.name, SegmentCapacity::forContacts(1));
    EXPECT_TRUE(Segment::exists(g.name));
  }
  EXPECT_FALSE(Segment::exists(g.name));
  {
    Segment a = Segment::create(g.name, SegmentCapacity::forContacts(1));
    EXPECT_TRUE(Segment::remove(g.name));
    CreateOptions o;
    o.remove_on_destroy = false;
    Segment b = Segment::create(g.name, SegmentCapacity::forContacts(1), o);
    EXPECT_EQ(b.generation(), 1u);  // the name was free: a new lineage
    EXPECT_EQ(b.creationNote(), "");
  }
  EXPECT_TRUE(Segment::exists(g.name));  // a's destructor left b's object alone
}

}  // namespace
}  // namespace tactus::shared
