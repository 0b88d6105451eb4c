"""Random joint rigs: a parent and a child of random mass, full inertia tensor and orientation on each joint type,
shared by the joint and specialisation tests."""

from __future__ import annotations

import math

import numpy as np
from numpy_checks import momenta, rotations, sim_state
from reference import BallTree, matrices
from scipy.spatial.transform import Rotation

import warpimpulse
import warpimpulse as wi

DT = 1e-2
STEPS = 150
# Joint and velocity tolerance of these runs. Tight, because the impulse of a point constraint acts at A on
# one body and at B on the other, which are up to the tolerance apart: the allowed momenta then drift by about
# tolerance x impulse a step (measured at h = 1e-2 over 1.5 s: 1e-8 relative at 1e-6, 2e-12 at 1e-8, 1e-13 at 1e-10).
TOL = 1e-10
JOINTS = ("ball", "revolute", "prismatic", "cylindrical", "universal", "fixed", "planar")
# The branches of `floating_body`, in its order (its random draws follow it).
FLOATING_JOINTS = ("ball", "revolute", "universal", "cylindrical", "prismatic", "planar", "fixed")


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def _random_body(rng, b, position, v=0.0, w=0.0, name=None) -> int:
    moments = rng.uniform(0.8, 1.5, 3)  # any two add up to more than the third
    r = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    inertia = r @ np.diag(moments) @ r.T  # not diagonal in the body frame
    q = Rotation.random(random_state=rng.integers(1 << 31)).as_quat()
    return b.add_body(rng.uniform(0.5, 3.0), inertia, position, q, v, w, name=name)


class Rig:
    """A child on a joint to the world (or to a dynamic parent), and its relative coordinates."""

    def __init__(self, joint: str, seed: int, velocities=None, parent_dynamic=False, kinds=None) -> None:
        rng = np.random.default_rng(seed)
        self.joint = joint
        self.anchor = rng.normal(size=3)
        self.axis = _unit(rng.normal(size=3))
        child_axis = _unit(rng.normal(size=3))
        self.child_axis = _unit(child_axis - 0.5 * np.dot(child_axis, self.axis) * self.axis)
        com = self.anchor + rng.normal(scale=0.6, size=3)  # the child's centre of mass, off the joint
        self.b = b = warpimpulse.SceneBuilder(gravity=(0.0, 0.0, 0.0))
        self.parent = None
        if parent_dynamic:
            parent_com = self.anchor + rng.normal(scale=0.6, size=3)
            self.parent = _random_body(rng, b, parent_com, rng.normal(size=3), rng.normal(size=3), "parent")
        v, w = velocities(self, rng, com) if velocities else (rng.normal(size=3), rng.normal(size=3))
        self.child = _random_body(rng, b, com, v, w, "child")
        if kinds is not None:  # a custom joint from basic constraints
            for kind in kinds:
                b.add_constraint(kind, self.parent, self.child, self.anchor, self.axis, self.child_axis)
        elif joint == "universal":
            b.add_joint_universal(self.parent, self.child, self.anchor, self.axis, self.child_axis)
        else:
            axes = () if joint in ("ball", "fixed") else (self.axis,)
            getattr(b, f"add_joint_{joint}")(self.parent, self.child, self.anchor, *axes)
        self.sim = warpimpulse.Simulator(b.finalize(), DT, tolerance=TOL)
        # Body-frame constants: the joint point and axes on each side.
        x0, r0 = self.parent_pose()
        x1, r1 = self.child_pose()
        self.anchor_child = r1.T @ (self.anchor - x1)
        self.axis_parent = r0.T @ self.axis  # parent frame
        self.child_axis_child = r1.T @ self.child_axis  # child frame
        self.p0 = self.relative_point()
        self.r_rel0 = r0.T @ r1

    def parent_pose(self):
        if self.parent is None:
            return np.zeros(3), np.eye(3)
        return self.sim.positions()[self.parent], rotations(self.sim.orientations()[self.parent])

    def child_pose(self):
        return self.sim.positions()[self.child], rotations(self.sim.orientations()[self.child])

    def relative_point(self) -> np.ndarray:
        """The child's joint point in the parent frame."""
        x0, r0 = self.parent_pose()
        x1, r1 = self.child_pose()
        return r0.T @ (x1 + r1 @ self.anchor_child - x0)

    def coordinates(self) -> tuple[dict, dict]:
        """(locked, free) coordinates of the joint now, in the parent frame: locked ones stay 0."""
        x0, r0 = self.parent_pose()
        x1, r1 = self.child_pose()
        a = self.axis_parent
        dp = self.relative_point() - self.p0
        dr = r0.T @ r1 @ self.r_rel0.T  # the relative rotation since the start, parent frame
        turn = Rotation.from_matrix(dr)
        off_axis = np.linalg.norm(dr @ a - a)  # ~ the angle by which the rotation leaves the axis
        along = float(np.dot(a, dp))
        across = np.linalg.norm(dp - along * a)
        spin = float(np.dot(turn.as_rotvec(), a))  # the angle about the axis, while the rotation is about it
        j = self.joint
        if j == "ball":
            return {"point": np.linalg.norm(dp)}, {"rotation": turn.magnitude()}
        if j == "revolute":
            return {"point": np.linalg.norm(dp), "off_axis": off_axis}, {"spin": spin}
        if j == "prismatic":
            return {"across": across, "rotation": turn.magnitude()}, {"slide": along}
        if j == "cylindrical":
            return {"across": across, "off_axis": off_axis}, {"slide": along, "spin": spin}
        if j == "fixed":
            return {"point": np.linalg.norm(dp), "rotation": turn.magnitude()}, {}
        if j == "planar":
            return {"normal": abs(along), "off_axis": off_axis}, {"in_plane": across, "spin": spin}
        if j == "universal":
            b_now = r0.T @ r1 @ self.child_axis_child  # the child's axis in the parent frame
            b_start = self.r_rel0 @ self.child_axis_child
            angle = math.acos(np.clip(np.dot(a, b_now), -1, 1)) - math.acos(np.clip(np.dot(a, b_start), -1, 1))
            # dr = Rot(a, alpha) Rot(b_start, beta): alpha turns the child axis about a, beta is about it.
            alpha = angle_about(a, b_start, b_now)
            rest = Rotation.from_rotvec(-alpha * a) * turn
            beta = float(np.dot(rest.as_rotvec(), b_start))
            off = np.linalg.norm(rest.as_rotvec() - beta * b_start)
            return {"point": np.linalg.norm(dp), "angle": abs(angle), "other_rotation": off}, {
                "alpha": alpha,
                "beta": beta,
            }
        raise AssertionError(j)

    def momenta(self):
        return momenta(self.b, *sim_state(self.sim), about=self.anchor)


def angle_about(axis, u, v) -> float:
    """The angle about `axis` from u to v, both projected on the plane perpendicular to it."""
    pu = u - np.dot(u, axis) * axis
    pv = v - np.dot(v, axis) * axis
    return math.atan2(np.dot(axis, np.cross(pu, pv)), np.dot(pu, pv))


# ---------------------------------------------------------------- allowed velocities, world parent


def floating_body(seed: int, consistent: bool) -> warpimpulse.SceneBuilder:
    """A root with a branch of two bodies on every joint type; no joint to the world.

    consistent: start every child moving with its parent as one rigid body plus a random spin about its own
    joint axis, so no constraint is broken; otherwise random velocities that the first step repairs."""
    rng = np.random.default_rng(seed)
    b = warpimpulse.SceneBuilder(gravity=(0.0, 0.0, 0.0))
    v_root, w_root = rng.normal(size=3), rng.normal(size=3)

    def body(position, parent_motion=None, axis=None, anchor=None):
        moments = rng.uniform(0.8, 1.5, 3)
        r = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
        q = Rotation.random(random_state=rng.integers(1 << 31)).as_quat()
        if consistent:
            v, w = parent_motion if parent_motion is not None else (v_root, w_root)
        else:
            v, w = rng.normal(size=3), rng.normal(size=3)
        return b.add_body(rng.uniform(0.5, 3.0), r @ np.diag(moments) @ r.T, position, q, v, w)

    root = body(np.zeros(3))
    for k, joint in enumerate(FLOATING_JOINTS):
        direction = np.array(
            [np.cos(2 * np.pi * k / len(FLOATING_JOINTS)), np.sin(2 * np.pi * k / len(FLOATING_JOINTS)), 0.3]
        )
        parent, top = root, 0.5 * direction
        for _ in range(2):
            anchor = top
            centre = anchor + 0.5 * direction + rng.normal(scale=0.1, size=3)
            # Rigid motion of the root, at the child's centre.
            motion = (v_root + np.cross(w_root, centre), w_root)
            child = body(centre, motion)
            axis = rng.normal(size=3)
            if joint == "universal":
                b.add_joint_universal(parent, child, anchor, axis, rng.normal(size=3))
            elif joint in ("ball", "fixed"):
                b.add_joint(joint, parent, child, anchor)
            else:
                b.add_joint(joint, parent, child, anchor, axis)
            parent, top = child, anchor + direction
    return b


# ---------------------------------------------------------------- ball-joint systems in reduced coordinates
def rod_orientation(direction) -> np.ndarray:
    """The quaternion that turns +z onto `direction`."""
    z, d = np.array([0.0, 0.0, 1.0]), np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    axis = np.cross(z, d)
    angle = math.atan2(np.linalg.norm(axis), z @ d)
    return np.array([*(axis / np.linalg.norm(axis) * math.sin(0.5 * angle)), math.cos(0.5 * angle)])


def ball_chain(directions, lengths, masses, spins, gravity=(0.0, 0.0, -9.81)) -> tuple[wi.SceneBuilder, BallTree]:
    """Rods on ball joints, each hung from the end of the previous one (the first from the world origin), with
    asymmetric inertias (moments 1, 0.75, 0.3 of m L^2 / 12) and world angular velocities `spins`; every
    linear velocity is set from the reference's kinematics, so the joints hold at the start."""
    b = wi.SceneBuilder(gravity=gravity)
    top, parent = np.zeros(3), None
    for i, (d, length, mass, spin) in enumerate(zip(directions, lengths, masses, spins)):
        d = np.asarray(d, dtype=float) / np.linalg.norm(d)
        inertia = np.diag([1.0, 0.75, 0.3]) * (mass * length * length / 12.0)
        body = b.add_body(mass, inertia, top + 0.5 * length * d, rod_orientation(d), angular_velocity=spin,
                          name=f"rod{i}")  # fmt: skip
        b.add_joint_ball(parent, body, top, name=f"ball{i}")
        parent, top = body, top + length * d
    ref = BallTree(b)
    for body, v in zip(b.bodies, ref.velocities(ref.q0, ref.w0)):
        body.linear_velocity = v
    return b, ref


DURATION = 1.0


def run_against_reference(make, rate: int, duration: float = DURATION, tolerance: float = 1e-8):
    """Max centre-of-mass distance (m) and max |R - R_ref| from the reference over the run."""
    builder, ref = make()
    n = int(round(duration * rate))
    times = np.arange(n + 1) / rate
    com, q_ref, _ = ref.solve(times)
    np.testing.assert_allclose(com[0], [b.position for b in builder.bodies], atol=1e-12)
    sim = wi.Simulator(builder.finalize(), 1.0 / rate, tolerance=tolerance)
    x_err = r_err = 0.0
    for k in range(1, n + 1):
        sim.step()
        x_err = max(x_err, float(np.linalg.norm(sim.positions() - com[k], axis=1).max()))
        r_err = max(r_err, float(np.abs(matrices(sim.orientations()) - matrices(q_ref[k])).max()))
    return x_err, r_err


def welded_hinge(arm_spin: float = 0.0) -> wi.SceneBuilder:
    """A hinge and a fixed joint on the same pair, hung from the world: the loop joint's redundant rows are
    regularised in the factor (kernels/cholesky.py, `factor_column`); the arm turning at `arm_spin` (rad/s) about
    the hinge's axis."""
    b = wi.SceneBuilder()
    base = b.add_body(1.0, (0.1, 0.1, 0.1), (0.0, 0.0, 0.0), name="base")
    arm = b.add_body(2.0, (0.1, 0.2, 0.3), (1.0, 0.0, 0.0), name="arm", angular_velocity=(0.0, arm_spin, 0.0))
    b.add_joint_ball(None, base, (-0.5, 0.0, 0.0), name="pivot")
    b.add_joint_fixed(base, arm, (0.5, 0.0, 0.0), name="weld")
    b.add_joint_revolute(base, arm, (0.5, 0.0, 0.0), (0.0, 1.0, 0.0), name="hinge")
    return b
