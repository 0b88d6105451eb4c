"""Higher order in time by composing the paper's step (order 2, symmetric) with itself.

The paper's step is symmetric: the impulses at t0 use the Jacobian of the constraints at t0 and land the
prediction on them, the velocity projection at t0+h uses the same Jacobian at t0+h, so the step run with -h
from its end undoes it (exactly, up to the O(h^5) of the RK4 free flight and the tolerances). For a symmetric
step S(h) of order 2, the composition S(g_s h) ... S(g_1 h) with symmetric coefficients (g_i = g_{s+1-i}) that
sum to 1 has order 4 when sum g_i^3 = 0, and order 6 under two more conditions (Hairer, Lubich & Wanner,
Geometric Numerical Integration, section V.3). Some coefficients are negative: those substeps run backwards.

The tables below are the classic schemes; the simulator takes the one `DEFAULT[order]` names, picked by
measured error against cost (benchmarks/orders.py, docs/time-order.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

ORDERS = (2, 4, 6)


@dataclass(frozen=True)
class Scheme:
    name: str
    order: int
    stages: tuple[float, ...]  # the substeps as fractions of the step, in the order they are taken
    source: str

    @property
    def cost(self) -> int:
        """Base steps per step."""
        return len(self.stages)

    @property
    def reach(self) -> float:
        """The largest |substep| as a fraction of the step (the spin split sizes steps by it)."""
        return max(abs(g) for g in self.stages)


def stage_keys(stages: tuple[float, ...]) -> tuple[tuple[float, int], ...]:
    """Each stage as (its fraction of the step, how many stages of that fraction come before it): the key of its
    carried right-hand side (kernels/carry.py). Suzuki's p, p, 1 - 4p, p, p gives (p, 0), (p, 1), (1 - 4p, 0),
    (p, 2), (p, 3): stages of one size keep a c each, every one measured a whole step apart at the same point of
    the step, as the extrapolation assumes; shared, the four were one history sampled at the last stage only."""
    seen: dict[float, int] = {}
    keys = []
    for g in stages:
        keys.append((g, seen.get(g, 0)))
        seen[g] = seen.get(g, 0) + 1
    return tuple(keys)


def _mirror(*half: float) -> tuple[float, ...]:
    """A symmetric scheme from its first half; the middle coefficient makes the sum 1."""
    return (*half, 1.0 - 2.0 * sum(half), *half[::-1])


_TRIPLE = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
_SUZUKI = 1.0 / (4.0 - 4.0 ** (1.0 / 3.0))

SCHEMES = {
    s.name: s
    for s in (
        Scheme("base", 2, (1.0,), "the paper's step"),
        Scheme("yoshida3", 4, _mirror(_TRIPLE), "Yoshida 1990, Creutz & Gocksch 1989: the triple jump"),
        Scheme("suzuki5", 4, _mirror(_SUZUKI, _SUZUKI), "Suzuki 1990: p, p, 1 - 4p, p, p with p = 1/(4 - 4^(1/3))"),
        Scheme("mclachlan5", 4, _mirror(0.28, 0.62546642846767004501), "McLachlan 1995, optimised 5 stages"),
        Scheme(
            "yoshida7",
            6,
            _mirror(0.78451361047755726382, 0.23557321335935813368, -1.17767998417887100695),
            "Yoshida 1990, solution A",
        ),
        Scheme(
            "kahanli9",
            6,
            _mirror(0.39216144400731413928, 0.33259913678935943860, -0.70624617255763935981, 0.08221359629355080023),
            "Kahan & Li 1997, s9odr6a",
        ),
    )
}

# Picked by benchmarks/orders.py: the smallest error for the work on the paper's tree, the double pendulum
# and the 50-link chain (docs/time-order.md has the numbers).
DEFAULT = {2: "base", 4: "suzuki5", 6: "kahanli9"}


def scheme(order: int, name: str | None = None) -> Scheme:
    """The composition for `order` (2, 4 or 6): `name` from SCHEMES, or the measured best."""
    if order not in ORDERS:
        raise ValueError(f"order must be one of {ORDERS}, got {order!r}")
    chosen = SCHEMES.get(DEFAULT[order] if name is None else name)
    if chosen is None:
        raise ValueError(f"unknown composition {name!r}; expected one of {sorted(SCHEMES)}")
    if chosen.order != order:
        raise ValueError(f"composition {chosen.name!r} has order {chosen.order}, not {order}")
    return chosen


# The tolerance rule (m or rad). The joint correction stops within the tolerance, so every base step leaves
# up to that much error, and a symmetric composition only cancels errors that are smooth in h: a tolerance
# near the step's own error caps the order, a tighter one costs joint iterations for nothing. The rule is
# COEFFICIENT[order] dt^(order+1), measured (benchmarks/tolerances.py, docs/tolerance.md: five MJCF scenes,
# order 4 at h = 1/30 ... 1/240, order 6 at 1/15 ... 1/120, the trajectory error against MuJoCo RK4 at
# 1/32000) as the loosest that keeps every scene's error within 5% of its error at tolerance 1e-12. The
# paper's tree binds: its motion is slow, its error small, and its 127 joints add up what each leaves. At
# order 4 it allows no looser coefficient than 10 (1/60: 1e-8 keeps 1.01 of the tight error, 1e-7 1.33;
# 1/120: 1e-9 1.05), at order 6 it allows 200 (1/30: 9.1e-9 keeps 1.01, 1/40: 1.2e-9 1.04, 1/60: 7.1e-11
# 1.03; 10 before: 14 to 18% more joint iterations for the same error). The serial scenes would take far
# looser ones (arm7 at order 4: 1e-5 at 1/60 and 1/120), which a rule of h alone cannot see; a run that
# wants them sets the tolerance (benchmarks/scene_kinds.py searches it), or asks `accuracy=`. Round-off in
# float64 sets the floor; 1e-6 (the paper's) the cap.
TOLERANCE_CAP = 1e-6
TOLERANCE_FLOOR = 1e-12
COEFFICIENT = {4: 10.0, 6: 200.0}


def default_tolerance(dt: float, order: int) -> float:
    """The joint tolerance used when the user gives none: 1e-6 at order 2 (the paper's), else
    COEFFICIENT[order] dt^(order + 1) (dt in s, read in m or rad: 10 dt^5 at order 4, 200 dt^7 at 6), clamped to
    [1e-12, 1e-6]."""
    if order == 2:
        return TOLERANCE_CAP
    return min(TOLERANCE_CAP, max(TOLERANCE_FLOOR, COEFFICIENT[order] * math.pow(abs(dt), order + 1)))
