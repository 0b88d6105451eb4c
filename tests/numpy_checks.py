"""Independent numpy checks of the engine's state.

The helpers here recompute joint errors, constraint velocities and momenta from the builder's constraint
data and the simulator's numpy state, with numpy rotation matrices: they share no code with the kernels, so a wrong
kernel and a wrong check would have to be wrong in the same way to hide a bug.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp
from reference import matrices
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from warpimpulse.types import ConstraintKind

POINT, LINE, PLANE, ROTATION, AXIS, ANGLE = ConstraintKind


def rotations(q) -> np.ndarray:
    """R(q) of (N, 4) or (4,) quaternions (x, y, z, w), not normalised first (scipy's from_quat would be): a
    quaternion off unit length gives a matrix off a rotation, which the checks built on it then see."""
    return matrices(q)


def _pose(b: int, x: np.ndarray, r: np.ndarray):
    if b < 0:
        return np.zeros(3), np.eye(3)
    return x[b], r[b]


def _twist(b: int, v: np.ndarray, w: np.ndarray):
    if b < 0:
        return np.zeros(3), np.zeros(3)
    return v[b], w[b]


def _perp(u: np.ndarray) -> np.ndarray:
    """Projector onto the plane perpendicular to the unit vector u."""
    return np.eye(3) - np.outer(u, u)


def constraint_errors(builder, x, q) -> np.ndarray:
    """Error of every basic constraint at poses (x, q), in m or rad: the distance of the joint point B from
    the point / line / plane of body0, the rotation angle away from the rest relative rotation, the angle
    between the common axes, and the change of the angle between the two angle axes."""
    r = rotations(q)
    out = np.zeros(len(builder.constraints))
    for i, c in enumerate(builder.constraints):
        x0, r0 = _pose(c.body0, x, r)
        x1, r1 = _pose(c.body1, x, r)
        a = x0 + r0 @ c.anchor0
        b = x1 + r1 @ c.anchor1
        n0 = r0 @ c.axis0
        n1 = r1 @ c.axis1
        kind = int(c.kind)
        if kind == POINT:
            out[i] = np.linalg.norm(b - a)
        elif kind == LINE:
            out[i] = np.linalg.norm(_perp(n0) @ (b - a))
        elif kind == PLANE:
            out[i] = abs(np.dot(n0, b - a))
        elif kind == ROTATION:
            # R0 R_rest R1^T is the identity when the constraint holds.
            rest = rotations(c.rest_rotation)
            out[i] = Rotation.from_matrix(r0 @ rest @ r1.T).magnitude()
        elif kind == AXIS:
            out[i] = np.linalg.norm(np.cross(n0, n1))
        else:
            out[i] = abs(np.arccos(np.clip(np.dot(n0, n1), -1.0, 1.0)) - c.rest_angle)
    return out


def constraint_velocity_errors(builder, x, q, v, w, with_slack=False):
    """|P_i (u_A - u_B)| of every constraint: the relative velocity of the joint points (or the relative
    angular velocity) in the directions the constraint removes.

    with_slack: also return |w0| |A - B| per constraint, the amount by which the answer changes when body0's
    velocity is taken at B instead of A (both conventions are sound; they differ while the joint error is
    not zero)."""
    r = rotations(q)
    out = np.zeros(len(builder.constraints))
    slack = np.zeros(len(builder.constraints))
    for i, c in enumerate(builder.constraints):
        x0, r0 = _pose(c.body0, x, r)
        x1, r1 = _pose(c.body1, x, r)
        v0, w0 = _twist(c.body0, v, w)
        v1, w1 = _twist(c.body1, v, w)
        a = x0 + r0 @ c.anchor0
        b = x1 + r1 @ c.anchor1
        n0 = r0 @ c.axis0
        n1 = r1 @ c.axis1
        kind = int(c.kind)
        if kind in (POINT, LINE, PLANE):
            # The velocities of the two joint points; for a line or plane, A is first moved to the point
            # closest to B (method paper, section 4.2).
            if kind == LINE:
                a = a + n0 * np.dot(b - a, n0)
            elif kind == PLANE:
                a = b - n0 * np.dot(b - a, n0)
            rel = (v0 + np.cross(w0, a - x0)) - (v1 + np.cross(w1, b - x1))
            slack[i] = np.linalg.norm(w0) * np.linalg.norm(a - b)
            if kind == LINE:
                rel = _perp(n0) @ rel
            elif kind == PLANE:
                rel = np.dot(n0, rel) * n0
        else:
            rel = w0 - w1
            if kind == AXIS:
                rel = _perp(n0) @ rel
            elif kind == ANGLE:
                n = np.cross(n0, n1)
                n /= np.linalg.norm(n)
                rel = np.dot(n, rel) * n
        out[i] = np.linalg.norm(rel)
    return (out, slack) if with_slack else out


def per_joint(builder, constraint_values: np.ndarray) -> np.ndarray:
    out = np.zeros(len(builder.joints))
    for j, joint in enumerate(builder.joints):
        out[j] = max(constraint_values[k] for k in joint.constraints)
    return out


def world_inertia(builder, q) -> np.ndarray:
    r = rotations(q)
    inertia = np.array([b.inertia for b in builder.bodies])
    return np.einsum("nij,njk,nlk->nil", r, inertia, r)


def momenta(builder, x, q, v, w, about=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Total linear momentum and total angular momentum about the point `about`."""
    about = np.asarray(about, dtype=float)
    m = np.array([b.mass for b in builder.bodies])
    linear = (m[:, None] * v).sum(axis=0)
    spin = np.einsum("nij,nj->ni", world_inertia(builder, q), w)
    angular = (np.cross(x - about, m[:, None] * v) + spin).sum(axis=0)
    return linear, angular


def velocity_within(stats, tolerance: float) -> bool:
    """The step's velocity correction left at most `tolerance`, or was left to the next read of the velocities
    or the next step (NaN, `Simulator.defer_velocities`: the read takes it and reports it under the iteration
    policy, and the caller's own check of the velocities read covers it)."""
    return math.isnan(stats.max_velocity_error) or stats.max_velocity_error <= tolerance


def sim_state(sim):
    return sim.positions(), sim.orientations(), sim.linear_velocities(), sim.angular_velocities()


class DoublePendulumReference:
    """Two uniform rods on parallel hinges in reduced coordinates (Lagrange's equations; the derivation is in
    test_double_pendulum.py), integrated by scipy's DOP853: shares no code with the engine."""

    def __init__(self, builder) -> None:
        b0, b1 = builder.bodies
        h0, h1 = builder.joints
        np.testing.assert_allclose(h0.axis, [0, 1, 0])
        np.testing.assert_allclose(h1.axis, [0, 1, 0])
        self.pivot = h0.anchor
        self.m1, self.m2 = b0.mass, b1.mass
        self.l1 = float(np.linalg.norm(h1.anchor - h0.anchor))
        self.c1 = float(np.linalg.norm(b0.position - h0.anchor))
        self.c2 = float(np.linalg.norm(b1.position - h1.anchor))
        self.i1, self.i2 = (self._hinge_moment(b) for b in (b0, b1))
        self.g = -float(builder.gravity[2])
        assert np.allclose(builder.gravity[:2], 0.0)

    @staticmethod
    def _hinge_moment(body) -> float:
        r = Rotation.from_quat(body.orientation).as_matrix()
        return float((r @ body.inertia @ r.T)[1, 1])

    def rhs(self, t, y):
        t1, t2, w1, w2 = y
        m1, m2, l1, c1, c2, g = self.m1, self.m2, self.l1, self.c1, self.c2, self.g
        c, s = math.cos(t1 - t2), math.sin(t1 - t2)
        m12 = m2 * l1 * c2 * c
        mass = np.array([[m1 * c1 * c1 + self.i1 + m2 * l1 * l1, m12], [m12, m2 * c2 * c2 + self.i2]])
        force = np.array(
            [
                -m2 * l1 * c2 * s * w2 * w2 - (m1 * c1 + m2 * l1) * g * math.sin(t1),
                m2 * l1 * c2 * s * w1 * w1 - m2 * c2 * g * math.sin(t2),
            ]
        )
        a1, a2 = np.linalg.solve(mass, force)
        return [w1, w2, a1, a2]

    def energy(self, y) -> np.ndarray:
        t1, t2, w1, w2 = y
        m1, m2, l1, c1, c2, g = self.m1, self.m2, self.l1, self.c1, self.c2, self.g
        kinetic = 0.5 * (m1 * c1 * c1 + self.i1 + m2 * l1 * l1) * w1**2 + 0.5 * (m2 * c2 * c2 + self.i2) * w2**2
        kinetic += m2 * l1 * c2 * np.cos(t1 - t2) * w1 * w2
        potential = -g * ((m1 * c1 + m2 * l1) * np.cos(t1) + m2 * c2 * np.cos(t2))
        return kinetic + potential

    def solve(self, angles, times, rtol: float = 1e-12):
        y0 = [angles[0], angles[1], 0.0, 0.0]
        sol = solve_ivp(self.rhs, (0.0, times[-1]), y0, method="DOP853", rtol=rtol, atol=rtol, t_eval=times)
        assert sol.success
        return sol.y

    def coms(self, y) -> np.ndarray:
        """(T, 2, 3) centre-of-mass positions of the two rods."""
        t1, t2 = y[0], y[1]
        u1 = np.stack([np.sin(t1), np.zeros_like(t1), -np.cos(t1)], axis=-1)
        u2 = np.stack([np.sin(t2), np.zeros_like(t2), -np.cos(t2)], axis=-1)
        return self.pivot + np.stack([self.c1 * u1, self.l1 * u1 + self.c2 * u2], axis=1)


class Internals:
    """The one place the tests read the engine's internals (their names change with refactors): the rows P_i
    of every constraint at the current state, a solve with the simulator's own linear solver, and the K that
    a CG solver assembles from the simulator's frames. Everything else goes through the public API."""

    def __init__(self, sim) -> None:
        self.sim = sim

    def rows(self) -> np.ndarray:
        """P_i (n_constraints, 3, 3) at the current state."""
        return self.sim.frames.proj.numpy()

    def formulation(self) -> str:
        return self.sim.linear.pattern.formulation

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """lambda of K lambda = rhs (n_constraints, 3) with the simulator's factorization."""
        b = wp.array(rhs, dtype=wp.vec3d)
        out = wp.zeros_like(b)
        self.sim.linear.solve(b, out)
        return out.numpy()

    def assembled_k(self) -> np.ndarray:
        """The dense K that the engine's assembly kernel writes (CG's full block pattern)."""
        from warpimpulse.solver import CGSolver

        model = self.sim.model
        cg = CGSolver(model, self.sim.frames)
        cg.prepare()
        csr = model.topology.csr()
        n = model.constraint_count
        k = np.zeros((3 * n, 3 * n))
        for value, i, j in zip(cg.values.numpy(), csr.row, csr.col):
            k[3 * i : 3 * i + 3, 3 * j : 3 * j + 3] = value
        return k
