"""The pinocchio peer must simulate the builder's scene: it is the benchmark's second, independent reference."""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest

from warpimpulse import SceneBuilder, scenes
from warpimpulse.bench import harness
from warpimpulse.bench.harness import Probe
from warpimpulse.bench.peers.mujoco import MujocoRunner, MujocoScene, mujoco_available
from warpimpulse.bench.peers.pinocchio import PinocchioRunner, PinocchioScene

pin = pytest.importorskip("pinocchio")


@pytest.mark.parametrize("builder", [scenes.double_pendulum(), scenes.binary_tree(15), scenes.star(15)])
def test_initial_pose_and_mass_match(builder: SceneBuilder) -> None:
    runner = PinocchioRunner(PinocchioScene.from_builder(builder), 60)
    x, q = runner.poses()
    np.testing.assert_allclose(x, [b.position for b in builder.bodies], atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(q * [b.orientation for b in builder.bodies], axis=1)), 1.0, atol=1e-12)
    mass = sum(inertia.mass for inertia in runner.model.inertias)
    assert mass == pytest.approx(sum(b.mass for b in builder.bodies), rel=1e-12)


@pytest.mark.parametrize(
    ("kind", "dofs"),
    [("ball", 3), ("revolute", 1), ("prismatic", 1), ("cylindrical", 2), ("universal", 2), ("planar", 3), ("fixed", 0)],
)
def test_every_joint_kind_has_its_degrees_of_freedom(kind: str, dofs: int) -> None:
    builder = SceneBuilder()
    base = builder.add_body(1.0, (0.1, 0.1, 0.1), (0.0, 0.0, 0.0))
    tip = builder.add_body(1.0, (0.1, 0.1, 0.1), (0.0, 0.0, -1.0), angular_velocity=(0.0, 0.0, 0.0))
    builder.add_joint_ball(None, base, (0.0, 0.0, 0.5))
    builder.add_joint(kind, base, tip, (0.0, 0.0, -0.5), (0.0, 1.0, 0.0), (1.0, 0.0, 0.0))
    runner = PinocchioRunner(PinocchioScene.from_builder(builder), 1000)
    assert runner.model.nv == 3 + dofs
    for _ in range(10):
        runner.step()
    runner.check()


def test_free_body_with_initial_velocity_falls_on_a_parabola() -> None:
    builder = SceneBuilder()
    builder.add_body(2.0, (0.1, 0.2, 0.25), (1.0, 2.0, 3.0), linear_velocity=(0.5, -1.0, 2.0))
    runner = PinocchioRunner(PinocchioScene.from_builder(builder), 1000)
    for _ in range(500):
        runner.step()
    t = 0.5
    expected = [1.0 + 0.5 * t, 2.0 - t, 3.0 + 2.0 * t - 0.5 * 9.81 * t * t]
    np.testing.assert_allclose(runner.poses()[0][0], expected, atol=1e-9)


def test_double_pendulum_conserves_energy() -> None:
    runner = PinocchioRunner(PinocchioScene.from_builder(scenes.double_pendulum()), 1000)
    e0, _ = runner.energy()
    for _ in range(1000):
        runner.step()
    energy, kinetic = runner.energy()
    assert energy == pytest.approx(e0, abs=1e-6) and kinetic > 1.0


@pytest.mark.skipif(mujoco_available() is not None, reason="needs MuJoCo")
@pytest.mark.parametrize("builder", [scenes.binary_tree(15), scenes.chain(8)])
def test_agrees_with_mujoco_through_the_start_torque(builder: SceneBuilder) -> None:
    """Two independent reduced-coordinate implementations, same RK4 scheme and step: they must agree closely."""
    probe = Probe.from_builder(builder)
    rate = 1000
    runners = [PinocchioRunner(PinocchioScene.from_builder(builder), rate),
               MujocoRunner(MujocoScene.from_builder(builder, 1.0 / rate), "RK4", rate)]  # fmt: skip
    for _ in range(rate // 2):
        for r in runners:
            r.step()
    ours, theirs = (probe.points(*r.poses()) for r in runners)
    moved = np.linalg.norm(ours - probe.points(*PinocchioRunner(runners[0].scene, rate).poses()), axis=1).max()
    assert moved > 1e-2
    assert np.linalg.norm(ours - theirs, axis=1).max() < 1e-7


def test_reference_is_cross_checked_against_pinocchio() -> None:
    pytest.importorskip("mujoco")
    builder = scenes.double_pendulum()
    mscene, pscene = MujocoScene.from_builder(builder, 1e-3), PinocchioScene.from_builder(builder)
    ref = harness.reference(mscene, pscene, Probe.from_builder(builder), harness.ERROR_TIME, 0.0)
    assert ref.pinocchio_residual is not None and ref.pinocchio_residual < 1e-7


def test_fresh_runners_start_from_the_initial_state() -> None:
    """The sweep times fresh runners from a factory: building one must not change the scene."""
    scene = PinocchioScene.from_builder(scenes.double_pendulum())
    factory = partial(PinocchioRunner, scene, 60)
    a, b = factory(), factory()
    a.step()
    assert not np.allclose(a.q, b.q) and np.allclose(b.q, factory().q)


def test_rk4_is_fourth_order_on_fast_spinning_ball_joints() -> None:
    """The trees' start torque spins the root fast: RK4 in the tangent space drops to second order there."""
    builder = scenes.binary_tree(7)
    probe = Probe.from_builder(builder)
    scene = PinocchioScene.from_builder(builder)

    def points(rate: int) -> np.ndarray:
        runner = PinocchioRunner(scene, rate)
        for _ in range(rate // 2):
            runner.step()
        return probe.points(*runner.poses())

    fine = points(2400)
    coarse, half = (np.linalg.norm(points(rate) - fine, axis=1).max() for rate in (150, 300))
    assert coarse / half > 12.0  # 16 for fourth order, 4 for second
