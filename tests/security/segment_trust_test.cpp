// Segment trust and device-input sanity:
//  * a simulation whose owner is alive (even stopped, even silent past the stale threshold) is
//    never replaced, and a simulation whose segment was removed and re-created while it was
//    stopped notices on resume and stops with a message (real sim_server processes);
//  * the haptic attach refuses a segment owned by another user or open to others (mode 0666),
//    and create() never replaces another user's object;
//  * the single-haptic-process claim is a lock: of many racing claimants exactly one wins, a dead
//    claimant's claim is taken over, and a recycled pid does not block it; two creators replacing
//    one stale segment never displace each other;
//  * an absurd but finite device pose (1e300 m) neither carries the god object away nor sticks:
//    it is rejected and counted, the god object stays where it was, and it follows the device
//    again once the samples are sane.
#include <fcntl.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <functional>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "../../sim_server/src/app/segment_host.h"
#include "tactus/shared/error.h"
#include "tactus/shared/segment.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/pipeline.h"
#include "tactus/sim/scene.h"

namespace {

using namespace std::chrono_literals;
using ::testing::HasSubstr;
using tactus::SegmentError;
using tactus::shared::Access;
using tactus::shared::CreateOptions;
using tactus::shared::DeviceSample;
using tactus::shared::OpenStatus;
using tactus::shared::Segment;
using tactus::shared::SegmentCapacity;
using tactus::shared::SegmentHeader;
using tactus::shared::Side;

const std::string kBin = TACTUS_BINARY_DIR;
const std::string kData = TACTUS_TEST_DATA_DIR;

std::string uniqueName(const char* tag) {
  return "tactus_sec_segment_" + std::to_string(::getpid()) + "_" + tag;
}

std::string logPath(const std::string& name, const char* what) {
  return std::string(::testing::TempDir()) + "/" + name + "_" + what + ".log";
}

// Removes the name (and the daemons' logs of this test) at scope exit whatever happens.
struct NameGuard {
  std::string name;
  explicit NameGuard(std::string n) : name(std::move(n)) { Segment::remove(name); }
  ~NameGuard() {
    Segment::remove(name);
    for (const char* tag : {"first", "second", "displaced", "haptic"}) {
      ::unlink(logPath(name, tag).c_str());
    }
  }
};

bool exited(pid_t pid, int* status) { return ::waitpid(pid, status, WNOHANG) == pid; }

// A child process that is always reaped (SIGCONT + SIGKILL first if still there).
struct SegmentChild {
  pid_t pid = -1;
  bool reaped = false;
  int status = 0;
  ~SegmentChild() {
    if (pid <= 0 || reaped) return;
    ::kill(pid, SIGCONT);
    ::kill(pid, SIGKILL);
    ::waitpid(pid, nullptr, 0);
  }
  // Waits up to `timeout` for the exit; true if it exited.
  bool waitExit(std::chrono::milliseconds timeout) {
    const auto end = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < end) {
      if (exited(pid, &status)) {
        reaped = true;
        return true;
      }
      std::this_thread::sleep_for(20ms);
    }
    return false;
  }
};

SegmentChild spawn(const std::vector<std::string>& args, const std::string& log) {
  SegmentChild c;
  c.pid = ::fork();
  if (c.pid == 0) {
    std::FILE* f = std::freopen(log.c_str(), "w", stdout);
    (void)f;
    ::dup2(::fileno(stdout), ::fileno(stderr));
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  return c;
}

std::string slurp(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

SegmentChild startSim(const std::string& name, const char* log_tag) {
  return spawn({kBin + "/sim_server/sim_server", kData + "/scenes/press_cube.yaml", "--segment",
                name},
               logPath(name, log_tag));
}

// Waits until the simulation's segment is attachable (bounded).
bool waitForSegment(const std::string& name, std::chrono::milliseconds timeout = 20000ms) {
  const auto end = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < end) {
    if (Segment::tryOpen(name, Access::kReadOnly).ok()) return true;
    std::this_thread::sleep_for(20ms);
  }
  return false;
}

// ---------------------------------------------------------------------------------------------
// A live (stopped) owner is never replaced; a displaced simulation stops.

TEST(SegmentOwnership, AStoppedSimulationIsNeverReplaced) {
  NameGuard g(uniqueName("stopped"));
  SegmentChild first = startSim(g.name, "first");
  ASSERT_TRUE(waitForSegment(g.name)) << slurp(logPath(g.name, "first"));
  ASSERT_EQ(::kill(first.pid, SIGSTOP), 0);
  // silent for longer than an (impatient) stale threshold: still alive, still refused
  std::this_thread::sleep_for(50ms);
  CreateOptions impatient;
  impatient.stale_after_ns = 1 * tactus::shared::kNsPerMs;
  try {
    Segment::create(g.name, SegmentCapacity::forContacts(2), impatient);
    FAIL() << "the segment of a live (stopped) simulation was replaced";
  } catch (const SegmentError& e) {
    EXPECT_THAT(e.what(), HasSubstr("is in use by a live simulation (pid " +
                                    std::to_string(first.pid) + ")"));
    EXPECT_THAT(e.what(), HasSubstr("silent for"));
    EXPECT_THAT(e.what(), HasSubstr("never replaced"));
  }
  // a second sim_server is refused too, with the message, and the first keeps its segment
  SegmentChild second = startSim(g.name, "second");
  ASSERT_TRUE(second.waitExit(20000ms)) << "second sim_server did not exit";
  ASSERT_TRUE(WIFEXITED(second.status));
  EXPECT_NE(WEXITSTATUS(second.status), 0);
  EXPECT_THAT(slurp(logPath(g.name, "second")), HasSubstr("is in use by a live simulation"));
  ::kill(first.pid, SIGCONT);
  Segment seg = Segment::open(g.name, Access::kReadOnly);
  EXPECT_EQ(seg.header().creator_pid, first.pid);
  EXPECT_EQ(seg.generation(), 1u);
  // SIGKILL: the lock goes with the process, so the stale segment is replaced as before
  ::kill(first.pid, SIGKILL);
  ASSERT_TRUE(first.waitExit(10000ms));
  Segment fresh = Segment::create(g.name, SegmentCapacity::forContacts(2));
  EXPECT_EQ(fresh.generation(), 2u);
  EXPECT_THAT(fresh.creationNote(), HasSubstr("replaced a stale segment"));
}

TEST(SegmentOwnership, ADisplacedSimulationStopsWithAMessage) {
  NameGuard g(uniqueName("displaced"));
  SegmentChild sim = startSim(g.name, "displaced");
  ASSERT_TRUE(waitForSegment(g.name)) << slurp(logPath(g.name, "displaced"));
  ASSERT_EQ(::kill(sim.pid, SIGSTOP), 0);
  // someone removes the name by hand and another segment takes it while the sim is stopped
  ASSERT_TRUE(Segment::remove(g.name));
  Segment usurper = Segment::create(g.name, SegmentCapacity::forContacts(2));
  ASSERT_EQ(::kill(sim.pid, SIGCONT), 0);
  ASSERT_TRUE(sim.waitExit(20000ms)) << "the displaced simulation kept running";
  ASSERT_TRUE(WIFEXITED(sim.status));
  EXPECT_EQ(WEXITSTATUS(sim.status), 3);
  const std::string log = slurp(logPath(g.name, "displaced"));
  EXPECT_THAT(log, HasSubstr("no longer refers to the segment this simulation created"));
  EXPECT_THAT(log, HasSubstr("segment '" + g.name + "'"));
  // it left the new owner's segment alone
  EXPECT_TRUE(usurper.stillCurrent());
}

// ---------------------------------------------------------------------------------------------
// Owner and mode are checked before attaching.

int openShm(const std::string& name) { return ::shm_open(("/" + name).c_str(), O_RDWR, 0); }

TEST(SegmentTrust, AnotherUsersSegmentIsRefused) {
  if (::geteuid() != 0) GTEST_SKIP() << "needs root to give the object to another uid";
  NameGuard g(uniqueName("foreign_uid"));
  Segment sim = Segment::create(g.name, SegmentCapacity::forContacts(2));
  const int fd = openShm(g.name);
  ASSERT_GE(fd, 0);
  ASSERT_EQ(::fchown(fd, 65534, 65534), 0);
  for (Access access : {Access::kReadWrite, Access::kReadOnly}) {
    const auto r = Segment::tryOpen(g.name, access);
    EXPECT_EQ(r.status, OpenStatus::kError);
    EXPECT_FALSE(r.segment.has_value());
    EXPECT_THAT(r.message, HasSubstr("belongs to uid 65534, not to this user (uid 0)"));
  }
  ASSERT_EQ(::fchown(fd, 0, 0), 0);
  EXPECT_TRUE(Segment::tryOpen(g.name).ok());   // the same object, trusted again
  ::close(fd);
}

// The header's first page, mapped read-write by hand (what another process of this user could
// write into a segment).
SegmentHeader* mapHeader(int fd) {
  void* p = ::mmap(nullptr, 4096, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
  return p == MAP_FAILED ? nullptr : static_cast<SegmentHeader*>(p);
}

// A header claiming a capacity whose layout needs 31 GiB (a sparse object of that size, every
// offset and size consistent with it): the attacher would size its solver memory from it. It is
// refused before anything is allocated (tryOpen used to trust it once the layout matched).
TEST(SegmentTrust, AnAbsurdCapacityIsRefusedBeforeAnythingIsSizedFromIt) {
  NameGuard g(uniqueName("capacity"));
  Segment sim = Segment::create(g.name, SegmentCapacity::forContacts(2));
  SegmentCapacity big = SegmentCapacity::forContacts(12'000, true);
  const tactus::shared::SegmentLayout l = tactus::shared::SegmentLayout::forCapacity(big);
  ASSERT_GT(l.total_bytes, std::size_t{16} << 30);
  const int fd = openShm(g.name);
  ASSERT_GE(fd, 0);
  ASSERT_EQ(::ftruncate(fd, static_cast<off_t>(l.total_bytes)), 0) << "a sparse object";
  SegmentHeader* h = mapHeader(fd);
  ASSERT_NE(h, nullptr);
  h->total_bytes = l.total_bytes;
  h->max_rows = big.max_rows;
  h->max_contacts = big.max_contacts;
  h->snapshot_offset = l.snapshot_offset;
  h->snapshot_bytes = l.snapshot_bytes;
  h->snapshot_slot_bytes = l.snapshot.total_bytes;
  h->device_offset = l.device_offset;
  h->device_bytes = l.device_bytes;
  h->stats_offset = l.stats_offset;
  h->stats_bytes = l.stats_bytes;
  h->display_max_contacts = l.display.capacity.max_contacts;
  h->display_offset = l.display_offset;
  h->display_bytes = l.display_bytes;
  h->display_slot_bytes = l.display.frame_bytes;
  h->topology_offset = l.topology_offset;
  h->topology_bytes = l.topology_bytes;
  ::munmap(h, 4096);
  const auto r = Segment::tryOpen(g.name);
  EXPECT_FALSE(r.ok());
  EXPECT_THAT(r.message, HasSubstr("more than any simulation creates"));
  ::close(fd);
}

// A triple buffer whose control block is corrupt (its slot state not a permutation of the three
// slots) is refused on attach, never used.
TEST(SegmentTrust, ACorruptTripleBufferIsRefused) {
  NameGuard g(uniqueName("triple"));
  Segment sim = Segment::create(g.name, SegmentCapacity::forContacts(2));
  const int fd = openShm(g.name);
  ASSERT_GE(fd, 0);
  const std::size_t at = sim.header().snapshot_offset;
  void* p = ::mmap(nullptr, at + 4096, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
  ASSERT_NE(p, MAP_FAILED);
  auto* control = reinterpret_cast<tactus::shared::TripleBufferControl*>(
      static_cast<unsigned char*>(p) + at);
  const std::uint8_t good = control->state.load();
  control->state.store(tactus::shared::TripleBufferControl::make(3, 0, 1, true));
  auto r = Segment::tryOpen(g.name);
  EXPECT_FALSE(r.ok());
  EXPECT_THAT(r.message, HasSubstr("snapshot triple buffer is corrupt"));
  control->state.store(good);
  control->slot_stride = 64;   // a stride that is not the layout's
  r = Segment::tryOpen(g.name);
  EXPECT_FALSE(r.ok());
  EXPECT_THAT(r.message, HasSubstr("snapshot triple buffer is corrupt"));
  control->slot_stride = tactus::shared::roundUpToCacheLine(control->slot_bytes);
  EXPECT_TRUE(Segment::tryOpen(g.name).ok());
  ::munmap(p, at + 4096);
  ::close(fd);
}

// A directory under the segment's name is not a segment being created (create() used to say
// "being created by another process right now").
TEST(SegmentTrust, ADirectoryUnderTheNameIsNotASegment) {
  NameGuard g(uniqueName("directory"));
  const std::string path = Segment::pathOf(g.name);
  ASSERT_EQ(::mkdir(path.c_str(), 0700), 0);
  std::string message;
  try {
    Segment::create(g.name, SegmentCapacity::forContacts(1));
  } catch (const SegmentError& e) {
    message = e.what();
  }
  ::rmdir(path.c_str());
  EXPECT_THAT(message, HasSubstr("exists and is not a shared-memory object (a directory)"));
}

TEST(SegmentTrust, AWorldWritableSegmentIsRefused) {
  NameGuard g(uniqueName("mode"));
  Segment sim = Segment::create(g.name, SegmentCapacity::forContacts(2));
  const int fd = openShm(g.name);
  ASSERT_GE(fd, 0);
  for (mode_t mode : {0666, 0620, 0604}) {
    ASSERT_EQ(::fchmod(fd, mode), 0);
    const auto r = Segment::tryOpen(g.name);
    EXPECT_EQ(r.status, OpenStatus::kError) << std::oct << mode;
    char text[8];
    std::snprintf(text, sizeof(text), "%04o", static_cast<unsigned>(mode));
    EXPECT_THAT(r.message, HasSubstr(std::string("has mode ") + text +
                                     ": other users can read or write it"));
  }
  ASSERT_EQ(::fchmod(fd, 0600), 0);
  EXPECT_TRUE(Segment::tryOpen(g.name).ok());
  ::close(fd);
}

TEST(SegmentTrust, HapticServerDoesNotAttachToAWorldWritableSegment) {
  NameGuard g(uniqueName("haptic_mode"));
  Segment sim = Segment::create(g.name, SegmentCapacity::forContacts(2));
  sim.beat(Side::kSim);
  const int fd = openShm(g.name);
  ASSERT_GE(fd, 0);
  ASSERT_EQ(::fchmod(fd, 0666), 0);
  ::close(fd);
  SegmentChild haptic = spawn({kBin + "/haptic_server/haptic_server", "--segment", g.name,
                               "--device", "simulated", "--priority", "0"},
                              logPath(g.name, "haptic"));
  // bounded wait for the refusal in its log, beating meanwhile so the segment looks alive
  const auto end = std::chrono::steady_clock::now() + 20s;
  std::string log;
  while (std::chrono::steady_clock::now() < end && log.find("has mode 0666") == std::string::npos) {
    sim.beat(Side::kSim);
    std::this_thread::sleep_for(50ms);
    log = slurp(logPath(g.name, "haptic"));
  }
  EXPECT_THAT(log, HasSubstr("cannot attach to segment '" + g.name + "'"));
  EXPECT_THAT(log, HasSubstr("has mode 0666: other users can read or write it"));
  EXPECT_THAT(log, ::testing::Not(HasSubstr("attached to segment")));
  EXPECT_EQ(sim.header().haptic_pid.load(), 0);   // it never claimed the segment
  EXPECT_EQ(sim.heartbeatNs(Side::kHaptic), 0);   // nor ran its loop on it
  ::kill(haptic.pid, SIGTERM);
  EXPECT_TRUE(haptic.waitExit(10000ms));
}

TEST(SegmentTrust, AnotherUsersStaleSegmentIsNotReplaced) {
  if (::geteuid() != 0) GTEST_SKIP() << "needs root to give the object to another uid";
  NameGuard g(uniqueName("foreign_stale"));
  // a foreign object nobody holds (no lock): create() must still not remove it
  const int fd = ::shm_open(("/" + g.name).c_str(), O_RDWR | O_CREAT | O_EXCL, 0600);
  ASSERT_GE(fd, 0);
  ASSERT_EQ(::ftruncate(fd, 4096), 0);
  ASSERT_EQ(::fchown(fd, 65534, 65534), 0);
  ::close(fd);
  // an hour old: by age alone it would count as a crashed creation and be replaced
  const timespec old_times[2] = {{::time(nullptr) - 3600, 0}, {::time(nullptr) - 3600, 0}};
  ASSERT_EQ(::utimensat(AT_FDCWD, Segment::pathOf(g.name).c_str(), old_times, 0), 0);
  try {
    Segment::create(g.name, SegmentCapacity::forContacts(2));
    FAIL() << "another user's object was replaced";
  } catch (const SegmentError& e) {
    EXPECT_THAT(e.what(), HasSubstr("belongs to uid 65534"));
  }
  struct stat st {};
  ASSERT_EQ(::stat(Segment::pathOf(g.name).c_str(), &st), 0);
  EXPECT_EQ(st.st_uid, 65534u);
}

// ---------------------------------------------------------------------------------------------
// The haptic claim (a lock the kernel drops with its holder).

// What a racing child process uses to start with the others and to stay alive until all tried.
struct ChildSync {
  int go, done, quit;
  /// Blocks until the parent releases every child at once; false on a pipe problem.
  bool waitForGo() const {
    char c = 0;
    return ::read(go, &c, 1) == 0;   // released when the parent closes its end
  }
  /// Tells the parent this child tried, then stays alive (holding what it got) until every child
  /// has; false on a pipe problem.
  bool triedThenWaitForAll() const {
    char c = 1;
    if (::write(done, &c, 1) != 1) return false;
    return ::read(quit, &c, 1) == 0;
  }
};

// Forks `n` children that run `child` (its return value is the child's exit code; an exception
// is code 3) released at once; `after_all_tried` runs in the parent once every child has said
// it tried and before they end. Returns the exit codes in fork order (-1: did not exit
// normally) and the count of children that said they tried.
std::pair<std::vector<int>, int> raceInChildren(int n,
                                                const std::function<int(const ChildSync&)>& child,
                                                const std::function<void()>& after_all_tried,
                                                std::vector<pid_t>* pids = nullptr) {
  int go[2], done[2], quit[2];
  if (::pipe(go) != 0 || ::pipe(done) != 0 || ::pipe(quit) != 0) return {{}, 0};
  std::vector<pid_t> kids;
  for (int i = 0; i < n; ++i) {
    const pid_t pid = ::fork();
    if (pid == 0) {
      ::close(go[1]);
      ::close(done[0]);
      ::close(quit[1]);
      int code = 3;
      try {
        code = child(ChildSync{go[0], done[1], quit[0]});
      } catch (...) {
        code = 3;
      }
      ::_exit(code);
    }
    kids.push_back(pid);
  }
  ::close(go[0]);
  ::close(done[1]);
  ::close(quit[0]);
  ::close(go[1]);   // start them all at once
  int finished = 0;
  char c = 0;
  while (finished < n && ::read(done[0], &c, 1) == 1) ++finished;
  after_all_tried();
  ::close(quit[1]);
  ::close(done[0]);
  std::vector<int> codes;
  for (pid_t pid : kids) {
    int status = 0;
    const bool reaped = pid > 0 && ::waitpid(pid, &status, 0) == pid;
    codes.push_back(reaped && WIFEXITED(status) ? WEXITSTATUS(status) : -1);
  }
  if (pids != nullptr) *pids = kids;
  return {codes, finished};
}

TEST(SegmentHapticClaim, ExactlyOneOfManyRacingClaimantsWins) {
  NameGuard g(uniqueName("claim"));
  Segment sim = Segment::create(g.name, SegmentCapacity::forContacts(1));
  constexpr int kClaimants = 8;
  constexpr int kRounds = 10;
  for (int round = 0; round < kRounds; ++round) {
    SCOPED_TRACE("round " + std::to_string(round));
    std::int64_t holder = 0;
    std::vector<pid_t> kids;
    const auto [codes, finished] = raceInChildren(
        kClaimants,
        [&](const ChildSync& sync) {
          Segment mine = Segment::open(g.name);
          if (!sync.waitForGo()) return 4;
          const int code = mine.claimHaptic(::getpid()) == 0 ? 0 : 1;
          return sync.triedThenWaitForAll() ? code : 5;
        },
        [&] { holder = sim.header().haptic_pid.load(); }, &kids);
    int winners = 0;
    pid_t winner = -1;
    for (std::size_t i = 0; i < codes.size(); ++i) {
      ASSERT_GE(codes[i], 0);
      ASSERT_LE(codes[i], 1) << "claimant failed with " << codes[i];
      if (codes[i] == 0) {
        ++winners;
        winner = kids[i];
      }
    }
    EXPECT_EQ(finished, kClaimants);
    EXPECT_EQ(winners, 1);
    EXPECT_EQ(holder, winner);
    // the winner is dead now: its claim can be taken over (here by the test process)
    {
      Segment taker = Segment::open(g.name);
      EXPECT_EQ(taker.claimHaptic(::getpid()), 0);
      EXPECT_EQ(sim.header().haptic_pid.load(), ::getpid());
    }
    sim.setHapticPid(0);
  }
}

// A dead holder's pid, recycled by an unrelated live process, must not block a new claim (the
// claim used to trust kill(pid, 0)); a live holder's claim still refuses it.
TEST(SegmentHapticClaim, ARecycledPidOfADeadHolderDoesNotBlockTheClaim) {
  NameGuard g(uniqueName("claim_recycled"));
  Segment sim = Segment::create(g.name, SegmentCapacity::forContacts(1));
  sim.setHapticPid(::getppid());   // a live process that holds no claim
  {
    Segment mine = Segment::open(g.name);
    EXPECT_EQ(mine.claimHaptic(::getpid()), 0);
    EXPECT_EQ(sim.header().haptic_pid.load(), ::getpid());
    Segment other = Segment::open(g.name);
    EXPECT_EQ(other.claimHaptic(::getpid() + 1), ::getpid()) << "a live holder refuses";
  }
  Segment next = Segment::open(g.name);   // the holder's segment is closed: free again
  EXPECT_EQ(next.claimHaptic(::getpid() + 1), 0);
}

// Two simulations replacing the same stale segment at once: exactly one gets it, and the other
// never removes the winner's new segment (create() used to judge the segment stale and then
// remove whatever the name referred to by then).
TEST(SegmentOwnership, TwoCreatorsReplacingAStaleSegmentNeverDisplaceEachOther) {
  NameGuard g(uniqueName("stale_race"));
  constexpr int kCreators = 6;
  constexpr int kRounds = 8;
  CreateOptions keep;
  keep.remove_on_destroy = false;
  for (int round = 0; round < kRounds; ++round) {
    SCOPED_TRACE("round " + std::to_string(round));
    // a stale segment: its creator died
    const pid_t dead = ::fork();
    ASSERT_GE(dead, 0);
    if (dead == 0) {
      try {
        Segment s = Segment::create(g.name, SegmentCapacity::forContacts(1), keep);
        ::_exit(0);
      } catch (...) {
        ::_exit(1);
      }
    }
    int status = 0;
    ASSERT_EQ(::waitpid(dead, &status, 0), dead);
    ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
    ASSERT_TRUE(Segment::exists(g.name));
    // 0: created it and still owns the name once every creator has tried; 1: refused; 2: created
    // it but another creator displaced it
    const auto [codes, finished] = raceInChildren(
        kCreators,
        [&](const ChildSync& sync) {
          if (!sync.waitForGo()) return 4;
          std::optional<Segment> mine;
          try {
            mine.emplace(Segment::create(g.name, SegmentCapacity::forContacts(1), keep));
          } catch (const SegmentError&) {
          }
          if (!sync.triedThenWaitForAll()) return 5;
          if (!mine) return 1;
          return mine->stillCurrent() ? 0 : 2;
        },
        [] {});
    const std::string all = ::testing::PrintToString(codes);
    EXPECT_EQ(finished, kCreators) << all;
    EXPECT_EQ(std::count(codes.begin(), codes.end(), 2), 0)
        << "a creator's new segment was removed by another: " << all;
    EXPECT_EQ(std::count(codes.begin(), codes.end(), 0), 1) << all;
    for (int code : codes) EXPECT_TRUE(code >= 0 && code <= 2) << all;
  }
}

// ---------------------------------------------------------------------------------------------
// Absurd but finite device poses.

tactus::sim::SceneSpec pressCube() {
  return tactus::sim::loadScene(kData + "/scenes/press_cube.yaml");
}

void writeSample(tactus::shared::TripleWriter<DeviceSample>& writer, std::uint64_t seq,
                 const Eigen::Vector3d& pos_m, bool pose_valid = true, bool fault = false) {
  DeviceSample s{};
  s.seq = seq;
  s.t_ns = tactus::shared::monotonicNs();
  s.pos_m = {pos_m.x(), pos_m.y(), pos_m.z()};
  s.quat_wxyz = {1.0, 0.0, 0.0, 0.0};
  s.gripper_rad = 0.0;
  s.status = (fault ? tactus::shared::kDeviceFault : tactus::shared::kDeviceOk) |
             (pose_valid ? tactus::shared::kDevicePoseValid : 0u);
  writer.publish(s);
}

bool inside(const tactus::sim::BoxSpec& box, const Eigen::Vector3d& p) {
  return (p.array() >= box.min_m.array()).all() && (p.array() <= box.max_m.array()).all();
}

TEST(DeviceSanity, AbsurdPoseIsRejectedAndTheGodObjectRecovers) {
  NameGuard g(uniqueName("pose"));
  tactus::sim::SceneSpec spec = pressCube();
  tactus::sim::Simulation sim(spec);
  tactus::sim::Instrument& tool = *sim.instrument();
  const tactus::sim::BoxSpec workspace = tool.workspace();
  // the default workspace: the cube and the initial pose, grown by the margin
  EXPECT_LT(workspace.max_m.x(), 1.0);
  EXPECT_GT(workspace.max_m.x(), 0.5);
  tactus::sim::SegmentHost link(g.name, spec, workspace);
  Segment haptic = Segment::open(g.name);
  auto writer = haptic.deviceWriter();

  const Eigen::Vector3d start = spec.instrument.initial_pose.position_m;
  std::uint64_t seq = 0;
  auto step = [&](const Eigen::Vector3d& device_m) {
    writeSample(writer, ++seq, device_m);
    tactus::sim::DeviceTarget target = sim.scriptedTarget(sim.time());
    link.deviceTarget(target);
    sim.setDeviceTarget(target);
    sim.step();
  };
  for (int k = 0; k < 20; ++k) step(start);
  ASSERT_LT((tool.pose().pos_m - start).norm(), 1e-3);
  EXPECT_EQ(link.rejectedJumps(), 0u);

  // one simulated second of 1e300 m: rejected, the last good target is held
  for (int k = 0; k < 100; ++k) {
    step(Eigen::Vector3d(1e300, -1e300, 1e300));
    const Eigen::Vector3d p = tool.pose().pos_m;
    ASSERT_TRUE(p.allFinite()) << "step " << k;
    ASSERT_TRUE(inside(workspace, p)) << "step " << k;
    ASSERT_LT((p - start).norm(), 1e-3) << "step " << k << ": the god object left";
  }
  EXPECT_EQ(link.rejectedJumps(), 100u);

  // sane again, 5 mm aside: followed at once
  const Eigen::Vector3d moved = start + Eigen::Vector3d(0.005, 0.0, 0.0);
  for (int k = 0; k < 100; ++k) step(moved);
  EXPECT_LT((tool.pose().pos_m - moved).norm(), 1e-3);
  EXPECT_EQ(link.rejectedJumps(), 100u);
  EXPECT_TRUE(tool.twist().allFinite());
}

// Before its first real sample, haptic_server publishes samples at the origin (the pose it does
// not have yet); they must never move the instrument, however long they keep coming and whatever
// the jump allowance has grown to: the instrument holds the scene's own pose (its script).
TEST(DeviceSanity, SamplesWithoutADevicePoseNeverMoveTheInstrument) {
  NameGuard g(uniqueName("nopose"));
  tactus::sim::SceneSpec spec = pressCube();
  tactus::sim::Simulation sim(spec);
  tactus::sim::Instrument& tool = *sim.instrument();
  tactus::sim::SegmentHost link(g.name, spec, tool.workspace());
  Segment haptic = Segment::open(g.name);
  auto writer = haptic.deviceWriter();
  const Eigen::Vector3d start = spec.instrument.initial_pose.position_m;
  std::uint64_t seq = 0;
  auto step = [&](const Eigen::Vector3d& device_m, bool pose_valid) {
    writeSample(writer, ++seq, device_m, pose_valid);
    tactus::sim::DeviceTarget target = sim.scriptedTarget(sim.time());
    const bool driven = link.deviceTarget(target);
    sim.setDeviceTarget(target);
    sim.step();
    return driven;
  };
  // half a simulated second of origin samples (the allowance would cover 4.5 cm after 4 ms)
  for (int k = 0; k < 50; ++k) {
    ASSERT_FALSE(step(Eigen::Vector3d::Zero(), false)) << "step " << k;
    ASSERT_LT((tool.pose().pos_m - start).norm(), 1e-3) << "step " << k << ": dragged";
  }
  // the device's first real pose, 4 mm aside: followed
  const Eigen::Vector3d real = start + Eigen::Vector3d(0.004, 0.0, 0.0);
  for (int k = 0; k < 50; ++k) EXPECT_TRUE(step(real, true));
  EXPECT_LT((tool.pose().pos_m - real).norm(), 1e-3);
}

// The shutdown snapshot is the newest snapshot: the next seq and stamped now (it used to keep
// the slot's old seq and time, so readers saw the seq go backwards, and at seq 0, before any
// snapshot, they never saw the flag at all).
TEST(SegmentShutdown, TheShutdownSnapshotIsTheNewestOne) {
  for (int published : {0, 3}) {
    SCOPED_TRACE(published);
    NameGuard g(uniqueName("shutdown"));
    tactus::sim::SceneSpec spec = pressCube();
    tactus::sim::Simulation sim(spec);
    std::optional<tactus::sim::SegmentHost> host;
    host.emplace(g.name, spec, sim.instrument()->workspace());
    Segment haptic = Segment::open(g.name);
    auto sub = haptic.snapshotSubscriber();
    for (int k = 0; k < published; ++k) {
      sim.step();
      host->publish(sim);
    }
    const std::uint64_t last_seq = sub.latest().header().seq;
    EXPECT_EQ(last_seq, static_cast<std::uint64_t>(published));
    const std::int64_t before = tactus::shared::monotonicNs();
    host.reset();
    bool fresh = false;
    const auto& h = sub.latest(&fresh).header();
    EXPECT_TRUE(fresh);
    EXPECT_EQ(h.seq, last_seq + 1);
    EXPECT_GE(h.t_ns, before);
    EXPECT_NE(h.flags & tactus::shared::kSnapshotShuttingDown, 0u);
    EXPECT_EQ(h.flags & tactus::shared::kSnapshotValid, 0u);
  }
}

// A device that faults after it drove the instrument holds the instrument where it was (the
// haptic side holds the same pose): it used to go back to the scene's script, away from the hand,
// and on recovery the hand met tissue the local model had not had, past the engage gate.
TEST(DeviceSanity, AFaultingDeviceHoldsTheInstrumentWhereItWas) {
  NameGuard g(uniqueName("fault_hold"));
  tactus::sim::SceneSpec spec = pressCube();
  tactus::sim::Simulation sim(spec);
  tactus::sim::Instrument& tool = *sim.instrument();
  tactus::sim::SegmentHost link(g.name, spec, tool.workspace());
  Segment haptic = Segment::open(g.name);
  auto writer = haptic.deviceWriter();
  const Eigen::Vector3d start = spec.instrument.initial_pose.position_m;
  const Eigen::Vector3d pressed = start - Eigen::Vector3d(0.0, 0.0, 0.006);
  std::uint64_t seq = 0;
  auto step = [&](bool fault) {
    writeSample(writer, ++seq, pressed, true, fault);
    tactus::sim::DeviceTarget target = sim.scriptedTarget(sim.time());
    const bool driven = link.deviceTarget(target);
    sim.setDeviceTarget(target);
    sim.step();
    return std::make_pair(driven, target.pose.pos_m);
  };
  for (int k = 0; k < 30; ++k) step(false);
  for (int k = 0; k < 30; ++k) {
    const auto [driven, target] = step(true);
    ASSERT_TRUE(driven) << k;
    ASSERT_LT((target - pressed).norm(), 1e-12) << k << ": the instrument left the held pose";
  }
  const auto [driven, target] = step(false);   // recovered: followed at once
  EXPECT_TRUE(driven);
  EXPECT_LT((target - pressed).norm(), 1e-12);
}

// Samples that stop while haptic_server is still attached (its device read stalls or blocks)
// hold the instrument where it was too; once no haptic process holds the segment any more, the
// instrument follows the scene's script again.
TEST(DeviceSanity, StoppedSamplesHoldTheInstrumentWhileHapticServerIsAttached) {
  NameGuard g(uniqueName("stall_hold"));
  tactus::sim::SceneSpec spec = pressCube();
  tactus::sim::Simulation sim(spec);
  tactus::sim::SegmentHost link(g.name, spec, sim.instrument()->workspace());
  std::optional<Segment> claim(Segment::open(g.name));   // the haptic process's claim
  ASSERT_EQ(claim->claimHaptic(::getpid()), 0);
  Segment haptic = Segment::open(g.name);
  auto writer = haptic.deviceWriter();
  const Eigen::Vector3d pressed =
      spec.instrument.initial_pose.position_m - Eigen::Vector3d(0.0, 0.0, 0.006);
  for (std::uint64_t seq = 1; seq <= 10; ++seq) {
    writeSample(writer, seq, pressed);
    tactus::sim::DeviceTarget target = sim.scriptedTarget(sim.time());
    ASSERT_TRUE(link.deviceTarget(target));
  }
  // no sample for longer than the watchdog
  std::this_thread::sleep_for(std::chrono::milliseconds(
      static_cast<int>(2 * spec.haptics.watchdog_ms)));
  tactus::sim::DeviceTarget held = sim.scriptedTarget(sim.time());
  EXPECT_TRUE(link.deviceTarget(held)) << "the instrument went back to the script";
  EXPECT_LT((held.pose.pos_m - pressed).norm(), 1e-12);
  claim.reset();                                        // haptic_server is gone
  tactus::sim::DeviceTarget script = sim.scriptedTarget(sim.time());
  const Eigen::Vector3d scripted = script.pose.pos_m;
  EXPECT_FALSE(link.deviceTarget(script));
  EXPECT_EQ(script.pose.pos_m, scripted);
}

TEST(DeviceSanity, TheInstrumentBoundsAnyTargetToItsWorkspace) {
  // defence in depth below the link: even a caller handing 1e300 m to the instrument directly
  tactus::sim::SceneSpec spec = pressCube();
  tactus::sim::Instrument tool(spec.instrument);
  tactus::sim::BoxSpec box;
  box.min_m = Eigen::Vector3d(-0.5, -0.5, -0.5);
  box.max_m = Eigen::Vector3d(0.5, 0.5, 0.5);
  tool.setWorkspace(box);
  tactus::shared::Pose far;
  far.pos_m = Eigen::Vector3d(1e300, 0.0, -1e300);
  tactus::shared::Vector6d twist;
  twist << 1e300, 0, 0, 0, 0, -1e300;
  for (int k = 0; k < 200; ++k) tool.freeMotion(0.01, far, twist, 1.0);
  EXPECT_TRUE(tool.pose().pos_m.allFinite());
  EXPECT_TRUE(tool.twist().allFinite());
  EXPECT_TRUE(inside(box, tool.pose().pos_m));
  EXPECT_LT((tool.pose().pos_m - Eigen::Vector3d(0.5, 0.0, -0.5)).norm(), 0.05);
  EXPECT_EQ(tool.clampedTargets(), 200);
  // back: the god object returns
  tactus::shared::Pose home;
  for (int k = 0; k < 300; ++k) tool.freeMotion(0.01, home, tactus::shared::Vector6d::Zero(), 1.0);
  EXPECT_LT(tool.pose().pos_m.norm(), 1e-3);
  EXPECT_EQ(tool.clampedTargets(), 200);
  tactus::sim::BoxSpec bad = box;
  bad.min_m.x() = 1.0;
  EXPECT_THROW(tool.setWorkspace(bad), tactus::SceneError);
}

}  // namespace
