"""The joint-correction loop decided on the device (the parallel schedule's `Simulator._correct_joints`).

The parallel schedule's loop (measure the prediction; while its largest joint error is over the tolerance and the
iteration policy allows: solve, apply at t0, predict again, measure) is one captured graph: the measurements are
reduced to one record, `loop_decide` writes whether to go on, and `wp.capture_while` repeats the iteration on
that flag without the host (a CUDA conditional node; on a CPU, Warp's own capture of the same loop). The host
reads the record once, after the loop. The policy is the host's (`Simulator._may_iterate`), to the same
comparisons: stop at the tolerance, at `max_iterations`, or when the error has grown 1000-fold over the best of
the step after at least three iterations; a non-finite error stops the loop for the host to report.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

f64 = wp.float64

LOOP_ERROR = wp.constant(0)  # the largest error of the measurement being reduced (m, or m/s)
LOOP_LAST = wp.constant(1)  # the largest error of the last measurement
LOOP_BEST = wp.constant(2)  # the smallest LOOP_LAST of the loop so far
LOOP_ITERATIONS = wp.constant(3)  # iterations taken
LOOP_BAD = wp.constant(4)  # 1 when the measurement had a NaN or Inf
LOOP_WIDTH = 5


@wp.kernel
def loop_start(loop_state: wp.array(dtype=f64)):
    """A new loop: no iterations, no best error yet, the reduction empty."""
    loop_state[LOOP_ERROR] = f64(0.0)
    loop_state[LOOP_LAST] = f64(0.0)
    loop_state[LOOP_BEST] = f64(wp.inf)
    loop_state[LOOP_ITERATIONS] = f64(0.0)
    loop_state[LOOP_BAD] = f64(0.0)


@wp.kernel
def loop_reduce(
    # Data in: one error per constraint (or per limit row)
    errors: wp.array(dtype=f64),
    # Data out:
    loop_state: wp.array(dtype=f64),
):
    """The largest error into LOOP_ERROR; a non-finite one raises LOOP_BAD (a maximum would drop a NaN)."""
    e = errors[wp.tid()]
    if wp.isfinite(e):
        wp.atomic_max(loop_state, LOOP_ERROR, e)
    else:
        loop_state[LOOP_BAD] = f64(1.0)


@wp.kernel
def loop_decide(
    tolerance: f64,
    max_iterations: int,
    # Data out:
    loop_state: wp.array(dtype=f64),
    loop_go: wp.array(dtype=wp.int32),
):
    """Whether the loop takes another iteration, counted here (`Simulator._may_iterate`'s comparisons); the
    reduction is emptied for the next measurement."""
    err = loop_state[LOOP_ERROR]
    if loop_state[LOOP_BAD] != f64(0.0):
        err = f64(wp.nan)
    loop_state[LOOP_LAST] = err
    loop_state[LOOP_ERROR] = f64(0.0)
    best = wp.min(loop_state[LOOP_BEST], err)
    loop_state[LOOP_BEST] = best
    iterations = int(loop_state[LOOP_ITERATIONS])
    diverging = iterations >= 3 and err > f64(1.0e3) * best
    go = wp.isfinite(err) and err > tolerance and iterations < max_iterations and not diverging
    if go:
        loop_state[LOOP_ITERATIONS] = f64(iterations + 1)
        loop_go[0] = 1
    else:
        loop_go[0] = 0
