"""External loads: `SceneBuilder.add_force(body, force, torque, until)` and `Simulator.set_external_forces`.

A load is a world force at the centre of mass and a world torque, constant over a step, on while the step
starts before `until`. What they must do, from Newton and Euler, not from the engine:
- on a free body the linear momentum changes by (F + m g) t and the world angular momentum I_w w by tau t;
- the load switches off exactly at `until`: the momentum stops changing at that step, not one step earlier or
  later;
- on a jointed system the motion follows the reduced-coordinate reference (tests/reference.py) that has the
  same loads, and on a floating one without gravity the total momenta change by sum F t and sum tau t.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy_checks import momenta, sim_state
from reference import BallTree, matrices, order
from rigs import ball_chain, floating_body, run_against_reference

import warpimpulse as wi

DT = 0.01
MASS = 2.0
INERTIA = np.array([[0.5, 0.05, 0.0], [0.05, 0.8, -0.1], [0.0, -0.1, 1.1]])  # kg m^2, body frame, not diagonal
Q0 = np.array([0.3, -0.1, 0.2, 0.9]) / np.linalg.norm([0.3, -0.1, 0.2, 0.9])
X0, V0, W0 = np.array([0.1, -0.2, 1.0]), np.array([0.5, 0.0, -0.3]), np.array([0.4, -0.7, 1.2])
FORCE, TORQUE = np.array([4.0, -1.0, 2.5]), np.array([0.3, -0.2, 0.5])
GRAVITY = np.array([0.0, 0.0, -9.81])


def free_body() -> wi.SceneBuilder:
    b = wi.SceneBuilder(gravity=GRAVITY)
    b.add_body(MASS, INERTIA, X0, Q0, V0, W0, name="box")
    return b


def spin_momentum(sim) -> np.ndarray:
    """I_w w of body 0 from the raw state (no normalisation of q)."""
    r = matrices(sim.orientations()[0])
    return r @ INERTIA @ r.T @ sim.angular_velocities()[0]


def expected_free_motion(t: float, on: float):
    """Position, velocity and spin momentum of the free body at t when the load acted for its first `on` s."""
    a = GRAVITY + FORCE / MASS
    x_on = X0 + V0 * on + 0.5 * a * on * on
    v_on = V0 + a * on
    rest = t - on
    x = x_on + v_on * rest + 0.5 * GRAVITY * rest * rest
    v = v_on + GRAVITY * rest
    r0 = matrices(Q0)
    return x, v, r0 @ INERTIA @ r0.T @ W0 + TORQUE * on


def check_free_body(sim, until: float, steps: int) -> tuple[float, float]:
    """Step and compare every state with Newton and Euler; returns the worst errors (m/s, N m s)."""
    worst_v = worst_l = 0.0
    for k in range(1, steps + 1):
        sim.step()
        t = k * DT
        x, v, spin = expected_free_motion(t, min(t, until))
        np.testing.assert_allclose(sim.positions()[0], x, rtol=0, atol=1e-12, err_msg=f"step {k}")
        worst_v = max(worst_v, float(np.abs(sim.linear_velocities()[0] - v).max()))
        worst_l = max(worst_l, float(np.abs(spin_momentum(sim) - spin).max()))
    return worst_v, worst_l


# Measured: velocity 1.4e-14 m/s (the translation is exact), spin momentum 3.1e-10 N m s (RK4's error).
@pytest.mark.parametrize("until", [0.5, np.inf])
def test_add_force_changes_momenta_by_impulse(until):
    b = free_body()
    b.add_force("box", FORCE, TORQUE, until=until)
    sim = wi.Simulator(b.finalize(), DT)
    worst_v, worst_l = check_free_body(sim, until, 100)
    print(f"\nuntil {until}: velocity error {worst_v:.1e} m/s, spin momentum error {worst_l:.1e} N m s")
    assert worst_v < 1e-12
    assert worst_l < 1e-9


def test_load_switches_off_exactly_at_until():
    """until = 0.5 s at h = 0.01: 50 steps pushed, not 49 or 51; off the grid (0.505) the step that starts at
    0.50 is still pushed (51 steps)."""
    for until, pushed in ((0.5, 50), (0.505, 51), (0.4999, 50)):
        b = free_body()
        b.add_force(0, FORCE, TORQUE, until=until)
        sim = wi.Simulator(b.finalize(), DT)
        p = []
        for _ in range(60):
            sim.step()
            p.append(MASS * (sim.linear_velocities()[0] - GRAVITY * sim.time))
        p = np.array(p) - MASS * V0
        impulse = FORCE * DT * np.minimum(np.arange(1, 61), pushed)[:, None]
        np.testing.assert_allclose(p, impulse, rtol=0, atol=1e-12, err_msg=f"until {until}")


def test_set_external_forces_changes_momenta_and_adds_to_builder_loads():
    """The simulator's loads act like the builder's, add to them, and hold until set again."""
    sim = wi.Simulator(free_body().finalize(), DT)
    sim.set_external_forces(FORCE[None, :], TORQUE[None, :])
    worst_v, worst_l = check_free_body(sim, 0.5, 50)
    sim.set_external_forces(np.zeros((1, 3)), np.zeros((1, 3)))
    for k in range(51, 101):
        sim.step()
        x, v, spin = expected_free_motion(k * DT, 0.5)
        np.testing.assert_allclose(sim.positions()[0], x, rtol=0, atol=1e-12)
        worst_v = max(worst_v, float(np.abs(sim.linear_velocities()[0] - v).max()))
        worst_l = max(worst_l, float(np.abs(spin_momentum(sim) - spin).max()))
    assert worst_v < 1e-12 and worst_l < 1e-9

    # Both at once: half of the load from the builder, half from the simulator.
    b = free_body()
    b.add_force("box", 0.5 * FORCE, 0.5 * TORQUE, until=0.5)
    sim = wi.Simulator(b.finalize(), DT)
    sim.set_external_forces(0.5 * FORCE[None, :], 0.5 * TORQUE[None, :])
    check_free_body(sim, 0.5, 50)


def test_loads_on_a_floating_jointed_body_change_its_momenta():
    """No gravity, every joint type, forces on three bodies and torques on two: the total linear momentum
    changes by sum F t, and the total angular momentum about the origin by the integral of sum (x x F + tau)."""
    builder = floating_body(seed=5, consistent=True)
    loads = {0: (np.array([3.0, -1.0, 2.0]), np.array([0.0, 0.0, 0.0])),
             4: (np.array([0.0, 0.0, 0.0]), np.array([0.4, 0.9, -0.3])),
             9: (np.array([-1.0, 2.0, 0.5]), np.array([-0.6, 0.2, 0.1]))}  # fmt: skip
    n = len(builder.bodies)
    force, torque = np.zeros((n, 3)), np.zeros((n, 3))
    for body, (f, tau) in loads.items():
        force[body], torque[body] = f, tau
    sim = wi.Simulator(builder.finalize(), DT, tolerance=1e-10)
    sim.set_external_forces(force, torque)
    p0, l0 = momenta(builder, *sim_state(sim))
    l_expected = l0.copy()
    x_start = sim.positions()
    for _ in range(100):
        x_before = sim.positions()
        sim.step()
        x_after = sim.positions()
        # Within a step each loaded centre of mass moves on a parabola with x'' = F / m (no gravity), so
        # the trapezoid of x x F over the step is exact: its error, h^3 / 12 x'' x F, vanishes.
        l_expected += DT * (np.cross(0.5 * (x_before + x_after), force).sum(axis=0) + torque.sum(axis=0))
    p, l = momenta(builder, *sim_state(sim))
    np.testing.assert_allclose(p - p0, force.sum(axis=0) * 100 * DT, rtol=0, atol=1e-10)
    assert np.abs(sim.positions() - x_start).max() > 0.3
    print(f"\nangular momentum change {np.linalg.norm(l - l0):.3f}, off by {np.linalg.norm(l - l_expected):.2e}")
    assert np.linalg.norm(l - l_expected) < 1e-8 * np.linalg.norm(l - l0)  # measured 1.5e-10 of 3.2


def pushed_chain():
    """The 3-link chain of test_rotation3d at rest, its tip pushed sideways and the middle link twisted."""
    builder, _ = ball_chain(
        [(1.0, 0.0, -0.2), (0.2, 1.0, 0.3), (-0.5, 0.4, -1.0)], [1.0, 0.8, 0.6], [1.0, 0.7, 0.5], [(0.0, 0.0, 0.0)] * 3
    )
    builder.add_force("rod2", (3.0, -2.0, 5.0), until=0.5)
    builder.add_force("rod1", torque=(0.5, 0.2, -0.3), until=0.3)
    return builder, BallTree(builder)  # the reference of the loaded scene


def test_loads_on_a_ball_chain_match_reduced_coordinates():
    """Measured at h = 1/200, 1/400 over 1 s: COM error 1.1e-3, 2.8e-4 m (order 2.00)."""
    x200, _ = run_against_reference(pushed_chain, 200)
    x400, _ = run_against_reference(pushed_chain, 400)
    p = order(x200, x400)
    print(f"\npushed chain: COM error {x200:.2e} / {x400:.2e} m at h = 1/200, 1/400, order {p:.2f}")
    assert x400 < 5e-4
    assert 1.8 < p < 2.2
