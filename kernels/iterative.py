"""The paper's iterative method without a system (section 4.5, first paragraph; [BFS05]).

One thread sweeps the constraints in order, Gauss-Seidel style: predict the two bodies of a constraint,
and when its error exceeds the tolerance apply the impulse that its own K_ii says removes it. The host
repeats sweeps until one finds every constraint within tolerance. Sequential by nature: the baseline.
"""

import warp as wp

from .assemble import diagonal_block
from .cholesky import cholesky3, lower_inverse3
from .constraints import constraint_error, constraint_velocity, pose_q, pose_x, projected_error
from .rigid import predict_body

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
quatd = wp.quatd
mat33d = wp.mat33d
f64 = wp.float64


@wp.func
def solve_block(k: mat33d, rhs: vec3d) -> vec3d:
    l, ok = cholesky3(k, f64(0.0))
    li = lower_inverse3(l)
    return wp.transpose(li) * (li * rhs)


@wp.func
def apply_to_body(
    b: int,
    r: int,
    lam: vec3d,
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia_world: wp.array(dtype=mat33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    if b >= 0:
        body_v[b] = body_v[b] + wp.transpose(jac_lin[r]) * lam * body_inv_mass[b]
        body_w[b] = body_w[b] + inv_inertia_world[b] * (wp.transpose(jac_ang[r]) * lam)


@wp.func
def correct_alone(
    i: int,
    rhs: vec3d,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia_world: wp.array(dtype=mat33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Solve K_ii lambda = rhs for constraint i alone and apply lambda to its two bodies at once."""
    k = diagonal_block(
        i, constraint_kind, constraint_body0, constraint_body1, body_inv_mass, inv_inertia_world, jac_lin, jac_ang
    )
    lam = solve_block(k, rhs)
    apply_to_body(constraint_body0[i], 2 * i, lam, body_inv_mass, inv_inertia_world, jac_lin, jac_ang, body_v, body_w)
    apply_to_body(
        constraint_body1[i], 2 * i + 1, lam, body_inv_mass, inv_inertia_world, jac_lin, jac_ang, body_v, body_w
    )


@wp.kernel
def sweep_positions(
    # model
    constraint_count: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    anchor0: wp.array(dtype=vec3d),
    anchor1: wp.array(dtype=vec3d),
    axis0: wp.array(dtype=vec3d),
    axis1: wp.array(dtype=vec3d),
    rest_rotation: wp.array(dtype=quatd),
    rest_angle: wp.array(dtype=f64),
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    gravity: vec3d,
    h: f64,
    tolerance: f64,
    # data in
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_force: wp.array(dtype=vec3d),
    body_torque: wp.array(dtype=vec3d),
    inv_inertia_world: wp.array(dtype=mat33d),
    proj: wp.array(dtype=mat33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    # data in/out
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    max_error: wp.array(dtype=f64),
):
    """One joint-correction sweep; max_error[0] = the largest error met before its correction."""
    worst = f64(0.0)
    for i in range(constraint_count):
        b0 = constraint_body0[i]
        b1 = constraint_body1[i]
        x0 = pose_x(b0, body_x)
        q0 = pose_q(b0, body_q)
        if b0 >= 0:
            x0, q0, v0, w0 = predict_body(
                body_x[b0], body_q[b0], body_v[b0], body_w[b0], body_inv_mass[b0], body_inertia[b0],
                body_inv_inertia[b0], body_force[b0], body_torque[b0], gravity, h,
            )  # fmt: skip
        x1, q1, v1, w1 = predict_body(
            body_x[b1], body_q[b1], body_v[b1], body_w[b1], body_inv_mass[b1], body_inertia[b1],
            body_inv_inertia[b1], body_force[b1], body_torque[b1], gravity, h,
        )  # fmt: skip
        d = constraint_error(
            constraint_kind[i], x0, q0, x1, q1,
            anchor0[i], anchor1[i], axis0[i], axis1[i], rest_rotation[i], rest_angle[i],
        )  # fmt: skip
        e = wp.length(d)
        worst = wp.max(worst, e)
        if e > tolerance:
            rhs = -projected_error(constraint_kind[i], proj[i], d) / h
            correct_alone(
                i, rhs, constraint_kind, constraint_body0, constraint_body1,
                body_inv_mass, inv_inertia_world, jac_lin, jac_ang, body_v, body_w,
            )  # fmt: skip
    max_error[0] = worst


@wp.kernel
def sweep_velocities(
    # model
    constraint_count: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    tolerance: f64,
    # data in
    inv_inertia_world: wp.array(dtype=mat33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    # data in/out
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    max_error: wp.array(dtype=f64),
):
    """One velocity-correction sweep; max_error[0] = the largest |J_i v| met before its correction."""
    worst = f64(0.0)
    for i in range(constraint_count):
        jv = constraint_velocity(i, constraint_body0, constraint_body1, jac_lin, jac_ang, body_v, body_w)
        e = wp.length(jv)
        worst = wp.max(worst, e)
        if e > tolerance:
            correct_alone(
                i, -jv, constraint_kind, constraint_body0, constraint_body1,
                body_inv_mass, inv_inertia_world, jac_lin, jac_ang, body_v, body_w,
            )  # fmt: skip
    max_error[0] = worst
