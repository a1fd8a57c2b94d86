#include "tactus/shared/fclib.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <iomanip>
#include <sstream>

#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"

namespace tactus::shared {
namespace {

// Whitespace-separated tokens of a text file, each with its line number; '#' lines skipped.
class TokenReader {
 public:
  explicit TokenReader(const std::filesystem::path& path)
      : file_(printable(path.string(), 256)) {
    std::istringstream in(readTextFileChecked(path, "FCLIB file", kMaxFclibBytes));
    std::string line;
    int line_no = 0;
    while (std::getline(in, line)) {
      ++line_no;
      const auto first = line.find_first_not_of(" \t\r");
      if (first == std::string::npos || line[first] == '#') continue;
      std::istringstream words(line);
      std::string word;
      while (words >> word) tokens_.push_back({word, line_no});
    }
    last_line_ = line_no;
  }

  [[noreturn]] void fail(int line, const std::string& what) const {
    throw Error(file_ + ":" + std::to_string(line) + ": " + what);
  }

  bool done() const { return next_ >= tokens_.size(); }
  std::size_t remaining() const { return tokens_.size() - next_; }
  int line() const { return done() ? last_line_ : tokens_[next_].line; }

  double number(const std::string& field) {
    if (done()) fail(last_line_, "unexpected end of file, expected " + field);
    const Token& t = tokens_[next_++];
    double v = 0.0;
    const char* end = t.text.data() + t.text.size();
    const auto [ptr, ec] = std::from_chars(t.text.data(), end, v);
    if (ec != std::errc() || ptr != end) {
      fail(t.line, "expected " + field + ", got '" + printable(t.text) + "'");
    }
    if (!std::isfinite(v)) fail(t.line, field + " is not finite ('" + printable(t.text) + "')");
    return v;
  }

  int integer(const std::string& field) {
    const int line_no = line();
    const std::string text = done() ? std::string() : tokens_[next_].text;
    const double v = number(field);
    // the token as written (std::to_string would print 999999999999.000000)
    if (v != std::floor(v)) {
      fail(line_no, field + " must be a whole number, got '" + printable(text) + "'");
    }
    if (std::abs(v) > 2e9) {
      fail(line_no, field + " = " + printable(text) + " is beyond 2e9: not a problem this "
                    "reader can hold");
    }
    return static_cast<int>(v);
  }

 private:
  struct Token {
    std::string text;
    int line;
  };
  std::string file_;
  std::vector<Token> tokens_;
  std::size_t next_ = 0;
  int last_line_ = 0;
};

std::string stemOf(const std::filesystem::path& path) {
  std::string name = path.filename().string();
  for (const char* suffix : {".fc3d.txt", ".ref.txt", ".hdf5", ".txt"}) {
    const std::string s(suffix);
    if (name.size() > s.size() && name.compare(name.size() - s.size(), s.size(), s) == 0) {
      return name.substr(0, name.size() - s.size());
    }
  }
  return name;
}

}  // namespace

ContactProblemView FclibProblem::view() const {
  return denseProblemView(contacts, rows(), row_offset.data(), W.data(), rows(), q.data(),
                          mu.data());
}

FclibProblem assembleFclibProblem(const std::string& source, std::string name,
                                  std::vector<double> mu, std::vector<double> q,
                                  const std::vector<int>& row, const std::vector<int>& col,
                                  const std::vector<double>& value) {
  const int nc = static_cast<int>(mu.size());
  if (nc < 1) throw Error(source + ": no contacts (nc = 0)");
  if (q.size() != 3 * mu.size()) {
    throw Error(source + ": q has " + std::to_string(q.size()) + " entries, expected 3 nc = " +
                std::to_string(3 * nc));
  }
  if (row.size() != value.size() || col.size() != value.size()) {
    throw Error(source + ": W triplet arrays differ in length");
  }
  const int m = 3 * nc;
  FclibProblem p;
  p.contacts = nc;
  p.name = std::move(name);
  p.mu = std::move(mu);
  p.q = std::move(q);
  p.W.assign(static_cast<std::size_t>(m) * m, 0.0);
  for (std::size_t k = 0; k < value.size(); ++k) {
    if (row[k] < 0 || row[k] >= m || col[k] < 0 || col[k] >= m) {
      throw Error(source + ": W entry " + std::to_string(k) + " at (" + std::to_string(row[k]) +
                  ", " + std::to_string(col[k]) + ") is outside the " + std::to_string(m) + " x " +
                  std::to_string(m) + " matrix");
    }
    p.W[static_cast<std::size_t>(row[k]) * m + col[k]] += value[k];
  }
  p.row_offset.resize(nc + 1);
  for (int i = 0; i <= nc; ++i) p.row_offset[i] = 3 * i;
  return p;
}

FclibProblem readFclibText(const std::filesystem::path& path) {
  TokenReader in(path);
  const int nc_line = in.line();
  const int nc = in.integer("nc (number of contacts)");
  if (nc < 1) in.fail(nc_line, "nc must be >= 1, got " + std::to_string(nc));
  // counts come from the file: reserve no more than the values left (a short file claiming
  // nc = 10^9 fails at its end instead of allocating gigabytes first)
  std::vector<double> mu;
  mu.reserve(std::min(static_cast<std::size_t>(nc), in.remaining()));
  for (int i = 0; i < nc; ++i) {
    const int line_no = in.line();
    mu.push_back(in.number("mu[" + std::to_string(i) + "]"));
    if (mu[i] < 0.0) in.fail(line_no, "mu[" + std::to_string(i) + "] is negative");
  }
  std::vector<double> q;
  q.reserve(std::min(3 * static_cast<std::size_t>(nc), in.remaining()));
  for (std::size_t j = 0; j < 3 * static_cast<std::size_t>(nc); ++j) {
    q.push_back(in.number("q[" + std::to_string(j) + "]"));
  }
  const int nnz_line = in.line();
  const int nnz = in.integer("nnz (number of W entries)");
  if (nnz < 0) in.fail(nnz_line, "nnz must be >= 0, got " + std::to_string(nnz));
  const int m = 3 * nc;
  std::vector<int> rows, cols;
  std::vector<double> values;
  const std::size_t nnz_fits = std::min(static_cast<std::size_t>(nnz), in.remaining() / 3);
  rows.reserve(nnz_fits);
  cols.reserve(nnz_fits);
  values.reserve(nnz_fits);
  for (int k = 0; k < nnz; ++k) {
    const int line_no = in.line();
    const std::string entry = "W entry " + std::to_string(k);
    rows.push_back(in.integer(entry + " row"));
    cols.push_back(in.integer(entry + " column"));
    values.push_back(in.number(entry + " value"));
    if (rows[k] < 0 || rows[k] >= m || cols[k] < 0 || cols[k] >= m) {
      in.fail(line_no, entry + " (" + std::to_string(rows[k]) + ", " + std::to_string(cols[k]) +
                           ") is outside the " + std::to_string(m) + " x " + std::to_string(m) +
                           " matrix (indices are 0-based)");
    }
  }
  if (!in.done()) in.fail(in.line(), "unexpected content after the " + std::to_string(nnz) +
                                         " W entries");
  return assembleFclibProblem(path.string(), stemOf(path), std::move(mu), std::move(q), rows,
                              cols, values);
}

FclibReference readFclibReference(const std::filesystem::path& path) {
  const std::string file = printable(path.string(), 256);
  std::istringstream in(readTextFileChecked(path, "FCLIB reference", kMaxFclibBytes));
  FclibReference ref;
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    const auto first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos) continue;
    if (line[first] == '#') {
      // "... error 1.2e-10 ..." in the first comment that states one
      const auto at = line.find("error ");
      if (ref.error < 0.0 && at != std::string::npos) {
        std::istringstream rest(line.substr(at + 6));
        double e = 0.0;
        if (rest >> e && std::isfinite(e)) ref.error = e;
      }
      continue;
    }
    std::istringstream words(line);
    std::string a, b, extra;
    double r = 0.0, u = 0.0;
    const bool two = static_cast<bool>(words >> a >> b) && !(words >> extra);
    auto parse = [](const std::string& s, double& v) {
      const char* end = s.data() + s.size();
      const auto [ptr, ec] = std::from_chars(s.data(), end, v);
      return ec == std::errc() && ptr == end && std::isfinite(v);
    };
    if (!two || !parse(a, r) || !parse(b, u)) {
      throw Error(file + ":" + std::to_string(line_no) +
                  ": expected two finite numbers `r u`, got '" + printable(line) + "'");
    }
    ref.r.push_back(r);
    ref.u.push_back(u);
  }
  return ref;
}

void writeFclibSolution(const std::filesystem::path& path, const std::vector<double>& r,
                        const std::vector<double>& u, const std::string& comment,
                        bool overwrite) {
  std::ostringstream out;
  std::istringstream lines(comment);
  std::string line;
  while (std::getline(lines, line)) out << "# " << line << '\n';
  out << std::setprecision(17);
  for (std::size_t j = 0; j < r.size() && j < u.size(); ++j) out << r[j] << ' ' << u[j] << '\n';
  writeFileChecked(path, out.str(), "FCLIB solution",
                   {.overwrite = overwrite, .overwrite_hint = "pass --overwrite"});
}

}  // namespace tactus::shared
