"""The paper's iterative method without a system (section 4.5, first paragraph; [BFS05]).

One thread sweeps the constraints in order, Gauss-Seidel style: predict the two bodies of a constraint,
and when its error exceeds the tolerance apply the impulse that its own K_ii says removes it. The host
repeats sweeps until one finds every constraint within tolerance. Sequential by nature: the baseline.
"""

import warp as wp

from .assemble import diagonal_block
from .cholesky import cholesky3_inverse
from .constraints import constraint_error, constraint_velocity, pose_q, pose_x, projected_error, side_body
from .impulses import apply_to_body
from .inertia import sym33d
from .rigid import predict_of

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
quatd = wp.quatd
mat33d = wp.mat33d
f64 = wp.float64


@wp.func
def solve_block(k: mat33d, rhs: vec3d) -> vec3d:
    li, bad = cholesky3_inverse(k, f64(0.0), f64(1.0))
    return wp.transpose(li) * (li * rhs)


@wp.func
def correct_alone(
    i: int,
    rhs: vec3d,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia_world: wp.array(dtype=sym33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Solve K_ii lambda = rhs for constraint i alone and apply lambda to its two bodies at once."""
    k = diagonal_block(
        i, constraint_kind, constraint_body0, constraint_body1, body_inv_mass, inv_inertia_world, jac_lin, jac_ang,
        jac_skew,
    )  # fmt: skip
    lam = solve_block(k, rhs)
    kind = constraint_kind[i]
    for side in range(2):
        apply_to_body(
            side_body(i, side, constraint_body0, constraint_body1), kind, 2 * i + side, lam, body_inv_mass,
            inv_inertia_world, jac_lin, jac_ang, jac_skew, body_v, body_w,
        )  # fmt: skip


@wp.func
def sweep_positions_once(
    constraint_count: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    constraint_anchor0: wp.array(dtype=vec3d),
    constraint_anchor1: wp.array(dtype=vec3d),
    constraint_axis0: wp.array(dtype=vec3d),
    constraint_axis1: wp.array(dtype=vec3d),
    constraint_rest_rotation: wp.array(dtype=quatd),
    constraint_rest_angle: wp.array(dtype=f64),
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    body_principal: wp.array(dtype=int),
    body_euler: wp.array(dtype=vec3d),
    body_axes: wp.array(dtype=quatd),
    gravity: vec3d,
    h: f64,
    tolerance: f64,
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_force_in: wp.array(dtype=vec3d),
    body_torque_in: wp.array(dtype=vec3d),
    inv_inertia_world_in: wp.array(dtype=sym33d),
    proj_in: wp.array(dtype=mat33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
) -> f64:
    """One joint-correction sweep; returns the largest error met before its correction."""
    worst = f64(0.0)
    i = wp.int32(0)
    while i < constraint_count:
        b0 = constraint_body0[i]
        b1 = constraint_body1[i]
        x0 = pose_x(b0, body_x_in)
        q0 = pose_q(b0, body_q_in)
        if b0 >= 0:
            x0, q0, v0, w0 = predict_of(
                b0, body_x_in[b0], body_q_in[b0], body_v_out[b0], body_w_out[b0], body_inv_mass, body_inertia,
                body_inv_inertia, body_principal, body_euler, body_axes, body_force_in[b0], body_torque_in[b0],
                gravity, h,
            )  # fmt: skip
        x1, q1, v1, w1 = predict_of(
            b1, body_x_in[b1], body_q_in[b1], body_v_out[b1], body_w_out[b1], body_inv_mass, body_inertia,
            body_inv_inertia, body_principal, body_euler, body_axes, body_force_in[b1], body_torque_in[b1], gravity,
            h,
        )  # fmt: skip
        d = constraint_error(
            constraint_kind[i], x0, q0, x1, q1,
            constraint_anchor0[i], constraint_anchor1[i], constraint_axis0[i], constraint_axis1[i],
            constraint_rest_rotation[i], constraint_rest_angle[i],
        )  # fmt: skip
        e = wp.length(d)
        worst = wp.max(worst, e)
        if e > tolerance:
            rhs = -projected_error(constraint_kind[i], proj_in[i], d) / h
            correct_alone(
                i, rhs, constraint_kind, constraint_body0, constraint_body1,
                body_inv_mass, inv_inertia_world_in, jac_lin_in, jac_ang_in, jac_skew_in, body_v_out, body_w_out,
            )  # fmt: skip
        i += 1
    return worst


@wp.kernel
def sweep_positions(
    # Model:
    constraint_count: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    constraint_anchor0: wp.array(dtype=vec3d),
    constraint_anchor1: wp.array(dtype=vec3d),
    constraint_axis0: wp.array(dtype=vec3d),
    constraint_axis1: wp.array(dtype=vec3d),
    constraint_rest_rotation: wp.array(dtype=quatd),
    constraint_rest_angle: wp.array(dtype=f64),
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    body_principal: wp.array(dtype=int),
    body_euler: wp.array(dtype=vec3d),
    body_axes: wp.array(dtype=quatd),
    gravity: vec3d,
    # Data in:
    h: f64,
    tolerance: f64,
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_force_in: wp.array(dtype=vec3d),
    body_torque_in: wp.array(dtype=vec3d),
    inv_inertia_world_in: wp.array(dtype=sym33d),
    proj_in: wp.array(dtype=mat33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    # Data out (velocities updated in place):
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
    sweep_error_out: wp.array(dtype=f64),
):
    """One joint-correction sweep; sweep_error_out[0] = the largest error met before its correction."""
    sweep_error_out[0] = sweep_positions_once(
        constraint_count, constraint_kind, constraint_body0, constraint_body1, constraint_anchor0,
        constraint_anchor1, constraint_axis0, constraint_axis1, constraint_rest_rotation, constraint_rest_angle,
        body_inv_mass, body_inertia, body_inv_inertia, body_principal, body_euler, body_axes, gravity, h, tolerance,
        body_x_in, body_q_in, body_force_in, body_torque_in, inv_inertia_world_in, proj_in, jac_lin_in, jac_ang_in,
        jac_skew_in, body_v_out, body_w_out,
    )  # fmt: skip


@wp.func
def sweep_velocities_once(
    constraint_count: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    velocity_tolerance: f64,
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
) -> f64:
    """One velocity-correction sweep; returns the largest |J_i v| met before its correction."""
    worst = f64(0.0)
    i = wp.int32(0)
    while i < constraint_count:
        jv = constraint_velocity(
            i,
            constraint_kind,
            constraint_body0,
            constraint_body1,
            jac_lin_in,
            jac_ang_in,
            jac_skew_in,
            body_v_out,
            body_w_out,
        )
        e = wp.length(jv)
        worst = wp.max(worst, e)
        if e > velocity_tolerance:
            correct_alone(
                i, -jv, constraint_kind, constraint_body0, constraint_body1,
                body_inv_mass, inv_inertia_world_in, jac_lin_in, jac_ang_in, jac_skew_in, body_v_out, body_w_out,
            )  # fmt: skip
        i += 1
    return worst


@wp.kernel
def sweep_velocities(
    # Model:
    constraint_count: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    # Data in:
    velocity_tolerance: f64,
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    # Data out (velocities updated in place):
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
    sweep_error_out: wp.array(dtype=f64),
):
    """One velocity-correction sweep; sweep_error_out[0] = the largest |J_i v| met before its correction."""
    sweep_error_out[0] = sweep_velocities_once(
        constraint_count, constraint_kind, constraint_body0, constraint_body1, body_inv_mass, velocity_tolerance,
        inv_inertia_world_in, jac_lin_in, jac_ang_in, jac_skew_in, body_v_out, body_w_out,
    )  # fmt: skip
