#pragma once
// A simulation state as a value (docs/api.md): everything a step reads that an earlier step
// wrote (time and step index, the device targets, per tissue positions, velocities, element
// rotations, the linear solve's factor and warm starts, the compliance's rotations, the
// collision memory; the god objects; the warm-start contact forces), as bytes with a header tying
// them to the model. Copy it, compare it, save it to a file, and hand it to
// Simulation::setState: the steps that follow give the same bits as those that followed
// Simulation::state() (docs/design.md, "State: copy, save, restore").

#include <cstdint>
#include <filesystem>
#include <string>

namespace tactus {

class State {
 public:
  State() = default;

  /// Reads a state file written by save(): a regular file of at most 2 GiB with a state header.
  /// Throws FileError (unreadable, not a regular file, too large) or StateError (not a state,
  /// another format version). Whether it belongs to a model is checked by setState.
  static State load(const std::filesystem::path& path);
  /// Writes the state through a temporary file renamed into place (every write checked). An
  /// existing file is replaced only when `overwrite`. Throws FileError.
  void save(const std::filesystem::path& path, bool overwrite = false) const;

  /// The bytes (header and fields) and a state from them (throws StateError on a bad header).
  const std::string& bytes() const { return bytes_; }
  static State fromBytes(std::string bytes);

  bool empty() const { return bytes_.empty(); }
  double time() const { return t_s_; }                 ///< simulated time [s]
  long stepIndex() const { return step_; }             ///< steps taken
  std::uint64_t modelIdentity() const { return model_identity_; }
  /// The scene it was saved from (its file name).
  const std::string& modelName() const { return model_name_; }

  /// Equal states have equal bytes (the same simulation continues from both alike).
  friend bool operator==(const State& a, const State& b) { return a.bytes_ == b.bytes_; }

 private:
  std::string bytes_;
  double t_s_ = 0.0;
  long step_ = 0;
  std::uint64_t model_identity_ = 0;
  std::string model_name_;
  std::string source_ = "state";   ///< names the state in messages (its file, once loaded)
  /// from bytes named `source` in messages (a file's path, or "state")
  static State fromBytes(std::string bytes, std::string source);
  friend class Simulation;
};

}  // namespace tactus
