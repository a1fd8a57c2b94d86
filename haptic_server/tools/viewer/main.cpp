// tactus-viewer: the live view of a running simulation in a browser.
//
// Attaches read-only to the segment (--segment), serves the built web page (three.js) over HTTP
// on 127.0.0.1 (--bind / --port; a non-loopback address needs --allow-remote) and streams over a
// WebSocket (/ws) the display frames as binary messages (segment_watcher.h) and a JSON status
// (rates, contacts, force, haptic period-error histogram) about 20 times a second. Follows the
// simulation across restarts. Nothing a client sends changes the simulation: the HTTP side
// answers GET/HEAD only and the WebSocket side ignores incoming messages.
//
// Single-threaded (one Asio io_context): a timer polls the segment at --rate Hz and broadcasts.
// A client that cannot keep up loses frames, never the topology, and never slows the others.
#include <CLI/CLI.hpp>
#include <sys/resource.h>

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <chrono>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

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

std::string mimeType(const std::filesystem::path& p) {
  const std::string e = p.extension().string();
  if (e == ".html") return "text/html; charset=utf-8";
  if (e == ".js" || e == ".mjs") return "text/javascript; charset=utf-8";
  if (e == ".css") return "text/css; charset=utf-8";
  if (e == ".json" || e == ".map") return "application/json";
  if (e == ".png") return "image/png";
  if (e == ".svg") return "image/svg+xml";
  return "application/octet-stream";
}

const char* kMissingPage =
    "<!doctype html><meta charset=utf-8><title>Tactus live view</title>"
    "<body style='font:14px sans-serif;margin:2em'><h1>Tactus live view</h1>"
    "<p>The web page has not been built. It is built with node and npm by the CMake target "
    "<code>tactus-viewer-web</code> (<code>ninja -C build tactus-viewer-web</code>), or by "
    "<code>scripts/view</code>; then reload.</p>"
    "<p>Raw status: <a href='/status.json'>/status.json</a></p>";

// One HTTP connection: static files, /status.json, and the upgrade to /ws.
class HttpSession : public std::enable_shared_from_this<HttpSession> {
 public:
  HttpSession(tcp::socket&& socket, Hub& hub, std::filesystem::path web)
      : stream_(std::move(socket)), hub_(hub), web_(std::move(web)) {}
  void run() { doRead(); }

 private:
  void doRead() {
    req_ = {};
    stream_.expires_after(std::chrono::seconds(30));
    http::async_read(stream_, buffer_, req_,
                     beast::bind_front_handler(&HttpSession::onRead, shared_from_this()));
  }

  void onRead(beast::error_code ec, std::size_t) {
    if (ec) {
      beast::error_code ignored;
      stream_.socket().shutdown(tcp::socket::shutdown_send, ignored);
      return;
    }
    if (websocket::is_upgrade(req_)) {
      if (req_.target() != "/ws") {
        reply(http::status::not_found, "text/plain", "WebSocket endpoint is /ws\n");
        return;
      }
      stream_.expires_never();
      std::make_shared<WsSession>(stream_.release_socket(), hub_)->run(std::move(req_));
      return;
    }
    if (req_.method() != http::verb::get && req_.method() != http::verb::head) {
      reply(http::status::method_not_allowed, "text/plain",
            "the live view is read-only: GET and HEAD only\n");
      return;
    }
    std::string target(req_.target());
    if (const auto q = target.find('?'); q != std::string::npos) target.resize(q);
    if (target == "/status.json") {
      reply(http::status::ok, "application/json", hub_.status());
      return;
    }
    if (target == "/" || target.empty()) target = "/index.html";
    if (target.find("..") != std::string::npos || target[0] != '/') {
      reply(http::status::bad_request, "text/plain", "bad path\n");
      return;
    }
    const std::filesystem::path file = web_ / target.substr(1);
    std::ifstream in(file, std::ios::binary);
    if (!in) {
      if (target == "/index.html") {
        reply(http::status::ok, "text/html; charset=utf-8", kMissingPage);
      } else {
        reply(http::status::not_found, "text/plain", "not found\n");
      }
      return;
    }
    std::ostringstream body;
    body << in.rdbuf();
    reply(http::status::ok, mimeType(file), body.str());
  }

  void reply(http::status status, const std::string& type, std::string body) {
    auto res = std::make_shared<http::response<http::string_body>>(status, req_.version());
    res->set(http::field::server, "tactus-viewer");
    res->set(http::field::content_type, type);
    res->set(http::field::cache_control, "no-store");
    res->keep_alive(req_.keep_alive());
    const bool head = req_.method() == http::verb::head;
    res->body() = head ? std::string() : std::move(body);
    res->prepare_payload();
    if (head) res->content_length(body.size());
    http::async_write(stream_, *res,
                      [self = shared_from_this(), res](beast::error_code ec, std::size_t) {
                        if (ec || !res->keep_alive()) {
                          beast::error_code ignored;
                          self->stream_.socket().shutdown(tcp::socket::shutdown_send, ignored);
                          return;
                        }
                        self->doRead();
                      });
  }

  beast::tcp_stream stream_;
  Hub& hub_;
  std::filesystem::path web_;
  beast::flat_buffer buffer_;
  http::request<http::string_body> req_;
};

class Listener : public std::enable_shared_from_this<Listener> {
 public:
  Listener(net::io_context& ioc, tcp::endpoint at, Hub& hub, std::filesystem::path web)
      : ioc_(ioc), acceptor_(ioc), hub_(hub), web_(std::move(web)) {
    acceptor_.open(at.protocol());
    acceptor_.set_option(net::socket_base::reuse_address(true));
    acceptor_.bind(at);
    acceptor_.listen(net::socket_base::max_listen_connections);
  }
  unsigned short port() const { return acceptor_.local_endpoint().port(); }
  void run() { doAccept(); }

 private:
  void doAccept() {
    acceptor_.async_accept(net::make_strand(ioc_), [self = shared_from_this()](
                                                       beast::error_code ec, tcp::socket s) {
      if (!ec) std::make_shared<HttpSession>(std::move(s), self->hub_, self->web_)->run();
      self->doAccept();
    });
  }
  net::io_context& ioc_;
  tcp::acceptor acceptor_;
  Hub& hub_;
  std::filesystem::path web_;
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
  CLI::App app{"Tactus live view: serves a browser page showing the running simulation "
               "(read-only)"};
  std::string segment = "tactus";
  std::string bind = "127.0.0.1";
  int port = 8090;
  bool allow_remote = false;
  double rate = 60.0;
  std::string web = TACTUS_VIEWER_WEB_DIR;
  int nice_level = 10;
  app.add_option("--segment", segment, "Segment name of the running simulation")
      ->capture_default_str();
  app.add_option("--port", port, "TCP port (0: any free port; the URL is printed)")
      ->capture_default_str()
      ->check(CLI::Range(0, 65535));
  app.add_option("--bind", bind, "Address to listen on (loopback unless --allow-remote)")
      ->capture_default_str();
  app.add_flag("--allow-remote", allow_remote,
               "Allow a non-loopback --bind address (anyone who can reach it sees the view)");
  app.add_option("--rate", rate, "Frames per second streamed at most")
      ->capture_default_str()
      ->check(CLI::Range(1.0, 240.0));
  app.add_option("--web-dir", web, "Directory of the built page (index.html, app.js)")
      ->capture_default_str();
  app.add_option("--nice", nice_level, "Scheduling niceness of the viewer (it yields the CPU to "
                 "the simulation)")
      ->capture_default_str()
      ->check(CLI::Range(0, 19));
  CLI11_PARSE(app, argc, argv);
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

  net::io_context ioc(1);
  Hub hub;
  SegmentWatcher watcher(segment);
  std::shared_ptr<Listener> listener;
  try {
    listener = std::make_shared<Listener>(ioc, tcp::endpoint(address, static_cast<unsigned short>(port)),
                                          hub, std::filesystem::path(web));
  } catch (const boost::system::system_error& e) {
    std::fprintf(stderr, "tactus-viewer: cannot listen on %s:%d: %s (choose another --port)\n",
                 bind.c_str(), port, e.what());
    return 1;
  }
  listener->run();
  Pump pump(ioc, watcher, hub, rate);
  pump.start();
  net::signal_set signals(ioc, SIGINT, SIGTERM);
  signals.async_wait([&ioc](beast::error_code, int) { ioc.stop(); });

  const std::string host = address.is_v6() ? "[" + bind + "]" : bind;
  if (!std::filesystem::exists(std::filesystem::path(web) / "index.html")) {
    std::fprintf(stderr, "tactus-viewer: no built page in '%s' (build the tactus-viewer-web "
                 "target); serving a placeholder\n", web.c_str());
  }
  std::printf("tactus-viewer: http://%s:%u/ (segment '%s', read-only)\n", host.c_str(),
              listener->port(), segment.c_str());
  std::fflush(stdout);
  ioc.run();
  std::printf("tactus-viewer: stopped (%llu frames read, %llu attaches)\n",
              static_cast<unsigned long long>(watcher.framesRead()),
              static_cast<unsigned long long>(watcher.attachCount()));
  return 0;
}
