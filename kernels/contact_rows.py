"""Contacts on jointed bodies as rows of the rows' system (`kernels/limits.py`), solved with the limits and stiff
motors and with the joints holding: the survey's joints as one block solved directly, the contacts, limits and
motors around it as one block of their own, not swept one after another.

A foot under a walking machine's leg alone is light: a contact sweep that sees the leg's own mass closes its
gap with the leg's mobility, and the joints' solve, which holds the leg to the body and the crank's motor,
undoes about 90% of it; the two alternate at 4-8% a prediction (docs/contacts.md). Here every row r (a limit's
or motor's coordinate, or a contact's normal or one of its two tangents) is a Jacobian g_r on at most two
bodies, and the rows' system is S = G M^-1 G^T - C^T K^-1 C with C = J M^-1 G^T: the rows' mobility with the
joints holding, K^-1 C from one solve with K's factor per row and step (limits' rows reuse theirs). One solve
of S with block pivoting on the bounds (limits push only, motors within max_force h, contacts push only,
friction within mu times the normal impulse) moves every row at once; each row's impulse goes to its bodies
with the joints' linear reaction -K^-1 c, so the joints stay as they were to first order.

Friction is a box on two tangents, the first along the contact's slip when the rows are built (a sliding
contact slides along its first tangent, at mu lambda_n against its slip), its bounds mu lambda_n updated from
the normal impulses and solved again (a few passes); the tangential total is then projected onto the cone's
disc.
"""

import warp as wp

from . import collide
from .contact_solve import relative_velocity
from .forces import coordinate_row
from .limits import compensate, limit_side, row_setup

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
quatd = wp.quatd
mat33d = wp.mat33d
vec2d = wp.vec2d
f64 = wp.float64

@wp.kernel
def assign_rows(
    # Model:
    limit_count: int,
    body_jointed: wp.array(dtype=int),
    # Data in:
    contact_count: wp.array(dtype=int),
    contact_body: wp.array(dtype=wp.vec2i),
    # Data out: per contact its first row (-1: swept alone), per slot its contact, the rows in all
    contact_row_out: wp.array(dtype=int),
    row_contact_out: wp.array(dtype=int),
    row_count_out: wp.array(dtype=int),
):
    """Rows for the contacts that touch a jointed body, three each after the limits' rows, as many as the slots
    hold (one thread; the others are swept alone)."""
    count = wp.min(contact_count[0], contact_body.shape[0])
    slots = int(0)
    for k in range(count):
        a = contact_body[k][0]
        b = contact_body[k][1]
        jointed = (a >= 0 and body_jointed[a] != 0) or (b >= 0 and body_jointed[b] != 0)
        contact_row_out[k] = -1
        if jointed and slots < row_contact_out.shape[0]:
            contact_row_out[k] = limit_count + 3 * slots
            row_contact_out[slots] = k
            slots += 1
    row_count_out[0] = limit_count + 3 * slots


@wp.func
def contact_tangent(n: vec3d, slip: vec3d) -> vec3d:
    """The first tangent of a contact's rows: along its slip, or any when it does not slip."""
    if wp.length(slip) > f64(1.0e-12):
        return wp.normalize(slip)
    return collide.any_perpendicular(n)


@wp.kernel
def row_jacobians(
    # Model:
    velocity: int,
    limit_count: int,
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    coordinate_rest_rotation: wp.array(dtype=quatd),
    limit_coordinate: wp.array(dtype=int),
    # Data in: the state at t0, the contacts as last measured
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    row_count: wp.array(dtype=int),
    row_contact: wp.array(dtype=int),
    contact_body: wp.array(dtype=wp.vec2i),
    contact_normal: wp.array(dtype=vec3d),
    contact_arm_a: wp.array(dtype=vec3d),
    contact_arm_b: wp.array(dtype=vec3d),
    contact_slip: wp.array(dtype=vec3d),
    # Data out: each row's bodies (side 0, side 1) and Jacobian, a contact row's direction (world)
    row_body_out: wp.array(dtype=wp.vec2i),
    row_lin0_out: wp.array(dtype=vec3d),
    row_ang0_out: wp.array(dtype=vec3d),
    row_lin1_out: wp.array(dtype=vec3d),
    row_ang1_out: wp.array(dtype=vec3d),
    row_direction_out: wp.array(dtype=vec3d),
):
    """Row r's Jacobian: d(rate_r) = lin0 . v_body0 + ang0 . w_body0 + lin1 . v_body1 + ang1 . w_body1. A limit's
    as `limit_side` gives it; a contact's along its normal or a tangent d at the arms of the last measurement
    (relative velocity of b's point against a's: +d on b, -d on a), the first tangent along the slip over the
    step (position pass, `velocity` 0) or the tangential velocity at t0 + h (velocity pass)."""
    r = wp.tid()
    if r >= row_count[0]:
        return
    if r < limit_count:
        b0, l0, a0 = limit_side(
            limit_coordinate[r], 0, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0,
            coordinate_anchor1, coordinate_axis0, coordinate_rest_rotation, body_x_in, body_q_in, body_v_in,
            body_w_in,
        )  # fmt: skip
        b1, l1, a1 = limit_side(
            limit_coordinate[r], 1, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0,
            coordinate_anchor1, coordinate_axis0, coordinate_rest_rotation, body_x_in, body_q_in, body_v_in,
            body_w_in,
        )  # fmt: skip
        row_body_out[r] = wp.vec2i(b0, b1)
        row_lin0_out[r] = l0
        row_ang0_out[r] = a0
        row_lin1_out[r] = l1
        row_ang1_out[r] = a1
        return
    slot = (r - limit_count) // 3
    axis = (r - limit_count) - 3 * slot
    k = row_contact[slot]
    n = contact_normal[k]
    ra = contact_arm_a[k]
    rb = contact_arm_b[k]
    slip = contact_slip[k]
    if velocity != 0:  # the tangential velocity at t0 + h
        u = relative_velocity(contact_body[k][0], contact_body[k][1], ra, rb, body_v_in, body_w_in)
        slip = u - n * wp.dot(n, u)
    t1 = contact_tangent(n, slip)
    d = n
    if axis == 1:
        d = t1
    elif axis == 2:
        d = wp.cross(n, t1)
    row_body_out[r] = contact_body[k]
    row_direction_out[r] = d
    row_lin0_out[r] = -d
    row_ang0_out[r] = -wp.cross(ra, d)
    row_lin1_out[r] = d
    row_ang1_out[r] = wp.cross(rb, d)


@wp.func
def row_side(
    r: int,
    side: int,
    row_body: wp.array(dtype=wp.vec2i),
    row_lin0: wp.array(dtype=vec3d),
    row_ang0: wp.array(dtype=vec3d),
    row_lin1: wp.array(dtype=vec3d),
    row_ang1: wp.array(dtype=vec3d),
):
    """(body, linear row, angular row) of row r's Jacobian on one side."""
    if side == 0:
        return row_body[r][0], row_lin0[r], row_ang0[r]
    return row_body[r][1], row_lin1[r], row_ang1[r]


@wp.kernel
def row_coupling(
    # Model:
    body_inv_mass: wp.array(dtype=f64),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    # Data in:
    inv_inertia_world_in: wp.array(dtype=mat33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    row_count: wp.array(dtype=int),
    row_body: wp.array(dtype=wp.vec2i),
    row_lin0: wp.array(dtype=vec3d),
    row_ang0: wp.array(dtype=vec3d),
    row_lin1: wp.array(dtype=vec3d),
    row_ang1: wp.array(dtype=vec3d),
    # Data out: c of row r for constraint i at r * constraint_count + i
    row_coupling_out: wp.array(dtype=vec3d),
):
    """c_i = sum over the bodies that row r and constraint i share of J_ib M_b^-1 g_b^T."""
    r, i = wp.tid()
    nc = constraint_body0.shape[0]
    c = vec3d()
    if r < row_count[0]:
        for side in range(2):
            b, g_lin, g_ang = row_side(r, side, row_body, row_lin0, row_ang0, row_lin1, row_ang1)
            if b >= 0:
                if constraint_body0[i] == b:
                    c += jac_lin_in[2 * i] * g_lin * body_inv_mass[b] + jac_ang_in[2 * i] * (
                        inv_inertia_world_in[b] * g_ang
                    )
                if constraint_body1[i] == b:
                    c += jac_lin_in[2 * i + 1] * g_lin * body_inv_mass[b] + jac_ang_in[2 * i + 1] * (
                        inv_inertia_world_in[b] * g_ang
                    )
    row_coupling_out[r * nc + i] = c


@wp.kernel
def row_matrix(
    # Model:
    body_inv_mass: wp.array(dtype=f64),
    constraint_body0: wp.array(dtype=int),
    # Data in:
    inv_inertia_world_in: wp.array(dtype=mat33d),
    row_count: wp.array(dtype=int),
    row_body: wp.array(dtype=wp.vec2i),
    row_lin0: wp.array(dtype=vec3d),
    row_ang0: wp.array(dtype=vec3d),
    row_lin1: wp.array(dtype=vec3d),
    row_ang1: wp.array(dtype=vec3d),
    row_coupling: wp.array(dtype=vec3d),
    row_response: wp.array(dtype=vec3d),
    # Data out: S, row-major with the row count as its stride
    row_matrix_out: wp.array(dtype=f64),
):
    """S_kl = g_k M^-1 g_l^T - c_k . K^-1 c_l (`limits.limit_matrix` for any rows); a diagonal is kept at least
    1e-9 of its free value."""
    k, l = wp.tid()
    n = row_count[0]
    if k >= n or l >= n:
        return
    free = f64(0.0)
    for sk in range(2):
        bk, glk, gak = row_side(k, sk, row_body, row_lin0, row_ang0, row_lin1, row_ang1)
        if bk >= 0:
            for sl in range(2):
                bl, gll, gal = row_side(l, sl, row_body, row_lin0, row_ang0, row_lin1, row_ang1)
                if bl == bk:
                    free += body_inv_mass[bk] * wp.dot(glk, gll) + wp.dot(gak, inv_inertia_world_in[bk] * gal)
    held = free
    nc = constraint_body0.shape[0]
    for i in range(nc):
        held -= wp.dot(row_coupling[k * nc + i], row_response[l * nc + i])
    if k == l:
        held = wp.max(held, f64(1.0e-9) * free)
    row_matrix_out[k * n + l] = held


@wp.func
def push_row(
    r: int,
    amount: f64,
    row_body: wp.array(dtype=wp.vec2i),
    row_lin0: wp.array(dtype=vec3d),
    row_ang0: wp.array(dtype=vec3d),
    row_lin1: wp.array(dtype=vec3d),
    row_ang1: wp.array(dtype=vec3d),
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia_world: wp.array(dtype=mat33d),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Row r's impulse `amount` on its bodies: M^-1 g^T amount."""
    for side in range(2):
        b, g_lin, g_ang = row_side(r, side, row_body, row_lin0, row_ang0, row_lin1, row_ang1)
        if b >= 0:
            body_v[b] = body_v[b] + g_lin * (amount * body_inv_mass[b])
            body_w[b] = body_w[b] + inv_inertia_world[b] * (g_ang * amount)


@wp.func
def pgs_row(
    r: int,
    n: int,
    matrix: wp.array(dtype=f64),
    goal: wp.array(dtype=f64),
    before: wp.array(dtype=f64),
    low: f64,
    high: f64,
    delta: wp.array(dtype=f64),
    y: wp.array(dtype=f64),
) -> f64:
    """One projected Gauss-Seidel update of row r (y = S delta kept up to date); returns the rate change it made
    (m/s or rad/s)."""
    diag = matrix[r * n + r]
    total = wp.clamp(before[r] + delta[r] + (goal[r] - y[r]) / diag, low, high)
    step = total - before[r] - delta[r]
    delta[r] = delta[r] + step
    for i in range(n):
        y[i] = y[i] + matrix[i * n + r] * step
    return wp.abs(step) * diag


@wp.func
def pgs_friction(
    r: int,
    n: int,
    limit: f64,
    matrix: wp.array(dtype=f64),
    goal: wp.array(dtype=f64),
    before: wp.array(dtype=f64),
    delta: wp.array(dtype=f64),
    y: wp.array(dtype=f64),
) -> f64:
    """A contact's two friction rows r, r + 1 at once: the 2x2 block's solve, its total projected onto the disc
    of radius `limit`; returns the rate change it made."""
    a = matrix[r * n + r]
    b = matrix[r * n + r + 1]
    d = matrix[(r + 1) * n + r + 1]
    e0 = goal[r] - y[r]
    e1 = goal[r + 1] - y[r + 1]
    det = a * d - b * b
    s0 = e0 / a
    s1 = e1 / d
    if det > f64(1.0e-12) * a * d:
        s0 = (d * e0 - b * e1) / det
        s1 = (a * e1 - b * e0) / det
    t = vec2d(before[r] + delta[r] + s0, before[r + 1] + delta[r + 1] + s1)
    size = wp.length(t)
    if size > limit:
        t = t * (limit / size)
    step0 = t[0] - before[r] - delta[r]
    step1 = t[1] - before[r + 1] - delta[r + 1]
    delta[r] = delta[r] + step0
    delta[r + 1] = delta[r + 1] + step1
    for i in range(n):
        y[i] = y[i] + matrix[i * n + r] * step0 + matrix[i * n + r + 1] * step1
    return wp.max(wp.abs(step0) * a, wp.abs(step1) * d)


@wp.kernel
def solve_rows(
    # Model:
    h: f64,
    limit_count: int,
    body_inv_mass: wp.array(dtype=f64),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    coordinate_rest_rotation: wp.array(dtype=quatd),
    limit_coordinate: wp.array(dtype=int),
    limit_bounds: wp.array(dtype=wp.vec2d),
    limit_drive: wp.array(dtype=int),
    drive_mode: wp.array(dtype=int),
    drive_max_force: wp.array(dtype=f64),
    velocity: int,
    sweeps: int,
    tolerance: f64,
    bounce_speed: f64,
    # Data in:
    drive_target: wp.array(dtype=f64),
    inv_inertia_world_in: wp.array(dtype=mat33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    limit_value_in: wp.array(dtype=f64),
    limit_rate_in: wp.array(dtype=f64),
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    row_count: wp.array(dtype=int),
    row_contact: wp.array(dtype=int),
    row_body: wp.array(dtype=wp.vec2i),
    row_lin0: wp.array(dtype=vec3d),
    row_ang0: wp.array(dtype=vec3d),
    row_lin1: wp.array(dtype=vec3d),
    row_ang1: wp.array(dtype=vec3d),
    row_direction: wp.array(dtype=vec3d),
    row_response: wp.array(dtype=vec3d),
    row_matrix: wp.array(dtype=f64),
    contact_body: wp.array(dtype=wp.vec2i),
    contact_normal: wp.array(dtype=vec3d),
    contact_material: wp.array(dtype=wp.vec2d),
    contact_gap: wp.array(dtype=f64),
    contact_slip: wp.array(dtype=vec3d),
    contact_arm_a: wp.array(dtype=vec3d),
    contact_arm_b: wp.array(dtype=vec3d),
    contact_u0: wp.array(dtype=vec3d),
    contact_impact: wp.array(dtype=f64),
    contact_approach: wp.array(dtype=f64),
    # Data in/out: the velocities at t0 (t0 + h), the impulses of the step, scratch
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    limit_impulse: wp.array(dtype=f64),
    limit_velocity_impulse: wp.array(dtype=f64),
    contact_impulse: wp.array(dtype=vec3d),
    contact_velocity_impulse: wp.array(dtype=vec3d),
    row_mask: wp.array(dtype=int),
    row_goal: wp.array(dtype=f64),
    row_before: wp.array(dtype=f64),
    row_low: wp.array(dtype=f64),
    row_high: wp.array(dtype=f64),
    row_delta: wp.array(dtype=f64),
    row_rhs: wp.array(dtype=f64),
    contact_error: wp.array(dtype=f64),
):
    """Every row at once (one thread), by projected Gauss-Seidel on the rows' system S, until no row moves its
    coordinate by more than `tolerance` over the step; contact_error[1 + velocity] = the sweeps taken.

    Position pass (`velocity` 0, at t0, on the prediction just measured): a limit or motor as
    `limits.correct_rows` wants it; a contact's gap g' = g + h n . du >= 0, pushing only; its slip over the step
    (the slip measured + du_t) stopped within mu lambda_n. Velocity pass (1, at t0 + h, after
    `contact_solve.solve_velocities` measured the gaps and arms there): a limit or motor as `correct_rows`
    wants it, a contact's normal velocity as `solve_velocities` wants it, its tangential velocity stopped within
    mu times this phase's normal impulse. The impulses go to the bodies with the joints' reaction, and into
    the step's totals of their phase."""
    n = row_count[0]
    nl = limit_count
    for i in range(nl):
        value, rate, axis_i, pb = coordinate_row(
            limit_coordinate[i], coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0,
            coordinate_anchor1, coordinate_axis0, coordinate_rest_rotation, body_x_in, body_q_in, body_v, body_w,
        )  # fmt: skip
        current = rate
        pushed = limit_impulse[i]
        if velocity == 0:
            current = limit_value_in[i] + h * (rate - limit_rate_in[i])
        active, goal, low, high = row_setup(
            velocity, pushed, current, limit_drive[i], limit_bounds[i], drive_mode, drive_max_force, drive_target,
            h,
        )  # fmt: skip
        row_mask[i] = active
        row_goal[i] = goal
        row_low[i] = low
        row_high[i] = high
        row_before[i] = pushed
        if velocity != 0:
            row_before[i] = pushed + limit_velocity_impulse[i]
        row_delta[i] = f64(0.0)
    for r in range(nl, n, 3):
        k = row_contact[(r - nl) // 3]
        a = contact_body[k][0]
        b = contact_body[k][1]
        nrm = contact_normal[k]
        u = relative_velocity(a, b, contact_arm_a[k], contact_arm_b[k], body_v, body_w)
        lam = vec3d(contact_impulse[k])
        active = int(1)  # noqa: UP018
        if velocity == 0:
            du = u - contact_u0[k]
            slip = contact_slip[k] + du
            row_goal[r] = -(contact_gap[k] + h * wp.dot(nrm, du)) / h
        else:  # as `contact_solve.solve_velocities` wants it
            lam = vec3d(contact_velocity_impulse[k])
            slip = u
            gap = contact_gap[k]
            target = -wp.max(gap, f64(0.0)) / h
            if contact_impact[k] > bounce_speed:
                target = contact_material[k][1] * contact_impact[k]
            elif gap > f64(0.0) and contact_approach[k] > bounce_speed:
                active = 0  # an impact of the next step
            row_goal[r] = target - wp.dot(nrm, u)
        s1 = collide.any_perpendicular(nrm)  # the basis the step's totals are kept in
        total = s1 * lam[1] + wp.cross(nrm, s1) * lam[2]
        row_before[r] = lam[0]
        for axis in range(3):
            row_mask[r + axis] = active
            row_delta[r + axis] = f64(0.0)
            if axis > 0:
                d = row_direction[r + axis]
                row_goal[r + axis] = -wp.dot(d, slip)
                row_before[r + axis] = wp.dot(d, total)
    # y = S delta, kept up to date row by row.
    for i in range(n):
        row_rhs[i] = f64(0.0)
    taken = int(0)
    for sweep in range(sweeps):
        taken += 1
        change = f64(0.0)
        for i in range(n):
            r = i
            if sweep % 2 == 1:
                r = n - 1 - i  # symmetric Gauss-Seidel
            if r < nl:
                if row_mask[r] != 0:
                    change = wp.max(change, pgs_row(r, n, row_matrix, row_goal, row_before, row_low[r],
                                                    row_high[r], row_delta, row_rhs))  # fmt: skip
            else:
                base = r - (r - nl) % 3
                if r == base and row_mask[r] != 0:  # a contact: its normal, then its friction as a 2x2 block within the disc
                    k = row_contact[(base - nl) // 3]
                    change = wp.max(change, pgs_row(base, n, row_matrix, row_goal, row_before, f64(0.0),
                                                    f64(1.0e300), row_delta, row_rhs))  # fmt: skip
                    mu_n = contact_material[k][0] * (row_before[base] + row_delta[base])
                    change = wp.max(change, pgs_friction(base + 1, n, mu_n, row_matrix, row_goal, row_before,
                                                         row_delta, row_rhs))  # fmt: skip
        if change * h <= tolerance:
            break
    for r in range(n):
        amount = row_delta[r]
        if amount != f64(0.0):
            push_row(r, amount, row_body, row_lin0, row_ang0, row_lin1, row_ang1, body_inv_mass,
                     inv_inertia_world_in, body_v, body_w)  # fmt: skip
            compensate(r, amount, constraint_body0, constraint_body1, body_inv_mass, inv_inertia_world_in, jac_lin_in,
                       jac_ang_in, row_response, body_v, body_w)  # fmt: skip
    for i in range(nl):
        if velocity == 0:
            limit_impulse[i] = limit_impulse[i] + row_delta[i]
        else:
            limit_velocity_impulse[i] = limit_velocity_impulse[i] + row_delta[i]
    contact_error[1 + velocity] = f64(taken)
    for r in range(nl, n, 3):
        k = row_contact[(r - nl) // 3]
        nrm = contact_normal[k]
        s1 = collide.any_perpendicular(nrm)
        friction = row_direction[r + 1] * (row_before[r + 1] + row_delta[r + 1]) + row_direction[r + 2] * (
            row_before[r + 2] + row_delta[r + 2]
        )
        lam = vec3d(row_before[r] + row_delta[r], wp.dot(friction, s1), wp.dot(friction, wp.cross(nrm, s1)))
        if velocity == 0:
            contact_impulse[k] = lam
        else:
            contact_velocity_impulse[k] = lam
