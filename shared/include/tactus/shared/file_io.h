#pragma once
// Checked file input and output for every reader and writer outside the real-time path, the
// process-wide stop request that lets SIGINT/SIGTERM interrupt loading, and the one helper that
// makes untrusted text safe to echo in a message.
//
// Reading: a file is opened with O_NONBLOCK|O_CLOEXEC (a FIFO never blocks the open) and fstat'ed
// before a byte is read: it must be a regular file no larger than the reader's limit. Reads go in
// bounded chunks, retry on EINTR and stop with tactus::Cancelled once a stop is requested.
//
// Writing: OutputFile writes a regular file through a temporary file in the same folder, checks
// every write, fsyncs and renames it into place on commit(); it refuses to replace an existing
// file unless told to overwrite. An existing non-regular target (a character device such as
// /dev/null or /dev/stdout, a FIFO with a reader) is written directly, with the same checks.

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>

#include "tactus/shared/error.h"

namespace tactus::shared {

/// Size limits of the files the readers accept [bytes].
inline constexpr std::uint64_t kMaxSceneBytes = std::uint64_t{1} << 20;             // 1 MiB
inline constexpr std::uint64_t kMaxTrajectoryCsvBytes = std::uint64_t{256} << 20;   // 256 MiB
inline constexpr std::uint64_t kMaxMeshBytes = std::uint64_t{1} << 30;              // 1 GiB
inline constexpr std::uint64_t kMaxFclibBytes = std::uint64_t{256} << 20;           // 256 MiB

/// The process-wide stop flag. Setting it is async-signal-safe (a lock-free atomic): signal
/// handlers call requestStop(); long loops outside the real-time path poll stopRequested().
std::atomic<bool>& stopFlag() noexcept;
inline void requestStop() noexcept { stopFlag().store(true, std::memory_order_relaxed); }
inline bool stopRequested() noexcept { return stopFlag().load(std::memory_order_relaxed); }
/// Throws tactus::Cancelled("interrupted (stop requested) while <during>") when a stop is pending.
void throwIfStopRequested(std::string_view during);

/// `text` made safe to echo in a message or a log: control bytes (C0, DEL, C1) and invalid UTF-8
/// are written as \xNN, and at most `max_chars` characters are kept (then "..." is appended).
std::string printable(std::string_view text, std::size_t max_chars = 64);

/// A file opened for reading after the checks above. Not copyable; closes on destruction.
class InputFile {
 public:
  /// Opens `path`; `what` names the kind of file in messages ("scene file", "mesh file").
  /// Throws FileError when it is missing, unreadable, a directory, not a regular file, or larger
  /// than `max_bytes`.
  InputFile(const std::filesystem::path& path, std::string_view what, std::uint64_t max_bytes);
  ~InputFile();
  InputFile(const InputFile&) = delete;
  InputFile& operator=(const InputFile&) = delete;

  /// Size at open time [bytes].
  std::uint64_t size() const noexcept { return size_; }
  /// The path as given, printable (for messages).
  const std::string& name() const noexcept { return name_; }

  /// Reads up to `n` bytes at the current position; fewer only at the end of the file.
  std::size_t read(void* buffer, std::size_t n);
  /// Reads exactly `n` bytes or throws FileError (the file is shorter).
  void readExact(void* buffer, std::size_t n);
  /// Everything from the current position to the end (at most the limit given at open).
  std::string readRest();
  /// The open descriptor of the checked file, for mapping it (mmap): map at most size() bytes.
  /// Reads through it bypass the position, the limit and the stop request above.
  int descriptor() const noexcept { return fd_; }

 private:
  int fd_ = -1;
  std::uint64_t size_ = 0;
  std::uint64_t max_bytes_ = 0;
  std::uint64_t consumed_ = 0;
  std::string name_;
  std::string what_;
};

/// The whole of a checked file (InputFile + readRest()).
std::string readFileChecked(const std::filesystem::path& path, std::string_view what,
                            std::uint64_t max_bytes);

/// The whole of a checked text file: as readFileChecked, but the first 4 KiB are read first and a
/// NUL byte there rejects the file as binary before the rest is read.
std::string readTextFileChecked(const std::filesystem::path& path, std::string_view what,
                                std::uint64_t max_bytes);

/// How an OutputFile may treat an existing target.
struct OutputOptions {
  bool overwrite = false;       ///< replace an existing regular file
  bool allow_special = true;    ///< write into an existing device or FIFO (else refuse)
  const char* overwrite_hint = nullptr;  ///< how to ask for overwrite ("pass --overwrite")
};

/// A file being written (see the header comment). Writes are buffered; write() never throws and
/// keeps the first error, which commit() reports. Destroying an uncommitted OutputFile removes
/// its temporary file and leaves the target untouched.
class OutputFile {
 public:
  /// Checks the target and creates the temporary file. Throws FileError when the target exists
  /// and overwriting is not allowed, is a directory, or the folder is not writable.
  OutputFile(const std::filesystem::path& path, std::string_view what, OutputOptions options = {});
  ~OutputFile();
  OutputFile(const OutputFile&) = delete;
  OutputFile& operator=(const OutputFile&) = delete;

  /// Appends bytes; false once any write failed (the first error is kept).
  bool write(std::string_view bytes) noexcept;
  /// Writes buffered bytes to the file; false once any write failed.
  bool flush() noexcept;
  /// True while every write so far succeeded.
  bool ok() const noexcept { return error_.empty(); }
  /// The first error ("PATH: write failed: No space left on device"), empty while ok().
  const std::string& error() const noexcept { return error_; }
  /// Flushes, fsyncs and closes, then renames the temporary file into place (a regular target).
  /// Throws FileError with the first error of any step; the target is then left untouched.
  void commit();

 private:
  void fail(const std::string& step, int err) noexcept;
  void discard() noexcept;
  bool writeAll(std::string_view bytes) noexcept;

  int fd_ = -1;
  bool direct_ = false;         ///< writing into an existing device/FIFO, no temporary file
  bool committed_ = false;
  OutputOptions options_;
  std::filesystem::path path_;
  std::string temp_path_;
  std::string name_;
  std::string what_;
  std::string buffer_;
  std::string error_;
};

/// Writes `data` to `path` through an OutputFile and commits it (throws FileError on failure).
void writeFileChecked(const std::filesystem::path& path, std::string_view data,
                      std::string_view what, OutputOptions options = {});

}  // namespace tactus::shared
