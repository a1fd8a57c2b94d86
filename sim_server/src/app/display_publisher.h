#pragma once
// Simulation side of the live view: fills a display frame (tactus/shared/display.h) from a
// Simulation and publishes it into the segment's display part, at most `max_rate_hz` times per
// second (default 60). The surface triangles of every tissue are written once into the topology
// area at construction.
//
// Cost: a publish copies the surface vertex positions (float), their displacement magnitude, the
// von Mises stress averaged onto the surface vertices (every `stress_every`-th frame), the
// contacts and the tool primitives; nothing happens on the steps in between (one clock read).
// The stress reuses the element rotations of the last step (no polar decomposition):
// eps = sym(R^T F) - I, von Mises = 2 mu sqrt(3/2) |dev eps|, the corotated linear law of the FEM
// (FemBody::vonMises, which re-extracts R, costs ~10x more). It never waits for a viewer and does not know whether one is
// attached.
//
// Use (runner.cpp), after the SegmentHost has created the segment:
//   auto display = link ? std::make_unique<DisplayLink>(options.segment, sim) : nullptr;
//   ... each step, after link->publish(sim):  if (display) display->publish(sim, report);

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "tactus/shared/display.h"
#include "tactus/shared/segment.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {

struct DisplayOptions {
  double max_rate_hz = 60.0;         ///< frames per second at most
  int stress_every = 2;              ///< recompute the vertex stress every n-th frame (0: never)
};

class DisplayLink {
 public:
  /// Attaches to the segment `segment_name` (created by the SegmentHost of this process) and
  /// writes the topology. When the segment has no display part or the surface does not fit its
  /// capacity, logs a warning saying so and publishes nothing (enabled() is false). Throws
  /// tactus::SegmentError when the segment cannot be opened.
  DisplayLink(const std::string& segment_name, const Simulation& sim,
              const DisplayOptions& options = {});
  ~DisplayLink();

  bool enabled() const noexcept { return enabled_; }
  /// Surface vertices and triangles published (all tissues).
  int vertexCount() const noexcept { return vertex_count_; }
  int triangleCount() const noexcept { return triangle_count_; }

  /// Publishes a frame of the current state when one is due (rate limit); `report` (optional)
  /// adds the step time and solver figures. Returns true when a frame was published.
  bool publish(const Simulation& sim, const StepReport* report = nullptr);
  bool publish(const Simulation& sim, const StepReport& report) { return publish(sim, &report); }

  /// Same, ignoring the rate limit (tests).
  bool publishNow(const Simulation& sim, const StepReport* report = nullptr);

  std::uint64_t framesPublished() const noexcept { return seq_; }

 private:
  struct TissueMap {
    std::vector<int> nodes;          ///< surface vertex -> tissue node
    std::vector<int> tet_begin;      ///< CSR: tets incident to surface vertex i
    std::vector<int> tets;
    std::vector<Eigen::Matrix3d> dm_inv;   ///< per tet: inverse rest edge matrix
    double mu = 0.0;                       ///< Lame shear modulus [Pa]
    bool corotational = true;
  };
  void fillStress(const Simulation& sim);

  std::optional<shared::Segment> segment_;
  shared::DisplayPublisher publisher_;
  DisplayOptions options_;
  bool enabled_ = false;
  int vertex_count_ = 0;
  int triangle_count_ = 0;
  std::uint64_t topology_generation_ = 0;
  std::vector<TissueMap> tissues_;
  std::vector<std::uint64_t> staging_;     ///< the frame being composed (8-aligned)
  shared::DisplayFrameRef frame_;
  std::vector<double> von_mises_;          ///< per element scratch
  std::vector<float> stress_cache_;        ///< last vertex stresses (between recomputations)
  double max_stress_pa_ = 0.0;
  std::uint64_t seq_ = 0;
  std::int64_t last_ns_ = 0;
  std::int64_t period_ns_ = 0;
  bool warned_contacts_ = false;
};

}  // namespace tactus::sim
