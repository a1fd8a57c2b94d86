"""The Python module `tactus` (api/python; docs/api.md "Python"): models, simulations read in
place, states copied, saved and restored bit for bit, contact problems solved with NSGS and read
from and written to FCLIB and snapshot files, the haptic local model, and the examples' physics
(examples/python). Run by ctest (python_api) with PYTHONPATH=build/python."""
import copy
import math
import pathlib
import pickle
import sys

import numpy as np
import pytest

import tactus

ROOT = pathlib.Path(__file__).resolve().parents[2]
SCENES = ROOT / "scenes"
FCLIB = ROOT / "tests" / "data" / "fclib" / "problems"
SNAPSHOTS = ROOT / "tests" / "data" / "haptic" / "liver_grasp_hold.snap"
sys.path.insert(0, str(ROOT / "examples" / "python"))
import grasp  # noqa: E402
import incline  # noqa: E402

BLOCK = """
time_step: 0.01
gravity: [0, 0, -9.81]
tissues:
  - name: block
    mesh: block.vtk
    material: {young_modulus: 3000, poisson_ratio: 0.45}
    damping: {rayleigh_mass: 2, rayleigh_stiffness: 0.02}
    compliance: {model: warped}
obstacles:
  - {name: table, plane: {point: [0, 0, 0], normal: [0, 0, 1]}, friction: 0.5}
"""


@pytest.fixture(scope="module")
def block_model(tmp_path_factory):
    """A soft 4 cm block dropped 0.5 mm onto a table."""
    folder = tmp_path_factory.mktemp("block")
    incline.write_box_mesh(folder / "block.vtk", (0.04, 0.04, 0.02), (3, 3, 2),
                           (-0.02, -0.02, 0.0005))
    return tactus.Model.from_string(BLOCK, str(folder), "block.yaml")


def test_a_model_from_a_scene_file():
    m = tactus.Model.from_file(SCENES / "liver_grasp.yaml")
    assert m.name == "liver_grasp.yaml"
    assert m.time_step == 0.01 and m.duration == 8.0
    assert (m.tissue_count, m.instrument_count) == (1, 1)
    rest = m.rest_positions(0)
    assert rest.shape == (507, 3) and rest.dtype == np.float64
    assert not rest.flags.writeable
    assert m.tetrahedra(0).shape == (1493, 4)
    tris = m.surface_triangles(0)
    assert tris.shape[1] == 3 and tris.max() < 507
    fixed = m.fixed_nodes(0)
    assert len(fixed) == 161 and np.all(np.diff(fixed) > 0)
    with pytest.raises(IndexError):
        m.node_count(1)
    with pytest.raises(tactus.SceneError, match="bad.yaml"):
        tactus.Model.from_string("time_step: -1\n", str(SCENES), "bad.yaml")


def test_positions_are_a_view_of_the_state(block_model):
    sim = tactus.Simulation(block_model)
    q = sim.positions(0)
    before = q.copy()
    sim.step()
    assert not np.array_equal(q, before)          # the view follows the simulation
    assert np.array_equal(q, sim.positions(0))
    assert np.shares_memory(q, sim.positions(0))
    with pytest.raises(ValueError):
        q[0, 0] = 1.0                              # read-only
    del sim
    assert np.isfinite(q).all()                    # the view keeps the simulation alive


def test_a_state_restores_the_run_bit_for_bit(block_model, tmp_path):
    sim = tactus.Simulation(block_model)
    for _ in range(30):
        sim.step()
    saved = sim.state()
    assert (saved.step_index, saved.model_name) == (30, "block.yaml")
    assert saved.model_identity == block_model.identity
    for _ in range(20):
        sim.step()
    q50, v50, end = sim.positions(0).copy(), sim.velocities(0).copy(), sim.state()

    sim.set_state(saved)                      # rewound
    assert sim.step_index == 30 and sim.last_problem().contacts == 0
    for _ in range(20):
        sim.step()
    assert np.array_equal(sim.positions(0), q50) and np.array_equal(sim.velocities(0), v50)
    assert sim.state() == end

    path = tmp_path / "block.state"           # through a file, into another simulation
    saved.save(path)
    with pytest.raises(tactus.FileError, match="overwrite"):
        saved.save(path)
    other = tactus.Simulation(block_model)
    other.set_state(tactus.State.load(path))
    for _ in range(20):
        other.step()
    assert np.array_equal(other.positions(0), q50)

    assert pickle.loads(pickle.dumps(saved)) == saved
    assert copy.deepcopy(saved) == saved
    liver = tactus.Simulation(tactus.Model.from_file(SCENES / "liver_on_support.yaml"))
    with pytest.raises(tactus.StateError, match="another model"):
        other.set_state(liver.state())


def test_the_benchmark_steps_from_cpp_as_python_does(block_model):
    """tools/python_step_bench's C++ loop: the same steps as the Python loop, timed."""
    sim = tactus.Simulation(block_model)
    start = sim.state()
    for _ in range(5):
        sim.follow_script()
        sim.step()
    by_python = sim.state()
    sim.set_state(start)
    wall_s, cpu_s = tactus.benchmark.cpp_steps(sim, 5)
    assert wall_s >= 0.0 and cpu_s >= 0.0
    assert sim.state() == by_python


def test_device_targets_drive_the_instrument():
    sim = tactus.Simulation(tactus.Model.from_file(SCENES / "liver_grasp.yaml"))
    start = sim.instrument(0).pose.position
    goal = sim.scripted_target(0, 2.0)               # where the script grasps
    assert np.linalg.norm(goal.pose.position - start) > 1e-2
    sim.set_device_target(0, goal)
    for _ in range(40):
        sim.step()
    assert np.array_equal(sim.instrument(0).target.pose.position, goal.pose.position)
    assert np.linalg.norm(sim.instrument(0).pose.position - goal.pose.position) < 0.1 * np.linalg.norm(
        goal.pose.position - start)                  # the god object followed the target
    # a pose from arrays, jaws closing
    sim.set_device_pose(0, goal.pose.position, goal.pose.quaternion, gripper_opening=0.0)
    for _ in range(20):
        sim.step()
    assert sim.instrument(0).gripper_opening < 0.5
    # a non-finite target is not taken: the last valid one is held
    sim.set_device_pose(0, [math.nan, 0.0, 0.0], goal.pose.quaternion)
    assert np.array_equal(sim.instrument(0).target.pose.position, goal.pose.position)
    assert sim.step().finite


def test_contact_forces_and_reactions(block_model):
    sim = tactus.Simulation(block_model)
    for _ in range(60):
        report = sim.step()
    # no strain_limit in the scene: the limiter is not run
    assert report.strain_limited_elements == 0 and report.strain_limit_unresolved == 0
    p = sim.last_problem()
    assert p.contacts > 0 and p.rows == 3 * p.contacts
    assert p.points.shape == (p.contacts, 3) and p.normals.shape == (p.contacts, 3)
    assert np.allclose(p.normals, [0, 0, -1])      # tissue -> the table below
    assert p.W.shape == (p.rows, p.rows) and p.f.shape == (p.rows,)
    r = sim.reactions()
    table = r["obstacles"]["table"]
    assert np.allclose(p.forces_on_tissue().sum(axis=0), table, rtol=1e-9, atol=1e-12)
    assert table[2] == pytest.approx(-r["weight_n"][2], rel=0.05)   # at rest: it holds the weight


def test_nsgs_on_arrays():
    # one frictional contact pressed 1 mm in: f_n = 1e-3 / W_nn, no tangential force
    W = np.diag([2e-3, 4e-3, 4e-3])
    f, result = tactus.solve_contact_problem(W, np.array([-1e-3, 0.0, 0.0]), 0.5)
    assert result.converged and result.status == "converged"
    assert f == pytest.approx([0.5, 0.0, 0.0])
    # pushed sideways harder than friction holds: it slides, |f_t| = mu f_n
    f, result = tactus.solve_contact_problem(W, np.array([-1e-3, 4e-3, 0.0]), 0.5)
    assert result.converged
    assert math.hypot(f[1], f[2]) == pytest.approx(0.5 * f[0], rel=1e-6)
    with pytest.raises(tactus.Error, match="mu"):
        tactus.solve_contact_problem(W, np.zeros(3), -1.0)


def test_fclib_files(tmp_path):
    p = tactus.read_fclib(FCLIB / "Box_Stacks-i0122-82-5.local.fc3d.txt")
    assert (p.contacts, p.rows) == (82, 246)
    result = p.solve(tactus.NsgsSettings(tolerance=1e-6, max_sweeps=1000))
    assert result.converged and p.f.shape == (246,)
    out = tmp_path / "again.fc3d.txt"
    tactus.write_fclib(out, p)
    back = tactus.read_fclib(out)
    assert np.array_equal(back.W, p.W) and np.array_equal(back.delta_free, p.delta_free)
    assert np.array_equal(back.mu, p.mu)
    with pytest.raises(tactus.FileError):
        tactus.write_fclib(out, p)


def test_snapshot_files_and_the_haptic_local_model(tmp_path):
    problems = tactus.read_snapshots(SNAPSHOTS)
    assert problems and problems[0].contacts > 0
    p = problems[0]
    assert p.J.shape == (p.rows, 6) and p.points.shape == (p.contacts, 3)
    out = tmp_path / "copy.snap"
    tactus.write_snapshots(out, problems[:3])
    back = tactus.read_snapshots(out)
    assert len(back) == 3
    for a, b in zip(back, problems[:3]):
        assert np.array_equal(a.W, b.W) and np.array_equal(a.f, b.f) and np.array_equal(a.J, b.J)
        assert np.array_equal(a.contact_id, b.contact_id)
    # the local model at the device pose the problem was made at gives back its solution's
    # wrench; with the device moved up the force changes
    model = tactus.HapticModel(tactus.HapticModelSettings(kind="full", max_sweeps=500))
    assert model.adopt(p) == "ready"
    at = model.solve()
    assert at.converged and at.force_n.shape == (1, 3)
    device = p.device_pose
    up = model.solve([tactus.Pose(device.position + [0, 0, 1e-3], device.quaternion)])
    assert up.converged
    assert not np.allclose(up.force_n, at.force_n)


def test_the_incline_example_follows_coulomb():
    v, expected = incline.slide(theta_deg=30.0, mu=0.3, steps=40)
    assert expected > 0
    assert np.allclose(np.diff(v), expected, rtol=0.01)
    v, expected = incline.slide(theta_deg=20.0, mu=0.8, steps=20)   # tan 20 deg < 0.8: it sticks
    assert expected == 0.0
    assert np.all(np.abs(np.diff(v)) < 1e-2 * 1e-3 * 9.81 * math.sin(math.radians(20)))


def test_the_grasp_example(tmp_path):
    series, probe = grasp.grasp(steps=260, probe_at_s=2.3)
    assert series["contacts"].max() > 0
    assert series["normal_force_n"].max() > 0.5     # the jaws close on the lobe
    assert probe is not None and probe["status"] == "ready"
    assert np.isfinite(probe["force_n"]).all() and np.isfinite(probe["force_lifted_n"]).all()
    figure = tmp_path / "grasp.png"
    sys.argv = ["grasp.py", "--steps", "5", "--output", str(figure)]
    assert grasp.main() == 0 and figure.stat().st_size > 0
    assert grasp.main() == 2                        # never overwritten unasked
