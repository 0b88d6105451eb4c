"""Free rigid-body motion over one step (method paper, section 3, equations 1-4)."""

import warp as wp

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
quatd = wp.quatd
mat33d = wp.mat33d
f64 = wp.float64


@wp.func
def rotation_rate(q: quatd, w_body: vec3d) -> quatd:
    """dq/dt = 1/2 q (w_body, 0): equation 3 with the angular velocity in body space."""
    return f64(0.5) * (q * quatd(w_body[0], w_body[1], w_body[2], f64(0.0)))


@wp.func
def angular_acceleration(q: quatd, w_body: vec3d, inertia: mat33d, inv_inertia: mat33d, torque: vec3d) -> vec3d:
    """Equation 4 in body space, with the gyroscopic term; the world torque is held constant over the step."""
    tau = wp.quat_rotate_inv(q, torque)
    return inv_inertia * (tau - wp.cross(w_body, inertia * w_body))


MAX_SUBSTEP_ROTATION = wp.constant(wp.float64(0.25))  # rad per RK4 substep of the rotation
MAX_SUBSTEPS = wp.constant(64)


@wp.func
def rk4_rotation(q: quatd, wb: vec3d, inertia: mat33d, inv_inertia: mat33d, torque: vec3d, h: f64):
    """One classic RK4 step of equations 3 and 4 for (q, body-space w)."""
    half = f64(0.5) * h
    k1q = rotation_rate(q, wb)
    k1w = angular_acceleration(q, wb, inertia, inv_inertia, torque)
    q2 = q + k1q * half
    w2 = wb + k1w * half
    k2q = rotation_rate(q2, w2)
    k2w = angular_acceleration(q2, w2, inertia, inv_inertia, torque)
    q3 = q + k2q * half
    w3 = wb + k2w * half
    k3q = rotation_rate(q3, w3)
    k3w = angular_acceleration(q3, w3, inertia, inv_inertia, torque)
    q4 = q + k3q * h
    w4 = wb + k3w * h
    k4q = rotation_rate(q4, w4)
    k4w = angular_acceleration(q4, w4, inertia, inv_inertia, torque)
    sixth = h / f64(6.0)
    q1 = wp.normalize(q + (k1q + k2q * f64(2.0) + k3q * f64(2.0) + k4q) * sixth)
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
    n = wp.min(int(wp.ceil(wp.length(w) * wp.abs(h) / MAX_SUBSTEP_ROTATION)), MAX_SUBSTEPS)  # h < 0 runs backwards
    n = wp.max(n, 1)
    hs = h / f64(n)
    q1 = q
    for _ in range(n):
        q1, wb = rk4_rotation(q1, wb, inertia, inv_inertia, torque, hs)
    return x1, q1, v1, wp.quat_rotate(q1, wb)


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
    b = wp.tid()
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
def world_inverse_inertia(
    # Model:
    body_inv_inertia: wp.array(dtype=mat33d),
    # Data in:
    body_q_in: wp.array(dtype=quatd),
    # Data out:
    inv_inertia_world_out: wp.array(dtype=mat33d),
):
    """J~^-1 = R J^-1 R^T at the current orientation (section 4.1); zero for static bodies."""
    b = wp.tid()
    r = wp.quat_to_matrix(body_q_in[b])
    inv_inertia_world_out[b] = r * body_inv_inertia[b] * wp.transpose(r)


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
    b = wp.tid()
    w = body_w_in[b]
    s = wp.length_sq(body_x_in[b]) + wp.length_sq(body_v_in[b]) + wp.length_sq(w) + wp.dot(body_q_in[b], body_q_in[b])
    if wp.isfinite(s):
        wp.atomic_max(summary_out, 1, wp.length(w))
    else:
        wp.atomic_add(summary_out, 0, f64(1.0))
