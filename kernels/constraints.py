"""The six basic constraints (method paper, sections 4.2 and 4.3): geometry, error, projection, Jacobian.

Every constraint i is stored as 3 rows; a constraint of dimension k < 3 has zero rows k..2 in its
projection P_i and Jacobian, and a unit diagonal in its block of K (docs/architecture.md, "The system matrix").
Side 0 is body0 (the parent, sign +1), side 1 is body1 (the child, sign -1). A body index < 0 is the world.
Convention: the error c = A - B (or its rotational analogue) and J v = dc/dt.
The kernels that depend on the kind come from `specialized(kinds)`: a scene compiles only the kinds it has.
"""

import functools
from types import SimpleNamespace

import numpy as np
import warp as wp

from ..types import ConstraintKind

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
quatd = wp.quatd
mat33d = wp.mat33d
f64 = wp.float64

# The kinds' codes, from the one definition the host uses.
POINT = wp.constant(int(ConstraintKind.POINT))
LINE = wp.constant(int(ConstraintKind.LINE))
PLANE = wp.constant(int(ConstraintKind.PLANE))
ROTATION = wp.constant(int(ConstraintKind.ROTATION))
AXIS = wp.constant(int(ConstraintKind.AXIS))
ANGLE = wp.constant(int(ConstraintKind.ANGLE))


@wp.func
def constraint_dim(kind: int) -> int:
    if kind == POINT or kind == ROTATION:
        return 3
    if kind == LINE or kind == AXIS:
        return 2
    return 1


@wp.func
def is_translational(kind: int) -> bool:
    return kind < ROTATION


@wp.func
def side_body(i: int, side: int, constraint_body0: wp.array(dtype=int), constraint_body1: wp.array(dtype=int)):
    """Constraint i's body on side `side` (0: body0, 1: body1); < 0 for the world."""
    if side == 0:
        return constraint_body0[i]
    return constraint_body1[i]


@wp.func
def pose_x(b: int, xs: wp.array(dtype=vec3d)) -> vec3d:
    if b < 0:
        return vec3d()
    return xs[b]


@wp.func
def pose_q(b: int, qs: wp.array(dtype=quatd)) -> quatd:
    if b < 0:
        return wp.quat_identity(dtype=f64)
    return qs[b]


@wp.func
def perpendicular_basis(a: vec3d) -> mat33d:
    """Rows: two unit vectors perpendicular to the unit vector a, and a zero row."""
    t = vec3d(f64(1.0), f64(0.0), f64(0.0))
    if wp.abs(a[0]) > f64(0.7):
        t = vec3d(f64(0.0), f64(1.0), f64(0.0))
    b = wp.normalize(wp.cross(a, t))
    c = wp.cross(a, b)
    return mat33d(b[0], b[1], b[2], c[0], c[1], c[2], f64(0.0), f64(0.0), f64(0.0))


@wp.func
def single_row(n: vec3d) -> mat33d:
    z = f64(0.0)
    return mat33d(n[0], n[1], n[2], z, z, z, z, z, z)


@wp.func
def skew_times(v: vec3d, a: mat33d) -> mat33d:
    """[v]x a, row by row: a's rows combined as in v x u (18 products where the matrix product takes 27)."""
    a0 = a[0]
    a1 = a[1]
    a2 = a[2]
    return wp.matrix_from_rows(a2 * v[1] - a1 * v[2], a0 * v[2] - a2 * v[0], a1 * v[0] - a0 * v[1])


@wp.func
def times_skew_transpose(a: mat33d, v: vec3d) -> mat33d:
    """a [v]x^T = -a [v]x: row m is v x a_m (18 products where the matrix product takes 27)."""
    return wp.matrix_from_rows(wp.cross(v, a[0]), wp.cross(v, a[1]), wp.cross(v, a[2]))


@wp.func
def angular_times(
    kind: int, r: int, jac_ang: wp.array(dtype=mat33d), jac_skew: wp.array(dtype=vec3d), u: vec3d
) -> vec3d:
    """J_ang u of Jacobian row r (2 i + side) of a constraint of `kind`. A point constraint's J_ang = [s]x is
    kept as s alone (`constraint_frame` writes no block for it): s x u, 3 loads where the block takes 9."""
    if kind == POINT:
        return wp.cross(jac_skew[r], u)
    return jac_ang[r] * u


@wp.func
def angular_transpose_times(
    kind: int, r: int, jac_ang: wp.array(dtype=mat33d), jac_skew: wp.array(dtype=vec3d), lam: vec3d
) -> vec3d:
    """J_ang^T lam of Jacobian row r (2 i + side) of a constraint of `kind`: a point constraint's
    [s]x^T lam = -s x lam = lam x s, s read from jac_skew (`angular_times`)."""
    if kind == POINT:
        return wp.cross(lam, jac_skew[r])
    return wp.transpose(jac_ang[r]) * lam


@wp.func
def joint_points(kind: int, x0: vec3d, q0: quatd, x1: vec3d, q1: quatd, anchor0: vec3d, anchor1: vec3d, axis0: vec3d):
    """World points A (on body0) and B (on body1). For a line or plane, A is moved to the point closest
    to B before every impulse (section 4.2)."""
    a = x0 + wp.quat_rotate(q0, anchor0)
    b = x1 + wp.quat_rotate(q1, anchor1)
    n = wp.quat_rotate(q0, axis0)
    if kind == LINE:
        a = a + n * wp.dot(b - a, n)
    elif kind == PLANE:
        a = b - n * wp.dot(b - a, n)
    return a, b


@wp.func
def projection(kind: int, q0: quatd, q1: quatd, axis0: vec3d, axis1: vec3d) -> mat33d:
    """P_i: the rows of the directions the constraint removes (sections 4.2, 4.3). A line's or an axis's two rows
    are made in body0's frame (axis0 is in it) and turned with the body: any basis of the plane removes the same
    motion, but this one turns smoothly with the joint, so the values the first iteration carries from step to
    step in these rows (kernels/carry.py) stay in one frame; one made from the world axis switches its helper
    vector as the axis turns."""
    if kind == POINT or kind == ROTATION:
        return wp.identity(n=3, dtype=f64)
    if kind == LINE or kind == AXIS:
        return perpendicular_basis(axis0) * wp.transpose(wp.quat_to_matrix(q0))
    a0 = wp.quat_rotate(q0, axis0)
    if kind == PLANE:
        return single_row(a0)
    return single_row(wp.normalize(wp.cross(a0, wp.quat_rotate(q1, axis1))))


@wp.func
def rotation_vector(q: quatd) -> vec3d:
    """Axis times angle of a unit quaternion, taking the short way round."""
    v = vec3d(q[0], q[1], q[2])
    s = wp.length(v)
    w = q[3]
    if w < f64(0.0):
        v = -v
        w = -w
    if s < f64(1.0e-12):
        return v * f64(2.0)
    return v * (f64(2.0) * wp.atan2(s, w) / s)


@wp.func
def constraint_error(
    kind: int,
    x0: vec3d,
    q0: quatd,
    x1: vec3d,
    q1: quatd,
    anchor0: vec3d,
    anchor1: vec3d,
    axis0: vec3d,
    axis1: vec3d,
    rest_rotation: quatd,
    rest_angle: f64,
) -> vec3d:
    """The unprojected error d of the constraint at the given poses (world frame)."""
    if is_translational(kind):
        a, b = joint_points(kind, x0, q0, x1, q1, anchor0, anchor1, axis0)
        return a - b
    if kind == ROTATION:
        return rotation_vector(q0 * rest_rotation * wp.quat_inverse(q1))
    a0 = wp.quat_rotate(q0, axis0)
    a1 = wp.quat_rotate(q1, axis1)
    if kind == AXIS:
        return wp.cross(a1, a0)
    n = wp.cross(a0, a1)
    phi = wp.atan2(wp.length(n), wp.dot(a0, a1))
    return wp.normalize(n) * (rest_angle - phi)


@wp.func
def projected_error(kind: int, p: mat33d, d: vec3d) -> vec3d:
    """P_i(t0) d_i(t0+h): the error in the removed directions of the step's start, for the right-hand side.

    Convergence is judged on |d| itself, which is the true error of every kind at t0+h. An angle
    constraint's direction a0 x a1 turns within the step, so its projection could shrink while the angle
    error does not: its right-hand side is the signed angle error itself.
    """
    if kind == POINT or kind == ROTATION:  # P = I (`projection`): the same value without the product
        return d
    pd = p * d
    if kind == ANGLE:
        s = f64(1.0)
        if pd[0] < f64(0.0):
            s = f64(-1.0)
        return vec3d(s * wp.length(d), f64(0.0), f64(0.0))
    return pd


@wp.func
def point_arms(x0: vec3d, x1: vec3d, q1: quatd, anchor1: vec3d):
    """A point constraint's J_ang as its two vectors s (J_ang = [s]x): -(B - x0) on body0, B - x1 on body1, B
    body1's anchor in the world (m). Both impulses act at B, equal and opposite, so they add no couple and
    angular momentum is kept exactly; the paper's A is within the tolerance of B (section 4.2)."""
    b = x1 + wp.quat_rotate(q1, anchor1)
    arm0 = b - x0
    arm1 = b - x1
    return -arm0, arm1


@wp.func
def constraint_frame(
    kind: int,
    i: int,
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    anchor0: wp.array(dtype=vec3d),
    anchor1: wp.array(dtype=vec3d),
    axis0: wp.array(dtype=vec3d),
    axis1: wp.array(dtype=vec3d),
    body_x: wp.array(dtype=vec3d),
    body_q: wp.array(dtype=quatd),
    proj: wp.array(dtype=mat33d),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
):
    """P_i and J_ib at the current poses: J = s P [I | -r*] (translational, r from each body's centre to the
    joint point B) or s P [0 | I] (rotational).

    A point constraint's J_ang = [s]x is written as s alone (jac_skew, 24 bytes a row where the block takes 72):
    every reader takes its products from s (`angular_times`, `angular_transpose_times`, `assemble.row_products`),
    and its jac_ang rows are never written nor read. Only the blocks that move are written: a point constraint's
    P = I and J_lin = +-I, a rotation's P = I and J_ang = +-I, and every rotational kind's zero J_lin are the same
    at every pose, written once where the arrays are made (`constant_frames`), which saves each frames pass up to
    360 bytes a constraint, and a point's 144 bytes of J_ang more."""
    b0 = constraint_body0[i]
    b1 = constraint_body1[i]
    x0 = pose_x(b0, body_x)
    q0 = pose_q(b0, body_q)
    x1 = pose_x(b1, body_x)
    q1 = pose_q(b1, body_q)
    if kind == ROTATION:
        return
    if kind == POINT:  # P = I: the angular blocks without the products
        s0, s1 = point_arms(x0, x1, q1, anchor1[i])
        jac_skew[2 * i] = s0
        jac_skew[2 * i + 1] = s1
        return
    p = projection(kind, q0, q1, axis0[i], axis1[i])
    proj[i] = p
    if is_translational(kind):
        a, b = joint_points(kind, x0, q0, x1, q1, anchor0[i], anchor1[i], axis0[i])
        jac_lin[2 * i] = p
        jac_lin[2 * i + 1] = -p
        jac_ang[2 * i] = -p * wp.skew(b - x0)
        jac_ang[2 * i + 1] = p * wp.skew(b - x1)
    else:
        jac_ang[2 * i] = p
        jac_ang[2 * i + 1] = -p


def constant_frames(kinds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The frames' blocks that no pose changes (`constraint_frame` leaves them alone), for constraints of the
    given kinds: (P (n, 3, 3), J_lin (2n, 3, 3), J_ang (2n, 3, 3)), every other block zero. The signs are
    those the kernel wrote when it wrote them (-I has -0.0 off its diagonal), so nothing changes bit for bit.
    A point constraint's J_ang rows stay zero: its J_ang lives in `Frames.jac_skew` (`constraint_frame`); they
    keep their place so that row r of every Jacobian array is 2 i + side."""
    n = len(kinds)
    eye = np.eye(3)
    point = np.asarray(kinds) == int(ConstraintKind.POINT)
    rotation = np.asarray(kinds) == int(ConstraintKind.ROTATION)
    proj = np.zeros((n, 3, 3))
    proj[point | rotation] = eye
    jac_lin = np.zeros((2 * n, 3, 3))
    jac_lin[0::2][point] = eye
    jac_lin[1::2][point] = -eye
    jac_ang = np.zeros((2 * n, 3, 3))
    jac_ang[0::2][rotation] = eye
    jac_ang[1::2][rotation] = -eye
    return proj, jac_lin, jac_ang


@wp.func
def position_error(
    kind: int,
    i: int,
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    anchor0: wp.array(dtype=vec3d),
    anchor1: wp.array(dtype=vec3d),
    axis0: wp.array(dtype=vec3d),
    axis1: wp.array(dtype=vec3d),
    rest_rotation: wp.array(dtype=quatd),
    rest_angle: wp.array(dtype=f64),
    inv_h: f64,
    proj: wp.array(dtype=mat33d),
    pred_x: wp.array(dtype=vec3d),
    pred_q: wp.array(dtype=quatd),
    error: wp.array(dtype=f64),
    rhs: wp.array(dtype=vec3d),
):
    """Projected error P_i d_i(t0+h) of the predicted state, and the joint-correction right-hand side
    -P_i d_i / h (section 4.5, equation 14)."""
    b0 = constraint_body0[i]
    b1 = constraint_body1[i]
    d = constraint_error(
        kind,
        pose_x(b0, pred_x), pose_q(b0, pred_q), pose_x(b1, pred_x), pose_q(b1, pred_q),
        anchor0[i], anchor1[i], axis0[i], axis1[i], rest_rotation[i], rest_angle[i],
    )  # fmt: skip
    error[i] = wp.length(d)
    rhs[i] = -projected_error(kind, proj[i], d) * inv_h


@wp.func
def constraint_velocity(
    i: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
    body_lin_v: wp.array(dtype=vec3d),
    body_ang_v: wp.array(dtype=vec3d),
) -> vec3d:
    """J_i v: the rate of change of the constraint's error. A point constraint's J_lin is I on body0 and -I on
    body1 and its J_ang is a skew matrix [s]x (`constraint_frame`): its linear part is the velocities themselves,
    its angular part s x w, s read from jac_skew (24 bytes a row where the matrix takes 72). A rotational
    constraint's J_lin is zero: its part is J_ang w."""
    b0 = constraint_body0[i]
    b1 = constraint_body1[i]
    kind = constraint_kind[i]
    point = kind == POINT
    translational = is_translational(kind)
    jv = vec3d()
    if b0 >= 0:
        if point:
            jv += body_lin_v[b0] + wp.cross(jac_skew[2 * i], body_ang_v[b0])
        elif translational:
            jv += jac_lin[2 * i] * body_lin_v[b0] + jac_ang[2 * i] * body_ang_v[b0]
        else:
            jv += jac_ang[2 * i] * body_ang_v[b0]
    if b1 >= 0:
        if point:
            jv += wp.cross(jac_skew[2 * i + 1], body_ang_v[b1]) - body_lin_v[b1]
        elif translational:
            jv += jac_lin[2 * i + 1] * body_lin_v[b1] + jac_ang[2 * i + 1] * body_ang_v[b1]
        else:
            jv += jac_ang[2 * i + 1] * body_ang_v[b1]
    return jv


@wp.func
def velocity_error(
    i: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    jac_lin_in: wp.array(dtype=mat33d),
    jac_ang_in: wp.array(dtype=mat33d),
    jac_skew_in: wp.array(dtype=vec3d),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    errors_out: wp.array(dtype=f64),
    rhs_out: wp.array(dtype=vec3d),
):
    """|J_i v|, and the velocity-correction right-hand side -J_i v (equations 9, 13)."""
    jv = constraint_velocity(
        i,
        constraint_kind,
        constraint_body0,
        constraint_body1,
        jac_lin_in,
        jac_ang_in,
        jac_skew_in,
        body_v_in,
        body_w_in,
    )
    errors_out[i] = wp.length(jv)
    rhs_out[i] = -jv


ALL_KINDS = frozenset((POINT, LINE, PLANE, ROTATION, AXIS, ANGLE))


@wp.func
def shifted_pose(b: int, x: vec3d, q: quatd, response_v: wp.array(dtype=vec3d), response_turn: wp.array(dtype=vec3d),
                 h: f64):  # fmt: skip
    """Body b's predicted pose moved as a velocity change du at t0 moves it, to first order: by h dv, and turned
    by h times its turn (`impulses.step_turn`, world frame) at the step's end. The world (b < 0) stays."""
    if b < 0:
        return x, q
    dw = response_turn[b] * (f64(0.5) * h)
    return x + response_v[b] * h, wp.normalize(q + quatd(dw[0], dw[1], dw[2], f64(0.0)) * q)


@wp.func
def arm_correction(
    kind: int,
    i: int,
    constraint_kind: wp.array(dtype=int),
    constraint_body0: wp.array(dtype=int),
    constraint_body1: wp.array(dtype=int),
    anchor0: wp.array(dtype=vec3d),
    anchor1: wp.array(dtype=vec3d),
    axis0: wp.array(dtype=vec3d),
    axis1: wp.array(dtype=vec3d),
    rest_rotation: wp.array(dtype=quatd),
    rest_angle: wp.array(dtype=f64),
    h: f64,
    proj: wp.array(dtype=mat33d),
    pred_x: wp.array(dtype=vec3d),
    pred_q: wp.array(dtype=quatd),
    jac_lin: wp.array(dtype=mat33d),
    jac_ang: wp.array(dtype=mat33d),
    jac_skew: wp.array(dtype=vec3d),
    response_v: wp.array(dtype=vec3d),
    response_w: wp.array(dtype=vec3d),
    response_turn: wp.array(dtype=vec3d),
) -> vec3d:
    """E_i du: how much more constraint i's projected predicted error moves, per unit of h, under the bodies'
    velocity changes du at t0 (`impulses.impulse_response`) than K models (J_i(t0) du; m/s, rad/s).

    K = J(t0) M^-1 J(t0)^T takes a velocity change dw at t0 to move a joint point by h dw x r with the arm r of
    the step's start, but the point moves by h dw x r(t0+h), and axes, lines and planes turn: the error answers
    an impulse through K + E, so the paper's iteration shrinks it linearly, by about the rotation of a body in a
    step (docs/architecture.md, "Fewer joint iterations"). A point constraint's E du is that arm change in
    closed form, (s(t0+h) - s(t0)) x dw on each side (`point_arms`); the other kinds' is the change of
    P d / h (`projected_error`, P of t0 as in the right-hand side) between the prediction and the prediction
    moved by du (`shifted_pose`), less J(t0) du.

    Each body turns by h times its `impulses.step_turn` of dw, not by h dw: the turned body's rate picks up
    w x dtheta, and an oblong body's dw changes as its inertia turns. Without it, E models the arms alone and
    leaves an axis's error as it was (a rotational row has no arm): K + E then models the error's answer no
    better than K on a 7-hinge arm at h = 1/30 (docs/history.md, "The turn's answer")."""
    b0 = constraint_body0[i]
    b1 = constraint_body1[i]
    x0 = pose_x(b0, pred_x)
    q0 = pose_q(b0, pred_q)
    x1 = pose_x(b1, pred_x)
    q1 = pose_q(b1, pred_q)
    if kind == POINT:  # J_lin = +-I does not move; J_ang = [s]x
        s0, s1 = point_arms(x0, x1, q1, anchor1[i])
        e = vec3d()
        if b0 >= 0:
            e += wp.cross(s0, response_turn[b0]) - wp.cross(jac_skew[2 * i], response_w[b0])
        if b1 >= 0:
            e += wp.cross(s1, response_turn[b1]) - wp.cross(jac_skew[2 * i + 1], response_w[b1])
        return e
    # d again, not from rhs: a batched world that is done has its rhs zeroed (`worlds.mask_worlds`), and its
    # E du must be zero too (du = 0 there), not P d / h.
    d = constraint_error(
        kind, x0, q0, x1, q1, anchor0[i], anchor1[i], axis0[i], axis1[i], rest_rotation[i], rest_angle[i]
    )
    y0, r0 = shifted_pose(b0, x0, q0, response_v, response_turn, h)
    y1, r1 = shifted_pose(b1, x1, q1, response_v, response_turn, h)
    moved = constraint_error(
        kind, y0, r0, y1, r1, anchor0[i], anchor1[i], axis0[i], axis1[i], rest_rotation[i], rest_angle[i]
    )
    p = proj[i]
    change = (projected_error(kind, p, moved) - projected_error(kind, p, d)) / h
    return change - constraint_velocity(
        i, constraint_kind, constraint_body0, constraint_body1, jac_lin, jac_ang, jac_skew, response_v, response_w
    )


@functools.cache
def specialized(kinds: frozenset[int]) -> SimpleNamespace:
    """The constraint kernels compiled for the constraint kinds in `kinds` only: `frames`, `position_errors`,
    `velocity_errors`, the per-constraint funcs they loop over (`frame`, `position_error`, for the fused step
    of `kernels/step.py`), the sorted `kinds` and the `module` name.

    `frames` and `position_errors` dispatch on their constraint's kind to the @wp.func above, called with the
    kind as a compile-time constant (`wp.static`), so the compiler folds away the other kinds' branches, and
    a kind not in `kinds` has no code: its constraints are left untouched. `velocity_errors` does not depend
    on the kind; it is here so that a scene compiles one module of constraint kernels, as before (each
    module costs its compiler start-up). One module per set of kinds, compiled once and cached on disk
    (benchmarks/skips.py measures what this saves and costs).
    """
    ks = tuple(sorted(int(k) for k in kinds))
    module = f"{__name__}.kinds_{'_'.join(map(str, ks))}"
    wp.set_module_options({"enable_backward": False}, module)

    @wp.func(module=module)
    def frame(
        i: int,
        constraint_kind: wp.array(dtype=int),
        constraint_body0: wp.array(dtype=int),
        constraint_body1: wp.array(dtype=int),
        constraint_anchor0: wp.array(dtype=vec3d),
        constraint_anchor1: wp.array(dtype=vec3d),
        constraint_axis0: wp.array(dtype=vec3d),
        constraint_axis1: wp.array(dtype=vec3d),
        body_x_in: wp.array(dtype=vec3d),
        body_q_in: wp.array(dtype=quatd),
        proj_out: wp.array(dtype=mat33d),
        jac_lin_out: wp.array(dtype=mat33d),
        jac_ang_out: wp.array(dtype=mat33d),
        jac_skew_out: wp.array(dtype=vec3d),
    ):
        """`constraint_frame` of constraint i, for its kind as a compile-time constant."""
        kind = constraint_kind[i]
        for k in range(wp.static(len(ks))):
            if kind == wp.static(ks[k]):
                constraint_frame(
                    wp.static(ks[k]), i, constraint_body0, constraint_body1, constraint_anchor0, constraint_anchor1,
                    constraint_axis0, constraint_axis1, body_x_in, body_q_in, proj_out, jac_lin_out, jac_ang_out,
                    jac_skew_out,
                )  # fmt: skip

    @wp.func(module=module)
    def position_error_of(
        i: int,
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
        proj_in: wp.array(dtype=mat33d),
        body_x_in: wp.array(dtype=vec3d),
        body_q_in: wp.array(dtype=quatd),
        errors_out: wp.array(dtype=f64),
        rhs_out: wp.array(dtype=vec3d),
    ):
        """`position_error` of constraint i, for its kind as a compile-time constant."""
        kind = constraint_kind[i]
        for k in range(wp.static(len(ks))):
            if kind == wp.static(ks[k]):
                position_error(
                    wp.static(ks[k]), i, constraint_body0, constraint_body1, constraint_anchor0, constraint_anchor1,
                    constraint_axis0, constraint_axis1, constraint_rest_rotation, constraint_rest_angle, inv_h,
                    proj_in, body_x_in, body_q_in, errors_out, rhs_out,
                )  # fmt: skip

    @wp.func(module=module)
    def arm_correction_of(
        i: int,
        constraint_kind: wp.array(dtype=int),
        constraint_body0: wp.array(dtype=int),
        constraint_body1: wp.array(dtype=int),
        constraint_anchor0: wp.array(dtype=vec3d),
        constraint_anchor1: wp.array(dtype=vec3d),
        constraint_axis0: wp.array(dtype=vec3d),
        constraint_axis1: wp.array(dtype=vec3d),
        constraint_rest_rotation: wp.array(dtype=quatd),
        constraint_rest_angle: wp.array(dtype=f64),
        h: f64,
        proj_in: wp.array(dtype=mat33d),
        pred_x: wp.array(dtype=vec3d),
        pred_q: wp.array(dtype=quatd),
        jac_lin_in: wp.array(dtype=mat33d),
        jac_ang_in: wp.array(dtype=mat33d),
        jac_skew_in: wp.array(dtype=vec3d),
        response_v_in: wp.array(dtype=vec3d),
        response_w_in: wp.array(dtype=vec3d),
        response_turn_in: wp.array(dtype=vec3d),
    ) -> vec3d:
        """`arm_correction` of constraint i, for its kind as a compile-time constant."""
        kind = constraint_kind[i]
        e = vec3d()
        for k in range(wp.static(len(ks))):
            if kind == wp.static(ks[k]):
                e = arm_correction(
                    wp.static(ks[k]), i, constraint_kind, constraint_body0, constraint_body1, constraint_anchor0,
                    constraint_anchor1, constraint_axis0, constraint_axis1, constraint_rest_rotation,
                    constraint_rest_angle, h, proj_in, pred_x, pred_q, jac_lin_in, jac_ang_in, jac_skew_in,
                    response_v_in, response_w_in, response_turn_in,
                )  # fmt: skip
        return e

    @wp.kernel(module=module)
    def frames(
        # Model:
        constraint_kind: wp.array(dtype=int),
        constraint_body0: wp.array(dtype=int),
        constraint_body1: wp.array(dtype=int),
        constraint_anchor0: wp.array(dtype=vec3d),
        constraint_anchor1: wp.array(dtype=vec3d),
        constraint_axis0: wp.array(dtype=vec3d),
        constraint_axis1: wp.array(dtype=vec3d),
        # Data in:
        body_x_in: wp.array(dtype=vec3d),
        body_q_in: wp.array(dtype=quatd),
        # Data out: P_i and the Jacobian blocks [lin | ang] of both sides, signs included
        proj_out: wp.array(dtype=mat33d),
        jac_lin_out: wp.array(dtype=mat33d),
        jac_ang_out: wp.array(dtype=mat33d),
        jac_skew_out: wp.array(dtype=vec3d),
    ):
        frame(
            wp.tid(), constraint_kind, constraint_body0, constraint_body1, constraint_anchor0, constraint_anchor1,
            constraint_axis0, constraint_axis1, body_x_in, body_q_in, proj_out, jac_lin_out, jac_ang_out, jac_skew_out,
        )  # fmt: skip

    @wp.kernel(module=module)
    def position_errors(
        # Model:
        constraint_kind: wp.array(dtype=int),
        constraint_body0: wp.array(dtype=int),
        constraint_body1: wp.array(dtype=int),
        constraint_anchor0: wp.array(dtype=vec3d),
        constraint_anchor1: wp.array(dtype=vec3d),
        constraint_axis0: wp.array(dtype=vec3d),
        constraint_axis1: wp.array(dtype=vec3d),
        constraint_rest_rotation: wp.array(dtype=quatd),
        constraint_rest_angle: wp.array(dtype=f64),
        # Data in: 1/h, the projections of t0, the predicted state
        inv_h: f64,
        proj_in: wp.array(dtype=mat33d),
        body_x_in: wp.array(dtype=vec3d),
        body_q_in: wp.array(dtype=quatd),
        # Data out:
        errors_out: wp.array(dtype=f64),
        rhs_out: wp.array(dtype=vec3d),
    ):
        position_error_of(
            wp.tid(), constraint_kind, constraint_body0, constraint_body1, constraint_anchor0, constraint_anchor1,
            constraint_axis0, constraint_axis1, constraint_rest_rotation, constraint_rest_angle, inv_h, proj_in,
            body_x_in, body_q_in, errors_out, rhs_out,
        )  # fmt: skip

    @wp.kernel(module=module)
    def velocity_errors(
        # Model:
        constraint_kind: wp.array(dtype=int),
        constraint_body0: wp.array(dtype=int),
        constraint_body1: wp.array(dtype=int),
        # Data in:
        jac_lin_in: wp.array(dtype=mat33d),
        jac_ang_in: wp.array(dtype=mat33d),
        jac_skew_in: wp.array(dtype=vec3d),
        body_v_in: wp.array(dtype=vec3d),
        body_w_in: wp.array(dtype=vec3d),
        # Data out:
        errors_out: wp.array(dtype=f64),
        rhs_out: wp.array(dtype=vec3d),
    ):
        """The constraint velocity J_i v, and the velocity-correction right-hand side -J_i v (equations 9, 13)."""
        velocity_error(
            wp.tid(), constraint_kind, constraint_body0, constraint_body1, jac_lin_in, jac_ang_in, jac_skew_in,
            body_v_in, body_w_in, errors_out, rhs_out,
        )  # fmt: skip

    @wp.kernel(module=module)
    def arm_corrections(
        # Model:
        constraint_kind: wp.array(dtype=int),
        constraint_body0: wp.array(dtype=int),
        constraint_body1: wp.array(dtype=int),
        constraint_anchor0: wp.array(dtype=vec3d),
        constraint_anchor1: wp.array(dtype=vec3d),
        constraint_axis0: wp.array(dtype=vec3d),
        constraint_axis1: wp.array(dtype=vec3d),
        constraint_rest_rotation: wp.array(dtype=quatd),
        constraint_rest_angle: wp.array(dtype=f64),
        # Data in: the step, the prediction, the frames of t0, the bodies' velocity changes from the impulses
        h: f64,
        body_x_in: wp.array(dtype=vec3d),
        body_q_in: wp.array(dtype=quatd),
        proj_in: wp.array(dtype=mat33d),
        jac_lin_in: wp.array(dtype=mat33d),
        jac_ang_in: wp.array(dtype=mat33d),
        jac_skew_in: wp.array(dtype=vec3d),
        response_v_in: wp.array(dtype=vec3d),
        response_w_in: wp.array(dtype=vec3d),
        response_turn_in: wp.array(dtype=vec3d),
        rhs_in: wp.array(dtype=vec3d),
        # Data out:
        newton_rhs_out: wp.array(dtype=vec3d),
    ):
        """The Newton step's right-hand side, rhs - E lambda (`arm_correction`, du from the impulses lambda)."""
        i = wp.tid()
        newton_rhs_out[i] = rhs_in[i] - arm_correction_of(
            i, constraint_kind, constraint_body0, constraint_body1, constraint_anchor0, constraint_anchor1,
            constraint_axis0, constraint_axis1, constraint_rest_rotation, constraint_rest_angle, h, proj_in,
            body_x_in, body_q_in, jac_lin_in, jac_ang_in, jac_skew_in, response_v_in, response_w_in, response_turn_in,
        )  # fmt: skip

    return SimpleNamespace(
        kinds=ks,
        module=module,
        frame=frame,
        position_error=position_error_of,
        frames=frames,
        position_errors=position_errors,
        velocity_errors=velocity_errors,
        arm_correction=arm_correction_of,
        arm_corrections=arm_corrections,
    )
