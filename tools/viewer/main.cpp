// tactus-viewer: the live view of a running simulation in a browser.
//
// Attaches read-only to the segment (--segment), serves the built web page (three.js) over HTTP
// on 127.0.0.1 (--bind / --port; a non-loopback address needs --allow-remote) and streams over a
// WebSocket (/ws) the display frames as binary messages (segment_watcher.h) and a JSON status
// (rates, contacts, force, haptic period-error histogram) about 20 times a second. Follows the
// simulation across restarts. Nothing a client sends changes the simulation: the HTTP side
// answers GET/HEAD only and the WebSocket side ignores incoming messages.
//
// Only the page's bundled files are served, from memory (loaded once at start-up; http_guard.h),
// and only to requests whose Host (and Origin, when sent) name this server: a web page elsewhere
// cannot read the view or open its WebSocket. Over-long request lines get 414, headers are bounded.
// (About 500 lines: the HTTP and WebSocket sessions and the status JSON are one server's parts.)
//
// Single-threaded (one Asio io_context): a timer polls the segment at --rate Hz and broadcasts.
// A client that cannot keep up loses frames, never the topology, and never slows the others.
#include "tactus/shared/cli.h"
#include <sys/resource.h>

// Boost 1.74's asio/awaitable.hpp uses std::exchange without including <utility> itself.
#include <utility>

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <array>
#include <chrono>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "http_guard.h"
#include "segment_watcher.h"
#include "tactus/shared/clock.h"

namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
namespace net = boost::asio;
using tcp = net::ip::tcp;

#ifndef TACTUS_VIEWER_WEB_DIR
#define TACTUS_VIEWER_WEB_DIR ""
#endif

namespace tactus::viewer {
namespace {

// A message shared by every client queue.
struct Message {
  std::string data;
  bool binary = true;
  bool droppable = true;             // frames and status; never the topology
};
using MessagePtr = std::shared_ptr<const Message>;

class Hub;

// One WebSocket client.
class WsSession : public std::enable_shared_from_this<WsSession> {
 public:
  WsSession(tcp::socket&& socket, Hub& hub) : ws_(std::move(socket)), hub_(hub) {}
  void run(http::request<http::string_body> req);
  void send(const MessagePtr& m);
  std::uint64_t dropped() const { return dropped_; }

 private:
  void onAccept(beast::error_code ec);
  void doRead();
  void write();
  websocket::stream<beast::tcp_stream> ws_;
  Hub& hub_;
  beast::flat_buffer in_;
  std::deque<MessagePtr> queue_;
  std::uint64_t dropped_ = 0;
  bool closed_ = false;
};

// The set of clients and what a newcomer needs first.
class Hub {
 public:
  void join(const std::shared_ptr<WsSession>& s) {
    sessions_.push_back(s);
    if (!topology_.empty()) s->send(std::make_shared<Message>(Message{topology_, true, false}));
    if (!status_.empty()) s->send(std::make_shared<Message>(Message{status_, false, true}));
  }
  void broadcast(const MessagePtr& m) {
    std::vector<std::shared_ptr<WsSession>> live;
    for (auto& w : sessions_) {
      if (auto s = w.lock()) live.push_back(std::move(s));
    }
    sessions_.assign(live.begin(), live.end());
    for (auto& s : live) s->send(m);
  }
  void setTopology(const std::string& t) { topology_ = t; }
  void setStatus(const std::string& s) { status_ = s; }
  const std::string& status() const { return status_; }
  std::size_t clients() const { return sessions_.size(); }

 private:
  std::vector<std::weak_ptr<WsSession>> sessions_;
  std::string topology_;
  std::string status_;
};

void WsSession::run(http::request<http::string_body> req) {
  ws_.set_option(websocket::stream_base::timeout::suggested(beast::role_type::server));
  ws_.read_message_max(4096);  // clients have nothing to say: incoming messages are ignored
  ws_.set_option(websocket::stream_base::decorator([](websocket::response_type& res) {
    res.set(http::field::server, "tactus-viewer");
  }));
  ws_.async_accept(req, beast::bind_front_handler(&WsSession::onAccept, shared_from_this()));
}

void WsSession::onAccept(beast::error_code ec) {
  if (ec) return;
  hub_.join(shared_from_this());
  doRead();
}

void WsSession::doRead() {
  // incoming messages are read and ignored (the view is read-only); a read error ends the session
  ws_.async_read(in_, [self = shared_from_this()](beast::error_code ec, std::size_t) {
    if (ec) {
      self->closed_ = true;
      return;
    }
    self->in_.consume(self->in_.size());
    self->doRead();
  });
}

void WsSession::send(const MessagePtr& m) {
  if (closed_) return;
  // a slow client: drop frames and status beyond a short backlog, keep the topology
  if (m->droppable && queue_.size() >= 3) {
    ++dropped_;
    return;
  }
  queue_.push_back(m);
  if (queue_.size() == 1) write();
}

void WsSession::write() {
  const MessagePtr& m = queue_.front();
  ws_.binary(m->binary);
  ws_.async_write(net::buffer(m->data), [self = shared_from_this()](beast::error_code ec,
                                                                    std::size_t) {
    if (ec) {
      self->closed_ = true;
      self->queue_.clear();
      return;
    }
    self->queue_.pop_front();
    if (!self->queue_.empty()) self->write();
  });
}

const char* kMissingPage =
    "<!doctype html><meta charset=utf-8><title>Tactus live view</title>"
    "<body style='font:14px sans-serif;margin:2em'><h1>Tactus live view</h1>"
    "<p>The web page has not been built. It is built with node and npm by the CMake target "
    "<code>tactus-viewer-web</code> (<code>ninja -C build tactus-viewer-web</code>), or by "
    "<code>scripts/view</code>; then restart the viewer.</p>"
    "<p>Raw status: <a href='/status.json'>/status.json</a></p>";

// Request size bounds: the whole header (request line included) and the request target.
constexpr std::uint32_t kMaxHeaderBytes = 8192;
constexpr std::size_t kMaxTargetBytes = 2048;
constexpr std::uint64_t kMaxBodyBytes = 4096;
constexpr std::size_t kMaxLingerBytes = std::size_t{1} << 20;

std::string_view sv(beast::string_view s) { return {s.data(), s.size()}; }

// What every HTTP session shares (read-only after start-up).
struct ServerContext {
  Hub& hub;
  const AssetTable& assets;
  const HostPolicy& hosts;
};

// One HTTP connection: the bundled assets, /status.json, and the upgrade to /ws.
class HttpSession : public std::enable_shared_from_this<HttpSession> {
 public:
  HttpSession(tcp::socket&& socket, const ServerContext& ctx)
      : stream_(std::move(socket)), ctx_(ctx), buffer_(2 * kMaxHeaderBytes) {}
  void run() { doRead(); }

 private:
  void doRead() {
    parser_.emplace();
    parser_->header_limit(kMaxHeaderBytes);
    parser_->body_limit(kMaxBodyBytes);
    stream_.expires_after(std::chrono::seconds(30));
    http::async_read(stream_, buffer_, *parser_,
                     beast::bind_front_handler(&HttpSession::onRead, shared_from_this()));
  }

  void onRead(beast::error_code ec, std::size_t) {
    if (ec == http::error::header_limit || ec == http::error::buffer_overflow) {
      // the parser fills in the target once it has the whole request line: without one, the
      // request line itself was too long
      if (parser_->get().target().empty()) {
        fail(http::status::uri_too_long, "request target too long\n");
      } else {
        fail(http::status::request_header_fields_too_large, "request header too large\n");
      }
      return;
    }
    if (ec == http::error::body_limit) {
      fail(http::status::payload_too_large, "request body too large\n");
      return;
    }
    if (ec && ec.category() == http::make_error_code(http::error::bad_target).category() &&
        ec != http::error::end_of_stream && ec != http::error::partial_message) {
      fail(http::status::bad_request, "malformed request\n");
      return;
    }
    if (ec) {
      close();
      return;
    }
    req_ = parser_->release();
    if (req_.target().size() > kMaxTargetBytes) {
      fail(http::status::uri_too_long, "request target too long\n");
      return;
    }
    // another site's page (DNS rebinding, cross-site WebSocket) never gets an answer
    const auto host = req_.find(http::field::host);
    if (host == req_.end() || !ctx_.hosts.hostAllowed(sv(host->value()))) {
      fail(http::status::forbidden, "Host not allowed: the live view answers only to the address "
                                    "it listens on (localhost, 127.0.0.1, [::1])\n");
      return;
    }
    if (const auto origin = req_.find(http::field::origin);
        origin != req_.end() && !ctx_.hosts.originAllowed(sv(origin->value()), sv(host->value()))) {
      fail(http::status::forbidden, "cross-origin requests are refused\n");
      return;
    }
    if (websocket::is_upgrade(req_)) {
      if (req_.target() != "/ws") {
        reply(http::status::not_found, "text/plain", "WebSocket endpoint is /ws\n");
        return;
      }
      stream_.expires_never();
      std::make_shared<WsSession>(stream_.release_socket(), ctx_.hub)->run(std::move(req_));
      return;
    }
    if (req_.method() != http::verb::get && req_.method() != http::verb::head) {
      reply(http::status::method_not_allowed, "text/plain",
            "the live view is read-only: GET and HEAD only\n");
      return;
    }
    std::string_view target = sv(req_.target());
    if (const auto q = target.find('?'); q != std::string_view::npos) target = target.substr(0, q);
    if (target == "/status.json") {
      reply(http::status::ok, "application/json", ctx_.hub.status());
      return;
    }
    // only the fixed table of bundled files: never a path on the file system
    if (const Asset* asset = ctx_.assets.find(target)) {
      reply(http::status::ok, asset->content_type, asset->body);
    } else if (target == "/" || target == "/index.html") {
      reply(http::status::ok, "text/html; charset=utf-8", kMissingPage);
    } else {
      reply(http::status::not_found, "text/plain", "not found\n");
    }
  }

  // An error answer to a request that may not have been parsed; the connection closes after it.
  void fail(http::status status, const char* body) {
    req_ = {};
    req_.version(11);
    req_.keep_alive(false);
    linger_ = true;
    reply(status, "text/plain", body, false);
  }

  // After an error answer: stop sending, then read and drop what the client still sends (at most
  // kMaxLingerBytes or 2 s) so that closing does not reset the connection before the client has
  // read the answer.
  void lingerClose() {
    close();
    stream_.expires_after(std::chrono::seconds(2));
    stream_.async_read_some(
        net::buffer(discard_), [self = shared_from_this()](beast::error_code ec, std::size_t n) {
          self->lingered_ += n;
          if (!ec && self->lingered_ < kMaxLingerBytes) self->lingerClose();
        });
  }

  void reply(http::status status, const std::string& type, const std::string& body,
             bool keep_alive = true) {
    auto res = std::make_shared<http::response<http::string_body>>(status, req_.version());
    res->set(http::field::server, "tactus-viewer");
    res->set(http::field::content_type, type);
    res->set(http::field::cache_control, "no-store");
    res->set("X-Content-Type-Options", "nosniff");
    res->keep_alive(keep_alive && req_.keep_alive());
    const bool head = req_.method() == http::verb::head;
    if (!head) res->body() = body;
    res->prepare_payload();
    if (head) res->content_length(body.size());
    http::async_write(stream_, *res,
                      [self = shared_from_this(), res](beast::error_code ec, std::size_t) {
                        if (!ec && self->linger_) {
                          self->lingerClose();
                          return;
                        }
                        if (ec || !res->keep_alive()) {
                          self->close();
                          return;
                        }
                        self->doRead();
                      });
  }

  void close() {
    beast::error_code ignored;
    stream_.socket().shutdown(tcp::socket::shutdown_send, ignored);
  }

  beast::tcp_stream stream_;
  const ServerContext& ctx_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  http::request<http::string_body> req_;
  bool linger_ = false;
  std::array<char, 4096> discard_{};
  std::size_t lingered_ = 0;
};

class Listener : public std::enable_shared_from_this<Listener> {
 public:
  Listener(net::io_context& ioc, tcp::endpoint at)
      : ioc_(ioc), acceptor_(ioc) {
    acceptor_.open(at.protocol());
    acceptor_.set_option(net::socket_base::reuse_address(true));
    acceptor_.bind(at);
    acceptor_.listen(net::socket_base::max_listen_connections);
  }
  unsigned short port() const { return acceptor_.local_endpoint().port(); }
  void run(const ServerContext& ctx) {
    ctx_ = &ctx;
    doAccept();
  }

 private:
  void doAccept() {
    acceptor_.async_accept(net::make_strand(ioc_), [self = shared_from_this()](
                                                       beast::error_code ec, tcp::socket s) {
      if (!ec) std::make_shared<HttpSession>(std::move(s), *self->ctx_)->run();
      self->doAccept();
    });
  }
  net::io_context& ioc_;
  tcp::acceptor acceptor_;
  const ServerContext* ctx_ = nullptr;
};

// Polls the segment at the frame rate and broadcasts; status every 50 ms.
class Pump {
 public:
  Pump(net::io_context& ioc, SegmentWatcher& watcher, Hub& hub, double rate_hz)
      : timer_(ioc), watcher_(watcher), hub_(hub),
        period_(std::chrono::nanoseconds(static_cast<std::int64_t>(1e9 / rate_hz))) {}
  void start() {
    next_ = std::chrono::steady_clock::now();
    tick();
  }

 private:
  void tick() {
    const std::int64_t now = shared::monotonicNs();
    watcher_.poll(now);
    if (auto t = watcher_.takeTopologyMessage()) {
      hub_.setTopology(*t);
      hub_.broadcast(std::make_shared<Message>(Message{std::move(*t), true, false}));
    }
    if (auto f = watcher_.takeFrameMessage()) {
      hub_.broadcast(std::make_shared<Message>(Message{std::move(*f), true, true}));
    }
    if (now - last_status_ns_ >= 50 * shared::kNsPerMs) {
      last_status_ns_ = now;
      std::string s = watcher_.takeStatusJson(now);
      hub_.setStatus(s);
      hub_.broadcast(std::make_shared<Message>(Message{std::move(s), false, true}));
    }
    next_ += period_;
    const auto now_tp = std::chrono::steady_clock::now();
    if (next_ < now_tp) next_ = now_tp;
    timer_.expires_at(next_);
    timer_.async_wait([this](beast::error_code ec) {
      if (!ec) tick();
    });
  }
  net::steady_timer timer_;
  SegmentWatcher& watcher_;
  Hub& hub_;
  std::chrono::steady_clock::duration period_;
  std::chrono::steady_clock::time_point next_;
  std::int64_t last_status_ns_ = 0;
};

}  // namespace
}  // namespace tactus::viewer

int main(int argc, char** argv) {
  using namespace tactus::viewer;
  namespace cli = tactus::shared::cli;
  cli::App app{"Tactus live view: serves a browser page showing the running simulation "
               "(read-only)"};
  app.footer(
      "Example:\n"
      "  tactus-viewer --segment tactus --port 8090");
  std::string segment = "tactus";
  std::string bind = "127.0.0.1";
  int port = 8090;
  bool allow_remote = false;
  double rate = 60.0;
  std::string web = TACTUS_VIEWER_WEB_DIR;
  int nice_level = 10;
  app.addOption("--segment", segment, "Segment name of the running simulation")
      ->captureDefault();
  app.addOption("--port", port, "TCP port (0: any free port; the URL is printed)")
      ->captureDefault()
      ->check(cli::range(0, 65535));
  app.addOption("--bind", bind, "Address to listen on (loopback unless --allow-remote)")
      ->captureDefault();
  app.addFlag("--allow-remote", allow_remote,
               "Allow a non-loopback --bind address (anyone who can reach it sees the view)");
  app.addOption("--rate", rate, "Frames per second streamed at most")
      ->captureDefault()
      ->check(cli::range(1.0, 240.0));
  app.addOption("--web-dir", web,
                 "Directory of the built page: index.html, app.js, app.js.map and style.css are "
                 "read once at start-up (regular files only); nothing else is served")
      ->captureDefault();
  app.addOption("--nice", nice_level, "Scheduling niceness of the viewer (it yields the CPU to "
                 "the simulation)")
      ->captureDefault()
      ->check(cli::range(0, 19));
  TACTUS_CLI_PARSE(app, argc, argv);
  // the view is best effort: never compete with the simulation for a core
  if (nice_level > 0 && ::setpriority(PRIO_PROCESS, 0, nice_level) != 0) {
    std::fprintf(stderr, "tactus-viewer: could not lower the priority (nice %d)\n", nice_level);
  }

  boost::system::error_code ec;
  const net::ip::address address = net::ip::make_address(bind, ec);
  if (ec) {
    std::fprintf(stderr, "tactus-viewer: --bind '%s' is not an IP address\n", bind.c_str());
    return 2;
  }
  if (!address.is_loopback() && !allow_remote) {
    std::fprintf(stderr,
                 "tactus-viewer: refusing to listen on %s: it is not a loopback address and the "
                 "view has no authentication; use --bind 127.0.0.1, or add --allow-remote if you "
                 "mean it\n",
                 bind.c_str());
    return 2;
  }
  if (!tactus::shared::Segment::isValidName(segment)) {
    std::fprintf(stderr, "tactus-viewer: invalid --segment '%s'\n", segment.c_str());
    return 2;
  }

  std::vector<std::string> problems;
  const AssetTable assets = AssetTable::load(std::filesystem::path(web), problems);
  for (const auto& p : problems) std::fprintf(stderr, "tactus-viewer: %s\n", p.c_str());
  if (!assets.hasIndex()) {
    std::fprintf(stderr, "tactus-viewer: no built page in '%s' (build the tactus-viewer-web "
                 "target); serving a placeholder\n", web.c_str());
  }

  net::io_context ioc(1);
  Hub hub;
  SegmentWatcher watcher(segment);
  std::shared_ptr<Listener> listener;
  try {
    listener = std::make_shared<Listener>(
        ioc, tcp::endpoint(address, static_cast<unsigned short>(port)));
  } catch (const boost::system::system_error& e) {
    std::fprintf(stderr, "tactus-viewer: cannot listen on %s:%d: %s (choose another --port)\n",
                 bind.c_str(), port, e.what());
    return 1;
  }
  const HostPolicy hosts(address.to_string(), listener->port(), allow_remote);
  const ServerContext context{hub, assets, hosts};
  listener->run(context);
  Pump pump(ioc, watcher, hub, rate);
  pump.start();
  // SIGHUP (the terminal closed) stops the viewer like SIGINT and SIGTERM
  net::signal_set signals(ioc, SIGINT, SIGTERM, SIGHUP);
  signals.async_wait([&ioc](beast::error_code, int) { ioc.stop(); });

  const std::string host = address.is_v6() ? "[" + bind + "]" : bind;
  std::printf("tactus-viewer: http://%s:%u/ (segment '%s', read-only)\n", host.c_str(),
              listener->port(), segment.c_str());
  std::fflush(stdout);
  ioc.run();
  std::printf("tactus-viewer: stopped (%llu frames read, %llu attaches)\n",
              static_cast<unsigned long long>(watcher.framesRead()),
              static_cast<unsigned long long>(watcher.attachCount()));
  return 0;
}
