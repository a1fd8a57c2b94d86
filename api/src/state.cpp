// tactus::State: a simulation state as a value, saved and read through checked files (state.h).
#include "tactus/state.h"

#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"
#include "tactus/sim/pipeline.h"

namespace tactus {

namespace {
constexpr std::uint64_t kMaxStateFileBytes = std::uint64_t{2} << 30;   // 2 GiB
}

State State::fromBytes(std::string bytes, std::string source) {
  const sim::StateHeader h = sim::readStateHeader(bytes, source);
  State s;
  s.bytes_ = std::move(bytes);
  s.t_s_ = h.t_s;
  s.step_ = h.step;
  s.model_identity_ = h.model_identity;
  s.model_name_ = h.model_name;
  s.source_ = std::move(source);
  return s;
}

State State::fromBytes(std::string bytes) { return fromBytes(std::move(bytes), "state"); }

State State::load(const std::filesystem::path& path) {
  return fromBytes(shared::readFileChecked(path, "state file", kMaxStateFileBytes), path.string());
}

void State::save(const std::filesystem::path& path, bool overwrite) const {
  if (bytes_.empty()) throw StateError(path.string() + ": an empty State has nothing to save");
  shared::OutputOptions options;
  options.overwrite = overwrite;
  options.overwrite_hint = "pass overwrite=true";
  shared::writeFileChecked(path, bytes_, "state file", options);
}

}  // namespace tactus
