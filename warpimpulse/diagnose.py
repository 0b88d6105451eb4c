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
