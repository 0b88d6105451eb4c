"""Block assembly of the system matrix K = J M^-1 J^T (method paper, section 4.5; docs/architecture.md).

K is stored as 3x3 blocks in "slots". Each slot is one block (row constraint i, column constraint j)
and lists the bodies the two constraints share (at most two) by the side each has on them. The host
builds the slot lists once per topology (`warpimpulse/topology.py`): the lower factor pattern for
Cholesky (fill slots share no body and assemble to zero), assembled a block column at a time
(`assemble_column`), and the full pattern for CG, a slot at a time (`assemble_slot`).
"""

import warp as wp

from ..types import Slot
from .constraints import POINT, constraint_dim, is_translational, side_body, skew_times, times_skew_transpose
from .inertia import sym33d, symmetric_matrix

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
mat33d = wp.mat33d
f64 = wp.float64
# The two leading rows of a Jacobian block of a constraint of dimension < 3, and their transpose.
mat23d = wp.types.matrix(shape=(2, 3), dtype=f64)
mat32d = wp.types.matrix(shape=(3, 2), dtype=f64)


@wp.func
def leading_rows_times(j: mat33d, a: mat33d, dim: int) -> mat33d:
    """j a for a Jacobian block j of a constraint of dimension `dim`, whose rows dim..2 are 0: a constraint of
    dimension < 3 multiplies its two leading rows alone (2 x 3 by 3 x 3, 18 products, not 27; Warp fuses them as it
    does j a's, so the same bits) and leaves row 2 zero."""
    if dim == 3:
        return j * a
    t = mat23d(j[0, 0], j[0, 1], j[0, 2], j[1, 0], j[1, 1], j[1, 2]) * a
    z = f64(0.0)
    return mat33d(t[0, 0], t[0, 1], t[0, 2], t[1, 0], t[1, 1], t[1, 2], z, z, z)


@wp.func
def times_leading_transpose(a: mat33d, j: mat33d, dim: int) -> mat33d:
    """a j^T for a Jacobian block j of a constraint of dimension `dim` (`leading_rows_times`): column 2 stays
    zero below dimension 3."""
    if dim == 3:
        return a * wp.transpose(j)
    t = a * mat32d(j[0, 0], j[1, 0], j[0, 1], j[1, 1], j[0, 2], j[1, 2])
    z = f64(0.0)
    return mat33d(t[0, 0], t[0, 1], z, t[1, 0], t[1, 1], z, t[2, 0], t[2, 1], z)


@wp.func
def row_products(
    kind: int,
    side: int,
    r: int,
    inv_mass: f64,
    inv_inertia_world: sym33d,
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
):
    """(m^-1 J_lin, J_ang J~^-1) of Jacobian row r, side `side` of a constraint of `kind`: that side's factor of
    every block of K its body is in. A point constraint's J_lin is I on side 0 and -I on side 1 and its J_ang a
    skew matrix [s]x, s kept alone (`constraints.constraint_frame`): its products are +-m^-1 I, J_lin unread, and
    `skew_times` of s (24 bytes read where the block takes 72). A rotational constraint's J_lin is 0: its linear
    product is 0, J_lin unread. A constraint of dimension < 3 multiplies only its Jacobian's leading rows
    (`leading_rows_times`)."""
    if kind == POINT:
        m = inv_mass
        if side != 0:
            m = -inv_mass
        z = f64(0.0)
        return mat33d(m, z, z, z, m, z, z, z, m), skew_times(jac_skew[r], symmetric_matrix(inv_inertia_world))
    inertia = leading_rows_times(jac_ang[r], symmetric_matrix(inv_inertia_world), constraint_dim(kind))
    if is_translational(kind):
        return inv_mass * jac_lin[r], inertia
    return mat33d(), inertia


@wp.func
def row_block(
    mass_jac: mat33d,
    inertia_jac: mat33d,
    kind: int,
    side: int,
    r: int,
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
) -> mat33d:
    """J_ib M_b^-1 J_jb^T from row i's products (`row_products`) and Jacobian row r of constraint j (of `kind`, on
    its `side`). A point constraint's J_lin is I on side 0 and -I on side 1 and its J_ang a skew matrix [s]x, s
    kept alone (`constraints.constraint_frame`): there the linear part is +-m^-1 J_lin of row i, the same value
    without the product, and the angular part is `times_skew_transpose` of s. A rotational constraint's J_lin is
    0: no linear part (adding its zeros changed no bit). Row j's constraint of dimension < 3 leaves the block's
    columns from its dimension on zero, unformed (`times_leading_transpose`)."""
    if kind == POINT:
        angular = times_skew_transpose(inertia_jac, jac_skew[r])
        if side == 0:
            return mass_jac + angular
        return angular - mass_jac
    dim = constraint_dim(kind)
    angular = times_leading_transpose(inertia_jac, jac_ang[r], dim)
    if is_translational(kind):
        return times_leading_transpose(mass_jac, jac_lin[r], dim) + angular
    return angular


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
    inv_inertia_world: wp.array(dtype=sym33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
) -> mat33d:
    """J_ib M_b^-1 J_jb^T for the body b that side si of constraint i and side sj of j share, from row i's
    products formed for this block alone (CG's slots, the iterative sweeps' blocks)."""
    b = side_body(i, si, constraint_body0, constraint_body1)
    m, w = row_products(
        constraint_kind[i], si, 2 * i + si, body_inv_mass[b], inv_inertia_world[b], jac_lin, jac_ang, jac_skew
    )
    return row_block(m, w, constraint_kind[j], sj, 2 * j + sj, jac_lin, jac_ang, jac_skew)


@wp.func
def pad_unused_rows(k: mat33d, kind: int) -> mat33d:
    """Rows a constraint of dimension < 3 does not use get a unit pivot, so K stays SPD."""
    r = constraint_dim(kind)
    while r < 3:
        k[r, r] = f64(1.0)
        r += 1
    return k


@wp.func
def diagonal_block(
    i: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia_world: wp.array(dtype=sym33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
) -> mat33d:
    """K_ii: the matrix of one constraint alone (equations 8 and 12)."""
    k = mat33d()
    for side in range(2):
        if side_body(i, side, constraint_body0, constraint_body1) >= 0:
            k += shared_body_block(
                i, side, i, side, constraint_kind, constraint_body0, constraint_body1,
                body_inv_mass, inv_inertia_world, jac_lin, jac_ang, jac_skew,
            )  # fmt: skip
    return pad_unused_rows(k, constraint_kind[i])


@wp.func
def assemble_slot(
    s: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    slot_row: wp.array(dtype=int),
    slot_col: wp.array(dtype=int),
    slot_sides: wp.array(dtype=wp.vec4i),
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    values_out: wp.array(dtype=mat33d),
):
    """Slot s of K: the sum over the (at most two) bodies its row and column constraints share
    (`shared_body_block`)."""
    i = slot_row[s]
    j = slot_col[s]
    sides = slot_sides[s]
    k = mat33d()
    if sides[0] >= 0:
        k += shared_body_block(
            i, sides[0], j, sides[1], constraint_kind, constraint_body0, constraint_body1,
            body_inv_mass, inv_inertia_world_in, jac_lin_in, jac_ang_in, jac_skew_in,
        )  # fmt: skip
    if sides[2] >= 0:
        k += shared_body_block(
            i, sides[2], j, sides[3], constraint_kind, constraint_body0, constraint_body1,
            body_inv_mass, inv_inertia_world_in, jac_lin_in, jac_ang_in, jac_skew_in,
        )  # fmt: skip
    if i == j:
        k = pad_unused_rows(k, constraint_kind[i])
    values_out[s] = k


@wp.kernel
def assemble(
    # Model:
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    # Pattern: the slots to fill
    slot_row: wp.array(dtype=int),
    slot_col: wp.array(dtype=int),
    slot_sides: wp.array(dtype=wp.vec4i),
    # Data in:
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    # Data out:
    values_out: wp.array(dtype=mat33d),
):
    """Every slot of K (`assemble_slot`)."""
    assemble_slot(
        wp.tid(), constraint_kind, constraint_body0, constraint_body1, body_inv_mass, slot_row, slot_col, slot_sides,
        inv_inertia_world_in, jac_lin_in, jac_ang_in, jac_skew_in, values_out,
    )  # fmt: skip


@wp.func
def side_products(
    c: int,
    side: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia_world: wp.array(dtype=sym33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
):
    """`row_products` of side `side` of constraint c; zeros for the world's side (never read: no slot lists it)."""
    b = side_body(c, side, constraint_body0, constraint_body1)
    if b < 0:
        return mat33d(), mat33d()
    return row_products(
        constraint_kind[c], side, 2 * c + side, body_inv_mass[b], inv_inertia_world[b], jac_lin, jac_ang, jac_skew
    )


@wp.func
def assemble_column(
    j: int,
    perm: wp.array(dtype=int),
    col_start: wp.array(dtype=int),
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    slot_row: wp.array(dtype=int),
    slot_sides: wp.array(dtype=wp.vec4i),
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    values_out: wp.array(dtype=mat33d),
):
    """Block column j (in elimination order) of K's factor pattern: its column constraint c's two `row_products`,
    formed once, then every slot (i, c) of the column as K_ic = (J_cb M_b^-1 J_ib^T)^T over the bodies b that i
    and c share (`row_block`).

    A column at a time, so that c's products stay in registers for its slots (on a tree, the side on the parent
    serves three): stored per Jacobian row, they were 144 bytes a row written and read back ~2.5 times, which
    made the assembly of a 65,535-body tree memory bound: 117 ns a body-step, 77 a column at a time
    (docs/architecture.md, "Cheaper stages"). The diagonal slot (the column's first) is formed apart: its pairs
    are c's own sides, so it needs neither its row nor a choice of products (chain10 1,230 -> 1,094 ns, a
    65,535-body tree 3.47 -> 3.17 ms)."""
    c = perm[j]
    m0, w0 = side_products(
        c, 0, constraint_kind, constraint_body0, constraint_body1, body_inv_mass, inv_inertia_world_in, jac_lin_in,
        jac_ang_in, jac_skew_in,
    )  # fmt: skip
    m1, w1 = side_products(
        c, 1, constraint_kind, constraint_body0, constraint_body1, body_inv_mass, inv_inertia_world_in, jac_lin_in,
        jac_ang_in, jac_skew_in,
    )  # fmt: skip
    d = col_start[j]
    kind_c = constraint_kind[c]
    own = slot_sides[d]  # (0, 0) then (1, 1), for the sides whose body is dynamic
    diagonal = mat33d()
    if own[0] == 0:
        diagonal += wp.transpose(row_block(m0, w0, kind_c, 0, 2 * c, jac_lin_in, jac_ang_in, jac_skew_in))
    if own[0] == 1 or own[2] == 1:
        diagonal += wp.transpose(row_block(m1, w1, kind_c, 1, 2 * c + 1, jac_lin_in, jac_ang_in, jac_skew_in))
    values_out[d] = pad_unused_rows(diagonal, kind_c)
    s = d + 1
    stop = col_start[j + 1]
    while s < stop:
        i = slot_row[s]
        kind = constraint_kind[i]
        sides = slot_sides[s]
        k = mat33d()
        for pair in range(2):
            si = sides[2 * pair]
            if si >= 0:
                m = m0  # c's products on the side it shares the body by
                w = w0
                if sides[2 * pair + 1] != 0:
                    m = m1
                    w = w1
                k += wp.transpose(row_block(m, w, kind, si, 2 * i + si, jac_lin_in, jac_ang_in, jac_skew_in))
        values_out[s] = k
        s += 1


@wp.kernel
def assemble_columns(
    # Model:
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    # Pattern: the factor's
    perm: wp.array(dtype=int),
    col_start: wp.array(dtype=int),
    slot_row: wp.array(dtype=int),
    slot_sides: wp.array(dtype=wp.vec4i),
    # Data in:
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    # Data out:
    values_out: wp.array(dtype=mat33d),
):
    """Every block column of K's factor pattern (`assemble_column`), a column a thread."""
    assemble_column(
        wp.tid(), perm, col_start, constraint_kind, constraint_body0, constraint_body1, body_inv_mass, slot_row,
        slot_sides, inv_inertia_world_in, jac_lin_in, jac_ang_in, jac_skew_in, values_out,
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
def angular_block(kind: int, r: int, jac_ang: wp.array(dtype=mat33d), jac_skew: wp.array(dtype=vec3d)) -> mat33d:
    """J_ang of Jacobian row r (2 i + side) of a constraint of `kind` as a block: a point constraint's is [s]x of
    its s alone (`constraints.constraint_frame`)."""
    if kind == POINT:
        return wp.skew(jac_skew[r])
    return jac_ang[r]


@wp.func
def augmented_slot(
    s: int,
    constraint_kind: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    slot_code: wp.array(dtype=int),
    slot_ref: wp.array(dtype=int),
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
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
        k = wp.inverse(symmetric_matrix(inv_inertia_world_in[r]))
    elif code == SLOT_JLIN:
        k = jac_lin_in[r]
    elif code == SLOT_JANG:
        k = angular_block(constraint_kind[r // 2], r, jac_ang_in, jac_skew_in)
    elif code == SLOT_JLIN_T:
        k = wp.transpose(jac_lin_in[r])
    elif code == SLOT_JANG_T:
        k = wp.transpose(angular_block(constraint_kind[r // 2], r, jac_ang_in, jac_skew_in))
    elif code == SLOT_PAD:
        row = constraint_dim(constraint_kind[r])
        while row < 3:
            k[row, row] = f64(-1.0)
            row += 1
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
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    # Data out:
    values_out: wp.array(dtype=mat33d),
):
    """Every slot of the augmented matrix (`augmented_slot`)."""
    augmented_slot(
        wp.tid(), constraint_kind, body_inv_mass, slot_code, slot_ref, inv_inertia_world_in, jac_lin_in,
        jac_ang_in, jac_skew_in, values_out,
    )  # fmt: skip
