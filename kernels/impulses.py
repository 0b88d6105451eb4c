"""Apply constraint impulses and angular momenta to the bodies (method paper, sections 4.2-4.3).

Gathered per body over its constraints, so no atomics and the same sum order on every device.
"""

import warp as wp

from .constraints import POINT, angular_transpose_times, is_translational
from .inertia import sym33d, symmetric_matrix, symmetric_times

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
mat33d = wp.mat33d
quatd = wp.quatd
f64 = wp.float64


@wp.func
def impulse_response(
    b: int,
    constraint_kind: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    body_rows_start: wp.array(dtype=int),
    body_rows: wp.array(dtype=int),
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    impulse_in: wp.array(dtype=vec3d),
):
    """Body b's velocity change from the impulses, (m^-1 sum J_lin^T lambda, J~^-1 sum J_ang^T lambda) over its
    Jacobian rows (m/s, rad/s; world frame). A point constraint's J_lin is +-I and its J_ang a skew matrix [v]x
    (`constraints.constraint_frame`), so its J_lin^T lambda is +-lambda, the same value without the product, and
    its J_ang^T lambda = -v x lambda = lambda x v, v read from jac_skew; a rotational constraint's J_lin is zero,
    so it adds to w only."""
    dv = vec3d()
    dl = vec3d()
    k = body_rows_start[b]
    end = body_rows_start[b + 1]
    while k < end:  # not `for k in range(...)`: Warp's range loops cost more in short loops (docs/architecture.md)
        r = body_rows[k]
        i = r // 2
        lam = impulse_in[i]
        if constraint_kind[i] == POINT:
            if r == 2 * i:
                dv += lam
            else:
                dv -= lam
            dl += wp.cross(lam, jac_skew_in[r])
        else:
            if is_translational(constraint_kind[i]):  # a rotational kind's J_lin is zero: nothing to add
                dv += wp.transpose(jac_lin_in[r]) * lam
            dl += wp.transpose(jac_ang_in[r]) * lam
        k += 1
    return dv * body_inv_mass[b], symmetric_times(inv_inertia_world_in[b], dl)


@wp.func
def apply_body(
    b: int,
    constraint_kind: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    body_rows_start: wp.array(dtype=int),
    body_rows: wp.array(dtype=int),
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    impulse_in: wp.array(dtype=vec3d),
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
):
    """Body b: v += m^-1 J_lin^T lambda, w += J~^-1 J_ang^T lambda, summed over its Jacobian rows
    (`impulse_response`)."""
    dv, dw = impulse_response(
        b, constraint_kind, body_inv_mass, body_rows_start, body_rows, inv_inertia_world_in, jac_lin_in, jac_ang_in,
        jac_skew_in, impulse_in,
    )  # fmt: skip
    body_v_out[b] = body_v_out[b] + dv
    body_w_out[b] = body_w_out[b] + dw


@wp.kernel
def apply_impulses(
    # Model:
    constraint_kind: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    body_rows_start: wp.array(dtype=int),
    body_rows: wp.array(dtype=int),
    # Data in:
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    impulse_in: wp.array(dtype=vec3d),
    # Data out (updated in place):
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
):
    """Every body's impulses (`apply_body`)."""
    apply_body(
        wp.tid(), constraint_kind, body_inv_mass, body_rows_start, body_rows, inv_inertia_world_in, jac_lin_in,
        jac_ang_in, jac_skew_in, impulse_in, body_v_out, body_w_out,
    )  # fmt: skip


@wp.func
def step_turn(dw: vec3d, h: f64, w: vec3d, inv_inertia_world: sym33d) -> vec3d:
    """The turn over a step of h, per unit of h (rad/s, world frame), that a velocity change dw at t0 gives a body
    turning at w (t0) with world inverse inertia J~^-1, to first order in the turn:
    dw + h/2 (w x dw + J~^-1 (L x dw - w x J~ dw)), L = J~ w. The perturbed orientation's rate is
    dw(t) + w x dtheta, and dw(t) = J~(t)^-1 J~ dw moves with the body while the impulse's angular momentum stays
    put in the world: h dw exactly only for a body at rest (docs/history.md, "The turn's answer"). J~ is J~^-1
    inverted here (no inertia read); a static body (J~^-1 zero, so dw zero) gets zero."""
    if dw[0] == f64(0.0) and dw[1] == f64(0.0) and dw[2] == f64(0.0):
        return dw
    inverse = symmetric_matrix(inv_inertia_world)
    inertia = wp.inverse(inverse)
    gyro = wp.cross(inertia * w, dw) - wp.cross(w, inertia * dw)
    return dw + (wp.cross(w, dw) + inverse * gyro) * (f64(0.5) * h)


@wp.kernel
def impulse_responses(
    # Model:
    constraint_kind: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    body_rows_start: wp.array(dtype=int),
    body_rows: wp.array(dtype=int),
    # Data in: the step, the state's angular velocities (with the impulses applied so far)
    h: f64,
    body_w_in: wp.array(dtype=vec3d),
    inv_inertia_world_in: wp.array(dtype=sym33d),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    impulse_in: wp.array(dtype=vec3d),
    # Data out:
    response_v_out: wp.array(dtype=vec3d),
    response_w_out: wp.array(dtype=vec3d),
    response_turn_out: wp.array(dtype=vec3d),
):
    """Every body's velocity change from the impulses (`impulse_response`) and the turn it gives over the step
    (`step_turn`), the bodies left as they are: the first iteration's Newton step (`constraints.arm_correction`)
    reads them."""
    b = wp.tid()
    dv, dw = impulse_response(
        b, constraint_kind, body_inv_mass, body_rows_start, body_rows, inv_inertia_world_in, jac_lin_in, jac_ang_in,
        jac_skew_in, impulse_in,
    )  # fmt: skip
    response_v_out[b] = dv
    response_w_out[b] = dw
    response_turn_out[b] = step_turn(dw, h, body_w_in[b], inv_inertia_world_in[b])


@wp.func
def apply_to_body(
    b: int,
    kind: int,
    r: int,
    lam: vec3d,
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia_world: wp.array(dtype=sym33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Impulse lam of Jacobian row r (2 i + side) of a constraint of `kind` onto body b at once (none for the
    world, b < 0): v += m^-1 J_lin^T lam, w += J~^-1 J_ang^T lam (`angular_transpose_times`). For the serial
    sweeps and the rows' reaction (`limits.compensate`), which apply one constraint's impulse at a time."""
    if b >= 0:
        body_v[b] = body_v[b] + wp.transpose(jac_lin[r]) * lam * body_inv_mass[b]
        dl = angular_transpose_times(kind, r, jac_ang, jac_skew, lam)
        body_w[b] = body_w[b] + symmetric_times(inv_inertia_world[b], dl)
