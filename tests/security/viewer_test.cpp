// The live view's HTTP side against hostile requests. The real tactus-viewer binary is started on
// a free loopback port against a segment with no simulation (it must still serve its page) and a
// web dir of its own: index.html and app.js are files, style.css is a FIFO (a start-up that
// opened it would block). Requests are raw HTTP over a socket.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <cstdio>
#include <memory>
#include <regex>

#include "daemon_process.h"

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using tactus::test::ChildProcess;
using tactus::test::HttpAnswer;
using tactus::test::rawHttp;

namespace {

const char* kPageMarker = "tactus-viewer-security-test-page";

class ViewerSecurity : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / ("tactus_sec_viewer_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "web");
    std::FILE* f = std::fopen((dir_ / "web/index.html").c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fprintf(f, "<!doctype html><title>%s</title>", kPageMarker);
    std::fclose(f);
    f = std::fopen((dir_ / "web/app.js").c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fprintf(f, "console.log('app');\n");
    std::fclose(f);
    ASSERT_EQ(::mkfifo((dir_ / "web/style.css").c_str(), 0600), 0);
    segment_ = "tactus_sec_viewer_nosim_" + std::to_string(::getpid());
    viewer_ = std::make_unique<ChildProcess>(
        std::vector<std::string>{TACTUS_BINARY_DIR "/tools/viewer/tactus-viewer",
                                 "--segment", segment_, "--port", "0", "--web-dir",
                                 (dir_ / "web").string(), "--nice", "0"},
        dir_ / "viewer.out", dir_ / "viewer.err");
    ASSERT_TRUE(viewer_->started());
    // the URL line carries the port it listens on
    const std::regex url(R"(http://127\.0\.0\.1:(\d+)/)");
    std::smatch m;
    const bool up = tactus::test::waitFor(
        [&] {
          const std::string out = viewer_->out();
          return std::regex_search(out, m, url) || !viewer_->running();
        },
        15s);
    const std::string out = viewer_->out();
    ASSERT_TRUE(up && std::regex_search(out, m, url))
        << "viewer did not start: " << out << viewer_->err();
    port_ = static_cast<unsigned short>(std::stoi(m[1].str()));
  }
  static void TearDownTestSuite() {
    viewer_.reset();
    fs::remove_all(dir_);
  }
  void TearDown() override {
    // whatever a test sent, the server is still there and answers the next request
    ASSERT_TRUE(viewer_->running()) << viewer_->err();
    EXPECT_EQ(get("/").status, 200);
  }

  static std::string host() { return "127.0.0.1:" + std::to_string(port_); }
  static HttpAnswer get(const std::string& target, const std::string& extra_headers = "") {
    return rawHttp(port_, "GET " + target + " HTTP/1.1\r\nHost: " + host() +
                              "\r\nConnection: close\r\n" + extra_headers + "\r\n");
  }
  static HttpAnswer request(const std::string& text, bool headers_only = false) {
    return rawHttp(port_, text, headers_only);
  }
  static std::string upgrade(const std::string& host_value, const std::string& origin) {
    return "GET /ws HTTP/1.1\r\nHost: " + host_value +
           "\r\nConnection: Upgrade\r\nUpgrade: websocket\r\nSec-WebSocket-Version: 13\r\n"
           "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n" +
           (origin.empty() ? "" : "Origin: " + origin + "\r\n") + "\r\n";
  }

  static fs::path dir_;
  static std::string segment_;
  static std::unique_ptr<ChildProcess> viewer_;
  static unsigned short port_;
};
fs::path ViewerSecurity::dir_;
std::string ViewerSecurity::segment_;
std::unique_ptr<ChildProcess> ViewerSecurity::viewer_;
unsigned short ViewerSecurity::port_ = 0;

TEST_F(ViewerSecurity, ServesItsPageWithoutASimulation) {
  const HttpAnswer page = get("/");
  EXPECT_EQ(page.status, 200);
  EXPECT_NE(page.body().find(kPageMarker), std::string::npos) << page.raw;
  EXPECT_EQ(get("/index.html").status, 200);
  EXPECT_EQ(get("/app.js?v=1").status, 200);
  EXPECT_EQ(get("/status.json").status, 200);
  const HttpAnswer head =
      request("HEAD / HTTP/1.1\r\nHost: " + host() + "\r\nConnection: close\r\n\r\n");
  EXPECT_EQ(head.status, 200);
  EXPECT_TRUE(head.body().empty());
}

TEST_F(ViewerSecurity, FileSystemPathsAreNotFound) {
  const std::vector<std::string> targets = {
      "//etc/passwd", "/../../etc/passwd", "/%2e%2e/%2e%2e/etc/passwd", "/..%2f..%2fetc%2fpasswd",
      "/%2e%2e%2f%2e%2e%2fetc%2fpasswd", "/index.html/../../../etc/passwd", "//dev/zero",
      "//proc/self/environ", "/web/index.html", "/viewer.out"};
  for (const std::string& target : targets) {
    const HttpAnswer a = get(target);
    EXPECT_EQ(a.status, 404) << target << ": " << a.raw.substr(0, 200);
    EXPECT_EQ(a.body().find("root:"), std::string::npos) << target;
  }
  // a FIFO in the web dir is neither opened at start-up (the server is up) nor served
  EXPECT_EQ(get("/style.css").status, 404);
  EXPECT_NE(viewer_->err().find("not a regular file"), std::string::npos) << viewer_->err();
}

TEST_F(ViewerSecurity, ForeignHostIsForbidden) {
  const std::string port = std::to_string(port_);
  const std::vector<std::string> bad_hosts = {
      "evil.example:" + port, "evil.example", "127.0.0.1", "127.0.0.1:1",
      "localhost.evil.example:" + port, "127.0.0.1:" + port + "@evil.example", ""};
  for (const std::string& bad : bad_hosts) {
    const HttpAnswer a =
        request("GET / HTTP/1.1\r\nHost: " + bad + "\r\nConnection: close\r\n\r\n");
    EXPECT_EQ(a.status, 403) << "Host: " << bad;
    EXPECT_EQ(a.body().find(kPageMarker), std::string::npos);
  }
  // HTTP/1.0 without a Host header
  EXPECT_EQ(request("GET / HTTP/1.0\r\n\r\n").status, 403);
  for (const std::string& good :
       std::vector<std::string>{"localhost:" + port, "LOCALHOST:" + port, "[::1]:" + port}) {
    EXPECT_EQ(request("GET / HTTP/1.1\r\nHost: " + good + "\r\nConnection: close\r\n\r\n").status,
              200)
        << "Host: " << good;
  }
}

TEST_F(ViewerSecurity, CrossSiteOriginIsRefused) {
  const std::vector<std::string> origins = {"http://evil.example",
                                            "http://evil.example:" + std::to_string(port_), "null",
                                            "https://" + host(), "file://"};
  for (const std::string& origin : origins) {
    const HttpAnswer ws = request(upgrade(host(), origin), true);
    EXPECT_NE(ws.status, 101) << "Origin: " << origin;
    EXPECT_EQ(ws.status, 403) << "Origin: " << origin;
    EXPECT_EQ(get("/status.json", "Origin: " + origin + "\r\n").status, 403) << origin;
  }
  // a foreign Host on the upgrade (DNS rebinding) is refused too
  EXPECT_EQ(request(upgrade("evil.example:" + std::to_string(port_), ""), true).status, 403);
  // the page's own origin opens the WebSocket
  EXPECT_EQ(request(upgrade(host(), "http://" + host()), true).status, 101);
  EXPECT_EQ(request(upgrade(host(), ""), true).status, 101);
}

TEST_F(ViewerSecurity, OverLongRequestsAreRefused) {
  EXPECT_EQ(get("/" + std::string(10 * 1024, 'a')).status, 414);
  EXPECT_EQ(get("/" + std::string(3000, 'a')).status, 414);
  // a request line that never ends
  EXPECT_EQ(request("GET /" + std::string(64 * 1024, 'a')).status, 414);
  // headers beyond the bound
  EXPECT_EQ(get("/", "X-Padding: " + std::string(16 * 1024, 'b') + "\r\n").status, 431);
  // a large body announced to a read-only server
  EXPECT_EQ(request("POST / HTTP/1.1\r\nHost: " + host() +
                    "\r\nConnection: close\r\nContent-Length: 100000\r\n\r\n" +
                    std::string(100000, 'c'))
                .status,
            413);
}

TEST_F(ViewerSecurity, SighupStopsTheViewerCleanly) {
  // a viewer of its own (the suite's keeps serving)
  ChildProcess v({TACTUS_BINARY_DIR "/tools/viewer/tactus-viewer", "--segment",
                  segment_, "--port", "0", "--web-dir", (dir_ / "web").string()},
                 dir_ / "hup.out", dir_ / "hup.err");
  ASSERT_TRUE(tactus::test::waitFor([&] { return v.out().find("http://") != std::string::npos; },
                                    15s))
      << v.err();
  v.signal(SIGHUP);
  const std::optional<int> st = v.waitExit(10s);
  ASSERT_TRUE(st.has_value()) << "the viewer ignored SIGHUP";
  EXPECT_TRUE(WIFEXITED(*st) && WEXITSTATUS(*st) == 0) << "wait status " << *st;
  EXPECT_NE(v.out().find("stopped"), std::string::npos);
}

}  // namespace
