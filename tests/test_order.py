"""Order 4 and 6 in time: symmetric compositions of the paper's step (warpimpulse/composition.py).

Measured on the double pendulum against the reduced-coordinate reference (numpy_checks.py), 1 s from both rods
horizontal, tolerances by the default rule: the default order 4 (Suzuki) gives 3.4e-6, 2.1e-7, 1.3e-8 m at
h = 1/50, 1/100, 1/200 (order 4.01, 4.00); the default order 6 (Kahan & Li) 1.0e-7, 1.5e-9, 2.4e-11 m
(order 6.03, 6.01). The paper's step alone: 2.5e-3, 6.3e-4, 1.6e-4 m.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy_checks import DoublePendulumReference, constraint_errors, constraint_velocity_errors, sim_state

import warpimpulse
from warpimpulse import composition, scenes
from warpimpulse.transforms import quat_mul

ANGLES = (math.pi / 2, math.pi / 2)
JOINTS = ("ball", "revolute", "prismatic", "cylindrical", "universal", "fixed", "planar")


# ------------------------------------------------------------------------------------------ the tables
def _verlet_pendulum(scheme: composition.Scheme, steps: int, duration: float = 2.0) -> np.ndarray:
    """A nonlinear pendulum by Stormer-Verlet (symmetric, order 2) composed by `scheme`: an ODE with no
    constraints, to check the coefficient tables apart from the engine."""
    q, p, h = 2.5, 0.0, duration / steps
    for _ in range(steps):
        for g in scheme.stages:
            p -= 0.5 * g * h * math.sin(q)
            q += g * h * p
            p -= 0.5 * g * h * math.sin(q)
    return np.array([q, p])


@pytest.mark.parametrize("name", sorted(composition.SCHEMES))
def test_scheme_tables(name):
    s = composition.SCHEMES[name]
    assert s.stages == s.stages[::-1] and math.isclose(sum(s.stages), 1.0, abs_tol=1e-15)
    if s.order >= 4:
        assert abs(sum(g**3 for g in s.stages)) < 1e-14
    if s.order >= 6:
        assert abs(sum(g**5 for g in s.stages)) < 1e-14
    exact = _verlet_pendulum(composition.SCHEMES["kahanli9"], 4000)
    e1, e2 = (np.abs(_verlet_pendulum(s, n) - exact).max() for n in (40, 80))
    assert abs(math.log2(e1 / e2) - s.order) < 0.15


def test_order_and_scheme_checked():
    model = scenes.double_pendulum().finalize()
    for bad in (3, 8, "4"):
        with pytest.raises(ValueError, match="order"):
            warpimpulse.Simulator(model, 0.01, order=bad)
    with pytest.raises(ValueError, match="suzuki5"):
        warpimpulse.Simulator(model, 0.01, order=6, options=warpimpulse.StepOptions(scheme="suzuki5"))
    with pytest.raises(ValueError, match="unknown composition"):
        warpimpulse.Simulator(model, 0.01, order=4, options=warpimpulse.StepOptions(scheme="rk4"))


def test_default_tolerance_rule():
    model = scenes.double_pendulum().finalize()
    assert warpimpulse.Simulator(model, 1 / 60).tolerance == 1e-6
    assert warpimpulse.Simulator(model, 1 / 60, order=4).tolerance == pytest.approx(10 * (1 / 60) ** 5)
    assert warpimpulse.Simulator(model, 1 / 30, order=6).tolerance == pytest.approx(200 * (1 / 30) ** 7)
    assert warpimpulse.Simulator(model, 1 / 120, order=6).tolerance == composition.TOLERANCE_FLOOR
    assert warpimpulse.Simulator(model, 1 / 5, order=4).tolerance == composition.TOLERANCE_CAP
    assert warpimpulse.Simulator(model, 1 / 60, order=4, tolerance=1e-5).tolerance == 1e-5


# ------------------------------------------------------------------------------------------ the order
@pytest.fixture(scope="module")
def pendulum():
    builder = scenes.double_pendulum(angles=ANGLES)
    return builder, DoublePendulumReference(builder)


def _max_error(builder, ref, rate: int, order: int, scheme=None, duration: float = 1.0) -> float:
    n = int(round(duration * rate))
    expected = ref.coms(ref.solve(ANGLES, np.arange(n + 1) / rate, rtol=1e-13))
    sim = warpimpulse.Simulator(
        builder.finalize(), 1.0 / rate, order=order, options=warpimpulse.StepOptions(scheme=scheme)
    )
    worst = 0.0
    for k in range(1, n + 1):
        stats = sim.step()
        assert stats.order == order and not stats.fallback
        worst = max(worst, float(np.linalg.norm(sim.positions() - expected[k], axis=1).max()))
    return worst


@pytest.mark.parametrize("order", [4, 6])
def test_measured_order(pendulum, order):
    """The defaults: 4 +- 0.3 and 6 +- 0.5 against the independent reference."""
    builder, ref = pendulum
    e1, e2 = (_max_error(builder, ref, rate, order) for rate in (50, 100))
    observed = math.log2(e1 / e2)
    print(f"\norder {order}: max COM error {e1:.3g} m at h = 1/50, {e2:.3g} m at 1/100: observed order {observed:.2f}")
    assert abs(observed - order) < (0.3 if order == 4 else 0.5)
    assert e2 < (1e-6 if order == 4 else 1e-8)


@pytest.mark.parametrize("name", [n for n, s in composition.SCHEMES.items() if s.order > 2])
def test_every_scheme_reaches_its_order(pendulum, name):
    builder, ref = pendulum
    s = composition.SCHEMES[name]
    e1, e2 = (_max_error(builder, ref, rate, s.order, name) for rate in (50, 100))
    assert abs(math.log2(e1 / e2) - s.order) < 0.5


# ------------------------------------------------------------------------------------------ symmetry
def _moving_chain(joint: str, links: int = 4) -> warpimpulse.SceneBuilder:
    """A chain whose every joint moves: a ball joint to the world, then `joint` and ball joints in turn, under
    a tilted gravity (so prismatic joints slide too)."""
    builder = scenes.chain(links, joint=("ball", joint))
    builder.gravity = np.array([2.0, 3.0, -9.81])
    return builder


def _state(sim) -> np.ndarray:
    x, q, v, w = sim_state(sim)
    q = q * np.sign(q[:, 3:4] + 1e-300)
    return np.concatenate([x, q, v, w], axis=1)


def _symmetry_gaps(sim) -> list[float]:
    """The largest state difference from the current state after step(h) then step(-h), h = 1/30 and 1/60."""
    start = _state(sim)
    gaps = []
    for h in (1 / 30, 1 / 60):
        sim.set_state(start[:, :3], start[:, 3:7], start[:, 7:10], start[:, 10:])
        for hh in (h, -h):
            sim._advance(hh, sim.max_substep_depth, (1.0,))
        gaps.append(np.abs(_state(sim) - start).max())
    return gaps


@pytest.mark.parametrize("joint", JOINTS)
def test_step_is_symmetric(joint):
    """step(h) then step(-h) returns to the start, with an error shrinking like h^5 or faster (the RK4 free
    flight is the only part that is not exactly reversible), for every joint type and so every basic
    constraint: the impulses at t0 and the projection at t0+h use the Jacobian of the same constraint."""
    sim = warpimpulse.Simulator(
        _moving_chain(joint).finalize(),
        1 / 30,
        tolerance=1e-13,
        options=warpimpulse.StepOptions(defer_velocities=False),
    )
    for _ in range(10):
        sim.step()  # moving, on the constraints
    gaps = _symmetry_gaps(sim)
    print(f"\n{joint}: step(h) step(-h) from the start: {gaps[0]:.3g} at h = 1/30, {gaps[1]:.3g} at 1/60")
    assert gaps[1] < 1e-6
    assert gaps[1] < 1e-12 or gaps[0] / gaps[1] > 2**4.5


@pytest.mark.parametrize("joint", JOINTS)
def test_jacobian_is_the_constraint_gradient(joint):
    """For every basic constraint, J (used by the impulses at t0 and by the projection at t0+h) is the
    derivative of the constraint's error function: moving a state on the constraints by eps times a random
    twist makes the independently computed error eps |J twist| to first order."""
    builder = _moving_chain(joint)
    sim = warpimpulse.Simulator(builder.finalize(), 1 / 30, tolerance=1e-13)
    for _ in range(10):
        sim.step()
    x, q, _, _ = sim_state(sim)
    assert constraint_errors(builder, x, q).max() < 1e-12
    rng = np.random.default_rng(3)
    v, w = rng.normal(size=x.shape), rng.normal(size=x.shape)
    sim.state.body_v.assign(v)
    sim.state.body_w.assign(w)
    sim._velocity_errors.launch()  # |J_i (v, w)| with the Jacobian at the current frames
    rate = sim.errors.numpy().copy()
    eps = 1e-6
    angle = np.linalg.norm(w, axis=1, keepdims=True)
    turn = np.concatenate([w / angle * np.sin(0.5 * eps * angle), np.cos(0.5 * eps * angle)], axis=1)
    moved = constraint_errors(builder, x + eps * v, quat_mul(turn, q))
    np.testing.assert_allclose(moved / eps, rate, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("solver", ["cg", "iterative"])
def test_every_solver_steps_backwards(solver):
    """CG and the paper's iterative sweeps take negative steps too: step(h) then step(-h) returns to the start."""
    sim = warpimpulse.Simulator(
        _moving_chain("revolute").finalize(), 1 / 60, tolerance=1e-10, solver=solver, max_iterations=5000
    )
    for _ in range(10):
        sim.step()
    start = _state(sim)
    sim._advance(1 / 60, sim.max_substep_depth, (1.0,))
    assert np.abs(_state(sim) - start).max() > 1e-3
    sim._advance(-1 / 60, sim.max_substep_depth, (1.0,))
    assert np.abs(_state(sim) - start).max() < 1e-7  # the tolerances, not the step, set this


def test_backward_spin_is_substepped():
    """A body spinning fast takes several RK4 rotation substeps in a step; a negative step must take as many."""
    builder = warpimpulse.SceneBuilder(gravity=(0.0, 0.0, 0.0))
    builder.add_body(1.0, np.diag([1.0, 2.0, 3.0]), (0, 0, 0), angular_velocity=(30.0, 1.0, 0.5))
    sim = warpimpulse.Simulator(builder.finalize(), 1 / 30, options=warpimpulse.StepOptions(max_rotation=None))
    start = _state(sim)
    sim._advance(1 / 30, 0, (1.0,))
    assert np.abs(_state(sim) - start).max() > 0.1
    sim._advance(-1 / 30, 0, (1.0,))
    assert np.abs(_state(sim) - start).max() < 1e-5


# ------------------------------------------------------------------------------------------ the joints
@pytest.mark.parametrize("order", [4, 6])
def test_joints_hold_after_every_substep(order):
    """Measured with the independent numpy checks after every base step of the composition, backward ones
    included, on a chain mixing every joint type. The parallel schedule takes base steps one by one from the
    host, where they can be looked at; the fused one takes the same steps bit for bit (test_schedules.py)."""
    builder = scenes.chain(7, joint=JOINTS)
    builder.gravity = np.array([2.0, 3.0, -9.81])
    sim = warpimpulse.Simulator(
        builder.finalize(),
        1 / 30,
        order=order,
        options=warpimpulse.StepOptions(schedule="parallel", defer_velocities=False),
    )
    seen = []
    base_step = sim._base_step

    def checked(h, final, stage=0):
        out = base_step(h, final, stage)
        x, q, v, w = sim_state(sim)
        velocity, slack = constraint_velocity_errors(builder, x, q, v, w, with_slack=True)
        seen.append(h)
        assert constraint_errors(builder, x, q).max() <= 2 * sim.tolerance, h
        assert (velocity - slack).max() <= 1e-9, h
        return out

    sim._base_step = checked
    for _ in range(10):
        sim.step()
    assert min(seen) < 0 and len(seen) == 10 * len(sim.scheme.stages)


def test_fall_back_to_order_2():
    """A step asked to fall back (a non-reversible event) is the paper's step, and says why in its stats."""
    builder = scenes.double_pendulum(angles=(1.0, 2.0))
    four = warpimpulse.Simulator(builder.finalize(), 1 / 60, order=4, tolerance=1e-10)
    two = warpimpulse.Simulator(builder.finalize(), 1 / 60, tolerance=1e-10)
    four.step()
    two.state.copy_from(four.state)
    two._update_frames()
    four.fall_back("contact at the tip")
    stats = four.step()
    assert (stats.order, stats.fallback) == (2, "contact at the tip")
    two.step()
    np.testing.assert_array_equal(four.positions(), two.positions())
    stats = four.step()
    assert (stats.order, stats.fallback) == (4, "")


def test_substep_rules_apply_to_whole_composed_steps():
    """A fast spin splits a composed step into whole composed substeps: the same as composed steps of dt/2."""
    builder = scenes.double_pendulum(angles=(1.0, 2.0))
    builder.bodies[1].angular_velocity = np.array([0.0, 18.0, 0.0])  # the hinge axis: a consistent spin
    builder.bodies[1].linear_velocity = np.cross(
        [0.0, 18.0, 0.0], builder.bodies[1].position - builder.joints[1].anchor
    )
    # K factored at every stage in both (`reuse_factor` would keep it along different sequences of stages)
    split = warpimpulse.Simulator(
        builder.finalize(),
        1 / 20,
        tolerance=1e-10,
        order=4,
        options=warpimpulse.StepOptions(max_rotation=0.5, reuse_factor=False),
    )
    halves = warpimpulse.Simulator(
        builder.finalize(),
        1 / 40,
        tolerance=1e-10,
        order=4,
        options=warpimpulse.StepOptions(max_rotation=None, reuse_factor=False),
    )
    stats = split.step()
    assert stats.substeps == 2 and stats.order == 4
    halves.step(2)  # one call, as the split step: the velocities corrected at its end (`defer_velocities`)
    np.testing.assert_array_equal(split.positions(), halves.positions())


def test_failed_composed_step_is_redone_as_two_halves():
    """A stage that runs out of iterations undoes the whole composed step, which is redone as two composed
    halves: the same bits as a simulator at dt/2."""
    builder = scenes.double_pendulum(angles=(1.0, 2.0))
    # K factored at every stage in both (`reuse_factor` would keep it along different sequences of stages)
    settings = dict(tolerance=1e-12, order=4, max_iterations=5, max_rotation=None, reuse_factor=False)
    whole = warpimpulse.Simulator(builder.finalize(), 1 / 10, **warpimpulse.StepOptions.fold(settings))
    halves = warpimpulse.Simulator(builder.finalize(), 1 / 20, **warpimpulse.StepOptions.fold(settings))
    stats = whole.step()
    assert stats.substeps > 1 and stats.order == 4 and stats.converged
    halves.step(2)  # one call, as the halved step: the velocities corrected at its end (`defer_velocities`)
    np.testing.assert_array_equal(whole.positions(), halves.positions())
    np.testing.assert_array_equal(whole.angular_velocities(), halves.angular_velocities())


# ------------------------------------------------------------------------------------------ energy, checkpoints
def _energy_series(duration: float) -> np.ndarray:
    builder = scenes.double_pendulum(angles=(1.0, 0.5))
    sim = warpimpulse.Simulator(builder.finalize(), 1 / 30, order=4)
    out = [sim.energy()]
    for _ in range(int(round(duration * 30))):
        sim.step()
        out.append(sim.energy())
    return np.array(out)


def _check_energy(e: np.ndarray, duration: float) -> None:
    scale = 9.81 * 2.0  # J: m g L, the potential energy scale of the pendulum
    t = np.linspace(0.0, duration, len(e))
    slope = np.polyfit(t, e - e[0], 1)[0]
    print(f"\nenergy over {duration:g} s: max |E - E0| {np.abs(e - e[0]).max():.3g} J, trend {slope:.3g} J/s")
    assert np.abs(e - e[0]).max() < 1e-4 * scale
    assert abs(slope) * duration < 1e-5 * scale


def test_energy_bounded_100s():
    """Order 4 at h = 1/30 on a conservative scene: 100 s (15000 base steps, a few seconds)."""
    _check_energy(_energy_series(100.0), 100.0)


@pytest.mark.parametrize("order", [2, 4, 6])
def test_checkpoint_resume_bit_identical(tmp_path, order):
    builder = scenes.binary_tree(15)  # a torque on the root for the first second
    model = builder.finalize()
    a = warpimpulse.Simulator(model, 1 / 10, order=order)
    for _ in range(5):
        a.step()
    a.save_checkpoint(tmp_path / "c.npz")
    for _ in range(10):
        a.step()
    b = warpimpulse.Simulator(model, 1 / 10, order=order)
    b.load_checkpoint(tmp_path / "c.npz")
    for _ in range(10):
        b.step()
    for get in ("positions", "orientations", "linear_velocities", "angular_velocities"):
        np.testing.assert_array_equal(getattr(a, get)(), getattr(b, get)())
    other = warpimpulse.Simulator(model, 1 / 10, order=2 if order != 2 else 4)
    with pytest.raises(ValueError, match="composition"):
        other.load_checkpoint(tmp_path / "c.npz")


# ------------------------------------------------------------------------------------------ split forces
def _sprung_chain() -> warpimpulse.SceneBuilder:
    """The revolute `_moving_chain` with forces of the poses alone on it: an undamped joint spring on every
    hinge (rest 0.2 rad), a spring from the last link to a world point and an effort motor at 0.4 N m on the
    second hinge."""
    builder = _moving_chain("revolute")
    for j in range(1, len(builder.joints), 2):
        builder.add_joint_spring(j, 8.0, rest=0.2)
    last = len(builder.bodies) - 1
    builder.add_spring(None, last, (2.0, 1.0, -1.0), builder.bodies[last].position, 30.0, rest_length=1.0)
    builder.add_motor(1, mode="effort", target=0.4)
    return builder


def test_split_forces_keep_the_step_symmetric_and_order_4():
    """Half kicks about each base step (`split_forces`) keep it symmetric: step(h) then step(-h) returns to the
    start with a gap shrinking like h^5 or faster, so Suzuki's composition keeps order 4: measured against the
    coupled RK4 prediction at h = 1/960 (the other way to integrate the same forces) over 0.5 s."""
    model = _sprung_chain().finalize()
    sim = warpimpulse.Simulator(model, 1 / 30, tolerance=1e-13, options=warpimpulse.StepOptions(defer_velocities=False))
    assert sim._kicked
    sim.step(10)
    gaps = _symmetry_gaps(sim)
    assert gaps[1] < 1e-9 and gaps[0] / gaps[1] > 2**4.5, gaps

    coupled = warpimpulse.StepOptions(split_forces=False)
    reference = warpimpulse.Simulator(model, 1 / 960, order=4, tolerance=1e-13, options=coupled)
    assert reference._forced
    reference.step(480)
    errors = []
    for rate in (30, 60):
        split = warpimpulse.Simulator(model, 1 / rate, order=4, tolerance=1e-13)
        assert split._kicked and split.defer_velocities
        split.step(rate // 2)
        errors.append(float(np.abs(split.positions() - reference.positions()).max()))
    observed = math.log2(errors[0] / errors[1])
    print(f"\nsplit forces at order 4: {errors[0]:.3g} m at 1/30, {errors[1]:.3g} at 1/60 (order {observed:.2f})")
    assert abs(observed - 4.0) < 0.4 and errors[1] < 1e-5


def test_split_forces_run_alike_on_both_schedules():
    """The parallel schedule kicks where the fused kernel does: the same state, bit for bit, at orders 2 and 4
    (a kept factor off, which only the fused kernel has)."""
    model = _sprung_chain().finalize()
    for order in (2, 4):
        runs = []
        for schedule in ("fused", "parallel"):
            options = warpimpulse.StepOptions(schedule=schedule, reuse_factor=False)
            sim = warpimpulse.Simulator(model, 1 / 60, order=order, tolerance=1e-10, options=options)
            assert sim._kicked and sim.schedule == schedule
            sim.step(30)
            runs.append(_state(sim))
        np.testing.assert_array_equal(runs[0], runs[1])
