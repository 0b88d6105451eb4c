"""Joint limits: lower <= coordinate <= upper on revolute angles and prismatic offsets, as push-only impulses
in the joint-correction loop (method paper, section 4.5's iteration, with unilateral constraints).

Each iteration of the loop measures the prediction (`limit_errors`), solves the joints' system, then solves
the rows' own system (`correct_rows`): a row's predicted coordinate is updated to first order by the impulses
applied since the measurement, h (rate now - rate measured), and the rows' impulses move every active row to
its goal at once. The rows' system is S = G M^-1 G^T - C^T K^-1 C with C = J M^-1 G^T (`limit_coupling`, one
solve with K's factor per row and factor; `limit_matrix`; the fused step forms a row's part only once a pass makes
it active, kernels/step.py `correct_rows_all`): the rows' mobility with the joints holding, as the
loop joints' system of section 4.6 is to the tree's. Each row's impulse is applied with the joints' linear
reaction -K^-1 c (`compensate`), so the joints stay as they were to first order. A swing into a limit settles
in 2 iterations at h = 1/60 s, where the free body's mobility alone took 36 (a rod on a hinge), and a motor on
a four-bar's light crank, 47 times freer alone than in its loop, would not settle; rows coupled through the
joints (a limit or a motor on every hinge of a chain) are solved together, not one after another. With CG (no
factor) C is not formed: S is the free mobility.

The impulse accumulated over the step keeps its sign (push only) and may shrink back to 0, never past it: the
active set is the limits with a nonzero accumulated impulse, and for them the bound is an equality. The loop
ends when the joints and the limits hold, so a swing into a limit stops there, as a perfectly inelastic
impact: it cannot gain energy.

A stiff motor is a row of the same loop (`limit_drive` >= 0): its coordinate must advance by h target in
the step (velocity mode) or reach the target (position mode): an equality on the offset from that goal,
wrapped for angles, with an impulse of at most max_force h either way. A saturated motor counts as holding.
"""

import warp as wp

from .constraints import angular_times, pose_x, side_body
from .forces import VELOCITY_MODE, angle_near, coordinate_row, wrap_angle
from .impulses import apply_to_body
from .inertia import sym33d, symmetric_times

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
quatd = wp.quatd
mat33d = wp.mat33d
f64 = wp.float64

ANGLE_COORDINATE = wp.constant(0)


@wp.struct
class Rows:
    """A scene's rows of the correction loop for the fused step (`fused(kinds, rows=True)`): joint limits, stiff
    motors and distance constraints on the table of coordinates, the rows' system S with the joints holding and
    its scratch (`kernels/limits.py`; `Simulator._limit_system_launches`, `_correct_limits` and
    `_correct_limit_velocities` are its parallel schedule). `coupling_rows` and `response_rows` are
    `limit_coupling` and `limit_response` seen as one row of constraint_count entries a limit row."""

    coordinate_kind: wp.array(dtype=int)
    coordinate_body0: wp.array(dtype=int)
    coordinate_body1: wp.array(dtype=int)
    coordinate_anchor0: wp.array(dtype=vec3d)
    coordinate_anchor1: wp.array(dtype=vec3d)
    coordinate_axis0: wp.array(dtype=vec3d)
    coordinate_rest_rotation: wp.array(dtype=quatd)
    limit_coordinate: wp.array(dtype=int)
    limit_bounds: wp.array(dtype=wp.vec2d)
    limit_drive: wp.array(dtype=int)
    drive_mode: wp.array(dtype=int)
    drive_max_force: wp.array(dtype=f64)
    drive_target: wp.array(dtype=f64)
    limit_impulse: wp.array(dtype=f64)  # accumulated over the step (the position pass)
    limit_velocity_impulse: wp.array(dtype=f64)
    limit_value: wp.array(dtype=f64)
    limit_rate: wp.array(dtype=f64)
    limit_error: wp.array(dtype=f64)
    limit_mask: wp.array(dtype=int)
    limit_low: wp.array(dtype=f64)
    limit_high: wp.array(dtype=f64)
    limit_goal: wp.array(dtype=f64)
    limit_before: wp.array(dtype=f64)
    limit_rhs: wp.array(dtype=f64)
    limit_delta: wp.array(dtype=f64)
    limit_scratch: wp.array(dtype=f64)
    limit_work: wp.array(dtype=f64)
    limit_matrix: wp.array(dtype=f64)
    limit_side_body: wp.array(dtype=int)
    limit_side_lin: wp.array(dtype=vec3d)
    limit_side_ang: wp.array(dtype=vec3d)
    limit_coupling: wp.array(dtype=vec3d)
    limit_response: wp.array(dtype=vec3d)
    coupling_rows: wp.array2d(dtype=vec3d)
    response_rows: wp.array2d(dtype=vec3d)
    limit_formed: wp.array(dtype=int)  # the fused step's rows whose c, K^-1 c and entries of S are formed


@wp.func
def rows_coordinate(
    r: int,
    rows: Rows,
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """`coordinate_row` r of the rows' coordinates at the given state: (value, rate, axis, point)."""
    return coordinate_row(
        r, rows.coordinate_kind, rows.coordinate_body0, rows.coordinate_body1, rows.coordinate_anchor0,
        rows.coordinate_anchor1, rows.coordinate_axis0, rows.coordinate_rest_rotation, body_x, body_q, body_v,
        body_w,
    )  # fmt: skip


@wp.func
def limit_error(
    i: int,
    # Data in: the prediction (body_*_in), the state at t0 (start_*)
    h: f64,
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    start_x: wp.array(dtype=vec3d),
    start_q: wp.array(dtype=quatd),
    start_v: wp.array(dtype=vec3d),
    start_w: wp.array(dtype=vec3d),
    # Data in/out: the rows; out: the predicted coordinate, its rate at t0 now, the error (m or rad)
    rows: Rows,
):
    """The error of row i at the prediction: a limit's violation, or for an active limit the distance to its
    bound. A stiff motor's value is its offset from its goal, value(t0) + h target or target, its bounds (0, 0).
    Returns the error (m or rad)."""
    r = rows.limit_coordinate[i]
    value, rate, a, pb = rows_coordinate(r, rows, body_x_in, body_q_in, body_v_in, body_w_in)
    value0, rate0, a0, pb0 = rows_coordinate(r, rows, start_x, start_q, start_v, start_w)
    bounds = rows.limit_bounds[i]
    lam = rows.limit_impulse[i]
    motor = rows.limit_drive[i]
    if motor >= 0:
        goal = rows.drive_target[motor]
        if rows.drive_mode[motor] == VELOCITY_MODE:
            goal = value0 + h * rows.drive_target[motor]
        value = value - goal
        if rows.coordinate_kind[r] == ANGLE_COORDINATE:
            value = wrap_angle(value)
        cap = rows.drive_max_force[motor] * h
        err = wp.abs(value)
        if (lam >= cap and value < f64(0.0)) or (lam <= -cap and value > f64(0.0)):
            err = f64(0.0)  # saturated: the motor gives all it has
    else:
        if rows.coordinate_kind[r] == ANGLE_COORDINATE:
            # An angle is measured within one turn: take the turn about the range's middle, so that a range
            # past +-pi (Panda's joint 6: [-0.0175, 3.75]) is one interval, not a jump of 2 pi at pi.
            value = angle_near(value, f64(0.5) * (bounds[0] + bounds[1]))
        err = wp.max(wp.max(bounds[0] - value, value - bounds[1]), f64(0.0))
        if lam > f64(0.0):
            err = wp.abs(value - bounds[0])
        elif lam < f64(0.0):
            err = wp.abs(value - bounds[1])
    rows.limit_value[i] = value
    rows.limit_rate[i] = rate0
    rows.limit_error[i] = err
    return err


@wp.kernel
def limit_errors(
    # Data in: the prediction (body_*_in), the state at t0 (start_*)
    h: f64,
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    start_x: wp.array(dtype=vec3d),
    start_q: wp.array(dtype=quatd),
    start_v: wp.array(dtype=vec3d),
    start_w: wp.array(dtype=vec3d),
    # Data in/out:
    rows: Rows,
):
    """Every row's error at the prediction (`limit_error`), a thread a row."""
    limit_error(wp.tid(), h, body_x_in, body_q_in, body_v_in, body_w_in, start_x, start_q, start_v, start_w, rows)


@wp.func
def limit_side(
    r: int,
    side: int,
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    coordinate_rest_rotation: wp.array(dtype=quatd),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """(body, linear row, angular row) of a limit's Jacobian g on one side: d(rate) = g_lin . v + g_ang . w."""
    value, rate, a, pb = coordinate_row(
        r, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0, coordinate_anchor1,
        coordinate_axis0, coordinate_rest_rotation, body_x, body_q, body_v, body_w,
    )  # fmt: skip
    b = coordinate_body0[r]
    sign = f64(-1.0)
    if side == 1:
        b = coordinate_body1[r]
        sign = f64(1.0)
    if coordinate_kind[r] == ANGLE_COORDINATE:
        return b, vec3d(), a * sign
    return b, a * sign, wp.cross(pb - pose_x(b, body_x), a) * sign


@wp.func
def coupling_through(
    i: int,
    b: int,
    g_lin: vec3d,
    g_ang: vec3d,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia_world: wp.array(dtype=sym33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
) -> vec3d:
    """J_ib M_b^-1 g_b^T: what a row's Jacobian g = [g_lin | g_ang] on body b (>= 0) couples to constraint i
    through b, zero if i is not on b (a constraint's two bodies differ: one side at most)."""
    kind = constraint_kind[i]
    for side in range(2):
        r = 2 * i + side
        if side_body(i, side, constraint_body0, constraint_body1) == b:
            return jac_lin[r] * g_lin * body_inv_mass[b] + angular_times(
                kind, r, jac_ang, jac_skew, symmetric_times(inv_inertia_world[b], g_ang)
            )
    return vec3d()


@wp.func
def coupling_entry(
    l: int,
    i: int,
    # Model:
    body_inv_mass: wp.array(dtype=f64),
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    # Data in: the rows' Jacobians (`row_sides`), the frames
    limit_side_body_in: wp.array(dtype=int),
    limit_side_lin_in: wp.array(dtype=vec3d),
    limit_side_ang_in: wp.array(dtype=vec3d),
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    # Data out: c of limit l for constraint i at l * constraint_count + i
    limit_coupling_out: wp.array(dtype=vec3d),
):
    """c_i = sum over the bodies that limit l and constraint i share of J_ib M_b^-1 g_b^T (`coupling_through`)."""
    nc = constraint_body0.shape[0]
    c = vec3d()
    for side in range(2):
        b = limit_side_body_in[2 * l + side]
        if b >= 0:
            c += coupling_through(
                i, b, limit_side_lin_in[2 * l + side], limit_side_ang_in[2 * l + side], constraint_kind,
                constraint_body0, constraint_body1, body_inv_mass, inv_inertia_world_in, jac_lin_in, jac_ang_in,
                jac_skew_in,
            )  # fmt: skip
    limit_coupling_out[l * nc + i] = c


@wp.func
def row_sides(
    l: int,
    # Model:
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    coordinate_rest_rotation: wp.array(dtype=quatd),
    limit_coordinate: wp.array(dtype=int),
    # Data in:
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    # Data out: side s of row l at 2 l + s
    limit_side_body_out: wp.array(dtype=int),
    limit_side_lin_out: wp.array(dtype=vec3d),
    limit_side_ang_out: wp.array(dtype=vec3d),
):
    """Row l's Jacobian g on both sides at the state (`limit_side`), kept for S and C: every entry of both reads
    it, so each row's coordinate is evaluated once a state, not once an entry."""
    for side in range(2):
        b, g_lin, g_ang = limit_side(
            limit_coordinate[l], side, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0,
            coordinate_anchor1, coordinate_axis0, coordinate_rest_rotation, body_x_in, body_q_in, body_v_in,
            body_w_in,
        )  # fmt: skip
        limit_side_body_out[2 * l + side] = b
        limit_side_lin_out[2 * l + side] = g_lin
        limit_side_ang_out[2 * l + side] = g_ang


@wp.kernel
def limit_sides(
    # Model:
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    coordinate_rest_rotation: wp.array(dtype=quatd),
    limit_coordinate: wp.array(dtype=int),
    # Data in:
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    # Data out:
    limit_side_body_out: wp.array(dtype=int),
    limit_side_lin_out: wp.array(dtype=vec3d),
    limit_side_ang_out: wp.array(dtype=vec3d),
):
    """Every row's Jacobian on both sides (`row_sides`), a thread a row."""
    row_sides(
        wp.tid(), coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0, coordinate_anchor1,
        coordinate_axis0, coordinate_rest_rotation, limit_coordinate, body_x_in, body_q_in, body_v_in, body_w_in,
        limit_side_body_out, limit_side_lin_out, limit_side_ang_out,
    )  # fmt: skip


@wp.kernel
def limit_coupling(
    # Model:
    body_inv_mass: wp.array(dtype=f64),
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    # Data in:
    limit_side_body_in: wp.array(dtype=int),
    limit_side_lin_in: wp.array(dtype=vec3d),
    limit_side_ang_in: wp.array(dtype=vec3d),
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    # Data out: c of limit l for constraint i at l * constraint_count + i
    limit_coupling_out: wp.array(dtype=vec3d),
):
    """Every row's coupling to every constraint (`coupling_entry`), a thread an entry."""
    l, i = wp.tid()
    coupling_entry(
        l, i, body_inv_mass, constraint_kind, constraint_body0, constraint_body1, limit_side_body_in,
        limit_side_lin_in, limit_side_ang_in, inv_inertia_world_in, jac_lin_in, jac_ang_in, jac_skew_in,
        limit_coupling_out,
    )  # fmt: skip


@wp.func
def matrix_entry(
    k: int,
    l: int,
    # Model:
    coupled: int,
    body_inv_mass: wp.array(dtype=f64),
    # Data in: the rows' Jacobians (`row_sides`), c and K^-1 c of every row (when `coupled`)
    limit_side_body_in: wp.array(dtype=int),
    limit_side_lin_in: wp.array(dtype=vec3d),
    limit_side_ang_in: wp.array(dtype=vec3d),
    inv_inertia_world_in: wp.array(dtype=sym33d),
    limit_coupling_in: wp.array(dtype=vec3d),
    limit_response_in: wp.array(dtype=vec3d),
    # Data out: S, row-major (rows k, l)
    limit_matrix_out: wp.array(dtype=f64),
):
    """The rows' own system with the joints holding: S_kl = g_k M^-1 g_l^T - c_k . K^-1 c_l, the rate change of
    row k per unit impulse of row l. A diagonal is kept at least 1e-9 of its free value g M^-1 g^T (a row the
    joints lock gets no unbounded impulse)."""
    nl = limit_side_body_in.shape[0] // 2
    free = f64(0.0)
    for sk in range(2):
        bk = limit_side_body_in[2 * k + sk]
        glk = limit_side_lin_in[2 * k + sk]
        gak = limit_side_ang_in[2 * k + sk]
        if bk >= 0:
            for sl in range(2):
                bl = limit_side_body_in[2 * l + sl]
                gll = limit_side_lin_in[2 * l + sl]
                gal = limit_side_ang_in[2 * l + sl]
                if bl == bk:
                    angular = wp.dot(gak, symmetric_times(inv_inertia_world_in[bk], gal))
                    free += body_inv_mass[bk] * wp.dot(glk, gll) + angular
    held = free
    if coupled != 0:
        nc = limit_coupling_in.shape[0] // nl
        i = wp.int32(0)
        while i < nc:
            held -= wp.dot(limit_coupling_in[k * nc + i], limit_response_in[l * nc + i])
            i += 1
    if k == l:
        held = wp.max(held, f64(1.0e-9) * free)
    limit_matrix_out[k * nl + l] = held


@wp.kernel
def limit_matrix(
    # Model:
    coupled: int,
    body_inv_mass: wp.array(dtype=f64),
    # Data in: the rows' Jacobians (`row_sides`), c and K^-1 c of every row (when `coupled`)
    limit_side_body_in: wp.array(dtype=int),
    limit_side_lin_in: wp.array(dtype=vec3d),
    limit_side_ang_in: wp.array(dtype=vec3d),
    inv_inertia_world_in: wp.array(dtype=sym33d),
    limit_coupling_in: wp.array(dtype=vec3d),
    limit_response_in: wp.array(dtype=vec3d),
    # Data out: S, row-major (rows k, l)
    limit_matrix_out: wp.array(dtype=f64),
):
    """The rows' system S (`matrix_entry`), a thread an entry."""
    k, l = wp.tid()
    matrix_entry(
        k, l, coupled, body_inv_mass, limit_side_body_in, limit_side_lin_in, limit_side_ang_in, inv_inertia_world_in,
        limit_coupling_in, limit_response_in, limit_matrix_out,
    )  # fmt: skip


@wp.func
def factor_masked(
    n: int, stride: int, matrix: wp.array(dtype=f64), mask: wp.array(dtype=int), work: wp.array(dtype=f64)
):
    """The dense Cholesky factor (in `work`, n x n) of the leading n x n block of `matrix` (row stride `stride`)
    on the rows with mask 1, unit rows and columns elsewhere; a pivot below 1e-12 of its diagonal (rows that
    repeat each other) is regularised to that diagonal."""
    i = wp.int32(0)
    while i < n:
        j = wp.int32(0)
        while j < n:
            v = f64(0.0)
            if mask[i] == 1 and mask[j] == 1:
                v = matrix[i * stride + j]
            elif i == j:
                v = f64(1.0)
            work[i * n + j] = v
            j += 1
        i += 1
    j = wp.int32(0)
    while j < n:
        diag = work[j * n + j]
        t = diag
        k = wp.int32(0)
        while k < j:
            t -= work[j * n + k] * work[j * n + k]
            k += 1
        if t <= f64(1.0e-12) * diag:
            t = diag
        d = wp.sqrt(t)
        work[j * n + j] = d
        i = j + 1
        while i < n:
            u = work[i * n + j]
            k = wp.int32(0)
            while k < j:
                u -= work[i * n + k] * work[j * n + k]
                k += 1
            work[i * n + j] = u / d
            i += 1
        j += 1


@wp.func
def solve_factored(
    n: int,
    work: wp.array(dtype=f64),
    mask: wp.array(dtype=int),
    rhs: wp.array(dtype=f64),
    scratch: wp.array(dtype=f64),
    out: wp.array(dtype=f64),
    out_offset: int,
):
    """out[out_offset + i] = (S_AA^-1 rhs_A)_i on the rows i with mask 1 (others keep theirs) from
    `factor_masked`'s factor (`scratch`: n more)."""
    # The unit rows and columns outside A keep those rows out of the solve (their scratch entries are 0).
    i = wp.int32(0)
    while i < n:
        y = f64(0.0)
        if mask[i] == 1:
            y = rhs[i]
        k = wp.int32(0)
        while k < i:
            y -= work[i * n + k] * scratch[k]
            k += 1
        scratch[i] = y / work[i * n + i]
        i += 1
    ii = wp.int32(0)
    while ii < n:
        i = n - 1 - ii
        x = scratch[i]
        k = i + 1
        while k < n:
            x -= work[k * n + i] * scratch[k]
            k += 1
        scratch[i] = x / work[i * n + i]
        ii += 1
    i = wp.int32(0)
    while i < n:
        if mask[i] == 1:
            out[out_offset + i] = scratch[i]
        i += 1


@wp.func
def solve_masked(
    n: int,
    matrix: wp.array(dtype=f64),
    mask: wp.array(dtype=int),
    rhs: wp.array(dtype=f64),
    work: wp.array(dtype=f64),
    scratch: wp.array(dtype=f64),
    out: wp.array(dtype=f64),
):
    """out = S_AA^-1 rhs_A on the rows with mask 1 (other rows keep their out), by a dense Cholesky in `work`
    (`scratch`: n more)."""
    factor_masked(n, n, matrix, mask, work)
    solve_factored(n, work, mask, rhs, scratch, out, 0)


@wp.func
def compensate(
    l: int,
    amount: f64,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia_world: wp.array(dtype=sym33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
    limit_response: wp.array(dtype=vec3d),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Apply the joints' impulses -K^-1 c_l amount that keep them holding under limit l's impulse `amount`."""
    nc = constraint_body0.shape[0]
    i = wp.int32(0)
    while i < nc:
        lam = limit_response[l * nc + i] * (-amount)
        for side in range(2):
            apply_to_body(
                side_body(i, side, constraint_body0, constraint_body1), constraint_kind[i], 2 * i + side, lam,
                body_inv_mass, inv_inertia_world, jac_lin, jac_ang, jac_skew, body_v, body_w,
            )  # fmt: skip
        i += 1


@wp.func
def apply_row(
    i: int,
    r: int,
    amount: f64,
    a: vec3d,
    pb: vec3d,
    coupled: int,
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    inv_inertia_world: wp.array(dtype=sym33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
    limit_response: wp.array(dtype=vec3d),
    body_x: wp.array(dtype=vec3d),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Apply row i's impulse `amount` on coordinate r (axis a, point B = pb) to its two bodies, and, when
    `coupled`, the joints' reaction to it."""
    kind = coordinate_kind[r]
    b0 = coordinate_body0[r]
    b1 = coordinate_body1[r]
    inv0 = sym33d()
    inv1 = sym33d()
    if b0 >= 0:
        inv0 = inv_inertia_world[b0]
    if b1 >= 0:
        inv1 = inv_inertia_world[b1]
    push_side(kind, b0, f64(-1.0), amount, a, pb - pose_x(b0, body_x), body_inv_mass, inv0, body_v, body_w)
    push_side(kind, b1, f64(1.0), amount, a, pb - pose_x(b1, body_x), body_inv_mass, inv1, body_v, body_w)
    if coupled != 0:
        compensate(
            i, amount, constraint_kind, constraint_body0, constraint_body1, body_inv_mass, inv_inertia_world, jac_lin,
            jac_ang, jac_skew, limit_response, body_v, body_w,
        )  # fmt: skip


@wp.func
def push_side(
    kind: int,
    b: int,
    sign: f64,
    lam: f64,
    a: vec3d,
    arm: vec3d,
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia: sym33d,
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Apply sign lam about (angle) or along (offset, at the arm) the axis to body b."""
    if b < 0:
        return
    if kind == ANGLE_COORDINATE:
        body_w[b] = body_w[b] + symmetric_times(inv_inertia, a) * (sign * lam)
    else:
        body_v[b] = body_v[b] + a * (sign * lam * body_inv_mass[b])
        body_w[b] = body_w[b] + symmetric_times(inv_inertia, wp.cross(arm, a)) * (sign * lam)


@wp.func
def apply_fixed(
    i: int,
    amount: f64,
    coupled: int,
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    coordinate_rest_rotation: wp.array(dtype=quatd),
    limit_coordinate: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    inv_inertia_world: wp.array(dtype=sym33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
    limit_response: wp.array(dtype=vec3d),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Row i's impulse `amount` on its bodies and the joints' reaction (`apply_row`), its axis and point at
    the poses given."""
    r = limit_coordinate[i]
    value, rate, a, pb = coordinate_row(
        r, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0, coordinate_anchor1,
        coordinate_axis0, coordinate_rest_rotation, body_x, body_q, body_v, body_w,
    )  # fmt: skip
    apply_row(
        i, r, amount, a, pb, coupled, coordinate_kind, coordinate_body0, coordinate_body1, body_inv_mass,
        constraint_kind, constraint_body0, constraint_body1, inv_inertia_world, jac_lin, jac_ang, jac_skew,
        limit_response, body_x, body_v, body_w,
    )  # fmt: skip


@wp.func
def row_setup(
    velocity: int,
    lam: f64,
    current: f64,
    motor: int,
    bounds: wp.vec2d,
    drive_mode: wp.array(dtype=int),
    drive_max_force: wp.array(dtype=f64),
    drive_target: wp.array(dtype=f64),
    h: f64,
):
    """(active, rate change wanted, low, high) of a limit or motor row whose total impulse so far this step is
    `lam` and whose coordinate (position pass, `velocity` 0: predicted, m or rad) or rate (velocity pass) is
    `current`; the bounds are on the row's total impulse (N s or N m s). `correct_rows` says what each pass
    wants."""
    active = int(0)  # noqa: UP018
    goal = f64(0.0)
    up = int(0)  # noqa: UP018 (a limit row pushing up from its lower bound; by the side, not by the goal: a
    # joint locked by lower == upper, as URDF's revolute joints without bounds, has one goal for both sides)
    if motor >= 0:
        if velocity == 0 or drive_mode[motor] == VELOCITY_MODE:
            active = 1
            if velocity != 0:
                goal = drive_target[motor]
        elif wp.abs(lam) < drive_max_force[motor] * h:
            active = 1  # a position motor holding its target: hold it still
    elif velocity == 0:
        if lam > f64(0.0) or (lam == f64(0.0) and current < bounds[0]):
            active = 1
            goal = bounds[0]
            up = 1
        elif lam < f64(0.0) or current > bounds[1]:
            active = 1
            goal = bounds[1]
    elif lam != f64(0.0):
        active = 1
    # Bounds on the row's total impulse: a motor's max_force h either way; a limit pushes only (the velocity
    # pass adds to the step's push, never takes from it).
    low = f64(-1.0e300)
    high = f64(1.0e300)
    if motor >= 0:
        low = -drive_max_force[motor] * h
        high = drive_max_force[motor] * h
    elif lam > f64(0.0) or up == 1:
        low = wp.where(velocity == 0, f64(0.0), lam)
    else:
        high = wp.where(velocity == 0, f64(0.0), lam)
    want = goal - current
    if velocity == 0:
        want = want / h
    return active, want, low, high


@wp.func
def fix_furthest_out(
    count: int,
    stride: int,
    matrix: wp.array(dtype=f64),
    mask: wp.array(dtype=int),
    before: wp.array(dtype=f64),
    low: wp.array(dtype=f64),
    high: wp.array(dtype=f64),
    delta: wp.array(dtype=f64),
    threshold: f64,
) -> int:
    """Block pivoting's first move: of the free rows (mask 1) among the first `count`, fix the one whose total
    before + delta lies furthest outside [low, high] (measured as a rate: times its diagonal entry of the
    row-major `matrix` of width `stride`, and only beyond `threshold`) at that bound (mask 2 low, 3 high).
    Returns the row fixed, or -1 when every free row is within its bounds."""
    pick = int(-1)  # noqa: UP018 (a Warp variable the loop changes must not start as a constant)
    worst = threshold
    i = wp.int32(0)
    while i < count:
        if mask[i] == 1:
            total = before[i] + delta[i]
            over = wp.max(low[i] - total, total - high[i]) * matrix[i * stride + i]
            if over > worst:
                worst = over
                pick = i
        i += 1
    if pick >= 0:
        total = before[pick] + delta[pick]
        mask[pick] = wp.where(total < low[pick], 2, 3)
        delta[pick] = wp.clamp(total, low[pick], high[pick]) - before[pick]
    return pick


@wp.func
def box_pivot(
    n: int,
    matrix: wp.array(dtype=f64),
    mask: wp.array(dtype=int),
    goal: wp.array(dtype=f64),
    before: wp.array(dtype=f64),
    low: wp.array(dtype=f64),
    high: wp.array(dtype=f64),
    delta: wp.array(dtype=f64),
    rhs: wp.array(dtype=f64),
    work: wp.array(dtype=f64),
    scratch: wp.array(dtype=f64),
):
    """delta with matrix_AA delta_A = goal_A on the rows A with mask 1, the totals before + delta within
    [low, high], by block pivoting on the box: mask 1 free (solved), 2 at its low bound, 3 at its high bound,
    0 inactive. Each round solves the free rows with the fixed rows' impulses moved to the right-hand side,
    then fixes the free row furthest out of its bounds, or else frees the fixed row whose demand points
    inwards the most, until neither happens."""
    _round = wp.int32(0)
    while _round < 4 * n + 4:
        i = wp.int32(0)
        while i < n:
            want = goal[i]
            j = wp.int32(0)
            while j < n:
                if mask[j] >= 2:
                    want -= matrix[i * n + j] * delta[j]
                j += 1
            rhs[i] = want
            i += 1
        solve_masked(n, matrix, mask, rhs, work, scratch, delta)
        worst = f64(0.0)
        pick = fix_furthest_out(n, n, matrix, mask, before, low, high, delta, worst)
        if pick < 0:
            i = wp.int32(0)
            while i < n:
                if mask[i] >= 2:
                    demand = rhs[i]  # the rate change still wanted at fixed row i, all impulses counted
                    j = wp.int32(0)
                    while j < n:
                        if mask[j] == 1:
                            demand -= matrix[i * n + j] * delta[j]
                        j += 1
                    inward = wp.where(mask[i] == 2, demand, -demand)  # towards the inside of its bounds
                    if inward > worst:
                        worst = inward
                        pick = i
                i += 1
            if pick < 0:
                break
            mask[pick] = 1
        _round += 1


@wp.func
def setup_all(
    velocity: int,
    h: f64,
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    rows: Rows,
):
    """`correct_rows`' first half: which rows are active in this pass (limit_mask), and each one's goal and
    bounds; only the active rows' entries of S are read after it (`resolve_all`), so the fused step forms S
    row by row as rows turn active (kernels/step.py `correct_rows_all`)."""
    n = rows.limit_coordinate.shape[0]
    i = wp.int32(0)
    while i < n:
        r = rows.limit_coordinate[i]
        value, rate, a, pb = rows_coordinate(r, rows, body_x_in, body_q_in, body_v, body_w)
        current = rate
        if velocity == 0:
            current = rows.limit_value[i] + h * (rate - rows.limit_rate[i])
        active, goal, low, high = row_setup(
            velocity,
            rows.limit_impulse[i],
            current,
            rows.limit_drive[i],
            rows.limit_bounds[i],
            rows.drive_mode,
            rows.drive_max_force,
            rows.drive_target,
            h,
        )
        rows.limit_low[i] = low
        rows.limit_high[i] = high
        rows.limit_mask[i] = active
        rows.limit_goal[i] = goal
        rows.limit_delta[i] = f64(0.0)
        rows.limit_before[i] = rows.limit_impulse[i]  # the row's total before this pass
        if velocity != 0:
            rows.limit_velocity_impulse[i] = f64(0.0)
        i += 1


@wp.func
def resolve_all(
    velocity: int,
    coupled: int,
    # Model:
    body_inv_mass: wp.array(dtype=f64),
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    # Data in:
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    # Data in/out: the state's velocities; the rows, their impulses and scratch
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    rows: Rows,
):
    """`correct_rows`' second half: the active rows' impulses within their bounds (`box_pivot`), applied with
    the joints' reaction."""
    n = rows.limit_coordinate.shape[0]
    box_pivot(
        n,
        rows.limit_matrix,
        rows.limit_mask,
        rows.limit_goal,
        rows.limit_before,
        rows.limit_low,
        rows.limit_high,
        rows.limit_delta,
        rows.limit_rhs,
        rows.limit_work,
        rows.limit_scratch,
    )
    i = wp.int32(0)
    while i < n:
        if rows.limit_mask[i] != 0:
            d = rows.limit_delta[i]
            if velocity == 0:
                rows.limit_impulse[i] = rows.limit_impulse[i] + d
            else:
                rows.limit_velocity_impulse[i] = rows.limit_velocity_impulse[i] + d
            apply_fixed(
                i,
                d,
                coupled,
                rows.coordinate_kind,
                rows.coordinate_body0,
                rows.coordinate_body1,
                rows.coordinate_anchor0,
                rows.coordinate_anchor1,
                rows.coordinate_axis0,
                rows.coordinate_rest_rotation,
                rows.limit_coordinate,
                body_inv_mass,
                constraint_kind,
                constraint_body0,
                constraint_body1,
                inv_inertia_world_in,
                jac_lin_in,
                jac_ang_in,
                jac_skew_in,
                rows.limit_response,
                body_x_in,
                body_q_in,
                body_v,
                body_w,
            )
        i += 1


@wp.kernel
def correct_rows(
    velocity: int,
    coupled: int,
    # Model:
    body_inv_mass: wp.array(dtype=f64),
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    # Data in:
    h: f64,
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    # Data in/out:
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    rows: Rows,
):
    """All rows at once (one thread), on the rows' system S (`limit_matrix`) with an active set.

    Position pass (`velocity` 0, in the joint-correction loop): each row's predicted coordinate, updated to
    first order by the impulses since the measurement, h (rate now - rate measured); an active row (a motor,
    a limit violated or already pushing) is moved to its goal: S_AA d = (goal - predicted) / h. Velocity pass
    (1, after the step): a motor's rate to its target (velocity mode) or to 0 once it holds its target
    (position mode), a limit that pushed in the step to rate 0: S_AA d = goal - rate. The totals stay in their
    bounds (push only; |motor| <= max_force h over the step) by block pivoting: rows out of bounds are fixed
    at them one at a time, fixed rows whose demand turns inwards are freed, until neither happens. The
    impulses go to the bodies with the joints' reaction (`setup_all`, then `resolve_all`)."""
    setup_all(velocity, h, body_x_in, body_q_in, body_v, body_w, rows)
    resolve_all(
        velocity, coupled, body_inv_mass, constraint_kind, constraint_body0, constraint_body1, inv_inertia_world_in,
        jac_lin_in, jac_ang_in, jac_skew_in, body_x_in, body_q_in, body_v, body_w, rows,
    )  # fmt: skip
