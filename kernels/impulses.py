"""Apply constraint impulses and angular momenta to the bodies (method paper, sections 4.2-4.3).

Gathered per body over its constraints, so no atomics and the same sum order on every device.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
mat33d = wp.mat33d
f64 = wp.float64


@wp.kernel
def apply_impulses(
    # model
    body_inv_mass: wp.array(dtype=f64),
    body_rows_start: wp.array(dtype=int),
    body_rows: wp.array(dtype=int),
    # data in
    inv_inertia_world: wp.array(dtype=mat33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    impulse: wp.array(dtype=vec3d),
    # data out
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """v += m^-1 J_lin^T lambda, w += J~^-1 J_ang^T lambda, summed over the Jacobian rows on this body."""
    b = wp.tid()
    dv = vec3d()
    dl = vec3d()
    for k in range(body_rows_start[b], body_rows_start[b + 1]):
        r = body_rows[k]
        lam = impulse[r // 2]
        dv += wp.transpose(jac_lin[r]) * lam
        dl += wp.transpose(jac_ang[r]) * lam
    body_v[b] = body_v[b] + dv * body_inv_mass[b]
    body_w[b] = body_w[b] + inv_inertia_world[b] * dl
