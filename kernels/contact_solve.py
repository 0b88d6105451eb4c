"""Contact detection launches and the contact impulses (Bender & Schmitt, CASA 2006, in the step's loop).

Position phase (at t0, in the loop with the joints): every contact's gap on the predicted state must be >= 0.
Linearised about the current prediction, an impulse at t0 that changes the contact's relative point velocity by
du changes the predicted gap by h n . du, and the contact's tangential slip over the step by h du_t. The
impulses are push-only (lambda_n >= 0); friction sticks (no slip over the step) when the impulse that stops
the slip lies in the cone |lambda_t| <= mu lambda_n, else it slides with |lambda_t| = mu lambda_n. Solved by
projected Gauss-Seidel sweeps over the contacts, then the bodies are predicted again (`contacts.py`).

Velocity phase (at t0+h, after the joints' velocity correction): the relative normal velocity of a touching
contact becomes >= e v_impact at an impact (Newton's restitution), >= 0 otherwise, and friction stops the
tangential velocity within the cone of this phase's normal impulse.

The impact speed is the speed at the moment of contact, from the free prediction's normal velocity and gap and
the normal acceleration of the bodies' loads: v_impact^2 = v_n^2 - 2 a_n g (exact for constant loads), so a
bounce returns the energy of the impact whatever the step.

A Gauss-Seidel sweep updates bodies one contact at a time, so the sweep kernels run as one thread.
"""

import warp as wp

from . import collide
from .inertia import sym33d, symmetric_matrix

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
quatd = wp.quatd
mat33d = wp.mat33d
mat22d = wp.mat22d
vec2d = wp.vec2d
f64 = wp.float64


# ------------------------------------------------------------------------------------------ detection
@wp.kernel
def swept_bounds(
    # Model (the stage's collider list):
    collider_body: wp.array(dtype=int),
    body_bound: wp.array(dtype=f64),
    margin: f64,
    # Data in: the state at t0 and the prediction
    body_x_in: wp.array(dtype=vec3d),
    pred_x: wp.array(dtype=vec3d),
    # Data out:
    lowers_out: wp.array(dtype=wp.vec3),
    uppers_out: wp.array(dtype=wp.vec3),
):
    """The box around a collider's bounding sphere at t0 and at t0+h: a fast body finds what it passes."""
    i = wp.tid()
    b = collider_body[i]
    r = body_bound[b] + margin
    x0 = body_x_in[b]
    x1 = pred_x[b]
    lo = wp.min(x0, x1) - vec3d(r, r, r)
    hi = wp.max(x0, x1) + vec3d(r, r, r)
    lowers_out[i] = wp.vec3(float(lo[0]), float(lo[1]), float(lo[2]))
    uppers_out[i] = wp.vec3(float(hi[0]), float(hi[1]), float(hi[2]))


@wp.func
def filtered(keys: wp.array(dtype=wp.int64), key: wp.int64) -> bool:
    """Binary search of a sorted key list."""
    lo = int(0)
    hi = keys.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if keys[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    return lo < keys.shape[0] and keys[lo] == key


@wp.kernel
def broad_phase(
    # Model:
    bvh: wp.uint64,
    collider_body: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    filter_keys: wp.array(dtype=wp.int64),
    body_count: int,
    # Data in:
    lowers: wp.array(dtype=wp.vec3),
    uppers: wp.array(dtype=wp.vec3),
    # Data out:
    pair_count_out: wp.array(dtype=int),
    pair_body_out: wp.array(dtype=wp.vec2i),
):
    """Pairs of colliders whose swept boxes overlap, once each (i < j), neither both static nor filtered."""
    i = wp.tid()
    bi = collider_body[i]
    query = wp.bvh_query_aabb(bvh, lowers[i], uppers[i])
    j = int(0)
    while wp.bvh_query_next(query, j):
        if j > i:
            bj = collider_body[j]
            if body_inv_mass[bi] > f64(0.0) or body_inv_mass[bj] > f64(0.0):
                key = wp.int64(wp.min(bi, bj)) * wp.int64(body_count) + wp.int64(wp.max(bi, bj))
                if not filtered(filter_keys, key):
                    slot = wp.atomic_add(pair_count_out, 0, 1)
                    if slot < pair_body_out.shape[0]:
                        pair_body_out[slot] = wp.vec2i(bi, bj)


@wp.kernel
def all_pairs(
    # Model:
    collider_body: wp.array(dtype=int),
    body_inv_mass: wp.array(dtype=f64),
    filter_keys: wp.array(dtype=wp.int64),
    body_count: int,
    collider_count: int,
    # Data in:
    lowers: wp.array(dtype=wp.vec3),
    uppers: wp.array(dtype=wp.vec3),
    # Data out:
    pair_count_out: wp.array(dtype=int),
    pair_body_out: wp.array(dtype=wp.vec2i),
):
    """The same pairs as `broad_phase` by testing every pair of boxes: the baseline it is measured against."""
    i = wp.tid()
    bi = collider_body[i]
    lo = lowers[i]
    hi = uppers[i]
    j = i + 1
    while j < collider_count:
        if lo[0] <= uppers[j][0] and lowers[j][0] <= hi[0] and lo[1] <= uppers[j][1] and lowers[j][1] <= hi[1]:
            if lo[2] <= uppers[j][2] and lowers[j][2] <= hi[2]:
                bj = collider_body[j]
                if body_inv_mass[bi] > f64(0.0) or body_inv_mass[bj] > f64(0.0):
                    key = wp.int64(wp.min(bi, bj)) * wp.int64(body_count) + wp.int64(wp.max(bi, bj))
                    if not filtered(filter_keys, key):
                        slot = wp.atomic_add(pair_count_out, 0, 1)
                        if slot < pair_body_out.shape[0]:
                            pair_body_out[slot] = wp.vec2i(bi, bj)
        j += 1


@wp.func
def body_inv_mass_of(b: int, body_inv_mass: wp.array(dtype=f64)) -> f64:
    if b < 0:
        return f64(0.0)
    return body_inv_mass[b]


@wp.func
def body_acceleration(
    b: int, body_inv_mass: wp.array(dtype=f64), gravity: vec3d, body_force: wp.array(dtype=vec3d)
) -> vec3d:
    """The acceleration of a body's centre under gravity and its constant force (zero for static bodies)."""
    if b < 0:
        return vec3d()
    im = body_inv_mass[b]
    if im == f64(0.0):
        return vec3d()
    return gravity + body_force[b] * im


@wp.func
def point_velocity(b: int, p: vec3d, xs: wp.array(dtype=vec3d), vs: wp.array(dtype=vec3d), ws: wp.array(dtype=vec3d)):
    if b < 0:
        return vec3d()
    return vs[b] + wp.cross(ws[b], p - xs[b])


@wp.func
def to_local(b: int, p: vec3d, xs: wp.array(dtype=vec3d), qs: wp.array(dtype=quatd)) -> vec3d:
    if b < 0:
        return p
    return wp.quat_rotate_inv(qs[b], p - xs[b])


@wp.func
def to_world(b: int, p: vec3d, xs: wp.array(dtype=vec3d), qs: wp.array(dtype=quatd)) -> vec3d:
    if b < 0:
        return p
    return xs[b] + wp.quat_rotate(qs[b], p)


@wp.func
def surface_points(
    a: int,
    b: int,
    anchor_a: vec3d,
    anchor_b: vec3d,
    radius: wp.vec2d,
    n: vec3d,
    xs: wp.array(dtype=vec3d),
    qs: wp.array(dtype=quatd),
):
    """A contact's points on a's and b's surfaces (world) at the poses xs, qs (`emit`: anchors and radii)."""
    return to_world(a, anchor_a, xs, qs) + n * radius[0], to_world(b, anchor_b, xs, qs) - n * radius[1]


@wp.func
def rounding(kind: int, size: vec3d) -> f64:
    """The radius about a shape's core of its surface near a contact: a sphere's or capsule's (the core: its
    centre or axis), 0 for a box and for a cylinder's rim against a plane (points fixed in the body)."""
    if kind == collide.SPHERE or kind == collide.CAPSULE:
        return size[0]
    return f64(0.0)


@wp.func
def emit(
    a: int,
    b: int,
    count: int,
    n: vec3d,
    points: collide.mat83d,
    gaps: collide.vec8d,
    radius_a: f64,
    radius_b: f64,
    friction: f64,
    restitution: f64,
    body_inv_mass: wp.array(dtype=f64),
    gravity: vec3d,
    body_force: wp.array(dtype=vec3d),
    pred_x: wp.array(dtype=vec3d),
    pred_q: wp.array(dtype=quatd),
    pred_v: wp.array(dtype=vec3d),
    pred_w: wp.array(dtype=vec3d),
    contact_count: wp.array(dtype=int),
    contact_body: wp.array(dtype=wp.vec2i),
    contact_anchor_a: wp.array(dtype=vec3d),
    contact_anchor_b: wp.array(dtype=vec3d),
    contact_radius: wp.array(dtype=wp.vec2d),
    contact_normal: wp.array(dtype=vec3d),
    contact_material: wp.array(dtype=wp.vec2d),
    contact_impact: wp.array(dtype=f64),
):
    """Store a manifold: anchors in the bodies' frames (world for a plane), the impact speed of each point.
    The anchor of a rounded side (a sphere, a capsule: `radius_a`, `radius_b` > 0) is the centre of its
    rounding, the surface point `radius` from it along the normal (`surface_points`): a rolling ball's contact
    stays under its centre while it turns, where a point fixed in the ball would turn away from the ground."""
    if count == 0:
        return
    first = wp.atomic_add(contact_count, 0, count)
    da = body_acceleration(a, body_inv_mass, gravity, body_force)
    db = body_acceleration(b, body_inv_mass, gravity, body_force)
    an = wp.dot(n, db - da)
    i = wp.int32(0)
    while i < count:
        k = first + i
        if k < contact_body.shape[0]:
            pb = points[i]
            g = gaps[i]
            pa = pb - n * g
            contact_body[k] = wp.vec2i(a, b)
            contact_anchor_a[k] = to_local(a, pa - n * radius_a, pred_x, pred_q)
            contact_anchor_b[k] = to_local(b, pb + n * radius_b, pred_x, pred_q)
            contact_radius[k] = wp.vec2d(radius_a, radius_b)
            contact_normal[k] = n
            contact_material[k] = wp.vec2d(friction, restitution)
            vn = wp.dot(
                n, point_velocity(b, pb, pred_x, pred_v, pred_w) - point_velocity(a, pa, pred_x, pred_v, pred_w)
            )
            impact = f64(0.0)
            if vn < f64(0.0) and g < f64(0.0):
                impact = wp.sqrt(wp.max(vn * vn - f64(2.0) * an * g, f64(0.0)))
            contact_impact[k] = impact
        i += 1


@wp.func
def body_rotation(b: int, qs: wp.array(dtype=quatd)) -> mat33d:
    return wp.quat_to_matrix(qs[b])


@wp.func
def effective_kind(kind: int) -> int:
    """Against anything but a plane a cylinder is taken as a capsule (module docstring of `collide`)."""
    if kind == collide.CYLINDER:
        return collide.CAPSULE
    return kind


@wp.kernel
def narrow_phase(
    # Model:
    body_shape: wp.array(dtype=int),
    body_size: wp.array(dtype=vec3d),
    body_friction: wp.array(dtype=f64),
    body_restitution: wp.array(dtype=f64),
    body_inv_mass: wp.array(dtype=f64),
    gravity: vec3d,
    margin: f64,
    # Data in:
    body_force_in: wp.array(dtype=vec3d),
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    pred_x: wp.array(dtype=vec3d),
    pred_q: wp.array(dtype=quatd),
    pred_v: wp.array(dtype=vec3d),
    pred_w: wp.array(dtype=vec3d),
    pair_count: wp.array(dtype=int),
    pair_body: wp.array(dtype=wp.vec2i),
    # Data out:
    contact_count_out: wp.array(dtype=int),
    contact_body_out: wp.array(dtype=wp.vec2i),
    contact_anchor_a_out: wp.array(dtype=vec3d),
    contact_anchor_b_out: wp.array(dtype=vec3d),
    contact_radius_out: wp.array(dtype=wp.vec2d),
    contact_normal_out: wp.array(dtype=vec3d),
    contact_material_out: wp.array(dtype=wp.vec2d),
    contact_impact_out: wp.array(dtype=f64),
):
    """One pair of bodies on the predicted state; a is the one of the higher shape code (box > capsule >
    sphere), so each function sees its shapes in one order."""
    tid = wp.tid()
    if tid >= wp.min(pair_count[0], pair_body.shape[0]):
        return
    a = pair_body[tid][0]
    b = pair_body[tid][1]
    if effective_kind(body_shape[a]) < effective_kind(body_shape[b]):
        a, b = b, a
    ka = effective_kind(body_shape[a])
    kb = effective_kind(body_shape[b])
    ca = pred_x[a]
    cb = pred_x[b]
    ra = body_rotation(a, pred_q)
    rb = body_rotation(b, pred_q)
    sa = body_size[a]
    sb = body_size[b]
    za = collide.column(ra, 2)
    zb = collide.column(rb, 2)
    count = int(0)
    n = vec3d()
    points = collide.mat83d()
    gaps = collide.vec8d()
    if ka == collide.SPHERE:
        count, n, points, gaps = collide.sphere_sphere(ca, sa[0], cb, sb[0], margin)
    elif ka == collide.CAPSULE:
        if kb == collide.SPHERE:
            count, n, points, gaps = collide.capsule_sphere(ca, za, sa[0], sa[1], cb, sb[0], margin)
        else:
            count, n, points, gaps = collide.capsule_capsule(ca, za, sa[0], sa[1], cb, zb, sb[0], sb[1], margin)
    else:
        if kb == collide.SPHERE:
            # b's centre at t0 in a's frame at t0: the sweep of b relative to a.
            start = wp.quat_rotate_inv(body_q_in[a], body_x_in[b] - body_x_in[a])
            count, n, points, gaps = collide.box_sphere(ca, ra, sa, cb, sb[0], start, margin)
        elif kb == collide.CAPSULE:
            count, n, points, gaps = collide.box_capsule(ca, ra, sa, cb, zb, sb[0], sb[1], margin)
        else:
            count, n, points, gaps = collide.box_box(ca, ra, sa, cb, rb, sb, margin)
    friction = wp.sqrt(body_friction[a] * body_friction[b])
    restitution = wp.max(body_restitution[a], body_restitution[b])
    emit(a, b, count, n, points, gaps, rounding(ka, sa), rounding(kb, sb), friction, restitution, body_inv_mass,
         gravity, body_force_in, pred_x, pred_q, pred_v, pred_w, contact_count_out, contact_body_out,
         contact_anchor_a_out, contact_anchor_b_out, contact_radius_out, contact_normal_out, contact_material_out,
         contact_impact_out)  # fmt: skip


@wp.kernel
def plane_phase(
    # Model:
    collider_body: wp.array(dtype=int),
    body_shape: wp.array(dtype=int),
    body_size: wp.array(dtype=vec3d),
    body_friction: wp.array(dtype=f64),
    body_restitution: wp.array(dtype=f64),
    body_inv_mass: wp.array(dtype=f64),
    plane_normal: wp.array(dtype=vec3d),
    plane_offset: wp.array(dtype=f64),
    plane_material: wp.array(dtype=wp.vec2d),
    gravity: vec3d,
    margin: f64,
    # Data in:
    body_force_in: wp.array(dtype=vec3d),
    pred_x: wp.array(dtype=vec3d),
    pred_q: wp.array(dtype=quatd),
    pred_v: wp.array(dtype=vec3d),
    pred_w: wp.array(dtype=vec3d),
    # Data out:
    contact_count_out: wp.array(dtype=int),
    contact_body_out: wp.array(dtype=wp.vec2i),
    contact_anchor_a_out: wp.array(dtype=vec3d),
    contact_anchor_b_out: wp.array(dtype=vec3d),
    contact_radius_out: wp.array(dtype=wp.vec2d),
    contact_normal_out: wp.array(dtype=vec3d),
    contact_material_out: wp.array(dtype=wp.vec2d),
    contact_impact_out: wp.array(dtype=f64),
):
    """Every dynamic collider against every ground plane (a = -1, the plane)."""
    i, p = wp.tid()
    b = collider_body[i]
    if body_inv_mass[b] == f64(0.0):
        return
    n = plane_normal[p]
    off = plane_offset[p]
    c = pred_x[b]
    rot = body_rotation(b, pred_q)
    s = body_size[b]
    z = collide.column(rot, 2)
    kind = body_shape[b]
    count = int(0)
    points = collide.mat83d()
    gaps = collide.vec8d()
    if kind == collide.SPHERE:
        count, n, points, gaps = collide.plane_sphere(n, off, c, s[0], margin)
    elif kind == collide.CAPSULE:
        count, n, points, gaps = collide.plane_capsule(n, off, c, z, s[0], s[1], margin)
    elif kind == collide.BOX:
        count, n, points, gaps = collide.plane_box(n, off, c, rot, s, margin)
    else:
        count, n, points, gaps = collide.plane_cylinder(n, off, c, z, s[0], s[1], margin)
    mat = plane_material[p]
    friction = wp.sqrt(body_friction[b] * mat[0])
    restitution = wp.max(body_restitution[b], mat[1])
    emit(-1, b, count, n, points, gaps, f64(0.0), rounding(kind, s), friction, restitution, body_inv_mass, gravity,
         body_force_in, pred_x, pred_q, pred_v, pred_w, contact_count_out, contact_body_out, contact_anchor_a_out,
         contact_anchor_b_out, contact_radius_out, contact_normal_out, contact_material_out,
         contact_impact_out)  # fmt: skip


# ------------------------------------------------------------------------------------------ impulses
@wp.func
def inverse_inertia(b: int, inv_inertia_world: wp.array(dtype=sym33d)) -> mat33d:
    if b < 0:
        return mat33d()
    return symmetric_matrix(inv_inertia_world[b])


@wp.func
def pair_inverses(a: int, b: int, body_inv_mass: wp.array(dtype=f64), inv_inertia_world: wp.array(dtype=sym33d)):
    """(1/m_a, 1/m_b, I_a^-1, I_b^-1) of a contact's two bodies (world frame; zeros for the world, index < 0)."""
    return (body_inv_mass_of(a, body_inv_mass), body_inv_mass_of(b, body_inv_mass),
            inverse_inertia(a, inv_inertia_world), inverse_inertia(b, inv_inertia_world))  # fmt: skip


@wp.func
def impulse_vector(n: vec3d, lam: vec3d) -> vec3d:
    """The world impulse of a contact's (normal, tangent 1, tangent 2) components; the tangents are
    `collide.any_perpendicular(n)` and n x it, as the solves use them."""
    t1 = collide.any_perpendicular(n)
    return n * lam[0] + t1 * lam[1] + wp.cross(n, t1) * lam[2]


@wp.func
def apply_impulse(
    b: int,
    p: vec3d,
    r: vec3d,
    inv_m: f64,
    inv_i: mat33d,
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    if b >= 0 and inv_m > f64(0.0):
        body_v[b] = body_v[b] + p * inv_m
        body_w[b] = body_w[b] + inv_i * wp.cross(r, p)


@wp.func
def apply_pair(
    a: int,
    b: int,
    p: vec3d,
    ra: vec3d,
    rb: vec3d,
    ima: f64,
    imb: f64,
    ia: mat33d,
    ib: mat33d,
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
):
    """A contact's impulse p on body b at arm rb, and -p on body a at arm ra."""
    apply_impulse(b, p, rb, imb, ib, body_v, body_w)
    apply_impulse(a, -p, ra, ima, ia, body_v, body_w)


@wp.kernel
def contact_keys(
    # Model:
    gravity: wp.vec3d,
    # Data in: the prediction
    pred_x: wp.array(dtype=vec3d),
    pred_q: wp.array(dtype=quatd),
    contact_count: wp.array(dtype=int),
    contact_body: wp.array(dtype=wp.vec2i),
    contact_anchor_b: wp.array(dtype=vec3d),
    # Data out: the sort's keys and values (2 x the contacts each)
    contact_key_out: wp.array(dtype=wp.float32),
    contact_order_out: wp.array(dtype=int),
):
    """Each contact's height against gravity (its point on b), to sweep the contacts from the bottom up (and back):
    a stack's or a pile's support then travels its height in one sweep."""
    k = wp.tid()
    key = wp.float32(0.0)
    if k < wp.min(contact_count[0], contact_body.shape[0]):
        up = -gravity
        if wp.length(up) > f64(0.0):
            up = wp.normalize(up)
        else:
            up = vec3d(f64(0.0), f64(0.0), f64(1.0))
        key = wp.float32(wp.dot(up, to_world(contact_body[k][1], contact_anchor_b[k], pred_x, pred_q)))
    contact_key_out[k] = key
    contact_order_out[k] = k


# ------------------------------------------------------------------------------------------ warm start
@wp.func
def pair_key(body: wp.vec2i, body_count: int) -> int:
    """A contact's pair of bodies as one sortable key (a is -1 for a ground plane)."""
    return (body[0] + 1) * (body_count + 1) + body[1]


@wp.kernel
def keep_contacts(
    # Model:
    body_count: int,
    # Data in: the step's contacts, solved
    contact_count: wp.array(dtype=int),
    contact_body: wp.array(dtype=wp.vec2i),
    contact_anchor_b: wp.array(dtype=vec3d),
    contact_normal: wp.array(dtype=vec3d),
    contact_impulse: wp.array(dtype=vec3d),
    contact_velocity_impulse: wp.array(dtype=vec3d),
    # Data out: the same, kept for the next step's match, and the sort's keys and values
    kept_body_out: wp.array(dtype=wp.vec2i),
    kept_anchor_b_out: wp.array(dtype=vec3d),
    kept_normal_out: wp.array(dtype=vec3d),
    kept_impulse_out: wp.array(dtype=vec3d),
    kept_velocity_impulse_out: wp.array(dtype=vec3d),
    kept_key_out: wp.array(dtype=int),
    kept_order_out: wp.array(dtype=int),
):
    """A step's contacts and their impulses (both phases), to start the next step's from (`match_contacts`)."""
    k = wp.tid()
    key = int(2147483647)
    if k < wp.min(contact_count[0], contact_body.shape[0]):
        key = pair_key(contact_body[k], body_count)
        kept_body_out[k] = contact_body[k]
        kept_anchor_b_out[k] = contact_anchor_b[k]
        kept_normal_out[k] = contact_normal[k]
        kept_impulse_out[k] = contact_impulse[k]
        kept_velocity_impulse_out[k] = contact_velocity_impulse[k]
    kept_key_out[k] = key
    kept_order_out[k] = k


@wp.func
def carried(old: vec3d, n_old: vec3d, n: vec3d, scale: f64, mu: f64) -> vec3d:
    """A kept impulse (normal, two tangents about n_old) for a contact of normal n: the normal part scaled by
    the ratio of the step sizes, the friction turned onto n's tangents and kept inside the cone."""
    t1 = collide.any_perpendicular(n_old)
    p = t1 * old[1] + wp.cross(n_old, t1) * old[2]
    ln = wp.max(old[0], f64(0.0)) * scale
    s1 = collide.any_perpendicular(n)
    lt = vec2d(wp.dot(p, s1), wp.dot(p, wp.cross(n, s1))) * scale
    size = wp.length(lt)
    if size > mu * ln:
        lt = lt * (mu * ln / size)
    return vec3d(ln, lt[0], lt[1])


@wp.kernel
def match_contacts(
    # Model:
    body_count: int,
    distance: f64,
    scale: f64,
    kept_count: int,
    # Data in: this step's contacts and the last step's, sorted by pair
    contact_count: wp.array(dtype=int),
    contact_body: wp.array(dtype=wp.vec2i),
    contact_anchor_b: wp.array(dtype=vec3d),
    contact_normal: wp.array(dtype=vec3d),
    contact_material: wp.array(dtype=wp.vec2d),
    kept_body: wp.array(dtype=wp.vec2i),
    kept_anchor_b: wp.array(dtype=vec3d),
    kept_normal: wp.array(dtype=vec3d),
    kept_impulse: wp.array(dtype=vec3d),
    kept_velocity_impulse: wp.array(dtype=vec3d),
    kept_key: wp.array(dtype=int),
    kept_order: wp.array(dtype=int),
    # Data out: each contact's match (-1: none) and the impulses its phases start from
    contact_match_out: wp.array(dtype=int),
    contact_warm_out: wp.array(dtype=vec3d),
    contact_warm_velocity_out: wp.array(dtype=vec3d),
):
    """The last step's contact that this one continues: the same bodies, a normal within 18 degrees, and the
    nearest anchor on b within `distance` (m, in b's frame). Its impulses, carried (`carried`), start this
    contact's position and velocity phases: a resting pile then needs few sweeps."""
    k = wp.tid()
    if k >= wp.min(contact_count[0], contact_body.shape[0]):
        return
    key = pair_key(contact_body[k], body_count)
    lo = int(0)
    hi = kept_count
    while lo < hi:  # the first kept contact of the pair
        mid = (lo + hi) // 2
        if kept_key[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    n = contact_normal[k]
    best = int(-1)
    nearest = distance
    while lo < kept_count and kept_key[lo] == key:
        j = kept_order[lo]
        d = wp.length(kept_anchor_b[j] - contact_anchor_b[k])
        if wp.dot(kept_normal[j], n) > f64(0.95) and d <= nearest:
            best = j
            nearest = d
        lo += 1
    contact_match_out[k] = best
    if best < 0:
        contact_warm_out[k] = vec3d()
        contact_warm_velocity_out[k] = vec3d()
        return
    mu = contact_material[k][0]
    contact_warm_out[k] = carried(kept_impulse[best], kept_normal[best], n, scale, mu)
    contact_warm_velocity_out[k] = carried(kept_velocity_impulse[best], kept_normal[best], n, scale, mu)


@wp.kernel
def warm_positions(
    # Model:
    body_inv_mass: wp.array(dtype=f64),
    # Data in:
    inv_inertia_world_in: wp.array(dtype=sym33d),
    contact_count: wp.array(dtype=int),
    contact_body: wp.array(dtype=wp.vec2i),
    contact_normal: wp.array(dtype=vec3d),
    contact_arm_a: wp.array(dtype=vec3d),
    contact_arm_b: wp.array(dtype=vec3d),
    contact_row: wp.array(dtype=int),
    contact_warm: wp.array(dtype=vec3d),
    # Data out (updated in place): the velocities at t0 and the position phase's impulses
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
    contact_impulse_out: wp.array(dtype=vec3d),
):
    """The position phase's first iterate: each matched contact's carried impulse, applied at t0 (one thread:
    contacts share bodies). The sweeps that follow take back what is too much: they solve the same problem
    from here, to the same tolerance (`measure`'s linearisation counts these impulses)."""
    count = wp.min(contact_count[0], contact_body.shape[0])
    for k in range(count):
        if contact_row[k] >= 0:
            continue
        a = contact_body[k][0]
        b = contact_body[k][1]
        n = contact_normal[k]
        lam = contact_warm[k]
        contact_impulse_out[k] = lam
        ima, imb, ia, ib = pair_inverses(a, b, body_inv_mass, inv_inertia_world_in)
        apply_pair(a, b, impulse_vector(n, lam), contact_arm_a[k], contact_arm_b[k], ima, imb, ia, ib, body_v_out,
                   body_w_out)  # fmt: skip


@wp.func
def sweep_index(i: int, count: int, sweep: int) -> int:
    """The i-th contact of a sweep: odd sweeps run backwards (symmetric Gauss-Seidel: a stack's support travels
    both ways)."""
    if sweep % 2 == 1:
        return count - 1 - i
    return i


@wp.func
def response(d: vec3d, e: vec3d, ra: vec3d, rb: vec3d, ima: f64, imb: f64, ia: mat33d, ib: mat33d) -> f64:
    """e . K d: the relative point velocity along e from a unit impulse along d (K: the contact's mass matrix)."""
    ad = wp.cross(ra, d)
    bd = wp.cross(rb, d)
    return (ima + imb) * wp.dot(d, e) + wp.dot(wp.cross(ia * ad, ra), e) + wp.dot(wp.cross(ib * bd, rb), e)


@wp.func
def relative_velocity(
    a: int, b: int, ra: vec3d, rb: vec3d, body_v: wp.array(dtype=vec3d), body_w: wp.array(dtype=vec3d)
) -> vec3d:
    u = vec3d()
    if b >= 0:
        u = body_v[b] + wp.cross(body_w[b], rb)
    if a >= 0:
        u = u - body_v[a] - wp.cross(body_w[a], ra)
    return u


@wp.func
def contact_masses(
    a: int,
    b: int,
    n: vec3d,
    ra: vec3d,
    rb: vec3d,
    body_inv_mass: wp.array(dtype=f64),
    inv_inertia_world: wp.array(dtype=sym33d),
) -> wp.vec2d:
    """(n . K n, the largest eigenvalue of K on the tangent plane): the relative point velocity from a unit
    impulse along the normal, and the most from a unit tangential one (K: the contact's mass matrix). Fixed
    while a solve sweeps, so computed once per solve."""
    ima, imb, ia, ib = pair_inverses(a, b, body_inv_mass, inv_inertia_world)
    t1 = collide.any_perpendicular(n)
    t2 = wp.cross(n, t1)
    k11 = response(t1, t1, ra, rb, ima, imb, ia, ib)
    k12 = response(t1, t2, ra, rb, ima, imb, ia, ib)
    k22 = response(t2, t2, ra, rb, ima, imb, ia, ib)
    half = f64(0.5) * (k11 - k22)
    return wp.vec2d(response(n, n, ra, rb, ima, imb, ia, ib), f64(0.5) * (k11 + k22) + wp.sqrt(half * half + k12 * k12))


@wp.func
def friction_step(
    slip: vec3d,
    n: vec3d,
    kt: f64,
    limit: f64,
    old: vec2d,
    a: int,
    b: int,
    ra: vec3d,
    rb: vec3d,
    ima: f64,
    imb: f64,
    ia: mat33d,
    ib: mat33d,
    body_v: wp.array(dtype=vec3d),
    body_w: wp.array(dtype=vec3d),
) -> vec2d:
    """The contact's total tangential impulse after one projected step against `slip` (a relative velocity):
    the step uses kt, the largest eigenvalue of the contact's tangential mass matrix, so it never overshoots,
    and the total is projected onto the cone's disc of radius `limit`. A contact sticks where the disc holds
    the impulse that stops the slip; else it slides at `limit`, and at convergence against the slip (the
    projection keeps the direction). The change is applied and the new total returned."""
    t1 = collide.any_perpendicular(n)
    t2 = wp.cross(n, t1)
    new = old
    if kt > f64(0.0):
        new = old - vec2d(wp.dot(t1, slip), wp.dot(t2, slip)) / kt
    size = wp.length(new)
    if size > limit:
        new = new * (limit / size)
    d = new - old
    p = t1 * d[0] + t2 * d[1]
    apply_pair(a, b, p, ra, rb, ima, imb, ia, ib, body_v, body_w)
    return new


@wp.kernel
def measure(
    # Model:
    inv_h: f64,
    body_inv_mass: wp.array(dtype=f64),
    # Data in: the state at t0 (velocities as corrected so far) and the prediction
    inv_inertia_world_in: wp.array(dtype=sym33d),
    body_x_in: wp.array(dtype=vec3d),
    body_v_in: wp.array(dtype=vec3d),
    body_w_in: wp.array(dtype=vec3d),
    pred_x: wp.array(dtype=vec3d),
    pred_q: wp.array(dtype=quatd),
    pred_w: wp.array(dtype=vec3d),
    contact_count: wp.array(dtype=int),
    contact_body: wp.array(dtype=wp.vec2i),
    contact_anchor_a: wp.array(dtype=vec3d),
    contact_anchor_b: wp.array(dtype=vec3d),
    contact_radius: wp.array(dtype=wp.vec2d),
    contact_normal: wp.array(dtype=vec3d),
    # Data out:
    contact_gap_out: wp.array(dtype=f64),
    contact_arm_a_out: wp.array(dtype=vec3d),
    contact_arm_b_out: wp.array(dtype=vec3d),
    contact_slip_out: wp.array(dtype=vec3d),
    contact_u0_out: wp.array(dtype=vec3d),
    contact_mass_out: wp.array(dtype=wp.vec2d),
    contact_error_out: wp.array(dtype=f64),
):
    """On the current prediction: each contact's gap, its lever arms, its slip over the step (the relative
    velocity of the contact point from the bodies' mean motion: centre displacement / h and mean angular
    velocity), and its relative point velocity at t0 (the linearisation point of the sweeps).
    contact_error[0] = the deepest penetration."""
    k = wp.tid()
    if k >= wp.min(contact_count[0], contact_body.shape[0]):
        return
    a = contact_body[k][0]
    b = contact_body[k][1]
    n = contact_normal[k]
    pa, pb = surface_points(a, b, contact_anchor_a[k], contact_anchor_b[k], contact_radius[k], n, pred_x, pred_q)
    g = wp.dot(n, pb - pa)
    contact_gap_out[k] = g
    wp.atomic_max(contact_error_out, 0, -g)
    ra = vec3d()
    rb = vec3d()
    mean = vec3d()
    if a >= 0:
        ra = pa - pred_x[a]
        mean = mean - (pred_x[a] - body_x_in[a]) * inv_h - wp.cross((body_w_in[a] + pred_w[a]) * f64(0.5), ra)
    if b >= 0:
        rb = pb - pred_x[b]
        mean = mean + (pred_x[b] - body_x_in[b]) * inv_h + wp.cross((body_w_in[b] + pred_w[b]) * f64(0.5), rb)
    contact_arm_a_out[k] = ra
    contact_arm_b_out[k] = rb
    contact_slip_out[k] = mean - n * wp.dot(n, mean)
    contact_u0_out[k] = relative_velocity(a, b, ra, rb, body_v_in, body_w_in)
    contact_mass_out[k] = contact_masses(a, b, n, ra, rb, body_inv_mass, inv_inertia_world_in)


@wp.kernel
def solve_positions(
    # Model:
    body_inv_mass: wp.array(dtype=f64),
    h: f64,
    sweeps: int,
    tolerance: f64,
    slop: f64,
    parity: int,
    # Data in:
    inv_inertia_world_in: wp.array(dtype=sym33d),
    contact_count: wp.array(dtype=int),
    contact_body: wp.array(dtype=wp.vec2i),
    contact_normal: wp.array(dtype=vec3d),
    contact_material: wp.array(dtype=wp.vec2d),
    contact_gap: wp.array(dtype=f64),
    contact_arm_a: wp.array(dtype=vec3d),
    contact_arm_b: wp.array(dtype=vec3d),
    contact_slip: wp.array(dtype=vec3d),
    contact_u0: wp.array(dtype=vec3d),
    contact_mass: wp.array(dtype=wp.vec2d),
    contact_row: wp.array(dtype=int),
    contact_order: wp.array(dtype=int),
    # Data out (updated in place): the velocities at t0 and the impulses of this step's position phase
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
    contact_impulse_out: wp.array(dtype=vec3d),
    contact_error_out: wp.array(dtype=f64),
):
    """Up to `sweeps` projected Gauss-Seidel sweeps of the linearised position phase (module docstring), until
    no impulse changes a gap or a slip by more than `tolerance` (m). A pushing contact is closed to `slop` (m)
    of penetration, not to touching: the loop runs when a contact is deeper than the step's tolerance, and
    closing every contact to 0 then kicked a resting pile apart (docs/contacts.md, "Coming to rest").
    contact_error[1] = the sweeps taken. The first sweep runs up the contacts' order (`contact_keys`) for
    `parity` 0, down for 1: the caller alternates it, so that one sweep a call ("paper") is symmetric too.
    Contacts with rows (`contact_row` >= 0) are solved with the joints (`contact_rows.py`) and skipped here."""
    count = wp.min(contact_count[0], contact_body.shape[0])
    taken = int(0)
    for sweep in range(sweeps):
        taken += 1
        change = f64(0.0)
        for i in range(count):
            k = contact_order[sweep_index(i, count, sweep + parity)]
            if contact_row[k] >= 0:
                continue
            a = contact_body[k][0]
            b = contact_body[k][1]
            n = contact_normal[k]
            ra = contact_arm_a[k]
            rb = contact_arm_b[k]
            ima, imb, ia, ib = pair_inverses(a, b, body_inv_mass, inv_inertia_world_in)
            lam = contact_impulse_out[k]
            du = relative_velocity(a, b, ra, rb, body_v_out, body_w_out) - contact_u0[k]
            gap = contact_gap[k] + h * wp.dot(n, du) + slop
            kn = contact_mass[k][0]
            ln = wp.max(lam[0] - gap / (h * kn), f64(0.0))
            dn = ln - lam[0]
            change = wp.max(change, wp.abs(dn) * h * kn)
            apply_pair(a, b, n * dn, ra, rb, ima, imb, ia, ib, body_v_out, body_w_out)
            du = relative_velocity(a, b, ra, rb, body_v_out, body_w_out) - contact_u0[k]
            slip = contact_slip[k] + du
            slip = slip - n * wp.dot(n, slip)
            old = vec2d(lam[1], lam[2])
            lt = friction_step(slip, n, contact_mass[k][1], contact_material[k][0] * ln, old, a, b, ra, rb, ima, imb,
                               ia, ib, body_v_out, body_w_out)  # fmt: skip
            change = wp.max(change, wp.length(lt - old) * (ima + imb) * h)
            contact_impulse_out[k] = vec3d(ln, lt[0], lt[1])
        if change <= tolerance:
            break
    contact_error_out[1] = f64(taken)


@wp.kernel
def solve_velocities(
    # Model:
    body_inv_mass: wp.array(dtype=f64),
    sweeps: int,
    tolerance: f64,
    bounce_speed: f64,
    inv_h: f64,
    first: int,
    take_back: f64,
    # Data in:
    body_x_in: wp.array(dtype=vec3d),
    body_q_in: wp.array(dtype=quatd),
    inv_inertia_world_in: wp.array(dtype=sym33d),
    contact_count: wp.array(dtype=int),
    contact_body: wp.array(dtype=wp.vec2i),
    contact_anchor_a: wp.array(dtype=vec3d),
    contact_anchor_b: wp.array(dtype=vec3d),
    contact_radius: wp.array(dtype=wp.vec2d),
    contact_normal: wp.array(dtype=vec3d),
    contact_material: wp.array(dtype=wp.vec2d),
    contact_impact: wp.array(dtype=f64),
    contact_impulse: wp.array(dtype=vec3d),
    contact_match: wp.array(dtype=int),
    contact_warm_velocity: wp.array(dtype=vec3d),
    contact_row: wp.array(dtype=int),
    contact_order: wp.array(dtype=int),
    # Data out (updated in place):
    body_v_out: wp.array(dtype=vec3d),
    body_w_out: wp.array(dtype=vec3d),
    contact_gap_out: wp.array(dtype=f64),
    contact_arm_a_out: wp.array(dtype=vec3d),
    contact_arm_b_out: wp.array(dtype=vec3d),
    contact_velocity_impulse_out: wp.array(dtype=vec3d),
    contact_mass_out: wp.array(dtype=wp.vec2d),
    contact_approach_out: wp.array(dtype=f64),
    contact_error_out: wp.array(dtype=f64),
):
    """The velocity phase at t0+h (module docstring). A contact apart by g > 0 may approach at up to g / h (it
    closes in the next step, not further), unless it approaches faster than `bounce_speed`: then it is an
    impact of the next step, whose prediction finds it with its impact speed, and this phase leaves it alone
    (clamped here, a ball would land at g / h and not bounce). The `first` solve of a step starts from the
    position phase's impulses (applied here; the sweeps take back what is too much), later ones (alternating
    with the joints) from where the last stopped. Sweeps until no impulse changes a velocity by more than
    `tolerance` (m/s). `take_back` 1: a contact's impulse here may go down to minus its position phase's, so
    that its total over the step pushes (0: this phase's alone pushes, the speed a position correction left is
    kept). contact_error[2] = the sweeps taken. Contacts with rows (`contact_row` >= 0) are left to
    `contact_rows.solve_rows`: here they only get their gaps, arms and approach speeds."""
    count = wp.min(contact_count[0], contact_body.shape[0])
    k = wp.int32(0)
    while k < count:
        a = contact_body[k][0]
        b = contact_body[k][1]
        pa, pb = surface_points(a, b, contact_anchor_a[k], contact_anchor_b[k], contact_radius[k], contact_normal[k],
                                body_x_in, body_q_in)  # fmt: skip
        contact_gap_out[k] = wp.dot(contact_normal[k], pb - pa)
        ra = vec3d()
        rb = vec3d()
        if a >= 0:
            ra = pa - body_x_in[a]
        if b >= 0:
            rb = pb - body_x_in[b]
        contact_arm_a_out[k] = ra
        contact_arm_b_out[k] = rb
        contact_mass_out[k] = contact_masses(a, b, contact_normal[k], ra, rb, body_inv_mass, inv_inertia_world_in)
        if first != 0 and contact_row[k] >= 0:
            contact_velocity_impulse_out[k] = vec3d()  # solved with the joints (`contact_rows.py`), from 0
        elif first != 0:
            # Start from the last step's impulses where the contact goes on (`match_contacts`), else from the
            # position phase's: a resting contact takes the same in both phases.
            lam = contact_impulse[k]
            if contact_match[k] >= 0:
                lam = contact_warm_velocity[k]
            contact_velocity_impulse_out[k] = lam
            ima, imb, ia, ib = pair_inverses(a, b, body_inv_mass, inv_inertia_world_in)
            apply_pair(a, b, impulse_vector(contact_normal[k], lam), ra, rb, ima, imb, ia, ib, body_v_out, body_w_out)
        k += 1
    if first != 0:  # the approach speeds once the position phase's impulses are all applied
        k = wp.int32(0)
        while k < count:
            u = relative_velocity(contact_body[k][0], contact_body[k][1], contact_arm_a_out[k], contact_arm_b_out[k],
                                  body_v_out, body_w_out)  # fmt: skip
            contact_approach_out[k] = -wp.dot(contact_normal[k], u)
            k += 1
    taken = int(0)
    for sweep in range(sweeps):
        taken += 1
        change = f64(0.0)
        for i in range(count):
            k = contact_order[sweep_index(i, count, sweep)]
            if contact_row[k] >= 0:
                continue
            a = contact_body[k][0]
            b = contact_body[k][1]
            n = contact_normal[k]
            ra = contact_arm_a_out[k]
            rb = contact_arm_b_out[k]
            ima, imb, ia, ib = pair_inverses(a, b, body_inv_mass, inv_inertia_world_in)
            lam = contact_velocity_impulse_out[k]
            # Apart by g > 0: may close it over the next step, not more (a speculative contact), unless it is an
            # impact of the next step.
            gap = contact_gap_out[k]
            target = -wp.max(gap, f64(0.0)) * inv_h
            if contact_impact[k] > bounce_speed:
                target = contact_material[k][1] * contact_impact[k]
            elif gap > f64(0.0) and contact_approach_out[k] > bounce_speed:
                target = f64(-1e300)
            u = relative_velocity(a, b, ra, rb, body_v_out, body_w_out)
            kn = contact_mass_out[k][0]
            # Push-only over the step: this phase may take back what the position phase pushed (its push
            # closed a gap; the speed it left would carry the bodies apart, a pile's jitter at a coarse tolerance).
            ln = wp.max(lam[0] + (target - wp.dot(n, u)) / kn, -take_back * contact_impulse[k][0])
            dn = ln - lam[0]
            change = wp.max(change, wp.abs(dn) * kn)
            apply_pair(a, b, n * dn, ra, rb, ima, imb, ia, ib, body_v_out, body_w_out)
            u = relative_velocity(a, b, ra, rb, body_v_out, body_w_out)
            slip = u - n * wp.dot(n, u)
            old = vec2d(lam[1], lam[2])
            limit = contact_material[k][0] * wp.max(ln, f64(0.0))
            lt = friction_step(slip, n, contact_mass_out[k][1], limit, old, a, b, ra, rb, ima, imb, ia, ib, body_v_out,
                               body_w_out)  # fmt: skip
            change = wp.max(change, wp.length(lt - old) * (ima + imb))
            contact_velocity_impulse_out[k] = vec3d(ln, lt[0], lt[1])
        if change <= tolerance:
            break
    contact_error_out[2] = f64(taken)
