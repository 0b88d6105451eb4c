"""Closed kinematic loops (method paper, section 4.6) with the default solver, redundant constraints included.

The planar four-bar's reference is its geometry: Freudenstein's equation
K1 cos(theta4) - K2 cos(theta2) + K3 = cos(theta2 - theta4), K1 = d/a, K2 = d/c, K3 = (a^2 - b^2 + c^2 + d^2)/(2ac),
between the crank angle theta2 and the rocker angle theta4, both read from the bodies' orientations.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import warpimpulse as wi
from warpimpulse import scenes

TOLERANCE = 1e-6


def hinge_angle(q: np.ndarray, q0: np.ndarray) -> float:
    """The angle about -y of the rotation from q0 to q (both (x, y, z, w))."""
    rel = wi.transforms.quat_mul(q, wi.transforms.quat_conj(q0))
    return 2.0 * math.atan2(-rel[1], rel[3])


def freudenstein(theta2: float, theta4: float, lengths=scenes.FOUR_BAR) -> float:
    d, a, b, c = lengths
    k1, k2, k3 = d / a, d / c, (a * a - b * b + c * c + d * d) / (2.0 * a * c)
    return k1 * math.cos(theta4) - k2 * math.cos(theta2) + k3 - math.cos(theta2 - theta4)


def test_four_bar_follows_freudenstein_with_the_default_solver():
    """10 s of the crank-rocker, the crank driven at 1 turn/s: every joint holds to the tolerance in every step,
    the rocker angle is the linkage's for the crank angle (C within 5e-6 m of the geometric solution) and
    Freudenstein's residual is within its sensitivity to those 5e-6 m; the 3 redundant rows are reported."""
    builder = scenes.four_bar()
    sim = wi.Simulator(builder.finalize(), dt=1.0 / 60.0)  # the defaults: Cholesky, tolerance 1e-6
    assert sim.redundant_rows == 3
    q0 = sim.orientations()
    d, a, b, c = scenes.FOUR_BAR
    bp, cp = scenes.four_bar_points(0.5 * math.pi)
    theta2_0, theta4_0 = 0.5 * math.pi, math.atan2(cp[2], cp[0] - d)
    worst_c, worst_residual, turns = 0.0, 0.0, 0.0
    for _ in range(600):
        stats = sim.step()
        assert stats.converged and stats.max_joint_error <= TOLERANCE
        assert sim.joint_errors().max() <= TOLERANCE
        q = sim.orientations()
        theta2 = theta2_0 + hinge_angle(q[0], q0[0])
        theta4 = theta4_0 + hinge_angle(q[2], q0[2])
        _, c_exact = scenes.four_bar_points(theta2)
        c_measured = np.array([d + c * math.cos(theta4), 0.0, c * math.sin(theta4)])
        worst_c = max(worst_c, float(np.linalg.norm(c_measured - c_exact)))
        worst_residual = max(worst_residual, abs(freudenstein(theta2, theta4)))
    turns = sim.joint_coordinates(0)[0]
    assert worst_c < 5e-6
    assert worst_residual < 5e-6 * (d / a) / c * 4.0  # |dF/dtheta4| <= K1 + 1, over the rocker's length
    np.testing.assert_allclose(sim.joint_velocities(0), 2.0 * math.pi, rtol=1e-9)  # the stiff motor's speed
    assert np.isfinite(turns)


def test_fixed_joint_and_hinge_on_one_pair_hold_with_the_defaults():
    """A hinge and a fixed joint between the same two bodies: the hinge's five rows repeat the fixed joint's six;
    the loop joint's redundant rows are regularised (5 reported) and the pair moves as one rigid body."""
    b = wi.SceneBuilder()
    base = b.add_body(1.0, (0.1, 0.1, 0.1), (0.0, 0.0, 0.0), name="base")
    arm = b.add_body(2.0, (0.1, 0.2, 0.3), (1.0, 0.0, 0.0), name="arm")
    b.add_joint_ball(None, base, (-0.5, 0.0, 0.0), name="pivot")
    b.add_joint_fixed(base, arm, (0.5, 0.0, 0.0), name="weld")
    b.add_joint_revolute(base, arm, (0.5, 0.0, 0.0), (0.0, 1.0, 0.0), name="hinge")
    sim = wi.Simulator(b.finalize(), dt=1.0 / 60.0)
    assert sim.redundant_rows == 5
    r0 = sim.positions()[1] - sim.positions()[0]
    for _ in range(120):
        assert sim.step().converged
        assert sim.joint_errors().max() <= TOLERANCE
    r = wi.transforms.quat_rotate(
        wi.transforms.quat_conj(sim.orientations()[0]), sim.positions()[1] - sim.positions()[0]
    )
    np.testing.assert_allclose(r, r0, atol=1e-5)  # welded: the arm has not moved in the base's frame
    assert sim.positions()[1][2] < -0.1  # the pair swung down


@pytest.mark.slow
def test_four_bar_holds_with_cg():
    """CG on the singular K (and the stiff motor with the free mobility: no factor) holds it too, slowly: 35 s."""
    solver = "cg"
    sim = wi.Simulator(scenes.four_bar().finalize(), dt=1.0 / 60.0, solver=solver)
    for _ in range(60):
        assert sim.step().converged
    assert sim.joint_errors().max() <= TOLERANCE


def test_stiff_motor_holds_its_speed_under_load_and_saturates():
    """A stiff velocity motor turns a braked wheel at exactly its target; with max_force below the load the
    wheel is braked down instead, the motor giving max_force."""

    def wheel(max_force):
        b = wi.SceneBuilder()
        w = b.add_body(2.0, (0.05, 0.05, 0.09), (0.0, 0.0, 1.0))
        j = b.add_joint_revolute(None, w, (0.0, 0.0, 1.0), (0.0, 0.0, 1.0))
        b.add_force(w, torque=(0.0, 0.0, -2.0))
        b.add_motor(j, "velocity", target=3.0, max_force=max_force, stiff=True)
        sim = wi.Simulator(b.finalize(), dt=0.01)
        for _ in range(100):
            assert sim.step().converged
        return sim

    np.testing.assert_allclose(wheel(10.0).angular_velocities()[0, 2], 3.0, rtol=1e-12)
    slow = wheel(1.5)  # 1.5 N m against 2 N m: decelerates at 0.5 / 0.09 rad/s^2 from rest... backwards
    np.testing.assert_allclose(slow.angular_velocities()[0, 2], -0.5 / 0.09 * 1.0, rtol=1e-6)


def test_car_held_up_wheels_turn_at_their_targets_and_steering_follows():
    """The car (chassis fixed to the world): each wheel turns at its motor's target, the steering angle follows
    its target and a new one, the suspension sliders rest at their preloaded springs' equilibrium."""
    builder = scenes.car()
    sim = wi.Simulator(builder.finalize(), dt=1.0 / 60.0)
    names = sim.model.joint_name
    axles = [names.index(f"{w}_axle") for w in ("front_left", "front_right", "rear_left", "rear_right")]
    steering = [names.index(f"{w}_steering") for w in ("front_left", "front_right")]
    for _ in range(60):
        assert sim.step().converged
    for j in axles:
        np.testing.assert_allclose(sim.joint_velocities(j), scenes.CAR_WHEEL_SPEED, rtol=1e-9)
    for j in steering:
        np.testing.assert_allclose(sim.joint_coordinates(j), scenes.CAR_STEERING, atol=1e-6)
    for motor, target in ((0, 2.0), (1, 2.0), (2, -3.0), (3, -3.0), (4, -0.2), (5, -0.2)):
        sim.set_motor_target(motor, target)
    for _ in range(60):
        assert sim.step().converged
        assert sim.joint_errors().max() <= TOLERANCE
    for j, target in zip(axles, (2.0, 2.0, -3.0, -3.0)):
        np.testing.assert_allclose(sim.joint_velocities(j), target, rtol=1e-9)
    for j in steering:
        np.testing.assert_allclose(sim.joint_coordinates(j), -0.2, atol=1e-6)
    for w in ("front_left", "rear_right"):
        assert abs(sim.joint_coordinates(names.index(f"{w}_suspension"))[0]) < 5e-3


def test_walking_machine_loops_close_and_feet_trace_closed_curves():
    """Every loop closes to the tolerance in every step (12 redundant rows: 3 per planar leg loop in 3D); each
    foot traces a closed curve per crank turn (back at its start after one turn, having enclosed an area), the
    same curve as the slotted lever's geometry (`walker_leg_points`)."""
    sim = wi.Simulator(scenes.walking_machine().finalize(), dt=1.0 / 60.0)
    assert sim.redundant_rows == 12 and len(sim.model.topology.loop_joints) == 4
    names = sim.model.body_name
    legs = [names.index(f"leg{i}_leg") for i in range(4)]
    x0, q0 = sim.positions()[legs], sim.orientations()[legs]
    feet = []
    for _, _, phase in scenes.WALKER_LEGS:
        o, p, s, f = scenes.walker_leg_points(2.0 * math.pi * phase)
        feet.append(f - (0.5 * (s - 0.15 * (p - s) / np.linalg.norm(p - s) + f)))  # foot from the leg's centre
    track = []
    for _ in range(60):  # one turn at 1 turn/s
        assert sim.step().converged
        assert sim.joint_errors().max() <= TOLERANCE
        x, q = sim.positions()[legs], sim.orientations()[legs]
        rel = [wi.transforms.quat_rotate(wi.transforms.quat_mul(q[i], wi.transforms.quat_conj(q0[i])), feet[i])
               for i in range(4)]  # fmt: skip
        track.append(x + np.array(rel))
    track = np.array(track)  # (steps, legs, 3)
    start = x0 + np.array(feet)
    np.testing.assert_allclose(track[-1], start, atol=1e-5)  # closed after one turn
    for i, (x, y, phase) in enumerate(scenes.WALKER_LEGS):
        xs, zs = track[:, i, 0], track[:, i, 2]
        area = 0.5 * abs(np.dot(xs, np.roll(zs, 1)) - np.dot(zs, np.roll(xs, 1)))
        assert area > 1e-3  # a loop, not a line
        k = 29  # mid-turn: the geometry at that crank angle
        _, _, _, f = scenes.walker_leg_points(2.0 * math.pi * (phase + (k + 1) / 60.0))
        np.testing.assert_allclose(track[k, i], np.array([x, y, 1.0]) + f, atol=1e-5)


def test_stiff_motors_on_every_hinge_of_a_chain_are_solved_together():
    """Ten coupled stiff motors (a horizontal chain held against gravity, turning at 0.5 rad/s): the rows'
    system is solved at once, so a step takes one iteration; with max_force below what the root needs the
    root motors saturate at it and the outer ones still hold their speed."""

    def chain(max_force):
        b = scenes.chain(10)
        for j in range(10):
            b.add_motor(j, "velocity", target=0.5, max_force=max_force, stiff=True)
        return wi.Simulator(b.finalize(), dt=1.0 / 60.0)

    sim = chain(1e4)
    for _ in range(30):
        stats = sim.step()
        assert stats.converged and stats.joint_iterations <= 2
    for j in range(10):
        np.testing.assert_allclose(sim.joint_velocities(j), 0.5, rtol=1e-9)
    weak = chain(1e3)  # the root needs about 3.7e3 N m against gravity
    assert weak.step().converged
    assert abs(weak.joint_velocities(0)[0] - 0.5) > 0.1  # saturated: the chain sags
    np.testing.assert_allclose(weak.limit_impulse.numpy()[:7], 1e3 / 60.0, rtol=1e-12)  # at max_force h
    for j in (7, 8, 9):
        np.testing.assert_allclose(weak.joint_velocities(j), 0.5, rtol=1e-9)


def test_the_papers_split_systems_hold_the_four_bar_but_auto_keeps_one_matrix():
    """Section 4.6's two systems (tree and loop joints factored apart, solved side by side in the common
    loop) hold the four-bar too, in about 20 iterations a step where one matrix with the loop joints last
    takes 2: "auto" keeps the one matrix (benchmarks/mechanisms.py has the times)."""
    split = wi.Simulator(scenes.four_bar().finalize(), dt=1.0 / 60.0, options=wi.StepOptions(formulation="split"))
    one = wi.Simulator(scenes.four_bar().finalize(), dt=1.0 / 60.0)
    assert one.linear.pattern.formulation == "constraint" and split.linear.pattern.formulation == "split"
    its = {"split": [], "one": []}
    for _ in range(30):
        for name, sim in (("split", split), ("one", one)):
            stats = sim.step()
            assert stats.converged and sim.joint_errors().max() <= TOLERANCE
            its[name].append(stats.joint_iterations)
    assert np.mean(its["one"]) <= 2.0 < 5.0 < np.mean(its["split"])
    np.testing.assert_allclose(split.positions(), one.positions(), atol=1e-5)  # the same motion
