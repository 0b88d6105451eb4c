"""Joint coordinates and rates against their definitions, and resetting or setting the state."""

import numpy as np
import pytest

import warpimpulse as wi
from warpimpulse import scenes
from warpimpulse.transforms import quat_from_axis_angle, quat_mul, quat_rotate

DT = 1 / 120


def _pair(kind: str, axis=(0.0, 0.0, 1.0), axis_child=(1.0, 0.0, 0.0)):
    """A static parent turned off the world axes and a child hanging on `kind` at its anchor."""
    b = wi.SceneBuilder(gravity=(0.0, 0.0, 0.0))
    q0 = quat_from_axis_angle((1.0, 2.0, 3.0), 0.7)
    parent = b.add_static_body((0.3, -0.2, 0.5), q0, name="parent")
    child = b.add_body(2.0, (0.2, 0.3, 0.4), (1.0, 0.5, 0.2), name="child")
    anchor = np.array([0.5, 0.1, 0.3])
    args = (axis, axis_child) if kind == "universal" else (axis,) if kind not in ("ball", "fixed") else ()
    getattr(b, f"add_joint_{kind}")(parent, child, anchor, *args, name="j")
    return b, q0, anchor


def _moved(kind: str, q_rel: np.ndarray, shift: np.ndarray, axis=(0.0, 0.0, 1.0)):
    """The child's state after turning it by q_rel (world frame, about the anchor) and moving it by shift."""
    b, q0, anchor = _pair(kind, axis)
    sim = wi.Simulator(b.finalize("cpu"), DT)
    x, q = sim.positions(), sim.orientations()
    x[1] = anchor + shift + quat_rotate(q_rel, x[1] - anchor)
    q[1] = quat_mul(q_rel, q[1])
    sim.set_state(positions=x, orientations=q)
    return sim, q0


def test_revolute_angle_is_right_handed_about_the_axis():
    axis = np.array([0.0, 0.0, 1.0])  # world axis at build time
    sim, _ = _moved("revolute", quat_from_axis_angle(axis, 0.4), np.zeros(3))
    assert sim.joint_coordinates("j") == pytest.approx([0.4], abs=1e-12)
    sim, _ = _moved("revolute", quat_from_axis_angle(axis, -2.5), np.zeros(3))
    assert sim.joint_coordinates(0) == pytest.approx([-2.5], abs=1e-12)


def test_prismatic_cylindrical_and_planar_offsets():
    axis = np.array([0.0, 0.6, 0.8])
    sim, _ = _moved("prismatic", np.array([0.0, 0.0, 0.0, 1.0]), 0.25 * axis, axis)
    assert sim.joint_coordinates("j") == pytest.approx([0.25], abs=1e-12)
    sim, _ = _moved("cylindrical", quat_from_axis_angle(axis, 0.3), -0.1 * axis, axis)
    assert sim.joint_coordinates("j") == pytest.approx([-0.1, 0.3], abs=1e-12)
    sim, _ = _moved("planar", quat_from_axis_angle(axis, 1.1), np.zeros(3), axis)
    assert sim.joint_coordinates("j") == pytest.approx([0.0, 0.0, 1.1], abs=1e-12)
    # An in-plane move of length 0.2 shows as (x, y) of length 0.2 in the plane.
    in_plane = np.cross(axis, [1.0, 0.0, 0.0])
    sim, _ = _moved("planar", np.array([0.0, 0.0, 0.0, 1.0]), 0.2 * in_plane / np.linalg.norm(in_plane), axis)
    xy = sim.joint_coordinates("j")
    assert np.hypot(xy[0], xy[1]) == pytest.approx(0.2, abs=1e-12) and xy[2] == pytest.approx(0.0, abs=1e-12)


def test_universal_angles_compose_parent_then_child_axis():
    b, q0, anchor = _pair("universal")
    sim = wi.Simulator(b.finalize("cpu"), DT)
    a, c = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])  # world, build time
    alpha, beta = 0.5, -0.8
    q_rel = quat_mul(quat_from_axis_angle(a, alpha), quat_from_axis_angle(c, beta))
    x, q = sim.positions(), sim.orientations()
    x[1] = anchor + quat_rotate(q_rel, x[1] - anchor)
    q[1] = quat_mul(q_rel, q[1])
    sim.set_state(positions=x, orientations=q)
    assert sim.joint_coordinates("j") == pytest.approx([alpha, beta], abs=1e-12)


def test_ball_and_fixed():
    q_rel = quat_from_axis_angle((1.0, 1.0, 0.0), 0.9)
    sim, q0 = _moved("ball", q_rel, np.zeros(3))
    # The relative rotation in the parent's frame: q0^-1 q_rel q0.
    expected = quat_mul(quat_mul(q0 * [-1, -1, -1, 1], q_rel), q0)
    assert sim.joint_coordinates("j") == pytest.approx(expected * np.sign(expected[3]), abs=1e-12)
    fixed, _ = _moved("fixed", np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3))
    assert fixed.joint_coordinates("j").shape == (0,) and fixed.joint_velocities("j").shape == (0,)


def test_rates_match_finite_differences_along_a_run():
    """A falling chain of every kind with coordinates: each rate is the central difference of the coordinates."""
    b = wi.SceneBuilder(gravity=(0.0, 0.0, -9.81))
    axes = {"revolute": (0.0, 1.0, 0.0), "prismatic": (0.0, 0.6, 0.8), "cylindrical": (0.6, 0.0, 0.8),
            "universal": (0.0, 1.0, 0.0), "planar": (0.0, 0.8, 0.6), "ball": None}  # fmt: skip
    parent = None
    for i, (kind, axis) in enumerate(axes.items()):
        body = b.add_body(1.0, (0.05, 0.06, 0.07), (0.3 * (i + 1), 0.0, 0.0), angular_velocity=(0.3, -0.5, 0.8))
        args = (axis, (1.0, 0.0, 0.0)) if kind == "universal" else () if axis is None else (axis,)
        getattr(b, f"add_joint_{kind}")(parent, body, (0.3 * i + 0.15, 0.0, 0.0), *args, name=kind)
        parent = body
    sim = wi.Simulator(b.finalize("cpu"), 1 / 4000, tolerance=1e-11)
    for _ in range(200):
        sim.step()
    names = list(axes)[:-1]
    before = {k: sim.joint_coordinates(k) for k in names}
    sim.step()
    rates = {k: sim.joint_velocities(k) for k in names}
    sim.step()
    for k in names:
        central = (sim.joint_coordinates(k) - before[k]) / (2 * sim.dt)
        assert np.abs(rates[k]).max() > 1e-2, f"{k} did not move"
        assert np.allclose(central, rates[k], rtol=1e-4, atol=1e-5), (k, central, rates[k])


def test_reset_returns_to_the_built_state_and_runs_the_same():
    sim = wi.Simulator(scenes.binary_tree(7).finalize("cpu"), 1 / 60)
    x0, q0 = sim.positions(), sim.orientations()
    first = [sim.step().max_joint_error for _ in range(10)]
    x10 = sim.positions()
    assert np.abs(x10 - x0).max() > 1e-3
    sim.set_external_forces(force=np.ones((7, 3)))
    sim.reset()
    assert sim.time == 0.0 and sim.step_count == 0
    assert np.array_equal(sim.positions(), x0) and np.array_equal(sim.orientations(), q0)
    again = [sim.step().max_joint_error for _ in range(10)]
    assert again == first and np.array_equal(sim.positions(), x10)


def test_set_state_refreshes_the_factorization():
    """Writing a state through set_state gives the same next step as a simulator built at that state (neither
    carries a right-hand side from its past steps: `Simulator.carry`, which set_state forgets)."""
    builder = scenes.chain(4)
    sim = wi.Simulator(builder.finalize("cpu"), 1 / 60, options=wi.StepOptions(carry=False))
    for _ in range(15):
        sim.step()
    state = sim.positions(), sim.orientations(), sim.linear_velocities(), sim.angular_velocities()
    other = wi.Simulator(builder.finalize("cpu"), 1 / 60, options=wi.StepOptions(carry=False))
    other.set_state(*state)
    sim.set_state(*state)  # the same rounding of the quaternions' norms
    sim.step(), other.step()
    assert np.array_equal(sim.positions(), other.positions())
    assert np.array_equal(sim.angular_velocities(), other.angular_velocities())


def test_set_state_checks_everything_before_writing():
    sim = wi.Simulator(scenes.chain(3).finalize("cpu"), 1 / 60)
    x = sim.positions()
    bad_q = sim.orientations()
    bad_q[1] = 0.0
    with pytest.raises(ValueError, match="body1|zero"):
        sim.set_state(positions=x + 1.0, orientations=bad_q)
    assert np.array_equal(sim.positions(), x)
    with pytest.raises(ValueError, match="positions must have shape"):
        sim.set_state(positions=x[:2])
    with pytest.raises(ValueError, match="no joint named"):
        sim.joint_coordinates("nope")
    with pytest.raises(ValueError, match="does not exist"):
        sim.joint_coordinates(7)
