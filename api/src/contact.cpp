// The contact solver and the problem files on ContactProblem (contact.h).
#include "tactus/contact.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <sstream>

#include "tactus/shared/error.h"
#include "tactus/shared/fclib.h"
#include "tactus/shared/file_io.h"
#include "tactus/shared/snapshot_file.h"

namespace tactus {

namespace {

template <class V>
void requireFinite(const V& values, const char* name) {
  for (const double x : values) {
    if (!std::isfinite(x)) throw Error(fmt::format("contact problem: {} holds {}", name, x));
  }
}

void requireSize(std::size_t size, std::size_t expected, const char* name, bool may_be_empty) {
  if (size == expected || (may_be_empty && size == 0)) return;
  throw Error(fmt::format("contact problem: {} has {} entries, expected {}{}", name, size,
                          expected, may_be_empty ? " (or none)" : ""));
}

shared::PoseSample poseSample(const Pose& pose, double gripper_rad) {
  shared::PoseSample out;
  for (int i = 0; i < 3; ++i) out.pos_m[static_cast<std::size_t>(i)] = pose.pos_m[i];
  out.quat_wxyz = {pose.rot.w(), pose.rot.x(), pose.rot.y(), pose.rot.z()};
  out.gripper_rad = gripper_rad;
  return out;
}

Pose pose(const shared::PoseSample& s) {
  Pose out;
  out.pos_m = Eigen::Vector3d(s.pos_m[0], s.pos_m[1], s.pos_m[2]);
  out.rot = Eigen::Quaterniond(s.quat_wxyz[0], s.quat_wxyz[1], s.quat_wxyz[2], s.quat_wxyz[3]);
  return out;
}

}  // namespace

void checkContactProblem(const ContactProblem& p) {
  if (p.contacts < 0 || p.rows < 0) throw Error("contact problem: negative contacts or rows");
  const auto nc = static_cast<std::size_t>(p.contacts);
  const auto m = static_cast<std::size_t>(p.rows);
  requireSize(p.row_offset.size(), nc + 1, "row_offset", false);
  if (p.row_offset[0] != 0) throw Error("contact problem: row_offset[0] must be 0");
  for (std::size_t c = 0; c < nc; ++c) {
    const int step = p.row_offset[c + 1] - p.row_offset[c];
    if (step != 1 && step != 3) {
      throw Error(fmt::format("contact problem: contact {} has {} rows (1 or 3)", c, step));
    }
  }
  if (p.row_offset[nc] != p.rows) {
    throw Error(fmt::format("contact problem: row_offset ends at {}, rows is {}",
                            p.row_offset[nc], p.rows));
  }
  requireSize(p.mu.size(), nc, "mu", false);
  for (std::size_t c = 0; c < nc; ++c) {
    if (!(p.mu[c] >= 0.0) || !std::isfinite(p.mu[c])) {
      throw Error(fmt::format("contact problem: mu[{}] = {} (must be finite and >= 0)", c,
                              p.mu[c]));
    }
  }
  if (static_cast<std::size_t>(p.W.rows()) != m || static_cast<std::size_t>(p.W.cols()) != m) {
    throw Error(fmt::format("contact problem: W is {} x {}, expected {} x {}", p.W.rows(),
                            p.W.cols(), m, m));
  }
  requireSize(static_cast<std::size_t>(p.delta_free.size()), m, "delta_free", false);
  requireSize(static_cast<std::size_t>(p.f.size()), m, "f", true);
  requireSize(static_cast<std::size_t>(p.J.rows()), m, "J", true);
  requireSize(p.contact_id.size(), nc, "contact_id", true);
  requireSize(p.point_m.size(), nc, "point_m", true);
  requireSize(p.normal.size(), nc, "normal", true);
  requireSize(p.tangent1.size(), nc, "tangent1", true);
  requireSize(p.tangent2.size(), nc, "tangent2", true);
  requireSize(p.contact_instrument.size(), nc, "contact_instrument", true);
  requireFinite(p.W.reshaped(), "W");
  requireFinite(p.delta_free, "delta_free");
  requireFinite(p.f, "f");
  requireFinite(p.J.reshaped(), "J");
}

NsgsResult solveContactProblem(ContactProblem& problem, const NsgsSettings& settings) {
  checkContactProblem(problem);
  if (problem.f.size() == 0) problem.f.setZero(problem.rows);
  shared::NsgsWorkspace workspace(problem.rows, problem.contacts);
  problem.solve = shared::solveNsgs(problem.view(), settings, workspace, problem.f.data());
  return problem.solve;
}

ContactProblem readFclib(const std::filesystem::path& path) {
  const shared::FclibProblem in = shared::readFclibText(path);
  ContactProblem p;
  p.contacts = in.contacts;
  p.rows = in.rows();
  p.row_offset = in.row_offset;
  p.mu = in.mu;
  p.W = Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(
      in.W.data(), p.rows, p.rows);
  p.delta_free = Eigen::Map<const Eigen::VectorXd>(in.q.data(), p.rows);
  p.f.setZero(p.rows);
  return p;
}

void writeFclib(const std::filesystem::path& path, const ContactProblem& p, bool overwrite) {
  checkContactProblem(p);
  if (p.rows != 3 * p.contacts) {
    throw Error(path.string() + ": FCLIB's local 3D problems have three rows per contact; this "
                "problem has one-row contacts");
  }
  std::ostringstream out;
  out << std::setprecision(17);
  out << "# FCLIB local 3D frictional contact problem (fc3d), written by Tactus\n";
  out << "# nc, mu[nc], q[3 nc], nnz, then nnz triplets 'row col value' of W (0-based)\n";
  out << p.contacts << "\n";
  for (const double mu : p.mu) out << mu << "\n";
  for (int r = 0; r < p.rows; ++r) out << p.delta_free[r] << "\n";
  long nnz = 0;
  for (int i = 0; i < p.rows; ++i) {
    for (int j = 0; j < p.rows; ++j) nnz += p.W(i, j) != 0.0 ? 1 : 0;
  }
  out << nnz << "\n";
  for (int i = 0; i < p.rows; ++i) {
    for (int j = 0; j < p.rows; ++j) {
      if (p.W(i, j) != 0.0) out << i << " " << j << " " << p.W(i, j) << "\n";
    }
  }
  shared::OutputOptions options;
  options.overwrite = overwrite;
  options.overwrite_hint = "pass overwrite=true";
  shared::writeFileChecked(path, out.str(), "FCLIB problem", options);
}

bool writeSnapshotSlot(const ContactProblem& p, std::uint64_t seq, std::int64_t t_ns,
                       std::uint64_t device_seq, shared::SnapshotWriter& slot,
                       std::span<const double> max_opening_rad) {
  const auto full_rad = [&](std::size_t i) {
    if (i < max_opening_rad.size()) return max_opening_rad[i];
    return i < p.instruments.size() ? p.instruments[i].max_opening_rad : 1.0;
  };
  auto& hdr = slot.header();
  int contacts = p.contacts;
  int rows = p.rows;
  const bool fits = slot.setSize(rows, contacts);
  if (!fits) {
    // an empty problem rather than a wrong one
    contacts = 0;
    rows = 0;
    slot.setSize(0, 0);
  }
  hdr.seq = seq;
  hdr.t_ns = t_ns;
  hdr.step = static_cast<std::uint64_t>(p.step);
  hdr.h_s = p.h_s;
  hdr.device_seq = device_seq;
  const bool solved = fits && rows > 0 && p.solve.status != shared::NsgsStatus::kEmpty;
  hdr.solver_sweeps = solved ? p.solve.sweeps : 0;
  hdr.solver_error = solved ? p.solve.error : 0.0;
  const bool jacobian = p.J.rows() == p.rows;
  // a problem that did not fit is not this step's problem: published empty and not valid, so
  // the haptic side treats it as stale (fades out) instead of rendering no contact
  hdr.flags = (fits ? shared::kSnapshotValid | (jacobian ? shared::kSnapshotHasJacobian : 0u)
                    : 0u) |
              (solved && p.solve.status == shared::NsgsStatus::kConverged
                   ? shared::kSnapshotConverged
                   : 0u);
  const double full0 = full_rad(0);
  hdr.device_pose = poseSample(p.device_pose, p.device_gripper * full0);
  hdr.tool_pose = poseSample(p.tool_pose, p.device_gripper * full0);
  // the per-instrument blocks (block 0 repeats the fields above)
  const int tools = std::min<int>(static_cast<int>(p.instruments.size()), shared::kMaxInstruments);
  hdr.instruments = tools;
  for (int i = 0; i < tools; ++i) {
    const InstrumentProblemData& in = p.instruments[static_cast<std::size_t>(i)];
    shared::SnapshotInstrument& block = hdr.instrument[static_cast<std::size_t>(i)];
    block.device_seq = i == 0 ? device_seq : 0;
    const double full = full_rad(static_cast<std::size_t>(i));
    block.device_pose = poseSample(in.device_pose, in.device_gripper * full);
    block.tool_pose = poseSample(in.tool_pose, in.device_gripper * full);
  }
  const int ld = slot.ld();
  slot.rowOffset()[0] = 0;
  for (int c = 0; c <= contacts; ++c) slot.rowOffset()[c] = p.row_offset[static_cast<std::size_t>(c)];
  const auto has = [&](std::size_t size) { return size == static_cast<std::size_t>(p.contacts); };
  for (int c = 0; c < contacts; ++c) {
    const auto k = static_cast<std::size_t>(c);
    slot.contactId()[c] = has(p.contact_id.size()) ? p.contact_id[k] : k;
    slot.mu()[c] = p.mu[k];
    slot.contactInstrument()[c] = has(p.contact_instrument.size()) ? p.contact_instrument[k] : 0;
    if (has(p.unreachable.size()) && p.unreachable[k] != 0) {
      slot.contactInstrument()[c] = shared::kContactUnreachable;
    }
    for (int j = 0; j < 3; ++j) {
      slot.contactPoint()[3 * c + j] = has(p.point_m.size()) ? p.point_m[k][j] : 0.0;
      slot.contactNormal()[3 * c + j] = has(p.normal.size()) ? p.normal[k][j] : 0.0;
      slot.contactTangent()[6 * c + j] = has(p.tangent1.size()) ? p.tangent1[k][j] : 0.0;
      slot.contactTangent()[6 * c + 3 + j] = has(p.tangent2.size()) ? p.tangent2[k][j] : 0.0;
    }
  }
  double* W = slot.W();
  const bool has_f = p.f.size() == p.rows;
  for (int i = 0; i < rows; ++i) {
    std::copy_n(p.W.data() + static_cast<std::ptrdiff_t>(i) * rows, rows,
                W + static_cast<std::ptrdiff_t>(i) * ld);
    slot.deltaFree()[i] = p.delta_free[i];
    slot.f()[i] = has_f ? p.f[i] : 0.0;
    for (int k = 0; k < 6; ++k) slot.J()[6 * i + k] = jacobian ? p.J(i, k) : 0.0;
  }
  // the haptic side's symmetric sweep needs W == W^T exactly: say so only when it holds.
  // Compared in 32 x 32 tiles, each tile of the upper triangle against its mirror in the lower,
  // both in cache (row by row against column by column took about 1 ms for 900 rows)
  constexpr int kTile = 32;
  bool symmetric = true;
  for (int i0 = 0; i0 < rows && symmetric; i0 += kTile) {
    const int i1 = std::min(rows, i0 + kTile);
    for (int j0 = i0; j0 < rows && symmetric; j0 += kTile) {
      const int j1 = std::min(rows, j0 + kTile);
      for (int i = i0; i < i1 && symmetric; ++i) {
        for (int j = std::max(j0, i + 1); j < j1; ++j) {
          if (!(W[static_cast<std::ptrdiff_t>(i) * ld + j] ==
                W[static_cast<std::ptrdiff_t>(j) * ld + i])) {
            symmetric = false;
            break;
          }
        }
      }
    }
  }
  if (symmetric) hdr.flags |= shared::kSnapshotSymmetricW;
  return fits;
}

ContactProblem problemFromSnapshot(const shared::SnapshotView& s) {
  const shared::ContactSnapshotHeader& h = s.header();
  ContactProblem p;
  p.contacts = std::max(0, s.contacts());
  p.rows = std::max(0, s.rows());
  p.step = static_cast<std::int64_t>(h.step);
  p.h_s = h.h_s;
  const auto nc = static_cast<std::size_t>(p.contacts);
  const int m = p.rows;
  p.row_offset.assign(s.rowOffset(), s.rowOffset() + nc + 1);
  p.contact_id.assign(s.contactId(), s.contactId() + nc);
  p.mu.assign(s.mu(), s.mu() + nc);
  p.W.resize(m, m);
  for (int i = 0; i < m; ++i) {
    std::copy_n(s.W() + static_cast<std::ptrdiff_t>(i) * s.ld(), m,
                p.W.data() + static_cast<std::ptrdiff_t>(i) * m);
  }
  p.delta_free = Eigen::Map<const Eigen::VectorXd>(s.deltaFree(), m);
  p.f = Eigen::Map<const Eigen::VectorXd>(s.f(), m);
  p.J = Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, 6, Eigen::RowMajor>>(s.J(), m, 6);
  p.grip.setZero(m);
  p.point_m.resize(nc);
  p.normal.resize(nc);
  p.tangent1.resize(nc);
  p.tangent2.resize(nc);
  p.contact_instrument.resize(nc);
  p.unreachable.assign(nc, 0);
  for (std::size_t c = 0; c < nc; ++c) {
    p.point_m[c] = Eigen::Map<const Eigen::Vector3d>(s.contactPoint() + 3 * c);
    p.normal[c] = Eigen::Map<const Eigen::Vector3d>(s.contactNormal() + 3 * c);
    p.tangent1[c] = Eigen::Map<const Eigen::Vector3d>(s.contactTangent() + 6 * c);
    p.tangent2[c] = Eigen::Map<const Eigen::Vector3d>(s.contactTangent() + 6 * c + 3);
    const std::int32_t who = s.contactInstrument()[c];
    p.contact_instrument[c] = who == shared::kContactUnreachable ? -1 : who;
    p.unreachable[c] = who == shared::kContactUnreachable ? 1 : 0;
  }
  const int tools = std::clamp(h.instruments, 0, shared::kMaxInstruments);
  for (int i = 0; i < tools; ++i) {
    const shared::SnapshotInstrument& b = h.instrument[static_cast<std::size_t>(i)];
    InstrumentProblemData in;
    in.device_pose = pose(b.device_pose);
    in.tool_pose = pose(b.tool_pose);
    in.device_gripper = b.device_pose.gripper_rad;
    in.max_opening_rad = 1.0;
    p.instruments.push_back(in);
  }
  p.device_pose = pose(h.device_pose);
  p.tool_pose = pose(h.tool_pose);
  p.device_gripper = h.device_pose.gripper_rad;
  if (m > 0 && h.solver_sweeps > 0) {
    p.solve.status = (h.flags & shared::kSnapshotConverged) != 0 ? shared::NsgsStatus::kConverged
                                                                  : shared::NsgsStatus::kMaxSweeps;
    p.solve.sweeps = h.solver_sweeps;
    p.solve.error = h.solver_error;
  }
  return p;
}

SnapshotBuffer::SnapshotBuffer(int max_rows, int max_contacts)
    : layout_(shared::SnapshotLayout::forCapacity(std::max(0, max_rows), std::max(0, max_contacts))),
      storage_(layout_.total_bytes + shared::kCacheLineBytes, 0) {}

unsigned char* SnapshotBuffer::bytes() const {
  auto at = reinterpret_cast<std::uintptr_t>(storage_.data());
  at = (at + shared::kCacheLineBytes - 1) / shared::kCacheLineBytes * shared::kCacheLineBytes;
  return reinterpret_cast<unsigned char*>(at);
}

std::vector<ContactProblem> readSnapshots(const std::filesystem::path& path) {
  std::vector<ContactProblem> out;
  for (const shared::RecordedSnapshot& r : shared::readSnapshotFile(path)) {
    SnapshotBuffer slot(r.rows(), r.contacts());
    r.writeTo(slot.writer(), r.header.seq, r.t_ns);
    out.push_back(problemFromSnapshot(slot.view()));
  }
  return out;
}

void writeSnapshots(const std::filesystem::path& path, std::span<const ContactProblem> problems,
                    bool overwrite) {
  shared::OutputOptions options;
  options.overwrite = overwrite;
  options.overwrite_hint = "pass overwrite=true";
  shared::SnapshotFileWriter file(path, options);
  std::uint64_t seq = 0;
  for (const ContactProblem& p : problems) {
    checkContactProblem(p);
    SnapshotBuffer slot(p.rows, p.contacts);
    shared::SnapshotWriter w = slot.writer();
    if (!writeSnapshotSlot(p, seq + 1, 0, 0, w)) {
      throw Error(fmt::format("{}: problem {} does not fit a snapshot slot", path.string(), seq));
    }
    if (!file.append(slot.view(), static_cast<std::int64_t>(seq) * 1'000'000)) {
      throw FileError(fmt::format("{}: problem {} would take the file past a snapshot file's "
                                  "maximum size; nothing written", path.string(), seq));
    }
    ++seq;
  }
  file.commit();
}

}  // namespace tactus
