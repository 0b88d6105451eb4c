"""One tree on several threads: the fused step's stages over the part of the tree each thread owns
(`warpimpulse/split.py` cuts the tree and runs these launches).

The tree is cut at its root: a few top bodies (the separator) are removed, and the subtrees below them are the
parts, one thread each. In the elimination order (deepest constraints first) a subtree's columns depend only on
its own, so its prediction, joint errors, frames, assembly, factor and forward rows need nothing from another
part; only the separator's columns couple them: they are factored and forward-solved after the parts, and
solved backward before them. Each launch below runs one part's share of one such phase over its index lists
(bodies, constraints, columns in elimination order, slots), calling the same per-element funcs as the fused
step (`kernels/step.py`) with the same arguments, so every body, constraint and column gets exactly the
arithmetic it gets there: the split step is the fused step bit for bit.

Per-part outputs (`part_out`): the largest joint error, the bodies with a NaN or Inf in the prediction, the
fastest spin (rad/s) of the prediction, the largest velocity error, each over the part's elements; the host
combines them as the fused step's loops do. `part_singular` is the part's `singular` of the factor.
"""

import functools
from types import SimpleNamespace

import warp as wp

from .assemble import assemble_column
from .carry import carry_into, carry_measure
from .cholesky import backward_column, factor_column, forward_row
from .constraints import specialized, velocity_error
from .impulses import apply_body
from .inertia import sym33d, world_inverse_inertia_of
from .rigid import body_summary, predict_index
from .step import max_or_nan

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
quatd = wp.quatd
mat33d = wp.mat33d
f64 = wp.float64

# part_out columns
OUT_ERROR = 0
OUT_BAD = 1
OUT_SPIN = 2
OUT_VELOCITY_ERROR = 3
OUT_WIDTH = 4


@wp.func
def forward_rows(
    part_columns: wp.array(dtype=int),
    perm: wp.array(dtype=int),
    col_start: wp.array(dtype=int),
    row_start: wp.array(dtype=int),
    row_slot: wp.array(dtype=int),
    row_col: wp.array(dtype=int),
    values: wp.array(dtype=mat33d),
    rhs: wp.array(dtype=vec3d),
    work: wp.array(dtype=vec3d),
):
    """L y = P rhs on the part's rows, in elimination order."""
    k = wp.int32(0)
    while k < part_columns.shape[0]:
        forward_row(part_columns[k], perm, col_start, row_start, row_slot, row_col, values, rhs, work)
        k += 1


@wp.func
def backward_apply(
    part_columns: wp.array(dtype=int),
    part_bodies: wp.array(dtype=int),
    constraint_kind: wp.array(dtype=int),
    perm: wp.array(dtype=int),
    col_start: wp.array(dtype=int),
    col_row: wp.array(dtype=int),
    col_sign: wp.array(dtype=f64),
    values: wp.array(dtype=mat33d),
    work: wp.array(dtype=vec3d),
    impulse: wp.array(dtype=vec3d),
    body_inv_mass: wp.array(dtype=f64),
    body_rows_start: wp.array(dtype=int),
    body_rows: wp.array(dtype=int),
    inv_inertia_world: wp.array(dtype=sym33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """L^T z = S y on the part's columns (last first), then the impulses onto the part's bodies."""
    n = part_columns.shape[0]
    k = wp.int32(0)
    while k < n:
        backward_column(part_columns[n - 1 - k], perm, col_start, col_row, col_sign, values, work, impulse)
        k += 1
    k = wp.int32(0)
    while k < part_bodies.shape[0]:
        apply_body(
            part_bodies[k], constraint_kind, body_inv_mass, body_rows_start, body_rows, inv_inertia_world, jac_lin,
            jac_ang, jac_skew, impulse, body_v, body_w,
        )  # fmt: skip
        k += 1


@wp.func
def velocity_errors_of(
    part_constraints: wp.array(dtype=int),
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
    worst = f64(0.0)
    k = wp.int32(0)
    while k < part_constraints.shape[0]:
        i = part_constraints[k]
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
        k += 1
    return worst


@functools.cache
def split_kernels(kinds: frozenset[int]) -> SimpleNamespace:
    """The launches of a split step for a set of constraint kinds (`constraints.specialized(kinds)`)."""
    ck = specialized(kinds)
    module = f"{__name__}.kinds_{'_'.join(map(str, ck.kinds))}"
    wp.set_module_options({"enable_backward": False}, module)
    frame = ck.frame
    position_error = ck.position_error

    @wp.kernel(module=module)
    def correct(
        # Model:
        body_inv_mass: wp.array(dtype=f64),
        body_inertia: wp.array(dtype=mat33d),
        body_inv_inertia: wp.array(dtype=mat33d),
        body_principal: wp.array(dtype=int),
        body_euler: wp.array(dtype=vec3d),
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
        # Pattern:
        perm: wp.array(dtype=int),
        col_start: wp.array(dtype=int),
        col_row: wp.array(dtype=int),
        col_sign: wp.array(dtype=f64),
        row_start: wp.array(dtype=int),
        row_slot: wp.array(dtype=int),
        row_col: wp.array(dtype=int),
        # The part:
        part_bodies: wp.array(dtype=int),
        part_constraints: wp.array(dtype=int),
        part_columns: wp.array(dtype=int),
        separator: int,
        # What this launch does:
        start: int,
        first: int,
        h: f64,
        tolerance: f64,
        body_force_in: wp.array(dtype=vec3d),
        body_torque_in: wp.array(dtype=vec3d),
        # Scratch:
        pred_x: wp.array(dtype=vec3d),
        pred_q: wp.array(dtype=quatd),
        pred_v: wp.array(dtype=vec3d),
        pred_w: wp.array(dtype=vec3d),
        v0: wp.array(dtype=vec3d),
        w0: wp.array(dtype=vec3d),
        errors: wp.array(dtype=f64),
        rhs: wp.array(dtype=vec3d),
        impulse: wp.array(dtype=vec3d),
        values: wp.array(dtype=mat33d),
        work: wp.array(dtype=vec3d),
        inv_inertia_world: wp.array(dtype=sym33d),
        proj: wp.array(dtype=mat33d),
        jac_lin: wp.array(dtype=mat33d),
        jac_ang: wp.array(dtype=mat33d),
        jac_skew: wp.array(dtype=vec3d),
        # The first iteration's carried right-hand side (`carrying` != 0; kernels/carry.py):
        carrying: int,
        carry: wp.array(dtype=vec3d),
        carry_next: wp.array(dtype=vec3d),
        body_x_out: wp.array(dtype=vec3d),
        body_q_out: wp.array(dtype=quatd),
        body_v_out: wp.array(dtype=vec3d),
        body_w_out: wp.array(dtype=vec3d),
        part_out: wp.array(dtype=f64),
    ):
        """One part's share of the joint correction. At the start of a step (`start`): keep the velocities of
        t0, predict. Else one iteration: the separator forward-solves its rows (after every part's) and
        solves backward; a part solves backward (after the separator); each applies the impulses to its bodies
        and predicts them again. Then the part's joint errors (`carrying`: at the start, the first solve's right-hand
        sides take c; after the `first` iteration, c's next value is measured); where they hold to `tolerance` (as
        they must everywhere if the step has converged) the NaN/spin summary of its prediction; and, for a part,
        its forward rows of the next solve (wasted when the step has converged)."""
        if start != 0:
            k = wp.int32(0)
            while k < part_bodies.shape[0]:
                b = part_bodies[k]
                v0[b] = body_v_out[b]
                w0[b] = body_w_out[b]
                k += 1
        else:
            if separator != 0:
                forward_rows(part_columns, perm, col_start, row_start, row_slot, row_col, values, rhs, work)
            backward_apply(
                part_columns, part_bodies, constraint_kind, perm, col_start, col_row, col_sign, values,
                work, impulse, body_inv_mass, body_rows_start, body_rows, inv_inertia_world, jac_lin, jac_ang, jac_skew,
                body_v_out, body_w_out,
            )  # fmt: skip
        k = wp.int32(0)
        while k < part_bodies.shape[0]:
            predict_index(
                part_bodies[k], body_inv_mass, body_inertia, body_inv_inertia, body_principal, body_euler, body_axes,
                gravity, h, body_x_out, body_q_out, body_v_out, body_w_out, body_force_in, body_torque_in, pred_x,
                pred_q, pred_v, pred_w,
            )  # fmt: skip
            k += 1
        inv_h = f64(1.0) / h
        worst = f64(0.0)
        k = wp.int32(0)
        while k < part_constraints.shape[0]:
            i = part_constraints[k]
            position_error(
                i, constraint_kind, constraint_body0, constraint_body1, constraint_anchor0, constraint_anchor1,
                constraint_axis0, constraint_axis1, constraint_rest_rotation, constraint_rest_angle, inv_h, proj,
                pred_x, pred_q, errors, rhs,
            )  # fmt: skip
            worst = max_or_nan(worst, errors[i])
            if carrying != 0:
                if start != 0:
                    carry_into(i, carry, rhs)
                elif first != 0:
                    carry_measure(i, carry, rhs, carry_next)
            k += 1
        part_out[0] = worst
        if worst <= tolerance:  # the step may have converged: the NaN/spin summary of the prediction
            bad = int(0)  # noqa: UP018 (a Warp variable the loop changes must not start as a constant)
            spin = f64(0.0)
            k = wp.int32(0)
            while k < part_bodies.shape[0]:
                finite, w = body_summary(part_bodies[k], pred_x, pred_q, pred_v, pred_w)
                if finite:
                    spin = wp.max(spin, w)
                else:
                    bad += 1
                k += 1
            part_out[1] = f64(bad)
            part_out[2] = spin
        if separator == 0:
            forward_rows(part_columns, perm, col_start, row_start, row_slot, row_col, values, rhs, work)

    @wp.kernel(module=module)
    def refactor(
        # Model:
        body_inv_mass: wp.array(dtype=f64),
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
        # Pattern:
        pivot_tolerance: f64,
        loop_tolerance: f64,
        perm: wp.array(dtype=int),
        col_start: wp.array(dtype=int),
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
        slot_sides: wp.array(dtype=wp.vec4i),
        # The part:
        part_bodies: wp.array(dtype=int),
        part_constraints: wp.array(dtype=int),
        part_columns: wp.array(dtype=int),
        separator: int,
        # What this launch does:
        accept: int,
        factor: int,
        # Scratch:
        pred_x: wp.array(dtype=vec3d),
        pred_q: wp.array(dtype=quatd),
        pred_v: wp.array(dtype=vec3d),
        pred_w: wp.array(dtype=vec3d),
        errors: wp.array(dtype=f64),
        rhs: wp.array(dtype=vec3d),
        values: wp.array(dtype=mat33d),
        work: wp.array(dtype=vec3d),
        part_singular: wp.array(dtype=int),
        inv_inertia_world: wp.array(dtype=sym33d),
        proj: wp.array(dtype=mat33d),
        jac_lin: wp.array(dtype=mat33d),
        jac_ang: wp.array(dtype=mat33d),
        jac_skew: wp.array(dtype=vec3d),
        body_x_out: wp.array(dtype=vec3d),
        body_q_out: wp.array(dtype=quatd),
        body_v_out: wp.array(dtype=vec3d),
        body_w_out: wp.array(dtype=vec3d),
        part_out: wp.array(dtype=f64),
    ):
        """One part's share of what follows an accepted prediction. `accept`: take the prediction as the new
        state, and the world inverse inertias, constraint frames and Jacobian rows' products there. `factor`:
        assemble and factor the part's columns (the separator's after every part's), its velocity errors and,
        for a part, its forward rows of the velocity correction (wasted when the velocities hold)."""
        if accept != 0:
            k = wp.int32(0)
            while k < part_bodies.shape[0]:
                b = part_bodies[k]
                body_x_out[b] = pred_x[b]
                body_q_out[b] = pred_q[b]
                body_v_out[b] = pred_v[b]
                body_w_out[b] = pred_w[b]
                world_inverse_inertia_of(
                    b, body_principal, body_inv_principal, body_inv_inertia, body_q_out, inv_inertia_world
                )
                k += 1
            k = wp.int32(0)
            while k < part_constraints.shape[0]:
                i = part_constraints[k]
                frame(
                    i, constraint_kind, constraint_body0, constraint_body1, constraint_anchor0, constraint_anchor1,
                    constraint_axis0, constraint_axis1, body_x_out, body_q_out, proj, jac_lin, jac_ang, jac_skew,
                )  # fmt: skip
                k += 1
        if factor != 0:
            k = wp.int32(0)
            while k < part_columns.shape[0]:
                assemble_column(
                    part_columns[k], perm, col_start, constraint_kind, constraint_body0, constraint_body1,
                    body_inv_mass, slot_row, slot_sides, inv_inertia_world, jac_lin, jac_ang, jac_skew, values,
                )  # fmt: skip
                k += 1
            k = wp.int32(0)
            while k < part_columns.shape[0]:  # K's factor, no signs (only the K formulation is cut)
                factor_column(
                    part_columns[k], 0, col_start, update_start, update_target, update_a, update_b, update_sign,
                    col_sign, col_loop, slot_shape, pivot_tolerance, loop_tolerance, values, part_singular,
                )  # fmt: skip
                k += 1
            part_out[3] = velocity_errors_of(
                part_constraints, constraint_kind, constraint_body0, constraint_body1, jac_lin, jac_ang, jac_skew,
                body_v_out, body_w_out, errors, rhs,
            )  # fmt: skip
            if separator == 0:
                forward_rows(part_columns, perm, col_start, row_start, row_slot, row_col, values, rhs, work)

    @wp.kernel(module=module)
    def velocity_fix(
        # Model:
        body_inv_mass: wp.array(dtype=f64),
        body_rows_start: wp.array(dtype=int),
        body_rows: wp.array(dtype=int),
        constraint_kind: wp.array(dtype=int),
        constraint_body0: wp.array(dtype=int),
        constraint_body1: wp.array(dtype=int),
        # Pattern:
        perm: wp.array(dtype=int),
        col_start: wp.array(dtype=int),
        col_row: wp.array(dtype=int),
        col_sign: wp.array(dtype=f64),
        row_start: wp.array(dtype=int),
        row_slot: wp.array(dtype=int),
        row_col: wp.array(dtype=int),
        # The part:
        part_bodies: wp.array(dtype=int),
        part_constraints: wp.array(dtype=int),
        part_columns: wp.array(dtype=int),
        separator: int,
        # Scratch:
        errors: wp.array(dtype=f64),
        rhs: wp.array(dtype=vec3d),
        impulse: wp.array(dtype=vec3d),
        values: wp.array(dtype=mat33d),
        work: wp.array(dtype=vec3d),
        inv_inertia_world: wp.array(dtype=sym33d),
        jac_lin: wp.array(dtype=mat33d),
        jac_ang: wp.array(dtype=mat33d),
        jac_skew: wp.array(dtype=vec3d),
        body_v_out: wp.array(dtype=vec3d),
        body_w_out: wp.array(dtype=vec3d),
        part_out: wp.array(dtype=f64),
    ):
        """One part's share of the velocity correction: the solve (the separator's forward rows, then
        backward, before the parts'), the impulses on its bodies, its velocity errors again."""
        if separator != 0:
            forward_rows(part_columns, perm, col_start, row_start, row_slot, row_col, values, rhs, work)
        backward_apply(
            part_columns, part_bodies, constraint_kind, perm, col_start, col_row, col_sign, values, work,
            impulse, body_inv_mass, body_rows_start, body_rows, inv_inertia_world, jac_lin, jac_ang, jac_skew,
            body_v_out, body_w_out,
        )  # fmt: skip
        part_out[3] = velocity_errors_of(
            part_constraints, constraint_kind, constraint_body0, constraint_body1, jac_lin, jac_ang, jac_skew,
            body_v_out, body_w_out, errors, rhs,
        )  # fmt: skip

    return SimpleNamespace(correct=correct, refactor=refactor, velocity_fix=velocity_fix)
