"""The world inverse inertia J~^-1 = R J^-1 R^T of every body (method paper, section 4.1), kept as its 6
distinct numbers.

J~^-1 (1 / (kg m^2), world frame) is symmetric: the frames pass writes it once a step, and the assembly of K,
every pass that applies impulses, the rows' and contacts' code and the sweeps read it, so it is stored as its
upper triangle (`sym33d`, 48 bytes a body where a `mat33d` takes 72) and readers form the matrix in registers
(`symmetric_matrix`) or multiply a vector by it (`symmetric_times`). The upper triangle holds the same bits as
the full product R J^-1 R^T computed by Warp's matrix products (`world_inverse_inertia_of`); what changes is
that the readers' lower triangle is now its mirror, where the full product's lower triangle differed from it
by round-off (docs/architecture.md, "Cheaper stages").
"""

import warp as wp

from .rigid import DIAGONAL

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
quatd = wp.quatd
mat33d = wp.mat33d
f64 = wp.float64
sym33d = wp.types.vector(length=6, dtype=f64)
"""A symmetric 3x3 as its upper triangle, row by row: (xx, xy, xz, yy, yz, zz)."""


@wp.func
def symmetric_upper(m: mat33d) -> sym33d:
    """The upper triangle of m (`sym33d`); the lower is dropped (m symmetric up to round-off)."""
    return sym33d(m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2])


@wp.func
def symmetric_matrix(s: sym33d) -> mat33d:
    """The full symmetric matrix of s (`sym33d`): its lower triangle mirrors the upper."""
    return mat33d(s[0], s[1], s[2], s[1], s[3], s[4], s[2], s[4], s[5])


@wp.func
def symmetric_times(s: sym33d, u: vec3d) -> vec3d:
    """S u for the symmetric S stored as s (`sym33d`), in the order of Warp's matrix-vector product."""
    return symmetric_matrix(s) * u


@wp.func
def world_inverse_inertia_of(
    b: int,
    body_principal: wp.array(dtype=int),
    body_inv_principal: wp.array(dtype=vec3d),
    body_inv_inertia: wp.array(dtype=mat33d),
    body_q_in: wp.array(dtype=quatd),
    inv_inertia_world_out: wp.array(dtype=sym33d),
):
    """J~^-1 = R J^-1 R^T of body b at its current orientation, as its upper triangle; zero for static bodies.

    A body built on its principal axes (`body_principal` DIAGONAL, `rigid.principal_terms`) reads its inverse inertia's
    diagonal d (24 bytes, `body_inv_principal`) where the matrix takes 72, and forms R diag(d) = R with its
    columns scaled by d (9 products where the matrix product takes 27 multiply-adds): the same bits, since the
    matrix product's terms with the zeros of diag(d) add nothing exactly. Either way only the upper triangle of
    (R J^-1) R^T is formed (18 multiply-adds, in the order of Warp's matrix product)."""
    r = wp.quat_to_matrix(body_q_in[b])
    rt = wp.transpose(r)
    if body_principal[b] == DIAGONAL:
        d = body_inv_principal[b]
        inv_inertia_world_out[b] = symmetric_upper(wp.cw_mul(r, wp.matrix_from_rows(d, d, d)) * rt)
    else:
        inv_inertia_world_out[b] = symmetric_upper(r * body_inv_inertia[b] * rt)


@wp.kernel
def world_inverse_inertia(
    # Model:
    body_principal: wp.array(dtype=int),
    body_inv_principal: wp.array(dtype=vec3d),
    body_inv_inertia: wp.array(dtype=mat33d),
    # Data in:
    body_q_in: wp.array(dtype=quatd),
    # Data out:
    inv_inertia_world_out: wp.array(dtype=sym33d),
):
    """J~^-1 of every body (`world_inverse_inertia_of`)."""
    world_inverse_inertia_of(
        wp.tid(), body_principal, body_inv_principal, body_inv_inertia, body_q_in, inv_inertia_world_out
    )
