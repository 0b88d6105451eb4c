"""The fused schedule: whole steps as one launch on one thread (docs/architecture.md, "Two schedules").

A Warp CPU launch runs on one thread anyway, so on a CPU the step's many launches (and the host's reading of
errors between them) buy nothing: here the same per-element stage funcs the parallel kernels call
(`rigid.predict_group`, the constraint funcs of `constraints.specialized`, `assemble.assemble_column`,
`augmented_slot`, `cholesky.factor_column` / `forward_row` / `backward_column`, `impulses.apply_body`, the sweeps
of `iterative.py`) run in serial loops, and the whole step (predict, joint errors, the convergence test, solve,
apply at t0, predict again, ...; accept; frames, assemble and factor at t0+h; velocity correction; the NaN/spin
summary) is decided on the device, for up to `batch_in[0]` steps a launch; with `defer` the velocity correction
is taken only in the last step of a launch that hands its state out (`batch_in[1]`; `Simulator.defer_velocities`),
the other steps' velocities going on to the next joint correction, and a launch of no step (`batch_in[0]` = 0)
takes the velocity correction a deferred step left (`Simulator.state`). A step is the base steps of a
composition in turn (`composition.py`: stages g_i h, some negative; one stage of h at order 2). Force elements
(`ForceElements`) make the prediction the coupled RK4 of all bodies; rows of the correction loop (`Rows`: joint
limits, stiff motors, distance constraints) are corrected after the joints in each iteration and after the
velocity correction, with the funcs of `limits.py`. The batch and the
starting spin are read from arrays, so the launch is fixed: on a CPU its arguments are packed once and each call is
one call of the compiled entry point (`launch.Packed`, ~0.3 us; a captured graph's replay packs the 90 arguments
again, ~1.7 us; a plain launch ~15 us), on a GPU it replays as a captured graph.

Each step writes one status row (`STATUS_*` columns), and the status array's last row sums up the launch's
steps that went OK (`finish`): the one record the host reads of a batch that went through. A step the fused
schedule does not finish itself stops the launch with a code, and the host takes that step by the parallel
schedule, which splits, halves, raises or warns exactly as it always has:
- SPLIT: a body spins so fast that the step must be split (nothing was changed);
- RETRY: the joint correction of a stage failed (iteration limit, divergence, NaN/Inf, or a body turned further
  than max_rotation): the state of the step's start is restored (after a first stage, the host recomputes its
  frames);
- SINGULAR / VELOCITY: the step was taken, but the factor lost a pivot (no further stage is taken) or a velocity
  correction left more than the tolerance (the step is finished): the host raises or warns as the parallel
  schedule does, once a step.
"""

import functools
from types import SimpleNamespace

import warp as wp

from .assemble import assemble_column, augmented_slot
from .carry import carry_into_all, carry_measure_all, commit_carry
from .cholesky import backward_column, factor_column, forward_row
from .constraints import specialized, velocity_error
from .forces import (
    coordinate_geometry,
    drive_wrench,
    implicit_dampers_all,
    integrate_drive,
    kick_body,
    rk4_stage_body,
    spring_wrench,
)
from .impulses import apply_body, impulse_response, step_turn
from .inertia import sym33d, world_inverse_inertia_of
from .iterative import sweep_positions_once, sweep_velocities_once
from .limits import Rows, coupling_entry, limit_error, matrix_entry, resolve_all, row_sides, setup_all
from .loop import diverging
from .rigid import LANES, body_summary, predict_group

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
quatd = wp.quatd
mat33d = wp.mat33d
f64 = wp.float64

# Status row columns.
STATUS_CODE = wp.constant(0)
STATUS_JOINT_ITERATIONS = wp.constant(1)
STATUS_VELOCITY_ITERATIONS = wp.constant(2)
STATUS_JOINT_ERROR = wp.constant(3)
STATUS_VELOCITY_ERROR = wp.constant(4)
STATUS_LINEAR_ITERATIONS = wp.constant(5)
STATUS_SPIN = wp.constant(6)  # rad/s: the largest |w| of the step's last prediction (of t0 when not taken)
STATUS_FAILED_VELOCITY = wp.constant(7)  # the largest velocity error over the tolerance among the stages (VELOCITY)
STATUS_WIDTH = wp.constant(8)
# `factor_state` columns (`cholesky_steps`, `older_factor`): the accepted stages since K was factored; the
# factorizations the kernel made (a count for tests and benchmarks); the stages still to factor at whatever happens (a
# hold after an older factor cost solves) and the next hold's length; the stages the factor in use served without a
# solve more (-1: the last stage's factor was of its start); then, a stage index each, the solves that stage took when
# it last started with K of its own start (-1: not yet).
FACTOR_AGE = wp.constant(0)
FACTOR_COUNT = wp.constant(1)
FACTOR_HOLD = wp.constant(2)
FACTOR_BACKOFF = wp.constant(3)
FACTOR_SERVED = wp.constant(4)
FACTOR_FRESH_SOLVES = wp.constant(5)
FACTOR_HOLD_MAX = wp.constant(64)
FACTOR_PAID = wp.constant(2)  # stages an older factor serves without a solve more to have paid (`older_factor`)
# Status codes.
# Solves a velocity correction takes at most (the direct solver): one is exact with K of the state but for
# round-off, and a second takes up what round-off left where that is over the tolerance (iterative refinement; the
# dm_control humanoid's light bodies left 3.7e-9 m/s against the 3.1e-9 of order 4 at h = 1/80 after one).
VELOCITY_SOLVES = wp.constant(2)

OK = wp.constant(0)
SPLIT = wp.constant(1)
RETRY = wp.constant(2)
SINGULAR = wp.constant(3)
VELOCITY = wp.constant(4)


@wp.struct
class Absent:
    """What a fused kernel takes for `ForceElements` or `Rows` where its scene has none (`fused`): a word where
    those structs' 36 and 35 arrays would be copied in at every launch, unused."""

    none: int


@wp.struct
class ForceElements:
    """A scene's force elements for the fused step (`fused(kinds, forced=True)`): the springs, the drives that
    are forces (`Model.drive_element`) and every drive's PID state, the wrench rows of each body, and the
    coupled RK4 prediction's scratch (`kernels/forces.py`; `Simulator._coupled_prediction` is its parallel
    schedule)."""

    spring_body0: wp.array(dtype=int)
    spring_body1: wp.array(dtype=int)
    spring_anchor0: wp.array(dtype=vec3d)
    spring_anchor1: wp.array(dtype=vec3d)
    spring_params: wp.array(dtype=vec3d)
    coordinate_kind: wp.array(dtype=int)
    coordinate_body0: wp.array(dtype=int)
    coordinate_body1: wp.array(dtype=int)
    coordinate_anchor0: wp.array(dtype=vec3d)
    coordinate_anchor1: wp.array(dtype=vec3d)
    coordinate_axis0: wp.array(dtype=vec3d)
    coordinate_rest_rotation: wp.array(dtype=quatd)
    drive_element: wp.array(dtype=int)
    drive_coordinate: wp.array(dtype=int)
    drive_chain: wp.array(dtype=wp.vec3i)
    drive_ends: wp.array(dtype=wp.vec2i)
    drive_rows: wp.array(dtype=int)  # the coordinate rows the force drives read (`Model.drive_rows`)
    drive_row_point: wp.array(dtype=int)  # whether a drive reads the row's point (`Model.drive_row_point`)
    drive_mode: wp.array(dtype=int)
    drive_gains: wp.array(dtype=vec3d)
    drive_max_force: wp.array(dtype=f64)
    drive_target: wp.array(dtype=f64)
    drive_integral: wp.array(dtype=f64)
    integral0: wp.array(dtype=f64)  # the integrals of the step's start, restored when a stage fails
    body_wrench_start: wp.array(dtype=int)
    body_wrench_rows: wp.array(dtype=int)
    wrench_force: wp.array(dtype=vec3d)
    wrench_torque: wp.array(dtype=vec3d)
    coordinate_world_axis: wp.array(dtype=vec3d)  # at the stage state, by coordinate row (`coordinate_geometry`)
    coordinate_world_point: wp.array(dtype=vec3d)
    stage_x: wp.array(dtype=vec3d)
    stage_q: wp.array(dtype=quatd)
    stage_v: wp.array(dtype=vec3d)
    stage_w: wp.array(dtype=vec3d)
    rk4_sum_x: wp.array(dtype=vec3d)
    rk4_sum_q: wp.array(dtype=quatd)
    rk4_sum_v: wp.array(dtype=vec3d)
    rk4_sum_w: wp.array(dtype=vec3d)
    damper_drive: wp.array(dtype=int)  # the drives whose damping (and stiff spring) is implicit (`dampers.pick`)
    damper_gain: wp.array(dtype=f64)
    damper_spring: wp.array(dtype=f64)


@wp.func
def turns_too_far(spin: f64, h: f64, max_rotation: f64) -> bool:
    """Whether a body spinning at `spin` turns further than max_rotation in a step of h (0: never split)."""
    return max_rotation > f64(0.0) and spin * wp.abs(h) > max_rotation


@wp.func
def save_start(
    body_count: int,
    stage_count: int,
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    x0: wp.array(dtype=vec3d),
    q0: wp.array(dtype=quatd),
    v0: wp.array(dtype=vec3d),
    w0: wp.array(dtype=vec3d),
):
    """Keep what a failed step must restore: the velocities of t0, and for a composed step (stage_count > 1),
    whose later stages start from moved bodies, the poses too."""
    b = wp.int32(0)
    while b < body_count:
        v0[b] = body_v[b]
        w0[b] = body_w[b]
        b += 1
    if stage_count > 1:
        b = wp.int32(0)
        while b < body_count:
            x0[b] = body_x[b]
            q0[b] = body_q[b]
            b += 1


@wp.func
def copy_values(source: wp.array(dtype=f64), target: wp.array(dtype=f64)):
    i = wp.int32(0)
    while i < source.shape[0]:
        target[i] = source[i]
        i += 1


@wp.func
def negate_all(count: int, values: wp.array(dtype=vec3d)):
    """values[i] = -values[i] for the first `count`: the impulses that take back the ones just applied."""
    i = wp.int32(0)
    while i < count:
        values[i] = -values[i]
        i += 1


@wp.func
def zero_values(target: wp.array(dtype=f64)):
    i = wp.int32(0)
    while i < target.shape[0]:
        target[i] = f64(0.0)
        i += 1


@wp.func
def restore_start(
    body_count: int,
    stage: int,
    x0: wp.array(dtype=vec3d),
    q0: wp.array(dtype=quatd),
    v0: wp.array(dtype=vec3d),
    w0: wp.array(dtype=vec3d),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Undo a step that failed in its stage `stage`: the velocities of t0, and the poses after a first stage
    (the frames then are those of the last stage taken: the host recomputes them)."""
    b = wp.int32(0)
    while b < body_count:
        body_v[b] = v0[b]
        body_w[b] = w0[b]
        b += 1
    if stage > 0:
        b = wp.int32(0)
        while b < body_count:
            body_x[b] = x0[b]
            body_q[b] = q0[b]
            b += 1


@wp.func
def traded(
    state_x: wp.array(dtype=vec3d),
    state_q: wp.array(dtype=quatd),
    state_v: wp.array(dtype=vec3d),
    state_w: wp.array(dtype=vec3d),
    next_x: wp.array(dtype=vec3d),
    next_q: wp.array(dtype=quatd),
    next_v: wp.array(dtype=vec3d),
    next_w: wp.array(dtype=vec3d),
):
    """The two states' arrays, the other way round (Warp assigns `a, b = b, a` in turn: both would be b)."""
    return next_x, next_q, next_v, next_w, state_x, state_q, state_v, state_w


@wp.func
def settle(
    body_count: int,
    state_x: wp.array(dtype=vec3d),
    state_q: wp.array(dtype=quatd),
    state_v: wp.array(dtype=vec3d),
    state_w: wp.array(dtype=vec3d),
    body_x_out: wp.array(dtype=vec3d),
    body_q_out: wp.array(dtype=quatd),
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
):
    """Leave the state where the host reads it. An accepted prediction is not copied into the state: the state
    and the prediction's arrays trade places (a pass of 104 bytes read and written a body saved every step), so
    after an odd number of accepted stages the state is in the prediction's arrays, copied back once a launch."""
    if state_x.ptr != body_x_out.ptr:
        b = wp.int32(0)
        while b < body_count:
            body_x_out[b] = state_x[b]
            body_q_out[b] = state_q[b]
            body_v_out[b] = state_v[b]
            body_w_out[b] = state_w[b]
            b += 1


@wp.func
def finish(
    status_out: wp.array2d(dtype=f64),
    k: int,
    code: int,
    joint_iterations: int,
    velocity_iterations: int,
    linear_iterations: int,
    joint_error: f64,
    velocity_error: f64,
    failed_velocity: f64,
    spin: f64,
):
    """Step k's status row, as `Simulator` combines a composed step's stages (`simulator._combined`): iterations
    summed, the largest joint error, the last velocity error; an OK step is also added to the summary row, the
    same way over the steps (errors are >= 0: the largest starts at 0)."""
    status_out[k, STATUS_JOINT_ITERATIONS] = f64(joint_iterations)
    status_out[k, STATUS_VELOCITY_ITERATIONS] = f64(velocity_iterations)
    status_out[k, STATUS_LINEAR_ITERATIONS] = f64(linear_iterations)
    status_out[k, STATUS_JOINT_ERROR] = joint_error
    status_out[k, STATUS_VELOCITY_ERROR] = velocity_error
    status_out[k, STATUS_FAILED_VELOCITY] = failed_velocity
    status_out[k, STATUS_SPIN] = spin
    status_out[k, STATUS_CODE] = f64(code)
    if code == OK:  # the summary row: the OK steps' count, as `Simulator._fused_stats` combines them
        s = status_out.shape[0] - 1
        status_out[s, STATUS_CODE] = status_out[s, STATUS_CODE] + f64(1.0)
        status_out[s, STATUS_JOINT_ITERATIONS] = status_out[s, STATUS_JOINT_ITERATIONS] + f64(joint_iterations)
        status_out[s, STATUS_VELOCITY_ITERATIONS] = status_out[s, STATUS_VELOCITY_ITERATIONS] + f64(velocity_iterations)
        status_out[s, STATUS_LINEAR_ITERATIONS] = status_out[s, STATUS_LINEAR_ITERATIONS] + f64(linear_iterations)
        status_out[s, STATUS_JOINT_ERROR] = wp.max(status_out[s, STATUS_JOINT_ERROR], joint_error)
        status_out[s, STATUS_VELOCITY_ERROR] = velocity_error
        status_out[s, STATUS_SPIN] = spin


@wp.func
def begin_summary(status_out: wp.array2d(dtype=f64)):
    """Zero the status array's summary row (its last) for a new launch (`finish` adds each OK step to it)."""
    s = status_out.shape[0] - 1
    for c in range(STATUS_WIDTH):
        status_out[s, c] = f64(0.0)


@wp.func(inline=True)
def predict_all(
    body_count: int,
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    body_principal: wp.array(dtype=int),
    body_euler: wp.array(dtype=vec3d),
    body_axes: wp.array(dtype=quatd),
    gravity: vec3d,
    h: f64,
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    body_force: wp.array(dtype=vec3d),
    body_torque: wp.array(dtype=vec3d),
    pred_x: wp.array(dtype=vec3d),
    pred_q: wp.array(dtype=quatd),
    pred_v: wp.array(dtype=vec3d),
    pred_w: wp.array(dtype=vec3d),
):
    """Every body's prediction (`predict_group`: LANES bodies at a time)."""
    b0 = wp.int32(0)
    while b0 < body_count:
        predict_group(
            b0, wp.min(LANES, body_count - b0), body_inv_mass, body_inertia, body_inv_inertia, body_principal,
            body_euler, body_axes, gravity, h, body_x, body_q, body_v, body_w, body_force,
            body_torque, pred_x, pred_q, pred_v, pred_w,
        )  # fmt: skip
        b0 += LANES


@wp.func
def element_wrenches(
    el: ForceElements,
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Every force element's wrench rows at the given state: the springs, then the drives (`spring_wrench`,
    `drive_wrench`) with their coordinate rows' axes and points at it (`coordinate_geometry`)."""
    e = wp.int32(0)
    while e < el.drive_rows.shape[0]:
        coordinate_geometry(
            e, el.drive_rows, el.drive_row_point, el.coordinate_kind, el.coordinate_body0, el.coordinate_body1,
            el.coordinate_anchor0, el.coordinate_anchor1, el.coordinate_axis0, body_x, body_q,
            el.coordinate_world_axis, el.coordinate_world_point,
        )  # fmt: skip
        e += 1
    springs = el.spring_body0.shape[0]
    e = wp.int32(0)
    while e < springs:
        spring_wrench(
            e, el.spring_body0, el.spring_body1, el.spring_anchor0, el.spring_anchor1, el.spring_params, body_x,
            body_q, body_v, body_w, el.wrench_force, el.wrench_torque,
        )  # fmt: skip
        e += 1
    e = wp.int32(0)
    while e < el.drive_element.shape[0]:
        drive_wrench(
            e, springs, el.coordinate_kind, el.coordinate_body0, el.coordinate_body1, el.coordinate_anchor0,
            el.coordinate_anchor1, el.coordinate_axis0, el.coordinate_rest_rotation, el.drive_element,
            el.drive_coordinate, el.drive_chain, el.drive_ends, el.drive_mode, el.drive_gains, el.drive_max_force,
            el.drive_target, el.drive_integral, body_x, body_q, body_v, body_w, el.coordinate_world_axis,
            el.coordinate_world_point, el.wrench_force, el.wrench_torque,
        )  # fmt: skip
        e += 1


@wp.func
def rk4_stage_all(
    stage: int,
    body_count: int,
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    gravity: vec3d,
    h: f64,
    el: ForceElements,
    start_x: wp.array(dtype=vec3d),
    start_q: wp.array(dtype=quatd),
    start_v: wp.array(dtype=vec3d),
    start_w: wp.array(dtype=vec3d),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    body_force: wp.array(dtype=vec3d),
    body_torque: wp.array(dtype=vec3d),
    out_x: wp.array(dtype=vec3d),
    out_q: wp.array(dtype=quatd),
    out_v: wp.array(dtype=vec3d),
    out_w: wp.array(dtype=vec3d),
):
    b = wp.int32(0)
    while b < body_count:
        rk4_stage_body(
            b, stage, h, body_inv_mass, body_inertia, body_inv_inertia, gravity, el.body_wrench_start,
            el.body_wrench_rows, start_x, start_q, start_v, start_w, body_x, body_q, body_v, body_w, body_force,
            body_torque, el.wrench_force, el.wrench_torque, el.rk4_sum_x, el.rk4_sum_q, el.rk4_sum_v, el.rk4_sum_w,
            out_x, out_q, out_v, out_w,
        )  # fmt: skip
        b += 1


@wp.func(inline=True)
def coupled_predict_all(
    body_count: int,
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    gravity: vec3d,
    h: f64,
    el: ForceElements,
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    body_force: wp.array(dtype=vec3d),
    body_torque: wp.array(dtype=vec3d),
    pred_x: wp.array(dtype=vec3d),
    pred_q: wp.array(dtype=quatd),
    pred_v: wp.array(dtype=vec3d),
    pred_w: wp.array(dtype=vec3d),
):
    """RK4 over all bodies at once, the force elements evaluated at every stage state, then the implicit
    dampers on the prediction: the launches of `Simulator._coupled_prediction` in the same order (stage 0 from
    the state, the next stage states in el.stage_*, the last into the prediction). Inlined at its two calls in
    the fused step: called, it took `ForceElements` and 20 arrays by value (3 KB copied a call), and the step
    around it kept less in registers (the reacher's steps 5-8% faster inlined)."""
    stage = wp.int32(0)
    while stage < 4:  # a loop, not unrolled: one copy of the elements' and the stages' code
        first = stage == 0
        last = stage == 3
        in_x = wp.where(first, body_x, el.stage_x)
        in_q = wp.where(first, body_q, el.stage_q)
        in_v = wp.where(first, body_v, el.stage_v)
        in_w = wp.where(first, body_w, el.stage_w)
        element_wrenches(el, in_x, in_q, in_v, in_w)
        rk4_stage_all(
            stage, body_count, body_inv_mass, body_inertia, body_inv_inertia, gravity, h, el, body_x, body_q, body_v,
            body_w, in_x, in_q, in_v, in_w, body_force, body_torque, wp.where(last, pred_x, el.stage_x),
            wp.where(last, pred_q, el.stage_q), wp.where(last, pred_v, el.stage_v), wp.where(last, pred_w, el.stage_w),
        )  # fmt: skip
        stage += 1
    dampers_on_prediction(h, el, body_inv_mass, body_inv_inertia, pred_x, pred_q, pred_v, pred_w)


@wp.func
def dampers_on_prediction(
    h: f64,
    el: ForceElements,
    body_inv_mass: wp.array(dtype=f64),
    body_inv_inertia: wp.array(dtype=mat33d),
    pred_x: wp.array(dtype=vec3d),
    pred_q: wp.array(dtype=quatd),
    pred_v: wp.array(dtype=vec3d),
    pred_w: wp.array(dtype=vec3d),
):
    """The implicit dampers (`dampers.pick`: stiff for the step) on a prediction of h, after its RK4 (coupled, or
    each body's own beside kicks)."""
    implicit_dampers_all(
        h, el.damper_drive, el.damper_gain, el.damper_spring, el.drive_coordinate, el.drive_chain, el.drive_ends,
        el.drive_mode, el.drive_target, el.coordinate_kind, el.coordinate_body0, el.coordinate_body1,
        el.coordinate_anchor0, el.coordinate_anchor1, el.coordinate_axis0, el.coordinate_rest_rotation, body_inv_mass,
        body_inv_inertia, pred_x, pred_q, pred_v, pred_w,
    )  # fmt: skip


@wp.func
def integrate_drives_all(
    h: f64,
    el: ForceElements,
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Every drive's PID integral at the accepted state (`integrate_drive`)."""
    e = wp.int32(0)
    while e < el.drive_coordinate.shape[0]:
        integrate_drive(
            e, h, el.coordinate_kind, el.coordinate_body0, el.coordinate_body1, el.coordinate_anchor0,
            el.coordinate_anchor1, el.coordinate_axis0, el.coordinate_rest_rotation, el.drive_coordinate,
            el.drive_mode, el.drive_gains, el.drive_max_force, el.drive_target, body_x, body_q, body_v, body_w,
            el.drive_integral,
        )  # fmt: skip
        e += 1


@wp.func
def kick_all(
    body_count: int,
    dt: f64,
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia_world: wp.array(dtype=sym33d),
    el: ForceElements,
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    formed: bool,
):
    """Every force element's wrench at the state's poses, acting on the bodies for dt (s): the half kick at each
    end of a split base step (`kick_body`; the frames' world inverse inertias are the state's). `formed`: the
    wrench rows already hold the elements' wrenches at these poses (the last stage's second kick; a kick's
    elements read no velocity), and are not formed again."""
    if not formed:
        element_wrenches(el, body_x, body_q, body_v, body_w)
    b = wp.int32(0)
    while b < body_count:
        kick_body(
            b, dt, body_inv_mass, inv_inertia_world, el.body_wrench_start, el.body_wrench_rows, el.wrench_force,
            el.wrench_torque, body_v, body_w,
        )  # fmt: skip
        b += 1


@wp.func
def apply_all(
    body_count: int,
    constraint_kind: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    body_rows_start: wp.array(dtype=int),
    body_rows: wp.array(dtype=int),
    inv_inertia_world: wp.array(dtype=sym33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
    impulse: wp.array(dtype=vec3d),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    b = wp.int32(0)
    while b < body_count:
        apply_body(
            b, constraint_kind, body_inv_mass, body_rows_start, body_rows, inv_inertia_world, jac_lin, jac_ang,
            jac_skew, impulse, body_v, body_w,
        )  # fmt: skip
        b += 1


@wp.func
def apply_and_predict_all(
    body_count: int,
    constraint_kind: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    body_principal: wp.array(dtype=int),
    body_euler: wp.array(dtype=vec3d),
    body_axes: wp.array(dtype=quatd),
    gravity: vec3d,
    h: f64,
    body_rows_start: wp.array(dtype=int),
    body_rows: wp.array(dtype=int),
    inv_inertia_world: wp.array(dtype=sym33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
    impulse: wp.array(dtype=vec3d),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    body_force: wp.array(dtype=vec3d),
    body_torque: wp.array(dtype=vec3d),
    pred_x: wp.array(dtype=vec3d),
    pred_q: wp.array(dtype=quatd),
    pred_v: wp.array(dtype=vec3d),
    pred_w: wp.array(dtype=vec3d),
):
    """`apply_all` then `predict_all` in one pass over the bodies: a body's prediction reads only its own
    velocities, which only its own impulses change, so the result is the two passes' bit for bit. The bodies
    go LANES at a time (`predict_group`)."""
    b0 = wp.int32(0)
    while b0 < body_count:
        count = wp.min(LANES, body_count - b0)
        b = b0
        while b < b0 + count:
            apply_body(
                b, constraint_kind, body_inv_mass, body_rows_start, body_rows, inv_inertia_world, jac_lin, jac_ang,
                jac_skew, impulse, body_v, body_w,
            )  # fmt: skip
            b += 1
        predict_group(
            b0, count, body_inv_mass, body_inertia, body_inv_inertia, body_principal, body_euler, body_axes, gravity,
            h, body_x, body_q, body_v, body_w, body_force, body_torque, pred_x, pred_q, pred_v, pred_w,
        )  # fmt: skip
        b0 += LANES


@wp.func
def velocity_errors_all(
    constraint_count: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    errors: wp.array(dtype=f64),
    rhs: wp.array(dtype=vec3d),
) -> f64:
    """|J_i v| and -J_i v of every constraint; returns the largest (NaN if any is)."""
    worst = f64(0.0)
    i = wp.int32(0)
    while i < constraint_count:
        velocity_error(
            i,
            constraint_kind,
            constraint_body0,
            constraint_body1,
            jac_lin,
            jac_ang,
            jac_skew,
            body_v,
            body_w,
            errors,
            rhs,
        )
        worst = max_or_nan(worst, errors[i])
        i += 1
    return worst


@wp.func
def limit_errors_all(
    h: f64,
    rows: Rows,
    pred_x: wp.array(dtype=vec3d),
    pred_q: wp.array(dtype=quatd),
    pred_v: wp.array(dtype=vec3d),
    pred_w: wp.array(dtype=vec3d),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
) -> f64:
    """Every row's error at the prediction, from the state at t0 (`limit_error`); returns the largest (NaN if
    any is)."""
    worst = f64(0.0)
    i = wp.int32(0)
    while i < rows.limit_coordinate.shape[0]:
        err = limit_error(i, h, pred_x, pred_q, pred_v, pred_w, body_x, body_q, body_v, body_w, rows)
        worst = max_or_nan(worst, err)
        i += 1
    return worst


@wp.func
def row_sides_all(
    rows: Rows,
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """Every row's Jacobian g at the state (`row_sides`), and none of c, K^-1 c and S formed for its factor yet:
    `correct_rows_all` forms a row's as a pass first makes it active."""
    l = wp.int32(0)
    while l < rows.limit_coordinate.shape[0]:
        row_sides(
            l, rows.coordinate_kind, rows.coordinate_body0, rows.coordinate_body1, rows.coordinate_anchor0,
            rows.coordinate_anchor1, rows.coordinate_axis0, rows.coordinate_rest_rotation, rows.limit_coordinate,
            body_x, body_q, body_v, body_w, rows.limit_side_body, rows.limit_side_lin, rows.limit_side_ang,
        )  # fmt: skip
        rows.limit_formed[l] = 0
        l += 1


@wp.func
def max_or_nan(a: f64, b: f64) -> f64:
    """max(a, b), NaN when either is NaN (so a non-finite error is never taken for a converged one)."""
    if not wp.isfinite(b) or not wp.isfinite(a):
        return a + b
    return wp.max(a, b)


@wp.func
def stale_rate(factor_state: wp.array(dtype=int), refactor_every: int, err: f64, last: f64, rate: f64) -> bool:
    """Whether a joint solve with an older factor of K left more than `rate` times the error before it: the
    quasi-Newton iteration has slowed (or diverges), and K is to be factored at the stage's start, where the
    frames still are (the loop then goes on from the impulses so far, or, where that solve made the error grow,
    from before it: `negate_all`)."""
    return refactor_every > 1 and factor_state[FACTOR_AGE] > 0 and not (err <= rate * last)


@wp.func
def older_factor(
    factor_state: wp.array(dtype=int),
    refactor_every: int,
    corrected: bool,
    stage: int,
    tries: int,
    fresh: bool,
    rescued: bool,
) -> bool:
    """At a stage's accepted state: whether the factor in use serves on, the record updated (`factor_state`).

    A stage whose correction began with K of its own start (`fresh`), as did the stage before it, sets the solves its
    index takes (the first fresh stage after older factors does not: the carried right-hand side, `carry`, which took up
    the older factor's error, still leaves it a solve more); until its index has that count, K is factored at every
    stage. One that began with an older factor and took no more has the factor serve on; one that took more, or had K
    factored midway (`rescued`, `stale_rate`), has K factored here. Where the older factor had served fewer than
    FACTOR_PAID stages before, it saved fewer factorizations than the solve it cost (assembly and factor ~265 ns a body
    on a hinge chain, a solve with its prediction ~175; on the paper's tree 112 and 121): K is then factored at every
    stage for a hold that doubles at each such failure (1, 3, 7, ... FACTOR_HOLD_MAX stages), so that where an older
    factor never pays (large steps of a whipping chain) it is tried once in FACTOR_HOLD_MAX stages; a factor that paid,
    or served `refactor_every` stages, ends the holds. Besides, K is factored at every `refactor_every`-th stage and
    where the velocities are `corrected` (its one solve is exact only with K of this state)."""
    fresh_solves = factor_state[FACTOR_FRESH_SOLVES + stage]
    backoff = factor_state[FACTOR_BACKOFF]
    hold = factor_state[FACTOR_HOLD]
    served = factor_state[FACTOR_SERVED]  # -1: this stage's factor is of its start (`fresh`)
    if fresh and not rescued:
        if served < 0:  # the stage before was fresh too
            factor_state[FACTOR_FRESH_SOLVES + stage] = tries
            fresh_solves = tries
        served = -1
        if fresh_solves < 0:
            hold = wp.max(hold, 1)
    elif rescued or (fresh_solves >= 0 and tries > fresh_solves):
        if served >= FACTOR_PAID:
            backoff = 0
        else:
            backoff = wp.min(2 * backoff + 1, FACTOR_HOLD_MAX)
        hold = wp.max(backoff, 1)  # this stage's factorization at least
        served = 0
    else:
        served = wp.max(served, 0) + 1
    age = factor_state[FACTOR_AGE] + 1
    if age >= refactor_every:
        backoff = 0
    if age >= refactor_every or corrected or hold > 0:
        age = 0
    if hold > 0:
        hold -= 1
    factor_state[FACTOR_AGE] = age
    factor_state[FACTOR_HOLD] = hold
    factor_state[FACTOR_BACKOFF] = backoff
    factor_state[FACTOR_SERVED] = served
    return age > 0


@wp.func
def assemble_and_factor(
    augmented: int,
    perm: wp.array(dtype=int),
    col_start: wp.array(dtype=int),
    update_start: wp.array(dtype=int),
    update_target: wp.array(dtype=int),
    update_a: wp.array(dtype=int),
    update_b: wp.array(dtype=int),
    update_sign: wp.array(dtype=f64),
    col_sign: wp.array(dtype=f64),
    col_loop: wp.array(dtype=int),
    slot_shape: wp.array(dtype=wp.vec2i),
    slot_row: wp.array(dtype=int),
    slot_sides: wp.array(dtype=wp.vec4i),
    slot_code: wp.array(dtype=int),
    slot_ref: wp.array(dtype=int),
    pivot_tolerance: f64,
    loop_tolerance: f64,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia_world: wp.array(dtype=sym33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
    values: wp.array(dtype=mat33d),
    singular: wp.array(dtype=int),
):
    """K = J M^-1 J^T (or the augmented matrix, `augmented_slot`) at the current frames, factored in place a
    column at a time (`assemble_column`, `factor_column`: `CholeskySolver.prepare`'s kernels)."""
    s = wp.int32(0)
    while s < slot_code.shape[0]:
        augmented_slot(
            s, constraint_kind, body_inv_mass, slot_code, slot_ref, inv_inertia_world, jac_lin, jac_ang, jac_skew,
            values,
        )  # fmt: skip
        s += 1
    singular[1] = 0  # the redundant loop rows of this factorization (`CholeskySolver.check`)
    j = wp.int32(0)
    columns = col_start.shape[0] - 1
    while j < columns:
        if slot_row.shape[0] > 0:
            assemble_column(
                j, perm, col_start, constraint_kind, constraint_body0, constraint_body1, body_inv_mass, slot_row,
                slot_sides, inv_inertia_world, jac_lin, jac_ang, jac_skew, values,
            )  # fmt: skip
        factor_column(
            j, augmented, col_start, update_start, update_target, update_a, update_b, update_sign, col_sign, col_loop,
            slot_shape, pivot_tolerance, loop_tolerance, values, singular,
        )  # fmt: skip
        j += 1


@wp.func
def cholesky_solve(
    augmented: int,
    offset: int,
    constraint_count: int,
    perm: wp.array(dtype=int),
    col_start: wp.array(dtype=int),
    col_row: wp.array(dtype=int),
    col_sign: wp.array(dtype=f64),
    row_start: wp.array(dtype=int),
    row_slot: wp.array(dtype=int),
    row_col: wp.array(dtype=int),
    values: wp.array(dtype=mat33d),
    work: wp.array(dtype=vec3d),
    aug_rhs: wp.array(dtype=vec3d),
    aug_x: wp.array(dtype=vec3d),
    rhs: wp.array(dtype=vec3d),
    impulse: wp.array(dtype=vec3d),
):
    """K impulse = rhs with the stored factor: rows forward, columns backward (`CholeskySolver.solve`). The
    augmented matrix takes [0; -rhs] and gives the impulses in its constraint part."""
    n = col_start.shape[0] - 1
    if augmented != 0:
        i = wp.int32(0)
        while i < constraint_count:
            aug_rhs[offset + i] = f64(-1.0) * rhs[i]
            i += 1
        j = wp.int32(0)
        while j < n:
            forward_row(j, perm, col_start, row_start, row_slot, row_col, values, aug_rhs, work)
            j += 1
        jj = wp.int32(0)
        while jj < n:
            backward_column(n - 1 - jj, perm, col_start, col_row, col_sign, values, work, aug_x)
            jj += 1
        i = wp.int32(0)
        while i < constraint_count:
            impulse[i] = f64(1.0) * aug_x[offset + i]
            i += 1
    else:
        j = wp.int32(0)
        while j < n:
            forward_row(j, perm, col_start, row_start, row_slot, row_col, values, rhs, work)
            j += 1
        jj = wp.int32(0)
        while jj < n:
            backward_column(n - 1 - jj, perm, col_start, col_row, col_sign, values, work, impulse)
            jj += 1


@wp.func
def correct_rows_all(
    velocity: int,
    h: f64,
    constraint_count: int,
    rows: Rows,
    body_inv_mass: wp.array(dtype=f64),
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    inv_inertia_world: wp.array(dtype=sym33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
    augmented: int,
    offset: int,
    perm: wp.array(dtype=int),
    col_start: wp.array(dtype=int),
    col_row: wp.array(dtype=int),
    col_sign: wp.array(dtype=f64),
    row_start: wp.array(dtype=int),
    row_slot: wp.array(dtype=int),
    row_col: wp.array(dtype=int),
    values: wp.array(dtype=mat33d),
    work: wp.array(dtype=vec3d),
    aug_rhs: wp.array(dtype=vec3d),
    aug_x: wp.array(dtype=vec3d),
):
    """The rows' position (`velocity` 0) or velocity (1) pass with the joints' reaction (`limits.correct_rows`'
    two halves), and between them, for each row the pass made active (limit_mask) that the factor has not served
    yet, its c = J M^-1 g^T (`coupling_entry`), K^-1 c (one solve with the factor) and its entries of S with every
    row formed before (`matrix_entry`): only active rows' entries are read (`resolve_all`), and a robot's limits
    are mostly slack, where forming S whole took one solve a row a stage (gymnasium's humanoid, 17 limits: 93 ->
    70 us a step). Each entry is the one the whole S would hold, bit for bit."""
    setup_all(velocity, h, body_x, body_q, body_v, body_w, rows)
    nl = rows.limit_coordinate.shape[0]
    l = wp.int32(0)
    while l < nl:
        if rows.limit_mask[l] != 0 and rows.limit_formed[l] == 0:
            i = wp.int32(0)
            while i < constraint_count:
                coupling_entry(
                    l, i, body_inv_mass, constraint_kind, constraint_body0, constraint_body1, rows.limit_side_body,
                    rows.limit_side_lin, rows.limit_side_ang, inv_inertia_world, jac_lin, jac_ang, jac_skew,
                    rows.limit_coupling,
                )  # fmt: skip
                i += 1
            cholesky_solve(
                augmented, offset, constraint_count, perm, col_start, col_row, col_sign, row_start, row_slot, row_col,
                values, work, aug_rhs, aug_x, rows.coupling_rows[l], rows.response_rows[l],
            )  # fmt: skip
            rows.limit_formed[l] = 1
            k = wp.int32(0)
            while k < nl:
                if rows.limit_formed[k] != 0:
                    matrix_entry(
                        k, l, 1, body_inv_mass, rows.limit_side_body, rows.limit_side_lin, rows.limit_side_ang,
                        inv_inertia_world, rows.limit_coupling, rows.limit_response, rows.limit_matrix,
                    )  # fmt: skip
                    if k != l:
                        matrix_entry(
                            l, k, 1, body_inv_mass, rows.limit_side_body, rows.limit_side_lin, rows.limit_side_ang,
                            inv_inertia_world, rows.limit_coupling, rows.limit_response, rows.limit_matrix,
                        )  # fmt: skip
                k += 1
        l += 1
    resolve_all(
        velocity, 1, body_inv_mass, constraint_kind, constraint_body0, constraint_body1, inv_inertia_world,
        jac_lin, jac_ang, jac_skew, body_x, body_q, body_v, body_w, rows,
    )  # fmt: skip


@wp.func
def velocity_solve(
    body_count: int,
    constraint_count: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    body_rows_start: wp.array(dtype=int),
    body_rows: wp.array(dtype=int),
    augmented: int,
    offset: int,
    perm: wp.array(dtype=int),
    col_start: wp.array(dtype=int),
    col_row: wp.array(dtype=int),
    col_sign: wp.array(dtype=f64),
    row_start: wp.array(dtype=int),
    row_slot: wp.array(dtype=int),
    row_col: wp.array(dtype=int),
    values: wp.array(dtype=mat33d),
    work: wp.array(dtype=vec3d),
    aug_rhs: wp.array(dtype=vec3d),
    aug_x: wp.array(dtype=vec3d),
    inv_inertia_world: wp.array(dtype=sym33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
    errors: wp.array(dtype=f64),
    rhs: wp.array(dtype=vec3d),
    impulse: wp.array(dtype=vec3d),
    state_v: wp.array(dtype=vec3d),
    state_w: wp.array(dtype=vec3d),
    verr: f64,
    tolerance: f64,
):
    """The velocity correction (the paper's section 4.2) of the velocity errors `velocity_errors_all` left in
    `rhs`, the largest `verr` (m/s or rad/s) over `tolerance`: the impulses that cancel them, with the factor of
    the state's K, applied through its Jacobians; exact but for round-off, which a solve more takes up where it
    left more than the tolerance (`VELOCITY_SOLVES`). Returns the largest velocity error after them and the
    solves."""
    solves = wp.int32(0)
    while solves < VELOCITY_SOLVES and not (verr <= tolerance):
        cholesky_solve(
            augmented, offset, constraint_count, perm, col_start, col_row, col_sign, row_start, row_slot, row_col,
            values, work, aug_rhs, aug_x, rhs, impulse,
        )  # fmt: skip
        apply_all(
            body_count, constraint_kind, body_inv_mass, body_rows_start, body_rows, inv_inertia_world, jac_lin,
            jac_ang, jac_skew, impulse, state_v, state_w,
        )  # fmt: skip
        verr = velocity_errors_all(
            constraint_count, constraint_kind, constraint_body0, constraint_body1, jac_lin, jac_ang, jac_skew,
            state_v, state_w, errors, rhs,
        )  # fmt: skip
        solves += 1
    return verr, solves


@functools.cache
def fused(kinds: frozenset[int], forced: bool = False, rows: bool = False, kicked: bool = False) -> SimpleNamespace:
    """The fused step kernels for a set of constraint kinds (`constraints.specialized(kinds)`'s stage funcs):
    `cholesky_steps` (the direct solver, either formulation) and `iterative_steps` (the paper's sweeps), and the
    kind-dependent serial stages they call (`benchmarks/step_breakdown.py` times each). `forced`: the scene has
    force elements (springs, joint springs, PID drives), so the prediction is the coupled RK4 of all bodies
    (`coupled_predict_all`) and each accepted stage integrates the drives; the iterative baseline has none.
    `rows`: the scene has joint limits, stiff motors or distance constraints (`Rows`, kernels/limits.py), rows of
    the correction loop solved after the joints in each iteration, then after the velocity correction, on their
    own system S, formed with the factor at each new state; the host passes one stage (the parallel schedule
    takes such steps at order 2: impacts and saturation are not reversible). `kicked`: the force elements depend on
    the poses alone, and act as two half kicks about each base step, whose prediction is each body's own with the
    implicit dampers on it (`kick_all`, `Simulator`'s `split_forces`; the simulator never sets it with `forced`).
    The iterative baseline has none."""
    ck = specialized(kinds)
    Elements = ForceElements if forced or kicked else Absent  # noqa: N806 (the types of two kernel arguments)
    LimitRows = Rows if rows else Absent  # noqa: N806
    flags = "".join(f"_{name}" for name, on in (("forced", forced), ("rows", rows), ("kicked", kicked)) if on)
    module = f"{__name__}.kinds_{'_'.join(map(str, ck.kinds))}{flags}"
    wp.set_module_options({"enable_backward": False}, module)
    frame = ck.frame
    position_error = ck.position_error
    arm_correction = ck.arm_correction

    @wp.func(module=module)
    def position_errors_all(
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
        inv_h: f64,
        proj: wp.array(dtype=mat33d),
        pred_x: wp.array(dtype=vec3d),
        pred_q: wp.array(dtype=quatd),
        errors: wp.array(dtype=f64),
        rhs: wp.array(dtype=vec3d),
    ) -> f64:
        """The joint errors of the prediction and -P d / h; returns the largest (NaN if any is)."""
        worst = f64(0.0)
        i = wp.int32(0)
        while i < constraint_count:
            position_error(
                i, constraint_kind, constraint_body0, constraint_body1, constraint_anchor0, constraint_anchor1,
                constraint_axis0, constraint_axis1, constraint_rest_rotation, constraint_rest_angle, inv_h, proj,
                pred_x, pred_q, errors, rhs,
            )  # fmt: skip
            worst = max_or_nan(worst, errors[i])
            i += 1
        return worst

    @wp.func(module=module)
    def frames_all(
        body_count: int,
        constraint_count: int,
        body_principal: wp.array(dtype=int),
        body_inv_principal: wp.array(dtype=vec3d),
        body_inv_inertia: wp.array(dtype=mat33d),
        constraint_kind: wp.array(dtype=int),
        constraint_body0: wp.array(dtype=int),
        constraint_body1: wp.array(dtype=int),
        constraint_anchor0: wp.array(dtype=vec3d),
        constraint_anchor1: wp.array(dtype=vec3d),
        constraint_axis0: wp.array(dtype=vec3d),
        constraint_axis1: wp.array(dtype=vec3d),
        body_x: wp.array(dtype=vec3d),
        body_q: wp.array(dtype=quatd),
        inv_inertia_world: wp.array(dtype=sym33d),
        proj: wp.array(dtype=mat33d),
        jac_lin: wp.array(dtype=mat33d),
        jac_ang: wp.array(dtype=mat33d),
        jac_skew: wp.array(dtype=vec3d),
    ):
        """World inverse inertias, P_i and J_ib at the current state."""
        b = wp.int32(0)
        while b < body_count:
            world_inverse_inertia_of(b, body_principal, body_inv_principal, body_inv_inertia, body_q, inv_inertia_world)
            b += 1
        i = wp.int32(0)
        while i < constraint_count:
            frame(
                i, constraint_kind, constraint_body0, constraint_body1, constraint_anchor0, constraint_anchor1,
                constraint_axis0, constraint_axis1, body_x, body_q, proj, jac_lin, jac_ang, jac_skew,
            )  # fmt: skip
            i += 1

    @wp.func(module=module)
    def newton_rhs_all(
        body_count: int,
        constraint_count: int,
        constraint_kind: wp.array(dtype=int),
        body_inv_mass: wp.array(dtype=f64),
        body_rows_start: wp.array(dtype=int),
        body_rows: wp.array(dtype=int),
        constraint_body0: wp.array(dtype=int),
        constraint_body1: wp.array(dtype=int),
        constraint_anchor0: wp.array(dtype=vec3d),
        constraint_anchor1: wp.array(dtype=vec3d),
        constraint_axis0: wp.array(dtype=vec3d),
        constraint_axis1: wp.array(dtype=vec3d),
        constraint_rest_rotation: wp.array(dtype=quatd),
        constraint_rest_angle: wp.array(dtype=f64),
        h: f64,
        proj: wp.array(dtype=mat33d),
        inv_inertia_world: wp.array(dtype=sym33d),
        jac_lin: wp.array(dtype=mat33d),
        jac_ang: wp.array(dtype=mat33d),
        jac_skew: wp.array(dtype=vec3d),
        impulse: wp.array(dtype=vec3d),
        state_w: wp.array(dtype=vec3d),
        pred_x: wp.array(dtype=vec3d),
        pred_q: wp.array(dtype=quatd),
        rhs: wp.array(dtype=vec3d),
        response_v: wp.array(dtype=vec3d),
        response_w: wp.array(dtype=vec3d),
        response_turn: wp.array(dtype=vec3d),
        newton_rhs: wp.array(dtype=vec3d),
    ):
        """The Newton step's right-hand side rhs - E lambda of the impulses just solved (`impulse_response`,
        `arm_correction`); solved with K, it gives the first iteration's impulses."""
        b = wp.int32(0)
        while b < body_count:
            dv, dw = impulse_response(
                b, constraint_kind, body_inv_mass, body_rows_start, body_rows, inv_inertia_world, jac_lin, jac_ang,
                jac_skew, impulse,
            )  # fmt: skip
            response_v[b] = dv
            response_w[b] = dw
            response_turn[b] = step_turn(dw, h, state_w[b], inv_inertia_world[b])
            b += 1
        i = wp.int32(0)
        while i < constraint_count:
            newton_rhs[i] = rhs[i] - arm_correction(
                i, constraint_kind, constraint_body0, constraint_body1, constraint_anchor0, constraint_anchor1,
                constraint_axis0, constraint_axis1, constraint_rest_rotation, constraint_rest_angle, h, proj, pred_x,
                pred_q, jac_lin, jac_ang, jac_skew, response_v, response_w, response_turn,
            )  # fmt: skip
            i += 1

    @wp.func(module=module)
    def summary_all(
        body_count: int,
        pred_x: wp.array(dtype=vec3d),
        pred_q: wp.array(dtype=quatd),
        pred_v: wp.array(dtype=vec3d),
        pred_w: wp.array(dtype=vec3d),
    ):
        """(bodies with a NaN or Inf, the largest finite |w|) of the prediction (`rigid.summarize_state`)."""
        bad = wp.int32(0)
        spin = f64(0.0)
        b = wp.int32(0)
        while b < body_count:
            finite, w = body_summary(b, pred_x, pred_q, pred_v, pred_w)
            if finite:
                spin = wp.max(spin, w)
            else:
                bad += 1
            b += 1
        return bad, spin

    @wp.kernel(module=module)
    def cholesky_steps(
        # Model:
        body_count: int,
        constraint_count: int,
        body_inv_mass: wp.array(dtype=f64),
        body_inertia: wp.array(dtype=mat33d),
        body_inv_inertia: wp.array(dtype=mat33d),
        body_principal: wp.array(dtype=int),
        body_euler: wp.array(dtype=vec3d),
        body_inv_principal: wp.array(dtype=vec3d),
        body_axes: wp.array(dtype=quatd),
        gravity: vec3d,
        body_rows_start: wp.array(dtype=int),
        body_rows: wp.array(dtype=int),
        constraint_kind: wp.array(dtype=int),
        constraint_body0: wp.array(dtype=int),
        constraint_body1: wp.array(dtype=int),
        constraint_anchor0: wp.array(dtype=vec3d),
        constraint_anchor1: wp.array(dtype=vec3d),
        constraint_axis0: wp.array(dtype=vec3d),
        constraint_axis1: wp.array(dtype=vec3d),
        constraint_rest_rotation: wp.array(dtype=quatd),
        constraint_rest_angle: wp.array(dtype=f64),
        # Pattern (`CholeskySolver`):
        augmented: int,
        offset: int,
        pivot_tolerance: f64,
        loop_tolerance: f64,
        perm: wp.array(dtype=int),
        col_start: wp.array(dtype=int),
        col_row: wp.array(dtype=int),
        col_sign: wp.array(dtype=f64),
        col_loop: wp.array(dtype=int),
        update_start: wp.array(dtype=int),
        update_target: wp.array(dtype=int),
        update_a: wp.array(dtype=int),
        update_b: wp.array(dtype=int),
        update_sign: wp.array(dtype=f64),
        row_start: wp.array(dtype=int),
        row_slot: wp.array(dtype=int),
        row_col: wp.array(dtype=int),
        slot_shape: wp.array(dtype=wp.vec2i),
        slot_row: wp.array(dtype=int),
        slot_col: wp.array(dtype=int),
        slot_sides: wp.array(dtype=wp.vec4i),
        slot_code: wp.array(dtype=int),
        slot_ref: wp.array(dtype=int),
        # Settings:
        h: f64,
        stages: wp.array(dtype=f64),
        reach: f64,
        batch_in: wp.array(dtype=int),
        defer: int,
        tolerance: f64,
        velocity_tolerance: f64,
        max_iterations: int,
        max_rotation: f64,
        final: int,
        spin_in: wp.array(dtype=f64),
        body_force_in: wp.array(dtype=vec3d),
        body_torque_in: wp.array(dtype=vec3d),
        elements: Elements,  # `Absent` without `forced`
        limit_rows: LimitRows,  # `Absent` without `rows`
        # Scratch: the prediction, the velocities of t0, errors, right-hand sides, impulses, the factor
        pred_x: wp.array(dtype=vec3d),
        pred_q: wp.array(dtype=quatd),
        pred_v: wp.array(dtype=vec3d),
        pred_w: wp.array(dtype=vec3d),
        x0: wp.array(dtype=vec3d),
        q0: wp.array(dtype=quatd),
        v0: wp.array(dtype=vec3d),
        w0: wp.array(dtype=vec3d),
        errors: wp.array(dtype=f64),
        rhs: wp.array(dtype=vec3d),
        impulse: wp.array(dtype=vec3d),
        values: wp.array(dtype=mat33d),
        work: wp.array(dtype=vec3d),
        aug_rhs: wp.array(dtype=vec3d),
        aug_x: wp.array(dtype=vec3d),
        singular: wp.array(dtype=int),
        # Frames at t0, then at each new state:
        inv_inertia_world: wp.array(dtype=sym33d),
        proj: wp.array(dtype=mat33d),
        jac_lin: wp.array(dtype=mat33d),
        jac_ang: wp.array(dtype=mat33d),
        jac_skew: wp.array(dtype=vec3d),
        # The first iteration's Newton step (`newton` != 0): the bodies' response to its impulses, its rhs
        newton: int,
        response_v: wp.array(dtype=vec3d),
        response_w: wp.array(dtype=vec3d),
        response_turn: wp.array(dtype=vec3d),
        newton_rhs: wp.array(dtype=vec3d),
        # The first iteration's carried right-hand side (`carrying` != 0, kernels/carry.py): a row of c for each
        # stage's step size (stage_carry[stage]), and the rows measured this step, taken when it is accepted
        carrying: int,
        stage_carry: wp.array(dtype=int),
        carry: wp.array2d(dtype=vec3d),
        carry_next: wp.array2d(dtype=vec3d),
        carry_past: wp.array2d(dtype=vec3d),
        # K factored at every `refactor_every`-th accepted stage's state (1: at each), and at a stage's start where
        # a joint solve with the older factor left more than stale_factor_rate of the error before it; its record
        refactor_every: int,
        stale_factor_rate: f64,
        factor_state: wp.array(dtype=int),
        # Data out: the state, advanced in place, and a status row a step
        body_x_out: wp.array(dtype=vec3d),
        body_q_out: wp.array(dtype=quatd),
        body_v_out: wp.array(dtype=vec3d),
        body_w_out: wp.array(dtype=vec3d),
        status_out: wp.array2d(dtype=f64),
    ):
        """Up to batch_in[0] steps of h, from a fastest spin of spin_in[0] (rad/s), the velocities corrected in
        every stage (`defer` 0) or in the last stage of the last step only, when batch_in[1] says that step's state
        is handed out (`defer` 1; a deferred step's status row has no velocity iteration and a NaN velocity
        error), with the direct solver
        (`Simulator` with the Cholesky solver: step by step the same operations as its parallel schedule);
        batch_in[0] = 0 takes no step, only the velocity correction a deferred step left (`Simulator.state`). A
        step is the base steps of stages[i] h in turn (a composition, `composition.py`; some run backwards);
        reach is the largest |stages[i]|, which sizes the spin split."""
        # The state and the prediction trade arrays on acceptance (`settle`); made by a call, as a plain
        # assignment would make them the kernel arguments themselves, which the trades would then overwrite.
        state_x, state_q, state_v, state_w, next_x, next_q, next_v, next_w = traded(
            pred_x, pred_q, pred_v, pred_w, body_x_out, body_q_out, body_v_out, body_w_out
        )  # fmt: skip
        spin = spin_in[0]
        stage_count = stages.shape[0]
        begin_summary(status_out)
        if batch_in[0] == 0:  # no step: the velocity correction the last (deferred) step left, in status row 0
            verr = velocity_errors_all(
                constraint_count, constraint_kind, constraint_body0, constraint_body1, jac_lin, jac_ang, jac_skew,
                state_v, state_w, errors, rhs,
            )  # fmt: skip
            solves = wp.int32(0)
            if not (verr <= velocity_tolerance):
                if refactor_every > 1 and factor_state[FACTOR_AGE] > 0:  # one solve is exact with K of this state only
                    assemble_and_factor(
                        augmented, perm, col_start, update_start, update_target, update_a, update_b, update_sign,
                        col_sign, col_loop, slot_shape, slot_row, slot_sides, slot_code, slot_ref, pivot_tolerance,
                        loop_tolerance, constraint_kind, constraint_body0, constraint_body1, body_inv_mass,
                        inv_inertia_world, jac_lin, jac_ang, jac_skew, values, singular,
                    )  # fmt: skip
                    factor_state[FACTOR_COUNT] = factor_state[FACTOR_COUNT] + 1
                    factor_state[FACTOR_AGE] = 0
                verr, solves = velocity_solve(
                    body_count, constraint_count, constraint_kind, constraint_body0, constraint_body1, body_inv_mass,
                    body_rows_start, body_rows, augmented, offset, perm, col_start, col_row, col_sign, row_start,
                    row_slot, row_col, values, work, aug_rhs, aug_x, inv_inertia_world, jac_lin, jac_ang, jac_skew,
                    errors, rhs, impulse, state_v, state_w, verr, velocity_tolerance,
                )  # fmt: skip
            left = wp.int32(OK)
            failed = f64(0.0)
            if not (verr <= velocity_tolerance):
                left = VELOCITY
                failed = verr
            finish(status_out, 0, left, 0, solves, solves, f64(0.0), verr, failed, spin)
            return
        kicked_here = wp.bool(False)  # the wrench rows hold the kicks' at the state's poses (`kick_all`)
        k = wp.int32(0)
        while k < batch_in[0]:
            status_out[k, STATUS_SPIN] = spin
            if turns_too_far(spin, reach * h, max_rotation):
                status_out[k, STATUS_CODE] = f64(SPLIT)
                settle(body_count, state_x, state_q, state_v, state_w, body_x_out, body_q_out, body_v_out, body_w_out)
                return
            save_start(
                body_count, stage_count, state_x, state_q, state_v, state_w, x0, q0, v0, w0
            )  # fmt: skip
            if wp.static(forced):
                if stage_count > 1:  # a later stage's failure undoes the integrals of the stages before it
                    copy_values(elements.drive_integral, elements.integral0)
            if wp.static(rows):
                zero_values(limit_rows.limit_impulse)  # the rows' impulses accumulate over the step
            iterations = wp.int32(0)  # summed over the stages, as are the velocity iterations
            row_solves = wp.int32(0)  # the velocity corrections before the rows' (`rows`)
            newton_solves = wp.int32(0)  # the Newton steps' second solves
            velocity_iterations = wp.int32(0)
            measured = wp.int32(0)  # a bit a carry row measured in this step (`carrying`)
            joint_error = f64(0.0)  # the largest over the stages
            verr = f64(0.0)  # the last stage's
            failed = f64(0.0)  # the largest velocity error over the tolerance
            code = wp.int32(OK)
            stage = wp.int32(0)
            while stage < stage_count:
                hs = stages[stage] * h
                inv_h = f64(1.0) / hs
                row = stage_carry[stage]
                if wp.static(kicked):  # the first half kick, at the stage's start (its frames are the state's)
                    kick_all(
                        body_count, f64(0.5) * hs, body_inv_mass, inv_inertia_world, elements, state_x, state_q,
                        state_v, state_w, kicked_here,
                    )  # fmt: skip
                if wp.static(forced):
                    coupled_predict_all(
                        body_count, body_inv_mass, body_inertia, body_inv_inertia, gravity, hs, elements,
                        state_x, state_q, state_v, state_w, body_force_in, body_torque_in, next_x,
                        next_q, next_v, next_w,
                    )  # fmt: skip
                else:
                    predict_all(
                        body_count, body_inv_mass, body_inertia, body_inv_inertia, body_principal, body_euler,
                        body_axes, gravity, hs, state_x, state_q, state_v, state_w, body_force_in, body_torque_in,
                        next_x, next_q, next_v, next_w,
                    )  # fmt: skip
                    if wp.static(kicked):
                        dampers_on_prediction(
                            hs, elements, body_inv_mass, body_inv_inertia, next_x, next_q, next_v, next_w
                        )  # fmt: skip
                err = position_errors_all(
                    constraint_count, constraint_kind, constraint_body0, constraint_body1, constraint_anchor0,
                    constraint_anchor1, constraint_axis0, constraint_axis1, constraint_rest_rotation,
                    constraint_rest_angle, inv_h, proj, next_x, next_q, errors, rhs,
                )  # fmt: skip
                if wp.static(rows):
                    err = max_or_nan(
                        err,
                        limit_errors_all(
                            hs, limit_rows, next_x, next_q, next_v, next_w, state_x, state_q, state_v,
                            state_w,
                        ),
                    )  # fmt: skip
                tries = wp.int32(0)
                fresh = refactor_every <= 1 or factor_state[FACTOR_AGE] == 0  # K of this stage's start
                rescued = wp.bool(False)  # K factored midway (`stale_rate`)
                best = err
                ok = wp.bool(False)
                restart = wp.int32(0)  # the solves before K was factored here for a failing older factor
                undo = wp.bool(False)  # the next pass takes back the older factor's impulses (`stale_rate`)
                while wp.isfinite(err):
                    best = wp.min(best, err)
                    if err <= tolerance:
                        ok = True
                        break
                    if tries - restart >= max_iterations or diverging(err, best, tries - restart):
                        if refactor_every <= 1 or factor_state[FACTOR_AGE] == 0:
                            break
                        # The older factor's failure, not the stage's: K of the stage's start and the iteration
                        # limit again, so that a stage fails (and is halved) only as it would without `refactor_every`.
                        assemble_and_factor(
                            augmented, perm, col_start, update_start, update_target, update_a, update_b, update_sign,
                            col_sign, col_loop, slot_shape, slot_row, slot_sides, slot_code, slot_ref,
                            pivot_tolerance, loop_tolerance, constraint_kind, constraint_body0, constraint_body1,
                            body_inv_mass, inv_inertia_world, jac_lin, jac_ang, jac_skew, values, singular,
                        )  # fmt: skip
                        factor_state[FACTOR_COUNT] = factor_state[FACTOR_COUNT] + 1
                        factor_state[FACTOR_AGE] = 0
                        rescued = True
                        restart = tries
                        best = err
                    last = err
                    if tries == 0 and carrying != 0:
                        carry_into_all(constraint_count, carry[row], rhs)
                    if undo:  # no solve: the impulses just applied, negated, go back the way they came
                        negate_all(constraint_count, impulse)
                    else:
                        cholesky_solve(
                            augmented, offset, constraint_count, perm, col_start, col_row, col_sign, row_start,
                            row_slot, row_col, values, work, aug_rhs, aug_x, rhs, impulse,
                        )  # fmt: skip
                    if tries == 0 and newton != 0:  # solve again with rhs - E lambda: K + E is the error's answer
                        newton_rhs_all(
                            body_count, constraint_count, constraint_kind, body_inv_mass, body_rows_start, body_rows,
                            constraint_body0, constraint_body1, constraint_anchor0, constraint_anchor1,
                            constraint_axis0, constraint_axis1, constraint_rest_rotation, constraint_rest_angle, hs,
                            proj, inv_inertia_world, jac_lin, jac_ang, jac_skew, impulse, state_w, next_x, next_q,
                            rhs, response_v, response_w, response_turn, newton_rhs,
                        )  # fmt: skip
                        cholesky_solve(
                            augmented, offset, constraint_count, perm, col_start, col_row, col_sign, row_start,
                            row_slot, row_col, values, work, aug_rhs, aug_x, newton_rhs, impulse,
                        )  # fmt: skip
                        newton_solves += 1
                    if wp.static(forced or rows):  # every impulse first: rows, elements couple the bodies
                        apply_all(
                            body_count, constraint_kind, body_inv_mass, body_rows_start, body_rows,
                            inv_inertia_world, jac_lin, jac_ang, jac_skew, impulse, state_v, state_w,
                        )  # fmt: skip
                        if wp.static(rows):
                            correct_rows_all(
                                0, hs, constraint_count, limit_rows, body_inv_mass, constraint_kind, constraint_body0,
                                constraint_body1, inv_inertia_world, jac_lin, jac_ang, jac_skew, state_x, state_q,
                                state_v, state_w, augmented, offset, perm, col_start, col_row, col_sign, row_start,
                                row_slot, row_col, values, work, aug_rhs, aug_x,
                            )  # fmt: skip
                        if wp.static(forced):
                            coupled_predict_all(
                                body_count, body_inv_mass, body_inertia, body_inv_inertia, gravity, hs, elements,
                                state_x, state_q, state_v, state_w, body_force_in, body_torque_in,
                                next_x, next_q, next_v, next_w,
                            )  # fmt: skip
                        else:
                            predict_all(
                                body_count, body_inv_mass, body_inertia, body_inv_inertia, body_principal,
                                body_euler, body_axes, gravity, hs, state_x, state_q, state_v, state_w, body_force_in,
                                body_torque_in, next_x, next_q, next_v, next_w,
                            )  # fmt: skip
                            if wp.static(kicked):
                                dampers_on_prediction(
                                    hs, elements, body_inv_mass, body_inv_inertia, next_x, next_q, next_v, next_w
                                )  # fmt: skip
                    else:
                        apply_and_predict_all(
                            body_count, constraint_kind, body_inv_mass, body_inertia, body_inv_inertia, body_principal,
                            body_euler, body_axes, gravity, hs, body_rows_start, body_rows,
                            inv_inertia_world, jac_lin, jac_ang, jac_skew, impulse, state_x, state_q, state_v, state_w,
                            body_force_in, body_torque_in, next_x, next_q, next_v, next_w,
                        )  # fmt: skip
                        if wp.static(kicked):
                            dampers_on_prediction(
                                hs, elements, body_inv_mass, body_inv_inertia, next_x, next_q, next_v, next_w
                            )  # fmt: skip
                    err = position_errors_all(
                        constraint_count, constraint_kind, constraint_body0, constraint_body1, constraint_anchor0,
                        constraint_anchor1, constraint_axis0, constraint_axis1, constraint_rest_rotation,
                        constraint_rest_angle, inv_h, proj, next_x, next_q, errors, rhs,
                    )  # fmt: skip
                    if tries == 0 and carrying != 0:
                        carry_measure_all(constraint_count, carry[row], rhs, carry_next[row])
                        measured = measured | (1 << row)
                    if wp.static(rows):
                        err = max_or_nan(
                            err,
                            limit_errors_all(
                                hs, limit_rows, next_x, next_q, next_v, next_w, state_x, state_q, state_v,
                                state_w,
                            ),
                        )  # fmt: skip
                    if undo:  # the pass took back a solve: not one itself
                        undo = wp.bool(False)
                        tries -= 1
                    elif stale_rate(factor_state, refactor_every, err, last, stale_factor_rate):
                        # Where the older factor's solve made the error grow, the next pass takes it back, so that
                        # K of the stage's start begins where a fresh stage would; and what the first solve left is
                        # no carried right-hand side (`carry_measure_all`): it holds the older factor's miss. On a
                        # scene with very light bodies (the dm_control humanoid's gimbals, 1e-6 of the body they
                        # carry) such a solve took an error of 1e-5 m to 0.1-1 m, and its carry the next step's.
                        undo = not (err <= last)
                        measured = measured & ~(1 << row)
                        assemble_and_factor(
                            augmented, perm, col_start, update_start, update_target, update_a, update_b, update_sign,
                            col_sign, col_loop, slot_shape, slot_row, slot_sides, slot_code, slot_ref,
                            pivot_tolerance, loop_tolerance, constraint_kind, constraint_body0, constraint_body1,
                            body_inv_mass, inv_inertia_world, jac_lin, jac_ang, jac_skew, values, singular,
                        )  # fmt: skip
                        factor_state[FACTOR_COUNT] = factor_state[FACTOR_COUNT] + 1
                        factor_state[FACTOR_AGE] = 0
                        rescued = True
                    tries += 1
                iterations += tries
                new_spin = spin
                if ok:
                    bad, new_spin = summary_all(body_count, next_x, next_q, next_v, next_w)
                    if bad > 0 or (final == 0 and turns_too_far(new_spin, hs, max_rotation)):
                        ok = wp.bool(False)
                if not ok:
                    restore_start(
                        body_count, stage, x0, q0, v0, w0, state_x, state_q, state_v, state_w
                    )  # fmt: skip
                    if wp.static(forced):
                        if stage > 0:
                            copy_values(elements.integral0, elements.drive_integral)
                    # the failed attempt's work, which the host counts in the step that takes it again halved
                    status_out[k, STATUS_JOINT_ITERATIONS] = f64(iterations)
                    status_out[k, STATUS_VELOCITY_ITERATIONS] = f64(velocity_iterations)
                    status_out[k, STATUS_LINEAR_ITERATIONS] = f64(
                        iterations + velocity_iterations + row_solves + newton_solves
                    )
                    status_out[k, STATUS_JOINT_ERROR] = err
                    status_out[k, STATUS_CODE] = f64(RETRY)
                    settle(
                        body_count, state_x, state_q, state_v, state_w, body_x_out, body_q_out, body_v_out, body_w_out
                    )
                    return
                joint_error = wp.max(joint_error, err)
                spin = new_spin
                # accept the prediction: it becomes the state, whose arrays take the next prediction (`settle`)
                state_x, state_q, state_v, state_w, next_x, next_q, next_v, next_w = traded(
                    state_x, state_q, state_v, state_w, next_x, next_q, next_v, next_w
                )  # fmt: skip
                if wp.static(forced):
                    integrate_drives_all(hs, elements, state_x, state_q, state_v, state_w)
                frames_all(
                    body_count, constraint_count, body_principal, body_inv_principal, body_inv_inertia, constraint_kind,
                    constraint_body0, constraint_body1, constraint_anchor0, constraint_anchor1, constraint_axis0,
                    constraint_axis1, state_x, state_q, inv_inertia_world, proj, jac_lin, jac_ang, jac_skew,
                )  # fmt: skip
                if wp.static(kicked):  # the second half kick, at the accepted poses, before any velocity correction
                    kick_all(
                        body_count, f64(0.5) * hs, body_inv_mass, inv_inertia_world, elements, state_x, state_q,
                        state_v, state_w, False,
                    )  # fmt: skip
                    kicked_here = True  # the next stage starts at these poses: its first kick takes these rows
                # The velocity correction where the state is handed out (`defer` == 0: every stage's): a deferred
                # one is the next joint correction's, which reaches the same velocities (`Simulator.defer_velocities`;
                # never with rows, whose velocity pass reads them).
                corrected = defer == 0 or (k == batch_in[0] - 1 and batch_in[1] != 0 and stage == stage_count - 1)
                # K factored here, unless an older factor serves on (`refactor_every`): never where the velocities are
                # corrected, whose one solve is exact with K of this state (the paper's section 4.2).
                refactor = wp.bool(True)
                if refactor_every > 1:
                    refactor = not older_factor(factor_state, refactor_every, corrected, stage, tries, fresh, rescued)
                if refactor:
                    assemble_and_factor(
                        augmented, perm, col_start, update_start, update_target, update_a, update_b, update_sign,
                        col_sign, col_loop, slot_shape, slot_row, slot_sides, slot_code, slot_ref, pivot_tolerance,
                        loop_tolerance, constraint_kind, constraint_body0, constraint_body1, body_inv_mass,
                        inv_inertia_world, jac_lin, jac_ang, jac_skew, values, singular,
                    )  # fmt: skip
                    factor_state[FACTOR_COUNT] = factor_state[FACTOR_COUNT] + 1
                if wp.static(rows):  # the rows' Jacobians; their system S with the joints holding as they turn active
                    row_sides_all(limit_rows, state_x, state_q, state_v, state_w)
                verr = f64(wp.nan)  # not measured
                if corrected:
                    verr = velocity_errors_all(
                        constraint_count, constraint_kind, constraint_body0, constraint_body1, jac_lin, jac_ang,
                        jac_skew, state_v, state_w, errors, rhs,
                    )  # fmt: skip
                if wp.static(rows):  # the joints exact, then the rows, then the joints take up their reaction
                    cholesky_solve(
                        augmented, offset, constraint_count, perm, col_start, col_row, col_sign, row_start,
                        row_slot, row_col, values, work, aug_rhs, aug_x, rhs, impulse,
                    )  # fmt: skip
                    apply_all(
                        body_count, constraint_kind, body_inv_mass, body_rows_start, body_rows, inv_inertia_world,
                        jac_lin, jac_ang, jac_skew, impulse, state_v, state_w,
                    )  # fmt: skip
                    row_solves += 1
                    correct_rows_all(
                        1, hs, constraint_count, limit_rows, body_inv_mass, constraint_kind, constraint_body0,
                        constraint_body1, inv_inertia_world, jac_lin, jac_ang, jac_skew, state_x, state_q, state_v,
                        state_w, augmented, offset, perm, col_start, col_row, col_sign, row_start, row_slot, row_col,
                        values, work, aug_rhs, aug_x,
                    )  # fmt: skip
                    verr = velocity_errors_all(
                        constraint_count, constraint_kind, constraint_body0, constraint_body1, jac_lin, jac_ang,
                        jac_skew, state_v, state_w, errors, rhs,
                    )  # fmt: skip
                if corrected and not (verr <= velocity_tolerance):
                    verr, solves = velocity_solve(
                        body_count, constraint_count, constraint_kind, constraint_body0, constraint_body1,
                        body_inv_mass, body_rows_start, body_rows, augmented, offset, perm, col_start, col_row,
                        col_sign, row_start, row_slot, row_col, values, work, aug_rhs, aug_x, inv_inertia_world,
                        jac_lin, jac_ang, jac_skew, errors, rhs, impulse, state_v, state_w, verr, velocity_tolerance,
                    )  # fmt: skip
                    velocity_iterations += solves
                if singular[0] != 0:  # the host raises: no further stage
                    code = SINGULAR
                    break
                if corrected and not (verr <= velocity_tolerance):  # the host raises or warns once the step is done
                    code = VELOCITY
                    failed = max_or_nan(failed, verr)
                stage += 1
            if code == OK or code == VELOCITY:  # the step is kept: its carry rows are taken
                commit_carry(measured, constraint_count, carry, carry_next, carry_past)
            finish(
                status_out, k, code, iterations, velocity_iterations,
                iterations + velocity_iterations + row_solves + newton_solves,
                joint_error, verr, failed, spin,
            )  # fmt: skip
            if code != OK:
                settle(body_count, state_x, state_q, state_v, state_w, body_x_out, body_q_out, body_v_out, body_w_out)
                return
            k += 1
        settle(body_count, state_x, state_q, state_v, state_w, body_x_out, body_q_out, body_v_out, body_w_out)

    iterative_steps = None  # the paper's baseline predicts each body alone and has no rows
    if not (forced or rows or kicked):

        @wp.kernel(module=module)
        def iterative_steps(
            # Model:
            body_count: int,
            constraint_count: int,
            body_inv_mass: wp.array(dtype=f64),
            body_inertia: wp.array(dtype=mat33d),
            body_inv_inertia: wp.array(dtype=mat33d),
            body_principal: wp.array(dtype=int),
            body_euler: wp.array(dtype=vec3d),
            body_inv_principal: wp.array(dtype=vec3d),
            body_axes: wp.array(dtype=quatd),
            gravity: vec3d,
            constraint_kind: wp.array(dtype=int),
            constraint_body0: wp.array(dtype=int),
            constraint_body1: wp.array(dtype=int),
            constraint_anchor0: wp.array(dtype=vec3d),
            constraint_anchor1: wp.array(dtype=vec3d),
            constraint_axis0: wp.array(dtype=vec3d),
            constraint_axis1: wp.array(dtype=vec3d),
            constraint_rest_rotation: wp.array(dtype=quatd),
            constraint_rest_angle: wp.array(dtype=f64),
            # Settings:
            h: f64,
            stages: wp.array(dtype=f64),
            reach: f64,
            batch_in: wp.array(dtype=int),
            tolerance: f64,
            velocity_tolerance: f64,
            max_iterations: int,
            max_rotation: f64,
            final: int,
            spin_in: wp.array(dtype=f64),
            body_force_in: wp.array(dtype=vec3d),
            body_torque_in: wp.array(dtype=vec3d),
            # Scratch:
            pred_x: wp.array(dtype=vec3d),
            pred_q: wp.array(dtype=quatd),
            pred_v: wp.array(dtype=vec3d),
            pred_w: wp.array(dtype=vec3d),
            x0: wp.array(dtype=vec3d),
            q0: wp.array(dtype=quatd),
            v0: wp.array(dtype=vec3d),
            w0: wp.array(dtype=vec3d),
            errors: wp.array(dtype=f64),
            rhs: wp.array(dtype=vec3d),
            # Frames:
            inv_inertia_world: wp.array(dtype=sym33d),
            proj: wp.array(dtype=mat33d),
            jac_lin: wp.array(dtype=mat33d),
            jac_ang: wp.array(dtype=mat33d),
            jac_skew: wp.array(dtype=vec3d),
            # Data out:
            body_x_out: wp.array(dtype=vec3d),
            body_q_out: wp.array(dtype=quatd),
            body_v_out: wp.array(dtype=vec3d),
            body_w_out: wp.array(dtype=vec3d),
            status_out: wp.array2d(dtype=f64),
        ):
            """Up to batch_in[0] steps of h, from a fastest spin of spin_in[0], with the paper's iterative
            baseline: joint sweeps until one meets every constraint within tolerance, the prediction, then velocity
            sweeps (as `Simulator` without a system); a step is the base steps of stages[i] h in turn, as in
            `cholesky_steps`."""
            # The state and the prediction trade arrays on acceptance (`settle`); made by a call, as a plain
            # assignment would make them the kernel arguments themselves, which the trades would then overwrite.
            state_x, state_q, state_v, state_w, next_x, next_q, next_v, next_w = traded(
                pred_x, pred_q, pred_v, pred_w, body_x_out, body_q_out, body_v_out, body_w_out
            )  # fmt: skip
            spin = spin_in[0]
            stage_count = stages.shape[0]
            begin_summary(status_out)
            k = wp.int32(0)
            while k < batch_in[0]:
                status_out[k, STATUS_SPIN] = spin
                if turns_too_far(spin, reach * h, max_rotation):
                    status_out[k, STATUS_CODE] = f64(SPLIT)
                    settle(
                        body_count, state_x, state_q, state_v, state_w, body_x_out, body_q_out, body_v_out, body_w_out
                    )
                    return
                save_start(
                    body_count, stage_count, state_x, state_q, state_v, state_w, x0, q0, v0, w0
                )  # fmt: skip
                iterations = wp.int32(0)
                velocity_iterations = wp.int32(0)
                joint_error = f64(0.0)
                verr = f64(0.0)
                failed = f64(0.0)
                code = wp.int32(OK)
                stage = wp.int32(0)
                while stage < stage_count:
                    hs = stages[stage] * h
                    inv_h = f64(1.0) / hs
                    sweeps = wp.int32(0)
                    best = f64(0.0)
                    ok = wp.bool(False)
                    while True:
                        err = sweep_positions_once(
                            constraint_count, constraint_kind, constraint_body0, constraint_body1, constraint_anchor0,
                            constraint_anchor1, constraint_axis0, constraint_axis1, constraint_rest_rotation,
                            constraint_rest_angle, body_inv_mass, body_inertia, body_inv_inertia, body_principal,
                            body_euler, body_axes, gravity, hs, tolerance, state_x, state_q, body_force_in,
                            body_torque_in, inv_inertia_world, proj, jac_lin, jac_ang, jac_skew, state_v, state_w,
                        )  # fmt: skip
                        if not wp.isfinite(err):
                            break
                        if sweeps == 0:
                            best = err
                        best = wp.min(best, err)
                        if err <= tolerance:
                            ok = True
                            break
                        if sweeps >= max_iterations or diverging(err, best, sweeps):
                            break
                        sweeps += 1
                    iterations += sweeps
                    predict_all(
                        body_count, body_inv_mass, body_inertia, body_inv_inertia, body_principal, body_euler,
                        body_axes, gravity, hs, state_x, state_q, state_v, state_w, body_force_in, body_torque_in,
                        next_x, next_q, next_v, next_w,
                    )  # fmt: skip
                    err = position_errors_all(
                        constraint_count, constraint_kind, constraint_body0, constraint_body1, constraint_anchor0,
                        constraint_anchor1, constraint_axis0, constraint_axis1, constraint_rest_rotation,
                        constraint_rest_angle, inv_h, proj, next_x, next_q, errors, rhs,
                    )  # fmt: skip
                    new_spin = spin
                    if ok:
                        bad, new_spin = summary_all(body_count, next_x, next_q, next_v, next_w)
                        if not (err <= tolerance) or bad > 0:
                            ok = wp.bool(False)
                        elif final == 0 and turns_too_far(new_spin, hs, max_rotation):
                            ok = wp.bool(False)
                    if not ok:
                        restore_start(
                            body_count, stage, x0, q0, v0, w0, state_x, state_q, state_v, state_w
                        )  # fmt: skip
                        status_out[k, STATUS_JOINT_ITERATIONS] = f64(iterations)
                        status_out[k, STATUS_JOINT_ERROR] = err
                        status_out[k, STATUS_CODE] = f64(RETRY)
                        settle(
                            body_count,
                            state_x,
                            state_q,
                            state_v,
                            state_w,
                            body_x_out,
                            body_q_out,
                            body_v_out,
                            body_w_out,
                        )
                        return
                    joint_error = wp.max(joint_error, err)
                    spin = new_spin
                    # accept the prediction: it becomes the state, whose arrays take the next prediction (`settle`)
                    state_x, state_q, state_v, state_w, next_x, next_q, next_v, next_w = traded(
                        state_x, state_q, state_v, state_w, next_x, next_q, next_v, next_w
                    )  # fmt: skip
                    frames_all(
                        body_count, constraint_count, body_principal, body_inv_principal, body_inv_inertia,
                        constraint_kind, constraint_body0, constraint_body1, constraint_anchor0, constraint_anchor1,
                        constraint_axis0, constraint_axis1, state_x, state_q, inv_inertia_world, proj, jac_lin, jac_ang,
                        jac_skew,
                    )  # fmt: skip
                    vsweeps = wp.int32(0)
                    vbest = f64(0.0)
                    converged = wp.bool(True)
                    while True:
                        verr = sweep_velocities_once(
                            constraint_count, constraint_kind, constraint_body0, constraint_body1, body_inv_mass,
                            velocity_tolerance, inv_inertia_world, jac_lin, jac_ang, jac_skew, state_v, state_w,
                        )  # fmt: skip
                        if vsweeps == 0:
                            vbest = verr
                        vbest = wp.min(vbest, verr)
                        if verr <= velocity_tolerance:
                            break
                        if not wp.isfinite(verr) or vsweeps >= max_iterations or diverging(verr, vbest, vsweeps):
                            converged = False
                            break
                        vsweeps += 1
                    velocity_iterations += vsweeps
                    verr = velocity_errors_all(
                        constraint_count, constraint_kind, constraint_body0, constraint_body1, jac_lin, jac_ang,
                        jac_skew, state_v, state_w, errors, rhs,
                    )  # fmt: skip
                    if not converged:  # the host raises or warns once the step is done
                        code = VELOCITY
                        failed = max_or_nan(failed, verr)
                    stage += 1
                finish(status_out, k, code, iterations, velocity_iterations, 0, joint_error, verr, failed, spin)
                if code != OK:
                    settle(
                        body_count, state_x, state_q, state_v, state_w, body_x_out, body_q_out, body_v_out, body_w_out
                    )
                    return
                k += 1
            settle(body_count, state_x, state_q, state_v, state_w, body_x_out, body_q_out, body_v_out, body_w_out)

    return SimpleNamespace(
        kinds=ck.kinds,
        module=module,
        cholesky_steps=cholesky_steps,
        iterative_steps=iterative_steps,
        position_errors_all=position_errors_all,
        frames_all=frames_all,
        summary_all=summary_all,
    )
