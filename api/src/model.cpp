// tactus::Model: a scene compiled once (model.h).
#include "tactus/model.h"

#include <fmt/format.h>

#include <stdexcept>

#include "model_data.h"
#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"
#include "tactus/sim/scene.h"

namespace tactus {
namespace detail {

const sim::TissueModel& ModelData::tissue(int i) const {
  if (i < 0 || i >= static_cast<int>(model->tissues.size())) {
    throw std::out_of_range(fmt::format("{}: no tissue {} (the model has {})", name, i,
                                        model->tissues.size()));
  }
  return model->tissues[static_cast<std::size_t>(i)];
}

}  // namespace detail

namespace {

std::shared_ptr<const detail::ModelData> compile(sim::SceneSpec spec, std::string name) {
  auto data = std::make_shared<detail::ModelData>();
  data->model = std::make_shared<const sim::SimulationModel>(sim::buildModel(spec));
  data->name = std::move(name);
  data->identity = sim::modelIdentity(*data->model);
  for (const sim::TissueModel& t : data->model->tissues) {
    data->surfaces.push_back(t.surface.triangles.empty() ? sim::extractSurface(t.mesh)
                                                         : t.surface);
  }
  for (int i = 0; i < sim::instrumentCount(data->model->spec); ++i) {
    const std::string& n = sim::instrumentSpec(data->model->spec, i).name;
    data->instrument_names.push_back(n.empty() ? fmt::format("instrument {}", i) : n);
  }
  return data;
}

}  // namespace

Model::Model(std::shared_ptr<const detail::ModelData> data) : data_(std::move(data)) {}

Model Model::fromFile(const std::filesystem::path& scene) {
  return Model(compile(sim::loadScene(scene), scene.filename().string()));
}

Model Model::fromString(std::string_view yaml, const std::filesystem::path& base_dir,
                        std::string_view name) {
  sim::SceneSpec spec = sim::parseScene(std::string(yaml), std::string(name), base_dir);
  spec.source = std::string(name);
  return Model(compile(std::move(spec), std::string(name)));
}

const std::string& Model::name() const { return data_->name; }
std::uint64_t Model::identity() const { return data_->identity; }
double Model::timeStep() const { return data_->model->h_s; }
double Model::duration() const { return data_->model->spec.duration_s; }
int Model::tissueCount() const { return static_cast<int>(data_->model->tissues.size()); }
const std::string& Model::tissueName(int tissue) const { return data_->tissue(tissue).name; }
int Model::nodeCount(int tissue) const { return data_->tissue(tissue).mesh.nodeCount(); }

Eigen::Map<const Eigen::Matrix3Xd> Model::restPositions(int tissue) const {
  const sim::TetMesh& mesh = data_->tissue(tissue).mesh;
  return {mesh.nodes.data(), 3, mesh.nodes.cols()};
}

std::span<const std::array<int, 4>> Model::tetrahedra(int tissue) const {
  return data_->tissue(tissue).mesh.tets;
}

std::span<const std::array<int, 3>> Model::surfaceTriangles(int tissue) const {
  data_->tissue(tissue);   // checks the index
  return data_->surfaces[static_cast<std::size_t>(tissue)].triangles;
}

std::span<const int> Model::fixedNodes(int tissue) const {
  return data_->tissue(tissue).fixed_nodes;
}

int Model::instrumentCount() const { return static_cast<int>(data_->instrument_names.size()); }

const std::string& Model::instrumentName(int instrument) const {
  if (instrument < 0 || instrument >= instrumentCount()) {
    throw std::out_of_range(fmt::format("{}: no instrument {} (the model has {})", name(),
                                        instrument, instrumentCount()));
  }
  return data_->instrument_names[static_cast<std::size_t>(instrument)];
}

}  // namespace tactus
