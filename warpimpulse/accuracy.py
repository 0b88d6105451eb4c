"""Accuracy on request: `Simulator(model, accuracy=E)` chooses the order, the joint tolerance and the step size so
that the body centres stay within about E metres of the exact trajectory over a horizon, at little more cost
than the cheapest fixed configuration that would (docs/accuracy.md has the measurements).

What is chosen, and how:
- the order, from E alone (`plan`): order 2 (the paper's step) at loose accuracies, where its large steps are
  cheapest, order 4 below `ORDER4_BELOW`. A scene with joint limits, stiff motors or distance rows, whose steps
  fall back to order 2 anyway (`simulator.ROWS_FALLBACK`), is controlled at order 2, as `Plan.note` says;
  contacts and batched worlds are refused.
- the joint tolerance: `TOLERANCE_SHARE` of E. Every step may leave up to the tolerance in each joint, and the
  step-doubling estimate below cannot see a local error below it.
- the step size, from an error estimate (`Controller`): the local error of the steps is measured by step
  doubling (one step of 2h from a state, undone, against the two steps of h the trajectory takes from it, in the
  same interval or across the next: for a method of order p they differ by C h^(p+1) (2^(p+1) - 2), which gives
  the error constant C), and h is set so that the local error per unit time, C h^p, is `SAFETY` E / horizon:
  the local errors then add up to about E over the horizon. A check costs one step of 2h and comes every
  `CHECK_EVERY` steps: about a tenth of the work.

`Simulator.dt` is the interval that `step()` advances (a frame of the USD recorder, a control tick): each is
taken as a whole number of equal steps, so frames land exactly on their times; the step size is at most dt.

What it cannot do: the estimate is local. Errors that the motion amplifies (a chaotic double pendulum) grow
faster than the sum of local errors, and errors that it damps grow slower; the benchmark
(benchmarks/accuracy.py) measures how near E the trajectory error of real scenes ends.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from . import checks, composition
from .steps import StepStats, combined

if TYPE_CHECKING:
    from .model import Model

ORDER4_BELOW = 3e-3
"""m: accuracies below this are reached at order 4 (the composed step), from it up at order 2: where order 2 wins
in benchmarks/accuracy.py's grid of (order, h, tolerance)."""
TOLERANCE_SHARE = 1e-3
"""The joint tolerance as a share of the accuracy (m or rad per m asked), clamped to [1e-12, 1e-5]: each step
may leave it in the joints, and a check cannot see a local error below about twice it (`Controller._constant`),
which must stay below the gap of the local error aimed at, or the step cannot grow to its size."""
TOLERANCE_CAP = 1e-5
SAFETY = 0.5
"""The local error per unit time aimed at, as a share of accuracy / horizon."""
NOISE_MARGIN = 2.0
"""A check's gap must exceed this many joint tolerances to be taken as an error (`Controller._constant`)."""
CHECK_EVERY = 10
"""Steps, and intervals, between two error checks: a check costs a step of 2h and, on a small scene where the calls
cost more than the steps, a few calls. The first come sooner (after 0, 1, 2, ... steps and intervals): the motion
from rest speeds up, and with it the error constant."""
GROWTH = 2.0
"""The step grows at most by this factor from one check to the next (it shrinks at once)."""
MAX_STEPS = 1 << 16
"""The most steps an interval is cut into: an estimate this small is noise, not a step size."""
DEFAULT_INTERVAL = 1.0 / 30.0
"""s: `Simulator.dt` where `accuracy` is given without it."""
DEFAULT_HORIZON = 1.0
"""s: the horizon over which E is meant when none is set (`Controller.horizon`; the CLI sets its --duration)."""
ROWS_NOTE = (
    "controlled at order 2: the scene has joint limits, stiff motors or distance rows, whose steps are taken at "
    "order 2 whatever the order (a composed step would run them backwards)"
)


@dataclass(frozen=True)
class Plan:
    """The settings `accuracy` chooses before the simulator is built."""

    accuracy: float  # m
    dt: float  # s: the interval step() advances, the largest step
    order: int
    tolerance: float  # m or rad
    note: str  # what the plan had to give up, or ""


def plan(model: Model, accuracy, dt: float | None, tolerance: float | None, order: int) -> Plan:
    """The order, tolerance and interval for `accuracy` (m) on `model`; a ValueError names what cannot be
    controlled (contacts, batched worlds, an order given with it)."""
    what = "accuracy"
    accuracy = checks.positive(accuracy, what, " (m: the body centres' largest position error over the horizon)")
    if model.colliders is not None:
        raise ValueError(
            "accuracy: the scene has contacts, whose impacts the step-doubling error estimate does not measure; "
            "give dt (and tolerance) instead"
        )
    if model.world_count > 1:
        raise ValueError(f"accuracy: batched worlds ({model.world_count}) step together at one dt; give dt instead")
    if order != 2:
        raise ValueError(f"accuracy chooses the order itself; leave order at its default (got order {order})")
    dt = DEFAULT_INTERVAL if dt is None else checks.positive(dt, "dt", " (seconds)")
    if tolerance is None:
        tolerance = min(TOLERANCE_CAP, max(composition.TOLERANCE_FLOOR, TOLERANCE_SHARE * accuracy))
    rows = model.limit_count > 0
    chosen = 2 if rows or accuracy >= ORDER4_BELOW else 4
    return Plan(accuracy, dt, chosen, tolerance, ROWS_NOTE if rows and accuracy < ORDER4_BELOW else "")


class Controller:
    """Steps a Simulator interval by interval (`Simulator.dt`), each in whole steps whose size follows the
    estimated local error. `horizon` (s) is the time over which the accuracy is meant."""

    def __init__(self, sim, chosen: Plan) -> None:  # sim: the Simulator it steps (which imports this module)
        self.sim = sim
        self.plan = chosen
        self.interval = chosen.dt
        self.horizon = DEFAULT_HORIZON
        # the order of the steps actually taken: 2 where rows make the composed step fall back
        self.order = 2 if sim.model.limit_count else sim.order
        self._start = sim.model.state()  # the state a check returns to
        self._integral = wp.zeros_like(sim.drive_integral)
        self._carry = wp.zeros_like(sim._carry)  # the carried right-hand sides (`Simulator.carry`) and their past
        self._carry_past = wp.zeros_like(sim._carry_past)
        self._copies = self._pairs()
        host = sim.model.host  # radii of gyration (m): sqrt(trace(I) / m), 0 for static bodies
        mass = np.where(host.body_mass > 0.0, host.body_mass, np.inf)
        self._gyration = np.sqrt(np.trace(host.body_inertia, axis1=1, axis2=2) / mass)
        self.reset()

    def reset(self) -> None:
        """Forget the error constant (a new run, or a state set from outside)."""
        self.constant: float | None = None  # C (m s^-(p+1)): a step of h leaves about C h^(p+1)
        self.steps = 0  # per interval
        self._since_check = self._intervals = 0  # steps and intervals since the last check
        self._checks = 0  # checks done: the first come early, while C is known from the pilot only
        self._pending: tuple[np.ndarray, int] | None = None  # a check's coarse `_measured`, fine steps to go

    @property
    def step_size(self) -> float:
        """s: the step now taken."""
        return self.interval / max(self.steps, 1)

    # ------------------------------------------------------------------ stepping
    def step(self, n: int) -> StepStats:
        """n intervals; their stats combined as `Simulator.step` combines steps, with the step size (the smallest
        used) and the estimated local error (m) the steps added, summed."""
        sim = self.sim
        parts = []
        try:
            for _ in range(n):
                parts.append(self._interval())
        finally:
            sim.dt = self.interval
        stats = parts[0] if n == 1 else combined(parts)
        return stats

    def _interval(self) -> StepStats:
        """One interval of whole steps of the current size, a check started or finished in it."""
        sim = self.sim
        end = (round(sim.time / self.interval) + 1) * self.interval  # frames land on f * dt exactly
        if self.constant is None:
            self._pilot()
        k, h = self.steps, self.step_size
        parts, measured = [], None  # measured: (C, noisy) of a check finished here
        spacing = min(CHECK_EVERY, self._checks)
        if self._pending is None and min(self._since_check, self._intervals) >= spacing:
            self._save()  # one step of 2h from here, compared with the trajectory two steps on
            limit, sim.max_rotation = sim.max_rotation, None  # a spin split would make it two steps of h
            try:
                check = self._steps(2.0 * h, 1)
            finally:
                sim.max_rotation = limit
            parts.append(check)
            if check.substeps == 1:  # else a failing correction halved it: no comparison
                self._pending = (self._measured(), 2)
            self._restore()
        if self._pending is not None and self._pending[1] <= k:
            coarse, ahead = self._pending
            parts.append(self._steps(h, ahead))
            measured = self._constant(coarse, self._measured(), h)
            self._pending, self._since_check, self._intervals, self._checks = None, 0, 0, self._checks + 1
            if k > ahead:
                parts.append(self._steps(h, k - ahead))
        else:
            parts.append(self._steps(h, k))
            if self._pending is not None:
                self._pending = (self._pending[0], self._pending[1] - k)
        stats = parts[0] if len(parts) == 1 else combined(parts)
        sim.time = end
        sim._set_step_size(h)  # the clock counts on from the frame time
        stats.step_size = h
        stats.error_estimate = k * self.constant * h ** (self.order + 1)
        self._since_check += k
        self._intervals += 1
        if measured is not None:
            self._adopt(measured)
        return stats

    def _steps(self, h: float, n: int) -> StepStats:
        """n steps of h, their stats combined."""
        self.sim._set_step_size(h)
        parts = self.sim._steps(n, combine=True)
        return parts[0] if len(parts) == 1 else combined(parts)

    def _measured(self) -> np.ndarray:
        """What a check compares: the body centres (m) and orientations, (n, 7)."""
        x, q = self._copies[0][0], self._copies[1][0]
        if not isinstance(x, np.ndarray):
            x, q = x.numpy(), q.numpy()
        return np.concatenate([x, q], axis=1)

    def _constant(self, coarse: np.ndarray, fine: np.ndarray, h: float) -> tuple[float, bool]:
        """C from one step of 2h (`coarse`) against two steps of h (`fine`): they differ by C h^(p+1) (2^(p+1) - 2),
        C of the body furthest apart: its centre's distance plus the angle between its orientations times its
        radius of gyration (a body's turn moves its points as much as its centre's shift). A gap within twice the
        joint tolerance (what each trajectory may leave in the joints) says only that the error is below it: C is
        taken from that, and flagged (True), so that it never shrinks the step."""
        p = self.order
        shift = np.linalg.norm(coarse[:, :3] - fine[:, :3], axis=1)
        qa, qb = coarse[:, 3:], fine[:, 3:]
        turn = 2.0 * np.minimum(np.linalg.norm(qa - qb, axis=1), np.linalg.norm(qa + qb, axis=1))  # rad, small
        gap = float((shift + self._gyration * turn).max(initial=0.0))
        floor = NOISE_MARGIN * self.sim.tolerance
        return max(gap, floor) / (h ** (p + 1) * (2.0 ** (p + 1) - 2.0)), gap <= floor

    def _pilot(self) -> None:
        """A first C, from the start state: one step of the interval against two of half of it, then undone."""
        sim = self.sim
        h = self.interval
        self._save()
        self._steps(h, 1)
        coarse = self._measured()
        self._restore()
        self._steps(0.5 * h, 2)
        measured = self._constant(coarse, self._measured(), 0.5 * h)
        self._restore()
        sim.dt = self.interval
        self.constant, self.steps = None, 0
        self._adopt(measured)
        self._checks = 1  # the pilot was one: the next check comes an interval on

    def _adopt(self, measured: tuple[float, bool]) -> None:
        """The new C, and the steps an interval takes for it: C h^p = SAFETY accuracy / horizon; the step grows by
        at most GROWTH a check. A C taken from the noise (an upper bound) may let the step grow, never shrink it:
        a tolerance-sized gap read as an error would shrink the step without end."""
        self.constant, noisy = measured
        wanted = SAFETY * self.plan.accuracy / self.horizon
        h = (wanted / self.constant) ** (1.0 / self.order) if self.constant > 0.0 else math.inf
        steps = min(MAX_STEPS, max(1, math.ceil(self.interval / h * (1.0 - 1e-9))))
        if self.steps:
            steps = max(steps, math.ceil(self.steps / GROWTH))
            if noisy:
                steps = min(steps, self.steps)
        self.steps = steps

    # ------------------------------------------------------------------ undo
    def _pairs(self) -> list[tuple]:
        """(simulator array, its copy) of everything a check undoes: the state, the drives' integrals and the
        carried right-hand sides; on a CPU as numpy views, copied without a launch (~0.2 us against ~10 us)."""
        sim = self.sim
        pairs = [(getattr(sim._state, f), getattr(self._start, f)) for f in ("body_x", "body_q", "body_v", "body_w")]
        pairs += [(sim.drive_integral, self._integral), (sim._carry, self._carry), (sim._carry_past, self._carry_past)]
        if sim.model.device.is_cpu:
            return [(a.numpy(), b.numpy()) for a, b in pairs]
        return pairs

    def _save(self) -> None:
        sim = self.sim
        for live, kept in self._copies:
            _copy(kept, live)
        self._saved = (sim.time, sim.step_count, sim._spin, sim._fallback, sim._handout)

    def _restore(self) -> None:
        sim = self.sim
        for live, kept in self._copies:
            _copy(live, kept)
        sim.time, sim.step_count, sim._spin, sim._fallback, sim._handout = self._saved
        sim._update_frames()


def _copy(dst, src) -> None:
    if isinstance(dst, np.ndarray):
        np.copyto(dst, src)
    else:
        wp.copy(dst, src)
