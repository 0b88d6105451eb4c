"""Contacts on jointed bodies as rows of the rows' system (`kernels/limits.py`), solved with the limits and stiff
motors and with the joints holding: the survey's joints as one block solved directly, the contacts, limits and
motors around it as one block of their own, not swept one after another.

A foot under a walking machine's leg alone is light: a contact sweep that sees the leg's own mass closes its
gap with the leg's mobility, and the joints' solve, which holds the leg to the body and the crank's motor,
undoes about 90% of it; the two alternate at 4-8% a prediction (docs/contacts.md). Here every row r (a limit's
or motor's coordinate, or a contact's normal or one of its two tangents) is a Jacobian g_r on at most two
bodies, and the rows' system is S = G M^-1 G^T - C^T K^-1 C with C = J M^-1 G^T: the rows' mobility with the
joints holding, K^-1 C from one solve with K's factor per row and step (limits' rows reuse theirs). In S the
limits and motors that hold are eliminated exactly (their block is small and stiffly coupled to the contacts:
a crank's motor and the foot it drives), the contacts' rows are swept by projected Gauss-Seidel on what is
left (normals push only, friction within mu times the normal impulse), and a limit or motor out of its bounds
(push only; max_force h) is fixed at them, or a fixed one freed, and again. Each row's impulse goes to its
bodies with the joints' linear reaction -K^-1 c, so the joints stay as they were to first order.

Friction: both tangents of a contact as a block, the first along its slip when the rows are built; where the
block's own solve lies in the cone's disc it sticks, else a step of the block's largest eigenvalue against
the slip left, projected onto the disc, so that a sliding contact's impulse points against its slip.
"""

import warp as wp

from . import collide
from .contact_solve import relative_velocity
from .forces import coordinate_row
from .inertia import sym33d, symmetric_times
from .limits import compensate, coupling_through, factor_masked, fix_furthest_out, limit_side, row_setup, solve_factored

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
quatd = wp.quatd
mat33d = wp.mat33d
vec2d = wp.vec2d
f64 = wp.float64

REGULARIZATION = wp.constant(f64(1.0e-8))
"""Added to each diagonal of S as a fraction of its free value: contacts repeat each other (four corners of a
box, two points of a wheel's rim) and S is singular; with it S is positive definite and a row's rate misses
its goal by 1e-8 of its free mobility times its impulse (for a 5 kg foot pushed with 10 N s, 2e-8 m/s)."""


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
    k = wp.int32(0)
    while k < count:
        a = contact_body[k][0]
        b = contact_body[k][1]
        jointed = (a >= 0 and body_jointed[a] != 0) or (b >= 0 and body_jointed[b] != 0)
        contact_row_out[k] = -1
        if jointed and slots < row_contact_out.shape[0]:
            contact_row_out[k] = limit_count + 3 * slots
            row_contact_out[slots] = k
            slots += 1
        k += 1
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
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    # Data in:
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    row_count: wp.array(dtype=int),
    row_body: wp.array(dtype=wp.vec2i),
    row_lin0: wp.array(dtype=vec3d),
    row_ang0: wp.array(dtype=vec3d),
    row_lin1: wp.array(dtype=vec3d),
    row_ang1: wp.array(dtype=vec3d),
    span: int,
    # Data out: c of row r for constraint i at r * constraint_count + i
    row_coupling_out: wp.array(dtype=vec3d),
):
    """c_i = sum over the bodies that row r and constraint i share of J_ib M_b^-1 g_b^T (`coupling_through`), for
    the `span` constraints from j span of thread (r, j): one each on a GPU, all of them on a CPU, where a thread is
    a call in a loop and the rows' slots, most of them empty, cost more as threads than their work (`ContactStage`
    launches (rows, 1) there)."""
    r, j = wp.tid()
    nc = constraint_body0.shape[0]
    active = r < row_count[0]
    i = j * span
    while i < wp.min(nc, (j + 1) * span):
        c = vec3d()
        if active:
            for side in range(2):
                b, g_lin, g_ang = row_side(r, side, row_body, row_lin0, row_ang0, row_lin1, row_ang1)
                if b >= 0:
                    c += coupling_through(
                        i, b, g_lin, g_ang, constraint_kind, constraint_body0, constraint_body1, body_inv_mass,
                        inv_inertia_world_in, jac_lin_in, jac_ang_in, jac_skew_in,
                    )  # fmt: skip
        row_coupling_out[r * nc + i] = c
        i += 1


@wp.func
def row_matrix_entry(
    k: int,
    l: int,
    body_inv_mass: wp.array(dtype=f64),
    nc: int,
    inv_inertia_world: wp.array(dtype=sym33d),
    row_body: wp.array(dtype=wp.vec2i),
    row_lin0: wp.array(dtype=vec3d),
    row_ang0: wp.array(dtype=vec3d),
    row_lin1: wp.array(dtype=vec3d),
    row_ang1: wp.array(dtype=vec3d),
    row_coupling: wp.array(dtype=vec3d),
    row_response: wp.array(dtype=vec3d),
) -> f64:
    """S_kl = g_k M^-1 g_l^T - c_k . K^-1 c_l (`limits.limit_matrix` for any rows); a diagonal is kept at least
    1e-9 of its free value."""
    free = f64(0.0)
    for sk in range(2):
        bk, glk, gak = row_side(k, sk, row_body, row_lin0, row_ang0, row_lin1, row_ang1)
        if bk >= 0:
            for sl in range(2):
                bl, gll, gal = row_side(l, sl, row_body, row_lin0, row_ang0, row_lin1, row_ang1)
                if bl == bk:
                    angular = wp.dot(gak, symmetric_times(inv_inertia_world[bk], gal))
                    free += body_inv_mass[bk] * wp.dot(glk, gll) + angular
    held = free
    i = wp.int32(0)
    while i < nc:
        held -= wp.dot(row_coupling[k * nc + i], row_response[l * nc + i])
        i += 1
    if k == l:
        held = wp.max(held, f64(1.0e-9) * free) + REGULARIZATION * free
    return held


@wp.kernel
def row_matrix(
    # Model:
    body_inv_mass: wp.array(dtype=f64),
    constraint_body0: wp.array(dtype=int),
    # Data in:
    inv_inertia_world_in: wp.array(dtype=sym33d),
    row_count: wp.array(dtype=int),
    row_body: wp.array(dtype=wp.vec2i),
    row_lin0: wp.array(dtype=vec3d),
    row_ang0: wp.array(dtype=vec3d),
    row_lin1: wp.array(dtype=vec3d),
    row_ang1: wp.array(dtype=vec3d),
    row_coupling: wp.array(dtype=vec3d),
    row_response: wp.array(dtype=vec3d),
    span: int,
    # Data out: S, row-major with the row count as its stride
    row_matrix_out: wp.array(dtype=f64),
):
    """S's entries (k, l) of the active rows (`row_matrix_entry`) for the `span` columns l from j span of thread
    (k, j): one each on a GPU, all of them on a CPU (as `row_coupling`)."""
    k, j = wp.tid()
    n = row_count[0]
    if k >= n:
        return
    nc = constraint_body0.shape[0]
    l = j * span
    while l < wp.min(n, (j + 1) * span):
        row_matrix_out[k * n + l] = row_matrix_entry(
            k, l, body_inv_mass, nc, inv_inertia_world_in, row_body, row_lin0, row_ang0, row_lin1, row_ang1,
            row_coupling, row_response,
        )  # fmt: skip
        l += 1


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
    inv_inertia_world: wp.array(dtype=sym33d),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Row r's impulse `amount` on its bodies: M^-1 g^T amount."""
    for side in range(2):
        b, g_lin, g_ang = row_side(r, side, row_body, row_lin0, row_ang0, row_lin1, row_ang1)
        if b >= 0:
            body_v[b] = body_v[b] + g_lin * (amount * body_inv_mass[b])
            body_w[b] = body_w[b] + symmetric_times(inv_inertia_world[b], g_ang * amount)


@wp.func
def contact_row_of(r: int, limit_count: int, row_contact: wp.array(dtype=int)) -> int:
    """The contact of row r (a contact's row)."""
    return row_contact[(r - limit_count) // 3]


@wp.func
def contact_sweeps(
    nr: int,
    nl: int,
    h: f64,
    tolerance: f64,
    max_sweeps: int,
    matrix: wp.array(dtype=f64),
    goal: wp.array(dtype=f64),
    before: wp.array(dtype=f64),
    delta: wp.array(dtype=f64),
    mask: wp.array(dtype=int),
    row_contact: wp.array(dtype=int),
    contact_material: wp.array(dtype=wp.vec2d),
    y: wp.array(dtype=f64),
) -> int:
    """Projected Gauss-Seidel sweeps over the contacts' rows nl.. nl + nr on their system `matrix` (nr x nr, the
    limits and motors that hold eliminated) from the current deltas, until no row moves by more than `tolerance`
    (m) over the step: a normal pushes only, the two tangents as one block within the disc of mu lambda_n.
    Returns the sweeps taken."""
    c = wp.int32(0)
    while c < nr:
        v = f64(0.0)
        e = wp.int32(0)
        while e < nr:
            v += matrix[c * nr + e] * delta[nl + e]
            e += 1
        y[c] = v
        c += 1
    taken = int(0)
    sweep = wp.int32(0)
    while sweep < max_sweeps:
        taken += 1
        change = f64(0.0)
        i = wp.int32(0)
        while i < nr:
            c = i
            if sweep % 2 == 1:
                c = nr - 3 - i  # symmetric Gauss-Seidel
            if mask[nl + c] != 0:
                diag = matrix[c * nr + c]
                total = wp.max(before[nl + c] + delta[nl + c] + (goal[c] - y[c]) / diag, f64(0.0))
                step = total - before[nl + c] - delta[nl + c]
                delta[nl + c] = delta[nl + c] + step
                e = wp.int32(0)
                while e < nr:
                    y[e] = y[e] + matrix[e * nr + c] * step
                    e += 1
                change = wp.max(change, wp.abs(step) * diag)
                limit = contact_material[row_contact[c // 3]][0] * total
                f = c + 1
                a = matrix[f * nr + f]
                b = matrix[f * nr + f + 1]
                d = matrix[(f + 1) * nr + f + 1]
                e0 = goal[f] - y[f]
                e1 = goal[f + 1] - y[f + 1]
                # The block's own solve where it sticks (inside the disc); else a step of the block's largest
                # eigenvalue along the slip left, onto the disc: at convergence a sliding contact's impulse
                # points against its slip (the block's solve, projected, would turn it).
                old = vec2d(before[nl + f] + delta[nl + f], before[nl + f + 1] + delta[nl + f + 1])
                det = a * d - b * b
                t = old + vec2d(e0 / a, e1 / d)
                if det > f64(1.0e-12) * a * d:
                    t = old + vec2d(d * e0 - b * e1, a * e1 - b * e0) / det
                if wp.length(t) > limit:
                    half = f64(0.5) * (a - d)
                    top = f64(0.5) * (a + d) + wp.sqrt(half * half + b * b)
                    t = old + vec2d(e0, e1) / top
                    size = wp.length(t)
                    if size > limit:
                        t = t * (limit / size)
                step0 = t[0] - before[nl + f] - delta[nl + f]
                step1 = t[1] - before[nl + f + 1] - delta[nl + f + 1]
                delta[nl + f] = delta[nl + f] + step0
                delta[nl + f + 1] = delta[nl + f + 1] + step1
                e = wp.int32(0)
                while e < nr:
                    y[e] = y[e] + matrix[e * nr + f] * step0 + matrix[e * nr + f + 1] * step1
                    e += 1
                change = wp.max(change, wp.max(wp.abs(step0) * a, wp.abs(step1) * d))
            i += 3
        if change * h <= tolerance:
            break
        sweep += 1
    return taken


@wp.kernel
def solve_rows(
    # Model:
    h: f64,
    limit_count: int,
    body_inv_mass: wp.array(dtype=f64),
    constraint_kind: wp.array(dtype=int),
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
    tolerance: f64,
    max_sweeps: int,
    bounce_speed: f64,
    # Data in:
    drive_target: wp.array(dtype=f64),
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
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
    row_work: wp.array(dtype=f64),
    row_scratch: wp.array(dtype=f64),
    row_free: wp.array(dtype=int),
    row_column: wp.array(dtype=f64),
    row_y: wp.array(dtype=f64),
    row_solved: wp.array(dtype=f64),
    row_reduced: wp.array(dtype=f64),
    row_reduced_goal: wp.array(dtype=f64),
    contact_error: wp.array(dtype=f64),
):
    """Every row at once (one thread) on the rows' system S (module docstring): the limits and motors that hold
    eliminated, the contacts swept until no row moves by more than `tolerance` (m) over the step or
    `max_sweeps` (a round), then the limits' and motors' bounds; contact_error[1 + velocity] = the sweeps.

    Position pass (`velocity` 0, at t0, on the prediction just measured): a limit or motor as
    `limits.correct_rows` wants it; a contact's gap g' = g + h n . du >= 0, pushing only; its slip over the step
    (the slip measured + du_t) stopped within mu lambda_n. Velocity pass (1, at t0 + h, after
    `contact_solve.solve_velocities` measured the gaps and arms there): a limit or motor as `correct_rows`
    wants it, a contact's normal velocity as `solve_velocities` wants it, its tangential velocity stopped within
    mu times this phase's normal impulse. The impulses go to the bodies with the joints' reaction, and into
    the step's totals of their phase."""
    n = row_count[0]
    nl = limit_count
    i = wp.int32(0)
    while i < nl:
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
        i += 1
    r = nl
    while r < n:
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
        tangential = s1 * lam[1] + wp.cross(nrm, s1) * lam[2]
        row_before[r] = lam[0]
        for axis in range(3):
            row_mask[r + axis] = active
            row_delta[r + axis] = f64(0.0)
            if axis > 0:
                d = row_direction[r + axis]
                row_goal[r + axis] = -wp.dot(d, slip)
                row_before[r + axis] = wp.dot(d, tangential)
        r += 3
    # The limits and motors that hold (mask 1) eliminated exactly, the contacts by projected Gauss-Seidel on
    # what is left; then a limit or motor out of its bounds is fixed at them, or a fixed one freed, and again.
    nr = n - nl
    sweeps = int(0)
    _round = wp.int32(0)
    while _round < 2 * nl + 2:
        i = wp.int32(0)
        while i < nl:
            row_free[i] = wp.where(row_mask[i] == 1, 1, 0)
            i += 1
        factor_masked(nl, n, row_matrix, row_free, row_work)
        c = wp.int32(0)
        while c < nr:  # X_c = S_mm^-1 S_mc
            i = wp.int32(0)
            while i < nl:
                row_column[i] = row_matrix[i * n + nl + c]
                row_solved[c * nl + i] = f64(0.0)
                i += 1
            solve_factored(nl, row_work, row_free, row_column, row_scratch, row_solved, c * nl)
            c += 1
        i = wp.int32(0)
        while i < nl:  # the free rows' own solution, the fixed rows' impulses counted
            want = row_goal[i]
            j = wp.int32(0)
            while j < nl:
                if row_mask[j] >= 2:
                    want -= row_matrix[i * n + j] * row_delta[j]
                j += 1
            row_column[i] = want
            row_y[i] = f64(0.0)
            i += 1
        solve_factored(nl, row_work, row_free, row_column, row_scratch, row_y, 0)
        c = wp.int32(0)
        while c < nr:  # the contacts' system with the free rows holding
            want = row_goal[nl + c]
            j = wp.int32(0)
            while j < nl:
                if row_mask[j] >= 2:
                    want -= row_matrix[(nl + c) * n + j] * row_delta[j]
                elif row_free[j] == 1:
                    want -= row_matrix[(nl + c) * n + j] * row_y[j]
                j += 1
            row_reduced_goal[c] = want
            e = wp.int32(0)
            while e < nr:
                v = row_matrix[(nl + c) * n + nl + e]
                i = wp.int32(0)
                while i < nl:
                    if row_free[i] == 1:
                        v -= row_matrix[(nl + c) * n + i] * row_solved[e * nl + i]
                    i += 1
                row_reduced[c * nr + e] = v
                e += 1
            c += 1
        sweeps += contact_sweeps(
            nr, nl, h, tolerance, max_sweeps, row_reduced, row_reduced_goal, row_before, row_delta, row_mask,
            row_contact, contact_material, row_column,
        )  # fmt: skip
        i = wp.int32(0)
        while i < nl:
            if row_free[i] == 1:
                held = row_y[i]
                c = wp.int32(0)
                while c < nr:
                    held -= row_solved[c * nl + i] * row_delta[nl + c]
                    c += 1
                row_delta[i] = held
            i += 1
        worst = tolerance / h  # a rate the contacts' sweeps may leave: no pivot on less
        pick = fix_furthest_out(nl, n, row_matrix, row_mask, row_before, row_low, row_high, row_delta, worst)
        if pick < 0:
            i = wp.int32(0)
            while i < nl:
                if row_mask[i] >= 2:
                    demand = row_goal[i]  # the rate change still wanted at fixed row i, all impulses counted
                    j = wp.int32(0)
                    while j < n:
                        if row_mask[j] != 0:
                            demand -= row_matrix[i * n + j] * row_delta[j]
                        j += 1
                    inward = wp.where(row_mask[i] == 2, demand, -demand)
                    if inward > worst:
                        worst = inward
                        pick = i
                i += 1
            if pick < 0:
                break
            row_mask[pick] = 1
        _round += 1
    r = wp.int32(0)
    while r < n:
        amount = row_delta[r]
        if amount != f64(0.0):
            push_row(r, amount, row_body, row_lin0, row_ang0, row_lin1, row_ang1, body_inv_mass,
                     inv_inertia_world_in, body_v, body_w)  # fmt: skip
            compensate(r, amount, constraint_kind, constraint_body0, constraint_body1, body_inv_mass,
                       inv_inertia_world_in, jac_lin_in, jac_ang_in, jac_skew_in, row_response, body_v,
                       body_w)  # fmt: skip
        r += 1
    i = wp.int32(0)
    while i < nl:
        if velocity == 0:
            limit_impulse[i] = limit_impulse[i] + row_delta[i]
        else:
            limit_velocity_impulse[i] = limit_velocity_impulse[i] + row_delta[i]
        i += 1
    contact_error[1 + velocity] = f64(sweeps)
    r = nl
    while r < n:
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
        r += 3
