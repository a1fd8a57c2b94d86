// tactus::HapticModel: the haptic local model on a ContactProblem (haptic_model.h).
#include "tactus/haptic_model.h"

#include <algorithm>
#include <array>
#include <memory>

namespace tactus {

struct HapticModel::Impl {
  LocalModelSettings settings;
  std::unique_ptr<SnapshotBuffer> slot;
  std::unique_ptr<haptic::OfflineLocalModel> model;
  int rows = 0;
  std::array<const Pose*, shared::kMaxInstruments> poses{};

  haptic::DevicePoses devicePoses(std::span<const Pose> given) {
    const std::size_t n = std::min<std::size_t>(given.size(), poses.size());
    for (std::size_t i = 0; i < poses.size(); ++i) poses[i] = i < n ? &given[i] : nullptr;
    return {poses.data(), poses.size()};
  }
};

HapticModel::HapticModel(const LocalModelSettings& settings) : impl_(std::make_unique<Impl>()) {
  settings.validate();
  impl_->settings = settings;
}
HapticModel::~HapticModel() = default;
HapticModel::HapticModel(HapticModel&&) noexcept = default;
HapticModel& HapticModel::operator=(HapticModel&&) noexcept = default;

PrepareStatus HapticModel::adopt(const ContactProblem& problem,
                                 std::span<const Pose> device_poses) {
  checkContactProblem(problem);
  Impl& m = *impl_;
  // capacity grows to the largest problem adopted (the model and its slot are sized once for it)
  const bool grow = !m.slot || problem.rows > m.slot->layout().max_rows ||
                    problem.contacts > m.slot->layout().max_contacts;
  if (grow) {
    m.model.reset();
    m.slot = std::make_unique<SnapshotBuffer>(problem.rows, problem.contacts);
    m.model = std::make_unique<haptic::OfflineLocalModel>(problem.rows, problem.contacts,
                                                          m.settings);
  }
  shared::SnapshotWriter writer = m.slot->writer();
  writeSnapshotSlot(problem, static_cast<std::uint64_t>(problem.step) + 1, 0, 0, writer);
  m.rows = problem.rows;
  return m.model->adopt(m.slot->view(), m.devicePoses(device_poses));
}

LocalModelResult HapticModel::solve(std::span<const Pose> device_poses, std::int64_t deadline_ns) {
  Impl& m = *impl_;
  if (!m.model) return {};
  return m.model->solve(m.devicePoses(device_poses), deadline_ns);
}

std::span<const double> HapticModel::forces() const {
  if (!impl_->model) return {};
  return {impl_->model->model().forces(), static_cast<std::size_t>(impl_->rows)};
}

const LocalModelSettings& HapticModel::settings() const { return impl_->settings; }

const haptic::PreparedSnapshot& HapticModel::prepared() const {
  static const haptic::PreparedSnapshot kNone;
  return impl_->model ? impl_->model->prepared() : kNone;
}

}  // namespace tactus
