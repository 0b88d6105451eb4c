"""What a model is, in two forms that failures and checkpoints use: its fingerprint, and the mass ratios
that double precision cannot resolve."""

from __future__ import annotations

import hashlib

import numpy as np

from .model import Model


def fingerprint(model: Model) -> dict[str, str]:
    """SHA-256 digests of what a checkpoint's state is only valid for: the bodies' masses and inertias,
    the constraints (kinds, bodies, local anchors, axes and rest values: the topology and geometry), and
    gravity with the model's forces. Initial poses are not in it: a checkpoint replaces them."""

    def digest(*arrays) -> str:
        h = hashlib.sha256()
        for a in arrays:
            a = np.ascontiguousarray(a, dtype=np.float64)
            h.update(repr(a.shape).encode())
            h.update(a.tobytes())
        return h.hexdigest()

    h = model.host
    return {
        "bodies": digest(h.body_mass, h.body_inertia, h.body_static),
        "constraints": digest(
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
        "forces": digest(h.gravity, h.force_body, h.force_force, h.force_torque, h.force_until),
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
