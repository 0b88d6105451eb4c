"""The velocity correction deferred to where the state is handed out (`Simulator(defer_velocities=...)`).

A step's velocity correction acts through the Jacobians of the next step's t0, as that step's joint correction
does, and the prediction depends only on the velocities the impulses leave; so the next joint correction reaches
the same state whether or not the correction came first, and `step(n)` corrects only its last step's velocities.
These tests hold it to that against the correction taken every step: the same motion, the difference shrinking
with the tolerance (a deferral that lost or doubled a velocity change would leave a difference the tolerance does
not shrink); handed-out velocities that hold by an independent numpy check; the stats of the deferred steps; and
where it is taken. That the fused and parallel schedules and the split step on threads defer bit for bit alike is
tests/test_schedules.py's and tests/test_split.py's (it is on by default there).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy_checks import constraint_errors, constraint_velocity_errors, sim_state
from rigs import JOINTS, welded_hinge

import warpimpulse as wi
from warpimpulse import scenes

SCENES = {
    "chain10": (lambda: scenes.chain(10), 1 / 60, {}),
    "tree31": (lambda: scenes.binary_tree(31), 1 / 30, {}),
    "double_pendulum": (scenes.double_pendulum, 1 / 120, {}),
    "every_joint_type": (lambda: scenes.chain(7, joint=list(JOINTS)), 1 / 60, {}),
    "loop_redundant_rows": (lambda: welded_hinge(2.0), 1 / 60, {}),
    "star31_body_matrix": (lambda: scenes.star(31), 1 / 60, {"formulation": "body"}),
    "chain10_order4": (lambda: scenes.chain(10), 1 / 60, {"order": 4}),
    "chain10_parallel": (lambda: scenes.chain(10), 1 / 60, {"schedule": "parallel"}),
}


def _run(case: str, tolerance: float, defer: bool) -> tuple[wi.Simulator, wi.StepStats]:
    make, dt, settings = SCENES[case]
    sim = wi.Simulator(
        make().finalize(),
        dt,
        tolerance=tolerance,
        **wi.StepOptions.fold({**settings, "defer_velocities": defer}),
    )
    sim.step(20)
    return sim, sim.step(10)


def _state(sim: wi.Simulator) -> np.ndarray:
    return np.concatenate([a.ravel() for a in sim_state(sim)])


@pytest.mark.parametrize("case", SCENES)
def test_deferred_corrections_reach_the_same_motion(case):
    """30 steps in two calls, deferring and not: the states (positions, quaternions, velocities) agree to within
    what the tolerance lets two runs drift (measured at 1e-6: 5e-8 to 7e-5), and at a tolerance of 1e-10 to 56
    to 47,000 times less (1e-11 to 5e-9), so the difference is the joint correction's tolerance, not the
    deferral."""
    gaps = {}
    for tolerance in (1e-6, 1e-10):
        (every, every_stats), (deferred, deferred_stats) = (_run(case, tolerance, d) for d in (False, True))
        assert deferred.defer_velocities and not every.defer_velocities
        assert deferred_stats.converged and every_stats.converged
        gaps[tolerance] = np.abs(_state(deferred) - _state(every)).max()
        assert gaps[tolerance] < 100 * tolerance, (tolerance, gaps[tolerance])
    print(f"\n{case}: {gaps}")
    assert gaps[1e-10] < 1e-2 * max(gaps[1e-6], 1e-7), gaps


@pytest.mark.parametrize("case", ["chain10", "every_joint_type", "chain10_order4", "chain10_parallel"])
def test_handed_out_velocities_hold_and_deferred_steps_say_so(case):
    """The velocities read are corrected: the joints' relative velocities hold by the independent numpy check (a
    deferral that never corrected leaves ~1e-2 m/s here). Every step leaves its correction to the next step or to
    the read (`Simulator.state`): the steps, one a call or many, report no velocity iteration and an unmeasured
    (NaN) velocity error, and converged, and reading the positions alone takes no correction. After a read of
    the velocities the next call's last step takes its correction itself (`Simulator._lazy_call`), and says so."""
    make, dt, settings = SCENES[case]
    builder = make()
    sim = wi.Simulator(builder.finalize(), dt, **wi.StepOptions.fold(settings))
    sim.step(30)
    stats = sim.simulate(20 * dt)
    assert [s.velocity_iterations for s in stats] == [0] * 20
    assert all(math.isnan(s.max_velocity_error) for s in stats)
    assert all(s.converged and s.max_joint_error <= sim.tolerance for s in stats)
    sim.positions(), sim.orientations()
    assert sim._handout  # positions need no correction: still to be taken
    raw = [a.numpy().copy() for a in (sim._state.body_v, sim._state.body_w)]
    x, q, v, w = sim_state(sim)
    assert not sim._handout
    velocity, slack = constraint_velocity_errors(builder, x, q, v, w, with_slack=True)
    assert (velocity - slack).max() <= 1e-9
    assert constraint_errors(builder, x, q).max() <= 2 * sim.tolerance
    assert constraint_velocity_errors(builder, x, q, *raw).max() > 1e3 * velocity.max()  # what the read corrected
    combined = sim.step(5)  # a reader: the call's last step takes the correction itself, for the next read
    assert combined.velocity_iterations == 1 and combined.max_velocity_error <= sim.velocity_tolerance
    assert not sim._handout
    combined = sim.step(5)  # not read since: left to the read again
    assert combined.velocity_iterations == 0 and math.isnan(combined.max_velocity_error) and sim._handout


@pytest.mark.parametrize("case", ["chain10", "chain10_order4"])
def test_a_step_a_call_takes_the_steps_of_one_call(case):
    """Left to the next step, the velocity correction no longer depends on how the steps are called: 24 steps one
    `step()` a call, reading the positions after each, and the same in one `step(24)` reach the same state bit
    for bit; reading the velocities too (which takes their correction) moves them within the tolerance."""
    make, dt, settings = SCENES[case]
    model = make().finalize()
    one, many, read = (wi.Simulator(model, dt, **wi.StepOptions.fold(settings)) for _ in range(3))
    for _ in range(24):
        one.step()
        one.positions(), one.orientations()
        read.step()
        read.energy()
    many.step(24)
    assert np.array_equal(_state(one), _state(many))
    assert 0.0 < np.abs(_state(read) - _state(many)).max() < 100 * one.tolerance


def _springs() -> wi.SceneBuilder:
    b = scenes.chain(3)
    b.add_joint_spring(0, stiffness=10.0, damping=1.0)
    return b


def _limits() -> wi.SceneBuilder:
    b = scenes.chain(3)
    b.add_joint_limit(0, -0.3, 0.3)
    return b


@pytest.mark.parametrize(
    ("make", "settings", "why"),
    [
        (scenes.chain, {"solver": "cg"}, "'cg' solver"),
        (scenes.chain, {"solver": "iterative"}, "'iterative' solver"),
        (welded_hinge, {"formulation": "split"}, "split formulation"),
        (_springs, {}, "force elements"),
        (_limits, {}, "joint limits"),
        (lambda: scenes.box_stack(2), {}, "contacts"),
        (lambda: scenes.chain(3).replicate(2), {}, "batched worlds"),
    ],
)
def test_deferred_only_where_the_next_joint_correction_reaches_the_same_state(make, settings, why):
    """Velocity-dependent forces, rows, contacts (their velocity phases), CG (a correction that stops short) and
    batched worlds keep every step's correction; asked for there, a ValueError says why."""
    assert wi.Simulator(scenes.chain(3).finalize(), 1 / 60).defer_velocities
    model = make().finalize()
    assert not wi.Simulator(model, 1 / 60, **wi.StepOptions.fold(settings)).defer_velocities
    with pytest.raises(ValueError, match=why):
        wi.Simulator(model, 1 / 60, **wi.StepOptions.fold({**settings, "defer_velocities": True}))
    with pytest.raises(ValueError, match="defer_velocities must be"):
        wi.Simulator(scenes.chain(3).finalize(), 1 / 60, options=wi.StepOptions(defer_velocities="yes"))


@pytest.mark.parametrize("schedule", ["fused", "parallel"])
@pytest.mark.parametrize("defer", [True, False])
def test_a_velocity_correction_over_its_tolerance_says_what_it_left(schedule, defer):
    """The velocity correction is one exact solve: one that leaves more than the velocity tolerance (here a
    tolerance below round-off) raises naming the error it left and the joints, not an iteration limit it never
    had: at the first step without the deferral, with it at the step handed out (the third): by `step(3)` on
    the parallel schedule, by the read of the velocities after it on the fused one."""
    sim = wi.Simulator(
        scenes.chain(5).finalize(),
        1 / 60,
        velocity_tolerance=1e-30,
        options=wi.StepOptions(schedule=schedule, defer_velocities=defer),
    )
    step = 3 if defer else 1
    with pytest.raises(wi.SimulationError, match=rf"step {step} .*the velocity correction left .*, over its "
                                                 r"tolerance of 1e-30; worst joints: ") as err:  # fmt: skip
        sim.step(3)
        sim.linear_velocities()
    assert "iterations" not in str(err.value)


@pytest.mark.parametrize("worlds", [1, 2])
@pytest.mark.parametrize("schedule", ["fused", "parallel"])
def test_round_off_over_the_tolerance_takes_one_solve_more(schedule, worlds):
    """One solve is exact but for round-off; where that leaves more than the velocity tolerance, one solve more
    takes it up (`VELOCITY_SOLVES`, iterative refinement) before the step is reported: two velocity iterations
    under a tolerance below round-off, on both schedules and in batched worlds."""
    sim = wi.Simulator(
        scenes.chain(5).replicate(worlds).finalize(),
        1 / 60,
        velocity_tolerance=1e-30,
        on_max_iterations="warn",
        options=wi.StepOptions(schedule=schedule, defer_velocities=False),
    )
    with pytest.warns(RuntimeWarning, match="the velocity correction left"):
        stats = sim.step()
    assert stats.velocity_iterations == wi.kernels.step.VELOCITY_SOLVES == 2
