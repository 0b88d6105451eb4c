"""Host-side quaternion helpers (numpy). Quaternions are (x, y, z, w), as in Warp; matrices act on column
vectors.

Each function takes one quaternion (shape (4,)) or a batch (..., 4). One quaternion is computed on Python
floats: numpy's stacking costs ~50 us a call, which adds up when a USD scene of 10,000 bodies is read one
prim at a time. Each formula is written once, over components that are floats or arrays alike.
"""

from __future__ import annotations

import math

import numpy as np


def _components(q: np.ndarray):
    """(x, y, z, w) as Python floats for one quaternion, as arrays over the batch otherwise."""
    return q.tolist() if q.ndim == 1 else _split(q)


def _split(a: np.ndarray) -> tuple:
    """The last axis's components as views (cheaper than np.moveaxis for the builder's one-row batches)."""
    return tuple(a[..., k] for k in range(a.shape[-1]))


def _product(ax, ay, az, aw, bx, by, bz, bw) -> tuple:
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def _rows(x, y, z, w) -> tuple:
    return (
        (1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)),
        (2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)),
        (2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)),
    )


def rotate_components(q, *vectors) -> list[tuple]:
    """Each vector rotated by the unit quaternion q, all given as components (Python floats, or arrays that
    broadcast): quat_rotate's batch formula, for callers that keep components (the builder computes a one-row
    add on floats and a batch on arrays, with the same bits)."""
    rows = _rows(*q)
    return [tuple(r0 * vx + r1 * vy + r2 * vz for r0, r1, r2 in rows) for vx, vy, vz in vectors]


def mul_components(a, b) -> tuple:
    """The rotation a * b of quaternions given as components (floats or arrays): quat_mul's formula."""
    return _product(*a, *b)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation a * b (b first, then a)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.ndim == b.ndim == 1:
        return np.array(_product(*a.tolist(), *b.tolist()))
    return np.stack(_product(*_split(a), *_split(b)), axis=-1)


def quat_conj(q: np.ndarray) -> np.ndarray:
    """The inverse rotation of unit quaternions."""
    q = np.asarray(q, dtype=float)
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4)."""
    q = np.asarray(q, dtype=float)
    rows = _rows(*_components(q))
    if q.ndim == 1:
        return np.array(rows)
    return np.stack([np.stack(row, -1) for row in rows], axis=-2)


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectors v (..., 3) rotated by unit quaternions q (..., 4)."""
    q, v = np.asarray(q, dtype=float), np.asarray(v, dtype=float)
    if q.ndim == 1 and v.ndim == 1:
        return quat_to_matrix(q) @ v
    # Element-wise over the batch (no matrix stacked, no reduction): a row gives the same bits in a batch of any size.
    return np.stack(rotate_components(_split(q), _split(v))[0], axis=-1)


def quat_from_matrix(m: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of one rotation matrix (column vectors), w >= 0."""
    m = np.asarray(m, dtype=np.float64).tolist()
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [(m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s, 0.25 * s]
    elif m[0][0] > m[1][1] and m[0][0] > m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2])
        q = [0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s, (m[2][1] - m[1][2]) / s]
    elif m[1][1] > m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2])
        q = [(m[0][1] + m[1][0]) / s, 0.25 * s, (m[1][2] + m[2][1]) / s, (m[0][2] - m[2][0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1])
        q = [(m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, 0.25 * s, (m[1][0] - m[0][1]) / s]
    n = math.sqrt(sum(c * c for c in q))
    sign = -1.0 if q[3] < 0.0 else 1.0
    return np.array([sign * c / n for c in q])


def quat_from_axis_angle(axis, angle: float) -> np.ndarray:
    """The rotation by `angle` (rad, right-handed) about `axis` (any length)."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    return np.append(axis * np.sin(0.5 * angle), np.cos(0.5 * angle))


def quat_between(a, b) -> np.ndarray:
    """The shortest rotation taking direction a onto direction b; (..., 3) batches give (..., 4)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.ndim > 1 or b.ndim > 1:
        return _quats_between(a, b)
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    c = np.cross(a, b)
    d = float(np.dot(a, b))
    if d < -1.0 + 1e-12:
        ortho = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(ortho) < 1e-6:
            ortho = np.cross(a, [0.0, 1.0, 0.0])
        return quat_from_axis_angle(ortho, np.pi)
    q = np.append(c, 1.0 + d)
    return q / np.linalg.norm(q)


def _quats_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """`quat_between` of a batch: the same formula, and the same half turn where a and b are opposite."""
    a, b = np.broadcast_arrays(a, b)
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    d = np.sum(a * b, axis=-1)
    q = np.concatenate([np.cross(a, b), (1.0 + d)[..., None]], axis=-1)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    q /= np.where(norm > 0.0, norm, 1.0)  # zero only where a and b are opposite, replaced below
    opposite = d < -1.0 + 1e-12
    if np.any(opposite):
        ortho = np.cross(a[opposite], [1.0, 0.0, 0.0])
        small = np.linalg.norm(ortho, axis=-1) < 1e-6
        ortho[small] = np.cross(a[opposite][small], [0.0, 1.0, 0.0])
        ortho /= np.linalg.norm(ortho, axis=-1, keepdims=True)
        q[opposite] = np.concatenate([ortho * np.sin(0.5 * np.pi), np.full((len(ortho), 1), np.cos(0.5 * np.pi))], -1)
    return q
