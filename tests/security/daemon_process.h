// Test helpers for the viewer and CLI security tests: a child process with its output in files
// (killed and reaped when the handle goes away), bounded waits, and a one-shot raw HTTP request
// over a POSIX socket. Every wait is bounded; nothing here can hang a test.
#pragma once

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

namespace tactus::test {

inline std::string readText(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

/// Polls `ready` every 20 ms until it is true or `timeout` passes; returns its last value.
inline bool waitFor(const std::function<bool()>& ready, std::chrono::milliseconds timeout) {
  const auto end = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    if (ready()) return true;
    if (std::chrono::steady_clock::now() > end) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
}

/// A spawned program; stdout and stderr go to files. SIGKILLed and reaped on destruction.
class ChildProcess {
 public:
  ChildProcess(const std::vector<std::string>& argv, const std::filesystem::path& out_file,
               const std::filesystem::path& err_file)
      : out_(out_file), err_(err_file) {
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    pid_ = ::fork();
    if (pid_ == 0) {
      const int out = ::open(out_file.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0600);
      const int err = ::open(err_file.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0600);
      if (out < 0 || err < 0 || ::dup2(out, 1) < 0 || ::dup2(err, 2) < 0) ::_exit(126);
      ::execv(args[0], args.data());
      ::_exit(127);
    }
  }
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;
  ~ChildProcess() {
    if (pid_ > 0 && !status_) {
      ::kill(pid_, SIGKILL);
      int st = 0;
      ::waitpid(pid_, &st, 0);
    }
  }
  bool started() const { return pid_ > 0; }
  pid_t pid() const { return pid_; }
  void signal(int sig) const {
    if (pid_ > 0 && !status_) ::kill(pid_, sig);
  }
  /// The wait status once it exited within `timeout`; nullopt (and still running) otherwise.
  std::optional<int> waitExit(std::chrono::milliseconds timeout) {
    if (status_) return status_;
    waitFor(
        [&] {
          int st = 0;
          if (::waitpid(pid_, &st, WNOHANG) == pid_) status_ = st;
          return status_.has_value();
        },
        timeout);
    return status_;
  }
  bool running() {
    return !waitExit(std::chrono::milliseconds(0)).has_value();
  }
  std::string out() const { return readText(out_); }
  std::string err() const { return readText(err_); }

 private:
  pid_t pid_ = -1;
  std::optional<int> status_;
  std::filesystem::path out_, err_;
};

/// Runs a program to completion (killed after `timeout`). `exit_code` is -1 when it did not
/// exit by itself in time or died by a signal.
struct RunResult {
  int exit_code = -1;
  bool timed_out = false;
  std::string out, err;
};
inline RunResult runProgram(const std::vector<std::string>& argv, const std::filesystem::path& dir,
                            std::chrono::milliseconds timeout = std::chrono::seconds(20)) {
  RunResult r;
  {
    ChildProcess p(argv, dir / "run.out", dir / "run.err");
    const std::optional<int> st = p.waitExit(timeout);
    r.timed_out = !st.has_value();
    if (st && WIFEXITED(*st)) r.exit_code = WEXITSTATUS(*st);
  }
  r.out = readText(dir / "run.out");
  r.err = readText(dir / "run.err");
  return r;
}

/// One raw HTTP exchange on a fresh loopback connection: sends `request` as is, reads until the
/// server closes, `max_bytes`, a 5 s silence or (with `headers_only`) the end of the response
/// header. `status` is 0 when no status line came back.
struct HttpAnswer {
  int status = 0;
  std::string raw;
  std::string body() const {
    const auto p = raw.find("\r\n\r\n");
    return p == std::string::npos ? std::string() : raw.substr(p + 4);
  }
};
inline HttpAnswer rawHttp(unsigned short port, const std::string& request,
                          bool headers_only = false,
                          std::size_t max_bytes = std::size_t{1} << 20) {
  HttpAnswer a;
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return a;
  timeval tv{5, 0};
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  ::setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(port);
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0) {
    std::size_t sent = 0;
    while (sent < request.size()) {
      const ssize_t n = ::send(fd, request.data() + sent, request.size() - sent, MSG_NOSIGNAL);
      if (n <= 0) break;  // the server may answer (414) before reading everything
      sent += static_cast<std::size_t>(n);
    }
    char buf[65536];
    while (a.raw.size() < max_bytes) {
      const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
      if (n <= 0) break;
      a.raw.append(buf, static_cast<std::size_t>(n));
      if (headers_only && a.raw.find("\r\n\r\n") != std::string::npos) break;
    }
  }
  ::close(fd);
  if (a.raw.rfind("HTTP/1.", 0) == 0 && a.raw.size() >= 12) {
    a.status = std::atoi(a.raw.substr(9, 3).c_str());
  }
  return a;
}

}  // namespace tactus::test
