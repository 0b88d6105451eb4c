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


@wp.func
def verdict(err: f64, best: f64, iterations: int, tolerance: f64, max_iterations: int):
    """(go on, failed) of a correction whose last error is err after `iterations` (best: the smallest error so
    far, err included): go on while over the tolerance, under the iteration limit and not diverging (the error
    1000-fold over the best after three iterations); failed when it must stop over the tolerance."""
    over = not (err <= tolerance)
    diverging = iterations >= 3 and err > f64(1.0e3) * best
    failed = over and (not wp.isfinite(err) or iterations >= max_iterations or diverging)
    return over and not failed, failed


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
    go, failed = verdict(err, best, iterations, tolerance, max_iterations)
    if go:
        loop_state[LOOP_ITERATIONS] = f64(iterations + 1)
        loop_go[0] = 1
    else:
        loop_go[0] = 0


@wp.kernel
def worlds_start(
    # Data out:
    world_loop_out: wp.array2d(dtype=f64),
):
    """A new loop for every world (batched worlds, `worlds.Batch`): the columns of `world_loop` are those of
    `loop_state`."""
    w = wp.tid()
    world_loop_out[w, LOOP_ERROR] = f64(0.0)
    world_loop_out[w, LOOP_LAST] = f64(0.0)
    world_loop_out[w, LOOP_BEST] = f64(wp.inf)
    world_loop_out[w, LOOP_ITERATIONS] = f64(0.0)
    world_loop_out[w, LOOP_BAD] = f64(0.0)


@wp.kernel
def worlds_reduce(
    # Model:
    constraint_world: wp.array(dtype=int),
    # Data in:
    errors: wp.array(dtype=f64),
    # Data out:
    world_loop_out: wp.array2d(dtype=f64),
):
    """Each world's largest error (`loop_reduce` per world)."""
    c = wp.tid()
    w = constraint_world[c]
    e = errors[c]
    if wp.isfinite(e):
        wp.atomic_max(world_loop_out, w, LOOP_ERROR, e)
    else:
        world_loop_out[w, LOOP_BAD] = f64(1.0)


@wp.kernel
def worlds_decide(
    tolerance: f64,
    max_iterations: int,
    # Data out:
    world_loop_out: wp.array2d(dtype=f64),
    world_batch_out: wp.array(dtype=wp.int32),
    world_active_out: wp.array(dtype=int),
    loop_go_out: wp.array(dtype=wp.int32),
):
    """Per world of the batch: go on (`world_active`, which masks the next solve's right-hand sides), or leave
    the batch when it failed (the host steps it alone). loop_go (zeroed before) becomes 1 when any goes on."""
    w = wp.tid()
    err = world_loop_out[w, LOOP_ERROR]
    if world_loop_out[w, LOOP_BAD] != f64(0.0):
        err = f64(wp.nan)
    world_loop_out[w, LOOP_LAST] = err
    world_loop_out[w, LOOP_ERROR] = f64(0.0)
    world_loop_out[w, LOOP_BAD] = f64(0.0)
    best = wp.min(world_loop_out[w, LOOP_BEST], err)
    world_loop_out[w, LOOP_BEST] = best
    iterations = int(world_loop_out[w, LOOP_ITERATIONS])
    go, failed = verdict(err, best, iterations, tolerance, max_iterations)
    active = 0
    if world_batch_out[w] != 0:
        if failed:
            world_batch_out[w] = 0
        elif go:
            active = 1
            world_loop_out[w, LOOP_ITERATIONS] = f64(iterations + 1)
            wp.atomic_max(loop_go_out, 0, 1)
    world_active_out[w] = active
