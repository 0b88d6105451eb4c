"""Joint coordinates and their rates from the bodies' maximal coordinates (host side, numpy).

Every coordinate is zero at the build pose. Rotations are measured as the child's rotation relative to the
parent, expressed in the parent's frame: d = (q0^-1 q1) r^-1, with r = q0^-1 q1 at build time, so a hinge
turned by theta about its axis a (parent frame) has d = R_a(theta). Offsets are those of the child's anchor
from the parent's anchor, in the parent's frame.

| joint | coordinates | rates |
|---|---|---|
| revolute | [angle about the axis] (rad, right-handed) | [rad/s] |
| prismatic | [offset along the axis] (m) | [m/s] |
| cylindrical | [offset, angle] | [m/s, rad/s] |
| universal | [angle about the parent axis, angle about the child axis] | their rates |
| planar | [x, y, angle] in the plane (m, m, rad) | their rates |
| ball | the relative rotation d as a quaternion (x, y, z, w) | the relative angular velocity, parent frame |
| fixed | [] | [] |
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .transforms import quat_conj, quat_mul, quat_rotate, quat_to_matrix
from .types import WORLD

CATALOGUE = ("revolute", "prismatic", "cylindrical", "universal", "planar", "ball", "fixed")


@dataclass
class JointFrame:
    """One joint's geometry at the current state, in its parent's frame."""

    kind: str
    rotation: np.ndarray  # d, the relative rotation (x, y, z, w)
    offset: np.ndarray  # child anchor minus parent anchor (m)
    axis: np.ndarray  # the joint axis or plane normal (unit)
    child_axis: np.ndarray  # a universal joint's child axis, where it is now (unit)
    child_axis_built: np.ndarray  # ... and where it was at build time
    angular_rate: np.ndarray  # child minus parent angular velocity (rad/s)
    offset_rate: np.ndarray  # d/dt of `offset` (m/s)


def twist_angle(q: np.ndarray, axis: np.ndarray) -> float:
    """The angle (rad, in (-pi, pi]) of the part of rotation q about the unit `axis` (swing-twist split)."""
    angle = 2.0 * np.arctan2(float(np.dot(q[:3], axis)), float(q[3]))
    return float(angle - 2.0 * np.pi * np.round(angle / (2.0 * np.pi)))


def _in_plane_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane normal to n, fixed in the parent's frame (as the kernels' choice)."""
    t = np.array([0.0, 1.0, 0.0]) if abs(n[0]) > 0.7 else np.array([1.0, 0.0, 0.0])
    u = np.cross(n, t)
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


def _pose(b: int, x: np.ndarray, q: np.ndarray, v: np.ndarray, w: np.ndarray):
    if b == WORLD:
        return np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.zeros(3)
    return x[b], q[b], v[b], w[b]


def joint_frame(model, joint: int, x: np.ndarray, q: np.ndarray, v: np.ndarray, w: np.ndarray) -> JointFrame:
    """`joint`'s relative rotation, offset and their rates at the state (x, q, v, w) (world frame, (n, .))."""
    h = model.host
    c = int(h.joint_constraint_start[joint])
    parent, child = int(h.joint_parent[joint]), int(h.joint_child[joint])
    x0, q0, v0, w0 = _pose(parent, x, q, v, w)
    x1, q1, v1, w1 = _pose(child, x, q, v, w)
    r0 = quat_to_matrix(q0)
    p0 = x0 + r0 @ h.constraint_anchor0[c]
    p1 = x1 + quat_rotate(q1, h.constraint_anchor1[c])
    relative = quat_mul(quat_conj(q0), q1)
    rest = h.constraint_rest_rotation[c]
    dp0 = v0 + np.cross(w0, p0 - x0)
    dp1 = v1 + np.cross(w1, p1 - x1)
    child_axis_built = quat_rotate(rest, h.constraint_axis1[c])
    return JointFrame(
        kind=model.joint_type[joint],
        rotation=quat_mul(relative, quat_conj(rest)),
        offset=r0.T @ (p1 - p0),
        axis=h.constraint_axis0[c],
        child_axis=quat_rotate(relative, h.constraint_axis1[c]),
        child_axis_built=child_axis_built,
        angular_rate=r0.T @ (w1 - w0),
        offset_rate=r0.T @ (dp1 - dp0 - np.cross(w0, p1 - p0)),
    )


def _check(model, joint: int) -> None:
    kind = model.joint_type[joint]
    if kind not in CATALOGUE:
        raise ValueError(
            f"joint {model.joint_name[joint]!r} is a custom joint of basic constraints ({kind}); coordinates are "
            f"defined for the catalogue joints {CATALOGUE}"
        )


def _signed_angle(a: np.ndarray, b: np.ndarray, axis: np.ndarray) -> float:
    """The angle (rad) about `axis` from a to b, both projected on the plane normal to `axis`."""
    a = a - axis * np.dot(a, axis)
    b = b - axis * np.dot(b, axis)
    return float(np.arctan2(np.dot(axis, np.cross(a, b)), np.dot(a, b)))


def coordinates(model, joint: int, x, q, v, w) -> np.ndarray:
    """The joint's coordinates (see the module docstring)."""
    _check(model, joint)
    f = joint_frame(model, joint, x, q, v, w)
    a = f.axis
    if f.kind == "revolute":
        return np.array([twist_angle(f.rotation, a)])
    if f.kind == "prismatic":
        return np.array([f.offset @ a])
    if f.kind == "cylindrical":
        return np.array([f.offset @ a, twist_angle(f.rotation, a)])
    if f.kind == "universal":
        alpha = _signed_angle(f.child_axis_built, f.child_axis, a)
        undo = np.append(-a * np.sin(0.5 * alpha), np.cos(0.5 * alpha))
        return np.array([alpha, twist_angle(quat_mul(undo, f.rotation), f.child_axis_built)])
    if f.kind == "planar":
        u, t = _in_plane_basis(a)
        return np.array([f.offset @ u, f.offset @ t, twist_angle(f.rotation, a)])
    if f.kind == "ball":
        return f.rotation * (1.0 if f.rotation[3] >= 0.0 else -1.0)
    return np.zeros(0)


def velocities(model, joint: int, x, q, v, w) -> np.ndarray:
    """The rates of the joint's coordinates (a ball joint: its relative angular velocity, parent frame)."""
    _check(model, joint)
    f = joint_frame(model, joint, x, q, v, w)
    a = f.axis
    if f.kind == "revolute":
        return np.array([f.angular_rate @ a])
    if f.kind == "prismatic":
        return np.array([f.offset_rate @ a])
    if f.kind == "cylindrical":
        return np.array([f.offset_rate @ a, f.angular_rate @ a])
    if f.kind == "universal":  # omega = alpha' a + beta' b (b: the child axis now), least squares
        basis = np.stack([a, f.child_axis], axis=1)
        return np.linalg.lstsq(basis, f.angular_rate, rcond=None)[0]
    if f.kind == "planar":
        u, t = _in_plane_basis(a)
        return np.array([f.offset_rate @ u, f.offset_rate @ t, f.angular_rate @ a])
    if f.kind == "ball":
        return f.angular_rate
    return np.zeros(0)
