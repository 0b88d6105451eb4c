"""Block assembly of the system matrix K = J M^-1 J^T (method paper, section 4.5; docs/architecture.md).

K is stored as 3x3 blocks in "slots". Each slot is one block (row constraint i, column constraint j)
and lists the bodies the two constraints share (at most two) by the side each has on them. The host
builds the slot lists once per topology (`warpimpulse/topology.py`): the lower factor pattern for
Cholesky (fill slots share no body and assemble to zero) and the full pattern for CG.
"""

import warp as wp

from ..types import Slot
from .constraints import POINT, constraint_dim, skew_times, skew_vector, times_skew_transpose

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
mat33d = wp.mat33d
f64 = wp.float64


@wp.func
def side_body(i: int, side: int, constraint_body0: wp.array(dtype=int), constraint_body1: wp.array(dtype=int)):
    if side == 0:
        return constraint_body0[i]
    return constraint_body1[i]


@wp.func
def row_products(kind: int, inv_mass: f64, inv_inertia_world: mat33d, jac_lin: mat33d, jac_ang: mat33d):
    """(m^-1 J_lin, J_ang J~^-1) of one side of a constraint of `kind`: that side's factor of every block of K
    its body is in, computed once a row instead of once a block. A point constraint's J_ang is a skew matrix
    (`constraints.constraint_frame`): its product is `skew_times`."""
    if kind == POINT:
        return inv_mass * jac_lin, skew_times(skew_vector(jac_ang), inv_inertia_world)
    return inv_mass * jac_lin, jac_ang * inv_inertia_world


@wp.func
def row_block(mass_jac: mat33d, inertia_jac: mat33d, kind: int, side: int, jac_lin: mat33d, jac_ang: mat33d) -> mat33d:
    """J_ib M_b^-1 J_jb^T from row i's products (`row_products`) and row j's Jacobian (constraint j of `kind`, on
    its `side`). A point constraint's J_lin is I on side 0 and -I on side 1 and its J_ang a skew matrix
    (`constraints.constraint_frame`): there the linear part is +-m^-1 J_lin of row i, the same value without the
    product, and the angular part is `times_skew_transpose`."""
    if kind == POINT:
        angular = times_skew_transpose(inertia_jac, skew_vector(jac_ang))
        if side == 0:
            return mass_jac + angular
        return angular - mass_jac
    return mass_jac * wp.transpose(jac_lin) + inertia_jac * wp.transpose(jac_ang)


@wp.func
def row_products_of(
    r: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia_world_in: wp.array(dtype=mat33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    mass_jac_out: wp.array(dtype=mat33d),
    inertia_jac_out: wp.array(dtype=mat33d),
):
    """`row_products` of Jacobian row r (constraint r // 2, side r % 2); none for the world's side."""
    i = r // 2
    b = side_body(i, r - 2 * i, constraint_body0, constraint_body1)
    if b >= 0:
        kind = constraint_kind[i]
        m, w = row_products(kind, body_inv_mass[b], inv_inertia_world_in[b], jac_lin_in[r], jac_ang_in[r])
        mass_jac_out[r] = m
        inertia_jac_out[r] = w


@wp.kernel
def assemble_rows(
    # Model:
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    # Data in:
    inv_inertia_world_in: wp.array(dtype=mat33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    # Data out:
    mass_jac_out: wp.array(dtype=mat33d),
    inertia_jac_out: wp.array(dtype=mat33d),
):
    """Every Jacobian row's products (`row_products_of`), before `assemble`."""
    row_products_of(
        wp.tid(), constraint_kind, constraint_body0, constraint_body1, body_inv_mass, inv_inertia_world_in, jac_lin_in,
        jac_ang_in, mass_jac_out, inertia_jac_out,
    )  # fmt: skip


@wp.func
def shared_body_block(
    i: int,
    si: int,
    j: int,
    sj: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia_world: wp.array(dtype=mat33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
) -> mat33d:
    """J_ib M_b^-1 J_jb^T for the body b that side si of constraint i and side sj of j share, without stored
    row products (the iterative sweeps' blocks)."""
    b = side_body(i, si, constraint_body0, constraint_body1)
    ri = 2 * i + si
    rj = 2 * j + sj
    m, w = row_products(constraint_kind[i], body_inv_mass[b], inv_inertia_world[b], jac_lin[ri], jac_ang[ri])
    return row_block(m, w, constraint_kind[j], sj, jac_lin[rj], jac_ang[rj])


@wp.func
def pad_unused_rows(k: mat33d, kind: int) -> mat33d:
    """Rows a constraint of dimension < 3 does not use get a unit pivot, so K stays SPD."""
    for r in range(constraint_dim(kind), 3):
        k[r, r] = f64(1.0)
    return k


@wp.func
def diagonal_block(
    i: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia_world: wp.array(dtype=mat33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
) -> mat33d:
    """K_ii: the matrix of one constraint alone (equations 8 and 12)."""
    k = mat33d()
    for side in range(2):
        if side_body(i, side, constraint_body0, constraint_body1) >= 0:
            k += shared_body_block(
                i, side, i, side, constraint_kind, constraint_body0, constraint_body1,
                body_inv_mass, inv_inertia_world, jac_lin, jac_ang,
            )  # fmt: skip
    return pad_unused_rows(k, constraint_kind[i])


@wp.func
def assemble_slot(
    s: int,
    constraint_kind: wp.array(dtype=int),
    slot_row: wp.array(dtype=int),
    slot_col: wp.array(dtype=int),
    slot_sides: wp.array(dtype=wp.vec4i),
    mass_jac_in: wp.array(dtype=mat33d),
    inertia_jac_in: wp.array(dtype=mat33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    values_out: wp.array(dtype=mat33d),
):
    """Slot s of K: the sum over the (at most two) bodies its row and column constraints share, from the rows'
    products (`row_products_of`)."""
    i = slot_row[s]
    j = slot_col[s]
    sides = slot_sides[s]
    kind = constraint_kind[j]
    k = mat33d()
    if sides[0] >= 0:
        ri = 2 * i + sides[0]
        rj = 2 * j + sides[1]
        k += row_block(mass_jac_in[ri], inertia_jac_in[ri], kind, sides[1], jac_lin_in[rj], jac_ang_in[rj])
    if sides[2] >= 0:
        ri = 2 * i + sides[2]
        rj = 2 * j + sides[3]
        k += row_block(mass_jac_in[ri], inertia_jac_in[ri], kind, sides[3], jac_lin_in[rj], jac_ang_in[rj])
    if i == j:
        k = pad_unused_rows(k, constraint_kind[i])
    values_out[s] = k


@wp.kernel
def assemble(
    # Model:
    constraint_kind: wp.array(dtype=int),
    # Pattern: the slots to fill
    slot_row: wp.array(dtype=int),
    slot_col: wp.array(dtype=int),
    slot_sides: wp.array(dtype=wp.vec4i),
    # Data in:
    mass_jac_in: wp.array(dtype=mat33d),
    inertia_jac_in: wp.array(dtype=mat33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    # Data out:
    values_out: wp.array(dtype=mat33d),
):
    """Every slot of K (`assemble_slot`), after `assemble_rows`."""
    assemble_slot(
        wp.tid(), constraint_kind, slot_row, slot_col, slot_sides, mass_jac_in, inertia_jac_in, jac_lin_in,
        jac_ang_in, values_out,
    )  # fmt: skip


# What a slot of the augmented matrix holds (`types.Slot`).
SLOT_MASS = wp.constant(int(Slot.MASS))
SLOT_INERTIA = wp.constant(int(Slot.INERTIA))
SLOT_JLIN = wp.constant(int(Slot.JLIN))
SLOT_JANG = wp.constant(int(Slot.JANG))
SLOT_JLIN_T = wp.constant(int(Slot.JLIN_T))
SLOT_JANG_T = wp.constant(int(Slot.JANG_T))
SLOT_PAD = wp.constant(int(Slot.PAD))


@wp.func
def augmented_slot(
    s: int,
    constraint_kind: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    slot_code: wp.array(dtype=int),
    slot_ref: wp.array(dtype=int),
    inv_inertia_world_in: wp.array(dtype=mat33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    values_out: wp.array(dtype=mat33d),
):
    """Slot s of [[M, J^T], [J, 0]] (Baraff 1996): a body's mass and world inertia, a constraint's Jacobian on
    a body, zero elsewhere; the unused rows of a constraint of dimension < 3 get a -1 pivot."""
    code = slot_code[s]
    r = slot_ref[s]
    k = mat33d()
    if code == SLOT_MASS:
        k = wp.identity(3, dtype=f64) / body_inv_mass[r]
    elif code == SLOT_INERTIA:
        k = wp.inverse(inv_inertia_world_in[r])
    elif code == SLOT_JLIN:
        k = jac_lin_in[r]
    elif code == SLOT_JANG:
        k = jac_ang_in[r]
    elif code == SLOT_JLIN_T:
        k = wp.transpose(jac_lin_in[r])
    elif code == SLOT_JANG_T:
        k = wp.transpose(jac_ang_in[r])
    elif code == SLOT_PAD:
        for row in range(constraint_dim(constraint_kind[r]), 3):
            k[row, row] = f64(-1.0)
    values_out[s] = k


@wp.kernel
def assemble_augmented(
    # Model:
    constraint_kind: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    # Pattern:
    slot_code: wp.array(dtype=int),
    slot_ref: wp.array(dtype=int),
    # Data in:
    inv_inertia_world_in: wp.array(dtype=mat33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    # Data out:
    values_out: wp.array(dtype=mat33d),
):
    """Every slot of the augmented matrix (`augmented_slot`)."""
    augmented_slot(
        wp.tid(), constraint_kind, body_inv_mass, slot_code, slot_ref, inv_inertia_world_in, jac_lin_in,
        jac_ang_in, values_out,
    )  # fmt: skip
