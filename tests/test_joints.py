"""Each joint type: the motion it allows stays free, the motion it removes stays removed.

Scenes have no gravity and random (seeded) masses, full inertia tensors, orientations, anchors and axes.
The locked and free coordinates are measured from the relative pose of the child in the parent's frame,
computed here from the joint's world anchor and axes at build time only (not from the engine's constraint
data). "Free" is checked through what the joint's impulses cannot change: with the world as parent, the
momentum along every allowed direction (e.g. the angular momentum about a hinge axis) is conserved, whatever
the correction impulses do, and the allowed coordinate advances at the expected rate.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy_checks import rotations, velocity_within, world_inertia
from rigs import DT, JOINTS, STEPS, TOL, Rig
from scipy.spatial.transform import Rotation

import warpimpulse


def allowed_velocities(rig: Rig, rng, com):
    """Velocities the joint allows (the child's joint point moves as the joint permits)."""
    a, c = rig.axis, rig.child_axis
    r = com - rig.anchor
    s1, s2 = rng.choice([-1.0, 1.0], 2) * rng.uniform(1.0, 2.0, 2)
    j = rig.joint
    if j == "ball":
        w = rng.normal(size=3)
        return np.cross(w, r), w
    if j == "revolute":
        return np.cross(s1 * a, r), s1 * a
    if j == "prismatic":
        return s1 * a, np.zeros(3)
    if j == "cylindrical":
        return s1 * a + np.cross(s2 * a, r), s2 * a
    if j == "universal":
        w = s1 * a + s2 * c
        return np.cross(w, r), w
    if j == "planar":
        v_point = rng.normal(size=3)
        v_point -= np.dot(v_point, a) * a
        return v_point + np.cross(s2 * a, r), s2 * a
    return np.zeros(3), np.zeros(3)


def conserved(rig: Rig, linear, angular) -> np.ndarray:
    """Momenta along the allowed directions, with the world as parent (angular momenta about the anchor)."""
    a = rig.axis
    j = rig.joint
    if j == "ball":
        return angular
    if j == "revolute":
        return np.array([np.dot(a, angular)])
    if j == "prismatic":
        return np.array([np.dot(a, linear)])
    if j == "cylindrical":
        return np.array([np.dot(a, linear), np.dot(a, angular)])
    if j == "universal":
        return np.array([np.dot(a, angular)])
    if j == "planar":
        return np.concatenate([linear - np.dot(a, linear) * a, [np.dot(a, angular)]])
    return np.zeros(0)


def _fmt(values: dict) -> str:
    return ", ".join(f"{k} {v:.2e}" for k, v in values.items())


def run(rig: Rig, steps=STEPS):
    locked_worst = {}
    history = []
    for _ in range(steps):
        stats = rig.sim.step()
        assert stats.converged and velocity_within(stats, TOL), stats
        locked, free = rig.coordinates()
        for key, value in locked.items():
            locked_worst[key] = max(locked_worst.get(key, 0.0), value)
        history.append((free, rig.momenta()))
    return locked_worst, history


@pytest.mark.parametrize("joint", [j for j in JOINTS if j != "fixed"])
@pytest.mark.parametrize("seed", [1, 2])
def test_allowed_motion_stays_free(joint, seed):
    rig = Rig(joint, seed, allowed_velocities)
    start = conserved(rig, *rig.momenta())
    v0, w0 = rig.sim.linear_velocities()[0], rig.sim.angular_velocities()[0]
    locked, history = run(rig)
    free, (linear, angular) = history[-1]
    end = conserved(rig, linear, angular)
    scale = max(np.abs(start).max(), 1.0)
    drift = np.abs(end - start).max() / scale
    t = STEPS * DT
    print(f"\n{joint}: locked {_fmt(locked)}, free {_fmt(free)}, allowed momenta drift {drift:.1e}")
    for key, value in locked.items():
        assert value <= 2 * TOL, f"{key} moved by {value:.3g}"
    assert drift < 1e-9
    # The allowed coordinates advance at the rates they started with.
    a = rig.axis
    # The spin angle lags omega t by the method's O(h^2) error (the child's inertia is not principal about
    # the axis, so each step's free prediction wobbles): measured 1.7e-5, 4.3e-6, 1.1e-6 rad at h = 1e-2,
    # 5e-3, 2.5e-3 for the revolute joint of seed 2, while omega itself holds to 3e-12.
    if joint in ("revolute", "cylindrical"):
        rate = float(np.dot(w0, a))
        assert abs(free["spin"] - math.remainder(rate * t, 2 * math.pi)) < 1e-4
        np.testing.assert_allclose(rig.sim.angular_velocities()[0], w0, atol=1e-9)
    if joint in ("prismatic", "cylindrical"):
        # The child's joint point slides at its initial speed along the axis (prismatic: v is that speed).
        point_velocity = v0 + np.cross(w0, rig.anchor - rig.b.bodies[rig.child].position)
        rate = float(np.dot(point_velocity, a))
        assert abs(free["slide"] - rate * t) < 1e-9
    if joint == "planar":
        np.testing.assert_allclose(free["spin"], math.remainder(float(np.dot(w0, a)) * t, 2 * math.pi), atol=1e-4)
        np.testing.assert_allclose(rig.sim.angular_velocities()[0], w0, atol=1e-9)
        assert free["in_plane"] > 0.5
    if joint == "universal":
        # It bends about both axes.
        assert abs(free["alpha"]) > 0.3 and abs(free["beta"]) > 0.3, free
    if joint == "ball":
        assert free["rotation"] > 0.3


@pytest.mark.parametrize("joint", JOINTS)
def test_removed_motion_is_removed(joint):
    """Random velocities that break the joint: the corrections remove them, and leave the allowed momenta."""
    rig = Rig(joint, seed=7)
    start = conserved(rig, *rig.momenta())
    locked, history = run(rig)
    end = conserved(rig, *history[-1][1])
    drift = np.abs(end - start).max() / max(np.abs(start).max(), 1.0) if len(start) else 0.0
    print(f"\n{joint}: locked {_fmt(locked)}, allowed momenta drift {drift:.1e}")
    for key, value in locked.items():
        assert value <= 2 * TOL, f"{key} moved by {value:.3g}"
    assert drift < 1e-9
    if joint == "fixed":
        np.testing.assert_allclose(rig.sim.linear_velocities(), 0.0, atol=TOL)
        np.testing.assert_allclose(rig.sim.angular_velocities(), 0.0, atol=TOL)


@pytest.mark.parametrize("joint", JOINTS)
def test_moving_parent(joint):
    """A dynamic parent, both bodies kicked: the relative coordinates behave as with the world."""
    rig = Rig(joint, seed=11, parent_dynamic=True)
    linear0, angular0 = rig.momenta()
    locked, history = run(rig)
    free, (linear, angular) = history[-1]
    print(f"\n{joint}: locked {_fmt(locked)}, free {_fmt(free)}")
    for key, value in locked.items():
        assert value <= 2 * TOL, f"{key} moved by {value:.3g}"
    for value in free.values():
        assert abs(value) > 1e-3  # the allowed motion happened
    np.testing.assert_allclose(linear, linear0, rtol=0, atol=1e-12 * max(1.0, np.abs(linear0).max()))
    # Nothing holds the pair to the world: its angular momentum (about the anchor's start) is conserved too.
    drift = np.linalg.norm(angular - angular0) / max(1.0, np.linalg.norm(angular0))
    print(f"{joint}: angular momentum drift {drift:.1e}")
    assert drift < 1e-9


# ---------------------------------------------------------------- custom joints from basic constraints
def test_custom_universal_from_point_and_angle():
    """A 'point' and an 'angle' constraint, added one by one, make a universal joint. Checked against the
    universal joint's definition in relative coordinates (Rig.coordinates, from the build-time anchor and axes,
    not from the engine's constraint data): the joint point and the angle between the two axes stay, the
    rotation about the two axes is free, and, with no joint to the world, both momenta of the pair hold."""
    rig = Rig("universal", seed=5, parent_dynamic=True, kinds=("point", "angle"))
    linear0, angular0 = rig.momenta()
    locked, history = run(rig)
    free, (linear, angular) = history[-1]
    print(f"\ncustom universal: locked {_fmt(locked)}, free {_fmt(free)}")
    for key, value in locked.items():
        assert value <= 2 * TOL, f"{key} moved by {value:.3g}"
    assert abs(free["alpha"]) > 0.1 and abs(free["beta"]) > 0.1, free
    np.testing.assert_allclose(linear, linear0, rtol=0, atol=1e-12 * max(1.0, np.abs(linear0).max()))
    assert np.linalg.norm(angular - angular0) < 1e-9 * max(1.0, np.linalg.norm(angular0))


def test_custom_point_on_line():
    """A lone 'line' constraint: the joint point stays on the line, slides along it, and turns every way."""
    rig = Rig("cylindrical", seed=3, kinds=("line",))
    linear0, angular0 = rig.momenta()
    q0 = rig.sim.orientations()[0]
    worst = 0.0
    for _ in range(STEPS):
        rig.sim.step()
        locked, free = rig.coordinates()
        worst = max(worst, locked["across"])
    linear, angular = rig.momenta()
    a = rig.axis
    turn = Rotation.from_matrix(rotations(rig.sim.orientations()[0]) @ rotations(q0).T).as_rotvec()
    print(f"\nline: across {worst:.1e}, slide {free['slide']:.3f}, turn {turn}")
    assert worst <= 2 * TOL
    assert abs(free["slide"]) > 0.1
    # Not held to the axis: the orientation turns about directions across it too.
    assert np.linalg.norm(turn - np.dot(turn, a) * a) > 0.1
    assert abs(np.dot(a, linear) - np.dot(a, linear0)) < 1e-9 * max(1.0, abs(np.dot(a, linear0)))
    assert abs(np.dot(a, angular) - np.dot(a, angular0)) < 1e-9 * max(1.0, np.linalg.norm(angular0))


def test_custom_axis_only():
    """A lone 'axis' constraint keeps the child's axis on the parent's and nothing else: the child
    translates freely (its linear momentum untouched) and spins about the axis."""
    rig = Rig("revolute", seed=4, kinds=("axis",))
    linear0, angular0 = rig.momenta()
    v0 = rig.sim.linear_velocities()[0]
    worst = 0.0
    for _ in range(STEPS):
        rig.sim.step()
        locked, free = rig.coordinates()
        worst = max(worst, locked["off_axis"])
    linear, angular = rig.momenta()
    print(f"\naxis: off axis {worst:.1e}, spin {free['spin']:.3f}")
    assert worst <= 2 * TOL
    assert abs(free["spin"]) > 0.1
    np.testing.assert_allclose(rig.sim.linear_velocities()[0], v0, atol=1e-12)
    np.testing.assert_allclose(linear, linear0, atol=1e-12)
    a = rig.axis
    assert abs(np.dot(a, angular) - np.dot(a, angular0)) < 1e-9 * max(1.0, np.linalg.norm(angular0))


def test_world_inertia_helper():
    """The helper the momentum checks use, against its definition: the angular momentum of a rigid cloud of
    point masses, sum m_k r_k x (w x r_k), with the cloud's inertia tensor given to the builder."""
    rng = np.random.default_rng(3)
    masses = rng.uniform(0.5, 2.0, 8)
    points = rng.normal(size=(8, 3))
    points -= masses @ points / masses.sum()  # about the centre of mass
    inertia = sum(m * (p @ p * np.eye(3) - np.outer(p, p)) for m, p in zip(masses, points))
    q = Rotation.random(random_state=4).as_quat()
    b = warpimpulse.SceneBuilder()
    b.add_body(masses.sum(), inertia, (0.0, 0.0, 0.0), q)
    w = rng.normal(size=3)
    r = rotations(q)  # also checked: it turns the body frame's axes as the quaternion says
    np.testing.assert_allclose(r @ [1.0, 0.0, 0.0], [1 - 2 * (q[1] ** 2 + q[2] ** 2), 2 * (q[0] * q[1] + q[2] * q[3]),
                                                     2 * (q[0] * q[2] - q[1] * q[3])], atol=1e-14)  # fmt: skip
    world_points = points @ r.T
    expected = sum(m * np.cross(p, np.cross(w, p)) for m, p in zip(masses, world_points))
    np.testing.assert_allclose(world_inertia(b, q[None, :])[0] @ w, expected, rtol=1e-12)
