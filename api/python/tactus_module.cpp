// The Python module `tactus` (pybind11 + numpy; docs/api.md "Python"): the public C++ API
// (api/include/tactus) as Python classes. Arrays the simulation's state owns (node positions and
// velocities, the model's meshes) are numpy views of that memory, read-only, kept alive by the
// object they come from; everything else (contact problems, reactions, results) is copied into
// Python-owned objects, whose arrays are again views of them. step() releases the GIL.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <time.h>

#include <chrono>
#include <string>
#include <utility>

#include "tactus/contact.h"
#include "tactus/haptic_model.h"
#include "tactus/tactus.h"

namespace py = pybind11;
using namespace pybind11::literals;

namespace {

using RowMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// A numpy view of `rows` x `cols` doubles at `data` (row stride `row_stride` doubles), kept
// alive by `owner`; read-only unless `writeable`.
py::array view(const double* data, py::ssize_t rows, py::ssize_t cols, py::ssize_t row_stride,
               py::handle owner, bool writeable = false) {
  py::array a(py::dtype::of<double>(), {rows, cols},
              {row_stride * static_cast<py::ssize_t>(sizeof(double)),
               static_cast<py::ssize_t>(sizeof(double))},
              data, owner);
  if (!writeable) py::detail::array_proxy(a.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
  return a;
}

py::array vectorView(const double* data, py::ssize_t n, py::handle owner, bool writeable) {
  py::array a(py::dtype::of<double>(), {n}, {static_cast<py::ssize_t>(sizeof(double))}, data,
              owner);
  if (!writeable) py::detail::array_proxy(a.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
  return a;
}

template <class T>
py::array intView(const T* data, py::ssize_t rows, py::ssize_t cols, py::handle owner) {
  std::vector<py::ssize_t> shape{rows}, strides{static_cast<py::ssize_t>(cols * sizeof(T))};
  if (cols > 1) {
    shape.push_back(cols);
    strides.push_back(static_cast<py::ssize_t>(sizeof(T)));
  }
  py::array a(py::dtype::of<T>(), shape, strides, data, owner);
  py::detail::array_proxy(a.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
  return a;
}

Eigen::Vector3d vec3(const py::object& o, const char* what) {
  const auto v = o.cast<Eigen::VectorXd>();
  if (v.size() != 3) throw py::value_error(std::string(what) + " must have 3 entries");
  return v;
}

tactus::Pose makePose(const py::object& position, const py::object& quaternion_wxyz) {
  tactus::Pose p;
  p.pos_m = vec3(position, "position");
  const auto q = quaternion_wxyz.cast<Eigen::VectorXd>();
  if (q.size() != 4) throw py::value_error("quaternion must be 4 entries (w, x, y, z)");
  p.rot = Eigen::Quaterniond(q[0], q[1], q[2], q[3]);
  return p;
}

Eigen::Vector4d wxyz(const Eigen::Quaterniond& q) { return {q.w(), q.x(), q.y(), q.z()}; }

std::vector<tactus::Pose> poses(const py::object& o) {
  std::vector<tactus::Pose> out;
  if (o.is_none()) return out;
  if (py::isinstance<tactus::Pose>(o)) {
    out.push_back(o.cast<tactus::Pose>());
    return out;
  }
  for (const py::handle h : o) out.push_back(h.cast<tactus::Pose>());
  return out;
}

std::int64_t threadCpuNs() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

// Arrays of a ContactProblem as views of the (Python-owned) problem.
py::array points(const std::vector<Eigen::Vector3d>& v, py::handle owner) {
  return view(v.empty() ? nullptr : v[0].data(), static_cast<py::ssize_t>(v.size()), 3, 3, owner);
}

tactus::ContactProblem problemFromArrays(const RowMatrix& W, const Eigen::VectorXd& delta_free,
                                         const py::object& mu, const py::object& row_offset,
                                         const py::object& f) {
  tactus::ContactProblem p;
  p.rows = static_cast<int>(delta_free.size());
  p.W = W;
  p.delta_free = delta_free;
  if (row_offset.is_none()) {
    if (p.rows % 3 != 0) {
      throw py::value_error("rows is not a multiple of 3: give row_offset (1 or 3 rows per contact)");
    }
    p.contacts = p.rows / 3;
    for (int c = 0; c <= p.contacts; ++c) p.row_offset.push_back(3 * c);
  } else {
    p.row_offset = row_offset.cast<std::vector<int>>();
    p.contacts = static_cast<int>(p.row_offset.size()) - 1;
  }
  if (py::isinstance<py::float_>(mu) || py::isinstance<py::int_>(mu)) {
    p.mu.assign(static_cast<std::size_t>(std::max(0, p.contacts)), mu.cast<double>());
  } else {
    p.mu = mu.cast<std::vector<double>>();
  }
  if (!f.is_none()) p.f = f.cast<Eigen::VectorXd>();
  tactus::checkContactProblem(p);
  return p;
}

}  // namespace

PYBIND11_MODULE(tactus, m) {
  m.doc() = "Tactus: soft-tissue simulation with frictional contact for haptics (docs/api.md)";
  m.attr("__version__") = TACTUS_VERSION;

  // errors: tactus.Error (a RuntimeError) and its kinds; the last registered is tried first
  const auto error = py::register_exception<tactus::Error>(m, "Error", PyExc_RuntimeError);
  py::register_exception<tactus::SceneError>(m, "SceneError", error.ptr());
  py::register_exception<tactus::MeshError>(m, "MeshError", error.ptr());
  py::register_exception<tactus::FileError>(m, "FileError", error.ptr());
  py::register_exception<tactus::StateError>(m, "StateError", error.ptr());
  py::register_exception<tactus::NumericalError>(m, "NumericalError", error.ptr());

  // ---- plain data ----
  py::class_<tactus::Pose>(m, "Pose", "A position [m] and an orientation (unit quaternion w, x, y, z)")
      .def(py::init([](const py::object& position, const py::object& quaternion) {
             return makePose(position, quaternion);
           }),
           "position"_a = Eigen::Vector3d::Zero().eval(),
           "quaternion"_a = Eigen::Vector4d(1, 0, 0, 0).eval())
      .def_property(
          "position", [](const tactus::Pose& p) { return Eigen::Vector3d(p.pos_m); },
          [](tactus::Pose& p, const py::object& v) { p.pos_m = vec3(v, "position"); })
      .def_property(
          "quaternion", [](const tactus::Pose& p) { return wxyz(p.rot); },
          [](tactus::Pose& p, const py::object& q) { p = makePose(py::cast(p.pos_m), q); })
      .def("__repr__", [](const tactus::Pose& p) {
        return "Pose(position=[" + std::to_string(p.pos_m.x()) + ", " +
               std::to_string(p.pos_m.y()) + ", " + std::to_string(p.pos_m.z()) +
               "], quaternion=[" + std::to_string(p.rot.w()) + ", " + std::to_string(p.rot.x()) +
               ", " + std::to_string(p.rot.y()) + ", " + std::to_string(p.rot.z()) + "])";
      });

  py::class_<tactus::DeviceTarget>(m, "DeviceTarget",
                                   "What drives an instrument: pose, twist [v; w], jaw opening")
      .def(py::init([](const tactus::Pose& pose, const py::object& twist, double gripper) {
             tactus::DeviceTarget t;
             t.pose = pose;
             if (!twist.is_none()) {
               const auto w = twist.cast<Eigen::VectorXd>();
               if (w.size() != 6) throw py::value_error("twist must have 6 entries");
               t.twist = w;
             }
             t.gripper_opening = gripper;
             return t;
           }),
           "pose"_a = tactus::Pose(), "twist"_a = py::none(), "gripper_opening"_a = 1.0)
      .def_readwrite("pose", &tactus::DeviceTarget::pose)
      .def_property(
          "twist", [](const tactus::DeviceTarget& t) { return tactus::Vector6d(t.twist); },
          [](tactus::DeviceTarget& t, const tactus::Vector6d& w) { t.twist = w; })
      .def_readwrite("gripper_opening", &tactus::DeviceTarget::gripper_opening);

  py::class_<tactus::NsgsResult>(m, "NsgsResult", "What an NSGS solve did")
      .def_property_readonly("status",
                             [](const tactus::NsgsResult& r) {
                               return std::string(tactus::shared::toString(r.status));
                             })
      .def_property_readonly("converged",
                             [](const tactus::NsgsResult& r) {
                               return r.status == tactus::NsgsStatus::kConverged;
                             })
      .def_readonly("sweeps", &tactus::NsgsResult::sweeps)
      .def_readonly("error", &tactus::NsgsResult::error)
      .def_readonly("sor", &tactus::NsgsResult::sor)
      .def_readonly("relaxations", &tactus::NsgsResult::relaxations)
      .def_readonly("ill_posed_contacts", &tactus::NsgsResult::ill_posed_contacts)
      .def_readonly("elapsed_ns", &tactus::NsgsResult::elapsed_ns)
      .def("__repr__", [](const tactus::NsgsResult& r) {
        return "NsgsResult(status=" + std::string(tactus::shared::toString(r.status)) +
               ", sweeps=" + std::to_string(r.sweeps) + ", error=" + std::to_string(r.error) + ")";
      });

  py::class_<tactus::NsgsSettings>(m, "NsgsSettings", "NSGS settings (tactus/shared/nsgs.h)")
      .def(py::init([](double tolerance, int max_sweeps, double sor, int anderson_depth) {
             tactus::NsgsSettings s;
             s.tolerance = tolerance;
             s.max_sweeps = max_sweeps;
             s.sor = sor;
             s.anderson_depth = anderson_depth;
             return s;
           }),
           "tolerance"_a = 1e-6, "max_sweeps"_a = 500, "sor"_a = 1.0, "anderson_depth"_a = 0)
      .def_readwrite("tolerance", &tactus::NsgsSettings::tolerance)
      .def_readwrite("max_sweeps", &tactus::NsgsSettings::max_sweeps)
      .def_readwrite("sor", &tactus::NsgsSettings::sor)
      .def_readwrite("anderson_depth", &tactus::NsgsSettings::anderson_depth)
      .def_readwrite("stall_sweeps", &tactus::NsgsSettings::stall_sweeps)
      .def_readwrite("time_budget_ns", &tactus::NsgsSettings::time_budget_ns);

  py::class_<tactus::StageTimes>(m, "StageTimes", "Wall time per stage of a step [s]")
      .def_readonly("free_motion_s", &tactus::StageTimes::free_motion_s)
      .def_readonly("detect_collisions_s", &tactus::StageTimes::detect_collisions_s)
      .def_readonly("update_compliance_s", &tactus::StageTimes::update_compliance_s)
      .def_readonly("build_w_s", &tactus::StageTimes::build_w_s)
      .def_readonly("solve_contacts_s", &tactus::StageTimes::solve_contacts_s)
      .def_readonly("constrained_motion_s", &tactus::StageTimes::constrained_motion_s)
      .def_readonly("total_s", &tactus::StageTimes::total_s);

  py::class_<tactus::StepReport>(m, "StepReport", "What one step did")
      .def_readonly("contacts", &tactus::StepReport::contacts)
      .def_readonly("rows", &tactus::StepReport::rows)
      .def_readonly("contacts_dropped", &tactus::StepReport::contacts_dropped)
      .def_readonly("nsgs", &tactus::StepReport::nsgs)
      .def_readonly("contact_groups", &tactus::StepReport::contact_groups)
      .def_readonly("max_penetration_m", &tactus::StepReport::max_penetration_m)
      .def_readonly("contact_passes", &tactus::StepReport::contact_passes)
      .def_readonly("geometric_penetration_m", &tactus::StepReport::geometric_penetration_m)
      .def_readonly("excess_penetration_m", &tactus::StepReport::excess_penetration_m)
      .def_readonly("distinct_tissue_nodes", &tactus::StepReport::distinct_tissue_nodes)
      .def_readonly("total_normal_force_n", &tactus::StepReport::total_normal_force_n)
      .def_property_readonly("tool_wrench",
                             [](const tactus::StepReport& r) { return tactus::Vector6d(r.tool_wrench); })
      .def_readonly("finite", &tactus::StepReport::finite)
      .def_readonly("inverted_elements", &tactus::StepReport::inverted_elements)
      .def_readonly("strain_limited_elements", &tactus::StepReport::strain_limited_elements)
      .def_readonly("strain_limit_unresolved", &tactus::StepReport::strain_limit_unresolved)
      .def_readonly("fem_factorisations", &tactus::StepReport::fem_factorisations)
      .def_readonly("fem_cg_iterations", &tactus::StepReport::fem_cg_iterations)
      .def_readonly("fem_pcg_local_nodes", &tactus::StepReport::fem_pcg_local_nodes)
      .def_readonly("times", &tactus::StepReport::times);

  py::class_<tactus::InstrumentState>(m, "InstrumentState", "An instrument's god object")
      .def_readonly("pose", &tactus::InstrumentState::pose)
      .def_property_readonly("twist",
                             [](const tactus::InstrumentState& s) { return tactus::Vector6d(s.twist); })
      .def_readonly("gripper_opening", &tactus::InstrumentState::gripper_opening)
      .def_readonly("grip_rate_radps", &tactus::InstrumentState::grip_rate_radps)
      .def_readonly("target", &tactus::InstrumentState::target)
      .def_property_readonly(
          "rendered_wrench",
          [](const tactus::InstrumentState& s) { return tactus::Vector6d(s.rendered_wrench); })
      .def_property_readonly(
          "contact_wrench",
          [](const tactus::InstrumentState& s) { return tactus::Vector6d(s.contact_wrench); });

  // ---- contact problems ----
  py::class_<tactus::ContactProblem>(
      m, "ContactProblem",
      "A frictional contact problem delta = W f + delta_free (one row n or three rows n, t1, t2 "
      "per contact); its arrays are views of it")
      .def(py::init(&problemFromArrays), "W"_a, "delta_free"_a, "mu"_a,
           "row_offset"_a = py::none(), "f"_a = py::none(),
           "A problem from arrays: W (rows x rows), delta_free (rows), mu (one per contact, or one "
           "for all), row_offset (contacts + 1; default: three rows per contact), f (warm start)")
      .def_readonly("contacts", &tactus::ContactProblem::contacts)
      .def_readonly("rows", &tactus::ContactProblem::rows)
      .def_readonly("step", &tactus::ContactProblem::step)
      .def_readonly("h_s", &tactus::ContactProblem::h_s)
      .def_readonly("solve_result", &tactus::ContactProblem::solve)
      .def_readonly("device_pose", &tactus::ContactProblem::device_pose,
                    "where instrument 0's device was for this step (J's origin)")
      .def_readonly("tool_pose", &tactus::ContactProblem::tool_pose)
      .def_property_readonly(
          "device_poses",
          [](const tactus::ContactProblem& p) {
            std::vector<tactus::Pose> out;
            for (const auto& in : p.instruments) out.push_back(in.device_pose);
            return out;
          },
          "each instrument's device pose for this step")
      .def_property_readonly("W",
                             [](py::object self) {
                               auto& p = self.cast<tactus::ContactProblem&>();
                               return view(p.W.data(), p.W.rows(), p.W.cols(), p.W.cols(), self);
                             })
      .def_property_readonly("delta_free",
                             [](py::object self) {
                               auto& p = self.cast<tactus::ContactProblem&>();
                               return vectorView(p.delta_free.data(), p.delta_free.size(), self, false);
                             })
      .def_property(
          "f",
          [](py::object self) {
            auto& p = self.cast<tactus::ContactProblem&>();
            return vectorView(p.f.data(), p.f.size(), self, false);
          },
          [](tactus::ContactProblem& p, const Eigen::VectorXd& f) {
            if (f.size() != p.rows) throw py::value_error("f must have one entry per row");
            p.f = f;
          })
      .def_property_readonly("J",
                             [](py::object self) {
                               auto& p = self.cast<tactus::ContactProblem&>();
                               return view(p.J.data(), p.J.rows(), 6, 6, self);
                             })
      .def_property_readonly("mu",
                             [](py::object self) {
                               auto& p = self.cast<tactus::ContactProblem&>();
                               return vectorView(p.mu.data(), static_cast<py::ssize_t>(p.mu.size()),
                                                 self, false);
                             })
      .def_property_readonly("row_offset",
                             [](py::object self) {
                               auto& p = self.cast<tactus::ContactProblem&>();
                               return intView(p.row_offset.data(),
                                              static_cast<py::ssize_t>(p.row_offset.size()), 1, self);
                             })
      .def_property_readonly("contact_id",
                             [](py::object self) {
                               auto& p = self.cast<tactus::ContactProblem&>();
                               return intView(p.contact_id.data(),
                                              static_cast<py::ssize_t>(p.contact_id.size()), 1, self);
                             })
      .def_property_readonly("contact_instrument",
                             [](py::object self) {
                               auto& p = self.cast<tactus::ContactProblem&>();
                               return intView(p.contact_instrument.data(),
                                              static_cast<py::ssize_t>(p.contact_instrument.size()), 1,
                                              self);
                             })
      .def_property_readonly(
          "points",
          [](py::object self) { return points(self.cast<tactus::ContactProblem&>().point_m, self); },
          "contact points on the tissues (contacts x 3) [m]")
      .def_property_readonly(
          "normals",
          [](py::object self) { return points(self.cast<tactus::ContactProblem&>().normal, self); },
          "contact normals, tissue -> tool (contacts x 3)")
      .def_property_readonly(
          "tangents1",
          [](py::object self) { return points(self.cast<tactus::ContactProblem&>().tangent1, self); })
      .def_property_readonly(
          "tangents2",
          [](py::object self) { return points(self.cast<tactus::ContactProblem&>().tangent2, self); })
      .def(
          "forces_on_tissue",
          [](const tactus::ContactProblem& p) {
            Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> out(p.contacts, 3);
            for (int c = 0; c < p.contacts; ++c) out.row(c) = p.forceOnTissue(c).transpose();
            return out;
          },
          "the force each contact applies to the tissue, world axes (contacts x 3) [N]")
      .def(
          "solve",
          [](tactus::ContactProblem& p, const tactus::NsgsSettings& settings) {
            return tactus::solveContactProblem(p, settings);
          },
          "settings"_a = tactus::NsgsSettings(),
          "NSGS from f (the warm start) to the solution, kept in f")
      .def("__copy__", [](const tactus::ContactProblem& p) { return p; })
      .def("__deepcopy__", [](const tactus::ContactProblem& p, py::dict) { return p; }, "memo"_a);

  m.def(
      "solve_contact_problem",
      [](const RowMatrix& W, const Eigen::VectorXd& delta_free, const py::object& mu,
         const py::object& row_offset, const py::object& f, const tactus::NsgsSettings& settings) {
        tactus::ContactProblem p = problemFromArrays(W, delta_free, mu, row_offset, f);
        const tactus::NsgsResult r = tactus::solveContactProblem(p, settings);
        return py::make_tuple(Eigen::VectorXd(p.f), r);
      },
      "W"_a, "delta_free"_a, "mu"_a, "row_offset"_a = py::none(), "f"_a = py::none(),
      "settings"_a = tactus::NsgsSettings(),
      "NSGS on a problem given as arrays; returns (f, NsgsResult)");
  m.def("read_fclib", &tactus::readFclib, "path"_a, "An FCLIB text problem (.fc3d.txt)");
  m.def("write_fclib", &tactus::writeFclib, "path"_a, "problem"_a, "overwrite"_a = false,
        "Writes a problem in FCLIB's text form (never over an existing file unless overwrite)");
  m.def("read_snapshots", &tactus::readSnapshots, "path"_a,
        "The problems of a snapshot file (sim_server --record-snapshots)");
  m.def(
      "write_snapshots",
      [](const std::filesystem::path& path, const std::vector<tactus::ContactProblem>& problems,
         bool overwrite) { tactus::writeSnapshots(path, problems, overwrite); },
      "path"_a, "problems"_a, "overwrite"_a = false, "Writes problems to a snapshot file");

  // ---- the haptic local model ----
  py::class_<tactus::LocalModelSettings>(m, "HapticModelSettings",
                                         "Settings of the haptic local model")
      .def(py::init([](const std::string& kind, double tolerance, int max_sweeps) {
             tactus::LocalModelSettings s;
             const auto k = tactus::haptic::parseLocalModelKind(kind);
             if (!k) throw py::value_error("kind: 'full', 'linearized' or 'automatic'");
             s.kind = *k;
             s.tolerance = tolerance;
             s.max_sweeps = max_sweeps;
             s.validate();
             return s;
           }),
           "kind"_a = "automatic", "tolerance"_a = 1e-6, "max_sweeps"_a = 50)
      .def_property_readonly("kind",
                             [](const tactus::LocalModelSettings& s) {
                               return std::string(tactus::haptic::toString(s.kind));
                             })
      .def_readwrite("tolerance", &tactus::LocalModelSettings::tolerance)
      .def_readwrite("max_sweeps", &tactus::LocalModelSettings::max_sweeps)
      .def_readwrite("anderson_depth", &tactus::LocalModelSettings::anderson_depth)
      .def_readwrite("max_translation_m", &tactus::LocalModelSettings::max_translation_m)
      .def_readwrite("max_rotation_rad", &tactus::LocalModelSettings::max_rotation_rad);

  py::class_<tactus::LocalModelResult>(m, "HapticResult", "What the haptic local model did")
      .def_property_readonly("used",
                             [](const tactus::LocalModelResult& r) {
                               return std::string(tactus::haptic::toString(r.used));
                             })
      .def_property_readonly("fallback",
                             [](const tactus::LocalModelResult& r) {
                               return std::string(tactus::haptic::toString(r.fallback));
                             })
      .def_property_readonly("status",
                             [](const tactus::LocalModelResult& r) {
                               return std::string(tactus::shared::toString(r.status));
                             })
      .def_property_readonly("converged", &tactus::LocalModelResult::converged)
      .def_readonly("sweeps", &tactus::LocalModelResult::sweeps)
      .def_readonly("error", &tactus::LocalModelResult::error)
      .def_readonly("rows", &tactus::LocalModelResult::rows)
      .def_readonly("contacts", &tactus::LocalModelResult::contacts)
      .def_readonly("elapsed_ns", &tactus::LocalModelResult::elapsed_ns)
      .def_property_readonly(
          "force_n",
          [](const tactus::LocalModelResult& r) {
            Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> out(r.instruments, 3);
            for (int i = 0; i < r.instruments; ++i) {
              for (int k = 0; k < 3; ++k) out(i, k) = r.force_n[static_cast<std::size_t>(i)][k];
            }
            return out;
          },
          "contact force on each instrument (instruments x 3) [N]")
      .def_property_readonly(
          "torque_nm",
          [](const tactus::LocalModelResult& r) {
            Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> out(r.instruments, 3);
            for (int i = 0; i < r.instruments; ++i) {
              for (int k = 0; k < 3; ++k) out(i, k) = r.torque_nm[static_cast<std::size_t>(i)][k];
            }
            return out;
          },
          "contact torque on each instrument about its tool point (instruments x 3) [N m]");

  py::class_<tactus::HapticModel>(
      m, "HapticModel",
      "The haptic local model: a contact problem re-solved for the devices' poses, as "
      "haptic_server does every tick")
      .def(py::init<const tactus::LocalModelSettings&>(),
           "settings"_a = tactus::LocalModelSettings())
      .def(
          "adopt",
          [](tactus::HapticModel& h, const tactus::ContactProblem& p, const py::object& device_poses) {
            const std::vector<tactus::Pose> ps = poses(device_poses);
            return std::string(tactus::haptic::toString(h.adopt(p, ps)));
          },
          "problem"_a, "device_poses"_a = py::none(),
          "Prepares a problem at the devices' poses (default: those it was made at); returns "
          "the preparation's status ('ready' when solve may run)")
      .def(
          "solve",
          [](tactus::HapticModel& h, const py::object& device_poses) {
            const std::vector<tactus::Pose> ps = poses(device_poses);
            return h.solve(ps);
          },
          "device_poses"_a = py::none(),
          "The contact wrench on each instrument with the devices at these poses")
      .def_property_readonly("forces",
                             [](const tactus::HapticModel& h) {
                               const auto f = h.forces();
                               return Eigen::VectorXd(Eigen::Map<const Eigen::VectorXd>(
                                   f.data(), static_cast<Eigen::Index>(f.size())));
                             })
      .def_property_readonly("settings", &tactus::HapticModel::settings);

  // ---- model, state, simulation ----
  py::class_<tactus::Model>(m, "Model", "A scene compiled once (immutable, shared)")
      .def_static("from_file", &tactus::Model::fromFile, "path"_a, "A scene file (scenes/README.md)")
      .def_static("from_string", &tactus::Model::fromString, "yaml"_a, "base_dir"_a = ".",
                  "name"_a = "scene.yaml",
                  "A scene from YAML text; relative paths resolve against base_dir")
      .def_property_readonly("name", &tactus::Model::name)
      .def_property_readonly("identity", &tactus::Model::identity)
      .def_property_readonly("time_step", &tactus::Model::timeStep)
      .def_property_readonly("duration", &tactus::Model::duration)
      .def_property_readonly("tissue_count", &tactus::Model::tissueCount)
      .def_property_readonly("instrument_count", &tactus::Model::instrumentCount)
      .def("tissue_name", &tactus::Model::tissueName, "tissue"_a)
      .def("instrument_name", &tactus::Model::instrumentName, "instrument"_a)
      .def("node_count", &tactus::Model::nodeCount, "tissue"_a)
      .def(
          "rest_positions",
          [](py::object self, int t) {
            const auto map = self.cast<tactus::Model&>().restPositions(t);
            return view(map.data(), map.cols(), 3, 3, self);
          },
          "tissue"_a, "rest positions (nodes x 3) [m], a read-only view")
      .def(
          "tetrahedra",
          [](py::object self, int t) {
            const auto tets = self.cast<tactus::Model&>().tetrahedra(t);
            return intView(tets.empty() ? nullptr : tets[0].data(),
                           static_cast<py::ssize_t>(tets.size()), 4, self);
          },
          "tissue"_a)
      .def(
          "surface_triangles",
          [](py::object self, int t) {
            const auto tris = self.cast<tactus::Model&>().surfaceTriangles(t);
            return intView(tris.empty() ? nullptr : tris[0].data(),
                           static_cast<py::ssize_t>(tris.size()), 3, self);
          },
          "tissue"_a, "boundary triangles (outward), what a renderer draws")
      .def(
          "fixed_nodes",
          [](py::object self, int t) {
            const auto nodes = self.cast<tactus::Model&>().fixedNodes(t);
            return intView(nodes.data(), static_cast<py::ssize_t>(nodes.size()), 1, self);
          },
          "tissue"_a);

  py::class_<tactus::State>(m, "State",
                            "A simulation state as a value: copy, compare, save, restore")
      .def(py::init<>())
      .def_static("load", &tactus::State::load, "path"_a)
      .def("save", &tactus::State::save, "path"_a, "overwrite"_a = false,
           "Writes the state (never over an existing file unless overwrite)")
      .def_property_readonly("time", &tactus::State::time)
      .def_property_readonly("step_index", &tactus::State::stepIndex)
      .def_property_readonly("model_identity", &tactus::State::modelIdentity)
      .def_property_readonly("model_name", &tactus::State::modelName)
      .def_property_readonly("nbytes",
                             [](const tactus::State& s) { return s.bytes().size(); })
      .def("to_bytes", [](const tactus::State& s) { return py::bytes(s.bytes()); })
      .def_static("from_bytes",
                  [](const py::bytes& b) { return tactus::State::fromBytes(std::string(b)); })
      .def("__eq__", [](const tactus::State& a, const tactus::State& b) { return a == b; })
      .def("__copy__", [](const tactus::State& s) { return s; })
      .def("__deepcopy__", [](const tactus::State& s, py::dict) { return s; }, "memo"_a)
      .def(py::pickle([](const tactus::State& s) { return py::bytes(s.bytes()); },
                      [](const py::bytes& b) { return tactus::State::fromBytes(std::string(b)); }));

  py::class_<tactus::Simulation>(m, "Simulation", "A running simulation of a Model")
      .def(py::init<const tactus::Model&>(), "model"_a)
      .def_property_readonly("model", &tactus::Simulation::model)
      .def("step", &tactus::Simulation::step, py::call_guard<py::gil_scoped_release>(),
           "Advances one time step; returns its StepReport")
      .def("set_device_target", &tactus::Simulation::setDeviceTarget, "instrument"_a, "target"_a)
      .def(
          "set_device_pose",
          [](tactus::Simulation& s, int i, const py::object& position, const py::object& quaternion,
             double gripper_opening) {
            tactus::DeviceTarget t;
            t.pose = makePose(position, quaternion);
            t.gripper_opening = gripper_opening;
            s.setDeviceTarget(i, t);
          },
          "instrument"_a, "position"_a, "quaternion"_a, "gripper_opening"_a = 1.0,
          "set_device_target with a pose at rest (zero twist)")
      .def("scripted_target", &tactus::Simulation::scriptedTarget, "instrument"_a, "t"_a)
      .def("follow_script", &tactus::Simulation::followScript,
           "Every instrument follows the scene's script at the current time")
      .def_property_readonly("time", &tactus::Simulation::time)
      .def_property_readonly("step_index", &tactus::Simulation::stepIndex)
      .def_property_readonly("instrument_count", &tactus::Simulation::instrumentCount)
      .def("instrument", &tactus::Simulation::instrument, "i"_a)
      .def(
          "positions",
          [](py::object self, int t) {
            const auto map = self.cast<tactus::Simulation&>().positions(t);
            return view(map.data(), map.cols(), 3, 3, self);
          },
          "tissue"_a,
          "node positions (nodes x 3) [m]: a read-only view of the simulation's memory, which "
          "later steps change (copy() to keep)")
      .def(
          "velocities",
          [](py::object self, int t) {
            const auto map = self.cast<tactus::Simulation&>().velocities(t);
            return view(map.data(), map.cols(), 3, 3, self);
          },
          "tissue"_a, "node velocities (nodes x 3) [m/s], a view as positions()")
      .def("last_problem", &tactus::Simulation::lastProblem, py::return_value_policy::copy,
           "a copy of the contact problem the last step solved (empty after set_state)")
      .def(
          "reactions",
          [](tactus::Simulation& s) {
            const tactus::ReactionForces r = s.reactions();
            py::dict d;
            py::list tissues;
            for (const tactus::TissueReactions& t : r.tissues) {
              py::dict td;
              td["fixed_reaction_n"] = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>(
                  t.fixed_reaction_n.transpose());
              td["contact_force_n"] = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>(
                  t.contact_force_n.transpose());
              td["fixed_total_n"] = Eigen::Vector3d(t.fixed_total_n);
              td["weight_n"] = Eigen::Vector3d(t.weight_n);
              td["from_tissues_n"] = Eigen::Vector3d(t.from_tissues_n);
              tissues.append(td);
            }
            d["tissues"] = tissues;
            py::dict obstacles;
            for (std::size_t i = 0; i < r.obstacle_names.size(); ++i) {
              obstacles[py::str(r.obstacle_names[i])] = Eigen::Vector3d(r.obstacle_force_n[i]);
            }
            d["obstacles"] = obstacles;
            d["instrument_force_n"] = Eigen::Vector3d(r.instrument_force_n);
            d["weight_n"] = Eigen::Vector3d(r.weight_n);
            d["applied_load_n"] = Eigen::Vector3d(r.applied_load_n);
            d["fixed_total_n"] = Eigen::Vector3d(r.fixed_total_n);
            d["imbalance_n"] = Eigen::Vector3d(r.imbalance_n());
            return d;
          },
          "reactions at the fixed nodes, per obstacle and from the instrument [N] (a dict of "
          "numpy arrays)")
      .def("total_energy", &tactus::Simulation::totalEnergy)
      .def("stages", &tactus::Simulation::stages)
      .def("state", &tactus::Simulation::state, "a copy of the state (a State)")
      .def("set_state", &tactus::Simulation::setState, "state"_a,
           "continues from a state of this model, bit for bit");

  // ---- for tools/python_step_bench: the same steps driven from C++ ----
  py::module_ bench = m.def_submodule("benchmark", "helpers of the Python-overhead benchmark");
  bench.def(
      "cpp_steps",
      [](tactus::Simulation& s, int steps) {
        const auto wall0 = std::chrono::steady_clock::now();
        const std::int64_t cpu0 = threadCpuNs();
        for (int k = 0; k < steps; ++k) {
          s.followScript();
          s.step();
        }
        const std::int64_t cpu = threadCpuNs() - cpu0;
        const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
        // a C++ pair: converted to a tuple once the guard has taken the GIL back
        return std::pair<double, double>(wall, 1e-9 * static_cast<double>(cpu));
      },
      "simulation"_a, "steps"_a, py::call_guard<py::gil_scoped_release>(),
      "steps x (follow_script, step) in a C++ loop; returns (wall s, thread CPU s)");
  bench.def("thread_cpu_s", [] { return 1e-9 * static_cast<double>(threadCpuNs()); });
}
