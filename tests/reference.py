"""Independent references for the engine's 3D motion, in numpy and scipy only (no code shared with the kernels).

- `FreeBody`: the torque-free (or torqued) rigid body, Euler's equations in the body frame and quaternion
  kinematics, integrated by scipy's DOP853.
- `BallTree`: bodies hung from the world by a tree of ball joints, in reduced coordinates: the generalized
  speeds are the bodies' world angular velocities, and the equations of motion come from Kane's method
  (d'Alembert's principle projected on the partial velocities), M(q) w' = Q(q, w), with the positions
  following from the orientations by the kinematics of the tree. External forces (at the centre of mass) and
  torques, switched off at their `until`, are part of Q.
- `numpy_energy`: kinetic plus gravitational energy from raw states.
- `numpy_k`: the system matrix J M^-1 J^T of the basic constraints, from the bodies and the constraints.

Quaternions are (x, y, z, w) and are never normalised silently here: `matrices` gives R(q) of the raw
quaternion (exact for a unit quaternion, not a rotation otherwise), so a check built on it sees |q| != 1.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

WORLD = -1
RTOL = 1e-12


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (..., 4) quaternions (x, y, z, w)."""
    av, aw = a[..., :3], a[..., 3:]
    bv, bw = b[..., :3], b[..., 3:]
    return np.concatenate([aw * bv + bw * av + np.cross(av, bv), aw * bw - np.sum(av * bv, -1, keepdims=True)], -1)


def matrices(q) -> np.ndarray:
    """R(q) of (..., 4) quaternions, the textbook formula without normalisation."""
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )  # fmt: skip
    return r.reshape(*q.shape[:-1], 3, 3)


def skew(v: np.ndarray) -> np.ndarray:
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def numpy_energy(builder, x, q, v, w) -> float:
    """sum 1/2 m v^2 + 1/2 w^T R I R^T w - m g.x over dynamic bodies, from raw (unnormalised) state arrays."""
    m = np.array([0.0 if b.static else b.mass for b in builder.bodies])
    inertia = np.array([b.inertia for b in builder.bodies])
    r = matrices(q)
    iw = r @ inertia @ np.swapaxes(r, -1, -2)
    kinetic = 0.5 * np.sum(m * np.sum(v * v, axis=1)) + 0.5 * np.einsum("ni,nij,nj->", w, iw, w)
    return float(kinetic - np.sum(m * (x @ np.asarray(builder.gravity))))


class FreeBody:
    """One rigid body: I wb' = tau_b - wb x I wb (body frame), q' = 1/2 q (wb, 0); the world torque constant."""

    def __init__(self, inertia, q0, w0_world, torque=(0.0, 0.0, 0.0)) -> None:
        self.inertia = np.asarray(inertia, dtype=np.float64)
        self.inv = np.linalg.inv(self.inertia)
        self.q0 = np.asarray(q0, dtype=np.float64)
        self.wb0 = matrices(self.q0).T @ np.asarray(w0_world, dtype=np.float64)
        self.torque = np.asarray(torque, dtype=np.float64)

    def rhs(self, t, y):
        q, wb = y[:4], y[4:]
        r = matrices(q / np.linalg.norm(q))
        dw = self.inv @ (r.T @ self.torque - np.cross(wb, self.inertia @ wb))
        dq = 0.5 * qmul(q, np.array([*wb, 0.0]))
        return np.concatenate([dq, dw])

    def solve(self, times) -> tuple[np.ndarray, np.ndarray]:
        """(orientations (T, 4), world angular velocities (T, 3)) at `times`."""
        sol = solve_ivp(self.rhs, (0.0, times[-1]), np.concatenate([self.q0, self.wb0]), method="DOP853",
                        rtol=RTOL, atol=RTOL, t_eval=times)  # fmt: skip
        assert sol.success, sol.message
        q = sol.y[:4].T / np.linalg.norm(sol.y[:4].T, axis=1, keepdims=True)
        w = np.einsum("tij,tj->ti", matrices(q), sol.y[4:].T)
        return q, w


class BallTree:
    """A tree of ball joints hung from the world, from a SceneBuilder whose joints are all "ball" (each body has
    exactly one parent joint), in reduced coordinates (orientations and world angular velocities)."""

    def __init__(self, builder) -> None:
        bodies = builder.bodies
        n = len(bodies)
        self.n = n
        self.parent = np.full(n, WORLD)
        anchor = np.zeros((n, 3))
        for j in builder.joints:
            assert j.kind == "ball", j.kind
            self.parent[j.child] = j.parent
            anchor[j.child] = j.anchor
        self.order = sorted(range(n), key=self._depth)  # parents before children
        r0 = matrices(np.array([b.orientation for b in bodies]))
        self.mass = np.array([b.mass for b in bodies])
        self.inertia = np.array([b.inertia for b in bodies])
        self.root_anchor = {i: anchor[i] for i in range(n) if self.parent[i] == WORLD}
        # Body-frame vectors: joint -> centre of mass, and joint -> each child's joint.
        self.com_local = np.array([r0[i].T @ (bodies[i].position - anchor[i]) for i in range(n)])
        self.child_local = {
            i: r0[self.parent[i]].T @ (anchor[i] - anchor[self.parent[i]]) for i in range(n) if self.parent[i] >= 0
        }
        self.path = [self._path(i) for i in range(n)]  # ancestors and self, root first
        self.gravity = np.asarray(builder.gravity, dtype=np.float64)
        self.forces = [(f.body, f.force, f.torque, f.until) for f in builder.forces]
        self.q0 = np.array([b.orientation for b in bodies])
        self.w0 = np.array([b.angular_velocity for b in bodies])

    def _depth(self, i: int) -> int:
        d = 0
        while self.parent[i] >= 0:
            i, d = self.parent[i], d + 1
        return d

    def _path(self, i: int) -> list[int]:
        out = [i]
        while self.parent[out[-1]] >= 0:
            out.append(int(self.parent[out[-1]]))
        return out[::-1]

    def kinematics(self, q: np.ndarray):
        """Rotations, joint points, centres of mass, and the lever s[k][i] of body k towards body i."""
        r = matrices(q / np.linalg.norm(q, axis=1, keepdims=True))
        joint = np.zeros((self.n, 3))
        for i in self.order:
            p = self.parent[i]
            joint[i] = self.root_anchor[i] if p < 0 else joint[p] + r[p] @ self.child_local[i]
        com = joint + np.einsum("nij,nj->ni", r, self.com_local)
        lever = {}
        for i in range(self.n):
            path = self.path[i]
            for a, k in enumerate(path):
                lever[k, i] = r[k] @ (self.com_local[k] if k == i else self.child_local[path[a + 1]])
        return r, joint, com, lever

    def velocities(self, q: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Centre-of-mass velocities: v_i = sum over the path to i of w_k x s_ki."""
        _, _, _, lever = self.kinematics(q)
        return np.array([sum(np.cross(w[k], lever[k, i]) for k in self.path[i]) for i in range(self.n)])

    def rhs(self, t, y, loads):
        n = self.n
        q = y[: 4 * n].reshape(n, 4)
        w = y[4 * n :].reshape(n, 3)
        r, _, _, lever = self.kinematics(q)
        iw = r @ self.inertia @ np.swapaxes(r, 1, 2)
        mass = np.zeros((3 * n, 3 * n))
        gen = np.zeros(3 * n)
        force, torque = loads
        for i in range(n):
            jac = np.zeros((3, 3 * n))  # v_i = jac w
            centripetal = np.zeros(3)
            for k in self.path[i]:
                jac[:, 3 * k : 3 * k + 3] = -skew(lever[k, i])
                centripetal += np.cross(w[k], np.cross(w[k], lever[k, i]))
            mass += self.mass[i] * jac.T @ jac
            mass[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] += iw[i]
            gen += jac.T @ (force[i] + self.mass[i] * (self.gravity - centripetal))
            gen[3 * i : 3 * i + 3] += torque[i] - np.cross(w[i], iw[i] @ w[i])
        dw = np.linalg.solve(mass, gen)
        dq = 0.5 * qmul(np.concatenate([w, np.zeros((n, 1))], axis=1), q)
        return np.concatenate([dq.ravel(), dw])

    def _loads(self, t: float):
        force, torque = np.zeros((self.n, 3)), np.zeros((self.n, 3))
        for b, f, tau, until in self.forces:
            if t < until:
                force[b] += f
                torque[b] += tau
        return force, torque

    def solve(self, times) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(centres of mass (T, n, 3), orientations (T, n, 4), world angular velocities (T, n, 3)) at `times`,
        integrated piecewise between the instants where a load switches off."""
        times = np.asarray(times, dtype=np.float64)
        cuts = sorted({0.0, float(times[-1])} | {u for *_, u in self.forces if 0.0 < u < times[-1]})
        y = np.concatenate([self.q0.ravel(), self.w0.ravel()])
        out = np.zeros((len(times), len(y)))
        for t0, t1 in zip(cuts[:-1], cuts[1:]):
            inside = (times >= t0) & (times <= t1)
            sol = solve_ivp(self.rhs, (t0, t1), y, method="DOP853", rtol=RTOL, atol=RTOL,
                            t_eval=times[inside], args=(self._loads(t0),), dense_output=True)  # fmt: skip
            assert sol.success, sol.message
            out[inside] = sol.y.T
            y = sol.sol(t1)
        q = out[:, : 4 * self.n].reshape(len(times), self.n, 4)
        q = q / np.linalg.norm(q, axis=2, keepdims=True)
        w = out[:, 4 * self.n :].reshape(len(times), self.n, 3)
        com = np.array([self.kinematics(qt)[2] for qt in q])
        return com, q, w

    def energy(self, q: np.ndarray, w: np.ndarray) -> float:
        r, _, com, _ = self.kinematics(q)
        v = self.velocities(q, w)
        iw = r @ self.inertia @ np.swapaxes(r, 1, 2)
        kinetic = 0.5 * np.sum(self.mass * np.sum(v * v, axis=1)) + 0.5 * np.einsum("ni,nij,nj->", w, iw, w)
        return float(kinetic - np.sum(self.mass * (com @ self.gravity)))


def order(coarse: float, fine: float, ratio: float = 2.0) -> float:
    """The observed convergence order from errors at step sizes h and h / ratio."""
    return math.log(coarse / fine) / math.log(ratio)


POINT, LINE, PLANE, ROTATION, AXIS, ANGLE = range(6)
DIM = (3, 2, 1, 3, 2, 1)


def check_rows(kind: int, rows: np.ndarray, n0: np.ndarray, n1: np.ndarray) -> None:
    """Assert that `rows` (3x3, the engine's P_i) are the directions the constraint removes: the identity for a
    point or rotation, two orthonormal rows across the axis for a line or common axis, the normal of a plane,
    the normal of the two axes of an angle; unused rows zero. Only the basis of a plane of directions is the
    engine's choice; everything else is checked."""
    d = DIM[kind]
    np.testing.assert_allclose(rows[d:], 0.0, atol=0)
    used = rows[:d]
    np.testing.assert_allclose(used @ used.T, np.eye(d), atol=1e-12)
    if kind in (POINT, ROTATION):
        np.testing.assert_allclose(used, np.eye(3), atol=1e-12)
    elif kind in (LINE, AXIS):
        np.testing.assert_allclose(used @ n0, 0.0, atol=1e-12)
    elif kind == PLANE:
        np.testing.assert_allclose(used[0], n0, atol=1e-12)
    else:
        n = np.cross(n0, n1)
        np.testing.assert_allclose(used[0], n / np.linalg.norm(n), atol=1e-12)


def numpy_jacobian(builder, x, q, rows) -> np.ndarray:
    """J (3 n_constraints x 6 n_bodies) at poses (x, q): the rate of every constraint's error, c = A - B (or
    its rotational analogue), in the directions `rows[i]` (the engine's P_i, checked by `check_rows`), for
    generalized velocities (v_0, w_0, v_1, w_1, ...) in the world frame. A translational constraint's impulses
    act at the joint point B on both bodies; the velocity of B as a point of body k is v_k + w_k x (B - x_k)."""
    r = matrices(q)
    jac = np.zeros((3 * len(builder.constraints), 6 * len(builder.bodies)))
    for i, c in enumerate(builder.constraints):
        kind = int(c.kind)
        r0 = np.eye(3) if c.body0 < 0 else r[c.body0]
        r1 = r[c.body1]
        x1 = x[c.body1]
        n0, n1 = r0 @ c.axis0, r1 @ c.axis1
        check_rows(kind, rows[i], n0, n1)
        p = rows[i]
        b = x1 + r1 @ c.anchor1
        for body, sign in ((c.body0, 1.0), (c.body1, -1.0)):
            if body < 0 or builder.bodies[body].static:
                continue
            block = jac[3 * i : 3 * i + 3, 6 * body : 6 * body + 6]
            if kind < ROTATION:
                block[:, :3] = sign * p
                block[:, 3:] = -sign * p @ skew(b - x[body])
            else:
                block[:, 3:] = sign * p
    return jac


def numpy_inverse_mass(builder, q) -> np.ndarray:
    """M^-1 (6 n x 6 n): 1/m I and R I^-1 R^T per dynamic body, zero for static ones."""
    r = matrices(q)
    out = np.zeros((6 * len(builder.bodies),) * 2)
    for k, body in enumerate(builder.bodies):
        if not body.static:
            out[6 * k : 6 * k + 3, 6 * k : 6 * k + 3] = np.eye(3) / body.mass
            out[6 * k + 3 : 6 * k + 6, 6 * k + 3 : 6 * k + 6] = r[k] @ np.linalg.inv(body.inertia) @ r[k].T
    return out


def numpy_k(builder, x, q, rows) -> np.ndarray:
    """K = J M^-1 J^T, with a unit diagonal in the unused rows of constraints of dimension < 3 (so it is SPD)."""
    jac = numpy_jacobian(builder, x, q, rows)
    k = jac @ numpy_inverse_mass(builder, q) @ jac.T
    for i, c in enumerate(builder.constraints):
        for row in range(DIM[int(c.kind)], 3):
            k[3 * i + row, 3 * i + row] = 1.0
    return k
