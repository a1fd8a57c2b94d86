// FCLIB text input: the 25 bundled problems and their references parse consistently; malformed
// files are refused with the file and line named; solutions round-trip through the writer.

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <unistd.h>

#include "tactus/shared/error.h"
#include "tactus/shared/fclib.h"

namespace tactus::shared {
namespace {

namespace fs = std::filesystem;
const fs::path kFclibSetDir = fs::path(TACTUS_TEST_DATA_DIR) / "fclib";

// A file in the temp dir with `text`, removed at the end of the test.
class TempFile {
 public:
  TempFile(const std::string& name, const std::string& text)
      : path_(fs::temp_directory_path() /
              ("tactus_fclib_" + std::to_string(::getpid()) + "_" + name)) {
    std::ofstream(path_) << text;
  }
  ~TempFile() { fs::remove(path_); }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

std::string errorOf(const fs::path& p) {
  try {
    readFclibText(p);
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

const char* kGood =
    "# comment\n"
    "1\n"
    "0.5\n"
    "-1 0.25 0\n"
    "4\n"
    "0 0 2.0\n"
    "1 1 1.5\n"
    "2 2 1.0\n"
    "0 1 0.125\n";

TEST(FclibText, ReadsAProblemIntoDenseRowMajorForm) {
  const TempFile f("good.fc3d.txt", kGood);
  const FclibProblem p = readFclibText(f.path());
  EXPECT_EQ(p.contacts, 1);
  EXPECT_EQ(p.rows(), 3);
  EXPECT_EQ(p.name, "tactus_fclib_" + std::to_string(::getpid()) + "_good");
  EXPECT_THAT(p.mu, testing::ElementsAre(0.5));
  EXPECT_THAT(p.q, testing::ElementsAre(-1.0, 0.25, 0.0));
  EXPECT_THAT(p.row_offset, testing::ElementsAre(0, 3));
  // (row 0, col 1) lands at W[0 * 3 + 1]; its transpose stays 0 (W need not be symmetric)
  EXPECT_THAT(p.W, testing::ElementsAre(2.0, 0.125, 0.0, 0.0, 1.5, 0.0, 0.0, 0.0, 1.0));
  const ContactProblemView v = p.view();
  EXPECT_EQ(v.rows, 3);
  EXPECT_EQ(v.ld, 3);
  EXPECT_EQ(v.W, p.W.data());
}

TEST(FclibText, DuplicateTripletsAreSummed) {
  const TempFile f("dup.fc3d.txt", "1\n0.1\n-1 0 0\n3\n0 0 1\n0 0 2\n1 1 1\n");
  const FclibProblem p = readFclibText(f.path());
  EXPECT_EQ(p.W[0], 3.0);
}

TEST(FclibText, MalformedFilesNameFileAndLine) {
  struct Case {
    const char* name;
    std::string text;
    std::string expected;  // substring after "FILE:"
  };
  const Case cases[] = {
      {"word", "1\n0.5\n-1 0.25 zero\n4\n", ":3: expected q[2], got 'zero'"},
      {"short", "1\n0.5\n-1 0.25 0\n4\n0 0 2.0\n1 1 1.5\n", ":6: unexpected end of file"},
      {"range", "1\n0.5\n-1 0 0\n1\n0 3 1.0\n", ":5: W entry 0 (0, 3) is outside the 3 x 3"},
      {"trailing", std::string(kGood) + "7\n", ":10: unexpected content"},
      {"nc0", "0\n", ":1: nc must be >= 1"},
      {"mu", "1\n-0.5\n", ":2: mu[0] is negative"},
      {"nan", "1\n0.5\n-1 nan 0\n", ":3: q[1] is not finite"},
      {"nnz", "1\n0.5\n-1 0 0\n2.5\n",
       ":4: nnz (number of W entries) must be a whole number, got '2.5'"},
      // too large for the reader: said as written (it used to read 999999999999.000000)
      {"nnz_huge", "1\n0.5\n-1 0 0\n999999999999\n",
       ":4: nnz (number of W entries) = 999999999999 is beyond 2e9"},
      {"empty", "# only a comment\n", ":1: unexpected end of file, expected nc"},
  };
  for (const Case& c : cases) {
    const TempFile f(std::string(c.name) + ".fc3d.txt", c.text);
    const std::string msg = errorOf(f.path());
    EXPECT_THAT(msg, testing::HasSubstr(f.path().string() + c.expected)) << c.name;
  }
  EXPECT_THAT(errorOf("/nonexistent/x.fc3d.txt"),
              testing::HasSubstr("/nonexistent/x.fc3d.txt: cannot open"));
}

TEST(FclibReferenceFile, ReadsRowsAndTheStatedError) {
  const FclibReference ref = readFclibReference(kFclibSetDir / "reference/CubeH8.local.ref.txt");
  ASSERT_EQ(ref.r.size(), 3u);
  ASSERT_EQ(ref.u.size(), 3u);
  EXPECT_DOUBLE_EQ(ref.r[0], 0.017461447862511029);
  EXPECT_DOUBLE_EQ(ref.u[2], 2.5831121326436742e-05);
  EXPECT_EQ(ref.error, 0.0);

  const TempFile bad("bad.ref.txt", "# x\n1 2\n3\n");
  try {
    readFclibReference(bad.path());
    FAIL() << "no error for a one-column line";
  } catch (const Error& e) {
    EXPECT_THAT(e.what(), testing::HasSubstr(bad.path().string() + ":3: expected two"));
  }
}

TEST(FclibReferenceFile, WriterRoundTrips) {
  const fs::path out = fs::temp_directory_path() /
                       ("tactus_fclib_" + std::to_string(::getpid()) + "_out.ref.txt");
  const std::vector<double> r = {0.1, -1.0 / 3.0, 2e-300};
  const std::vector<double> u = {0.0, 1e10, -7.25};
  writeFclibSolution(out, r, u, "solution, natural-map error 1.5e-09 (test)\nsecond line");
  const FclibReference back = readFclibReference(out);
  fs::remove(out);
  EXPECT_EQ(back.r, r);  // 17 significant digits: exact
  EXPECT_EQ(back.u, u);
  EXPECT_DOUBLE_EQ(back.error, 1.5e-9);
}

TEST(FclibBundled, AllProblemsAndReferencesAreConsistent) {
  int count = 0;
  for (const auto& e : fs::directory_iterator(kFclibSetDir / "problems")) {
    const std::string file = e.path().filename().string();
    SCOPED_TRACE(file);
    const FclibProblem p = readFclibText(e.path());
    const std::string name = file.substr(0, file.size() - std::string(".fc3d.txt").size());
    EXPECT_EQ(p.name, name);
    const FclibReference ref = readFclibReference(kFclibSetDir / "reference" / (name + ".ref.txt"));
    EXPECT_EQ(p.rows(), 3 * p.contacts);
    EXPECT_EQ(static_cast<int>(ref.r.size()), p.rows());
    EXPECT_EQ(p.W.size(), static_cast<std::size_t>(p.rows()) * p.rows());
    EXPECT_EQ(static_cast<int>(p.mu.size()), p.contacts);
    EXPECT_TRUE(std::all_of(p.mu.begin(), p.mu.end(), [](double m) { return m >= 0.0; }));
    // diagonal blocks carry a positive normal compliance
    for (int i = 0; i < p.contacts; ++i) EXPECT_GT(p.W[(3 * i) * p.rows() + 3 * i], 0.0);
    // the reference's u is W r + q (so the text's triplets are read the right way round)
    double du = 0.0, un = 0.0;
    for (int row = 0; row < p.rows(); ++row) {
      double u = p.q[row];
      for (int c = 0; c < p.rows(); ++c) u += p.W[row * p.rows() + c] * ref.r[c];
      du = std::max(du, std::abs(u - ref.u[row]));
      un = std::max({un, std::abs(ref.u[row]), std::abs(p.q[row])});
    }
    EXPECT_LE(du, 1e-8 * un);
    ++count;
  }
  EXPECT_EQ(count, 25);
}

}  // namespace
}  // namespace tactus::shared
