"""K's factor kept across steps (`StepOptions.reuse_factor`, kernels/step.py).

The joint correction with a factor of K from an earlier state is a quasi-Newton iteration: its error is measured on
the real prediction, its impulses act through the current Jacobians, so it stops at the same tolerance and only
its solve count changes. These tests hold it to that against factoring at every step: the same motion within a
few tolerances on a chain and a robot arm, the joints within the tolerance, and factorizations really skipped
(counted by the kernel); velocities handed out between steps exact (their one solve needs K of their state); a
checkpoint continuing bit for bit (the factor in use is kept); and where it is refused.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy_checks import constraint_velocity_errors, sim_state

import warpimpulse as wi
from warpimpulse import scenes

ROOT = Path(__file__).resolve().parent.parent
TOLERANCE = 1e-6
pytestmark = pytest.mark.fused  # K's factor kept across steps is the fused kernel's (`reuse_factor`)

SCENES = {
    "chain20": lambda: scenes.chain(20),
    "arm7": lambda: wi.load_mjcf(ROOT / "benchmarks/models/arm7.xml"),
}


def _sim(make, reuse: bool, order: int = 4, dt: float = 1 / 480) -> wi.Simulator:
    return wi.Simulator(make().finalize("cpu"), dt, tolerance=TOLERANCE, order=order,
                        options=wi.StepOptions(reuse_factor=reuse))  # fmt: skip


@pytest.mark.parametrize("scene", SCENES)
def test_reused_factor_matches_and_skips_factorizations(scene):
    """Order 4 at h = 1/480 (five stages a step; measured 1.0 and 3.0 factorizations a step instead of 5):
    the centres within 20 tolerances of factoring every stage after 120 steps (measured 4e-8 and 1e-9 m),
    every step's joints within the tolerance."""
    runs = {}
    for reuse in (False, True):
        sim = _sim(SCENES[scene], reuse)
        assert sim.reuse_factor is reuse
        before = sim.factorizations
        stats = sim.step(120)
        assert stats.converged and stats.max_joint_error <= TOLERANCE
        runs[reuse] = sim.factorizations - before, sim.state.body_x.numpy()
    always, reused = runs[False][0], runs[True][0]
    assert always == 120 * 5  # a factorization a stage
    assert reused < 0.7 * always  # measured 119 (chain20) and 361 (arm7) of 600
    assert np.abs(runs[True][1] - runs[False][1]).max() < 20 * TOLERANCE


@pytest.mark.parametrize(("rate", "tolerance"), [(60, 1e-6), (120, 1e-5), (60, 1e-4)])
def test_light_bodies_converge_with_an_older_factor(rate, tolerance):
    """Two legs of a free pelvis whose hips and ankles are two hinges at two points of one body (tests/data), so
    that `load_mjcf` puts a light body (1e-6 of the body's mass) between each pair, released with random joint
    rates, order 4 for 1 s. An older factor's solve took the light bodies' joint error from ~1e-5 to 1e-3..1 m,
    and its carried right-hand side the next step's; the correction then diverged (h = 1/60 at both tolerances)
    or took 237 solves a step in 18 substeps a step (h = 1/120). Now such a solve is taken back and its carry
    dropped: measured 7.2, 5.1 and 4.6 solves a step, no substep, every step's joints within the tolerance."""
    pytest.importorskip("mujoco")
    qvel = np.random.default_rng(0).standard_normal(16)  # the free base's 6 rates and the 10 hinges'
    builder = wi.load_mjcf(ROOT / "tests/data/legs_light.xml", qvel=qvel)
    assert sum(body.mass < 1e-5 for body in builder.bodies) == 4  # the light bodies
    sim = wi.Simulator(builder.finalize("cpu"), 1.0 / rate, tolerance=tolerance, order=4)
    assert sim.reuse_factor
    stats = sim.step(rate)
    assert stats.converged and stats.max_joint_error <= tolerance
    assert stats.substeps == rate
    assert stats.linear_iterations <= 10 * rate


def test_velocities_read_between_steps_are_exact():
    """The velocities handed out (read through `Simulator.state` after each `step()`) are corrected with one solve
    with K of their own state: the kernel factors it there where the factor in use is older. The joints' relative
    velocities then vanish (an independent numpy check, to the convention slack), and the motion stays within 20
    tolerances of the run factoring every stage."""
    builder = SCENES["chain20"]()
    runs = {}
    for reuse in (False, True):
        sim = _sim(SCENES["chain20"], reuse)
        before = sim.factorizations
        for _ in range(20):
            sim.step()
            x, q, v, w = sim_state(sim)
            velocity, slack = constraint_velocity_errors(builder, x, q, v, w, with_slack=True)
            assert (velocity - slack).max() <= 1e-9
        runs[reuse] = sim.factorizations - before, x
    assert runs[True][0] < runs[False][0]  # the stages between the reads still keep the factor
    assert np.abs(runs[True][1] - runs[False][1]).max() < 20 * TOLERANCE


def test_checkpoint_keeps_the_factor(tmp_path):
    """A checkpoint holds the factor in use (of an earlier state) and its age: loading it continues bit for bit."""
    sim = _sim(SCENES["chain20"], True)
    sim.step(7)
    path = tmp_path / "c.npz"
    sim.save_checkpoint(path)
    sim.step(9)
    expected = sim.state.body_x.numpy()
    sim.load_checkpoint(path)
    sim.step(9)
    np.testing.assert_array_equal(sim.state.body_x.numpy(), expected)


def test_refused_where_not_taken():
    """The parallel schedule factors at every step: reuse_factor=True there is one line saying so."""
    model = scenes.chain(3).finalize("cpu")
    with pytest.raises(ValueError, match="reuse_factor needs .*parallel schedule"):
        wi.Simulator(model, 1 / 60, options=wi.StepOptions(schedule="parallel", reuse_factor=True))
    assert not wi.Simulator(model, 1 / 60).reuse_factor  # None: off at order 2, on at 4 and 6 (measured)
    assert wi.Simulator(model, 1 / 60, order=4).reuse_factor
