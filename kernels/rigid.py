"""Free rigid-body motion over one step (method paper, section 3, equations 1-4)."""

import warp as wp

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
quatd = wp.quatd
mat33d = wp.mat33d
f64 = wp.float64


@wp.func
def rotation_rate(q: quatd, w_body: vec3d) -> quatd:
    """q (w_body, 0) = 2 dq/dt: equation 3, with the angular velocity in body space, less its factor 1/2, which
    `rk4_rotation` folds into its step fractions (scaling by 1/2 is exact: the same values, 4 products fewer). The
    product is spelled out without the terms of the zero scalar part (Warp's quaternion product in that order)."""
    x = w_body[0]
    y = w_body[1]
    z = w_body[2]
    return quatd(
        q[3] * x + q[1] * z - y * q[2],
        q[3] * y + q[2] * x - z * q[0],
        q[3] * z + q[0] * y - x * q[1],
        -q[0] * x - q[1] * y - q[2] * z,
    )


@wp.func
def diagonal_times(m: mat33d, v: vec3d) -> vec3d:
    """m v for a diagonal m, its zeros skipped (the same value)."""
    return vec3d(m[0, 0] * v[0], m[1, 1] * v[1], m[2, 2] * v[2])


@wp.func
def is_diagonal(m: mat33d) -> bool:
    z = f64(0.0)
    return m[0, 1] == z and m[0, 2] == z and m[1, 0] == z and m[1, 2] == z and m[2, 0] == z and m[2, 1] == z


@wp.func
def angular_acceleration(
    q: quatd, w_body: vec3d, inertia: mat33d, inv_inertia: mat33d, torque: vec3d, diagonal: bool
) -> vec3d:
    """Equation 4 in body space, with the gyroscopic term; the world torque is held constant over the step.
    A zero torque is not rotated into the body frame. A diagonal inertia (a body built on its principal axes)
    takes Euler's equations, dw_x/dt = (J_y - J_z) / J_x w_y w_z + tau_x / J_x and cyclic: the gyroscopic term
    in 6 products where J^-1 (w x J w) takes 18 (its coefficients are the same in the four RK4 stages, and the
    compiler forms them once), equal up to round-off."""
    if diagonal:
        w = w_body
        acc = vec3d(
            (inertia[1, 1] - inertia[2, 2]) * inv_inertia[0, 0] * w[1] * w[2],
            (inertia[2, 2] - inertia[0, 0]) * inv_inertia[1, 1] * w[2] * w[0],
            (inertia[0, 0] - inertia[1, 1]) * inv_inertia[2, 2] * w[0] * w[1],
        )
        if torque[0] == f64(0.0) and torque[1] == f64(0.0) and torque[2] == f64(0.0):
            return acc
        return acc + diagonal_times(inv_inertia, wp.quat_rotate_inv(q, torque))
    gyro = wp.cross(w_body, inertia * w_body)
    if torque[0] == f64(0.0) and torque[1] == f64(0.0) and torque[2] == f64(0.0):
        return inv_inertia * (-gyro)
    return inv_inertia * (wp.quat_rotate_inv(q, torque) - gyro)


MAX_SUBSTEP_ROTATION = wp.constant(wp.float64(0.25))  # rad per RK4 substep of the rotation
MAX_SUBSTEPS = wp.constant(64)


@wp.func
def rk4_rotation(q: quatd, wb: vec3d, inertia: mat33d, inv_inertia: mat33d, torque: vec3d, h: f64, diagonal: bool):
    """One classic RK4 step of equations 3 and 4 for (q, body-space w); `diagonal`: the inertia is. The
    quaternion's rates are 2 dq/dt (`rotation_rate`), so its fractions of the step are halved."""
    half = f64(0.5) * h
    quarter = f64(0.5) * half
    k1q = rotation_rate(q, wb)
    k1w = angular_acceleration(q, wb, inertia, inv_inertia, torque, diagonal)
    q2 = q + k1q * quarter
    w2 = wb + k1w * half
    k2q = rotation_rate(q2, w2)
    k2w = angular_acceleration(q2, w2, inertia, inv_inertia, torque, diagonal)
    q3 = q + k2q * quarter
    w3 = wb + k2w * half
    k3q = rotation_rate(q3, w3)
    k3w = angular_acceleration(q3, w3, inertia, inv_inertia, torque, diagonal)
    q4 = q + k3q * half
    w4 = wb + k3w * h
    k4q = rotation_rate(q4, w4)
    k4w = angular_acceleration(q4, w4, inertia, inv_inertia, torque, diagonal)
    sixth = h / f64(6.0)
    q1 = wp.normalize(q + (k1q + k2q * f64(2.0) + k3q * f64(2.0) + k4q) * (f64(0.5) * sixth))
    return q1, wb + (k1w + k2w * f64(2.0) + k3w * f64(2.0) + k4w) * sixth


@wp.func
def predict_body(
    x: vec3d,
    q: quatd,
    v: vec3d,
    w: vec3d,
    inv_mass: f64,
    inertia: mat33d,
    inv_inertia: mat33d,
    force: vec3d,
    torque: vec3d,
    gravity: vec3d,
    h: f64,
):
    """The state after a step of h: exact translation (equations 1-2), RK4 rotation (equations 3-4).

    A body turning more than MAX_SUBSTEP_ROTATION in the step takes several RK4 substeps, so that a
    fast spin stays on its axis; slower bodies take exactly one, as in the paper. Static bodies stay put.
    """
    if inv_mass == f64(0.0):
        return x, q, v, w
    a = gravity + force * inv_mass
    x1 = x + v * h + a * (f64(0.5) * h * h)
    v1 = v + a * h
    wb = wp.quat_rotate_inv(q, w)
    n = int(1)
    hs = h
    if wp.length_sq(w) * (h * h) > MAX_SUBSTEP_ROTATION * MAX_SUBSTEP_ROTATION:  # no root nor division below
        n = wp.min(int(wp.ceil(wp.length(w) * wp.abs(h) / MAX_SUBSTEP_ROTATION)), MAX_SUBSTEPS)  # h < 0: backwards
        n = wp.max(n, 1)
        hs = h / f64(n)
    q1 = q
    diagonal = is_diagonal(inertia)
    for _ in range(n):
        q1, wb = rk4_rotation(q1, wb, inertia, inv_inertia, torque, hs, diagonal)
    return x1, q1, v1, wp.quat_rotate(q1, wb)


@wp.func
def predict_index(
    b: int,
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    gravity: vec3d,
    h: f64,
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    body_force_in: wp.array(dtype=vec3d),
    body_torque_in: wp.array(dtype=vec3d),
    body_x_out: wp.array(dtype=vec3d),
    body_q_out: wp.array(dtype=quatd),
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
):
    """Body b's free motion over h from the state in, written to the state out (`predict_body`)."""
    x, q, v, w = predict_body(
        body_x_in[b], body_q_in[b], body_v_in[b], body_w_in[b],
        body_inv_mass[b], body_inertia[b], body_inv_inertia[b],
        body_force_in[b], body_torque_in[b], gravity, h,
    )  # fmt: skip
    body_x_out[b] = x
    body_q_out[b] = q
    body_v_out[b] = v
    body_w_out[b] = w


@wp.kernel
def predict(
    # Model:
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    gravity: vec3d,
    # Data in:
    h: f64,
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    body_force_in: wp.array(dtype=vec3d),
    body_torque_in: wp.array(dtype=vec3d),
    # Data out: the prediction
    body_x_out: wp.array(dtype=vec3d),
    body_q_out: wp.array(dtype=quatd),
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
):
    """Every body's free motion over h from the state in (section 3)."""
    predict_index(
        wp.tid(), body_inv_mass, body_inertia, body_inv_inertia, gravity, h, body_x_in, body_q_in, body_v_in,
        body_w_in, body_force_in, body_torque_in, body_x_out, body_q_out, body_v_out, body_w_out,
    )  # fmt: skip


@wp.func
def world_inverse_inertia_of(
    b: int,
    body_inv_inertia: wp.array(dtype=mat33d),
    body_q_in: wp.array(dtype=quatd),
    inv_inertia_world_out: wp.array(dtype=mat33d),
):
    """J~^-1 = R J^-1 R^T of body b at its current orientation (section 4.1); zero for static bodies."""
    r = wp.quat_to_matrix(body_q_in[b])
    inv_inertia_world_out[b] = r * body_inv_inertia[b] * wp.transpose(r)


@wp.kernel
def world_inverse_inertia(
    # Model:
    body_inv_inertia: wp.array(dtype=mat33d),
    # Data in:
    body_q_in: wp.array(dtype=quatd),
    # Data out:
    inv_inertia_world_out: wp.array(dtype=mat33d),
):
    """J~^-1 of every body (`world_inverse_inertia_of`)."""
    world_inverse_inertia_of(wp.tid(), body_inv_inertia, body_q_in, inv_inertia_world_out)


@wp.func
def body_summary(
    b: int,
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
):
    """(whether body b's state is finite, its |w| in rad/s)."""
    w = body_w_in[b]
    s = wp.length_sq(body_x_in[b]) + wp.length_sq(body_v_in[b]) + wp.length_sq(w) + wp.dot(body_q_in[b], body_q_in[b])
    return wp.isfinite(s), wp.length(w)


@wp.kernel
def summarize_state(
    # Data in:
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    # Data out:
    summary_out: wp.array(dtype=f64),
):
    """summary[0] += 1 for every body with a NaN or Inf in its state; summary[1] = the largest finite |w|.
    Two numbers to read back per step: the divergence check and the spin that sets the next step's substeps."""
    finite, spin = body_summary(wp.tid(), body_x_in, body_q_in, body_v_in, body_w_in)
    if finite:
        wp.atomic_max(summary_out, 1, spin)
    else:
        wp.atomic_add(summary_out, 0, f64(1.0))
