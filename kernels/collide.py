"""Collision detection on the predicted state: broad phase (a BVH of swept boxes), narrow phase per shape pair.

Conventions. A contact is between body a (or a ground plane, a = -1) and body b. Its normal n (world, unit)
points from a to b; its gap g = n . (p_b - p_a) is the signed distance of the two surface points (m), negative
when they overlap. A narrow-phase function returns a manifold: a count, one normal for the pair, and for each
point the world point p_b on b's surface and the gap; p_a = p_b - g n. Up to MAX_POINTS points (a box on a
plane or on a box rests on four). Shapes sit at the body's centre of mass, their axis along local z; sizes are
`Shape.collision_size()`: (radius, half length) or the box's half edges.

A cylinder meets a plane as a cylinder (its rims); against other shapes it is taken as the capsule of the
same radius and length (the narrow phase has no cylinder-box or cylinder-cylinder function).
"""

import warp as wp

from ..shapes import SHAPE_CODES

wp.set_module_options({"enable_backward": False})

vec3d = wp.vec3d
quatd = wp.quatd
mat33d = wp.mat33d
f64 = wp.float64

SPHERE = wp.constant(SHAPE_CODES["sphere"])
CAPSULE = wp.constant(SHAPE_CODES["capsule"])
BOX = wp.constant(SHAPE_CODES["box"])
CYLINDER = wp.constant(SHAPE_CODES["cylinder"])
MAX_POINTS = 8
mat83d = wp.types.matrix(shape=(MAX_POINTS, 3), dtype=f64)
vec8d = wp.types.vector(MAX_POINTS, f64)


# ------------------------------------------------------------------------------------------ helpers
@wp.func
def add_point(count: int, points: mat83d, gaps: vec8d, p: vec3d, g: f64, margin: f64):
    """Append (p, g) to a manifold when the gap is below the margin and there is room."""
    if g < margin and count < MAX_POINTS:
        points[count] = p
        gaps[count] = g
        count += 1
    return count, points, gaps


@wp.func
def any_perpendicular(a: vec3d) -> vec3d:
    t = vec3d(f64(1.0), f64(0.0), f64(0.0))
    if wp.abs(a[0]) > f64(0.7):
        t = vec3d(f64(0.0), f64(1.0), f64(0.0))
    return wp.normalize(wp.cross(a, t))


@wp.func
def closest_on_segment(p: vec3d, a: vec3d, d: vec3d) -> vec3d:
    """The point of the segment a + s d, s in [0, 1], closest to p."""
    dd = wp.dot(d, d)
    s = f64(0.0)
    if dd > f64(0.0):
        s = wp.clamp(wp.dot(p - a, d) / dd, f64(0.0), f64(1.0))
    return a + d * s


@wp.func
def closest_segments(a: vec3d, d1: vec3d, b: vec3d, d2: vec3d):
    """Closest points of the segments a + s d1 and b + t d2 (s, t in [0, 1]) (Ericson, 5.1.9)."""
    r = a - b
    aa = wp.dot(d1, d1)
    ee = wp.dot(d2, d2)
    f = wp.dot(d2, r)
    c = wp.dot(d1, r)
    bb = wp.dot(d1, d2)
    den = aa * ee - bb * bb
    s = f64(0.0)
    if den > f64(1e-12) * aa * ee:
        s = wp.clamp((bb * f - c * ee) / den, f64(0.0), f64(1.0))
    t = f64(0.0)
    if ee > f64(0.0):
        t = (bb * s + f) / ee
    if t < f64(0.0):
        t = f64(0.0)
        if aa > f64(0.0):
            s = wp.clamp(-c / aa, f64(0.0), f64(1.0))
    elif t > f64(1.0):
        t = f64(1.0)
        if aa > f64(0.0):
            s = wp.clamp((bb - c) / aa, f64(0.0), f64(1.0))
    return a + d1 * s, b + d2 * t


# ------------------------------------------------------------------------------------------ narrow phase
@wp.func
def sphere_sphere(ca: vec3d, ra: f64, cb: vec3d, rb: f64, margin: f64):
    """Two spheres (also the closest points of capsule axes); the normal defaults to +z when they coincide."""
    points = mat83d()
    gaps = vec8d()
    d = cb - ca
    dist = wp.length(d)
    n = vec3d(f64(0.0), f64(0.0), f64(1.0))
    if dist > f64(1e-12):
        n = d / dist
    count, points, gaps = add_point(0, points, gaps, cb - n * rb, dist - ra - rb, margin)
    return count, n, points, gaps


@wp.func
def plane_sphere(n: vec3d, offset: f64, c: vec3d, r: f64, margin: f64):
    points = mat83d()
    gaps = vec8d()
    count, points, gaps = add_point(0, points, gaps, c - n * r, wp.dot(n, c) - offset - r, margin)
    return count, n, points, gaps


@wp.func
def plane_capsule(n: vec3d, offset: f64, c: vec3d, axis: vec3d, r: f64, half: f64, margin: f64):
    """The two cap centres as spheres: a capsule lying on the plane rests on two points."""
    points = mat83d()
    gaps = vec8d()
    count = int(0)
    for k in range(2):
        e = c + axis * (half * f64(2 * k - 1))
        count, points, gaps = add_point(count, points, gaps, e - n * r, wp.dot(n, e) - offset - r, margin)
    return count, n, points, gaps


@wp.func
def plane_box(n: vec3d, offset: f64, c: vec3d, rot: mat33d, half: vec3d, margin: f64):
    """The box's corners below the margin (four when it lies flat)."""
    points = mat83d()
    gaps = vec8d()
    count = int(0)
    for k in range(8):
        local = vec3d(
            half[0] * f64(2 * (k & 1) - 1), half[1] * f64(2 * ((k >> 1) & 1) - 1), half[2] * f64(2 * ((k >> 2) & 1) - 1)
        )
        p = c + rot * local
        count, points, gaps = add_point(count, points, gaps, p, wp.dot(n, p) - offset, margin)
    return count, n, points, gaps


@wp.func
def plane_cylinder(n: vec3d, offset: f64, c: vec3d, axis: vec3d, r: f64, half: f64, margin: f64):
    """Rim points of both caps: the lowest point of each rim (a wheel touches on a line), and three more at
    quarter turns from it (a cylinder standing on a cap rests on four)."""
    points = mat83d()
    gaps = vec8d()
    radial = n - axis * wp.dot(n, axis)
    if wp.length(radial) > f64(1e-9):
        radial = -wp.normalize(radial)  # the rim direction furthest down the normal
    else:
        radial = any_perpendicular(axis)
    side = wp.cross(axis, radial)
    count = int(0)
    for cap in range(2):
        e = c + axis * (half * f64(2 * cap - 1))
        for k in range(4):
            d = radial
            if k == 1:
                d = side
            elif k == 2:
                d = -side
            elif k == 3:
                d = -radial
            p = e + d * r
            count, points, gaps = add_point(count, points, gaps, p, wp.dot(n, p) - offset, margin)
    return count, n, points, gaps


@wp.func
def capsule_sphere(c: vec3d, axis: vec3d, r: f64, half: f64, cb: vec3d, rb: f64, margin: f64):
    e = c - axis * half
    q = closest_on_segment(cb, e, axis * (f64(2.0) * half))
    return sphere_sphere(q, r, cb, rb, margin)


@wp.func
def capsule_capsule(ca: vec3d, axa: vec3d, ra: f64, ha: f64, cb: vec3d, axb: vec3d, rb: f64, hb: f64, margin: f64):
    """The closest points of the two axes; nearly parallel axes give two points, at the ends of the overlap, so
    capsules lying side by side do not roll about their contact."""
    a0 = ca - axa * ha
    da = axa * (f64(2.0) * ha)
    b0 = cb - axb * hb
    db = axb * (f64(2.0) * hb)
    pa, pb = closest_segments(a0, da, b0, db)
    count, n, points, gaps = sphere_sphere(pa, ra, pb, rb, margin)
    if wp.length_sq(wp.cross(axa, axb)) < f64(1e-6) and ha > f64(0.0) and hb > f64(0.0):
        # Overlap of b's segment projected on a's axis, as parameters along a.
        s0 = wp.dot(b0 - a0, da) / wp.dot(da, da)
        s1 = wp.dot(b0 + db - a0, da) / wp.dot(da, da)
        lo = wp.clamp(wp.min(s0, s1), f64(0.0), f64(1.0))
        hi = wp.clamp(wp.max(s0, s1), f64(0.0), f64(1.0))
        if hi - lo > f64(1e-6):
            count = int(0)
            for k in range(2):
                s = lo
                if k == 1:
                    s = hi
                p = a0 + da * s
                q = closest_on_segment(p, b0, db)
                d = q - p
                dist = wp.length(d)
                if dist > f64(1e-12):
                    n = d / dist
                count, points, gaps = add_point(count, points, gaps, q - n * rb, dist - ra - rb, margin)
    return count, n, points, gaps


@wp.func
def box_sphere(c: vec3d, rot: mat33d, half: vec3d, cb: vec3d, rb: f64, cb0_local: vec3d, margin: f64):
    """A box and a sphere; `cb0_local` is the sphere's centre at the start of the step in the box's frame: a
    sphere that moved further than its radius is swept against the box, so a fast one cannot tunnel through a
    thin box (it is stopped at the face it entered by)."""
    points = mat83d()
    gaps = vec8d()
    p = wp.transpose(rot) * (cb - c)
    q = vec3d(wp.clamp(p[0], -half[0], half[0]), wp.clamp(p[1], -half[1], half[1]), wp.clamp(p[2], -half[2], half[2]))
    d = p - q
    dist = wp.length(d)
    n_local = vec3d()
    g = f64(0.0)
    if dist > f64(1e-12):
        n_local = d / dist
        g = dist - rb
    else:  # the centre is inside: out through the nearest face
        best = f64(1e300)
        for i in range(3):
            for s in range(2):
                sign = f64(2 * s - 1)
                depth = half[i] - sign * p[i]
                if depth < best:
                    best = depth
                    n_local = vec3d()
                    n_local[i] = sign
        g = -best - rb
    # Swept: the segment from the start centre to the predicted one against the box grown by the radius.
    motion = p - cb0_local
    if wp.length(motion) > rb:
        t_enter = f64(-1e300)
        t_exit = f64(1e300)
        face = vec3d()
        for i in range(3):
            ext = half[i] + rb
            if wp.abs(motion[i]) < f64(1e-15):
                if wp.abs(cb0_local[i]) > ext:
                    t_exit = f64(-1.0)
            else:
                t1 = (-ext - cb0_local[i]) / motion[i]
                t2 = (ext - cb0_local[i]) / motion[i]
                sign = f64(-1.0)
                if t1 > t2:
                    t1, t2 = t2, t1
                    sign = f64(1.0)
                if t1 > t_enter:
                    t_enter = t1
                    face = vec3d()
                    face[i] = sign
                t_exit = wp.min(t_exit, t2)
        if t_enter >= f64(0.0) and t_enter <= f64(1.0) and t_enter <= t_exit:
            n_local = face
            k = int(0)
            for i in range(3):
                if face[i] != f64(0.0):
                    k = i
            g = wp.dot(face, p) - half[k] - rb
    n = rot * n_local
    count, points, gaps = add_point(0, points, gaps, cb - n * rb, g, margin)
    return count, n, points, gaps


@wp.func
def box_capsule(c: vec3d, rot: mat33d, half: vec3d, cb: vec3d, axis: vec3d, rb: f64, hb: f64, margin: f64):
    """The capsule's two cap centres and its middle as spheres against the box: up to three points, each with
    its own normal folded into one (the deepest point's)."""
    points = mat83d()
    gaps = vec8d()
    count = int(0)
    n = vec3d()
    best = f64(1e300)
    for k in range(3):
        e = cb + axis * (hb * f64(k - 1))
        m, nk, pk, gk = box_sphere(c, rot, half, e, rb, wp.transpose(rot) * (e - c), margin)
        if m > 0:
            if gk[0] < best:
                best = gk[0]
                n = nk
            count, points, gaps = add_point(count, points, gaps, pk[0], gk[0], margin)
    return count, n, points, gaps


@wp.func
def box_corner(rot: mat33d, half: vec3d, signs: vec3d) -> vec3d:
    return rot * vec3d(half[0] * signs[0], half[1] * signs[1], half[2] * signs[2])


@wp.func
def projected_radius(rot: mat33d, half: vec3d, axis: vec3d) -> f64:
    return (
        half[0] * wp.abs(wp.dot(axis, wp.vec3d(rot[0, 0], rot[1, 0], rot[2, 0])))
        + half[1] * wp.abs(wp.dot(axis, wp.vec3d(rot[0, 1], rot[1, 1], rot[2, 1])))
        + half[2] * wp.abs(wp.dot(axis, wp.vec3d(rot[0, 2], rot[1, 2], rot[2, 2])))
    )


@wp.func
def column(m: mat33d, i: int) -> vec3d:
    return vec3d(m[0, i], m[1, i], m[2, i])


@wp.func
def clip(poly: mat83d, count: int, normal: vec3d, offset: f64):
    """Sutherland-Hodgman: the part of the polygon with normal . x <= offset."""
    out = mat83d()
    m = int(0)
    for i in range(count):
        p = poly[i]
        q = poly[(i + 1) % count]
        dp = wp.dot(normal, p) - offset
        dq = wp.dot(normal, q) - offset
        if dp <= f64(0.0) and m < MAX_POINTS:
            out[m] = p
            m += 1
        if (dp < f64(0.0) and dq > f64(0.0)) or (dp > f64(0.0) and dq < f64(0.0)):
            if m < MAX_POINTS:
                out[m] = p + (q - p) * (dp / (dp - dq))
                m += 1
    return out, m


@wp.func
def face_contact(cr: vec3d, rr: mat33d, hr: vec3d, face: int, n: vec3d, ci: vec3d, ri: mat33d, hi: vec3d, margin: f64):
    """The reference box (cr, rr, hr) whose face `face` has outward normal n, the incident box (ci, ri, hi):
    the incident face clipped to the reference face's sides. Returns the points on the incident box and their
    gaps below the reference face, at most four (the extremes along the face's two directions)."""
    # The incident face: the face of the incident box most opposed to n.
    j = int(0)
    best = f64(-1.0)
    for k in range(3):
        dk = wp.abs(wp.dot(column(ri, k), n))
        if dk > best:
            best = dk
            j = k
    sj = f64(1.0)
    if wp.dot(column(ri, j), n) > f64(0.0):
        sj = f64(-1.0)
    u = (j + 1) % 3
    v = (j + 2) % 3
    centre = ci + column(ri, j) * (sj * hi[j])
    eu = column(ri, u) * hi[u]
    ev = column(ri, v) * hi[v]
    poly = mat83d()
    poly[0] = centre + eu + ev
    poly[1] = centre - eu + ev
    poly[2] = centre - eu - ev
    poly[3] = centre + eu - ev
    count = int(4)
    # Clip against the four side planes of the reference face.
    for k in range(3):
        if k != face:
            axis = column(rr, k)
            poly, count = clip(poly, count, axis, wp.dot(axis, cr) + hr[k])
            poly, count = clip(poly, count, -axis, -wp.dot(axis, cr) + hr[k])
    plane = wp.dot(n, cr) + hr[face]
    points = mat83d()
    gaps = vec8d()
    m = int(0)
    for i in range(count):
        m, points, gaps = add_point(m, points, gaps, poly[i], wp.dot(n, poly[i]) - plane, margin)
    if m <= 4:
        return m, points, gaps
    # Keep the extremes along the reference face's two in-plane directions.
    ta = column(rr, (face + 1) % 3)
    tb = column(rr, (face + 2) % 3)
    pick = wp.vec4i(0, 0, 0, 0)
    lo_a = f64(1e300)
    hi_a = f64(-1e300)
    lo_b = f64(1e300)
    hi_b = f64(-1e300)
    for i in range(m):
        a = wp.dot(ta, points[i])
        b = wp.dot(tb, points[i])
        if a < lo_a:
            lo_a = a
            pick[0] = i
        if a > hi_a:
            hi_a = a
            pick[1] = i
        if b < lo_b:
            lo_b = b
            pick[2] = i
        if b > hi_b:
            hi_b = b
            pick[3] = i
    kept = mat83d()
    kept_gaps = vec8d()
    k = int(0)
    for i in range(4):
        dup = False
        for l in range(i):
            if pick[l] == pick[i]:
                dup = True
        if not dup:
            kept[k] = points[pick[i]]
            kept_gaps[k] = gaps[pick[i]]
            k += 1
    return k, kept, kept_gaps


@wp.func
def box_box(ca: vec3d, ra: mat33d, ha: vec3d, cb: vec3d, rb: mat33d, hb: vec3d, margin: f64):
    """Separating axes (3 faces of each box, 9 edge pairs), then a face manifold by clipping, or the closest
    points of two edges. Face axes win over an edge axis unless it separates clearly more, so boxes at rest on
    boxes keep four points."""
    d = cb - ca
    best_face = f64(-1e300)
    face_axis = int(0)
    for k in range(6):
        axis = column(ra, k % 3)
        if k >= 3:
            axis = column(rb, k - 3)
        s = wp.abs(wp.dot(d, axis)) - projected_radius(ra, ha, axis) - projected_radius(rb, hb, axis)
        if s > best_face:
            best_face = s
            face_axis = k
    best_edge = f64(-1e300)
    edge_a = int(0)
    edge_b = int(0)
    edge_n = vec3d()
    for i in range(3):
        for j in range(3):
            axis = wp.cross(column(ra, i), column(rb, j))
            length = wp.length(axis)
            if length > f64(1e-6):
                axis = axis / length
                s = wp.abs(wp.dot(d, axis)) - projected_radius(ra, ha, axis) - projected_radius(rb, hb, axis)
                if s > best_edge:
                    best_edge = s
                    edge_a = i
                    edge_b = j
                    edge_n = axis
    points = mat83d()
    gaps = vec8d()
    n = vec3d(f64(0.0), f64(0.0), f64(1.0))
    if wp.max(best_face, best_edge) > margin:
        return int(0), n, points, gaps
    scale = wp.min(wp.min(ha[0], ha[1]), wp.min(wp.min(ha[2], hb[0]), wp.min(hb[1], hb[2])))
    if best_edge > best_face * f64(0.95) + f64(0.01) * scale:
        if wp.dot(edge_n, d) < f64(0.0):
            edge_n = -edge_n
        # The edge of a furthest along n and the edge of b furthest against it.
        sa = vec3d()
        sb = vec3d()
        for k in range(3):
            sa[k] = wp.sign(wp.dot(column(ra, k), edge_n))
            sb[k] = -wp.sign(wp.dot(column(rb, k), edge_n))
        sa[edge_a] = f64(0.0)
        sb[edge_b] = f64(0.0)
        ea = ca + box_corner(ra, ha, sa) - column(ra, edge_a) * ha[edge_a]
        eb = cb + box_corner(rb, hb, sb) - column(rb, edge_b) * hb[edge_b]
        pa, pb = closest_segments(
            ea, column(ra, edge_a) * (f64(2.0) * ha[edge_a]), eb, column(rb, edge_b) * (f64(2.0) * hb[edge_b])
        )
        count, points, gaps = add_point(0, points, gaps, pb, wp.dot(edge_n, pb - pa), margin)
        return count, edge_n, points, gaps
    if face_axis < 3:
        n = column(ra, face_axis)
        if wp.dot(n, d) < f64(0.0):
            n = -n
        count, pts, g = face_contact(ca, ra, ha, face_axis, n, cb, rb, hb, margin)
        return count, n, pts, g
    # Reference face on b, normal from b to a: the incident points lie on a.
    nb = column(rb, face_axis - 3)
    if wp.dot(nb, d) > f64(0.0):
        nb = -nb
    count, pts, g = face_contact(cb, rb, hb, face_axis - 3, nb, ca, ra, ha, margin)
    n = -nb
    for i in range(count):
        pts[i] = pts[i] + n * g[i]  # from the point on a to the point on b
    return count, n, pts, g
