// Recorded contact snapshots (shared/snapshot_file.h) and their replay through the jitter tool:
// the file round-trips every field, an existing file is never replaced, a truncated or corrupt
// file is rejected with a clear error before anything is allocated for it, and a short recorded
// run of a cube pressed by a probe replays through the real haptic loop (in-process rig and the
// tactus-jitter binary) with ticks that solve and converge. No timing thresholds.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "jitter_core.h"
#include "jitter_replay.h"
#include "tactus/shared/file_io.h"
#include "tactus/shared/messages.h"
#include "tactus/shared/snapshot_file.h"

namespace fs = std::filesystem;

namespace tactus {
namespace {

class TempDir {
 public:
  TempDir() {
    std::string pattern = (fs::temp_directory_path() / "tactus-jitter-replay-XXXXXX").string();
    if (::mkdtemp(pattern.data()) == nullptr) throw std::runtime_error("mkdtemp failed");
    path_ = pattern;
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

// A slot-shaped buffer with a snapshot of `contacts` frictional contacts (ld = capacity rows).
struct SlotBuffer {
  shared::SnapshotLayout layout;
  std::vector<unsigned char> bytes;
  SlotBuffer(int cap_rows, int cap_contacts)
      : layout(shared::SnapshotLayout::forCapacity(cap_rows, cap_contacts)),
        bytes(layout.total_bytes + 64, 0) {}
  void* base() {
    auto p = reinterpret_cast<std::uintptr_t>(bytes.data());
    return bytes.data() + ((64 - p % 64) % 64);
  }
  shared::SnapshotWriter writer() { return shared::SnapshotWriter(base(), layout); }
};

// Fills the slot with distinct values per field (k varies them between snapshots).
void fill(shared::SnapshotWriter w, int contacts, int k) {
  const int m = 3 * contacts;
  ASSERT_TRUE(w.setSize(m, contacts));
  auto& h = w.header();
  h.seq = 100 + k;
  h.step = 7 + k;
  h.h_s = 0.01;
  h.flags = shared::kSnapshotValid | shared::kSnapshotConverged | shared::kSnapshotHasJacobian;
  h.solver_sweeps = 12 + k;
  h.solver_error = 1e-7;
  h.device_seq = 55;
  h.device_pose.pos_m = {0.1, 0.2 + k, 0.3};
  h.tool_pose.gripper_rad = 0.25;
  for (int c = 0; c <= contacts; ++c) w.rowOffset()[c] = 3 * c;
  for (int c = 0; c < contacts; ++c) {
    w.contactId()[c] = 1000 + c;
    w.mu()[c] = 0.5 + 0.01 * c;
    for (int i = 0; i < 3; ++i) {
      w.contactPoint()[3 * c + i] = 0.001 * (c + i);
      w.contactNormal()[3 * c + i] = i == 2 ? 1.0 : 0.0;
    }
    for (int i = 0; i < 6; ++i) w.contactTangent()[6 * c + i] = i == 0 || i == 4 ? 1.0 : 0.0;
  }
  for (int r = 0; r < m; ++r) {
    for (int s = 0; s < m; ++s) w.W()[r * w.ld() + s] = r == s ? 1e-3 : 1e-5 * (r + s + k);
    w.deltaFree()[r] = -1e-4 * (r + 1);
    w.f()[r] = 0.1 * r;
    for (int i = 0; i < 6; ++i) w.J()[6 * r + i] = 0.01 * (i + r);
  }
}

// Writes `n` snapshots of 1 + i contacts each (the first one with none) to `path`.
void writeFile(const fs::path& path, int n) {
  SlotBuffer slot(12, 4);
  shared::SnapshotFileWriter out(path);
  for (int i = 0; i < n; ++i) {
    fill(slot.writer(), i % 5, i);
    ASSERT_TRUE(out.append(slot.writer().view(), 10'000'000LL * i));
  }
  EXPECT_EQ(out.count(), static_cast<std::uint64_t>(n));
  out.commit();
}

std::string readAll(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

void writeAll(const fs::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out << bytes;
}

// The message of the FileError reading `path` throws ("" when it does not throw).
std::string readError(const fs::path& path) {
  try {
    shared::readSnapshotFile(path);
  } catch (const FileError& e) {
    return e.what();
  }
  return "";
}

TEST(SnapshotFile, RoundTripKeepsEveryField) {
  TempDir dir;
  const fs::path file = dir.path() / "run.snap";
  writeFile(file, 5);
  const auto snaps = shared::readSnapshotFile(file);
  ASSERT_EQ(snaps.size(), 5u);
  for (int k = 0; k < 5; ++k) {
    SlotBuffer ref(12, 4);
    fill(ref.writer(), k % 5, k);
    const shared::SnapshotView v = ref.writer().view();
    const shared::RecordedSnapshot& s = snaps[k];
    SCOPED_TRACE(k);
    EXPECT_EQ(s.t_ns, 10'000'000LL * k);
    EXPECT_EQ(s.rows(), v.rows());
    EXPECT_EQ(s.contacts(), v.contacts());
    EXPECT_EQ(s.header.seq, v.header().seq);
    EXPECT_EQ(s.header.step, v.header().step);
    EXPECT_EQ(s.header.flags, v.header().flags);
    EXPECT_EQ(s.header.solver_sweeps, v.header().solver_sweeps);
    EXPECT_EQ(s.header.device_pose.pos_m, v.header().device_pose.pos_m);
    EXPECT_EQ(s.header.tool_pose.gripper_rad, 0.25);
    const int m = v.rows();
    const int nc = v.contacts();
    ASSERT_EQ(s.W.size(), static_cast<std::size_t>(m) * m);
    for (int r = 0; r < m; ++r) {
      for (int c = 0; c < m; ++c) ASSERT_EQ(s.W[r * m + c], v.W()[r * v.ld() + c]);
      ASSERT_EQ(s.delta_free[r], v.deltaFree()[r]);
      ASSERT_EQ(s.f[r], v.f()[r]);
      for (int i = 0; i < 6; ++i) ASSERT_EQ(s.J[6 * r + i], v.J()[6 * r + i]);
    }
    for (int c = 0; c <= nc; ++c) ASSERT_EQ(s.row_offset[c], v.rowOffset()[c]);
    for (int c = 0; c < nc; ++c) {
      ASSERT_EQ(s.contact_id[c], v.contactId()[c]);
      ASSERT_EQ(s.mu[c], v.mu()[c]);
      for (int i = 0; i < 3; ++i) ASSERT_EQ(s.contact_point_m[3 * c + i], v.contactPoint()[3 * c + i]);
      for (int i = 0; i < 3; ++i) ASSERT_EQ(s.contact_normal[3 * c + i], v.contactNormal()[3 * c + i]);
      for (int i = 0; i < 6; ++i) {
        ASSERT_EQ(s.contact_tangent[6 * c + i], v.contactTangent()[6 * c + i]);
      }
    }
    // and back into a slot of another capacity: the same problem
    SlotBuffer back(15, 5);
    ASSERT_TRUE(s.writeTo(back.writer(), 9, 123));
    const shared::SnapshotView b = back.writer().view();
    EXPECT_EQ(b.header().seq, 9u);
    EXPECT_EQ(b.header().t_ns, 123);
    EXPECT_EQ(b.rows(), m);
    for (int r = 0; r < m; ++r) {
      for (int c = 0; c < m; ++c) ASSERT_EQ(b.W()[r * b.ld() + c], v.W()[r * v.ld() + c]);
    }
    SlotBuffer small(3, 1);
    EXPECT_EQ(s.writeTo(small.writer(), 1, 1), nc <= 1);
  }
}

TEST(SnapshotFile, ExistingFileIsNotReplaced) {
  TempDir dir;
  const fs::path file = dir.path() / "run.snap";
  writeAll(file, "keep me");
  EXPECT_THROW(shared::SnapshotFileWriter{file}, FileError);
  EXPECT_EQ(readAll(file), "keep me");
  shared::OutputOptions o;
  o.overwrite = true;
  {
    shared::SnapshotFileWriter w(file, o);
    w.commit();
  }
  EXPECT_TRUE(shared::readSnapshotFile(file).empty());
}

// The writer never grows a file past its cap (what the reader accepts at most): the snapshot
// that would pass it is refused, and the file written so far is whole and readable.
TEST(SnapshotFile, TheWriterStopsBeforeItsCapAndTheFileStaysReadable) {
  TempDir dir;
  const fs::path file = dir.path() / "run.snap";
  SlotBuffer slot(12, 4);
  shared::SnapshotFileWriter w(file, {}, 20'000);
  int written = 0;
  std::uint64_t before = 0;
  for (int i = 0; i < 1000; ++i) {
    fill(slot.writer(), 4, i);
    before = w.bytes();
    if (!w.append(slot.writer().view(), 10'000'000LL * i)) break;
    ++written;
  }
  EXPECT_GT(written, 5);
  EXPECT_LT(written, 1000);
  EXPECT_LE(w.bytes(), 20'000u);
  EXPECT_EQ(w.bytes(), before) << "the refused snapshot wrote nothing";
  const std::uint64_t count = w.count();
  const std::uint64_t bytes = w.bytes();
  w.commit();
  EXPECT_EQ(fs::file_size(file), bytes);
  EXPECT_EQ(shared::readSnapshotFile(file).size(), count);
}

TEST(SnapshotFile, UncommittedWriterLeavesNoFile) {
  TempDir dir;
  const fs::path file = dir.path() / "run.snap";
  {
    SlotBuffer slot(12, 4);
    fill(slot.writer(), 2, 0);
    shared::SnapshotFileWriter w(file);
    ASSERT_TRUE(w.append(slot.writer().view(), 0));
  }
  EXPECT_FALSE(fs::exists(file));
}

TEST(SnapshotFile, EveryTruncationIsRejected) {
  TempDir dir;
  const fs::path file = dir.path() / "run.snap";
  writeFile(file, 3);
  const std::string bytes = readAll(file);
  const fs::path cut = dir.path() / "cut.snap";
  // every length that is not a whole number of records: a clear error, never a crash (each
  // length in the header and the records' fixed parts, every 16th byte in the arrays)
  const std::size_t fixed = 8 + sizeof(shared::ContactSnapshotHeader);
  const std::size_t end0 = 24 + fixed + 4;                                  // no contact
  // (version 2: + int32 contact_instrument per contact)
  const std::size_t end1 = end0 + fixed + 2 * 4 + 8 + 8 * (1 + 9 + 3 + 3 + 18 + 3 + 3 + 6) + 4;
  std::size_t tested = 0;
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    const bool boundary = n == 24 || n == end0 || n == end1;
    if (!boundary && n > end0 + fixed && n % 16 != 0) continue;
    writeAll(cut, bytes.substr(0, n));
    const std::string err = readError(cut);
    ++tested;
    if (boundary) {
      EXPECT_TRUE(err.empty()) << n << ": " << err;
    } else {
      EXPECT_NE(err.find("cut.snap"), std::string::npos) << n << ": " << err;
    }
  }
  EXPECT_GT(tested, 200u);
  writeAll(cut, bytes.substr(0, bytes.size() - 1));
  EXPECT_NE(readError(cut).find("bytes of arrays needed"), std::string::npos) << readError(cut);
}

TEST(SnapshotFile, CorruptFilesAreRejectedWithClearMessages) {
  TempDir dir;
  const fs::path file = dir.path() / "run.snap";
  writeFile(file, 2);  // snapshot 0: no contact; snapshot 1: one contact (3 rows)
  const std::string good = readAll(file);
  ASSERT_TRUE(readError(file).empty());
  const fs::path bad = dir.path() / "bad.snap";
  const std::size_t rec0 = 24;                                       // first record
  const std::size_t rec1 = rec0 + 8 + sizeof(shared::ContactSnapshotHeader) + 4;  // no arrays
  const std::size_t rows_at = rec1 + 8 + offsetof(shared::ContactSnapshotHeader, rows);
  const std::size_t contacts_at = rec1 + 8 + offsetof(shared::ContactSnapshotHeader, contacts);
  auto patched = [&](std::size_t at, const void* v, std::size_t n) {
    std::string b = good;
    b.replace(at, n, static_cast<const char*>(v), n);
    writeAll(bad, b);
    return readError(bad);
  };
  {
    const char m[8] = {'N', 'O', 'T', 'S', 'N', 'A', 'P', '!'};
    EXPECT_NE(patched(0, m, 8).find("wrong magic"), std::string::npos);
  }
  {
    const std::uint32_t v = 99;
    EXPECT_NE(patched(8, &v, 4).find("version 99"), std::string::npos);
  }
  {
    // a huge count is refused against the bytes left, before anything is allocated
    const std::int32_t rows = 6000;
    const std::int32_t contacts = 2000;
    std::string b = good;
    b.replace(rows_at, 4, reinterpret_cast<const char*>(&rows), 4);
    b.replace(contacts_at, 4, reinterpret_cast<const char*>(&contacts), 4);
    writeAll(bad, b);
    EXPECT_NE(readError(bad).find("bytes of arrays needed"), std::string::npos) << readError(bad);
    const std::int32_t too_many = 1 << 30;
    EXPECT_NE(patched(rows_at, &too_many, 4).find("out of range"), std::string::npos);
    const std::int32_t negative = -3;
    EXPECT_NE(patched(contacts_at, &negative, 4).find("out of range"), std::string::npos);
    const std::int32_t seven = 7;  // 7 rows for 1 contact
    EXPECT_NE(patched(rows_at, &seven, 4).find("do not fit"), std::string::npos);
  }
  const std::size_t arrays1 = rec1 + 8 + sizeof(shared::ContactSnapshotHeader);
  {
    const std::int32_t off = 2;  // row_offset[1] = 2 instead of 3
    EXPECT_NE(patched(arrays1 + 4, &off, 4).find("row offsets"), std::string::npos);
  }
  {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    const std::size_t mu_at = arrays1 + 2 * 4 + 8;  // after row_offset[2] and contact_id[1]
    EXPECT_NE(patched(mu_at + 8, &nan, 8).find("non-finite"), std::string::npos);  // W[0]
    const double negative_mu = -0.5;
    EXPECT_NE(patched(mu_at, &negative_mu, 8).find("friction"), std::string::npos);
  }
  {
    const std::int64_t earlier = -1;  // snapshot 1 before snapshot 0 (t = 0)
    EXPECT_NE(patched(rec1, &earlier, 8).find("backwards"), std::string::npos);
  }
  // a directory and a missing file
  EXPECT_FALSE(readError(dir.path()).empty());
  EXPECT_FALSE(readError(dir.path() / "missing.snap").empty());
}

// Runs `cmd` through the shell with a bounded time (coreutils timeout); returns its exit code.
int runBounded(const std::string& cmd, int timeout_s) {
  const std::string full =
      "timeout -k 5 " + std::to_string(timeout_s) + " " + cmd;
  const int rc = std::system(full.c_str());
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

// A 1 s run of the cube pressed by the probe (tests/data/scenes/press_cube.yaml with a scripted
// press), recorded by sim_server --steps. writePressScene() writes the scene.
fs::path writePressScene(const TempDir& dir) {
  const std::string scene_text = readAll(fs::path(TACTUS_TEST_DATA_DIR) / "scenes/press_cube.yaml");
  std::string scene = scene_text;
  const std::string mesh_rel = "../meshes/cube_low_res.msh";
  const auto at = scene.find(mesh_rel);
  EXPECT_NE(at, std::string::npos);
  scene.replace(at, mesh_rel.size(),
                (fs::path(TACTUS_TEST_DATA_DIR) / "meshes/cube_low_res.msh").string());
  scene += "duration: 1.0\n";
  // the probe (tip radius 6 mm, above the 3.5 cm top) presses 6 mm into the cube in 0.5 s
  const auto inst = scene.find("  initial_pose:");
  EXPECT_NE(inst, std::string::npos);
  scene.insert(inst,
               "  trajectory:\n"
               "    - {t: 0.0, position: [0.004, 0.003, 0.045], quaternion: [1, 0, 0, 0]}\n"
               "    - {t: 0.5, position: [0.004, 0.003, 0.035], quaternion: [1, 0, 0, 0]}\n");
  const fs::path scene_file = dir.path() / "press.yaml";
  writeAll(scene_file, scene);
  return scene_file;
}

fs::path recordPressCube(const TempDir& dir) {
  const fs::path scene_file = writePressScene(dir);
  const fs::path snap = dir.path() / "press.snap";
  const std::string cmd = std::string(TACTUS_BINARY_DIR) + "/sim_server/sim_server '" +
                          scene_file.string() + "' --steps 100 --record-snapshots '" +
                          snap.string() + "' > '" + (dir.path() / "sim.log").string() + "' 2>&1";
  EXPECT_EQ(runBounded(cmd, 120), 0) << readAll(dir.path() / "sim.log");
  return snap;
}

// tactus-bench's segment and sim_server's recording are sized as sim_server's segment (the
// obstacles' and tissue pairs' contacts too): with room for 5 instrument contacts, three boxes
// pressing the cube's sides give more obstacle contacts than that, and every step's problem is
// published (the bench stops with an error on one that does not fit) and recorded whole (a
// segment sized for the instrument alone dropped them: empty snapshots).
TEST(JitterReplay, TheBenchPublishesObstacleContactsBeyondTheInstrumentsCapacity) {
  TempDir dir;
  const fs::path base_scene = writePressScene(dir);
  std::string scene = readAll(base_scene);
  const auto solver = scene.find("solver: {max_contacts: 50}");
  ASSERT_NE(solver, std::string::npos);
  scene.replace(solver, std::string("solver: {max_contacts: 50}").size(),
                "solver: {max_contacts: 5}\n"
                "obstacles:\n"
                "  - name: right\n"
                "    box: {min: [0.034, -0.1, -0.03], max: [0.2, 0.1, 0.03]}\n"
                "  - name: left\n"
                "    box: {min: [-0.2, -0.1, -0.03], max: [-0.034, 0.1, 0.03]}\n"
                "  - name: back\n"
                "    box: {min: [-0.2, 0.034, -0.03], max: [0.2, 0.2, 0.03]}\n"
                "obstacle_contact: {alarm_distance: 0.002, max_contacts: 60}");
  const fs::path scene_file = dir.path() / "press_side.yaml";
  writeAll(scene_file, scene);
  const fs::path snap = dir.path() / "side.snap";
  const fs::path log = dir.path() / "bench.log";
  const fs::path json = dir.path() / "bench.json";
  const std::string bench = std::string(TACTUS_BINARY_DIR) + "/tools/bench/tactus-bench '" +
                            scene_file.string() + "' --steps 20 --json '" + json.string() +
                            "' > '" + log.string() + "' 2>&1";
  ASSERT_EQ(runBounded(bench, 120), 0) << readAll(log);
  const std::string js = readAll(json);
  const std::string key = "\"contacts\": {\"median\": ";
  const std::size_t at = js.find(key);
  ASSERT_NE(at, std::string::npos) << js;
  const std::size_t max_at = js.find("\"max\": ", at);
  ASSERT_NE(max_at, std::string::npos) << js;
  EXPECT_GT(std::stod(js.substr(max_at + 7)), 5.0) << js;
  const std::string record = std::string(TACTUS_BINARY_DIR) + "/sim_server/sim_server '" +
                             scene_file.string() + "' --steps 20 --record-snapshots '" +
                             snap.string() + "' > '" + log.string() + "' 2>&1";
  ASSERT_EQ(runBounded(record, 120), 0) << readAll(log);
  // the bench records nothing itself: asked to, it names sim_server's option and fails
  EXPECT_NE(runBounded(std::string(TACTUS_BINARY_DIR) + "/tools/bench/tactus-bench '" +
                           scene_file.string() + "' --record-snapshots '" +
                           (dir.path() / "b.snap").string() + "' > '" + log.string() + "' 2>&1",
                       120),
            0);
  EXPECT_NE(readAll(log).find("sim_server"), std::string::npos) << readAll(log);
  EXPECT_FALSE(fs::exists(dir.path() / "b.snap"));
  const auto snaps = shared::readSnapshotFile(snap);
  ASSERT_EQ(snaps.size(), 20u);
  int most = 0, obstacle_contacts = 0;
  for (const auto& s : snaps) {
    most = std::max(most, s.contacts());
    for (const std::int32_t i : s.contact_instrument) obstacle_contacts += i < 0 ? 1 : 0;
  }
  EXPECT_GT(most, 5) << readAll(log);
  EXPECT_GT(obstacle_contacts, 0);
}

TEST(JitterReplay, SimServerRecordsEveryStepAndKeepsAnExistingFile) {
  TempDir dir;
  const fs::path scene = writePressScene(dir);
  const fs::path snap = dir.path() / "sim.snap";
  const fs::path log = dir.path() / "sim.log";
  const std::string base = std::string(TACTUS_BINARY_DIR) + "/sim_server/sim_server --steps 60 "
                           "--record-snapshots '" + snap.string() + "' '" + scene.string() + "'";
  ASSERT_EQ(runBounded(base + " > '" + log.string() + "' 2>&1", 120), 0) << readAll(log);
  const auto snaps = shared::readSnapshotFile(snap);
  ASSERT_EQ(snaps.size(), 60u);
  EXPECT_EQ(snaps.back().t_ns, 600'000'000);
  std::size_t in_contact = 0;
  for (const auto& s : snaps) in_contact += s.contacts() > 0 ? 1 : 0;
  EXPECT_GT(in_contact, 0u);
  // a second run refuses to replace the recording; --overwrite replaces it
  const std::string before = readAll(snap);
  EXPECT_NE(runBounded(base + " > '" + log.string() + "' 2>&1", 120), 0);
  EXPECT_NE(readAll(log).find("--overwrite"), std::string::npos) << readAll(log);
  EXPECT_EQ(readAll(snap), before);
  EXPECT_EQ(runBounded(base + " --overwrite > '" + log.string() + "' 2>&1", 120), 0)
      << readAll(log);
  EXPECT_EQ(shared::readSnapshotFile(snap).size(), 60u);
  // a part of the run: steps 41-60, on the same timeline as the whole recording
  const fs::path part = dir.path() / "part.snap";
  const std::string part_cmd =
      std::string(TACTUS_BINARY_DIR) + "/sim_server/sim_server --steps 60 --record-snapshots '" +
      part.string() + "' --record-snapshots-from-step 41 '" + scene.string() + "'";
  ASSERT_EQ(runBounded(part_cmd + " > '" + log.string() + "' 2>&1", 120), 0) << readAll(log);
  const auto part_snaps = shared::readSnapshotFile(part);
  ASSERT_EQ(part_snaps.size(), 20u);
  EXPECT_EQ(part_snaps.front().t_ns, 410'000'000);
  EXPECT_EQ(part_snaps.back().t_ns, snaps.back().t_ns);
  EXPECT_EQ(part_snaps.back().contacts(), snaps.back().contacts());
  // a first step below 1 is refused before anything runs
  const fs::path none = dir.path() / "none.snap";
  EXPECT_NE(runBounded(std::string(TACTUS_BINARY_DIR) + "/sim_server/sim_server --steps 5 "
                       "--record-snapshots '" + none.string() +
                       "' --record-snapshots-from-step 0 '" + scene.string() + "' > '" +
                       log.string() + "' 2>&1", 120),
            0);
  EXPECT_NE(readAll(log).find("--record-snapshots-from-step"), std::string::npos) << readAll(log);
  EXPECT_FALSE(fs::exists(none));
}

TEST(JitterReplay, RecordedPressReplaysThroughTheHapticLoop) {
  TempDir dir;
  const fs::path snap = recordPressCube(dir);
  std::vector<shared::RecordedSnapshot> snaps = shared::readSnapshotFile(snap);
  ASSERT_EQ(snaps.size(), 100u);  // 1 s of 10 ms steps
  std::size_t in_contact = 0;
  for (const auto& s : snaps) in_contact += s.contacts() > 0 ? 1 : 0;
  ASSERT_GT(in_contact, 10u) << "the scripted press never touched the cube";
  EXPECT_EQ(snaps[1].t_ns - snaps[0].t_ns, 10'000'000);

  // in-process: one second of the recording (looped) through the real haptic loop
  haptic::jitter::ReplayOptions ro;
  ro.loop = true;
  haptic::jitter::ReplayRig rig(std::move(snaps), ro);
  haptic::jitter::RingFollower follower(rig.segment(), shared::StatsRingReader::Start::kOldest);
  haptic::jitter::JitterCollector c;
  rig.start();
  for (int i = 0; i < 10; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    follower.drain({&c});
  }
  rig.stop();
  follower.drain({&c});
  const haptic::jitter::JitterReport r = c.report();
  EXPECT_GT(r.records, 100u);
  EXPECT_EQ(r.records, rig.loop().counters().ticks.load());
  EXPECT_GT(rig.published(), 1u);
  EXPECT_GT(r.solved, 0u);  // ticks on the replayed contacts
  EXPECT_LT(r.not_converged, r.solved);
  EXPECT_EQ(r.non_finite_residuals, 0u);

  // bouncing: past the end the recording plays backwards, so the device follows neighbouring
  // snapshots only (looping jumps from the last one's pose back to the first's)
  {
    std::vector<shared::RecordedSnapshot> again = shared::readSnapshotFile(snap);
    const std::size_t n = again.size();
    haptic::jitter::ReplayOptions bo;
    bo.loop = true;
    bo.bounce = true;
    haptic::jitter::ReplayRig bouncing(std::move(again), bo);
    bouncing.start();
    std::size_t last = bouncing.device(0).following(), largest_step = 0, turns = 0;
    bool backwards = false;
    const auto until = std::chrono::steady_clock::now() + std::chrono::milliseconds(1500);
    while (std::chrono::steady_clock::now() < until) {
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
      const std::size_t now = bouncing.device(0).following();
      if (now == last) continue;
      largest_step = std::max(largest_step, now > last ? now - last : last - now);
      if ((now < last) != backwards) {
        backwards = now < last;
        ++turns;
      }
      last = now;
    }
    bouncing.stop();
    EXPECT_GE(bouncing.passes(), 1u);
    EXPECT_GE(turns, 1u) << "the replay never turned round";
    EXPECT_LT(largest_step, n / 4) << "the device jumped across the recording";
  }

  // the tactus-jitter binary: --replay for a second, exit 0, the replay table printed
  const fs::path log = dir.path() / "jitter.log";
  const std::string cmd = std::string(TACTUS_BINARY_DIR) + "/tools/jitter/tactus-jitter --replay '" +
                          snap.string() + "' --loop --duration 1 --quiet --priority 0 > '" +
                          log.string() + "' 2>&1";
  EXPECT_EQ(runBounded(cmd, 60), 0) << readAll(log);
  const std::string out = readAll(log);
  EXPECT_NE(out.find("replay: 100 snapshots"), std::string::npos) << out;
  EXPECT_NE(out.find("replay of"), std::string::npos) << out;
}

}  // namespace
}  // namespace tactus
