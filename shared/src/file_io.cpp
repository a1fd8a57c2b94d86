// Checked file input and output, the stop request, printable message text.
#include "tactus/shared/file_io.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

namespace tactus::shared {
namespace {

std::atomic<bool> g_stop{false};
static_assert(std::atomic<bool>::is_always_lock_free, "the stop flag is set in signal handlers");

constexpr std::size_t kReadChunk = std::size_t{8} << 20;   // bytes per read() call
constexpr std::size_t kWriteBuffer = std::size_t{64} << 10;

std::string errnoText(int err) {
  std::string s = std::strerror(err);
  if (err == ENOSPC) s += " (disk full?)";
  return s;
}

std::string sizeText(std::uint64_t bytes) {
  char buf[64];
  if (bytes >= (std::uint64_t{1} << 20)) {
    std::snprintf(buf, sizeof(buf), "%llu bytes (%.1f MiB)",
                  static_cast<unsigned long long>(bytes), static_cast<double>(bytes) / 1048576.0);
  } else {
    std::snprintf(buf, sizeof(buf), "%llu bytes", static_cast<unsigned long long>(bytes));
  }
  return buf;
}

void appendHex(std::string* out, unsigned char c) {
  static const char kDigits[] = "0123456789abcdef";
  *out += "\\x";
  *out += kDigits[c >> 4];
  *out += kDigits[c & 15];
}

// Length of a valid UTF-8 sequence at s[i] encoding a printable code point (>= U+00A0), else 0.
std::size_t printableUtf8(std::string_view s, std::size_t i) {
  const auto b = [&](std::size_t k) { return static_cast<unsigned char>(s[i + k]); };
  const unsigned char c = b(0);
  std::size_t len = 0;
  std::uint32_t cp = 0;
  if (c >= 0xc2 && c <= 0xdf) {
    len = 2;
    cp = c & 0x1f;
  } else if (c >= 0xe0 && c <= 0xef) {
    len = 3;
    cp = c & 0x0f;
  } else if (c >= 0xf0 && c <= 0xf4) {
    len = 4;
    cp = c & 0x07;
  } else {
    return 0;
  }
  if (i + len > s.size()) return 0;
  for (std::size_t k = 1; k < len; ++k) {
    if ((b(k) & 0xc0) != 0x80) return 0;
    cp = (cp << 6) | (b(k) & 0x3f);
  }
  const bool overlong = (len == 3 && cp < 0x800) || (len == 4 && cp < 0x10000);
  const bool surrogate = cp >= 0xd800 && cp <= 0xdfff;
  if (overlong || surrogate || cp > 0x10ffff || cp < 0xa0) return 0;
  return len;
}

void closeQuietly(int fd) noexcept {
  if (fd >= 0) ::close(fd);
}

}  // namespace

std::atomic<bool>& stopFlag() noexcept { return g_stop; }

void throwIfStopRequested(std::string_view during) {
  if (stopRequested()) {
    throw Cancelled("interrupted (stop requested) while " + std::string(during));
  }
}

std::string printable(std::string_view text, std::size_t max_chars) {
  std::string out;
  out.reserve(std::min(text.size(), max_chars) + 8);
  std::size_t chars = 0;
  std::size_t i = 0;
  while (i < text.size()) {
    if (chars == max_chars) {
      out += "...";
      break;
    }
    const auto c = static_cast<unsigned char>(text[i]);
    if (c < 0x20 || c == 0x7f) {
      appendHex(&out, c);
      ++i;
    } else if (c < 0x80) {
      out += static_cast<char>(c);
      ++i;
    } else if (const std::size_t len = printableUtf8(text, i); len > 0) {
      out.append(text.substr(i, len));
      i += len;
    } else {
      appendHex(&out, c);
      ++i;
    }
    ++chars;
  }
  return out;
}

// ------------------------------------------------------------------------------------------------
// Input

InputFile::InputFile(const std::filesystem::path& path, std::string_view what,
                     std::uint64_t max_bytes)
    : max_bytes_(max_bytes), name_(printable(path.string(), 256)), what_(what) {
  fd_ = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC | O_NOCTTY);
  if (fd_ < 0) {
    const int err = errno;
    throw FileError(name_ + ": cannot open " + what_ + ": " + errnoText(err) +
                    (err == ENOENT ? " (check the path)" : ""));
  }
  struct stat st {};
  std::string problem;
  if (::fstat(fd_, &st) != 0) {
    const int err = errno;
    problem = "cannot be examined: " + errnoText(err);
  } else if (S_ISDIR(st.st_mode)) {
    problem = "is a directory, not a " + what_;
  } else if (!S_ISREG(st.st_mode)) {
    problem = "is not a regular file (a FIFO, socket or device); give a regular " + what_;
  } else if (static_cast<std::uint64_t>(st.st_size) > max_bytes) {
    problem = "is " + sizeText(static_cast<std::uint64_t>(st.st_size)) + ", more than the " +
              sizeText(max_bytes) + " a " + what_ + " may have";
  } else {
    const int flags = ::fcntl(fd_, F_GETFL);
    if (flags >= 0) ::fcntl(fd_, F_SETFL, flags & ~O_NONBLOCK);
    size_ = static_cast<std::uint64_t>(st.st_size);
    return;
  }
  closeQuietly(fd_);
  fd_ = -1;
  throw FileError(name_ + ": " + problem);
}

InputFile::~InputFile() { closeQuietly(fd_); }

std::size_t InputFile::read(void* buffer, std::size_t n) {
  auto* out = static_cast<char*>(buffer);
  std::size_t done = 0;
  while (done < n) {
    throwIfStopRequested("reading " + name_);
    const std::size_t want = std::min(n - done, kReadChunk);
    const ssize_t r = ::read(fd_, out + done, want);
    if (r < 0) {
      const int err = errno;
      if (err == EINTR) continue;
      throw FileError(name_ + ": read error: " + errnoText(err));
    }
    if (r == 0) break;
    done += static_cast<std::size_t>(r);
    consumed_ += static_cast<std::uint64_t>(r);
    if (consumed_ > max_bytes_) {
      throw FileError(name_ + ": " + what_ + " grew beyond " + sizeText(max_bytes_) +
                      " while being read");
    }
  }
  return done;
}

void InputFile::readExact(void* buffer, std::size_t n) {
  if (read(buffer, n) != n) {
    throw FileError(name_ + ": unexpected end of file (truncated " + what_ + "?)");
  }
}

std::string InputFile::readRest() {
  std::string out;
  out.reserve(static_cast<std::size_t>(size_ > consumed_ ? size_ - consumed_ : 0));
  std::vector<char> chunk(std::min<std::uint64_t>(kReadChunk, std::max<std::uint64_t>(size_, 4096)));
  for (;;) {
    const std::size_t got = read(chunk.data(), chunk.size());
    out.append(chunk.data(), got);
    if (got < chunk.size()) break;
  }
  return out;
}

std::string readFileChecked(const std::filesystem::path& path, std::string_view what,
                            std::uint64_t max_bytes) {
  InputFile f(path, what, max_bytes);
  return f.readRest();
}

std::string readTextFileChecked(const std::filesystem::path& path, std::string_view what,
                                std::uint64_t max_bytes) {
  InputFile f(path, what, max_bytes);
  std::string text(static_cast<std::size_t>(std::min<std::uint64_t>(f.size(), 4096)), '\0');
  text.resize(f.read(text.data(), text.size()));
  if (text.find('\0') != std::string::npos) {
    throw FileError(f.name() + ": holds NUL bytes: a binary file, not a " + std::string(what));
  }
  text += f.readRest();
  return text;
}

// ------------------------------------------------------------------------------------------------
// Output

OutputFile::OutputFile(const std::filesystem::path& path, std::string_view what,
                       OutputOptions options)
    : options_(options), path_(path), name_(printable(path.string(), 256)), what_(what) {
  struct stat st {};
  if (::stat(path.c_str(), &st) == 0) {
    if (S_ISDIR(st.st_mode)) throw FileError(name_ + ": is a directory, not a " + what_);
    if (!S_ISREG(st.st_mode)) {
      if (!options.allow_special) {
        throw FileError(name_ + ": exists and is not a regular file; not replaced");
      }
      // a device or FIFO: write into it (O_NONBLOCK: a FIFO without a reader fails, not hangs)
      fd_ = ::open(path.c_str(), O_WRONLY | O_NONBLOCK | O_CLOEXEC | O_NOCTTY);
      if (fd_ < 0) {
        const int err = errno;
        throw FileError(name_ + ": cannot open for writing: " + errnoText(err) +
                        (err == ENXIO ? " (a FIFO nobody reads)" : ""));
      }
      const int flags = ::fcntl(fd_, F_GETFL);
      if (flags >= 0) ::fcntl(fd_, F_SETFL, flags & ~O_NONBLOCK);
      direct_ = true;
      return;
    }
    if (!options.overwrite) {
      throw FileError(name_ + ": " + what_ + " exists; not overwritten without an explicit "
                      "request (remove it, choose another name or " +
                      (options.overwrite_hint != nullptr ? std::string(options.overwrite_hint)
                                                         : std::string("ask to overwrite")) +
                      ")");
    }
  } else if (const int err = errno; err != ENOENT) {
    throw FileError(name_ + ": cannot examine the target: " + errnoText(err));
  }
  const std::string file_name = path.filename().string();
  if (file_name.empty() || file_name == "." || file_name == "..") {
    throw FileError(name_ + ": not a file name");
  }
  const std::filesystem::path dir = path.has_parent_path() ? path.parent_path() : ".";
  std::string tmpl = (dir / ("." + file_name + ".tmp-XXXXXX")).string();
  fd_ = ::mkostemp(tmpl.data(), O_CLOEXEC);
  if (fd_ < 0) {
    const int err = errno;
    throw FileError(name_ + ": cannot create a file in " + printable(dir.string(), 256) + ": " +
                    errnoText(err) + (err == ENOENT ? " (does the folder exist?)" : ""));
  }
  temp_path_ = tmpl;
  ::fchmod(fd_, 0644);
}

OutputFile::~OutputFile() {
  if (!committed_) discard();
}

void OutputFile::fail(const std::string& step, int err) noexcept {
  try {
    if (error_.empty()) error_ = name_ + ": " + step + ": " + errnoText(err);
  } catch (...) {
    // out of memory while formatting: keep a fixed message
    if (error_.empty()) error_ = "write failed";
  }
}

void OutputFile::discard() noexcept {
  closeQuietly(fd_);
  fd_ = -1;
  if (!temp_path_.empty()) ::unlink(temp_path_.c_str());
  temp_path_.clear();
}

bool OutputFile::writeAll(std::string_view bytes) noexcept {
  std::size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t r = ::write(fd_, bytes.data() + done, bytes.size() - done);
    if (r < 0) {
      const int err = errno;
      if (err == EINTR) continue;
      fail("write failed", err);
      return false;
    }
    if (r == 0) {
      fail("write failed", EIO);
      return false;
    }
    done += static_cast<std::size_t>(r);
  }
  return true;
}

bool OutputFile::write(std::string_view bytes) noexcept {
  if (!ok() || fd_ < 0) return false;
  if (buffer_.size() + bytes.size() >= kWriteBuffer) {
    if (!flush()) return false;
    if (bytes.size() >= kWriteBuffer) return writeAll(bytes);  // large blocks: no copy
  }
  try {
    buffer_.append(bytes);
  } catch (...) {
    fail("write failed", ENOMEM);
    return false;
  }
  return true;
}

bool OutputFile::flush() noexcept {
  if (!ok() || fd_ < 0) return false;
  const bool written = writeAll(buffer_);
  buffer_.clear();
  return written;
}

void OutputFile::commit() {
  if (committed_) return;
  if (fd_ < 0 && ok()) fail("write failed", EBADF);
  flush();
  if (ok() && !direct_ && ::fsync(fd_) != 0) {
    const int err = errno;
    fail("fsync failed", err);
  }
  if (fd_ >= 0) {
    if (::close(fd_) != 0 && ok()) {
      const int err = errno;
      fail("close failed", err);
    }
    fd_ = -1;
  }
  if (ok() && !direct_) {
    int rc = 0;
    if (options_.overwrite) {
      rc = ::rename(temp_path_.c_str(), path_.c_str());
    } else {
      rc = ::renameat2(AT_FDCWD, temp_path_.c_str(), AT_FDCWD, path_.c_str(), RENAME_NOREPLACE);
      if (rc != 0 && (errno == EINVAL || errno == ENOSYS)) {
        // no RENAME_NOREPLACE here: a hard link never replaces either
        rc = ::link(temp_path_.c_str(), path_.c_str());
        if (rc == 0) ::unlink(temp_path_.c_str());
      }
    }
    if (rc != 0) {
      const int err = errno;
      fail(err == EEXIST ? "appeared while it was written; not overwritten" : "rename failed",
           err);
    } else {
      temp_path_.clear();
      // make the rename itself durable
      const std::filesystem::path dir = path_.has_parent_path() ? path_.parent_path() : ".";
      const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
      if (dfd >= 0) {
        ::fsync(dfd);
        ::close(dfd);
      }
    }
  }
  if (!ok()) {
    discard();
    committed_ = true;
    throw FileError(error_);
  }
  committed_ = true;
}

void writeFileChecked(const std::filesystem::path& path, std::string_view data,
                      std::string_view what, OutputOptions options) {
  OutputFile out(path, what, options);
  out.write(data);
  out.commit();
}

}  // namespace tactus::shared
