// Recorded contact snapshots: checked binary writer and reader.
#include "tactus/shared/snapshot_file.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <sstream>
#include <string>

namespace tactus::shared {
namespace {

// The arguments streamed into one string (messages; this library does not link fmt).
template <class... Args>
std::string cat(const Args&... args) {
  std::ostringstream os;
  (os << ... << args);
  return os.str();
}

constexpr char kMagic[8] = {'T', 'A', 'C', 'T', 'S', 'N', 'A', 'P'};

struct FileHeader {
  char magic[8];
  std::uint32_t version;
  std::uint32_t record_header_bytes;
  std::uint64_t reserved;
};
static_assert(sizeof(FileHeader) == 24);

template <class T>
std::string_view bytesOf(const T* data, std::size_t n) {
  return {reinterpret_cast<const char*>(data), n * sizeof(T)};
}

// Bytes of a record's arrays for m rows and nc contacts (both already bounded).
std::uint64_t arrayBytes(std::uint64_t m, std::uint64_t nc) {
  return (nc + 1) * sizeof(std::int32_t) + nc * sizeof(std::uint64_t) +
         nc * sizeof(std::int32_t) +   // contact_instrument
         (nc + m * m + 2 * m + 6 * m + 3 * nc + 3 * nc + 6 * nc) * sizeof(double);
}

}  // namespace

bool RecordedSnapshot::writeTo(SnapshotWriter slot, std::uint64_t seq,
                               std::int64_t t_ns) const noexcept {
  const int m = rows();
  const int nc = contacts();
  if (m > slot.layout().max_rows || nc > slot.layout().max_contacts) return false;
  ContactSnapshotHeader& h = slot.header();
  h = header;
  h.seq = seq;
  h.t_ns = t_ns;
  const int ld = slot.ld();
  std::copy(row_offset.begin(), row_offset.end(), slot.rowOffset());
  std::copy(contact_id.begin(), contact_id.end(), slot.contactId());
  std::copy(mu.begin(), mu.end(), slot.mu());
  for (int r = 0; r < m; ++r) {
    std::copy_n(W.data() + static_cast<std::ptrdiff_t>(r) * m, m,
                slot.W() + static_cast<std::ptrdiff_t>(r) * ld);
  }
  std::copy(delta_free.begin(), delta_free.end(), slot.deltaFree());
  std::copy(f.begin(), f.end(), slot.f());
  std::copy(J.begin(), J.end(), slot.J());
  std::copy(contact_point_m.begin(), contact_point_m.end(), slot.contactPoint());
  std::copy(contact_normal.begin(), contact_normal.end(), slot.contactNormal());
  std::copy(contact_tangent.begin(), contact_tangent.end(), slot.contactTangent());
  if (contact_instrument.size() == static_cast<std::size_t>(nc)) {
    std::copy(contact_instrument.begin(), contact_instrument.end(), slot.contactInstrument());
  } else {   // a problem made in memory for one instrument
    std::fill_n(slot.contactInstrument(), nc, 0);
  }
  return true;
}

SnapshotFileWriter::SnapshotFileWriter(const std::filesystem::path& path, OutputOptions options,
                                       std::uint64_t max_bytes)
    : out_(path, "snapshot file", options),
      max_bytes_(std::min<std::uint64_t>(max_bytes, kMaxSnapshotFileBytes)) {
  FileHeader fh{};
  std::memcpy(fh.magic, kMagic, sizeof(kMagic));
  fh.version = kSnapshotFileVersion;
  fh.record_header_bytes = sizeof(ContactSnapshotHeader);
  fh.reserved = 0;
  out_.write(bytesOf(&fh, 1));
  bytes_ = sizeof(fh);
}

bool SnapshotFileWriter::append(const SnapshotView& s, std::int64_t t_ns) {
  const int m = std::max(0, s.rows());
  const int nc = std::max(0, s.contacts());
  if (m > kMaxRecordedRows || nc > kMaxRecordedContacts) {
    throw FileError(cat("snapshot file: a snapshot of ", m, " rows / ", nc,
                                " contacts exceeds the recordable ", kMaxRecordedRows, " / ",
                                kMaxRecordedContacts));
  }
  {
    // the record's size (see the header comment): never past max_bytes_
    const auto um = static_cast<std::uint64_t>(m), unc = static_cast<std::uint64_t>(nc);
    const std::uint64_t record = sizeof(std::int64_t) + sizeof(ContactSnapshotHeader) +
                                 4 * (nc == 0 ? 1 : unc + 1) + 8 * unc + 8 * unc +
                                 8 * um * um + 8 * um + 8 * um + 48 * um + 24 * unc + 24 * unc +
                                 48 * unc + 4 * unc;
    if (bytes_ + record > max_bytes_) return false;
    bytes_ += record;
  }
  ContactSnapshotHeader h = s.header();
  h.rows = m;
  h.contacts = nc;
  out_.write(bytesOf(&t_ns, 1));
  out_.write(bytesOf(&h, 1));
  const auto unc = static_cast<std::size_t>(nc);
  const auto um = static_cast<std::size_t>(m);
  if (nc == 0) {
    const std::int32_t zero = 0;
    out_.write(bytesOf(&zero, 1));
  } else {
    out_.write(bytesOf(s.rowOffset(), unc + 1));
  }
  out_.write(bytesOf(s.contactId(), unc));
  out_.write(bytesOf(s.mu(), unc));
  for (std::size_t r = 0; r < um; ++r) {
    out_.write(bytesOf(s.W() + r * static_cast<std::size_t>(s.ld()), um));
  }
  out_.write(bytesOf(s.deltaFree(), um));
  out_.write(bytesOf(s.f(), um));
  out_.write(bytesOf(s.J(), um * 6));
  out_.write(bytesOf(s.contactPoint(), unc * 3));
  out_.write(bytesOf(s.contactNormal(), unc * 3));
  out_.write(bytesOf(s.contactTangent(), unc * 6));
  if (!out_.write(bytesOf(s.contactInstrument(), unc))) throw FileError(out_.error());
  ++count_;
  return true;
}

void SnapshotFileWriter::commit() { out_.commit(); }

namespace {

template <class T>
void readArray(InputFile& in, std::vector<T>& v, std::size_t n) {
  v.resize(n);
  if (n > 0) in.readExact(v.data(), n * sizeof(T));
}

bool allFinite(const std::vector<double>& v) {
  return std::all_of(v.begin(), v.end(), [](double x) { return std::isfinite(x); });
}

}  // namespace

std::vector<RecordedSnapshot> readSnapshotFile(const std::filesystem::path& path) {
  InputFile in(path, "snapshot file", kMaxSnapshotFileBytes);
  const std::string name = in.name();
  FileHeader fh{};
  if (in.size() < sizeof(fh)) {
    throw FileError(cat(name, ": not a snapshot file (only ", in.size(), " bytes)"));
  }
  in.readExact(&fh, sizeof(fh));
  if (std::memcmp(fh.magic, kMagic, sizeof(kMagic)) != 0) {
    throw FileError(cat(name, ": not a snapshot file (wrong magic)"));
  }
  if (fh.version != kSnapshotFileVersion) {
    throw FileError(cat(name, ": snapshot file version ", fh.version,
                                " (this build reads ", kSnapshotFileVersion, ")"));
  }
  if (fh.record_header_bytes != sizeof(ContactSnapshotHeader)) {
    throw FileError(cat(name, ": snapshot header of ", fh.record_header_bytes,
                                " bytes (this build uses ", sizeof(ContactSnapshotHeader), ")"));
  }
  std::uint64_t at = sizeof(fh);
  std::vector<RecordedSnapshot> out;
  constexpr std::uint64_t kFixed = sizeof(std::int64_t) + sizeof(ContactSnapshotHeader);
  while (at < in.size()) {
    const std::size_t k = out.size();
    auto bad = [&](const std::string& what) {
      return FileError(cat(name, ": snapshot ", k, " (byte ", at, "): ", what));
    };
    if (in.size() - at < kFixed) throw bad("truncated header");
    RecordedSnapshot s;
    in.readExact(&s.t_ns, sizeof(s.t_ns));
    in.readExact(&s.header, sizeof(s.header));
    const std::int32_t m = s.header.rows;
    const std::int32_t nc = s.header.contacts;
    if (m < 0 || nc < 0 || m > kMaxRecordedRows || nc > kMaxRecordedContacts) {
      throw bad(cat("rows ", m, " / contacts ", nc, " out of range (0..", kMaxRecordedRows,
                      " / 0..", kMaxRecordedContacts, ")"));
    }
    if (m < nc || m > 3 * nc) {
      throw bad(cat("rows ", m, " do not fit ", nc, " contacts (1 to 3 rows each)"));
    }
    const std::uint64_t need = arrayBytes(static_cast<std::uint64_t>(m),
                                          static_cast<std::uint64_t>(nc));
    if (in.size() - at - kFixed < need) {
      throw bad(cat("truncated: ", need, " bytes of arrays needed, ", in.size() - at - kFixed,
                      " left"));
    }
    const auto um = static_cast<std::size_t>(m);
    const auto unc = static_cast<std::size_t>(nc);
    readArray(in, s.row_offset, unc + 1);
    readArray(in, s.contact_id, unc);
    readArray(in, s.mu, unc);
    readArray(in, s.W, um * um);
    readArray(in, s.delta_free, um);
    readArray(in, s.f, um);
    readArray(in, s.J, um * 6);
    readArray(in, s.contact_point_m, unc * 3);
    readArray(in, s.contact_normal, unc * 3);
    readArray(in, s.contact_tangent, unc * 6);
    readArray(in, s.contact_instrument, unc);
    if (s.row_offset[0] != 0 || s.row_offset[unc] != m) {
      throw bad("row offsets do not run from 0 to rows");
    }
    for (std::size_t c = 0; c < unc; ++c) {
      const std::int32_t d = s.row_offset[c + 1] - s.row_offset[c];
      if (d < 1 || d > 3) throw bad(cat("contact ", c, " has ", d, " rows (1 to 3)"));
    }
    for (const auto* v : {&s.mu, &s.W, &s.delta_free, &s.f, &s.J, &s.contact_point_m,
                          &s.contact_normal, &s.contact_tangent}) {
      if (!allFinite(*v)) throw bad("non-finite value");
    }
    if (std::any_of(s.mu.begin(), s.mu.end(), [](double x) { return x < 0.0; })) {
      throw bad("negative friction coefficient");
    }
    const ContactSnapshotHeader& h = s.header;
    if (!std::isfinite(h.h_s) || !std::isfinite(h.solver_error)) throw bad("non-finite header");
    if (h.instruments < 0 || h.instruments > kMaxInstruments) {
      throw bad(cat(h.instruments, " instruments (0 to ", kMaxInstruments, ")"));
    }
    const std::int32_t tools = std::max(1, h.instruments);
    if (std::any_of(s.contact_instrument.begin(), s.contact_instrument.end(),
                    [tools](std::int32_t i) { return i < kContactUnreachable || i >= tools; })) {
      throw bad(cat("a contact's instrument is not in -2..", tools - 1,
                    " (-1: none, -2: none and unreachable)"));
    }
    auto check_pose = [&bad](const PoseSample& p) {
      for (double x : p.pos_m) {
        if (!std::isfinite(x)) throw bad("non-finite pose");
      }
      for (double x : p.quat_wxyz) {
        if (!std::isfinite(x)) throw bad("non-finite pose");
      }
      if (!std::isfinite(p.gripper_rad)) throw bad("non-finite pose");
    };
    check_pose(h.device_pose);
    check_pose(h.tool_pose);
    for (std::int32_t i = 0; i < h.instruments; ++i) {
      check_pose(h.instrument[static_cast<std::size_t>(i)].device_pose);
      check_pose(h.instrument[static_cast<std::size_t>(i)].tool_pose);
    }
    if (!out.empty() && s.t_ns < out.back().t_ns) throw bad("time goes backwards");
    at += kFixed + need;
    out.push_back(std::move(s));
  }
  return out;
}

}  // namespace tactus::shared
