"""The MJCF export must describe the same scene as the builder: MuJoCo is the benchmark's reference."""

from __future__ import annotations

import math

import numpy as np
import pytest

from warpimpulse import SceneBuilder, scenes
from warpimpulse.bench import harness, report
from warpimpulse.bench.blocks import write_block
from warpimpulse.bench.peers.mujoco import MujocoScene, to_mjcf
from warpimpulse.bench.runner import advance
from warpimpulse.transforms import quat_from_axis_angle, quat_to_matrix

mujoco = pytest.importorskip("mujoco")


def _step(scene: MujocoScene, data, steps: int) -> None:
    for _ in range(steps):
        scene.apply_forces(data)
        mujoco.mj_step(scene.model, data)


@pytest.mark.parametrize("builder", [scenes.double_pendulum(), scenes.binary_tree(15), scenes.star(15)])
def test_initial_pose_and_mass_match(builder: SceneBuilder) -> None:
    scene = MujocoScene.from_builder(builder, 1e-3)
    data = scene.make_data()
    ours_x = np.array([b.position for b in builder.bodies])
    ours_q = np.array([b.orientation for b in builder.bodies])
    np.testing.assert_allclose(scene.positions(data), ours_x, atol=1e-12)
    # q and -q are the same rotation.
    np.testing.assert_allclose(np.abs(np.sum(scene.orientations(data) * ours_q, axis=1)), 1.0, atol=1e-12)
    assert scene.total_mass() == pytest.approx(sum(b.mass for b in builder.bodies), rel=1e-12)


def test_free_fall_and_initial_velocity() -> None:
    builder = SceneBuilder()
    builder.add_body(2.0, (0.1, 0.2, 0.25), (1.0, 2.0, 3.0), linear_velocity=(0.5, -1.0, 2.0))
    scene = MujocoScene.from_builder(builder, 1e-3)
    data = scene.make_data()
    _step(scene, data, 500)
    t = data.time
    expected = np.array([1.0 + 0.5 * t, 2.0 - t, 3.0 + 2.0 * t - 0.5 * 9.81 * t * t])
    np.testing.assert_allclose(scene.positions(data)[0], expected, atol=1e-9)


def test_torque_and_full_inertia_in_world_frame() -> None:
    """Zero gravity, a tilted body with products of inertia: angular momentum grows as torque * t."""
    builder = SceneBuilder(gravity=(0.0, 0.0, 0.0))
    inertia = np.array([[0.3, 0.02, -0.01], [0.02, 0.25, 0.03], [-0.01, 0.03, 0.2]])
    q = quat_from_axis_angle((1.0, 1.0, 0.0), 0.7)
    body = builder.add_body(1.5, inertia, (0.0, 0.0, 0.0), q, angular_velocity=(0.3, -0.2, 0.5))
    torque = np.array([0.1, -0.4, 0.2])
    builder.add_force(body, torque=torque, until=0.25)
    scene = MujocoScene.from_builder(builder, 1e-3)
    data = scene.make_data()

    def momentum() -> np.ndarray:
        rot = quat_to_matrix(scene.orientations(data)[0])
        omega = rot @ data.qvel[3:6]  # free joint: angular velocity in the body frame
        return rot @ inertia @ rot.T @ omega

    start = momentum()
    np.testing.assert_allclose(start, quat_to_matrix(q) @ inertia @ quat_to_matrix(q).T @ [0.3, -0.2, 0.5])
    _step(scene, data, 500)  # 0.25 s of torque, then 0.25 s free
    np.testing.assert_allclose(momentum(), start + torque * 0.25, atol=1e-9)


def test_double_pendulum_conserves_energy_and_length() -> None:
    builder = scenes.double_pendulum()
    scene = MujocoScene.from_builder(builder, 1e-3)
    data = scene.make_data()
    e0 = scene.energy(data)
    _step(scene, data, 1000)
    assert scene.energy(data) == pytest.approx(e0, abs=1e-6)
    tip = scene.points(data, np.array([1]), np.array([[0.0, 0.0, 0.5]]))[0]
    elbow = scene.points(data, np.array([0]), np.array([[0.0, 0.0, 0.5]]))[0]
    assert np.linalg.norm(elbow) == pytest.approx(1.0, abs=1e-12)
    assert np.linalg.norm(tip - elbow) == pytest.approx(1.0, abs=1e-12)
    assert tip[2] < -0.5  # it fell


@pytest.mark.parametrize(
    ("kind", "dofs"),
    [
        ("ball", 3),
        ("revolute", 1),
        ("prismatic", 1),
        ("cylindrical", 2),
        ("universal", 2),
        ("planar", 3),
        ("fixed", 0),
    ],
)
def test_every_joint_kind_has_its_degrees_of_freedom(kind: str, dofs: int) -> None:
    builder = SceneBuilder()
    base = builder.add_body(1.0, (0.1, 0.1, 0.1), (0.0, 0.0, 0.0))
    tip = builder.add_body(1.0, (0.1, 0.1, 0.1), (0.0, 0.0, -1.0))
    builder.add_joint_ball(None, base, (0.0, 0.0, 0.5))
    builder.add_joint(kind, base, tip, (0.0, 0.0, -0.5), (0.0, 1.0, 0.0), (1.0, 0.0, 0.0))
    scene = MujocoScene.from_builder(builder, 1e-3)
    assert scene.model.nv == 3 + dofs
    data = scene.make_data()
    _step(scene, data, 10)
    assert np.all(np.isfinite(data.qpos))


def test_universal_keeps_the_angle_between_its_axes() -> None:
    builder = SceneBuilder()
    base = builder.add_body(1.0, (0.1, 0.1, 0.1), (0.0, 0.0, 0.0), angular_velocity=(0.0, 0.0, 0.0))
    tip = builder.add_body(1.0, (0.1, 0.2, 0.3), (0.3, 0.0, -1.0))
    builder.add_joint_fixed(None, base, (0.0, 0.0, 0.0))
    builder.add_joint_universal(base, tip, (0.0, 0.0, -0.5), (0.0, 1.0, 0.0), (1.0, 0.0, 0.0))
    scene = MujocoScene.from_builder(builder, 1e-3)
    data = scene.make_data()
    _step(scene, data, 300)
    child_x = quat_to_matrix(scene.orientations(data)[1]) @ [1.0, 0.0, 0.0]
    assert abs(float(np.dot(child_x, [0.0, 1.0, 0.0]))) < 1e-9
    assert np.linalg.norm(data.qvel) > 0.1  # it moved


def test_loops_are_refused() -> None:
    builder = SceneBuilder()
    a = builder.add_body(1.0, (0.1, 0.1, 0.1), (0.0, 0.0, 0.0))
    b = builder.add_body(1.0, (0.1, 0.1, 0.1), (1.0, 0.0, 0.0))
    builder.add_joint_ball(None, a, (0.0, 0.0, 0.0))
    builder.add_joint_ball(None, b, (1.0, 0.0, 0.0))
    builder.add_joint_ball(a, b, (0.5, 0.0, 0.0))
    with pytest.raises(NotImplementedError, match="two parent joints"):
        to_mjcf(builder)


def test_forces_stop_on_the_same_step_as_ours() -> None:
    """The trees' start torque lasts 1 s: with h = 1/30 it acts on exactly 30 steps despite rounding."""
    builder = SceneBuilder()
    body = builder.add_body(1.0, (0.1, 0.1, 0.1), (0.0, 0.0, 0.0))
    builder.add_force(body, torque=(0.0, 0.0, 1.0), until=1.0)
    scene = MujocoScene.from_builder(builder, 1.0 / 30.0)
    data = scene.make_data()
    active = 0
    for _ in range(40):
        scene.apply_forces(data)
        active += bool(np.any(data.xfrc_applied))
        mujoco.mj_step(scene.model, data)
    assert active == 30
    assert math.isclose(data.time, 40 / 30.0)


@pytest.mark.parametrize("first", [0, 7, 30, 31])
def test_runs_of_steps_are_the_steps(first: int) -> None:
    """The timed loop's calls for many steps (`runner.advance`): MuJoCo's mj_step with nstep, split where the
    tree's start torque switches off (step 30 at h = 1/30), and our step(n), give the states of one step() at a
    time, wherever the run starts: bit for bit with every velocity correction taken, and within the tolerance
    where step(n) defers its steps' velocity corrections to the next joint correction (`defer_velocities`)."""
    builder = scenes.binary_tree(7)
    one = harness.MujocoRunner(MujocoScene.from_builder(builder, 1.0 / 30.0), "RK4", 30)
    many = harness.MujocoRunner(MujocoScene.from_builder(builder, 1.0 / 30.0), "RK4", 30)
    ours_one = harness.WarpimpulseRunner(builder, 30, 1e-8, defer_velocities=False)
    ours_many = harness.WarpimpulseRunner(builder, 30, 1e-8, defer_velocities=False)
    deferred = harness.WarpimpulseRunner(builder, 30, 1e-8)
    for runner in (one, many, ours_one, ours_many, deferred):
        for _ in range(first):
            runner.step()
    for _ in range(40):
        one.step()
        ours_one.step()
    advance(many, 40)
    advance(ours_many, 40)
    advance(deferred, 40)
    assert many.steps == one.steps == first + 40
    np.testing.assert_array_equal(many.data.qpos, one.data.qpos)
    np.testing.assert_array_equal(many.data.qvel, one.data.qvel)
    assert ours_many.steps == ours_one.steps and ours_many.joint_iterations == ours_one.joint_iterations
    np.testing.assert_array_equal(ours_many.poses()[0], ours_one.poses()[0])
    assert deferred.sim.defer_velocities and deferred.steps == ours_one.steps
    np.testing.assert_allclose(deferred.poses()[0], ours_one.poses()[0], rtol=0, atol=1e-7)


def test_benchmark_harness_end_to_end(tmp_path) -> None:
    """One configuration per engine on the double pendulum: every number and every output is produced."""
    pytest.importorskip("matplotlib")
    sweep = harness.run_vs_error(["double_pendulum"], [60], [1e-6], repeats=1, progress=False, orders=(2, 4))
    ref = sweep["references"]["double_pendulum"]
    ours = {r["order"]: r for r in sweep["runs"] if r["engine"] == "warpimpulse"}
    assert set(ours) == {2, 4} and ours[4]["tolerance"] < ours[2]["tolerance"]
    assert ours[4]["trajectory_error"] < 0.01 * ours[2]["trajectory_error"]  # order 4 at the same h
    assert ref["self_check_residual"] < 1e-8
    rk4 = next(r for r in sweep["runs"] if r["variant"] == "RK4" and r["engine"] == "mujoco")
    assert rk4["failed"] is None and rk4["trajectory_error"] < 1e-3 and rk4["energy_drift"] < 1e-2
    assert rk4["time_per_step"] > 0.0 and rk4["joint_error_anchor_gap"] < 1e-12
    results = {"run_vs_error": sweep}
    text = report.markdown(results)
    assert "| mujoco | RK4 | 1/60 |" in text and "## Where we win and lose" in text
    written = report.plots(results, tmp_path)
    assert {p.name for p in written} == {"pareto_double_pendulum.png", "energy_drift.png"}
    assert "| warpimpulse | auto order 4 | 1/60 |" in text
    readme = tmp_path / "README.md"
    readme.write_text(f"# title\n\nkept\n{report.README_BEGIN}\nold\n{report.README_END}\nkept too\n")
    write_block(readme, report.README_BLOCK, report.readme_block(results))
    text = readme.read_text()
    assert text.startswith("# title\n\nkept\n") and text.endswith(f"{report.README_END}\nkept too\n")
    assert "old" not in text and "pareto_double_pendulum.png" in text and "The bar" not in text


def test_mujoco_builds_chains_deeper_than_its_xml_parser_allows() -> None:
    scene = MujocoScene.from_builder(scenes.chain(700), 1.0 / 60.0)
    assert scene.model.nbody == 701 and scene.model.nv == 700


def test_speed_ratio_picks_the_fastest_peer_at_least_as_accurate() -> None:
    def run(engine, variant, rate, error, seconds):
        return {"scene": "tree127", "engine": engine, "variant": variant, "rate": rate, "tolerance": 1e-6,
                "failed": None, "trajectory_error": error, "time_per_step": seconds}  # fmt: skip

    runs = [
        run("warpimpulse", "auto", 60, 1e-3, 2e-4),
        run("mujoco", "RK4", 60, 1e-4, 5e-4),
        run("mujoco", "RK4", 30, 2e-3, 3e-4),  # faster but less accurate: not a match
        run("mujoco", "Euler", 300, 5e-4, 8e-4),
    ]
    (ratio,) = report.speed_ratios(runs)
    assert ratio["mujoco"] == "RK4 1/60"
    assert ratio["ratio"] == pytest.approx(2.5)
