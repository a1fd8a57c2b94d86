// Segment trust and device-input sanity (issue "Safe by construction", items 4, 5, 7, 8):
//  * a simulation whose owner is alive (even stopped, even silent past the stale threshold) is
//    never replaced, and a simulation whose segment was removed and re-created while it was
//    stopped notices on resume and stops with a message (real sim_server processes);
//  * the haptic attach refuses a segment owned by another user or open to others (mode 0666),
//    and create() never replaces another user's object;
//  * the single-haptic-process claim is one compare-exchange: of many racing claimants exactly
//    one wins, and a dead claimant's claim is taken over;
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

#include <chrono>
#include <cmath>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "../../sim_server/src/pipeline/segment_host.h"
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
struct Child {
  pid_t pid = -1;
  bool reaped = false;
  int status = 0;
  ~Child() {
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

Child spawn(const std::vector<std::string>& args, const std::string& log) {
  Child c;
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

Child startSim(const std::string& name, const char* log_tag) {
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
// Item 4: a live (stopped) owner is never replaced; a displaced simulation stops.

TEST(SegmentOwnership, AStoppedSimulationIsNeverReplaced) {
  NameGuard g(uniqueName("stopped"));
  Child first = startSim(g.name, "first");
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
  Child second = startSim(g.name, "second");
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
  Child sim = startSim(g.name, "displaced");
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
// Item 7: owner and mode are checked before attaching.

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
  Child haptic = spawn({kBin + "/haptic_server/haptic_server", "--segment", g.name, "--device",
                        "simulated", "--priority", "0"},
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
// Item 8: the haptic claim is one compare-exchange.

TEST(SegmentHapticClaim, ExactlyOneOfManyRacingClaimantsWins) {
  NameGuard g(uniqueName("claim"));
  Segment sim = Segment::create(g.name, SegmentCapacity::forContacts(1));
  constexpr int kClaimants = 8;
  constexpr int kRounds = 10;
  for (int round = 0; round < kRounds; ++round) {
    SCOPED_TRACE("round " + std::to_string(round));
    int go[2], done[2], quit[2];
    ASSERT_EQ(::pipe(go), 0);
    ASSERT_EQ(::pipe(done), 0);
    ASSERT_EQ(::pipe(quit), 0);
    std::vector<pid_t> kids;
    for (int i = 0; i < kClaimants; ++i) {
      const pid_t pid = ::fork();
      ASSERT_GE(pid, 0);
      if (pid == 0) {
        ::close(go[1]);
        ::close(done[0]);
        ::close(quit[1]);
        int code = 2;
        try {
          Segment mine = Segment::open(g.name);
          char c = 0;
          if (::read(go[0], &c, 1) != 0) ::_exit(4);   // released when the parent closes it
          code = mine.claimHaptic(::getpid()) == 0 ? 0 : 1;
          c = 1;
          if (::write(done[1], &c, 1) != 1) ::_exit(5);
          // stay alive (holding or losing) until every claimant has tried
          if (::read(quit[0], &c, 1) != 0) ::_exit(6);
        } catch (...) {
          ::_exit(3);
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
    while (finished < kClaimants && ::read(done[0], &c, 1) == 1) ++finished;
    const std::int64_t holder = sim.header().haptic_pid.load();
    ::close(quit[1]);
    ::close(done[0]);
    int winners = 0;
    pid_t winner = -1;
    for (pid_t pid : kids) {
      int status = 0;
      ASSERT_EQ(::waitpid(pid, &status, 0), pid);
      ASSERT_TRUE(WIFEXITED(status));
      ASSERT_LE(WEXITSTATUS(status), 1) << "claimant failed with " << WEXITSTATUS(status);
      if (WEXITSTATUS(status) == 0) {
        ++winners;
        winner = pid;
      }
    }
    EXPECT_EQ(finished, kClaimants);
    EXPECT_EQ(winners, 1);
    EXPECT_EQ(holder, winner);
    // the winner is dead now: its claim can be taken over (here by the test process)
    EXPECT_EQ(sim.claimHaptic(::getpid()), 0);
    EXPECT_EQ(sim.header().haptic_pid.load(), ::getpid());
    sim.setHapticPid(0);
  }
}

TEST(SegmentHapticClaim, ALiveHoldersClaimIsRefusedAndNamed) {
  NameGuard g(uniqueName("claim_live"));
  Segment sim = Segment::create(g.name, SegmentCapacity::forContacts(1));
  Segment a = Segment::open(g.name);
  Segment b = Segment::open(g.name);
  const std::int64_t parent = ::getppid();   // alive for the whole test
  EXPECT_EQ(a.claimHaptic(parent), 0);
  EXPECT_EQ(a.claimHaptic(parent), 0);       // already ours
  EXPECT_EQ(b.claimHaptic(::getpid()), parent);
  EXPECT_EQ(sim.header().haptic_pid.load(), parent);
  Segment ro = Segment::open(g.name, Access::kReadOnly);
  EXPECT_EQ(ro.claimHaptic(::getpid()), -1);
}

// ---------------------------------------------------------------------------------------------
// Item 5: absurd but finite device poses.

tactus::sim::SceneSpec pressCube() {
  return tactus::sim::loadScene(kData + "/scenes/press_cube.yaml");
}

void writeSample(tactus::shared::TripleWriter<DeviceSample>& writer, std::uint64_t seq,
                 const Eigen::Vector3d& pos_m) {
  DeviceSample s{};
  s.seq = seq;
  s.t_ns = tactus::shared::monotonicNs();
  s.pos_m = {pos_m.x(), pos_m.y(), pos_m.z()};
  s.quat_wxyz = {1.0, 0.0, 0.0, 0.0};
  s.gripper_rad = 0.0;
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
