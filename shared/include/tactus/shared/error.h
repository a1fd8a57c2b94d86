#pragma once
// Exception hierarchy used outside the real-time path. Inside the haptic tick and the simulation
// step, faults are reported through status codes and counters instead (never exceptions).

#include <stdexcept>
#include <string>

namespace tactus {

/// Base of every Tactus exception. The message says what went wrong and, where it can, what to do.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A scene file is malformed or out of range. The message names file, line, column and field path.
class SceneError : public Error {
 public:
  using Error::Error;
};

/// A mesh file cannot be read or describes an unusable mesh. The message names file and line.
class MeshError : public Error {
 public:
  using Error::Error;
};

/// A haptic device backend failed to load, open, calibrate or enable.
class DeviceError : public Error {
 public:
  using Error::Error;
};

/// The shared-memory segment cannot be created, opened or does not match this build.
class SegmentError : public Error {
 public:
  using Error::Error;
};

/// Real-time set-up (scheduling, affinity, memory locking) failed where it was required.
class RealtimeError : public Error {
 public:
  using Error::Error;
};

/// A numerical method failed (factorisation of a non-positive-definite matrix, ...).
class NumericalError : public Error {
 public:
  using Error::Error;
};

/// A file cannot be opened, is not a regular file, is too large, or a read or write failed
/// (shared/file_io.h).
class FileError : public Error {
 public:
  using Error::Error;
};

/// Work stopped because SIGINT/SIGTERM requested a stop (see shared::requestStop()).
class Cancelled : public Error {
 public:
  using Error::Error;
};

/// A saved simulation state cannot be restored: truncated or corrupt bytes, another format
/// version, or a state of another model. The message names the state and the field.
class StateError : public Error {
 public:
  using Error::Error;
};

}  // namespace tactus
