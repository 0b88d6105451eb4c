"""What a model is, in two forms that failures and checkpoints use: its fingerprint, and the mass ratios
that double precision cannot resolve."""

from __future__ import annotations

import hashlib

import numpy as np

from .model import Model

FINGERPRINT_PARTS = {
    "bodies": "bodies",
    "constraints": "joints",
    "forces": "gravity and forces",
    "springs": "springs",
    "drives": "motors and joint springs",
    "rows": "joint limits, distance rows and stiff motors",
    "colliders": "colliders and grounds",
    "contact_settings": "contact settings",
}
"""The parts of a fingerprint, each with the words a refused checkpoint uses for it."""


def fingerprint(model: Model, contact_settings: dict | None = None) -> dict[str, str]:
    """Digests of what a checkpoint's state is only valid for, a `FINGERPRINT_PARTS` key each: the bodies'
    masses and inertias, the constraints (kinds, bodies, local anchors, axes and rest values: the topology and
    geometry), gravity with the model's forces, every force element (springs; motors and joint springs: their
    joints, modes, gains, limits of force, stiffness), every row of the correction loop (limits, distance rows,
    stiff motors: joints, bounds, anchors), the colliders (shapes, materials, grounds, filtered pairs) and the
    simulator's `contact_settings`. Each is "<count>:<SHA-256>", the count of what it covers first, so that a
    refusal can say how they differ. Initial poses and motor targets are not in it: a checkpoint replaces them."""

    def digest(count: int, *arrays) -> str:
        h = hashlib.sha256()
        for a in arrays:
            a = np.ascontiguousarray(a, dtype=np.float64)
            h.update(repr(a.shape).encode())
            h.update(a.tobytes())
        return f"{count}:{h.hexdigest()}"

    h, c = model.host, model.colliders
    shapes = () if c is None else (c.shape_kind, c.shape_size, c.bound, c.friction, c.restitution, c.filter_pairs)
    planes = () if c is None else (c.plane_normal, c.plane_offset, c.plane_friction, c.plane_restitution)
    settings = sorted((contact_settings or {}).items())
    return {
        "bodies": digest(model.body_count, h.body_mass, h.body_inertia, h.body_static),
        "constraints": digest(
            model.joint_count,
            h.constraint_kind,
            h.constraint_body0,
            h.constraint_body1,
            model.constraint_joint,
            h.constraint_anchor0,
            h.constraint_anchor1,
            h.constraint_axis0,
            h.constraint_axis1,
            h.constraint_rest_rotation,
            h.constraint_rest_angle,
        ),  # fmt: skip
        "forces": digest(len(h.force_body), h.gravity, h.force_body, h.force_force, h.force_torque, h.force_until),
        "springs": digest(
            model.spring_count, h.spring_body0, h.spring_body1, h.spring_anchor0, h.spring_anchor1, h.spring_params
        ),  # fmt: skip
        "drives": digest(
            model.drive_count,
            h.drive_joint,
            h.drive_mode,
            h.drive_gains,
            h.drive_max_force,
            h.drive_motor,
            h.drive_stiff,
        ),  # fmt: skip
        "rows": digest(
            model.limit_count,
            h.limit_joint,
            h.limit_coordinate,
            h.limit_bounds,
            h.limit_drive,
            h.distance_body,
            h.distance_anchor,
        ),  # fmt: skip
        "colliders": digest(0 if c is None else c.collider_count + c.plane_count, *shapes, *planes),
        "contact_settings": digest(len(settings), np.frombuffer(repr(settings).encode(), dtype=np.uint8)),
    }


def mass_ratio_note(model: Model, limit: float = 1e8) -> str:
    """A sentence naming the pair of jointed dynamic bodies whose masses, or principal moments of inertia,
    differ most, when that ratio is above `limit`; '' otherwise. A failed factorization or a diverging
    correction appends it: K = J M^-1 J^T then sums terms of such different sizes that double precision
    loses the small ones, which looks like a redundant constraint but is not one."""
    h, names = model.host, model.body_name
    worst, note = limit, ""
    for j, (p, c) in enumerate(zip(h.joint_parent, h.joint_child)):
        pair = [int(b) for b in (p, c) if b >= 0 and not h.body_static[b]]
        if len(pair) == 2:
            light, heavy = sorted(pair, key=lambda b: h.body_mass[b])
            if h.body_mass[heavy] / h.body_mass[light] > worst:
                worst = h.body_mass[heavy] / h.body_mass[light]
                note = (f"the mass ratio between jointed bodies {names[heavy]!r} ({h.body_mass[heavy]:.3g} kg) "
                        f"and {names[light]!r} ({h.body_mass[light]:.3g} kg) is {worst:.3g}")  # fmt: skip
        moments = [(np.linalg.eigvalsh(h.body_inertia[b]), b) for b in pair]
        if moments:
            (small, low), (large, high) = min(moments, key=lambda m: m[0][0]), max(moments, key=lambda m: m[0][-1])
            if large[-1] / small[0] > worst:
                worst = large[-1] / small[0]
                note = (f"the ratio of principal moments of inertia across joint {model.joint_name[j]!r} is "
                        f"{worst:.3g} (body {names[high]!r}: {large[-1]:.3g} kg m^2, body {names[low]!r}: "
                        f"{small[0]:.3g} kg m^2)")  # fmt: skip
    if note:
        note += f": too large for double precision; keep such ratios below ~{limit:.0e}"
    return note


RUNAWAY = 1e3
"""m (or rad): a load that alone would move a body this far (or turn it this much) in one step is a runaway."""


def runaway_note(model: Model, dt: float, force: np.ndarray, torque: np.ndarray) -> str:
    """A sentence naming the dynamic body whose load alone would move it furthest in a step of `dt` (s), when that
    is over `RUNAWAY` m (0.5 |F| / m dt^2; a torque over the smallest principal moment turns it by as many rad);
    '' otherwise. `force` and `torque` (n, 3) are the step's loads (N, N m: the model's and the user's). A failed
    correction or factorization names it: no joint holds a body pushed by 1e30 N, and the impulses that try lose
    every other term of K to round-off, which looks like a degenerate joint but is not one."""
    h = model.host
    dynamic = np.flatnonzero(~h.body_static)
    if not len(dynamic):
        return ""
    with np.errstate(over="ignore", invalid="ignore"):
        shift = 0.5 * np.linalg.norm(force[dynamic], axis=1) / h.body_mass[dynamic] * dt * dt
        moments = np.linalg.eigvalsh(h.body_inertia[dynamic])[:, 0]
        turn = 0.5 * np.linalg.norm(torque[dynamic], axis=1) / moments * dt * dt
    worst = np.nan_to_num(np.maximum(shift, turn), nan=np.inf)
    k = int(np.argmax(worst))
    if not worst[k] > RUNAWAY:
        return ""
    b = int(dynamic[k])
    if shift[k] >= turn[k]:
        load = f"{np.linalg.norm(force[b]):.3g} N on body {model.body_name[b]!r} ({h.body_mass[b]:.3g} kg)"
        return f"a runaway force: {load} would move it {shift[k]:.3g} m in one step of {dt:g} s"
    load = f"{np.linalg.norm(torque[b]):.3g} N m on body {model.body_name[b]!r} (smallest moment {moments[k]:.3g} "
    load += "kg m^2)"
    return f"a runaway torque: {load} would turn it {turn[k]:.3g} rad in one step of {dt:g} s"


LOOP_CHECK_DOFS = 600
"""The most dynamic degrees of freedom (6 a body) whose loops `degenerate_loop` checks (a dense SVD of J)."""
SECOND_ORDER = 1e-3
"""The stretch (dimensionless: per unit length scale) above which a first-order motion is blocked at second
order (`degenerate_loop`); a real motion of a mechanism shows round-off, ~1e-9."""


def length_scale(model: Model) -> float:
    """The scene's lever (m): the longest anchor arm of a constraint from a body's centre of mass, at least 1 mm."""
    h = model.host
    arms = [np.linalg.norm(a[b >= 0], axis=1) for a, b in ((h.constraint_anchor0, h.constraint_body0),
                                                            (h.constraint_anchor1, h.constraint_body1))]  # fmt: skip
    return max([1e-3, *(float(a.max()) for a in arms if len(a))])


def degenerate_loop(model: Model, times, moved, dofs: int, rank_tolerance: float = 1e-8, epsilon: float = 1e-5) -> str:
    """A sentence naming the joints of a degenerate kinematic loop, or '' when every redundant row is consistent.

    A loop's rows are redundant when a combination w of them has w^T J = 0 (a self-stress: a planar four-bar's
    out-of-plane rows; three ball joints in line pulling along the line). That is harmless when every motion J
    allows (J u = 0, its null space) is a real motion of the mechanism: the combination then stays zero along
    it. It is degenerate when some allowed motion u stretches the combination at second order,
    w^T (dJ/du) u != 0: the joints in line let the middle one move sideways to first order only, the solver
    regularises the redundant row as if it were consistent, and the correction never converges. Checked on
    the dense J in generalized velocities u (m/s: angular ones times the length scale), rows normalised:

    `times(u)` is J u at the current pose (dofs,) -> (rows,), built at first; `moved(u, s)` moves the pose by s
    length scales along u (None: back to the built pose) and returns `times`; `rank_tolerance` is the singular
    value (relative to the largest) below which a direction is null: an exact redundancy, to round-off. A row
    only nearly redundant (a loop built a little out of plane, or out of line) is not checked: its motions are
    not exact, and their second-order terms would not say whether they are real."""
    columns = np.stack([times(e) for e in np.eye(dofs)], axis=1)
    scale = np.linalg.norm(columns, axis=1)
    rows = scale > 1e-12 * max(scale.max(initial=0.0), 1e-300)  # padded rows of constraints of dimension < 3
    jac = columns[rows] / scale[rows, None]
    u, s, vt = np.linalg.svd(jac)
    rank = int(np.count_nonzero(s > rank_tolerance * s[0])) if len(s) else 0
    stresses, flexes = u[:, rank:], vt[rank:].T
    if not stresses.shape[1] or not flexes.shape[1]:
        return ""
    worst, culprit = 0.0, None
    count = flexes.shape[1]
    for a in range(count):
        at = moved(flexes[:, a], epsilon)
        ahead = [at(flexes[:, b]) for b in range(a, count)]
        at = moved(flexes[:, a], -epsilon)
        back = [at(flexes[:, b]) for b in range(a, count)]
        for plus, minus in zip(ahead, back):
            change = (plus - minus)[rows] / scale[rows] / (2.0 * epsilon)
            stretch = stresses.T @ change  # each self-stress's second-order change along the pair of motions
            k = int(np.argmax(np.abs(stretch)))
            if abs(stretch[k]) > worst:
                worst, culprit = float(abs(stretch[k])), stresses[:, k]
    moved(None, 0.0)
    if worst <= SECOND_ORDER:
        return ""
    weight = np.zeros(len(scale))
    weight[rows] = np.abs(culprit)
    per_constraint = weight.reshape(-1, 3).max(axis=1)
    involved = np.flatnonzero(per_constraint > 0.05 * per_constraint.max())
    joints = sorted({int(model.constraint_joint[c]) for c in involved})
    names = ", ".join(repr(model.joint_name[j]) for j in joints)
    return (f"joints {names} form a degenerate loop: rows of theirs are redundant, yet a motion they allow to first "
            f"order stretches them at second order ({worst:.3g} per length scale; e.g. joints in line), so no "
            "impulse holds the loop; move a joint off the line or remove the redundant joint")  # fmt: skip
