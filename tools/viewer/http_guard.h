// What the live view's HTTP side accepts: a fixed table of bundled assets held in memory, and the
// Host and Origin checks that keep other web pages (DNS rebinding, cross-site WebSockets) out.
//
// The server never maps a request target onto the file system: the page's few files are read once
// at start-up (regular files only, bounded size) and a request either names one of them exactly
// or gets 404. A request is answered only when its Host names the server itself (localhost,
// 127.0.0.1, [::1] or the --bind address, with the listening port), unless --allow-remote; an
// Origin, when present, must name such a host too (with --allow-remote: the request's own Host).
#pragma once

#include <cstddef>
#include <filesystem>
#include <map>
#include <string>
#include <string_view>
#include <vector>

namespace tactus::viewer {

/// One served file.
struct Asset {
  std::string content_type;
  std::string body;
};

/// The page's files, loaded once into memory.
class AssetTable {
 public:
  /// The only files ever served (relative to the web dir); the built bundle of web/.
  static constexpr const char* kNames[] = {"index.html", "app.js", "app.js.map", "style.css"};
  /// Largest file accepted [bytes] (the bundled app.js is ~0.5 MB, its source map ~2 MB).
  static constexpr std::size_t kMaxAssetBytes = std::size_t{32} << 20;

  /// Reads each of kNames from `web_dir` that is a regular file of at most kMaxAssetBytes. A
  /// missing name is skipped silently; anything else not loaded (not a regular file, too large,
  /// unreadable) is skipped with a line in `problems`. Never blocks on a FIFO or device.
  static AssetTable load(const std::filesystem::path& web_dir, std::vector<std::string>& problems);

  /// The asset for a request path (no query): "/" means "/index.html"; anything but an exact
  /// "/<name>" of the table is nullptr.
  const Asset* find(std::string_view path) const;
  bool hasIndex() const { return find("/index.html") != nullptr; }
  std::size_t size() const { return assets_.size(); }

 private:
  std::map<std::string, Asset, std::less<>> assets_;  // key: "/<name>"
};

/// Host and Origin checks for one listening socket.
class HostPolicy {
 public:
  /// `listen_address`: the --bind address as text (v6 without brackets); `port`: the port
  /// actually listened on.
  HostPolicy(std::string listen_address, unsigned short port, bool allow_remote);

  /// A Host header value (authority "name[:port]") that names this server. Without
  /// --allow-remote: localhost, 127.0.0.1, [::1] or the listen address (case-insensitive), and
  /// the port must be the listening one (no port only when listening on 80). With
  /// --allow-remote any well-formed authority.
  bool hostAllowed(std::string_view host) const;

  /// An Origin header value: "http://" + an authority that hostAllowed() accepts, and with
  /// --allow-remote also equal to the request's `host`. "null", other schemes and paths are
  /// refused.
  bool originAllowed(std::string_view origin, std::string_view host) const;

 private:
  bool wellFormedAuthority(std::string_view authority, std::string& name, std::string& port) const;
  std::vector<std::string> names_;  // lower-case host names accepted
  std::string port_;
  bool allow_remote_;
};

}  // namespace tactus::viewer
