"""The first joint iteration's carried right-hand side (`Simulator(carry=...)`, kernels/carry.py).

The first solve of a step leaves about -E lambda unsolved (the arms turn over the step); that changes little from
one step to the next, so the first solve takes the last step's as an offset. These tests measure it against the
plain iteration: the error left after the first iteration, the iterations saved, the motion (the same to the
tolerance), and that a step's history is all it depends on (reset, set_state, checkpoints). That both schedules,
batched worlds and the split step take it bit for bit is tests/test_schedules.py's, tests/test_worlds.py's and
tests/test_split.py's (it is on by default there).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import warp as wp
from option_runs import assert_saves_iterations, off_and_on
from scipy.spatial.transform import Rotation
from warpimpulse.kernels import carry as carry_kernels
from warpimpulse.kernels import constraints as constraint_kernels

import warpimpulse as wi
from warpimpulse import scenes


def _first_iteration_errors(make, dt: float, before: int) -> tuple[float, float]:
    """The largest joint error after the first iteration of a step, taken after `before` steps one a call (every
    velocity corrected, as the carried values were measured), with the carry and from the same state with c = 0
    (the plain first iteration)."""
    sim = wi.Simulator(make().finalize("cpu"), dt, options=wi.StepOptions(schedule="parallel"))
    for _ in range(before):
        sim.step()
    sim.max_iterations, sim.on_max_iterations = 1, "warn"
    sim._loops_by_h.clear()  # the device loop, captured again with the limit of one iteration
    sim._use_step_size(sim.dt)
    state = sim._state  # as the steps left it, its velocity correction deferred (`Simulator.state`)
    start = [wp.clone(a) for a in (state.body_v, state.body_w)]
    errors = []
    for plain in (False, True):
        wp.copy(state.body_v, start[0])  # the impulses of the first try undone: the frames are t0's
        wp.copy(state.body_w, start[1])
        if plain:
            sim._carry_arrays((sim.dt, 0))[0].zero_()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # one iteration stops short of the tolerance
            iterations, error, *_ = sim._correct_joints(final=True)
        assert iterations == 1
        errors.append(error)
    return errors[0], errors[1]


def test_the_carry_leaves_a_fraction_of_the_first_iterations_error():
    """On the swinging double pendulum at h = 1/120 the carried first solve leaves under 1% of the plain one's
    error in most steps (measured at steps 132, 144, ... 240: 8 of 10 under 0.005, the others 0.01 and 0.14;
    the last step's c alone left 0.05 to 0.21, median 0.1): a c of the wrong sign, never taken, or not
    extrapolated leaves more."""
    ratios = [np.divide(*_first_iteration_errors(scenes.double_pendulum, 1 / 120, b)) for b in range(132, 241, 12)]
    assert np.median(ratios) < 0.02, np.round(ratios, 3)


@pytest.mark.parametrize(
    ("make", "dt", "most"),
    [
        (lambda: scenes.chain(10), 1 / 60, 0.97),
        (scenes.double_pendulum, 1 / 120, 0.7),
        (lambda: scenes.chain(50), 1 / 60, 0.99),
    ],
)
def test_the_carry_saves_iterations_and_ends_where_the_plain_one_does(make, dt, most):
    """Fewer joint iterations over a second of swinging (measured from 1.1 s, the velocity correction deferred as
    by default: chain10 4.12 -> 3.83 a step, the double pendulum 2.23 -> 1.23, chain50 2.58 -> 2.53; with it
    taken every step 3.88 -> 3.70, 2.14 -> 1.17, 2.52 -> 2.30), every step held to the tolerance, and the motion the
    plain iteration's to within what the tolerance lets a second of chaos drift. The double pendulum's bound
    is the extrapolation's (kernels/carry.py): the last step's c alone took 1.56 a step there, 0.73 of plain."""
    runs = off_and_on(make, dt, int(round(1.0 / dt)), "carry", before=int(round(1.1 / dt)))
    assert_saves_iterations(runs, "carry", most)
    np.testing.assert_allclose(runs[True][0].positions(), runs[False][0].positions(), atol=1e-3)


@wp.kernel
def _extrapolate(m: wp.array2d(dtype=wp.vec3d), out: wp.array(dtype=wp.vec3d)):
    i = wp.tid()
    out[i] = carry_kernels.extrapolated(m[i, 0], m[i, 1], m[i, 2], m[i, 3])


def test_c_is_extrapolated_by_the_rule_that_would_have_predicted_best():
    """The next c from the last four measured (newest first): the parabola through the last three, the line
    through the last two or the newest alone, whichever rule, applied a step earlier, came nearest the newest (a
    higher order only by a margin); the line or the newest alone where older values are unknown (NaN: after
    reset, set_state, for a new step size)."""
    nan = np.full(3, np.nan)
    cases = [  # (m0, m1, m2, m3), expected
        (([9.0, 0, 0], [4.0, 0, 0], [1.0, 0, 0], [0.0, 0, 0]), [16.0, 0, 0]),  # a parabola: the parabola
        (([4.0, 0, 0], [3.0, 0, 0], [2.0, 0, 0], [1.0, 0, 0]), [5.0, 0, 0]),  # a line: the line (as near)
        (([1.0, 2, 3], [1.0, 2, 3], [1.0, 2, 3], [1.0, 2, 3]), [1.0, 2, 3]),  # steady: the same by every rule
        (([1.0, 0, 0], [2.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]), [1.0, 0, 0]),  # a jumping value: the newest
        (([3.0, 0, 0], [2.0, 0, 0], [1.0, 0, 0], nan), [4.0, 0, 0]),  # three known: the line at most
        (([3.0, 0, 0], [2.0, 0, 0], nan, nan), [4.0, 0, 0]),  # two known: the line
        (([3.0, 0, 0], nan, nan, nan), [3.0, 0, 0]),  # one known: itself
    ]
    m = wp.array(np.array([c for c, _ in cases]), dtype=wp.vec3d, device="cpu")
    out = wp.zeros(len(cases), dtype=wp.vec3d, device="cpu")
    wp.launch(_extrapolate, len(cases), inputs=[m], outputs=[out], device="cpu")
    np.testing.assert_array_equal(out.numpy(), np.array([e for _, e in cases]))


def test_a_run_depends_on_its_steps_only():
    """reset() and set_state() forget the carry: the next steps are a fresh simulator's, bit for bit; a
    checkpoint keeps it: the run resumed from one is the run that went on."""
    make = lambda: scenes.chain(6).finalize("cpu")  # noqa: E731
    fresh = wi.Simulator(make(), 1 / 60)
    fresh.step(30)
    sim = wi.Simulator(make(), 1 / 60)
    sim.step(17)
    sim.reset()
    sim.step(30)
    for a, b in zip(
        (fresh.positions(), fresh.angular_velocities()), (sim.positions(), sim.angular_velocities()), strict=True
    ):
        assert np.array_equal(a, b)
    state = sim.positions(), sim.orientations(), sim.linear_velocities(), sim.angular_velocities()
    other = wi.Simulator(make(), 1 / 60)
    other.set_state(*state)
    other.time, other.step_count = sim.time, sim.step_count
    sim.set_state(*state)
    sim.step(10), other.step(10)
    assert np.array_equal(sim.positions(), other.positions())


def test_a_checkpoint_keeps_the_carry(tmp_path):
    make = lambda: scenes.chain(6).finalize("cpu")  # noqa: E731
    sim = wi.Simulator(make(), 1 / 60, order=4)  # a row of c a stage's step size
    sim.step(20)
    sim.save_checkpoint(tmp_path / "c.npz")
    resumed = wi.Simulator(make(), 1 / 60, order=4)
    resumed.load_checkpoint(tmp_path / "c.npz")
    sim.step(20), resumed.step(20)
    assert np.array_equal(sim.positions(), resumed.positions())
    assert np.array_equal(sim.angular_velocities(), resumed.angular_velocities())


def test_where_the_carry_is_taken():
    chain = scenes.chain(4).finalize("cpu")
    assert wi.Simulator(chain, 1 / 60).carry
    assert not wi.Simulator(chain, 1 / 60, options=wi.StepOptions(carry=False)).carry
    assert not wi.Simulator(chain, 1 / 60, solver="cg").carry
    assert not wi.Simulator(chain, 1 / 60, solver="iterative").carry
    for solver in ("cg", "iterative"):
        with pytest.raises(ValueError, match=f"carry needs joints, the cholesky solver.*'{solver}'"):
            wi.Simulator(chain, 1 / 60, solver=solver, options=wi.StepOptions(carry=True))
    with pytest.raises(ValueError, match="carry must be True, False or None"):
        wi.Simulator(chain, 1 / 60, options=wi.StepOptions(carry="yes"))
    stack = scenes.box_stack(2).finalize("cpu")  # contacts: their loop does not carry
    assert not wi.Simulator(stack, 1 / 60).carry
    with pytest.raises(ValueError, match="carry needs.*colliders"):
        wi.Simulator(stack, 1 / 60, options=wi.StepOptions(carry=True))


@wp.kernel
def _axis_rows(q0: wp.array(dtype=wp.quatd), axis0: wp.vec3d, rows: wp.array(dtype=wp.mat33d)):
    i = wp.tid()
    rows[i] = constraint_kernels.projection(constraint_kernels.AXIS, q0[i], q0[i], axis0, axis0)


def test_a_hinge_axis_rows_turn_with_its_first_body():
    """The two rows an axis constraint removes (the frame c is measured in) are perpendicular to the axis in
    the world and turn with the first body: the rows at orientation q are those at the identity turned by q,
    also where the axis turns past 0.7 of x (a basis made from the world axis switched its helper there, and the
    carried values were then taken in the wrong rows)."""
    axis = np.array([0.0, 0.0, 1.0])
    angles = np.linspace(0.0, np.pi, 37)  # the axis turns from z through x (|a_x| > 0.7 from 0.78 rad)
    quats = np.array([[0.0, np.sin(a / 2), 0.0, np.cos(a / 2)] for a in angles])  # about y, (x, y, z, w)
    q = wp.array(quats, dtype=wp.quatd, device="cpu")
    rows = wp.zeros(len(angles), dtype=wp.mat33d, device="cpu")
    wp.launch(_axis_rows, len(angles), inputs=[q, wp.vec3d(*axis)], outputs=[rows], device="cpu")
    rows = rows.numpy()
    turn = Rotation.from_quat(quats).as_matrix()
    for p, r in zip(rows, turn, strict=True):
        world_axis = r @ axis
        np.testing.assert_allclose(p[:2] @ p[:2].T, np.eye(2), atol=1e-12)
        np.testing.assert_allclose(p[:2] @ world_axis, 0.0, atol=1e-12)
        np.testing.assert_allclose(p, rows[0] @ r.T, atol=1e-12)


@pytest.mark.fused
def test_each_stage_of_a_composition_keeps_its_c():
    """suzuki5's stages p, p, 1 - 4p, p, p keep a row of c each (and the order-2 fallback one), so that each is
    measured a whole step apart at its own point of the step (`composition.stage_keys`); the fused kernel's
    stage_carry points each stage at its row."""
    from warpimpulse import composition

    p = composition.SCHEMES["suzuki5"].stages[0]
    keys = composition.stage_keys(composition.SCHEMES["suzuki5"].stages)
    assert keys == ((p, 0), (p, 1), (1 - 4 * p, 0), (p, 2), (p, 3))
    sim = wi.Simulator(scenes.chain(4).finalize("cpu"), 1 / 60, order=4)
    assert sim._carry.shape[0] == 6
    assert sim._stage_carry.numpy().tolist() == [0, 1, 2, 3, 4]
