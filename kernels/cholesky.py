"""Numeric block Cholesky A = L S L^T on a pattern precomputed by the host, and the triangular solves.

S is a fixed diagonal of signs, one per block column: all +1 for K (an SPD L L^T), and -1 for the
constraint pivots of the augmented body-joint matrix, whose Schur complements are negative definite in the
host's elimination order (Baraff 1996). Each pivot block is then s_j A_jj = L_jj L_jj^T. `signs` (0 for K)
says whether S has any -1: K's factor and solves skip the signs (multiplying by +1 is exact, so this changes no
bit).

Columns are in elimination order. The host groups columns so that a group runs in order on one thread
and the groups of one launch are independent (levels of the elimination tree): on a CPU one group holds
every column; on a GPU each level is one launch with a column a thread.
Storage: block column j owns slots col_start[j]..col_start[j+1]-1, the diagonal first. The factor overwrites
the off-diagonal slots with L_ij and the diagonal slot with L_jj^-1 (all the solves read of the diagonal; the
assembled block is read before, and nothing reads it after: every factor follows a fresh assembly). So a
backward column streams its slots as one run of one array: a solve of the 65,535-body tree took 2.10 ms, not
2.28 with L_jj^-1 in an array of its own (-8 %), the factor 3.21 ms, not 3.36, and its step 0.551 us a body-step,
not 0.586; tree127 and chain10, cache resident, unchanged (docs/architecture.md, "Cheaper stages").
L_jj^-1 is lower triangular (its upper three entries 0, never read); the solves apply it with `lower_times` and
`lower_transpose_times`.

A constraint of fewer than 3 rows is padded to 3 with a unit pivot, so its blocks' padded rows and columns stay
zero in L. The factor skips them by each slot's shape (`slot_shape`: its row unknown's rows by its column
unknown's): an update L_ik L_jk^T multiplies the column's rows only (`times_transpose`), a pivot of 2 or 1 rows is
a 2x2 or 1x1 (`cholesky_inverse`), the same bits (chain10's factor ~970 -> ~860 ns). The solves keep full 3x3
products: a branch there, per block or per row, cost more than the products it saved (docs/architecture.md,
"Cheaper stages").

The factor of a chain waits on each column's pivot block before the next column can start, so
`cholesky3_inverse` forms its three pivots from the leading minors, their divisions and square roots independent
(chain10's factor ~1.3 -> ~1.05 us). A block L D L^T (unit L, so one product a column on a solve's dependent
chain instead of two, and no square root) was measured and not kept: chain10's solve went from ~617 to ~602 ns
(a solve is bound by its arithmetic, not by that chain) while its factor, whose updates L_ik D_k L_jk^T need
D_k as well as D_k^-1, went from ~1.3 to ~1.9 us (docs/architecture.md, "Cheaper stages").
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
mat33d = wp.mat33d
f64 = wp.float64
# The leading two columns of a block whose column unknown has 2 rows, and their transpose (`times_transpose`).
mat32d = wp.types.matrix(shape=(3, 2), dtype=f64)
mat23d = wp.types.matrix(shape=(2, 3), dtype=f64)


@wp.func
def cholesky3_inverse_in_turn(a: mat33d, tiny: f64, fallback: f64):
    """`cholesky3_inverse` eliminating in turn, each pivot not above `tiny` replaced by `fallback` before the next
    is formed (the bad blocks' path). Each pivot's reciprocal is taken once and serves both L's column and its
    inverse: three divisions where dividing by the pivots would take six. L itself is not returned: nothing reads
    it (storing it cost ~8 ns a column, chain10 and a 65,535-body tree)."""
    z = f64(0.0)
    d0 = a[0, 0]
    bad = int(0)  # noqa: UP018 (a Warp variable the branches change must not start as a constant)
    if d0 <= tiny:
        bad += 1
        d0 = fallback
    r0 = f64(1.0) / wp.sqrt(d0)
    l10 = a[1, 0] * r0
    l20 = a[2, 0] * r0
    d1 = a[1, 1] - l10 * l10
    if d1 <= tiny:
        bad += 1
        d1 = fallback
    r1 = f64(1.0) / wp.sqrt(d1)
    l21 = (a[2, 1] - l20 * l10) * r1
    d2 = a[2, 2] - l20 * l20 - l21 * l21
    if d2 <= tiny:
        bad += 1
        d2 = fallback
    r2 = f64(1.0) / wp.sqrt(d2)
    b = -l10 * r0 * r1
    e = -l21 * r1 * r2
    c = -(l20 * r0 + l21 * b) * r2
    return mat33d(r0, z, z, b, r1, z, c, e, r2), bad


@wp.func
def cholesky3_inverse(a: mat33d, tiny: f64, fallback: f64):
    """The inverse of the lower Cholesky factor L of an SPD 3x3 block (its lower triangle read), and how many of
    its pivots were not above `tiny` (each replaced by `fallback`, `cholesky3_inverse_in_turn`).

    The squared pivots are ratios of the leading minors, d_i = M_i / M_(i-1), so their three divisions and three
    square roots wait on none of each other: a column of a chain's factor waits on one division and one square
    root where eliminating in turn waits on three of each."""
    m1 = a[0, 0]
    m2 = a[0, 0] * a[1, 1] - a[1, 0] * a[1, 0]
    c = a[0, 0] * a[2, 1] - a[1, 0] * a[2, 0]  # M1 times L's (2, 1) entry times its pivot
    m3 = (
        a[0, 0] * (a[1, 1] * a[2, 2] - a[2, 1] * a[2, 1])
        - a[1, 0] * (a[1, 0] * a[2, 2] - a[2, 1] * a[2, 0])
        + a[2, 0] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0])
    )
    q1 = f64(1.0) / m1
    q2 = f64(1.0) / m2
    q3 = f64(1.0) / m3
    if m1 > tiny and m2 * q1 > tiny and m3 * q2 > tiny:
        z = f64(0.0)
        r0 = wp.sqrt(q1)
        r1 = wp.sqrt(m1 * q2)
        r2 = wp.sqrt(m2 * q3)
        l10 = a[1, 0] * r0
        l20 = a[2, 0] * r0
        l21 = c * q1 * r1
        b = -l10 * r0 * r1
        e = -l21 * r1 * r2
        return mat33d(r0, z, z, b, r1, z, -(l20 * r0 + l21 * b) * r2, e, r2), int(0)
    return cholesky3_inverse_in_turn(a, tiny, fallback)


@wp.func
def cholesky_inverse(a: mat33d, rows: int, tiny: f64, fallback: f64):
    """`cholesky3_inverse` of a pivot block whose unknown has `rows` rows (`CholeskySolver._slot_shape`). Below 3
    its padded rows and columns are 0 but for a unit diagonal (`assemble.pad_unused_rows`), so only the leading
    minors are formed and the padded pivots are 1: the same operations as `cholesky3_inverse` for the leading
    part, so the same bits (its padded pivot there is M_3 / M_2 = 1 to round-off, read only against zeros).
    Only the leading pivots are held to `tiny`: a padded pivot is 1 by construction, not the scene's, and a block
    of a body of 4e-16 kg (gymnasium's pusher: a light body on its goal of 4e-10 kg) is ~1e15 across, where
    1 fell below the tolerance relative to it and the system was called singular."""
    if rows == 3:
        return cholesky3_inverse(a, tiny, fallback)
    z = f64(0.0)
    one = f64(1.0)
    m1 = a[0, 0]
    q1 = one / m1
    if rows == 2:
        m2 = a[0, 0] * a[1, 1] - a[1, 0] * a[1, 0]
        q2 = one / m2
        if m1 > tiny and m2 * q1 > tiny:
            r0 = wp.sqrt(q1)
            r1 = wp.sqrt(m1 * q2)
            l10 = a[1, 0] * r0
            b = -l10 * r0 * r1
            return mat33d(r0, z, z, b, r1, z, z, z, one), int(0)
    elif m1 > tiny:
        return mat33d(wp.sqrt(q1), z, z, z, one, z, z, z, one), int(0)
    return cholesky3_inverse_in_turn(a, tiny, fallback)


@wp.func
def times_transpose(a: mat33d, b: mat33d, inner: int) -> mat33d:
    """a b^T for blocks whose columns >= `inner` are structurally zero: the product of their leading columns
    (3 x inner times inner x 3), which Warp fuses as it does a b^T's (one column: their outer product, each
    entry one product as the fused one rounds it), so a b^T's bits but for the sign of a zero."""
    if inner == 3:
        return a * wp.transpose(b)
    if inner == 2:
        return mat32d(a[0, 0], a[0, 1], a[1, 0], a[1, 1], a[2, 0], a[2, 1]) * mat23d(
            b[0, 0], b[1, 0], b[2, 0], b[0, 1], b[1, 1], b[2, 1]
        )
    return wp.outer(vec3d(a[0, 0], a[1, 0], a[2, 0]), vec3d(b[0, 0], b[1, 0], b[2, 0]))


@wp.func
def lower_times(l: mat33d, v: vec3d) -> vec3d:
    """l v for a lower triangular l, its zeros skipped."""
    return vec3d(l[0, 0] * v[0], l[1, 0] * v[0] + l[1, 1] * v[1], l[2, 0] * v[0] + l[2, 1] * v[1] + l[2, 2] * v[2])


@wp.func
def lower_transpose_times(l: mat33d, v: vec3d) -> vec3d:
    """l^T v for a lower triangular l, its zeros skipped."""
    return vec3d(l[0, 0] * v[0] + l[1, 0] * v[1] + l[2, 0] * v[2], l[1, 1] * v[1] + l[2, 1] * v[2], l[2, 2] * v[2])


@wp.func
def times_lower_transpose(a: mat33d, l: mat33d) -> mat33d:
    """a l^T for a lower triangular l, its zeros skipped."""
    out = mat33d()
    for r in range(3):
        out[r, 0] = a[r, 0] * l[0, 0]
        out[r, 1] = a[r, 0] * l[1, 0] + a[r, 1] * l[1, 1]
        out[r, 2] = a[r, 0] * l[2, 0] + a[r, 1] * l[2, 1] + a[r, 2] * l[2, 2]
    return out


@wp.func
def negative_update(signs: int, u: int, update_sign: wp.array(dtype=f64)) -> bool:
    """Whether update u adds its product (its column's sign is -1); K's (`signs` 0) never do, unread."""
    if signs != 0:
        return update_sign[u] < f64(0.0)
    return False


@wp.func
def factor_column(
    j: int,
    signs: int,
    col_start: wp.array(dtype=int),
    update_start: wp.array(dtype=int),
    update_target: wp.array(dtype=int),
    update_a: wp.array(dtype=int),
    update_b: wp.array(dtype=int),
    update_sign: wp.array(dtype=f64),
    col_sign: wp.array(dtype=f64),
    col_loop: wp.array(dtype=int),
    slot_shape: wp.array(dtype=wp.vec2i),
    pivot_tolerance: f64,
    loop_tolerance: f64,
    values: wp.array(dtype=mat33d),
    singular: wp.array(dtype=int),
):
    """Column j, left-looking, a slot at a time: the slot's block less its updates L_ak s_k L_bk^T (the host
    sorts a column's updates by target slot, the diagonal's first; each on column k's rows, `slot_shape`), held in
    registers; then
    L_jj^-1 = chol(s_j .)^-1, written over the assembled diagonal block (read first: the loop scale below needs
    it), and each L_ij = (.) L_jj^-T s_j written once.

    `singular[0]` gets 1 + the first column whose pivot fell below pivot_tolerance times its diagonal
    (a degenerate constraint); that pivot is replaced by 1 so the solve stays finite.

    Columns of loop-closing joints (`col_loop`, eliminated last) may be redundant with the tree's: a pivot of
    theirs below loop_tolerance times its assembled diagonal (before elimination) is a direction the tree already
    constrains (the positive semidefinite Schur complement has a zero pivot there, and zeros below it). It is
    regularised: replaced by that diagonal scale, so its impulse is the residual over that scale, round-off
    against consistent errors, instead of round-off over round-off. `singular[1]` counts those rows:
    information, not an error.
    """
    d = col_start[j]
    u = update_start[j]
    end = update_start[j + 1]
    assembled = values[d]  # the diagonal block before elimination
    a = assembled
    while u < end:
        if update_target[u] != d:
            break
        l = values[update_a[u]]  # its update_b: a diagonal block's update is L_jk s_k L_jk^T
        update = times_transpose(l, l, slot_shape[update_a[u]][1])
        if negative_update(signs, u, update_sign):
            a = a + update
        else:
            a = a - update
        u += 1
    negative = False
    if signs != 0:
        negative = col_sign[j] < f64(0.0)
    if negative:
        a = -a
        assembled = -assembled
    scale = wp.max(wp.max(a[0, 0], a[1, 1]), a[2, 2])
    li = mat33d()
    if col_loop[j] != 0:  # relative to the assembled diagonal: the reduced one may be all round-off
        full = wp.max(wp.max(assembled[0, 0], assembled[1, 1]), assembled[2, 2])
        li, redundant = cholesky_inverse(a, slot_shape[d][0], loop_tolerance * full, full)
        singular[1] = singular[1] + redundant
    else:
        li, bad = cholesky_inverse(a, slot_shape[d][0], pivot_tolerance * scale, f64(1.0))
        if bad != 0 and singular[0] == 0:
            singular[0] = j + 1
    values[d] = li  # the assembled block is read above: the solves need only the inverse
    s = d + 1
    stop = col_start[j + 1]
    while s < stop:
        block = values[s]
        while u < end:
            if update_target[u] != s:
                break
            update = times_transpose(values[update_a[u]], values[update_b[u]], slot_shape[update_a[u]][1])
            if negative_update(signs, u, update_sign):
                block = block + update
            else:
                block = block - update
            u += 1
        block = times_lower_transpose(block, li)
        if negative:
            block = -block
        values[s] = block
        s += 1


@wp.kernel
def factor(
    first_group: int,
    signs: int,
    group_start: wp.array(dtype=int),
    col_start: wp.array(dtype=int),
    update_start: wp.array(dtype=int),
    update_target: wp.array(dtype=int),
    update_a: wp.array(dtype=int),
    update_b: wp.array(dtype=int),
    update_sign: wp.array(dtype=f64),
    col_sign: wp.array(dtype=f64),
    col_loop: wp.array(dtype=int),
    slot_shape: wp.array(dtype=wp.vec2i),
    pivot_tolerance: f64,
    loop_tolerance: f64,
    # data in/out
    values: wp.array(dtype=mat33d),
    singular: wp.array(dtype=int),
):
    """The columns of one group in order (`factor_column`)."""
    g = first_group + wp.tid()
    j = group_start[g]
    stop = group_start[g + 1]
    while j < stop:
        factor_column(
            j, signs, col_start, update_start, update_target, update_a, update_b, update_sign, col_sign, col_loop,
            slot_shape, pivot_tolerance, loop_tolerance, values, singular,
        )  # fmt: skip
        j += 1


@wp.func
def forward_row(
    j: int,
    perm: wp.array(dtype=int),
    col_start: wp.array(dtype=int),
    row_start: wp.array(dtype=int),
    row_slot: wp.array(dtype=int),
    row_col: wp.array(dtype=int),
    values: wp.array(dtype=mat33d),
    rhs: wp.array(dtype=vec3d),
    y: wp.array(dtype=vec3d),
):
    """Row j of L y = P b: y_j = L_jj^-1 (b_perm(j) - sum_k L_jk y_k), L_jj^-1 from column j's diagonal slot."""
    s = rhs[perm[j]]
    k = row_start[j]
    stop = row_start[j + 1]
    while k < stop:
        s -= values[row_slot[k]] * y[row_col[k]]
        k += 1
    y[j] = lower_times(values[col_start[j]], s)


@wp.kernel
def solve_forward(
    first_group: int,
    group_start: wp.array(dtype=int),
    perm: wp.array(dtype=int),
    col_start: wp.array(dtype=int),
    row_start: wp.array(dtype=int),
    row_slot: wp.array(dtype=int),
    row_col: wp.array(dtype=int),
    values: wp.array(dtype=mat33d),
    rhs: wp.array(dtype=vec3d),
    y: wp.array(dtype=vec3d),
):
    """L y = P b, the rows of one group in order (`forward_row`)."""
    g = first_group + wp.tid()
    j = group_start[g]
    stop = group_start[g + 1]
    while j < stop:
        forward_row(j, perm, col_start, row_start, row_slot, row_col, values, rhs, y)
        j += 1


@wp.func
def backward_column(
    j: int,
    perm: wp.array(dtype=int),
    col_start: wp.array(dtype=int),
    col_row: wp.array(dtype=int),
    col_sign: wp.array(dtype=f64),
    values: wp.array(dtype=mat33d),
    y: wp.array(dtype=vec3d),
    x: wp.array(dtype=vec3d),
):
    """Column j of L^T z = S y: z_j = L_jj^-T (s_j y_j - sum_i L_ij^T z_i); x_perm(j) = z_j.

    z overwrites y in place: every z_i it reads (i > j) is final, every y_j it has not yet overwritten.
    """
    d = col_start[j]
    s = col_sign[j] * y[j]
    k = d + 1
    stop = col_start[j + 1]
    while k < stop:
        s -= wp.transpose(values[k]) * y[col_row[k]]
        k += 1
    z = lower_transpose_times(values[d], s)
    y[j] = z
    x[perm[j]] = z


@wp.kernel
def solve_backward(
    first_group: int,
    group_start: wp.array(dtype=int),
    perm: wp.array(dtype=int),
    col_start: wp.array(dtype=int),
    col_row: wp.array(dtype=int),
    col_sign: wp.array(dtype=f64),
    values: wp.array(dtype=mat33d),
    y: wp.array(dtype=vec3d),
    x: wp.array(dtype=vec3d),
):
    """L^T z = S y, the columns of one group in reverse order (`backward_column`)."""
    g = first_group + wp.tid()
    begin = group_start[g]
    jj = wp.int32(0)
    while jj < group_start[g + 1] - begin:
        backward_column(group_start[g + 1] - 1 - jj, perm, col_start, col_row, col_sign, values, y, x)
        jj += 1


@wp.kernel
def copy_scaled(src: wp.array(dtype=vec3d), src_offset: int, scale: f64, dst: wp.array(dtype=vec3d), dst_offset: int):
    """dst[dst_offset + i] = scale src[src_offset + i]: moves the constraint part in and out of the augmented
    vectors [body linear; body angular; constraints]."""
    i = wp.tid()
    dst[dst_offset + i] = scale * src[src_offset + i]
