"""Forces that depend on the state, inside the prediction (method paper, sections 3 and 4.4).

Springs, dampers and servo motors change with the poses and velocities, so the prediction evaluates them
at every RK4 stage, and a spring couples the bodies it joins: the prediction of a scene with such force
elements advances all bodies together, stage by stage:

    for each stage k: element wrenches at the stage state  ->  every body's derivative and its next stage
    state (or, after stage 4, the predicted state).

Each element writes the wrench on each of its two sides (rows 2 e + side); a body gathers its rows, so
the sum needs no atomics and has the same order on every device. Scenes without elements keep the
single-body prediction of `rigid.predict`.
"""

import warp as wp

from .constraints import pose_q, pose_x
from .inertia import sym33d, symmetric_times

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
quatd = wp.quatd
mat33d = wp.mat33d
f64 = wp.float64

ANGLE_COORDINATE = wp.constant(0)  # revolute; 1 is a prismatic offset
DISTANCE_COORDINATE = wp.constant(2)  # the distance between two anchors (`SceneBuilder.add_distance`)
VELOCITY_MODE = wp.constant(1)
EFFORT_MODE = wp.constant(2)


@wp.func
def pose_v(b: int, vs: wp.array(dtype=vec3d)) -> vec3d:
    """A body's (linear or angular) velocity; the world's is zero."""
    if b < 0:
        return vec3d()
    return vs[b]


@wp.func
def coordinate_axis(
    coordinate: int, x0: vec3d, q0: quatd, x1: vec3d, q1: quatd, anchor0: vec3d, anchor1: vec3d, axis0: vec3d
):
    """(world axis, world point B) of a joint coordinate: all that a force along it (or a torque about it) needs,
    without its value's arc tangent."""
    a = wp.quat_rotate(q0, axis0)
    b = x1 + wp.quat_rotate(q1, anchor1)
    if coordinate == DISTANCE_COORDINATE:
        gap = b - (x0 + wp.quat_rotate(q0, anchor0))
        length = wp.length(gap)
        if length > f64(1.0e-12):
            a = gap / length
    return a, b


@wp.func
def coordinate_value(
    coordinate: int,
    x0: vec3d, q0: quatd, v0: vec3d, w0: vec3d,
    x1: vec3d, q1: quatd, v1: vec3d, w1: vec3d,
    anchor0: vec3d, axis0: vec3d, rest_rotation: quatd, a: vec3d, b: vec3d,
):  # fmt: skip
    """(value, rate) of a joint coordinate of world axis a and world point B b (`coordinate_axis`).

    Angle (rad): the rotation of q0^-1 q1 rest^-1 about axis0, in (-pi, pi]; rate = (w1 - w0) . axis.
    Offset (m): (B - A) . axis with A on body0 and B on body1; rate = (u_B - u_B0) . axis, the velocity of B
    on body1 against the point of body0 at B, which makes (force x rate) the power of the pair.
    Distance (m): |B - A|, an offset along the unit axis (B - A) / |B - A| (body0's axis0 while A and B meet).
    A push along that axis acts on body0 with the same moment at B as at A, B - A being parallel to it."""
    if coordinate == ANGLE_COORDINATE:
        d = wp.quat_inverse(q0) * q1 * wp.quat_inverse(rest_rotation)
        s = wp.dot(vec3d(d[0], d[1], d[2]), axis0)
        c = d[3]
        if c < f64(0.0):
            s = -s
            c = -c
        return f64(2.0) * wp.atan2(s, c), wp.dot(w1 - w0, a)
    p = x0 + wp.quat_rotate(q0, anchor0)
    u1 = v1 + wp.cross(w1, b - x1)
    u0 = v0 + wp.cross(w0, b - x0)
    return wp.dot(b - p, a), wp.dot(u1 - u0, a)


@wp.func
def coordinate_row_axis(
    r: int,
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
):
    """`coordinate_axis` of coordinate row r at the given poses: (world axis, world point B)."""
    b0 = coordinate_body0[r]
    b1 = coordinate_body1[r]
    return coordinate_axis(
        coordinate_kind[r], pose_x(b0, body_x), pose_q(b0, body_q), pose_x(b1, body_x), pose_q(b1, body_q),
        coordinate_anchor0[r], coordinate_anchor1[r], coordinate_axis0[r],
    )  # fmt: skip


@wp.func
def coordinate_row_value(
    r: int,
    a: vec3d,
    b: vec3d,
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    coordinate_rest_rotation: wp.array(dtype=quatd),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """`coordinate_value` of coordinate row r at the given state, its axis a and point b
    (`coordinate_row_axis`): (value, rate)."""
    b0 = coordinate_body0[r]
    b1 = coordinate_body1[r]
    return coordinate_value(
        coordinate_kind[r], pose_x(b0, body_x), pose_q(b0, body_q), pose_v(b0, body_v), pose_v(b0, body_w),
        pose_x(b1, body_x), pose_q(b1, body_q), pose_v(b1, body_v), pose_v(b1, body_w),
        coordinate_anchor0[r], coordinate_axis0[r], coordinate_rest_rotation[r], a, b,
    )  # fmt: skip


@wp.func
def coordinate_row(
    r: int,
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
    """(value, rate, world axis, world point B) of coordinate row r at the given state: `coordinate_row_axis`,
    then `coordinate_row_value` with them."""
    a, b = coordinate_row_axis(
        r, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0, coordinate_anchor1,
        coordinate_axis0, body_x, body_q,
    )  # fmt: skip
    value, rate = coordinate_row_value(
        r, a, b, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0, coordinate_axis0,
        coordinate_rest_rotation, body_x, body_q, body_v, body_w,
    )  # fmt: skip
    return value, rate, a, b


@wp.func
def angle_near(x: f64, centre: f64) -> f64:
    """x plus whole turns, in (centre - pi, centre + pi] (rad); x itself, bit for bit, where it lies there."""
    pi = f64(3.141592653589793)
    return x - f64(2.0) * pi * wp.floor((x - centre + pi) / (f64(2.0) * pi))


@wp.func
def wrap_angle(x: f64) -> f64:
    """x in (-pi, pi]."""
    return angle_near(x, f64(0.0))


@wp.func
def drive_output(
    coordinate: int, mode: int, value: f64, rate: f64, target: f64, gains: vec3d, max_force: f64, integral: f64
) -> f64:
    """The PID output (N m or N) of a drive, gains = (kp, ki, kd), clamped to +-max_force; in effort mode the
    target itself."""
    if mode == EFFORT_MODE:
        out = target
    elif mode == VELOCITY_MODE:
        out = gains[0] * (target - rate) + gains[1] * integral
    else:
        e = target - value
        if coordinate == ANGLE_COORDINATE:
            e = wrap_angle(e)
        out = gains[0] * e + gains[1] * integral - gains[2] * rate
    return wp.clamp(out, -max_force, max_force)


@wp.func
def drive_error(coordinate: int, mode: int, value: f64, rate: f64, target: f64) -> f64:
    """The error the PID integrates: target - value (position) or target - rate (velocity)."""
    if mode == VELOCITY_MODE:
        return target - rate
    e = target - value
    if coordinate == ANGLE_COORDINATE:
        e = wrap_angle(e)
    return e


@wp.func
def spring_wrench(
    e: int,
    spring_body0: wp.array(dtype=int),
    spring_body1: wp.array(dtype=int),
    spring_anchor0: wp.array(dtype=vec3d),
    spring_anchor1: wp.array(dtype=vec3d),
    spring_params: wp.array(dtype=vec3d),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    wrench_force: wp.array(dtype=vec3d),
    wrench_torque: wp.array(dtype=vec3d),
):
    """Spring e's wrenches (rows 2 e + side) at the given state: f = -k (L - L0) - c dL/dt along the unit vector
    n from A (body0) to B (body1): f n on body1 at B, -f n on body0 at A. Both act along one line, so momentum
    and angular momentum are kept."""
    b0 = spring_body0[e]
    b1 = spring_body1[e]
    x0 = pose_x(b0, body_x)
    x1 = pose_x(b1, body_x)
    pa = x0 + wp.quat_rotate(pose_q(b0, body_q), spring_anchor0[e])
    pb = x1 + wp.quat_rotate(pose_q(b1, body_q), spring_anchor1[e])
    ua = pose_v(b0, body_v) + wp.cross(pose_v(b0, body_w), pa - x0)
    ub = pose_v(b1, body_v) + wp.cross(pose_v(b1, body_w), pb - x1)
    k = spring_params[e]
    d = pb - pa
    length = wp.length(d)
    f = -k[0] * d  # a spring of rest length 0 at coincident points: no direction needed
    if length > f64(1.0e-12):
        n = d / length
        f = n * (-k[0] * (length - k[2]) - k[1] * wp.dot(ub - ua, n))
    wrench_force[2 * e] = -f
    wrench_torque[2 * e] = wp.cross(pa - x0, -f)
    wrench_force[2 * e + 1] = f
    wrench_torque[2 * e + 1] = wp.cross(pb - x1, f)


@wp.kernel
def spring_wrenches(
    # Model:
    spring_body0: wp.array(dtype=int),
    spring_body1: wp.array(dtype=int),
    spring_anchor0: wp.array(dtype=vec3d),
    spring_anchor1: wp.array(dtype=vec3d),
    spring_params: wp.array(dtype=vec3d),  # stiffness N/m, damping N s/m, rest length m
    # Data in: the stage state
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    # Data out: rows 2 e + side from row 0
    wrench_force_out: wp.array(dtype=vec3d),
    wrench_torque_out: wp.array(dtype=vec3d),
):
    """Every spring's wrenches (`spring_wrench`)."""
    spring_wrench(
        wp.tid(), spring_body0, spring_body1, spring_anchor0, spring_anchor1, spring_params, body_x_in, body_q_in,
        body_v_in, body_w_in, wrench_force_out, wrench_torque_out,
    )  # fmt: skip


@wp.func
def reciprocal(a: vec3d, b: vec3d, c: vec3d, count: int) -> vec3d:
    """The direction d with d . a = 1 and d . b = d . c = 0 in the span of a and the `count` (0, 1 or 2) others
    b, c: a torque (force) along d does work on a chain's coordinate of axis a only, none on the others'."""
    if count == 0:
        return a
    if count == 1:
        n = a - wp.dot(a, b) * b
        return n / wp.dot(n, a)
    n = wp.cross(b, c)
    return n / wp.dot(a, n)


@wp.func
def coordinate_geometry(
    i: int,
    drive_rows: wp.array(dtype=int),
    drive_row_point: wp.array(dtype=int),
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    coordinate_world_axis: wp.array(dtype=vec3d),
    coordinate_world_point: wp.array(dtype=vec3d),
):
    """`coordinate_row_axis` of the i-th coordinate row the force drives read (`Model.drive_rows`) at the given
    poses, kept at the row for the stage's drives (`drive_wrench`): a row is read by every drive on it and on its
    chain, several times a stage where each drive formed it anew (the dm_control humanoid: 21 rows, ~116 forms).
    The point only where a drive reads it (`drive_row_point`, every row but a hinge's that is no force's anchor):
    a torque needs the axis alone."""
    r = drive_rows[i]
    if drive_row_point[i] != 0:
        a, b = coordinate_row_axis(
            r, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0, coordinate_anchor1,
            coordinate_axis0, body_x, body_q,
        )  # fmt: skip
        coordinate_world_axis[r] = a
        coordinate_world_point[r] = b
    else:  # an angle's axis, as `coordinate_axis` forms it
        coordinate_world_axis[r] = wp.quat_rotate(pose_q(coordinate_body0[r], body_q), coordinate_axis0[r])


@wp.kernel
def coordinate_geometries(
    # Model:
    drive_rows: wp.array(dtype=int),
    drive_row_point: wp.array(dtype=int),
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    # Data in: the stage state
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    # Data out: at the rows of drive_rows
    coordinate_world_axis: wp.array(dtype=vec3d),
    coordinate_world_point: wp.array(dtype=vec3d),
):
    """Every coordinate row's world axis and point that the force drives read (`coordinate_geometry`)."""
    coordinate_geometry(
        wp.tid(), drive_rows, drive_row_point, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0,
        coordinate_anchor1, coordinate_axis0, body_x_in, body_q_in, coordinate_world_axis, coordinate_world_point,
    )  # fmt: skip


@wp.func
def chain_direction(
    r: int,
    a: vec3d,
    point: vec3d,
    chain: wp.vec3i,
    coordinate_world_axis: wp.array(dtype=vec3d),
    coordinate_world_point: wp.array(dtype=vec3d),
):
    """(direction, point) of a drive's wrench on coordinate row r of axis a and point B `point`: `reciprocal` to
    the world axes of the chain's other coordinates of its kind (rows chain[0], chain[1], -1 for none), and the
    world anchor of row chain[2] (where a force along a chain with hinges does no work on them: their common
    anchor; row r's own point where chain[2] is r, a drive on no chain); the rows' axes and points at the stage
    state (`coordinate_geometry`)."""
    b = vec3d()
    c = vec3d()
    count = int(0)
    if chain[0] >= 0:
        b = coordinate_world_axis[chain[0]]
        count = 1
    if chain[1] >= 0:
        c = coordinate_world_axis[chain[1]]
        count = 2
    anchor = point
    if chain[2] != r:
        anchor = coordinate_world_point[chain[2]]
    return reciprocal(a, b, c, count), anchor


@wp.func
def drive_wrench(
    e: int,
    row_offset: int,
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    coordinate_rest_rotation: wp.array(dtype=quatd),
    drive_element: wp.array(dtype=int),
    drive_coordinate: wp.array(dtype=int),
    drive_chain: wp.array(dtype=wp.vec3i),
    drive_ends: wp.array(dtype=wp.vec2i),
    drive_mode: wp.array(dtype=int),
    drive_gains: wp.array(dtype=vec3d),
    drive_max_force: wp.array(dtype=f64),
    drive_target: wp.array(dtype=f64),
    drive_integral: wp.array(dtype=f64),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    coordinate_world_axis: wp.array(dtype=vec3d),
    coordinate_world_point: wp.array(dtype=vec3d),
    wrench_force: wp.array(dtype=vec3d),
    wrench_torque: wp.array(dtype=vec3d),
):
    """Drive element e's wrenches (rows 2 (row_offset + e) + side) at the given state, its coordinate rows' world
    axes and points at it (`coordinate_geometry`), with the integral of the step's start: the torque tau about the
    axis (+tau on body1, -tau on body0), or the force f along the axis at B (+f on body1, -f on body0 at the same
    point, so no net couple). A drive on a joint of a chain of joints through light bodies
    (`SceneBuilder.chain_joints`) acts on the chain's two ends (drive_ends) along the `chain_direction` instead:
    the same work on its coordinate, none on the others', so that the light bodies take no force (an explicit
    force on a body of almost no inertia would make the prediction unstable)."""
    i = drive_element[e]
    r = drive_coordinate[i]
    a = coordinate_world_axis[r]
    pb = coordinate_world_point[r]
    kind = coordinate_kind[r]
    mode = drive_mode[i]
    value = f64(0.0)
    rate = f64(0.0)
    if mode != EFFORT_MODE:  # an effort is its target: it needs the coordinate's axis, not its value or rate
        value, rate = coordinate_row_value(
            r, a, pb, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0, coordinate_axis0,
            coordinate_rest_rotation, body_x, body_q, body_v, body_w,
        )  # fmt: skip
    out = drive_output(kind, mode, value, rate, drive_target[i], drive_gains[i], drive_max_force[i], drive_integral[i])
    row = 2 * (row_offset + e)
    if out == f64(0.0):  # no push (an effort motor at 0 beside springs that act): no direction to find
        for side in range(2):
            wrench_force[row + side] = vec3d()
            wrench_torque[row + side] = vec3d()
        return
    a, pb = chain_direction(r, a, pb, drive_chain[i], coordinate_world_axis, coordinate_world_point)
    ends = drive_ends[i]
    if kind == ANGLE_COORDINATE:
        wrench_force[row] = vec3d()
        wrench_torque[row] = -out * a
        wrench_force[row + 1] = vec3d()
        wrench_torque[row + 1] = out * a
    else:
        f = out * a
        wrench_force[row] = -f
        wrench_torque[row] = wp.cross(pb - pose_x(ends[0], body_x), -f)
        wrench_force[row + 1] = f
        wrench_torque[row + 1] = wp.cross(pb - pose_x(ends[1], body_x), f)


@wp.kernel
def drive_wrenches(
    # Model:
    row_offset: int,
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    coordinate_rest_rotation: wp.array(dtype=quatd),
    drive_element: wp.array(dtype=int),
    drive_coordinate: wp.array(dtype=int),
    drive_chain: wp.array(dtype=wp.vec3i),
    drive_ends: wp.array(dtype=wp.vec2i),
    drive_mode: wp.array(dtype=int),
    drive_gains: wp.array(dtype=vec3d),
    drive_max_force: wp.array(dtype=f64),
    # Data in: control, the integral at the step's start, the stage state and its coordinate rows' axes and points
    drive_target: wp.array(dtype=f64),
    drive_integral: wp.array(dtype=f64),
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    coordinate_world_axis: wp.array(dtype=vec3d),
    coordinate_world_point: wp.array(dtype=vec3d),
    # Data out: rows 2 (row_offset + e) + side
    wrench_force_out: wp.array(dtype=vec3d),
    wrench_torque_out: wp.array(dtype=vec3d),
):
    """Every drive element's wrenches (`drive_wrench`), after `coordinate_geometries` at the same state."""
    drive_wrench(
        wp.tid(), row_offset, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0,
        coordinate_anchor1, coordinate_axis0, coordinate_rest_rotation, drive_element, drive_coordinate, drive_chain,
        drive_ends, drive_mode, drive_gains, drive_max_force, drive_target, drive_integral, body_x_in, body_q_in,
        body_v_in, body_w_in, coordinate_world_axis, coordinate_world_point, wrench_force_out, wrench_torque_out,
    )  # fmt: skip


@wp.func
def integrate_drive(
    e: int,
    h: f64,
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    coordinate_rest_rotation: wp.array(dtype=quatd),
    drive_coordinate: wp.array(dtype=int),
    drive_mode: wp.array(dtype=int),
    drive_gains: wp.array(dtype=vec3d),
    drive_max_force: wp.array(dtype=f64),
    drive_target: wp.array(dtype=f64),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    drive_integral: wp.array(dtype=f64),
):
    """Drive e's PID integral += h e(t0 + h) at the state given (the end of the step), held constant within a
    step; clamped so that ki |integral| stays within max_force (anti wind-up)."""
    ki = drive_gains[e][1]
    if ki == f64(0.0):
        return
    r = drive_coordinate[e]
    value, rate, a, pb = coordinate_row(
        r, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0, coordinate_anchor1,
        coordinate_axis0, coordinate_rest_rotation, body_x, body_q, body_v, body_w,
    )  # fmt: skip
    bound = drive_max_force[e] / ki
    integral = drive_integral[e] + h * drive_error(coordinate_kind[r], drive_mode[e], value, rate, drive_target[e])
    drive_integral[e] = wp.clamp(integral, -bound, bound)


@wp.kernel
def integrate_drives(
    # Model:
    h: f64,
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    coordinate_rest_rotation: wp.array(dtype=quatd),
    drive_coordinate: wp.array(dtype=int),
    drive_mode: wp.array(dtype=int),
    drive_gains: wp.array(dtype=vec3d),
    drive_max_force: wp.array(dtype=f64),
    # Data in: control and the state at the end of the step
    drive_target: wp.array(dtype=f64),
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    # Data out:
    drive_integral: wp.array(dtype=f64),
):
    """Every drive's integral (`integrate_drive`)."""
    integrate_drive(
        wp.tid(), h, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0, coordinate_anchor1,
        coordinate_axis0, coordinate_rest_rotation, drive_coordinate, drive_mode, drive_gains, drive_max_force,
        drive_target, body_x_in, body_q_in, body_v_in, body_w_in, drive_integral,
    )  # fmt: skip


@wp.func
def body_derivative(
    q: quatd, v: vec3d, w: vec3d, inv_mass: f64, inertia: mat33d, inv_inertia: mat33d, force: vec3d, torque: vec3d,
    gravity: vec3d,
):  # fmt: skip
    """(dx, dv, dq, dw)/dt with the world angular velocity: equations 1-4 of the paper; dq/dt = 1/2 (w, 0) q
    and dw/dt = J~^-1 (tau - w x J~ w) with J~ = R J R^T, evaluated in the body frame: R J^-1 (tau_b - w_b x J w_b)
    with w_b = R^T w, tau_b = R^T tau (five products of a 3x3 and a vector, where forming J~ and J~^-1 took four
    of two 3x3s: the coupled prediction of the gymnasium ant 8% faster)."""
    wb = wp.quat_rotate_inv(q, w)  # the body frame's, where the inertia is constant
    dwb = inv_inertia * (wp.quat_rotate_inv(q, torque) - wp.cross(wb, inertia * wb))
    dq = f64(0.5) * (quatd(w[0], w[1], w[2], f64(0.0)) * q)
    return v, gravity + force * inv_mass, dq, wp.quat_rotate(q, dwb)


@wp.func
def gathered_wrench(
    b: int,
    force: vec3d,
    torque: vec3d,
    body_wrench_start: wp.array(dtype=int),
    body_wrench_rows: wp.array(dtype=int),
    wrench_force: wp.array(dtype=vec3d),
    wrench_torque: wp.array(dtype=vec3d),
):
    """(force, torque) plus body b's element wrench rows, in the rows' order (so the sum is the same on every
    device, without atomics)."""
    k = body_wrench_start[b]
    while k < body_wrench_start[b + 1]:
        r = body_wrench_rows[k]
        force += wrench_force[r]
        torque += wrench_torque[r]
        k += 1
    return force, torque


@wp.func
def rk4_stage_body(
    b: int,
    stage: int,
    h: f64,
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    gravity: vec3d,
    body_wrench_start: wp.array(dtype=int),
    body_wrench_rows: wp.array(dtype=int),
    start_x: wp.array(dtype=vec3d),
    start_q: wp.array(dtype=quatd),
    start_v: wp.array(dtype=vec3d),
    start_w: wp.array(dtype=vec3d),
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    body_force: wp.array(dtype=vec3d),
    body_torque: wp.array(dtype=vec3d),
    wrench_force: wp.array(dtype=vec3d),
    wrench_torque: wp.array(dtype=vec3d),
    rk4_sum_x: wp.array(dtype=vec3d),
    rk4_sum_q: wp.array(dtype=quatd),
    rk4_sum_v: wp.array(dtype=vec3d),
    rk4_sum_w: wp.array(dtype=vec3d),
    body_x_out: wp.array(dtype=vec3d),
    body_q_out: wp.array(dtype=quatd),
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
):
    """Stage `stage` (0-3) of classic RK4 for body b: k = f(stage state), sum += weight k, next stage = y0 + c k
    (c = h/2, h/2, h), and after the fourth stage y(t0 + h) = y0 + h/6 sum. Reads only body b's rows of the
    stage state, so the state out may be the state in."""
    inv_mass = body_inv_mass[b]
    if inv_mass == f64(0.0):
        body_x_out[b] = start_x[b]
        body_q_out[b] = start_q[b]
        body_v_out[b] = start_v[b]
        body_w_out[b] = start_w[b]
        return
    force, torque = gathered_wrench(
        b, body_force[b], body_torque[b], body_wrench_start, body_wrench_rows, wrench_force, wrench_torque
    )  # fmt: skip
    dx, dv, dq, dw = body_derivative(
        body_q_in[b], body_v_in[b], body_w_in[b], inv_mass, body_inertia[b], body_inv_inertia[b], force, torque, gravity
    )
    weight = f64(2.0)
    step = f64(0.5) * h
    if stage == 0 or stage == 3:
        weight = f64(1.0)
    if stage == 2:
        step = h
    if stage == 0:
        rk4_sum_x[b] = dx
        rk4_sum_q[b] = dq
        rk4_sum_v[b] = dv
        rk4_sum_w[b] = dw
    else:
        rk4_sum_x[b] = rk4_sum_x[b] + dx * weight
        rk4_sum_q[b] = rk4_sum_q[b] + dq * weight
        rk4_sum_v[b] = rk4_sum_v[b] + dv * weight
        rk4_sum_w[b] = rk4_sum_w[b] + dw * weight
    if stage == 3:
        sixth = h / f64(6.0)
        body_x_out[b] = start_x[b] + rk4_sum_x[b] * sixth
        body_q_out[b] = wp.normalize(start_q[b] + rk4_sum_q[b] * sixth)
        body_v_out[b] = start_v[b] + rk4_sum_v[b] * sixth
        body_w_out[b] = start_w[b] + rk4_sum_w[b] * sixth
    else:
        body_x_out[b] = start_x[b] + dx * step
        body_q_out[b] = wp.normalize(start_q[b] + dq * step)  # a rotation, for the elements and the next stage
        body_v_out[b] = start_v[b] + dv * step
        body_w_out[b] = start_w[b] + dw * step


@wp.func
def kick_body(
    b: int,
    dt: f64,
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia_world: wp.array(dtype=sym33d),
    body_wrench_start: wp.array(dtype=int),
    body_wrench_rows: wp.array(dtype=int),
    wrench_force: wp.array(dtype=vec3d),
    wrench_torque: wp.array(dtype=vec3d),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Body b's velocities after its element wrench rows act for dt (s) at its pose: dv = F dt / m,
    dw = I_world^-1 tau dt (world frame). The exact flow of forces that depend on the poses alone, which do not
    move while they act: half of the split step's kicks (`Simulator`'s `split_forces`, kernels/step.py)."""
    inv_mass = body_inv_mass[b]
    if inv_mass == f64(0.0):
        return
    force, torque = gathered_wrench(
        b, vec3d(), vec3d(), body_wrench_start, body_wrench_rows, wrench_force, wrench_torque
    )  # fmt: skip
    body_v[b] = body_v[b] + force * (inv_mass * dt)
    body_w[b] = body_w[b] + symmetric_times(inv_inertia_world[b], torque) * dt


@wp.kernel
def kick(
    # Model:
    body_inv_mass: wp.array(dtype=f64),
    body_wrench_start: wp.array(dtype=int),
    body_wrench_rows: wp.array(dtype=int),
    dt: f64,
    # Data in: the frames' world inverse inertias and the element wrenches at the state
    inv_inertia_world_in: wp.array(dtype=sym33d),
    wrench_force_in: wp.array(dtype=vec3d),
    wrench_torque_in: wp.array(dtype=vec3d),
    # Data out (updated in place):
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
):
    """Every body's half kick (`kick_body`)."""
    kick_body(
        wp.tid(), dt, body_inv_mass, inv_inertia_world_in, body_wrench_start, body_wrench_rows, wrench_force_in,
        wrench_torque_in, body_v_out, body_w_out,
    )  # fmt: skip


@wp.kernel
def rk4_stage(
    # Model:
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    gravity: vec3d,
    body_wrench_start: wp.array(dtype=int),
    body_wrench_rows: wp.array(dtype=int),
    stage: int,
    h: f64,
    # Data in: the state at t0 (start_*), the stage state, external and element wrenches
    start_x: wp.array(dtype=vec3d),
    start_q: wp.array(dtype=quatd),
    start_v: wp.array(dtype=vec3d),
    start_w: wp.array(dtype=vec3d),
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    body_force: wp.array(dtype=vec3d),
    body_torque: wp.array(dtype=vec3d),
    wrench_force: wp.array(dtype=vec3d),
    wrench_torque: wp.array(dtype=vec3d),
    # Data in/out: the weighted sum of the stage derivatives
    rk4_sum_x: wp.array(dtype=vec3d),
    rk4_sum_q: wp.array(dtype=quatd),
    rk4_sum_v: wp.array(dtype=vec3d),
    rk4_sum_w: wp.array(dtype=vec3d),
    # Data out: the next stage state (stages 0-2) or the prediction (stage 3)
    body_x_out: wp.array(dtype=vec3d),
    body_q_out: wp.array(dtype=quatd),
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
):
    """Stage `stage` of RK4 for every body at once (`rk4_stage_body`)."""
    rk4_stage_body(
        wp.tid(), stage, h, body_inv_mass, body_inertia, body_inv_inertia, gravity, body_wrench_start,
        body_wrench_rows, start_x, start_q, start_v, start_w, body_x_in, body_q_in, body_v_in, body_w_in, body_force,
        body_torque, wrench_force, wrench_torque, rk4_sum_x, rk4_sum_q, rk4_sum_v, rk4_sum_w, body_x_out,
        body_q_out, body_v_out, body_w_out,
    )  # fmt: skip


@wp.func
def turned(q: quatd, angle: vec3d) -> quatd:
    """q turned by the rotation vector `angle` (rad, world frame)."""
    length = wp.length(angle)
    if length == f64(0.0):
        return q
    return wp.normalize(wp.quat_from_axis_angle(angle / length, length) * q)


@wp.func
def skew(r: vec3d) -> mat33d:
    """[r]x: [r]x w = r x w."""
    return mat33d(f64(0.0), -r[2], r[1], r[2], f64(0.0), -r[0], -r[1], r[0], f64(0.0))


@wp.func
def body_mobility(
    b: int,
    point: vec3d,
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_inv_mass: wp.array(dtype=f64),
    body_inv_inertia: wp.array(dtype=mat33d),
):
    """(1/m, world J^-1, [point - x]x) of body b; zeros for the world or a static body."""
    if b < 0:
        return f64(0.0), mat33d(), mat33d()
    inv_mass = body_inv_mass[b]
    if inv_mass == f64(0.0):
        return f64(0.0), mat33d(), mat33d()
    r = wp.quat_to_matrix(body_q[b])
    return inv_mass, r * body_inv_inertia[b] * wp.transpose(r), skew(point - body_x[b])


@wp.func
def joint_response(
    angular: bool,
    a: vec3d,
    point: vec3d,
    b0: int,
    b1: int,
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_inv_mass: wp.array(dtype=f64),
    body_inv_inertia: wp.array(dtype=mat33d),
):
    """(k, rate_l, rate_a, dv0, dw0, dv1, dw1) of a coordinate of world axis a at `point` (a hinge's anchor, a
    slider's point B) with its own joint holding: k (1/(kg m^2) or 1/kg) the rate's change for a unit impulse on
    it; (rate_l, rate_a) the rate the joint's bodies have once their velocities are projected onto the joint
    (rate = rate_l . e_l + rate_a . e_a with e_l, e_a the point's relative velocity and the relative angular
    velocity); and (dv, dw) each body's velocity change for a unit change of the rate that leaves the joint's
    other five rows (those relative velocities, less the coordinate) unchanged.

    The six rows D (the point's relative velocity, then the relative angular velocity) have A = D M^-1 D^T with
    blocks A_ll = sum 1/m - [r]x J^-1 [r]x, A_la = sum -[r]x J^-1, A_aa = sum J^-1 (r = point - x, both bodies).
    The row impulse mu = A^-1 (0, a) (hinge) or A^-1 (a, 0) (slider) changes the coordinate's rate by 1 and the
    other five rows by 0; through the Schur complement S of the other block, mu's coordinate block is S^-1 a
    and k = 1 / (a . S^-1 a); the mass-weighted projection's rate is k mu . e. The articulated response can
    only be smaller (more rows hold), so k bounds it: the damper then keeps between none and all of its
    implicit Euler damping, never more."""
    m0, j0, x0 = body_mobility(b0, point, body_x, body_q, body_inv_mass, body_inv_inertia)
    m1, j1, x1 = body_mobility(b1, point, body_x, body_q, body_inv_mass, body_inv_inertia)
    eye = wp.identity(n=3, dtype=f64)
    a_ll = eye * (m0 + m1) - x0 * j0 * x0 - x1 * j1 * x1
    a_la = -(x0 * j0) - x1 * j1
    a_aa = j0 + j1
    if angular:
        s_inv = wp.inverse(a_aa - wp.transpose(a_la) * wp.inverse(a_ll) * a_la)
        mu_a = s_inv * a
        mu_l = -(wp.inverse(a_ll) * (a_la * mu_a))
    else:
        s_inv = wp.inverse(a_ll - a_la * wp.inverse(a_aa) * wp.transpose(a_la))
        mu_l = s_inv * a
        mu_a = -(wp.inverse(a_aa) * (wp.transpose(a_la) * mu_l))
    k = f64(1.0) / wp.dot(a, s_inv * a)
    # body i: (1/m mu_l, J^-1 ([r]x mu_l + mu_a)), body1 + and body0 -
    dv0 = -(mu_l * m0)
    dw0 = -(j0 * (x0 * mu_l + mu_a))
    dv1 = mu_l * m1
    dw1 = j1 * (x1 * mu_l + mu_a)
    return k, mu_l * k, mu_a * k, dv0, dw0, dv1, dw1


@wp.func
def damper_frame(
    r: int,
    chain: wp.vec3i,
    ends: wp.vec2i,
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
):
    """(direction, point, body0, body1) on which a damper on coordinate row r acts at the given poses: the row's
    world axis and point and its two bodies; on a chain of joints through light bodies (`SceneBuilder.chain_joints`;
    `chain` and `ends` are the drive's `drive_chain` and `drive_ends`), as the drive's wrench does (`drive_wrench`),
    the direction `reciprocal` to the chain's other axes of its kind, the chain's anchor and the chain's two ends,
    so that the damper's impulse, like its force, leaves the light bodies out and does no work on the chain's
    other coordinates (the rate along that direction is the coordinate's own rate)."""
    axes = mat33d()  # rows: the row's own axis, then the chain's others (zero where none)
    point = vec3d()
    count = int(0)
    k = int(0)
    while k < 4:
        row = r
        if k > 0:
            row = chain[k - 1]
        if row >= 0:
            a, b = coordinate_row_axis(
                row, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0, coordinate_anchor1,
                coordinate_axis0, body_x, body_q,
            )  # fmt: skip
            if k < 3:
                axes[k] = a
            if k == 0 or (k == 3 and row != r):
                point = b  # the chain's anchor where it has one other than the row's own
            if k == 1 or k == 2:
                count = k
        k += 1
    return reciprocal(axes[0], axes[1], axes[2], count), point, ends[0], ends[1]


@wp.kernel
def damper_rates(
    # Model:
    drive_coordinate: wp.array(dtype=int),
    drive_chain: wp.array(dtype=wp.vec3i),
    drive_ends: wp.array(dtype=wp.vec2i),
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    body_inv_mass: wp.array(dtype=f64),
    body_inv_inertia: wp.array(dtype=mat33d),
    # Data in:
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    # Data out:
    damper_k_out: wp.array(dtype=f64),
):
    """Every drive's k at the given state: its coordinate rate's change for a unit impulse on the two bodies
    its force acts on (`damper_frame`), predicted alone (1/(kg m^2) or 1/kg), which makes a damper of gain c a
    decay of rate c k in the explicit prediction; for the host to pick the dampers that go implicit
    (`dampers.pick`)."""
    i = wp.tid()
    r = drive_coordinate[i]
    a, point, b0, b1 = damper_frame(
        r, drive_chain[i], drive_ends[i], coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0,
        coordinate_anchor1, coordinate_axis0, body_x_in, body_q_in,
    )  # fmt: skip
    m0, j0, x0 = body_mobility(b0, point, body_x_in, body_q_in, body_inv_mass, body_inv_inertia)
    m1, j1, x1 = body_mobility(b1, point, body_x_in, body_q_in, body_inv_mass, body_inv_inertia)
    if coordinate_kind[r] == ANGLE_COORDINATE:
        damper_k_out[i] = wp.dot(a, (j0 + j1) * a)
    else:  # a force along a at the point: 1/m, and the turn of the arm r x a
        damper_k_out[i] = m0 + m1 + wp.dot(x0 * a, j0 * (x0 * a)) + wp.dot(x1 * a, j1 * (x1 * a))


@wp.func
def nudge(
    b: int,
    dv: vec3d,
    dw: vec3d,
    delta: f64,
    half: f64,
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Body b's predicted velocities changed by (dv, dw) times delta, its pose moved by them times `half` (a
    constant force over the step moves it by half its velocity change times h); the world (b < 0) stays."""
    if b >= 0:
        body_v[b] = body_v[b] + dv * delta
        body_w[b] = body_w[b] + dw * delta
        body_x[b] = body_x[b] + dv * half
        body_q[b] = turned(body_q[b], dw * half)


@wp.func
def implicit_damper(
    d: int,
    h: f64,
    damper_drive: wp.array(dtype=int),
    damper_gain: wp.array(dtype=f64),
    damper_spring: wp.array(dtype=f64),
    drive_coordinate: wp.array(dtype=int),
    drive_chain: wp.array(dtype=wp.vec3i),
    drive_ends: wp.array(dtype=wp.vec2i),
    drive_mode: wp.array(dtype=int),
    drive_target: wp.array(dtype=f64),
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    coordinate_rest_rotation: wp.array(dtype=quatd),
    body_inv_mass: wp.array(dtype=f64),
    body_inv_inertia: wp.array(dtype=mat33d),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Damper d of a stiff drive, implicit, on the prediction of a step of h (in place): the damper's force
    c (goal - rate) (goal 0 for a joint damper, the target rate of a velocity drive) held constant over the step
    at its value at the step's end, implicit Euler: with r the predicted end rate (the RK4 prediction without
    this damper) and k its response with its joint holding (`joint_response`), the rate changes by
    delta = c h k (goal - r) / (1 + c h k), so the end rate is (r + c h k goal) / (1 + c h k): stable and
    dissipative at any c h k. The constant force moves the poses by half the velocity change times h. Exact
    implicit Euler of the damper where nothing else holds the joint's bodies (a pendulum); on a chain the other
    joints add inertia, so it damps somewhat less than implicit Euler of the whole system; first order in the
    damper either way. A damper on a chain of joints through light bodies acts on the chain's ends along the
    direction its wrench takes (`damper_frame`), as if they were one joint of that coordinate: the chain's other
    coordinates are held through its impulse, which the joint correction then lets go.

    A stiff spring of the drive (a position drive's kp = s, stiff where h^2 s k > 4: `dampers.pick`) is taken
    with it: the held force is c (goal - r1) - s e1, e1 the coordinate's offset from the target at the step's end
    as implicit Euler has it (the predicted offset e plus h delta), so delta = h k (c (goal - r) - s e) / (1 + c h
    k + s h^2 k): stable at any step, the spring's oscillation damped where the step cannot follow it (h omega
    well over 1), first order."""
    i = damper_drive[d]
    r = drive_coordinate[i]
    a, point, b0, b1 = damper_frame(
        r, drive_chain[i], drive_ends[i], coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0,
        coordinate_anchor1, coordinate_axis0, body_x, body_q,
    )  # fmt: skip
    k, rate_l, rate_a, dv0, dw0, dv1, dw1 = joint_response(
        coordinate_kind[r] == ANGLE_COORDINATE, a, point, b0, b1, body_x, body_q, body_inv_mass, body_inv_inertia
    )
    # The predicted end rate as the velocity correction will leave it: the joint correction's impulses at t0 and
    # the free prediction leave the joint's bodies apart at the point (a pendulum's fall), which that
    # correction turns into rate; the rate read off the bodies alone misses it.
    v0 = pose_v(b0, body_v)
    w0 = pose_v(b0, body_w)
    w1 = pose_v(b1, body_w)
    gap = pose_v(b1, body_v) + wp.cross(w1, point - pose_x(b1, body_x)) - v0 - wp.cross(w0, point - pose_x(b0, body_x))
    rate = wp.dot(rate_l, gap) + wp.dot(rate_a, w1 - w0)
    goal = f64(0.0)
    if drive_mode[i] == VELOCITY_MODE:
        goal = drive_target[i]
    spring = damper_spring[d]
    offset = f64(0.0)
    if spring != f64(0.0):
        value, moving, axis, at = coordinate_row(
            r, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0, coordinate_anchor1,
            coordinate_axis0, coordinate_rest_rotation, body_x, body_q, body_v, body_w,
        )  # fmt: skip
        offset = value - drive_target[i]
        if coordinate_kind[r] == ANGLE_COORDINATE:
            offset = wrap_angle(offset)
    chk = damper_gain[d] * h * k
    delta = (chk * (goal - rate) - h * k * spring * offset) / (f64(1.0) + chk + h * h * k * spring)
    half = f64(0.5) * h * delta
    nudge(b1, dv1, dw1, delta, half, body_x, body_q, body_v, body_w)
    nudge(b0, dv0, dw0, delta, half, body_x, body_q, body_v, body_w)


@wp.func
def implicit_dampers_all(
    h: f64,
    damper_drive: wp.array(dtype=int),
    damper_gain: wp.array(dtype=f64),
    damper_spring: wp.array(dtype=f64),
    drive_coordinate: wp.array(dtype=int),
    drive_chain: wp.array(dtype=wp.vec3i),
    drive_ends: wp.array(dtype=wp.vec2i),
    drive_mode: wp.array(dtype=int),
    drive_target: wp.array(dtype=f64),
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    coordinate_rest_rotation: wp.array(dtype=quatd),
    body_inv_mass: wp.array(dtype=f64),
    body_inv_inertia: wp.array(dtype=mat33d),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Every implicit damper on the prediction, one after the other (Gauss-Seidel: each sees the velocities the
    ones before it left, so dampers that share a body need no atomics and give the same result on every
    device), `implicit_damper`."""
    d = wp.int32(0)
    while d < damper_drive.shape[0]:
        implicit_damper(
            d, h, damper_drive, damper_gain, damper_spring, drive_coordinate, drive_chain, drive_ends, drive_mode,
            drive_target, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0, coordinate_anchor1,
            coordinate_axis0, coordinate_rest_rotation, body_inv_mass, body_inv_inertia, body_x, body_q, body_v,
            body_w,
        )  # fmt: skip
        d += 1


@wp.kernel
def implicit_dampers(
    # Model:
    h: f64,
    damper_drive: wp.array(dtype=int),
    damper_gain: wp.array(dtype=f64),
    damper_spring: wp.array(dtype=f64),
    drive_coordinate: wp.array(dtype=int),
    drive_chain: wp.array(dtype=wp.vec3i),
    drive_ends: wp.array(dtype=wp.vec2i),
    drive_mode: wp.array(dtype=int),
    coordinate_kind: wp.array(dtype=int),
    coordinate_body0: wp.array(dtype=int),
    coordinate_body1: wp.array(dtype=int),
    coordinate_anchor0: wp.array(dtype=vec3d),
    coordinate_anchor1: wp.array(dtype=vec3d),
    coordinate_axis0: wp.array(dtype=vec3d),
    coordinate_rest_rotation: wp.array(dtype=quatd),
    body_inv_mass: wp.array(dtype=f64),
    body_inv_inertia: wp.array(dtype=mat33d),
    # Data in: control
    drive_target: wp.array(dtype=f64),
    # Data in/out: the prediction
    body_x_out: wp.array(dtype=vec3d),
    body_q_out: wp.array(dtype=quatd),
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
):
    """Every implicit damper on the prediction, on one thread (`implicit_dampers_all`)."""
    implicit_dampers_all(
        h, damper_drive, damper_gain, damper_spring, drive_coordinate, drive_chain, drive_ends, drive_mode,
        drive_target, coordinate_kind, coordinate_body0, coordinate_body1, coordinate_anchor0, coordinate_anchor1,
        coordinate_axis0, coordinate_rest_rotation, body_inv_mass, body_inv_inertia, body_x_out, body_q_out,
        body_v_out, body_w_out,
    )  # fmt: skip
