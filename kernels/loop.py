"""The joint-correction loop decided on the device (the parallel schedule's `Simulator._correct_joints`).

The parallel schedule's loop (measure the prediction; while its largest joint error is over the tolerance and the
iteration policy allows: solve, apply at t0, predict again, measure) is one captured graph: the measurements are
reduced to one record a world, `loop_decide` writes whether each goes on, and `wp.capture_while` repeats the
iteration while any does, without the host (a CUDA conditional node; on a CPU, Warp's own capture of the same
loop). The host reads the records once, after the loop. The policy is the host's (`Simulator._may_iterate`), to the same
comparisons: stop at the tolerance, at `max_iterations`, or when the correction diverges (`diverging`, the one rule
of every loop; `types.DIVERGENCE_GROWTH`); a non-finite error stops the loop for the host to report.
"""

import warp as wp

from ..types import DIVERGENCE_AFTER, DIVERGENCE_GROWTH

wp.set_module_options({"enable_backward": False})

f64 = wp.float64
DIVERGENCE_AFTER_ = wp.constant(DIVERGENCE_AFTER)
DIVERGENCE_GROWTH_ = wp.constant(DIVERGENCE_GROWTH)

LOOP_ERROR = wp.constant(0)  # the largest error of the measurement being reduced (m, or m/s)
LOOP_LAST = wp.constant(1)  # the largest error of the last measurement
LOOP_BEST = wp.constant(2)  # the smallest LOOP_LAST of the loop so far
LOOP_ITERATIONS = wp.constant(3)  # iterations taken
LOOP_BAD = wp.constant(4)  # 1 when the measurement had a NaN or Inf
LOOP_WIDTH = 5


@wp.kernel
def loop_start(
    # Data out: a row a world (one row for a one-world model)
    loop_state_out: wp.array2d(dtype=f64),
):
    """A new loop: no iterations, no best error yet, the reduction empty."""
    w = wp.tid()
    loop_state_out[w, LOOP_ERROR] = f64(0.0)
    loop_state_out[w, LOOP_LAST] = f64(0.0)
    loop_state_out[w, LOOP_BEST] = f64(wp.inf)
    loop_state_out[w, LOOP_ITERATIONS] = f64(0.0)
    loop_state_out[w, LOOP_BAD] = f64(0.0)


@wp.kernel
def loop_reduce(
    # Model:
    error_world: wp.array(dtype=int),
    # Data in: one error per constraint (or per limit row)
    errors: wp.array(dtype=f64),
    # Data out:
    loop_state_out: wp.array2d(dtype=f64),
):
    """Each world's largest error into its LOOP_ERROR; a non-finite one raises LOOP_BAD (a maximum would drop
    a NaN)."""
    i = wp.tid()
    w = error_world[i]
    e = errors[i]
    if wp.isfinite(e):
        wp.atomic_max(loop_state_out, w, LOOP_ERROR, e)
    else:
        loop_state_out[w, LOOP_BAD] = f64(1.0)


@wp.func
def diverging(err: f64, best: f64, iterations: int) -> wp.bool:
    """Whether a correction diverges (`types.DIVERGENCE_GROWTH`): the one rule of every loop on the device."""
    return iterations >= DIVERGENCE_AFTER_ and err > f64(DIVERGENCE_GROWTH_) * best


@wp.func
def verdict(err: f64, best: f64, iterations: int, tolerance: f64, max_iterations: int):
    """(go on, failed) of a correction whose last error is err after `iterations` (best: the smallest error so
    far, err included): go on while over the tolerance, under the iteration limit and not diverging (the error
    1000-fold over the best after three iterations); failed when it must stop over the tolerance."""
    over = not (err <= tolerance)
    failed = over and (not wp.isfinite(err) or iterations >= max_iterations or diverging(err, best, iterations))
    return over and not failed, failed


@wp.kernel
def loop_decide(
    tolerance: f64,
    max_iterations: int,
    # Data out:
    loop_state_out: wp.array2d(dtype=f64),
    loop_batch_out: wp.array(dtype=wp.int32),
    loop_active_out: wp.array(dtype=int),
    loop_go_out: wp.array(dtype=wp.int32),
):
    """Per world still in the batch: go on (`loop_active`, which masks the others' right-hand sides in batched
    worlds), counting the iteration, or leave the batch when it failed. loop_go (zeroed before) becomes 1 when
    any world goes on. The reduction is emptied for the next measurement."""
    w = wp.tid()
    err = loop_state_out[w, LOOP_ERROR]
    if loop_state_out[w, LOOP_BAD] != f64(0.0):
        err = f64(wp.nan)
    loop_state_out[w, LOOP_LAST] = err
    loop_state_out[w, LOOP_ERROR] = f64(0.0)
    loop_state_out[w, LOOP_BAD] = f64(0.0)
    best = wp.min(loop_state_out[w, LOOP_BEST], err)
    loop_state_out[w, LOOP_BEST] = best
    iterations = int(loop_state_out[w, LOOP_ITERATIONS])
    go, failed = verdict(err, best, iterations, tolerance, max_iterations)
    active = 0
    if loop_batch_out[w] != 0:
        if failed:
            loop_batch_out[w] = 0
        elif go:
            active = 1
            loop_state_out[w, LOOP_ITERATIONS] = f64(iterations + 1)
            wp.atomic_max(loop_go_out, 0, 1)
    loop_active_out[w] = active
