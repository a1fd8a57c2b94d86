#include "http_guard.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstring>

namespace tactus::viewer {
namespace {

std::string contentTypeOf(std::string_view name) {
  const auto ends = [&](std::string_view suffix) {
    return name.size() >= suffix.size() && name.substr(name.size() - suffix.size()) == suffix;
  };
  if (ends(".html")) return "text/html; charset=utf-8";
  if (ends(".js")) return "text/javascript; charset=utf-8";
  if (ends(".css")) return "text/css; charset=utf-8";
  if (ends(".map")) return "application/json";
  return "application/octet-stream";
}

std::string lower(std::string_view s) {
  std::string out(s);
  std::transform(out.begin(), out.end(), out.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return out;
}

// Reads a regular file of at most max_bytes; false with `why` otherwise. O_NONBLOCK: opening a
// FIFO must not wait for a writer (it is then refused as not regular).
bool readRegularFile(const std::filesystem::path& path, std::size_t max_bytes, std::string& out,
                     std::string& why, bool& missing) {
  missing = false;
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK | O_NOCTTY);
  if (fd < 0) {
    missing = errno == ENOENT;
    why = std::strerror(errno);
    return false;
  }
  struct stat st {};
  bool ok = false;
  if (::fstat(fd, &st) != 0) {
    why = std::strerror(errno);
  } else if (!S_ISREG(st.st_mode)) {
    why = "not a regular file";
  } else if (static_cast<std::uintmax_t>(st.st_size) > max_bytes) {
    why = "larger than " + std::to_string(max_bytes) + " bytes";
  } else {
    out.resize(static_cast<std::size_t>(st.st_size));
    std::size_t got = 0;
    ok = true;
    while (got < out.size()) {
      const ssize_t n = ::read(fd, out.data() + got, out.size() - got);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) {
        why = n < 0 ? std::strerror(errno) : "file shrank while reading";
        ok = false;
        break;
      }
      got += static_cast<std::size_t>(n);
    }
  }
  ::close(fd);
  return ok;
}

}  // namespace

AssetTable AssetTable::load(const std::filesystem::path& web_dir,
                            std::vector<std::string>& problems) {
  AssetTable table;
  for (const char* name : kNames) {
    const std::filesystem::path path = web_dir / name;
    Asset asset{contentTypeOf(name), {}};
    std::string why;
    bool missing = false;
    if (readRegularFile(path, kMaxAssetBytes, asset.body, why, missing)) {
      table.assets_.emplace(std::string("/") + name, std::move(asset));
    } else if (!missing) {
      problems.push_back("not serving " + path.string() + ": " + why);
    }
  }
  return table;
}

const Asset* AssetTable::find(std::string_view path) const {
  if (path == "/") path = "/index.html";
  const auto it = assets_.find(path);
  return it == assets_.end() ? nullptr : &it->second;
}

HostPolicy::HostPolicy(std::string listen_address, unsigned short port, bool allow_remote)
    : port_(std::to_string(port)), allow_remote_(allow_remote) {
  names_ = {"localhost", "127.0.0.1", "[::1]"};
  std::string own = lower(listen_address);
  if (own.find(':') != std::string::npos) own = "[" + own + "]";
  if (std::find(names_.begin(), names_.end(), own) == names_.end()) names_.push_back(own);
}

bool HostPolicy::wellFormedAuthority(std::string_view authority, std::string& name,
                                     std::string& port) const {
  if (authority.empty() || authority.size() > 255) return false;
  for (const char c : authority) {
    const auto u = static_cast<unsigned char>(c);
    if (!std::isalnum(u) && c != '.' && c != '-' && c != '_' && c != ':' && c != '[' && c != ']') {
      return false;
    }
  }
  std::size_t name_end = 0;
  if (authority.front() == '[') {
    name_end = authority.find(']');
    if (name_end == std::string_view::npos) return false;
    ++name_end;
  } else {
    name_end = authority.find(':');
    if (name_end == std::string_view::npos) name_end = authority.size();
  }
  name = lower(authority.substr(0, name_end));
  const std::string_view rest = authority.substr(name_end);
  port.clear();
  if (!rest.empty()) {
    if (rest.front() != ':' || rest.size() < 2 || rest.size() > 6) return false;
    port = std::string(rest.substr(1));
    if (!std::all_of(port.begin(), port.end(), [](unsigned char c) { return std::isdigit(c); })) {
      return false;
    }
  }
  if (name.empty()) return false;
  // brackets only around an IPv6 literal: "[...]" with none inside
  const std::size_t inner = name.find_first_of("[]", 1);
  return name.front() == '[' ? inner == name.size() - 1 && name.size() > 2
                             : name.find_first_of("[]") == std::string::npos;
}

bool HostPolicy::hostAllowed(std::string_view host) const {
  std::string name, port;
  if (!wellFormedAuthority(host, name, port)) return false;
  if (allow_remote_) return true;
  const bool port_ok = port.empty() ? port_ == "80" : port == port_;
  return port_ok && std::find(names_.begin(), names_.end(), name) != names_.end();
}

bool HostPolicy::originAllowed(std::string_view origin, std::string_view host) const {
  constexpr std::string_view kScheme = "http://";
  const std::string o = lower(origin);
  if (o.size() <= kScheme.size() || o.compare(0, kScheme.size(), kScheme) != 0) return false;
  const std::string authority = o.substr(kScheme.size());
  if (!hostAllowed(authority)) return false;
  return !allow_remote_ || authority == lower(host);
}

}  // namespace tactus::viewer
