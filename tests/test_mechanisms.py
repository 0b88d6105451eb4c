"""The paper's mechanisms (section 4.4): springs and dampers, joint springs, servo motors, joint limits.

References are analytic: the harmonic oscillator (period 2 pi sqrt(m/k), the damped solution), the
reduced mass of two bodies on a spring, a PI loop's steady state, and conserved energy and momentum.
Angles are measured from the bodies' poses here, not from the engine's own coordinate reader.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import warpimpulse as wi

ROD_MASS, ROD_LENGTH = 1.0, 1.0
ROD_INERTIA = np.array([1e-3, 1.0 / 12.0, 1.0 / 12.0])  # a thin rod along x, kg m^2 about its centre
ROD_PIVOT_INERTIA = ROD_INERTIA[2] + ROD_MASS * 0.25  # about the hinge at its end


def crossings(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Times where x crosses 0 upwards, linearly interpolated."""
    i = np.flatnonzero((x[:-1] < 0.0) & (x[1:] >= 0.0))
    return t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])


def run(sim: wi.Simulator, steps: int, measure) -> tuple[np.ndarray, np.ndarray]:
    t, values = [0.0], [measure(sim)]
    for _ in range(steps):
        stats = sim.step()
        assert stats.converged
        t.append(sim.time)
        values.append(measure(sim))
    return np.array(t), np.array(values)


def rod_on_hinge(gravity=(0.0, 0.0, 0.0)) -> tuple[wi.SceneBuilder, int, int]:
    """A rod along +x hinged at the origin about z."""
    b = wi.SceneBuilder(gravity=gravity)
    body = b.add_body(ROD_MASS, ROD_INERTIA, (0.5 * ROD_LENGTH, 0.0, 0.0), name="rod")
    joint = b.add_joint_revolute(None, body, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), name="hinge")
    return b, body, joint


def rod_angle(sim: wi.Simulator) -> float:
    x = sim.positions()[0]
    return math.atan2(x[1], x[0])


# ---------------------------------------------------------------- springs
@pytest.mark.parametrize("split", [False, True])
@pytest.mark.parametrize("slider", [False, True])
def test_spring_mass_period(slider, split):
    """A 2 kg body on a 50 N/m spring, free or on a prismatic joint, at h = 0.01 s. In the coupled RK4
    prediction the period is 2 pi sqrt(m/k) to 1e-4 relative; forces frozen at t0 of each step would miss it by
    far more (first order in h). Split into half kicks about each step (`split_forces`), the step along the
    spring is velocity Verlet, whose period is known in closed form: 2 pi h / arccos(1 - (h omega)^2 / 2), a
    second-order 1.04e-4 below the exact one here."""
    m, k, h = 2.0, 50.0, 0.01
    b = wi.SceneBuilder(gravity=(0.0, 0.0, -9.81) if slider else (0.0, 0.0, 0.0))
    body = b.add_body(m, (0.1, 0.1, 0.1), (1.0, 0.0, 0.0), linear_velocity=(0.3, 0.0, 0.0))
    if slider:
        b.add_joint_prismatic(None, body, (1.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    b.add_spring(None, body, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), k)
    sim = wi.Simulator(b.finalize(), dt=h, options=wi.StepOptions(split_forces=split))
    assert sim._kicked == split
    t, x = run(sim, 1000, lambda s: s.positions()[0, 0] - 1.0)
    periods = np.diff(crossings(t, x))
    assert len(periods) >= 5
    exact = 2.0 * math.pi * math.sqrt(m / k)
    if split:
        verlet = 2.0 * math.pi * h / math.acos(1.0 - 0.5 * h * h * k / m)
        np.testing.assert_allclose(periods, verlet, rtol=1e-6)  # crossings interpolated between samples
        np.testing.assert_allclose(periods.mean(), verlet, rtol=1e-7)
        np.testing.assert_allclose(periods, exact, rtol=2e-4)
    else:
        np.testing.assert_allclose(periods, exact, rtol=1e-4)
    if slider:
        assert np.abs(sim.positions()[0, 1:]).max() < 1e-6  # the slider holds against gravity


def test_damped_spring_matches_the_analytic_solution():
    """m x'' = -k x - c x': x(t) = e^(-gamma t) (x0 cos(wd t) + (v0 + gamma x0)/wd sin(wd t)) to 1e-5 of the
    amplitude, and its peaks (refined by a parabola through the samples) on the envelope x0 e^(-gamma t)."""
    m, k, c, x0, v0 = 1.5, 40.0, 0.9, 0.2, 0.0
    b = wi.SceneBuilder(gravity=(0.0, 0.0, 0.0))
    body = b.add_body(m, (0.1, 0.1, 0.1), (x0, 0.0, 0.0))
    b.add_spring(None, body, (-1.0, 0.0, 0.0), (x0, 0.0, 0.0), k, damping=c, rest_length=1.0)
    sim = wi.Simulator(b.finalize(), dt=0.005)
    t, x = run(sim, 800, lambda s: s.positions()[0, 0])
    gamma = c / (2.0 * m)
    wd = math.sqrt(k / m - gamma * gamma)
    exact = np.exp(-gamma * t) * (x0 * np.cos(wd * t) + (v0 + gamma * x0) / wd * np.sin(wd * t))
    assert np.abs(x - exact).max() < 1e-5 * x0
    i = np.flatnonzero((x[1:-1] > x[:-2]) & (x[1:-1] > x[2:])) + 1
    a, b, c = x[i - 1], x[i], x[i + 1]
    shift = 0.5 * (a - c) / (a - 2.0 * b + c)  # the parabola's vertex, in samples
    peak, t_peak = b - 0.25 * (a - c) * shift, t[i] + shift * (t[1] - t[0])
    assert len(i) >= 3
    np.testing.assert_allclose(peak, x0 * np.exp(-gamma * t_peak), rtol=1e-4)


def test_spring_between_two_bodies_keeps_momentum():
    """Two bodies on a spring: period 2 pi sqrt(mu/k) with the reduced mass, momentum and angular momentum
    kept (the forces act along one line), energy kept with the spring's own."""
    m1, m2, k = 1.0, 3.0, 30.0
    b = wi.SceneBuilder(gravity=(0.0, 0.0, 0.0))
    a = b.add_body(m1, (0.01, 0.02, 0.03), (0.0, 0.0, 0.0), linear_velocity=(-0.3, 0.1, 0.0),
                   angular_velocity=(0.0, 0.0, 0.7))  # fmt: skip
    c = b.add_body(m2, (0.02, 0.02, 0.02), (1.0, 0.0, 0.0), linear_velocity=(0.1, 0.0, 0.05))
    b.add_spring(a, c, (0.1, 0.05, 0.0), (0.9, 0.0, 0.0), k)
    sim = wi.Simulator(b.finalize(), dt=0.002)
    mass = np.array([m1, m2])

    def momenta(s):
        x, v = s.positions(), s.linear_velocities()
        w, r = s.angular_velocities(), wi.transforms.quat_to_matrix(s.orientations())
        spin = np.einsum("nij,njk,nlk,nl->ni", r, s.model.body_inertia.numpy(), r, w).sum(axis=0)
        return np.concatenate([mass @ v, np.cross(x, mass[:, None] * v).sum(axis=0) + spin])

    t, p = run(sim, 1500, momenta)
    assert np.abs(p - p[0]).max() < 1e-9
    x = sim.positions()
    assert np.linalg.norm(x[1] - x[0]) > 0.5  # it moved


def test_joint_spring_period():
    """A rod on a hinge with a 3 N m/rad joint spring: period 2 pi sqrt(I_pivot / k) to 1e-4, no gravity (the
    joint correction makes the hinged motion second order in h: 1.1e-4 at h = 0.01 s, 3e-5 at 0.005 s)."""
    k = 3.0
    b, body, joint = rod_on_hinge()
    b.add_joint_spring(joint, k)
    b.bodies[body].angular_velocity = np.array([0.0, 0.0, 0.5])
    b.bodies[body].linear_velocity = np.array([0.0, 0.25, 0.0])
    sim = wi.Simulator(b.finalize(), dt=0.005)
    t, angle = run(sim, 1400, rod_angle)
    periods = np.diff(crossings(t, angle))
    assert len(periods) >= 2
    np.testing.assert_allclose(periods, 2.0 * math.pi * math.sqrt(ROD_PIVOT_INERTIA / k), rtol=1e-4)
    np.testing.assert_allclose(sim.joint_coordinates(joint)[0], angle[-1], atol=1e-9)


def test_prismatic_joint_spring_with_rest_offset():
    """A slider's joint spring pulls the offset to its rest value, damped."""
    b = wi.SceneBuilder(gravity=(0.0, 0.0, 0.0))
    body = b.add_body(1.0, (0.1, 0.1, 0.1), (0.0, 0.0, 0.0))
    joint = b.add_joint_prismatic(None, body, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    b.add_joint_spring(joint, 20.0, damping=8.0, rest=0.3)
    sim = wi.Simulator(b.finalize(), dt=0.01)
    run(sim, 500, rod_angle)
    np.testing.assert_allclose(sim.positions()[0], [0.0, 0.3, 0.0], atol=1e-6)
    np.testing.assert_allclose(sim.joint_coordinates(joint)[0], 0.3, atol=1e-6)


def test_scenes_without_force_elements_keep_the_single_body_prediction():
    """No element: each body's own prediction. A spring: kicks about it (`split_forces`), or the coupled RK4."""
    b, _, joint = rod_on_hinge()
    bare = wi.Simulator(b.finalize(), dt=0.01)
    assert not (bare._forced or bare._kicked or bare.split_forces)
    b.add_joint_spring(joint, 1.0)
    split = wi.Simulator(b.finalize(), dt=0.01)
    assert split._kicked and not split._forced and split.defer_velocities
    coupled = wi.Simulator(b.finalize(), dt=0.01, options=wi.StepOptions(split_forces=False))
    assert coupled._forced and not coupled._kicked and not coupled.defer_velocities
    b.add_joint_spring(joint, 1.0, damping=0.1)
    with pytest.raises(ValueError, match="a drive with a velocity, damping or integral term"):
        wi.Simulator(b.finalize(), dt=0.01, options=wi.StepOptions(split_forces=True))
    assert wi.Simulator(b.finalize(), dt=0.01)._forced  # a damper reads the velocities: coupled


# ---------------------------------------------------------------- stiff dampers (implicit)
def light_bob_on_damped_hinge(damping: float, build: bool = True) -> wi.Model | wi.SceneBuilder:
    """A 1 kg bob of 1e-3 kg m^2 on a 0.5 m arm, hinged to the world about z, released at 0.5 rad under gravity,
    its hinge damped: the explicit prediction of the free bob decays at damping / 1e-3 per second. The model,
    or with `build` False its builder."""
    b = wi.SceneBuilder(gravity=(0.0, -9.81, 0.0))
    bob = b.add_body(1.0, (1e-3, 1e-3, 1e-3), (0.5 * math.sin(0.5), -0.5 * math.cos(0.5), 0.0), name="bob")
    hinge = b.add_joint_revolute(None, bob, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), name="hinge")
    b.add_joint_spring(hinge, 0.0, damping=damping)
    return b.finalize() if build else b


@pytest.mark.parametrize("damping, tolerance", [(5.0, 3e-4), (500.0, 4e-6)])
def test_stiff_joint_damper_is_implicit_and_follows_the_ode(damping, tolerance):
    """A hinge damper stiff for the step (h c / I_bob = 5 and 500 at 1 ms, RK4's limit is 2.8) is integrated
    implicitly: every step whole, and the angle within first-order reach of the pendulum's ODE
    (I theta'' = -m g L sin theta - c theta', scipy at 1e-12) over 1 s: 1.9e-4 and 2.4e-6 rad measured (MuJoCo's
    implicitfast at 1 ms: 8.5e-5 and 4.7e-7). A step of 0.1 ms keeps the mild damper in RK4 (to 2e-6)."""
    from scipy.integrate import solve_ivp

    inertia, mgl, h = 1e-3 + 0.25, 9.81 * 0.5, 1e-3

    def ode(t, y):
        return [y[1], (-mgl * math.sin(y[0]) - damping * y[1]) / inertia]

    reference = solve_ivp(ode, (0.0, 1.0), [0.5, 0.0], rtol=1e-12, atol=1e-12, dense_output=True)
    sim = wi.Simulator(light_bob_on_damped_hinge(damping), dt=h)
    assert sim.implicit_dampers == ("hinge.spring",)
    assert "hinge.spring" in sim.damper_note()
    angles = []
    for _ in range(1000):
        stats = sim.step()
        assert stats.converged and stats.substeps == 1
        x = sim.positions()[0]
        angles.append(math.atan2(x[0], -x[1]))
    error = np.abs(np.array(angles) - reference.sol(h * np.arange(1, 1001))[0]).max()
    assert error < tolerance
    if damping == 5.0:
        fine = wi.Simulator(light_bob_on_damped_hinge(damping), dt=1e-4)
        assert fine.implicit_dampers == ()
        fine.step(2000)
        x = fine.positions()[0]
        assert abs(math.atan2(x[0], -x[1]) - reference.sol(0.2)[0]) < 2e-6


def test_at_order_4_a_stiff_damper_stays_in_rk4_and_is_said():
    """Order 4 asked: the stiff damper is not taken implicitly (first order, it would hold every step at order
    2); it stays in RK4, the steps halve where they need it, each is taken at order 4, and the note says so."""
    sim = wi.Simulator(light_bob_on_damped_hinge(5.0), dt=1e-3, order=4)
    assert sim.implicit_dampers == () and "kept in RK4 to keep order 4" in sim.damper_note()
    stats = sim.step(20)
    assert stats.converged and stats.order == 4 and not stats.fallback


def test_kicks_beside_implicit_dampers():
    """A stiff damper taken implicitly reads only the prediction, so the elements of the poses alone beside it (a
    joint spring, an effort motor) still kick (`split_forces`), and the deferred velocity correction stays exact
    (5.6e-13 measured from the run that corrects every step, at tolerance 1e-12). Both ways are first order
    with the implicit damper: after 1 s at 1 ms, 1.05e-3 m from the coupled RK4 at 20 us where the coupled
    prediction at 1 ms is 7.4e-4 m off."""
    b = light_bob_on_damped_hinge(5.0, build=False)
    bob = len(b.bodies) - 1
    second = b.add_body(0.5, (1e-3, 2e-3, 1e-3), 2.0 * b.bodies[bob].position, angular_velocity=(0.0, 0.0, 3.0))
    elbow = b.add_joint_revolute(bob, second, b.bodies[bob].position, (0.3, 0.0, 1.0), name="elbow")
    b.add_joint_spring(elbow, 1.0)
    b.add_motor(elbow, mode="effort", target=0.2)
    model = b.finalize()
    runs = {}
    for name, options in (
        ("coupled", {"split_forces": False}),
        ("split", {}),
        ("corrected", {"defer_velocities": False}),
    ):
        sim = wi.Simulator(model, 1e-3, tolerance=1e-12, options=wi.StepOptions(**options))
        assert sim.implicit_dampers == ("hinge.spring",) and sim._kicked == (name != "coupled")
        assert sim.defer_velocities == (name == "split")
        for _ in range(100):
            sim.step(10)
            sim.angular_velocities()  # handed out: the deferred correction taken
        runs[name] = np.concatenate([sim.positions(), sim.angular_velocities()])
    np.testing.assert_allclose(runs["split"], runs["corrected"], rtol=0.0, atol=1e-11)
    reference = wi.Simulator(model, 2e-5, tolerance=1e-12, options=wi.StepOptions(split_forces=False))
    assert reference.implicit_dampers == ()  # not stiff at 20 us: in RK4
    reference.step(50000)
    coupled, split = (np.abs(runs[k][:2] - reference.positions()).max() for k in ("coupled", "split"))
    assert split < 2.0 * coupled and coupled < 2e-3


def test_stiff_slider_damper_reaches_the_terminal_velocity():
    """A 10 g slider falling along its vertical axis against a damper of 50 N s/m (time constant m / c = 0.2 ms,
    a fifth of the step): implicit, it settles at the terminal velocity m g / c and follows
    x(t) = v_t (t - tau (1 - exp(-t / tau))) to within a step's terminal motion h v_t (first order: 9.8e-7 m of
    0.39 mm measured, the first step's half step at rest)."""
    m, c, h = 0.01, 50.0, 1e-3
    b = wi.SceneBuilder(gravity=(0.0, 0.0, -9.81))
    body = b.add_body(m, (1e-4, 1e-4, 1e-4), (0.0, 0.0, 0.0))
    slider = b.add_joint_prismatic(None, body, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), name="slider")
    b.add_joint_spring(slider, 0.0, damping=c)
    sim = wi.Simulator(b.finalize(), dt=h)
    assert sim.implicit_dampers == ("slider.spring",)
    stats = sim.step(200)
    assert stats.converged and stats.substeps == 200
    terminal, tau, t = m * 9.81 / c, m / c, 0.2
    np.testing.assert_allclose(sim.linear_velocities()[0], [0.0, 0.0, -terminal], rtol=1e-9, atol=1e-12)
    fall = terminal * (t - tau * (1.0 - math.exp(-t / tau)))
    assert abs(sim.positions()[0][2] + fall) < h * terminal


# ---------------------------------------------------------------- motors
def test_position_servo_reaches_and_holds_its_target():
    """A PID servo lifts a rod against gravity to 0.5 rad, holds it, then goes to -1 rad on a new target."""
    b, _, joint = rod_on_hinge(gravity=(0.0, -9.81, 0.0))
    motor = b.add_motor(joint, "position", target=0.5, kp=50.0, ki=20.0, kd=10.0)
    sim = wi.Simulator(b.finalize(), dt=1.0 / 60.0)
    t, angle = run(sim, 600, rod_angle)
    assert abs(angle[-1] - 0.5) < 1e-3
    assert np.abs(angle[t > 8.0] - 0.5).max() < 2e-3  # held, the integral carrying the load
    sim.set_motor_target(motor, -1.0)
    t, angle = run(sim, 900, rod_angle)
    assert abs(angle[-1] + 1.0) < 1e-3


def test_velocity_servo_holds_its_speed_under_load():
    """A wheel with a 2 N m braking load: a PI velocity servo turns it at 3 rad/s; the integral carries the
    load, so the speed error vanishes; max_force caps the torque."""
    b = wi.SceneBuilder(gravity=(0.0, 0.0, -9.81))
    wheel = b.add_body(2.0, (0.05, 0.05, 0.09), (0.0, 0.0, 1.0))
    joint = b.add_joint_revolute(None, wheel, (0.0, 0.0, 1.0), (0.0, 0.0, 1.0))
    b.add_force(wheel, torque=(0.0, 0.0, -2.0))
    b.add_motor(joint, "velocity", target=3.0, kp=5.0, ki=10.0, max_force=50.0)
    sim = wi.Simulator(b.finalize(), dt=0.01)
    t, w = run(sim, 800, lambda s: s.angular_velocities()[0, 2])
    assert np.abs(w[t > 6.0] - 3.0).max() < 1e-3
    np.testing.assert_allclose(sim.joint_velocities(joint)[0], w[-1], atol=1e-9)


def test_motor_torque_is_clamped():
    """With max_force 0.5 N m a rod of pivot inertia I spins up at 0.5 / I rad/s^2, however large kp."""
    b, _, joint = rod_on_hinge()
    b.add_motor(joint, "velocity", target=100.0, kp=1e4, max_force=0.5)
    sim = wi.Simulator(b.finalize(), dt=0.01)
    run(sim, 100, rod_angle)
    np.testing.assert_allclose(sim.angular_velocities()[0, 2], 0.5 / ROD_PIVOT_INERTIA * 1.0, rtol=1e-5)


# ---------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "call, message",
    [
        (lambda b, j: b.add_motor("ball", target=1.0), "'ball' (ball) has no single coordinate"),
        (lambda b, j: b.add_joint_limit("ball", -1.0, 1.0), "'ball' (ball) has no single coordinate"),
        (lambda b, j: b.add_joint_limit(j, 0.5, -0.5), "'hinge': limit lower 0.5 > upper -0.5"),
        (lambda b, j: b.add_joint_spring(j, -1.0), "'hinge': joint spring stiffness must be >= 0"),
        (lambda b, j: b.add_motor(j, kp=-2.0), "'hinge': motor kp must be >= 0"),
        (lambda b, j: b.add_motor(j, target=math.nan), "'hinge': motor target must be finite"),
        (lambda b, j: b.add_motor(j, mode="torque"), "'hinge': motor mode must be"),
        (lambda b, j: b.add_motor("nope"), "no joint named 'nope'"),
        (lambda b, j: b.add_spring(0, 0, (0, 0, 0), (1, 0, 0), 1.0), "both ends are on the same body"),
        (lambda b, j: b.add_spring(None, 0, (0, 0, 0), (1, 0, 0), -1.0), "stiffness must be >= 0"),
    ],
)
def test_bad_mechanism_input_names_the_joint(call, message):
    b, body, joint = rod_on_hinge()
    other = b.add_body(1.0, (0.1, 0.1, 0.1), (2.0, 0.0, 0.0))
    b.add_joint_ball(body, other, (1.0, 0.0, 0.0), name="ball")
    with pytest.raises(wi.SceneError, match=message.replace("(", r"\(").replace(")", r"\)")):
        call(b, joint)


def test_set_motor_target_checks_its_input():
    b, _, joint = rod_on_hinge()
    b.add_joint_spring(joint, 1.0)
    motor = b.add_motor(joint, "position", kp=1.0)
    sim = wi.Simulator(b.finalize(), dt=0.01)
    assert motor == 0  # motors are counted apart from joint springs
    sim.set_motor_target(motor, 1.0)
    with pytest.raises(ValueError, match="target must be finite"):
        sim.set_motor_target(motor, math.inf)
    with pytest.raises(ValueError, match="does not exist"):
        sim.set_motor_target(5, 1.0)
    with pytest.raises(ValueError, match="solver 'iterative'"):
        wi.Simulator(b.finalize(), dt=0.01, solver="iterative")


# ---------------------------------------------------------------- limits
def swing_into_limit(limit: bool, dt: float = 1.0 / 60.0, steps: int = 300):
    """A rod hung from a hinge, swung at 4 rad/s towards a +-30 degree limit; (angles, energies, stats)."""
    b = wi.SceneBuilder(gravity=(0.0, -9.81, 0.0))
    body = b.add_body(ROD_MASS, ROD_INERTIA[[1, 0, 2]], (0.0, -0.5, 0.0), name="rod")  # along y
    joint = b.add_joint_revolute(None, body, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), name="hinge")
    if limit:
        b.add_joint_limit(joint, -math.radians(30.0), math.radians(30.0))
    b.bodies[body].angular_velocity = np.array([0.0, 0.0, 4.0])
    b.bodies[body].linear_velocity = np.array([2.0, 0.0, 0.0])
    sim = wi.Simulator(b.finalize(), dt=dt)
    e0 = sim.energy()
    angles, energies, stats = [], [], []
    for _ in range(steps):
        stats.append(sim.step())
        q = sim.orientations()[0]  # a rotation about z from the built pose: (0, 0, sin(a/2), cos(a/2))
        angles.append(2.0 * math.atan2(q[2], q[3]))
        energies.append(sim.energy() - e0)
        assert sim.joint_errors().max() < 1e-6
    return np.array(angles), np.array(energies), stats


def test_pendulum_into_a_limit_never_passes_it_and_gains_no_energy():
    """Unlimited, the swing reaches 63 degrees; limited, it stops at 30 degrees within the tolerance (1e-6
    rad), swings back to -30 and never gains energy: the impact is inelastic, the swings after it keep their
    energy to the method's own drift (the same as the unlimited pendulum's)."""
    free, free_energy, _ = swing_into_limit(False)
    assert np.abs(free).max() > math.radians(60.0)
    angles, energy, stats = swing_into_limit(True)
    bound = math.radians(30.0)
    assert np.abs(angles).max() <= bound + 1e-6
    assert angles.max() > bound - 1e-6  # it reached the limit
    drift = np.abs(free_energy).max()  # the integrator's own, about 3e-3 J at h = 1/60 s
    assert energy.max() < drift
    hit = int(np.argmax(angles > bound - 1e-6))
    assert energy[hit + 1] < -1.0  # the kinetic energy into the stop is gone
    after = energy[hit + 2 :]
    assert after.max() - after.min() < drift  # later swings reach 30 degrees again, without gaining
    assert all(s.converged for s in stats)


@pytest.mark.parametrize("spin", [4.0, -4.0])
def test_a_limit_past_pi_holds_its_range_as_one_interval(spin):
    """A rod spun at 4 rad/s either way on a hinge limited to [-0.5, 3.6] rad (or its mirror) turns through
    pi, where the angle read within one turn jumps by 2 pi, and stops at 3.6 rad, at rest. Panda's joint 6
    ([-0.0175, 3.7525] rad) once read that jump as 3.11 rad below its lower bound and diverged."""
    b, body, joint = rod_on_hinge()
    bound = 3.6 * math.copysign(1.0, spin)
    b.add_joint_limit(joint, min(bound, -0.5 * bound / 3.6), max(bound, -0.5 * bound / 3.6))
    b.bodies[body].angular_velocity = np.array([0.0, 0.0, spin])
    b.bodies[body].linear_velocity = np.array([0.0, 0.5 * spin, 0.0])
    sim = wi.Simulator(b.finalize(), dt=0.01)
    _, angles = run(sim, 120, rod_angle)  # 1.2 s: the stop is reached at 0.9 s
    turned = np.unwrap(angles)
    assert np.abs(turned).max() <= 3.6 + 1e-6
    assert turned[-1] == pytest.approx(bound, abs=1e-6)
    assert abs(sim.angular_velocities()[0, 2]) < 1e-6


@pytest.mark.parametrize("pull", [9.81, -9.81])
def test_a_limit_of_no_range_locks_the_joint_against_either_side(pull):
    """lower == upper (URDF's revolute joints without bounds: centauro's wheels) locks the joint: gravity
    pulling the rod either way, the angle stays within the tolerance of 0 for 1 s. A row pushing down from the
    upper bound was once taken for one pushing up from the lower (the same goal), kept from pushing, and the
    angle crept past the tolerance (centauro stopped at step 8)."""
    b, _, joint = rod_on_hinge(gravity=(0.0, pull, 0.0))
    b.add_joint_limit(joint, 0.0, 0.0)
    sim = wi.Simulator(b.finalize(), dt=0.01)
    _, angles = run(sim, 100, rod_angle)
    assert np.abs(angles).max() <= 1e-6


def test_a_limit_of_a_full_turn_is_said_to_never_bind_and_takes_no_row():
    """UR5's joints are limited to +-2 pi: such a limit never binds, so the model skips it (a row would cost a
    solve a step and keep an order-4 step at order 2); the builder keeps it for the files it writes."""
    b, _, joint = rod_on_hinge()
    with pytest.warns(UserWarning, match=r"'hinge': limit \[-3.2, 3.2\] rad spans a full turn or more"):
        b.add_joint_limit(joint, -3.2, 3.2)
    assert len(b.limits) == 1
    sim = wi.Simulator(b.finalize(), dt=0.01, order=4)
    assert sim.model.limit_count == 0 and sim.step().order == 4


@pytest.mark.parametrize("solver", ["cholesky", "cg"])
def test_prismatic_limit_stops_a_falling_slider(solver):
    """A slider falling along -z stops at its lower limit -0.2 m and rests there, at rest."""
    b = wi.SceneBuilder(gravity=(0.0, 0.0, -9.81))
    body = b.add_body(1.0, (0.1, 0.1, 0.1), (0.3, 0.0, 1.0))
    joint = b.add_joint_prismatic(None, body, (0.3, 0.0, 1.0), (0.0, 0.0, 1.0))
    b.add_joint_limit(joint, -0.2, 0.5)
    sim = wi.Simulator(b.finalize(), dt=0.01, solver=solver)
    t, z = run(sim, 200, lambda s: s.positions()[0, 2])
    assert z.min() >= 0.8 - 1e-6
    np.testing.assert_allclose(z[-50:], 0.8, atol=1e-6)
    assert abs(sim.linear_velocities()[0, 2]) < 1e-3


def test_checkpoint_and_reset_keep_the_motors(tmp_path):
    """A checkpoint carries the motors' targets and PID integrals: the run continues bit-identically; reset
    returns to the built targets."""
    b, _, joint = rod_on_hinge(gravity=(0.0, -9.81, 0.0))
    motor = b.add_motor(joint, "position", target=0.5, kp=50.0, ki=20.0, kd=10.0)
    sim = wi.Simulator(b.finalize(), dt=1.0 / 60.0)
    run(sim, 30, rod_angle)
    sim.set_motor_target(motor, -0.3)
    sim.save_checkpoint(tmp_path / "c.npz")
    _, ahead = run(sim, 30, rod_angle)
    again = wi.Simulator(b.finalize(), dt=1.0 / 60.0)
    again.load_checkpoint(tmp_path / "c.npz")
    _, resumed = run(again, 30, rod_angle)
    np.testing.assert_array_equal(resumed, ahead)
    sim.reset()
    assert sim.drive_target.numpy()[motor] == 0.5 and not sim.drive_integral.numpy().any()


def test_limits_fall_back_to_order_2_and_springs_compose():
    """A limit's impact and a saturating stiff motor are not reversible: a composition of order 4 would run
    them backwards in its negative substeps, so such a scene steps at order 2, each step saying why, exactly
    as the paper's step does; springs are smooth and compose."""
    b, _, joint = rod_on_hinge()
    b.add_joint_limit(joint, -0.3, 0.3)
    asked = wi.Simulator(b.finalize(), dt=0.01, order=4, tolerance=1e-9)
    plain = wi.Simulator(b.finalize(), dt=0.01, order=2, tolerance=1e-9)
    for _ in range(30):
        stats = asked.step()
        plain.step()
        assert stats.order == 2 and "not reversible" in stats.fallback
    np.testing.assert_array_equal(asked.positions(), plain.positions())
    m, k = 2.0, 50.0
    b = wi.SceneBuilder(gravity=(0.0, 0.0, 0.0))
    body = b.add_body(m, (0.1, 0.1, 0.1), (1.0, 0.0, 0.0), linear_velocity=(0.3, 0.0, 0.0))
    b.add_spring(None, body, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), k)
    sim = wi.Simulator(b.finalize(), dt=0.05, order=4)
    t, x = run(sim, 200, lambda s: s.positions()[0, 0] - 1.0)
    np.testing.assert_allclose(np.diff(crossings(t, x)), 2.0 * math.pi * math.sqrt(m / k), rtol=1e-4)


def test_energy_counts_the_springs_and_is_conserved():
    """Two bodies on a spring, one hinged to the world with a joint spring, no gravity: kinetic energy turns
    into elastic energy and back, and the sum stays put (the sum without the springs' share would swing)."""
    b = wi.SceneBuilder(gravity=(0.0, 0.0, 0.0))
    a = b.add_body(1.0, (0.02, 0.02, 0.02), (0.0, 0.0, 0.0), linear_velocity=(0.0, 0.3, 0.0))
    c = b.add_body(2.0, (0.03, 0.05, 0.04), (1.0, 0.0, 0.0), angular_velocity=(0.0, 0.0, 0.4))
    b.add_spring(a, c, (0.0, 0.0, 0.0), (1.0, 0.1, 0.0), stiffness=40.0, rest_length=0.8)
    hinge = b.add_joint_revolute(None, c, (1.5, 0.0, 0.0), (0.0, 0.0, 1.0))
    b.add_joint_spring(hinge, stiffness=3.0, rest=0.1)
    sim = wi.Simulator(b.finalize("cpu"), 1 / 600, tolerance=1e-10)
    energies, elastic = [], []
    for _ in range(600):
        sim.step()
        energies.append(sim.energy())
        elastic.append(sim.potential_energy())
    assert np.ptp(elastic) > 0.1 * max(elastic)  # energy really moves between the two forms
    assert np.ptp(energies) < 1e-4 * max(energies)


def free_walker_without_colliders() -> wi.SceneBuilder:
    """The walking machine with its body free (no "hold"; six legs with foot plates), no ground and no colliding
    shape: no contact stage."""
    import dataclasses

    from warpimpulse import scenes

    builder = scenes.walking_machine(ground=True)
    builder.grounds.clear()
    for body in builder.bodies:
        body.shape = dataclasses.replace(body.shape, collide=False)
    return builder


def test_free_walker_pushed_on_a_leg_keeps_its_motors_and_its_energy_balance():
    """The free walking machine falling for 2 s at h = 1/240 s, tolerance 1e-3, 300 N along x on one leg: its
    cranks keep their speed, its joints hold, and its energy grows by exactly the work of the push and of the
    motors (impulse times rate), to 1%. Before the loop rows' pivot tolerance followed the joint tolerance
    (`solver.loop_tolerance_for`), the loops' nearly redundant rows (pivots ~1e-7 of their diagonal) threw the
    cranks to hundreds of rad/s within 3 steps. The velocity tolerance is 1e-2: joints within 1e-3 tilt the
    loops' redundant rows, whose velocity errors are then inconsistent by up to ~5e-3 m/s."""
    dt, tolerance = 1.0 / 240.0, 1e-3
    builder = free_walker_without_colliders()
    leg = [b.name for b in builder.bodies].index("leg0_leg")
    sim = wi.Simulator(builder.finalize(), dt=dt, tolerance=tolerance, velocity_tolerance=1e-2)
    push = np.array([300.0, 0.0, 0.0])
    force = np.zeros((sim.model.body_count, 3))
    force[leg] = push
    sim.set_external_forces(force=force)
    servos = [name for name in sim.model.joint_name if name.endswith("_servo")]
    assert len(servos) == sim.model.limit_count == 6
    e0, work = sim.energy(), 0.0
    for _ in range(480):
        v0, r0 = sim.linear_velocities()[leg], np.array([sim.joint_velocities(s)[0] for s in servos])
        stats = sim.step()
        assert stats.converged and stats.max_joint_error <= tolerance
        v1, r1 = sim.linear_velocities()[leg], np.array([sim.joint_velocities(s)[0] for s in servos])
        motor_impulse = sim.limit_impulse.numpy() + sim.limit_velocity_impulse.numpy()
        work += push @ (v0 + v1) * 0.5 * dt + motor_impulse @ (0.5 * (r0 + r1))
        assert np.allclose(r1, 2.0 * math.pi, atol=1e-6)
    assert work > 1000.0  # the push's, mostly
    assert sim.energy() - e0 == pytest.approx(work, rel=0.01)
