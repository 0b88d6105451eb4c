"""Batched worlds (`SceneBuilder.replicate`): per-world reductions and masks over the flat, world-major arrays.

Every launch of the step covers all worlds; these kernels let each world converge on its own. A world that has
converged (or failed) gets zero right-hand sides, so the shared solve gives it zero impulses and its next
prediction repeats bit for bit: it takes no further iterations, and the others pay none for it.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
quatd = wp.quatd
f64 = wp.float64


@wp.kernel
def summarize_worlds(
    # Model:
    world_body_count: int,
    # Data in:
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    # Data out:
    world_summary_out: wp.array2d(dtype=f64),
):
    """Per world: [0] += 1 for every body with a NaN or Inf in its state, [1] = the largest finite |w| (rad/s)
    (`rigid.summarize_state` for each world alone)."""
    b = wp.tid()
    world = b // world_body_count
    w = body_w_in[b]
    s = wp.length_sq(body_x_in[b]) + wp.length_sq(body_v_in[b]) + wp.length_sq(w) + wp.dot(body_q_in[b], body_q_in[b])
    if wp.isfinite(s):
        wp.atomic_max(world_summary_out, world, 1, wp.length(w))
    else:
        wp.atomic_add(world_summary_out, world, 0, f64(1.0))


@wp.kernel
def mask_worlds(
    # Model:
    constraint_world: wp.array(dtype=int),
    world_active: wp.array(dtype=int),
    # Data out:
    rhs_out: wp.array(dtype=vec3d),
):
    """Zero the right-hand side of every constraint of a world that is not active: its impulses are zero."""
    c = wp.tid()
    if world_active[constraint_world[c]] == 0:
        rhs_out[c] = vec3d(f64(0.0), f64(0.0), f64(0.0))
