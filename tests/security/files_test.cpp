// Files, area "files": unbounded reads, files that are not regular files, signals while loading,
// lost writes and overwritten data, control bytes echoed in messages. Each test reproduces one
// report and asserts the fixed behaviour; daemons run with a bounded wait (a hang is a failure,
// the child is killed) and every temporary file lives in a per-test folder removed afterwards.
#include <fcntl.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <cstdio>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "tactus/device/backends.h"
#include "tactus/device/device.h"
#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"
#include "tactus/shared/snapshot_file.h"
#include "tactus/sim/mesh.h"
#include "tactus/sim/runner.h"
#include "tactus/sim/scene.h"

namespace fs = std::filesystem;
using namespace tactus;
using ::testing::HasSubstr;
using ::testing::Not;

namespace {

const std::string kSimServer = std::string(TACTUS_BINARY_DIR) + "/sim_server/sim_server";
const std::string kHapticServer = std::string(TACTUS_BINARY_DIR) + "/haptic_server/haptic_server";
const std::string kMeshes = std::string(TACTUS_TEST_DATA_DIR) + "/meshes";

struct RunResult {
  bool timed_out = false;
  bool exited = false;
  int code = -1;       ///< exit code when exited
  int signal = 0;      ///< terminating signal otherwise
  std::string output;  ///< stdout + stderr
};

std::string readAll(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// A child process whose stdout and stderr come back through a pipe (not a file: the file size
// limit some tests set must not cut the log), optionally with a file size limit [bytes].
class Child {
 public:
  explicit Child(const std::vector<std::string>& argv, long fsize_limit = -1,
                 long address_space_limit = -1) {
    int fds[2];
    if (::pipe2(fds, O_CLOEXEC) != 0) return;
    pid_ = ::fork();
    if (pid_ == 0) {
      ::dup2(fds[1], 1);
      ::dup2(fds[1], 2);
      if (fsize_limit >= 0) {
        ::signal(SIGXFSZ, SIG_IGN);  // a write past the limit fails with EFBIG instead
        const rlimit lim{static_cast<rlim_t>(fsize_limit), static_cast<rlim_t>(fsize_limit)};
        ::setrlimit(RLIMIT_FSIZE, &lim);
      }
      if (address_space_limit >= 0) {
        const rlimit lim{static_cast<rlim_t>(address_space_limit),
                         static_cast<rlim_t>(address_space_limit)};
        ::setrlimit(RLIMIT_AS, &lim);
      }
      std::vector<char*> args;
      for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
      args.push_back(nullptr);
      ::execv(args[0], args.data());
      ::_exit(127);
    }
    ::close(fds[1]);
    out_fd_ = fds[0];
    ::fcntl(out_fd_, F_SETFL, ::fcntl(out_fd_, F_GETFL) | O_NONBLOCK);
  }
  ~Child() {
    if (pid_ > 0 && !reaped_) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
    if (out_fd_ >= 0) ::close(out_fd_);
  }
  Child(const Child&) = delete;
  Child& operator=(const Child&) = delete;
  pid_t pid() const { return pid_; }
  const std::string& output() {
    pump();
    return output_;
  }

  /// Waits at most `limit`; a child still running then is killed and reported as timed out.
  RunResult wait(std::chrono::seconds limit) {
    RunResult r;
    const auto end = std::chrono::steady_clock::now() + limit;
    int status = 0;
    for (;;) {
      pump();
      const pid_t w = ::waitpid(pid_, &status, WNOHANG);
      if (w == pid_) break;
      if (w < 0 || std::chrono::steady_clock::now() > end) {
        ::kill(pid_, SIGKILL);
        ::waitpid(pid_, &status, 0);
        r.timed_out = true;
        break;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    reaped_ = true;
    if (WIFEXITED(status)) {
      r.exited = true;
      r.code = WEXITSTATUS(status);
    } else if (WIFSIGNALED(status)) {
      r.signal = WTERMSIG(status);
    }
    pump();
    r.output = output_;
    return r;
  }

  /// Waits (bounded) until the output contains `text`; false on timeout or when the child ended.
  bool waitForOutput(const std::string& text, std::chrono::seconds limit) {
    const auto end = std::chrono::steady_clock::now() + limit;
    while (std::chrono::steady_clock::now() < end) {
      pump();
      if (output_.find(text) != std::string::npos) return true;
      siginfo_t info{};
      // ended (not reaped: wait() collects it)
      if (::waitid(P_PID, static_cast<id_t>(pid_), &info, WEXITED | WNOHANG | WNOWAIT) == 0 &&
          info.si_pid == pid_) {
        return false;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return false;
  }

 private:
  void pump() {
    char buf[4096];
    for (;;) {
      const ssize_t n = out_fd_ >= 0 ? ::read(out_fd_, buf, sizeof(buf)) : -1;
      if (n <= 0) return;
      output_.append(buf, static_cast<std::size_t>(n));
    }
  }

  pid_t pid_ = -1;
  int out_fd_ = -1;
  bool reaped_ = false;
  std::string output_;
};

class FilesTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string templ = (fs::temp_directory_path() / "tactus_files_test_XXXXXX").string();
    ASSERT_NE(::mkdtemp(templ.data()), nullptr);
    dir_ = templ;
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  fs::path write(const std::string& name, const std::string& text) {
    const fs::path p = dir_ / name;
    std::ofstream out(p, std::ios::binary);
    out << text;
    return p;
  }

  // A small valid scene: a tissue (`mesh`, scaled by `scale`; `extra` goes into the tissue) and
  // a probe above it with a scripted trajectory (the compliance is only built with an instrument).
  fs::path scene(const std::string& name, const std::string& mesh, double scale,
                 const std::string& extra = "") {
    return write(name, "time_step: 0.01\ntissues:\n  - name: organ\n    mesh: " + kMeshes + "/" +
                           mesh + "\n    transform: {scale: " + std::to_string(scale) + "}\n" +
                           extra +
                           "instrument:\n  type: probe\n  trajectory:\n"
                           "    - {t: 0.0, position: [0, 0, 0.5]}\n"
                           "    - {t: 0.5, position: [0, 0, 0.45]}\n");
  }
  fs::path cubeScene(const std::string& name = "scene.yaml", const std::string& extra = "") {
    return scene(name, "cube_low_res.msh", 0.01, extra);
  }

  // Files left in the folder (to catch temporary files a failed write leaves behind).
  std::vector<std::string> listing() const {
    std::vector<std::string> names;
    for (const auto& e : fs::directory_iterator(dir_)) names.push_back(e.path().filename());
    return names;
  }

  RunResult run(const std::vector<std::string>& argv, std::chrono::seconds limit = std::chrono::seconds(30),
                long fsize_limit = -1, long address_space_limit = -1) {
    Child c(argv, fsize_limit, address_space_limit);
    return c.wait(limit);
  }

  fs::path dir_;
};

// ------------------------------------------------------------------------------------------------
// Reading

TEST_F(FilesTest, SimServerOnDevZeroIsRefusedBeforeReading) {
  const RunResult r = run({kSimServer, "/dev/zero"});
  ASSERT_FALSE(r.timed_out) << r.output;
  ASSERT_TRUE(r.exited) << "signal " << r.signal << ": " << r.output;
  EXPECT_NE(r.code, 0);
  EXPECT_THAT(r.output, HasSubstr("/dev/zero: is not a regular file"));
  EXPECT_THAT(r.output, Not(HasSubstr("bad_alloc")));
}

TEST_F(FilesTest, FifoSceneFailsFastInsteadOfBlocking) {
  const fs::path fifo = dir_ / "scene.yaml";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const RunResult r = run({kSimServer, fifo.string()}, std::chrono::seconds(20));
  ASSERT_FALSE(r.timed_out) << "sim_server blocked on a FIFO scene";
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_NE(r.code, 0);
  EXPECT_THAT(r.output, HasSubstr("is not a regular file"));
}

TEST_F(FilesTest, OversizedSceneIsRefused) {
  const fs::path big = dir_ / "big.yaml";
  {
    std::ofstream out(big);
    out << "time_step: 0.01\n";
  }
  fs::resize_file(big, shared::kMaxSceneBytes + 1);
  try {
    (void)sim::loadScene(big);
    FAIL() << "no error";
  } catch (const SceneError& e) {
    EXPECT_THAT(e.what(), HasSubstr("more than the"));
  }
}

TEST_F(FilesTest, FifoComplianceCacheIsRejectedAndRebuilt) {
  const fs::path cache = dir_ / "cache";
  fs::create_directories(cache);
  ASSERT_EQ(::mkfifo((cache / "organ.c0.bin").c_str(), 0600), 0);
  const fs::path scene =
      cubeScene("scene.yaml", "    compliance: {model: warped, cache_dir: " + cache.string() + "}\n");
  const RunResult r = run({kSimServer, scene.string(), "--steps", "2"}, std::chrono::seconds(60));
  ASSERT_FALSE(r.timed_out) << "sim_server blocked on a FIFO compliance cache";
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_THAT(r.output, HasSubstr("rejected"));
  EXPECT_THAT(r.output, HasSubstr("not a regular file"));
  // the FIFO is neither written into nor replaced
  struct stat st {};
  ASSERT_EQ(::stat((cache / "organ.c0.bin").c_str(), &st), 0);
  EXPECT_TRUE(S_ISFIFO(st.st_mode));
}

TEST_F(FilesTest, DirectoryAsMeshSaysIsADirectory) {
  fs::create_directories(dir_ / "mesh.msh");
  try {
    (void)sim::loadTetMesh(dir_ / "mesh.msh");
    FAIL() << "no error";
  } catch (const MeshError& e) {
    EXPECT_THAT(e.what(), HasSubstr("is a directory"));
    EXPECT_THAT(e.what(), Not(HasSubstr("not found")));
  }
  const fs::path scene = write("s.yaml", "time_step: 0.01\ntissues:\n  - mesh: " +
                                             (dir_ / "mesh.msh").string() + "\n");
  try {
    (void)sim::loadScene(scene);
    FAIL() << "no error";
  } catch (const SceneError& e) {
    EXPECT_THAT(e.what(), HasSubstr("is a directory"));
    EXPECT_THAT(e.what(), Not(HasSubstr("not found")));
  }
}

TEST_F(FilesTest, SparseTwoGigabyteMeshIsRejectedBeforeReading) {
  const fs::path mesh = dir_ / "huge.msh";
  {
    const int fd = ::open(mesh.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    ASSERT_GE(fd, 0);
    ASSERT_EQ(::ftruncate(fd, off_t{2} << 30), 0);  // sparse: no disk used
    ::close(fd);
  }
  rusage before{};
  ::getrusage(RUSAGE_SELF, &before);
  try {
    (void)sim::loadTetMesh(mesh);
    FAIL() << "no error";
  } catch (const MeshError& e) {
    EXPECT_THAT(e.what(), HasSubstr("more than the"));
  }
  // under the size limit: the format is sniffed from the first bytes, the rest is never read
  fs::resize_file(mesh, std::uintmax_t{512} << 20);
  try {
    (void)sim::loadTetMesh(mesh);
    FAIL() << "no error";
  } catch (const MeshError& e) {
    EXPECT_THAT(e.what(), HasSubstr("unrecognised mesh format"));
  }
  rusage after{};
  ::getrusage(RUSAGE_SELF, &after);
  // peak memory [KiB] did not grow by the file's 512 MiB (reading it whole would)
  EXPECT_LT(after.ru_maxrss - before.ru_maxrss, 128 * 1024);
}

TEST_F(FilesTest, ReplayOfDevZeroIsRefusedAtOnce) {
  try {
    (void)device::loadDevice("replay", {{"file", "/dev/zero"}});
    FAIL() << "no error";
  } catch (const DeviceError& e) {
    EXPECT_THAT(e.what(), HasSubstr("not a regular file"));
  }
  // a regular but binary file (sparse: all NUL bytes) is rejected from its first bytes
  const fs::path zeros = dir_ / "zeros.csv";
  {
    std::ofstream touch(zeros);
  }
  fs::resize_file(zeros, std::uintmax_t{200} << 20);
  rusage before{};
  ::getrusage(RUSAGE_SELF, &before);
  try {
    (void)device::loadDevice("replay", {{"file", zeros.string()}});
    FAIL() << "no error";
  } catch (const DeviceError& e) {
    EXPECT_THAT(e.what(), HasSubstr("binary file"));
  }
  rusage after{};
  ::getrusage(RUSAGE_SELF, &after);
  EXPECT_LT(after.ru_maxrss - before.ru_maxrss, 64 * 1024);  // [KiB]: not read whole
  const RunResult r = run({kHapticServer, "--device", "replay", "--device-option", "file=/dev/zero",
                           "--segment", "tactus_files_test_" + std::to_string(::getpid())},
                          std::chrono::seconds(20));
  ASSERT_FALSE(r.timed_out) << "haptic_server kept reading /dev/zero";
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_NE(r.code, 0);
  EXPECT_THAT(r.output, HasSubstr("not a regular file"));
}

TEST_F(FilesTest, SigtermDuringC0PrecomputationExitsWithAMessage) {
  const fs::path liver =
      scene("liver.yaml", "liver_23k.msh", 0.01, "    compliance: {model: warped}\n");
  Child c({kSimServer, liver.string(), "--steps", "1"});
  ASSERT_TRUE(c.waitForOutput("C0 precompute", std::chrono::seconds(120))) << c.output();
  ::kill(c.pid(), SIGTERM);
  const RunResult r = c.wait(std::chrono::seconds(30));
  ASSERT_FALSE(r.timed_out) << "SIGTERM ignored during the C0 precomputation";
  ASSERT_TRUE(r.exited) << "signal " << r.signal;
  EXPECT_EQ(r.code, 128 + SIGTERM);
  EXPECT_THAT(r.output, HasSubstr("interrupted"));
  EXPECT_THAT(r.output, Not(HasSubstr("100%")));
}

// ------------------------------------------------------------------------------------------------
// Writing

TEST_F(FilesTest, StatsJsonOnAFullDiskExitsNonZero) {
  const fs::path scene = cubeScene();
  const RunResult r =
      run({kSimServer, scene.string(), "--steps", "2", "--stats-json", "/dev/full"});
  ASSERT_FALSE(r.timed_out);
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_NE(r.code, 0);
  EXPECT_THAT(r.output, HasSubstr("/dev/full: write failed: No space left on device"));
}

TEST_F(FilesTest, StatsJsonWriteFailureLeavesNoFile) {
  const fs::path scene = cubeScene();
  const fs::path stats = dir_ / "stats.json";
  // the file size limit makes the temporary file's write fail (EFBIG), as a full disk would
  const RunResult r =
      run({kSimServer, scene.string(), "--steps", "2", "--stats-json", stats.string()},
          std::chrono::seconds(30), 100);
  ASSERT_FALSE(r.timed_out);
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_NE(r.code, 0);
  EXPECT_THAT(r.output, HasSubstr("write failed"));
  EXPECT_FALSE(fs::exists(stats));
  for (const auto& name : listing()) EXPECT_THAT(name, Not(HasSubstr(".tmp"))) << name;
}

TEST_F(FilesTest, StatsJsonIsNotOverwrittenUnlessAsked) {
  const fs::path scene = cubeScene();
  const fs::path stats = write("stats.json", "precious");
  RunResult r = run({kSimServer, scene.string(), "--steps", "2", "--stats-json", stats.string()});
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_NE(r.code, 0);
  EXPECT_THAT(r.output, HasSubstr("exists"));
  EXPECT_THAT(r.output, HasSubstr("--overwrite"));
  EXPECT_THAT(r.output, Not(HasSubstr("steps, simulated")));  // refused before running
  EXPECT_EQ(readAll(stats), "precious");
  r = run(
      {kSimServer, scene.string(), "--steps", "2", "--stats-json", stats.string(), "--overwrite"});
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_THAT(readAll(stats), HasSubstr("\"stages_ms\""));
}

// The runner times its VTK output (after the step and its publication, outside total) under the
// "output" stage of the statistics: a run writing a frame every step reports a nonzero output
// time (the row read 0 while nothing filled StageTimes::output_s).
TEST_F(FilesTest, StatsJsonReportsTheVtkOutputTime) {
  const fs::path scene = cubeScene();
  const fs::path stats = dir_ / "stats.json";
  const fs::path out_dir = dir_ / "vtk";
  const RunResult r = run({kSimServer, scene.string(), "--steps", "3", "--output", out_dir.string(),
                           "--output-every", "1", "--stats-json", stats.string()});
  ASSERT_TRUE(r.exited) << r.output;
  ASSERT_EQ(r.code, 0) << r.output;
  const std::string js = readAll(stats);
  const std::string key = "\"output\": {\"median\": ";
  const std::size_t at = js.find(key);
  ASSERT_NE(at, std::string::npos) << js;
  const double output_median_ms = std::stod(js.substr(at + key.size()));
  EXPECT_GT(output_median_ms, 0.0) << js;
  EXPECT_TRUE(fs::exists(out_dir / "series.pvd"));
}

// --record-snapshots is bounded: the recording stops (with a warning; the run goes on and exits
// 0) before the file passes --record-snapshots-max-mb, and what was written stays readable. It
// had no cap: a long hold wrote 2.73 GB that the replay then refused, and a daemon would fill
// the disk.
TEST_F(FilesTest, RecordSnapshotsStopsAtItsCapAndTheFileStaysReadable) {
  const fs::path snaps = dir_ / "run.snap";
  const RunResult r =
      run({kSimServer, std::string(TACTUS_TEST_DATA_DIR) + "/scenes/press_cube.yaml", "--steps",
           "5000", "--record-snapshots", snaps.string(), "--record-snapshots-max-mb", "1"});
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_THAT(r.output, HasSubstr("reached its cap of 1 MiB"));
  ASSERT_TRUE(fs::exists(snaps));
  EXPECT_LE(fs::file_size(snaps), std::uintmax_t{1} << 20);
  const auto recorded = tactus::shared::readSnapshotFile(snaps);
  EXPECT_GT(recorded.size(), 1000u);
  EXPECT_LT(recorded.size(), 5000u);
  const RunResult big = run(
      {kSimServer, std::string(TACTUS_TEST_DATA_DIR) + "/scenes/press_cube.yaml", "--steps", "1",
       "--record-snapshots", (dir_ / "b.snap").string(), "--record-snapshots-max-mb", "4096"});
  EXPECT_NE(big.code, 0) << "a cap beyond what the replay reads is refused";
  EXPECT_THAT(big.output, HasSubstr("--record-snapshots-max-mb"));
}

// A compliance block C0 that cannot fit the memory the process may have is refused up front
// with its size and what to do (it used to end in a bare std::bad_alloc once the allocation
// failed). liver_23k's C0 is 1.66 GB; the process may have 1.2 GB here (ulimit -v).
TEST_F(FilesTest, AComplianceBlockBeyondTheMemoryIsRefusedWithItsSize) {
  const fs::path scene = this->scene("big.yaml", "liver_23k.msh", 1.0);
  const RunResult r =
      run({kSimServer, scene.string(), "--steps", "1"}, std::chrono::seconds(60), -1, 1200L << 20);
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_THAT(r.output, HasSubstr("rest compliance block C0"));
  EXPECT_THAT(r.output, HasSubstr("needs 1.7 GB"));
  EXPECT_THAT(r.output, HasSubstr("compliance.model: exact"));
  EXPECT_THAT(r.output, Not(HasSubstr("C0 precompute")));
}

TEST_F(FilesTest, ExportTrajectoryChecksWritesAndRefusesOverwrite) {
  const fs::path scene = cubeScene();
  RunResult r = run({kSimServer, scene.string(), "--export-trajectory", "/dev/full"});
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_NE(r.code, 0);
  EXPECT_THAT(r.output, HasSubstr("No space left on device"));
  const fs::path csv = write("traj.csv", "precious");
  r = run({kSimServer, scene.string(), "--export-trajectory", csv.string()});
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_NE(r.code, 0);
  EXPECT_EQ(readAll(csv), "precious");
  r = run({kSimServer, scene.string(), "--export-trajectory", csv.string(), "--overwrite"});
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_THAT(readAll(csv), HasSubstr("t_s,x,y,z"));
}

// A VTK series replaces its own files as it grows, but an earlier run's series in the --output
// folder is kept unless --overwrite is given; the same for tactus-fc3d-solve's --output.
TEST_F(FilesTest, EarlierVtkSeriesAndSolverOutputAreNotReplacedUnlessAsked) {
  const fs::path scene = cubeScene();
  const fs::path out_dir = dir_ / "vtk";
  fs::create_directories(out_dir);
  const fs::path pvd = out_dir / "series.pvd";
  { std::ofstream(pvd) << "precious"; }
  RunResult r = run({kSimServer, scene.string(), "--steps", "2", "--output", out_dir.string()});
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_NE(r.code, 0);
  EXPECT_THAT(r.output, HasSubstr("earlier run"));
  EXPECT_THAT(r.output, HasSubstr("--overwrite"));
  EXPECT_EQ(readAll(pvd), "precious");
  r = run(
      {kSimServer, scene.string(), "--steps", "2", "--output", out_dir.string(), "--overwrite"});
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_THAT(readAll(pvd), HasSubstr("VTKFile"));

  const std::string solver = std::string(TACTUS_BINARY_DIR) + "/tools/fc3d_solve/tactus-fc3d-solve";
  const std::string problem =
      std::string(TACTUS_TEST_DATA_DIR) + "/fclib/problems/Box_Stacks-i0122-82-5.local.fc3d.txt";
  const fs::path solution = write("solution.ref.txt", "precious");
  r = run({solver, problem, "--output", solution.string()});
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_NE(r.code, 0);
  EXPECT_THAT(r.output, HasSubstr("--overwrite"));
  EXPECT_EQ(readAll(solution), "precious");
  r = run({solver, problem, "--output", solution.string(), "--overwrite"});
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_NE(readAll(solution), "precious");
}

TEST_F(FilesTest, RecordOntoAnExistingFileIsRefusedUnlessAsked) {
  const fs::path input = write("input.csv", std::string(device::Trajectory::kCsvHeader) +
                                                "\n0,0,0,0,1,0,0,0,0\n0.5,0.01,0,0,1,0,0,0,0\n");
  const std::string original = readAll(input);
  // replaying a file while recording onto it: refused, the input stays intact
  auto dev = device::loadDevice("replay", {{"file", input.string()}, {"record", input.string()}});
  try {
    dev->open();
    FAIL() << "no error";
  } catch (const DeviceError& e) {
    EXPECT_THAT(e.what(), HasSubstr("exists"));
    EXPECT_THAT(e.what(), HasSubstr("record_overwrite=1"));
  }
  dev.reset();
  EXPECT_EQ(readAll(input), original);
  // asked: the input is replaced, after the replay read it
  dev = device::loadDevice("replay", {{"file", input.string()},
                                      {"record", input.string()},
                                      {"record_overwrite", "1"}});
  dev->open();
  device::DeviceState s;
  for (int i = 0; i < 5; ++i) {
    ASSERT_EQ(dev->read(&s), device::IoStatus::kOk);
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  dev->close();
  auto* rec = dynamic_cast<device::RecordingDevice*>(dev.get());
  ASSERT_NE(rec, nullptr);
  EXPECT_EQ(rec->writeError(), "");
  EXPECT_NE(readAll(input), original);
  EXPECT_EQ(device::Trajectory::loadCsv(input.string()).points().size(), rec->recorded());
}

TEST_F(FilesTest, RecordingWriteFailureIsReported) {
  auto dev = device::loadDevice("simulated", {{"record", "/dev/full"}});
  dev->open();
  device::DeviceState s;
  ASSERT_EQ(dev->read(&s), device::IoStatus::kOk);
  dev->close();
  auto* rec = dynamic_cast<device::RecordingDevice*>(dev.get());
  ASSERT_NE(rec, nullptr);
  EXPECT_THAT(rec->writeError(), HasSubstr("No space left on device"));
  // the daemon reports it and exits non-zero
  const RunResult r =
      run({kHapticServer, "--device", "simulated", "--device-option", "record=/dev/full",
           "--duration", "0.2", "--segment", "tactus_files_test_" + std::to_string(::getpid())},
          std::chrono::seconds(20));
  ASSERT_FALSE(r.timed_out);
  ASSERT_TRUE(r.exited) << r.output;
  EXPECT_NE(r.code, 0);
  EXPECT_THAT(r.output, HasSubstr("recording not saved"));
}

TEST_F(FilesTest, OutputFileWritesThroughATemporaryFile) {
  const fs::path target = dir_ / "out.txt";
  shared::writeFileChecked(target, "one", "test file");
  EXPECT_EQ(readAll(target), "one");
  EXPECT_THROW(shared::writeFileChecked(target, "two", "test file"), FileError);
  EXPECT_EQ(readAll(target), "one");
  shared::writeFileChecked(target, "two", "test file", {.overwrite = true});
  EXPECT_EQ(readAll(target), "two");
  {
    // an abandoned (uncommitted) file leaves neither target nor temporary behind
    shared::OutputFile out(dir_ / "abandoned.txt", "test file");
    out.write("partial");
  }
  EXPECT_FALSE(fs::exists(dir_ / "abandoned.txt"));
  EXPECT_EQ(listing(), std::vector<std::string>{"out.txt"});
  // a folder that refuses files
  EXPECT_THROW(shared::writeFileChecked("/proc/self/tactus_out.txt", "x", "test file"), FileError);
  EXPECT_THROW(shared::writeFileChecked(dir_, "x", "test file", {.overwrite = true}), FileError);
}

// ------------------------------------------------------------------------------------------------
// Messages

TEST(FilesMessages, PrintableEscapesControlBytesAndTruncates) {
  EXPECT_EQ(shared::printable("a\x1b[31mb"), "a\\x1b[31mb");
  EXPECT_EQ(shared::printable("tab\there\n"), "tab\\x09here\\x0a");
  EXPECT_EQ(shared::printable("\x7f\xc2\x9b"), "\\x7f\\xc2\\x9b");  // DEL, C1 CSI
  EXPECT_EQ(shared::printable("caf\xc3\xa9"), "caf\xc3\xa9");        // UTF-8 text is kept
  EXPECT_EQ(shared::printable("\xff\xc3"), "\\xff\\xc3");            // invalid UTF-8
  EXPECT_EQ(shared::printable(std::string(100, 'x')), std::string(64, 'x') + "...");
  EXPECT_EQ(shared::printable(std::string(64, 'x')), std::string(64, 'x'));
}

TEST(FilesMessages, SceneErrorsEscapeControlBytesAndBoundTokens) {
  try {
    (void)sim::parseScene("time_step: 0.01\n\"evil\x1b]0;pwned\x07\": 1\n", "s.yaml", ".");
    FAIL() << "no error";
  } catch (const SceneError& e) {
    const std::string m = e.what();
    EXPECT_THAT(m, HasSubstr("evil\\x1b]0;pwned\\x07"));
    EXPECT_EQ(m.find('\x1b'), std::string::npos);
    EXPECT_EQ(m.find('\x07'), std::string::npos);
  }
  const std::string token(10 << 20, 'A');
  try {
    (void)sim::parseScene("time_step: " + token + "\n", "s.yaml", ".");
    FAIL() << "no error";
  } catch (const SceneError& e) {
    EXPECT_LT(std::string(e.what()).size(), 2000u);
    EXPECT_THAT(e.what(), HasSubstr("AAAA..."));
  }
}

TEST(FilesMessages, StatsJsonEscapesTheScenePath) {
  const std::string js = sim::RunStatistics().json("a\"b\\c\x1b.yaml");
  EXPECT_THAT(js, HasSubstr("\"scene\": \"a\\\"b\\\\c\\u001b.yaml\""));
}

TEST(FilesMessages, TrajectoryCsvErrorsEscapeControlBytes) {
  try {
    (void)device::Trajectory::parseCsv(std::string(device::Trajectory::kCsvHeader) +
                                           "\n0,\x1b[2J,0,0,1,0,0,0,0\n",
                                       "t.csv");
    FAIL() << "no error";
  } catch (const DeviceError& e) {
    EXPECT_THAT(e.what(), HasSubstr("\\x1b[2J"));
    EXPECT_EQ(std::string(e.what()).find('\x1b'), std::string::npos);
  }
}

}  // namespace
