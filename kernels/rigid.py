"""Free rigid-body motion over one step (method paper, section 3, equations 1-4).

On the CPU, bodies are predicted `LANES` at a time (`predict_group`): each scalar of the rotation's RK4 holds one
value per body (`lanes`, a quaternion as the `quat_lanes` rows x, y, z, w), so that clang's SLP vectorizer turns
the four bodies' identical operations into vector instructions (`rk4_lanes`). The rotation's maths is written
once, generic over a scalar (`f64`) or a lane vector (`lanes`): each lane does the scalar code's operations in
its order, so a body's prediction is the same bit for bit alone or in lanes (docs/architecture.md, "Predictions
in lanes"). A body whose inertia is not diagonal in its own frame (`TURNED`: a model's bodies whose inertial
frames are turned, as in most MJCF files) is predicted in its principal frame by Euler's equations, in lanes too
(`predict_turned`; docs/history.md, "Turned bodies in lanes").
"""

from typing import Any

import warp as wp

wp.set_module_options({"enable_backward": False})

LANES = 4  # bodies predicted at once: 4 f64 fill a 256-bit vector register

vec3d = wp.vec3d
quatd = wp.quatd
mat33d = wp.mat33d
f64 = wp.float64
lanes = wp.types.vector(length=LANES, dtype=f64)  # one scalar of LANES bodies
quat_lanes = wp.types.matrix(shape=(4, LANES), dtype=f64)  # rows x, y, z, w; a column is one body's quaternion
vec3_lanes = wp.types.matrix(shape=(3, LANES), dtype=f64)  # rows x, y, z; a column is one body's vector
# `Model.body_principal`: how a body's inertia J is known. GENERAL: a full matrix (static bodies too); DIAGONAL:
# diagonal in the body frame (a body built on its principal axes); TURNED: diagonal in its principal frame, which
# `Model.body_axes` turns into the body frame (J = R diag(j) R^T): its rotation is predicted in that frame.
GENERAL = wp.constant(0)
DIAGONAL = wp.constant(1)
TURNED = wp.constant(2)


@wp.func
def times(a: f64, b: f64) -> f64:
    """a b (`times` of lanes: lane by lane)."""
    return a * b


@wp.func
def times(a: lanes, b: lanes) -> lanes:  # noqa: F811 (an overload)
    return wp.cw_mul(a, b)


@wp.func
def less_one(a: f64) -> f64:
    """a - 1 (`less_one` of lanes: lane by lane)."""
    return a - f64(1.0)


@wp.func
def less_one(a: lanes) -> lanes:  # noqa: F811 (an overload)
    return a - lanes(f64(1.0))


@wp.func
def rotation_terms(qx: Any, qy: Any, qz: Any, qw: Any, x: Any, y: Any, z: Any):
    """The two parts (a, b) of a vector v rotated by a unit quaternion q: q v q^-1 = a + b, q^-1 v q = a - b,
    with Warp's `quat_rotate` / `quat_rotate_inv` operations in their order (so `rotate` and `rotate_inv` equal
    them bit for bit). Components of one body (f64) or of LANES bodies (`lanes`)."""
    c = less_one(times(qw * f64(2.0), qw))
    d = (times(qx, x) + times(qy, y) + times(qz, z)) * f64(2.0)
    return (
        times(x, c) + times(qx, d),
        times(y, c) + times(qy, d),
        times(z, c) + times(qz, d),
        times(times(qy, z) - times(qz, y), qw) * f64(2.0),
        times(times(qz, x) - times(qx, z), qw) * f64(2.0),
        times(times(qx, y) - times(qy, x), qw) * f64(2.0),
    )


@wp.func
def rotate(q: quatd, v: vec3d) -> vec3d:
    """q v q^-1 (`rotation_terms`): body to world space."""
    ax, ay, az, bx, by, bz = rotation_terms(q[0], q[1], q[2], q[3], v[0], v[1], v[2])
    return vec3d(ax + bx, ay + by, az + bz)


@wp.func
def rotate(q: quat_lanes, v: vec3_lanes) -> vec3_lanes:  # noqa: F811 (an overload)
    ax, ay, az, bx, by, bz = rotation_terms(q[0], q[1], q[2], q[3], v[0], v[1], v[2])
    return wp.matrix_from_rows(ax + bx, ay + by, az + bz)


@wp.func
def rotate_inv(q: quatd, v: vec3d) -> vec3d:
    """q^-1 v q (`rotation_terms`): world to body space."""
    ax, ay, az, bx, by, bz = rotation_terms(q[0], q[1], q[2], q[3], v[0], v[1], v[2])
    return vec3d(ax - bx, ay - by, az - bz)


@wp.func
def rotate_inv(q: quat_lanes, v: vec3_lanes) -> vec3_lanes:  # noqa: F811 (an overload)
    ax, ay, az, bx, by, bz = rotation_terms(q[0], q[1], q[2], q[3], v[0], v[1], v[2])
    return wp.matrix_from_rows(ax - bx, ay - by, az - bz)


@wp.func
def product_terms(ax: Any, ay: Any, az: Any, aw: Any, bx: Any, by: Any, bz: Any, bw: Any):
    """The quaternion product a b (x, y, z, w); of one body (f64) or of LANES bodies (`lanes`)."""
    return (
        times(aw, bx) + times(ax, bw) + times(ay, bz) - times(az, by),
        times(aw, by) - times(ax, bz) + times(ay, bw) + times(az, bx),
        times(aw, bz) + times(ax, by) - times(ay, bx) + times(az, bw),
        times(aw, bw) - times(ax, bx) - times(ay, by) - times(az, bz),
    )


@wp.func
def turn(q: quatd, r: quatd) -> quatd:
    """q r (`product_terms`): a TURNED body's orientation in its principal frame (r its `Model.body_axes`), or
    back in its body frame (r their inverse)."""
    x, y, z, w = product_terms(q[0], q[1], q[2], q[3], r[0], r[1], r[2], r[3])
    return quatd(x, y, z, w)


@wp.func
def turn(q: quat_lanes, r: quat_lanes) -> quat_lanes:  # noqa: F811 (an overload)
    x, y, z, w = product_terms(q[0], q[1], q[2], q[3], r[0], r[1], r[2], r[3])
    return wp.matrix_from_rows(x, y, z, w)


@wp.func
def rotation_rate_terms(qx: Any, qy: Any, qz: Any, qw: Any, x: Any, y: Any, z: Any):
    """q (w_body, 0) = 2 dq/dt: equation 3, with the angular velocity in body space, less its factor 1/2, which
    `rk4_rotation` folds into its step fractions (scaling by 1/2 is exact: the same values, 4 products fewer). The
    product is spelled out without the terms of the zero scalar part (Warp's quaternion product in that order).
    Components of one body (f64) or of LANES bodies (`lanes`)."""
    return (
        times(qw, x) + times(qy, z) - times(y, qz),
        times(qw, y) + times(qz, x) - times(z, qx),
        times(qw, z) + times(qx, y) - times(x, qy),
        times(-qx, x) - times(qy, y) - times(qz, z),
    )


@wp.func
def rotation_rate(q: quatd, w_body: vec3d) -> quatd:
    """`rotation_rate_terms` of one body."""
    x, y, z, w = rotation_rate_terms(q[0], q[1], q[2], q[3], w_body[0], w_body[1], w_body[2])
    return quatd(x, y, z, w)


@wp.func
def rotation_rate(q: quat_lanes, w_body: vec3_lanes) -> quat_lanes:  # noqa: F811 (an overload)
    """`rotation_rate_terms` of LANES bodies."""
    x, y, z, w = rotation_rate_terms(q[0], q[1], q[2], q[3], w_body[0], w_body[1], w_body[2])
    return wp.matrix_from_rows(x, y, z, w)


@wp.func
def diagonal_times(m: mat33d, v: vec3d) -> vec3d:
    """m v for a diagonal m, its zeros skipped (the same value)."""
    return vec3d(m[0, 0] * v[0], m[1, 1] * v[1], m[2, 2] * v[2])


@wp.func
def is_diagonal(m: mat33d) -> bool:
    z = f64(0.0)
    return m[0, 1] == z and m[0, 2] == z and m[1, 0] == z and m[1, 2] == z and m[2, 0] == z and m[2, 1] == z


@wp.func
def euler_coefficients(inertia: mat33d, inv_inertia: mat33d) -> vec3d:
    """(J_y - J_z) / J_x and cyclic, for a diagonal inertia J (kg m^2): Euler's equations' gyroscopic factors."""
    return vec3d(
        (inertia[1, 1] - inertia[2, 2]) * inv_inertia[0, 0],
        (inertia[2, 2] - inertia[0, 0]) * inv_inertia[1, 1],
        (inertia[0, 0] - inertia[1, 1]) * inv_inertia[2, 2],
    )


@wp.kernel
def principal_terms(
    # Model:
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    body_moments: wp.array(dtype=vec3d),
    # Data out:
    body_principal_out: wp.array(dtype=int),
    body_euler_out: wp.array(dtype=vec3d),
    body_inv_principal_out: wp.array(dtype=vec3d),
):
    """How each body's inertia is known (`body_principal`: DIAGONAL, TURNED where the host found its principal
    moments j, kg m^2, `body_moments`, else GENERAL), and for the first two their `euler_coefficients` (all a
    prediction without torque reads of its inertia), and for a DIAGONAL body its inverse inertia's diagonal
    (1 / (kg m^2): all the world inverse inertia reads, `inertia.world_inverse_inertia_of`); `Model.set_masses`
    runs this."""
    b = wp.tid()
    body_principal_out[b] = GENERAL
    body_euler_out[b] = vec3d()
    body_inv_principal_out[b] = vec3d()
    j = body_moments[b]
    if is_diagonal(body_inertia[b]):
        inv = body_inv_inertia[b]
        body_principal_out[b] = DIAGONAL
        body_euler_out[b] = euler_coefficients(body_inertia[b], inv)
        body_inv_principal_out[b] = vec3d(inv[0, 0], inv[1, 1], inv[2, 2])
    elif j[0] > f64(0.0) and j[1] > f64(0.0) and j[2] > f64(0.0):
        body_principal_out[b] = TURNED
        inv_j = vec3d(f64(1.0) / j[0], f64(1.0) / j[1], f64(1.0) / j[2])
        body_euler_out[b] = euler_coefficients(wp.diag(j), wp.diag(inv_j))


@wp.func
def euler_terms(c0: Any, c1: Any, c2: Any, wx: Any, wy: Any, wz: Any):
    """Euler's equations without torque, dw_x/dt = c0 w_y w_z and cyclic (`euler_coefficients`), body space;
    components of one body (f64) or of LANES bodies (`lanes`)."""
    return times(times(c0, wy), wz), times(times(c1, wz), wx), times(times(c2, wx), wy)


@wp.func
def angular_acceleration(q: quatd, w_body: vec3d, inertia: mat33d, inv_inertia: mat33d, torque: vec3d) -> vec3d:
    """Equation 4 in body space, with the gyroscopic term; the world torque is held constant over the step.
    A zero torque is not rotated into the body frame. A diagonal inertia (a body built on its principal axes)
    takes Euler's equations (`euler_terms`): the gyroscopic term in 6 products where J^-1 (w x J w) takes 18
    (its coefficients are the same in the four RK4 stages, and the compiler forms them once), equal up to
    round-off."""
    if is_diagonal(inertia):
        c = euler_coefficients(inertia, inv_inertia)
        ax, ay, az = euler_terms(c[0], c[1], c[2], w_body[0], w_body[1], w_body[2])
        acc = vec3d(ax, ay, az)
        if torque[0] == f64(0.0) and torque[1] == f64(0.0) and torque[2] == f64(0.0):
            return acc
        return acc + diagonal_times(inv_inertia, wp.quat_rotate_inv(q, torque))
    gyro = wp.cross(w_body, inertia * w_body)
    if torque[0] == f64(0.0) and torque[1] == f64(0.0) and torque[2] == f64(0.0):
        return inv_inertia * (-gyro)
    return inv_inertia * (wp.quat_rotate_inv(q, torque) - gyro)


@wp.func
def angular_acceleration(q: quatd, w_body: vec3d, c0: f64, c1: f64, c2: f64) -> vec3d:  # noqa: F811 (an overload)
    """Equation 4 of one body without torque in its principal frame (`euler_terms`; c0 c1 c2 its
    `euler_coefficients`): a TURNED body's (`predict_turned`)."""
    ax, ay, az = euler_terms(c0, c1, c2, w_body[0], w_body[1], w_body[2])
    return vec3d(ax, ay, az)


@wp.func
def angular_acceleration(q: quat_lanes, w_body: vec3_lanes, c0: lanes, c1: lanes, c2: lanes) -> vec3_lanes:  # noqa: F811 (an overload)
    """Equation 4 of LANES bodies of diagonal inertia without torque (`euler_terms`, c0 c1 c2 their
    `euler_coefficients`)."""
    ax, ay, az = euler_terms(c0, c1, c2, w_body[0], w_body[1], w_body[2])
    return wp.matrix_from_rows(ax, ay, az)


MAX_SUBSTEP_ROTATION = wp.constant(wp.float64(0.25))  # rad per RK4 substep of the rotation
MAX_SUBSTEPS = wp.constant(64)


@wp.func
def rk4_step(q: Any, wb: Any, p0: Any, p1: Any, p2: Any, h: f64):
    """One classic RK4 step of equations 3 and 4 for (q, body-space w), q not yet normalized: of one body
    (quatd, vec3d; p0 p1 p2 its inertia, inverse inertia and world torque) or of LANES bodies (`quat_lanes`,
    `vec3_lanes`; p0 p1 p2 their `euler_coefficients`). The quaternion's rates are 2 dq/dt (`rotation_rate`), so
    its fractions of the step are halved."""
    half = f64(0.5) * h
    quarter = f64(0.5) * half
    k1q = rotation_rate(q, wb)
    k1w = angular_acceleration(q, wb, p0, p1, p2)
    q2 = q + k1q * quarter
    w2 = wb + k1w * half
    k2q = rotation_rate(q2, w2)
    k2w = angular_acceleration(q2, w2, p0, p1, p2)
    q3 = q + k2q * quarter
    w3 = wb + k2w * half
    k3q = rotation_rate(q3, w3)
    k3w = angular_acceleration(q3, w3, p0, p1, p2)
    q4 = q + k3q * half
    w4 = wb + k3w * h
    k4q = rotation_rate(q4, w4)
    k4w = angular_acceleration(q4, w4, p0, p1, p2)
    sixth = h / f64(6.0)
    q1 = q + (k1q + k2q * f64(2.0) + k3q * f64(2.0) + k4q) * (f64(0.5) * sixth)
    return q1, wb + (k1w + k2w * f64(2.0) + k3w * f64(2.0) + k4w) * sixth


@wp.func
def rk4_rotation(q: quatd, wb: vec3d, p0: Any, p1: Any, p2: Any, h: f64):
    """`rk4_step` of one body, q normalized: p0 p1 p2 its inertia, inverse inertia and world torque, or for a
    TURNED body in its principal frame its three Euler coefficients."""
    q1, w1 = rk4_step(q, wb, p0, p1, p2, h)
    return wp.normalize(q1), w1


@wp.func(inline=False)
def rk4_lanes(q: quat_lanes, w: vec3_lanes, c0: lanes, c1: lanes, c2: lanes, h: f64):
    """`rk4_step` of LANES bodies from their world angular velocities (rad/s), returning q not yet normalized
    and w in body space. Kept out of line, like `rotate_lanes`: its results leave as whole vectors (stores of
    LANES doubles side by side), which is where clang's SLP vectorizer starts; inlined, the lanes feed scalar
    code (normalization, the stores of each body), and clang leaves them scalar (a body in lanes then costs the
    same ~40 ns as alone)."""
    return rk4_step(q, rotate_inv(q, w), c0, c1, c2, h)


@wp.func(inline=False)
def rk4_turned_lanes(q: quat_lanes, r: quat_lanes, w: vec3_lanes, c0: lanes, c1: lanes, c2: lanes, h: f64):
    """`rk4_lanes` of LANES TURNED bodies, in their principal frames (q turned by r, their `Model.body_axes`):
    (their orientation there, not yet normalized, and w in it)."""
    qp = turn(q, r)
    return rk4_step(qp, rotate_inv(qp, w), c0, c1, c2, h)


@wp.func(inline=False)
def rotate_lanes(q: quat_lanes, v: vec3_lanes) -> vec3_lanes:
    """`rotate` of LANES bodies, out of line (`rk4_lanes`)."""
    return rotate(q, v)


@wp.func(inline=False)
def turn_lanes(q: quat_lanes, r: quat_lanes) -> quat_lanes:
    """`turn` of LANES bodies, out of line (`rk4_lanes`)."""
    return turn(q, r)


@wp.func
def translation(x: vec3d, v: vec3d, inv_mass: f64, force: vec3d, gravity: vec3d, h: f64):
    """Exact translation over h under gravity and a constant force (equations 1-2): (x, v) at t0 + h."""
    a = gravity + force * inv_mass
    return x + v * h + a * (f64(0.5) * h * h), v + a * h


@wp.func
def substeps(w: vec3d, h: f64):
    """(n, h / n): the RK4 substeps of a body spinning at w (rad/s, world frame) over h, so that each turns at most
    MAX_SUBSTEP_ROTATION (a fast spin stays on its axis); one for slower bodies, as in the paper."""
    n = int(1)
    hs = h
    if wp.length_sq(w) * (h * h) > MAX_SUBSTEP_ROTATION * MAX_SUBSTEP_ROTATION:  # no root nor division below
        n = wp.min(int(wp.ceil(wp.length(w) * wp.abs(h) / MAX_SUBSTEP_ROTATION)), MAX_SUBSTEPS)  # h < 0: backwards
        n = wp.max(n, 1)
        hs = h / f64(n)
    return n, hs


@wp.func
def predict_body(
    x: vec3d,
    q: quatd,
    v: vec3d,
    w: vec3d,
    inv_mass: f64,
    inertia: mat33d,
    inv_inertia: mat33d,
    force: vec3d,
    torque: vec3d,
    gravity: vec3d,
    h: f64,
):
    """The state after a step of h: exact translation (equations 1-2), RK4 rotation (equations 3-4), in
    `substeps` of h. Static bodies stay put."""
    if inv_mass == f64(0.0):
        return x, q, v, w
    x1, v1 = translation(x, v, inv_mass, force, gravity, h)
    q1, wb = rotation_steps(q, rotate_inv(q, w), w, inertia, inv_inertia, torque, h)
    return x1, q1, v1, rotate(q1, wb)


@wp.func
def rotation_steps(q: quatd, wb: vec3d, w: vec3d, p0: Any, p1: Any, p2: Any, h: f64):
    """(q, w in the frame of q) after h in `substeps` of RK4 (`rk4_rotation`, p0 p1 p2 as there), w the world
    angular velocity at the start (rad/s)."""
    n, hs = substeps(w, h)
    q1 = q
    w1 = wb
    k = wp.int32(0)
    while k < n:
        q1, w1 = rk4_rotation(q1, w1, p0, p1, p2, hs)
        k += 1
    return q1, w1


@wp.func
def predict_turned(
    x: vec3d,
    q: quatd,
    v: vec3d,
    w: vec3d,
    inv_mass: f64,
    axes: quatd,
    euler: vec3d,
    force: vec3d,
    gravity: vec3d,
    h: f64,
):
    """`predict_body` of a TURNED body without torque: its rotation in its principal frame (q turned by `axes`,
    its `Model.body_axes`), by Euler's equations (`euler`: `principal_terms`), and turned back. RK4 is the same
    in any frame fixed in the body (its stages are linear in q and w), so this is the body frame's prediction to
    round-off, in 6 products of the gyroscopic term where J^-1 (w x J w) takes 18. (Not with a torque: turned
    into the body by an RK4 stage's q, not of unit length, it differs between frames by more than round-off.)"""
    x1, v1 = translation(x, v, inv_mass, force, gravity, h)
    qp = turn(q, axes)
    q1, wb = rotation_steps(qp, rotate_inv(qp, w), w, euler[0], euler[1], euler[2], h)
    return x1, turn(q1, wp.quat_inverse(axes)), v1, rotate(q1, wb)


@wp.func
def predict_of(
    b: int,
    x: vec3d,
    q: quatd,
    v: vec3d,
    w: vec3d,
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    body_principal: wp.array(dtype=int),
    body_euler: wp.array(dtype=vec3d),
    body_axes: wp.array(dtype=quatd),
    force: vec3d,
    torque: vec3d,
    gravity: vec3d,
    h: f64,
):
    """Body b's state after a step of h from (x, q, v, w): `predict_turned` for a TURNED body without torque, else
    `predict_body` (every prediction of a body, alone, in a group or in a sweep, takes this one)."""
    x1 = vec3d()
    q1 = quatd()
    v1 = vec3d()
    w1 = vec3d()
    if body_principal[b] == TURNED and torque[0] == f64(0.0) and torque[1] == f64(0.0) and torque[2] == f64(0.0):
        x1, q1, v1, w1 = predict_turned(x, q, v, w, body_inv_mass[b], body_axes[b], body_euler[b], force, gravity, h)
    else:
        x1, q1, v1, w1 = predict_body(
            x, q, v, w, body_inv_mass[b], body_inertia[b], body_inv_inertia[b], force, torque, gravity, h
        )
    return x1, q1, v1, w1


@wp.func
def predict_index(
    b: int,
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    body_principal: wp.array(dtype=int),
    body_euler: wp.array(dtype=vec3d),
    body_axes: wp.array(dtype=quatd),
    gravity: vec3d,
    h: f64,
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    body_force_in: wp.array(dtype=vec3d),
    body_torque_in: wp.array(dtype=vec3d),
    body_x_out: wp.array(dtype=vec3d),
    body_q_out: wp.array(dtype=quatd),
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
):
    """Body b's free motion over h from the state in, written to the state out (`predict_of`)."""
    x, q, v, w = predict_of(
        b, body_x_in[b], body_q_in[b], body_v_in[b], body_w_in[b], body_inv_mass, body_inertia, body_inv_inertia,
        body_principal, body_euler, body_axes, body_force_in[b], body_torque_in[b], gravity, h,
    )  # fmt: skip
    body_x_out[b] = x
    body_q_out[b] = q
    body_v_out[b] = v
    body_w_out[b] = w


@wp.func
def fits_lanes(
    b: int,
    body_inv_mass: wp.array(dtype=f64),
    h: f64,
    body_w_in: wp.array(dtype=vec3d),
    body_torque_in: wp.array(dtype=vec3d),
) -> bool:
    """Whether body b's prediction can take a lane (`predict_lanes`): it is static, or without torque in one RK4
    step (`substeps`)."""
    if body_inv_mass[b] == f64(0.0):
        return True
    t = body_torque_in[b]
    n, hs = substeps(body_w_in[b], h)
    no_torque = t[0] == f64(0.0) and t[1] == f64(0.0) and t[2] == f64(0.0)
    return no_torque and n == 1


@wp.func
def lane_kind(
    b0: int,
    body_inv_mass: wp.array(dtype=f64),
    body_principal: wp.array(dtype=int),
    h: f64,
    body_w_in: wp.array(dtype=vec3d),
    body_torque_in: wp.array(dtype=vec3d),
) -> int:
    """How bodies b0 .. b0 + LANES - 1 take lanes: DIAGONAL or TURNED, the `body_principal` of every dynamic one
    among them, or GENERAL: not at all (one does not `fits_lanes`, one is GENERAL, or DIAGONAL and TURNED bodies
    are mixed: a lane does a body's own operations, and a DIAGONAL body's are not turned). A group of static
    bodies takes DIAGONAL lanes."""
    diagonal = wp.int32(0)
    turned = wp.int32(0)
    fits = True
    for i in range(LANES):
        b = b0 + i
        if fits:
            fits = fits_lanes(b, body_inv_mass, h, body_w_in, body_torque_in)
        if body_inv_mass[b] != f64(0.0):
            p = body_principal[b]
            if p == TURNED:
                turned += 1
            elif p == DIAGONAL:
                diagonal += 1
            else:
                fits = False
    if not fits or (turned > 0 and diagonal > 0):
        return GENERAL
    if turned > 0:
        return TURNED
    return DIAGONAL


@wp.func
def predict_lanes(
    b0: int,
    kind: int,
    body_inv_mass: wp.array(dtype=f64),
    body_euler: wp.array(dtype=vec3d),
    body_axes: wp.array(dtype=quatd),
    gravity: vec3d,
    h: f64,
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    body_force_in: wp.array(dtype=vec3d),
    body_x_out: wp.array(dtype=vec3d),
    body_q_out: wp.array(dtype=quatd),
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
):
    """`predict_index` of bodies b0 .. b0 + LANES - 1, which all `fits_lanes`, their rotations in lanes: the
    same values (a static body's lane is computed and dropped). A body's inertia comes as its Euler coefficients
    (`principal_terms`): 24 bytes read, where the two inertia matrices are 144. `kind` (`lane_kind`) TURNED: the
    rotations are predicted in the principal frames (`predict_turned`)."""
    q = quat_lanes()
    w = vec3_lanes()
    r = quat_lanes()
    c0 = lanes()
    c1 = lanes()
    c2 = lanes()
    for i in range(LANES):
        b = b0 + i
        qi = body_q_in[b]
        wi = body_w_in[b]
        ci = body_euler[b]
        for k in range(3):
            w[k, i] = wi[k]
        for k in range(4):
            q[k, i] = qi[k]
        c0[i] = ci[0]
        c1[i] = ci[1]
        c2[i] = ci[2]
    q1 = quat_lanes()
    wb1 = vec3_lanes()
    if kind == TURNED:
        for i in range(LANES):
            ri = body_axes[b0 + i]
            for k in range(4):
                r[k, i] = ri[k]
        q1, wb1 = rk4_turned_lanes(q, r, w, c0, c1, c2, h)
    else:
        q1, wb1 = rk4_lanes(q, w, c0, c1, c2, h)
    for i in range(LANES):
        qi = wp.normalize(quatd(q1[0, i], q1[1, i], q1[2, i], q1[3, i]))
        for k in range(4):
            q1[k, i] = qi[k]
    w1 = rotate_lanes(q1, wb1)
    if kind == TURNED:  # back in the body frames
        q1 = turn_lanes(q1, wp.matrix_from_rows(-r[0], -r[1], -r[2], r[3]))
    for i in range(LANES):
        b = b0 + i
        inv_mass = body_inv_mass[b]
        if inv_mass == f64(0.0):
            body_x_out[b] = body_x_in[b]
            body_q_out[b] = body_q_in[b]
            body_v_out[b] = body_v_in[b]
            body_w_out[b] = body_w_in[b]
        else:
            x1, v1 = translation(body_x_in[b], body_v_in[b], inv_mass, body_force_in[b], gravity, h)
            body_x_out[b] = x1
            body_q_out[b] = quatd(q1[0, i], q1[1, i], q1[2, i], q1[3, i])
            body_v_out[b] = v1
            body_w_out[b] = vec3d(w1[0, i], w1[1, i], w1[2, i])


@wp.func(inline=True)
def predict_group(
    b0: int,
    count: int,
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    body_principal: wp.array(dtype=int),
    body_euler: wp.array(dtype=vec3d),
    body_axes: wp.array(dtype=quatd),
    gravity: vec3d,
    h: f64,
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    body_force_in: wp.array(dtype=vec3d),
    body_torque_in: wp.array(dtype=vec3d),
    body_x_out: wp.array(dtype=vec3d),
    body_q_out: wp.array(dtype=quatd),
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
):
    """`predict_index` of bodies b0 .. b0 + count - 1: in lanes when they are LANES that `lane_kind` takes, else
    one at a time."""
    kind = GENERAL
    if count == LANES:
        kind = lane_kind(b0, body_inv_mass, body_principal, h, body_w_in, body_torque_in)
    if kind != GENERAL:
        predict_lanes(
            b0, kind, body_inv_mass, body_euler, body_axes, gravity, h, body_x_in, body_q_in, body_v_in, body_w_in,
            body_force_in, body_x_out, body_q_out, body_v_out, body_w_out,
        )  # fmt: skip
    else:
        b = b0
        while b < b0 + count:
            predict_index(
                b, body_inv_mass, body_inertia, body_inv_inertia, body_principal, body_euler, body_axes, gravity, h,
                body_x_in, body_q_in, body_v_in, body_w_in, body_force_in, body_torque_in, body_x_out, body_q_out,
                body_v_out, body_w_out,
            )  # fmt: skip
            b += 1


@wp.kernel
def predict(
    # Model:
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    body_principal: wp.array(dtype=int),
    body_euler: wp.array(dtype=vec3d),
    body_axes: wp.array(dtype=quatd),
    gravity: vec3d,
    # Data in:
    h: f64,
    group_size: int,
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    body_force_in: wp.array(dtype=vec3d),
    body_torque_in: wp.array(dtype=vec3d),
    # Data out: the prediction
    body_x_out: wp.array(dtype=vec3d),
    body_q_out: wp.array(dtype=quatd),
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
):
    """Every body's free motion over h from the state in (section 3), `group_size` bodies a thread
    (`predict_group`: LANES on the CPU, 1 on a GPU)."""
    b0 = wp.tid() * group_size
    predict_group(
        b0, wp.min(group_size, body_inv_mass.shape[0] - b0), body_inv_mass, body_inertia, body_inv_inertia,
        body_principal, body_euler, body_axes, gravity, h, body_x_in, body_q_in, body_v_in, body_w_in, body_force_in,
        body_torque_in, body_x_out, body_q_out, body_v_out, body_w_out,
    )  # fmt: skip


@wp.func
def body_summary(
    b: int,
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
):
    """(whether body b's state is finite, its |w| in rad/s)."""
    w = body_w_in[b]
    s = wp.length_sq(body_x_in[b]) + wp.length_sq(body_v_in[b]) + wp.length_sq(w) + wp.dot(body_q_in[b], body_q_in[b])
    return wp.isfinite(s), wp.length(w)


@wp.kernel
def summarize_state(
    # Data in:
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    # Data out:
    summary_out: wp.array(dtype=f64),
):
    """summary[0] += 1 for every body with a NaN or Inf in its state; summary[1] = the largest finite |w|.
    Two numbers to read back per step: the divergence check and the spin that sets the next step's substeps."""
    finite, spin = body_summary(wp.tid(), body_x_in, body_q_in, body_v_in, body_w_in)
    if finite:
        wp.atomic_max(summary_out, 1, spin)
    else:
        wp.atomic_add(summary_out, 0, f64(1.0))
