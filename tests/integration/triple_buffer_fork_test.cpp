// Two real processes on a real segment: a "sim" process publishes 10^6 checksummed contact
// snapshots and reads device samples; a "haptic" process reads the snapshots, publishes device
// samples and stats records; the parent follows the stats ring through a read-only mapping.
// Asserts: zero torn or out-of-order reads on every channel, each reader ends on the newest
// value, the stats reader accounts for every record (read or counted lost).

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdint>
#include <cstring>
#include <string>

#include "tactus/shared/clock.h"
#include "tactus/shared/segment.h"

namespace tactus::shared {
namespace {

constexpr std::uint64_t kSnapshots = 1'000'000;
constexpr std::uint64_t kDone = ~std::uint64_t{0};
constexpr std::int64_t kStallNs = 20 * kNsPerS;  // a stuck peer fails the test instead of hanging

std::uint64_t mix(std::uint64_t x) {
  x ^= x >> 33;
  x *= 0xff51afd7ed558ccdULL;
  x ^= x >> 33;
  return x;
}
double value(std::uint64_t seq, std::uint64_t k) {
  return static_cast<double>(mix(seq * 1315423911ULL + k) >> 11) * 1e-9;
}

// Fills every array of the snapshot from its seq; stores a checksum in solver_error.
void fillSnapshot(SnapshotWriter& s, std::uint64_t seq) {
  const SnapshotLayout& l = s.layout();
  s.setSize(l.max_rows, l.max_contacts);
  ContactSnapshotHeader& h = s.header();
  h.seq = seq;
  h.step = seq * 3;
  h.t_ns = static_cast<std::int64_t>(seq);
  double sum = 0.0;
  std::uint64_t k = 0;
  auto put = [&](double* a, int n) {
    for (int i = 0; i < n; ++i) sum += (a[i] = value(seq, k++));
  };
  put(s.W(), l.max_rows * l.max_rows);
  put(s.deltaFree(), l.max_rows);
  put(s.f(), l.max_rows);
  put(s.J(), l.max_rows * 6);
  put(s.mu(), l.max_contacts);
  for (int c = 0; c <= l.max_contacts; ++c) s.rowOffset()[c] = 3 * c;
  h.device_pose.pos_m = {value(seq, 1000001), 0.0, 0.0};
  h.solver_error = sum + h.device_pose.pos_m[0];
}

bool snapshotIntact(const SnapshotView& v) {
  const ContactSnapshotHeader& h = v.header();
  const SnapshotLayout& l = v.layout();
  if (h.step != h.seq * 3 || h.t_ns != static_cast<std::int64_t>(h.seq)) return false;
  double sum = 0.0;
  std::uint64_t k = 0;
  auto check = [&](const double* a, int n) {
    bool ok = true;
    for (int i = 0; i < n; ++i) {
      ok &= a[i] == value(h.seq, k++);
      sum += a[i];
    }
    return ok;
  };
  bool ok = check(v.W(), l.max_rows * l.max_rows) && check(v.deltaFree(), l.max_rows) &&
            check(v.f(), l.max_rows) && check(v.J(), l.max_rows * 6) &&
            check(v.mu(), l.max_contacts);
  ok &= h.device_pose.pos_m[0] == value(h.seq, 1000001);
  ok &= v.problem().row_offset[l.max_contacts] == 3 * l.max_contacts;
  return ok && h.solver_error == sum + h.device_pose.pos_m[0];
}

void fillSample(DeviceSample* d, std::uint64_t seq) {
  d->seq = seq;
  d->t_ns = static_cast<std::int64_t>(mix(seq));
  d->pos_m = {value(seq, 1), value(seq, 2), value(seq, 3)};
  d->force_n = {value(seq, 4), value(seq, 5), value(seq, 6)};
}
bool sampleIntact(const DeviceSample& d) {
  return d.t_ns == static_cast<std::int64_t>(mix(d.seq)) && d.pos_m[2] == value(d.seq, 3) &&
         d.force_n[0] == value(d.seq, 4) && d.force_n[2] == value(d.seq, 6);
}

struct Report {
  std::uint64_t torn = 0;
  std::uint64_t backwards = 0;
  std::uint64_t fresh = 0;
  std::uint64_t last = 0;
  std::uint64_t stalled = 0;
};

// sim side: publish kSnapshots snapshots, read device samples until the done marker
Report simProcess(const std::string& name) {
  Report r;
  Segment seg = Segment::open(name);
  SnapshotPublisher pub = seg.snapshotPublisher();
  TripleReader<DeviceSample> dev = seg.deviceReader();
  auto readDevice = [&] {
    bool fresh = false;
    const DeviceSample& d = dev.latest(&fresh);
    if (!fresh) return;
    ++r.fresh;
    if (!sampleIntact(d)) ++r.torn;
    if (d.seq <= r.last && r.last != 0) ++r.backwards;
    r.last = d.seq;
  };
  for (std::uint64_t i = 1; i <= kSnapshots; ++i) {
    SnapshotWriter w = pub.slot();
    fillSnapshot(w, i);
    pub.publish();
    if ((i & 63) == 0) {
      readDevice();
      seg.beat(Side::kSim);
    }
  }
  const std::int64_t give_up = monotonicNs() + kStallNs;
  while (r.last != kDone) {
    readDevice();
    if (monotonicNs() > give_up) {
      r.stalled = 1;
      break;
    }
  }
  return r;
}

// haptic side: read snapshots until the newest, publish device samples and stats records
Report hapticProcess(const std::string& name) {
  Report r;
  Segment seg = Segment::open(name);
  SnapshotSubscriber sub = seg.snapshotSubscriber();
  TripleWriter<DeviceSample> dev = seg.deviceWriter();
  StatsRingWriter stats = seg.statsWriter();
  std::uint64_t sample_seq = 0, tick = 0;
  std::int64_t last_progress = monotonicNs();
  while (r.last < kSnapshots) {
    bool fresh = false;
    const SnapshotView v = sub.latest(&fresh);
    if (fresh) {
      ++r.fresh;
      if (!snapshotIntact(v)) ++r.torn;
      if (v.header().seq <= r.last) ++r.backwards;
      r.last = v.header().seq;
      last_progress = monotonicNs();
    } else if (monotonicNs() - last_progress > kStallNs) {
      r.stalled = 1;
      break;
    }
    if ((++tick & 15) == 0) {
      fillSample(&dev.buffer(), ++sample_seq);
      dev.publish();
      StatsRecord rec;
      rec.tick = tick;
      rec.scheduled_ns = static_cast<std::int64_t>(tick * 7);
      rec.snapshot_seq = r.last;
      rec.flags = tick ^ 0x5a5a;
      stats.push(rec);
    }
  }
  fillSample(&dev.buffer(), kDone);
  dev.publish();
  return r;
}

pid_t spawn(Report (*body)(const std::string&), const std::string& name, int fd) {
  const pid_t pid = ::fork();
  if (pid == 0) {
    Report r;
    try {
      r = body(name);
    } catch (...) {
      r.stalled = 2;
    }
    const ssize_t n = ::write(fd, &r, sizeof(r));
    ::_exit(n == static_cast<ssize_t>(sizeof(r)) ? 0 : 4);
  }
  return pid;
}

TEST(TripleBufferFork, MillionPublishesAcrossProcesses) {
  const std::string name = "tactus_fork_" + std::to_string(::getpid());
  Segment::remove(name);
  Segment creator = Segment::create(name, SegmentCapacity::forContacts(4));
  Segment tool = Segment::open(name, Access::kReadOnly);
  StatsRingReader stats = tool.statsReader(StatsRingReader::Start::kOldest);

  int sim_pipe[2], hap_pipe[2];
  ASSERT_EQ(::pipe(sim_pipe), 0);
  ASSERT_EQ(::pipe(hap_pipe), 0);
  pid_t hap = spawn(hapticProcess, name, hap_pipe[1]);
  pid_t sim = spawn(simProcess, name, sim_pipe[1]);
  ASSERT_GT(hap, 0);
  ASSERT_GT(sim, 0);

  // follow the stats ring live while the children run
  std::uint64_t stats_read = 0, stats_torn = 0, stats_disorder = 0, last_tick = 0;
  StatsRecord buf[256];
  int running = 2, sim_status = -1, hap_status = -1;
  while (running > 0) {
    const std::size_t n = stats.poll(buf, 256);
    for (std::size_t i = 0; i < n; ++i) {
      if (buf[i].flags != (buf[i].tick ^ 0x5a5a) ||
          buf[i].scheduled_ns != static_cast<std::int64_t>(buf[i].tick * 7)) {
        ++stats_torn;
      }
      if (buf[i].tick <= last_tick) ++stats_disorder;
      last_tick = buf[i].tick;
    }
    stats_read += n;
    int st = 0;
    for (pid_t* p : {&sim, &hap}) {
      if (*p > 0 && ::waitpid(*p, &st, WNOHANG) == *p) {
        (p == &sim ? sim_status : hap_status) = st;
        *p = -1;
        --running;
      }
    }
    if (n == 0) ::usleep(200);
  }
  stats_read += stats.poll(buf, 256);

  ASSERT_TRUE(WIFEXITED(sim_status) && WEXITSTATUS(sim_status) == 0);
  ASSERT_TRUE(WIFEXITED(hap_status) && WEXITSTATUS(hap_status) == 0);
  Report sr, hr;
  ASSERT_EQ(::read(sim_pipe[0], &sr, sizeof(sr)), static_cast<ssize_t>(sizeof(sr)));
  ASSERT_EQ(::read(hap_pipe[0], &hr, sizeof(hr)), static_cast<ssize_t>(sizeof(hr)));
  for (int fd : {sim_pipe[0], sim_pipe[1], hap_pipe[0], hap_pipe[1]}) ::close(fd);

  // snapshots (sim -> haptic)
  EXPECT_EQ(hr.stalled, 0u);
  EXPECT_EQ(hr.torn, 0u);
  EXPECT_EQ(hr.backwards, 0u);
  EXPECT_EQ(hr.last, kSnapshots);  // the reader ended on the newest snapshot
  EXPECT_GT(hr.fresh, 1u);
  // device samples (haptic -> sim)
  EXPECT_EQ(sr.stalled, 0u);
  EXPECT_EQ(sr.torn, 0u);
  EXPECT_EQ(sr.backwards, 0u);
  EXPECT_EQ(sr.last, kDone);
  // stats (haptic -> read-only tool)
  EXPECT_EQ(stats_torn, 0u);
  EXPECT_EQ(stats_disorder, 0u);
  EXPECT_GT(stats_read, 0u);
  EXPECT_EQ(stats_read + stats.lost(), stats.written());
  EXPECT_GT(creator.heartbeatNs(Side::kSim), 0);
}

}  // namespace
}  // namespace tactus::shared
