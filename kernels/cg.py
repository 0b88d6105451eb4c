"""Block-Jacobi preconditioned conjugate gradient on the full block-CSR K (rows = constraints).

`warp.optim.linear.cg` is too slow on a CPU (docs/architecture.md, "Measured facts"), so these are our own.
Scalars live in a small array: [rz, pq, rz_new, rr] so that every kernel reads values the previous launch finished.
"""

import warp as wp

from .cholesky import cholesky3_inverse

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
mat33d = wp.mat33d
f64 = wp.float64

RZ = wp.constant(0)
PQ = wp.constant(1)
RZ_NEW = wp.constant(2)
RR = wp.constant(3)


@wp.func
def row_times(i: int, row_start: wp.array(dtype=int), col: wp.array(dtype=int), values: wp.array(dtype=mat33d),
              x: wp.array(dtype=vec3d)) -> vec3d:  # fmt: skip
    s = vec3d()
    k = row_start[i]
    while k < row_start[i + 1]:
        s += values[k] * x[col[k]]
        k += 1
    return s


@wp.kernel
def diagonal_inverse(diag_slot: wp.array(dtype=int), values: wp.array(dtype=mat33d), precond: wp.array(dtype=mat33d)):
    """The block-Jacobi preconditioner: K_ii^-1 = L^-T L^-1 of each diagonal block."""
    i = wp.tid()
    li, bad = cholesky3_inverse(values[diag_slot[i]], f64(0.0), f64(1.0))
    precond[i] = wp.transpose(li) * li


@wp.kernel
def cg_start(
    row_start: wp.array(dtype=int),
    col: wp.array(dtype=int),
    values: wp.array(dtype=mat33d),
    precond: wp.array(dtype=mat33d),
    b: wp.array(dtype=vec3d),
    x: wp.array(dtype=vec3d),
    r: wp.array(dtype=vec3d),
    p: wp.array(dtype=vec3d),
    scalars: wp.array(dtype=f64),
):
    """r = b - K x (x is the warm start), p = z = M^-1 r; accumulates rz (as rz_new) and rr.

    The host zeroes the scalars first. Each iteration then runs: rotate, matvec, step, direction.
    """
    i = wp.tid()
    ri = b[i] - row_times(i, row_start, col, values, x)
    zi = precond[i] * ri
    r[i] = ri
    p[i] = zi
    wp.atomic_add(scalars, RZ_NEW, wp.dot(ri, zi))
    wp.atomic_add(scalars, RR, wp.dot(ri, ri))


@wp.kernel
def cg_matvec(
    row_start: wp.array(dtype=int),
    col: wp.array(dtype=int),
    values: wp.array(dtype=mat33d),
    p: wp.array(dtype=vec3d),
    q: wp.array(dtype=vec3d),
    scalars: wp.array(dtype=f64),
):
    """q = K p and pq = p . q."""
    i = wp.tid()
    qi = row_times(i, row_start, col, values, p)
    q[i] = qi
    wp.atomic_add(scalars, PQ, wp.dot(p[i], qi))


@wp.kernel
def cg_step(
    precond: wp.array(dtype=mat33d),
    p: wp.array(dtype=vec3d),
    q: wp.array(dtype=vec3d),
    x: wp.array(dtype=vec3d),
    r: wp.array(dtype=vec3d),
    z: wp.array(dtype=vec3d),
    scalars: wp.array(dtype=f64),
):
    """x += alpha p, r -= alpha q, z = M^-1 r; accumulates the new rz and rr."""
    i = wp.tid()
    alpha = scalars[RZ] / scalars[PQ]
    x[i] = x[i] + alpha * p[i]
    ri = r[i] - alpha * q[i]
    zi = precond[i] * ri
    r[i] = ri
    z[i] = zi
    wp.atomic_add(scalars, RZ_NEW, wp.dot(ri, zi))
    wp.atomic_add(scalars, RR, wp.dot(ri, ri))


@wp.kernel
def cg_direction(z: wp.array(dtype=vec3d), p: wp.array(dtype=vec3d), scalars: wp.array(dtype=f64)):
    """p = z + beta p with beta = rz_new / rz."""
    i = wp.tid()
    p[i] = z[i] + (scalars[RZ_NEW] / scalars[RZ]) * p[i]


@wp.kernel
def cg_rotate_scalars(scalars: wp.array(dtype=f64)):
    """rz = rz_new; clear the accumulators of the next iteration."""
    scalars[RZ] = scalars[RZ_NEW]
    scalars[PQ] = f64(0.0)
    scalars[RZ_NEW] = f64(0.0)
    scalars[RR] = f64(0.0)
