"""Accuracy on request: `Simulator(model, accuracy=E)` chooses the order, the joint tolerance and the step size so
that the body centres stay within about E metres of the exact trajectory over a horizon, at little more cost
than the cheapest fixed configuration that would (docs/accuracy.md has the measurements).

What is chosen, and how:
- the order, from a pilot of each (`cheaper_order`, as the simulator is built): each order runs the first
  `PROBE` s of the motion at two step sizes, which gives its trajectory error constant, hence the steps it needs
  for E and their work (stage predictions and linear solves); the cheaper is taken. Which order that is depends
  on the scene, not on E alone: order 4 at the largest step may be far below E where order 2 reaches it for less.
  A scene with joint limits, stiff motors or distance rows, whose steps fall back to order 2 anyway
  (`simulator.ROWS_FALLBACK`), is controlled at order 2, as `Plan.note` says; contacts and batched worlds are
  refused.
- the joint tolerance: `TOLERANCE_SHARE` of E (at most `TOLERANCE_CAP`). Every step may leave up to the
  tolerance in each joint; the trajectory error hardly moves while it is a fiftieth of that error.
- the step size, from an estimate of the trajectory error itself (`Controller`): a shadow Simulator runs the
  same model alongside at twice the step. For a method of order p, the trajectory errors of runs at h and 2h are
  G h^p and G (2h)^p, so their gap is (2^p - 1) times the trajectory's own error (Richardson's estimate, on the
  whole trajectory): it includes what the motion did with the errors of all earlier steps, which a local
  estimate does not see (a chaotic arm amplified its local errors 5-17x). Every block of intervals the gap is
  read, the error projected to the horizon's end, and the step of the next block sized so that it is `SAFETY`
  E there; the blocks mix the whole step counts below and above the wanted one (`Controller._aim`). The shadow
  costs its steps, half the trajectory's.

`Simulator.dt` is the interval that `step()` advances (a frame of the USD recorder, a control tick): each is
taken as a whole number of equal steps, so frames land exactly on their times; the step size is at most dt.

What it cannot do: take back an error already made. Where the motion suddenly amplifies the error (a chain's
whip, a tumbling arm), the estimate sees it a block late, and errors made earlier stay; the benchmark
(benchmarks/accuracy.py) measures how near E the trajectory error of real scenes ends.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
import warp as wp

from . import checks, composition
from .steps import SimulationError, StepStats, combined

if TYPE_CHECKING:
    from .model import Model

ORDERS = (2, 4)
"""The orders `cheaper_order` tries: order 6 is never the cheapest between 1e-2 and 1e-5 m in benchmarks/accuracy.py's
grid of (order, h, tolerance)."""
TOLERANCE_SHARE = 0.02
"""The joint tolerance as a share of the accuracy (m or rad per m asked), clamped to [1e-12, TOLERANCE_CAP]: a
tolerance a fiftieth of the trajectory error moves that error by under 2% (docs/history.md, "Tolerance at large
steps"), and at loose accuracies the iterations it saves are most of a step's cost."""
TOLERANCE_CAP = 1e-4
SAFETY = 0.5
"""The trajectory error aimed at the horizon's end, as a share of the accuracy. Below E, not at it: where the
motion amplifies errors late (a chaotic arm, a chain's whip) the projection from the error so far falls short,
and the step counts mixed between blocks (`Controller._aim`) no longer leave the error far below the aim (aimed
at E, the arm ended at 7-25 E and chain20 at 1e-4 m at 12 E; at E/2 the chain at 0.7-2.5 E)."""
NOISE_MARGIN = 2.0
"""The pilot's step-doubling gap is taken as at least this many joint tolerances (what each step may leave)."""
BLOCKS = 20
"""The comparisons with the shadow over the horizon (at most: a block is at least two intervals)."""
GROWTH = 2.0
"""The step grows at most by this factor from one block to the next."""
SHRINK = 2.0
"""... and shrinks at most by this one."""
GROWTH_POWER = 3.0
"""The steepest growth of the error with time, t^m, that the step is sized for."""
COSTLY = 2.0
"""The shadow's linear solves over the trajectory's in a block above which its steps of 2h are taken to be past
where the joint iteration converges in a few iterations, and its error past where it goes as (2h)^p. Where they
converge alike, half as many steps at a looser tolerance take 0.5-1.1 of the trajectory's solves (a step of 2h
needs more iterations than one of h: the tree of 127 bodies at order 4, h = 1/40, about 1.0). Past it the
steps of 2h cost more than the trajectory (a chain of 20 at order 4: 130 solves a step of 0.1 s where two steps
of 0.05 s took 24, 5.4x), so the trajectory's steps stay at most half as large for the rest of the run
(`Controller._least`): its shadow then steps where the trajectory stepped."""
START = 2.0
"""The first step is this much smaller than the pilot says: the motion from rest speeds up, and the error of a
chaotic motion is mostly made early."""
MAX_STEPS = 1 << 16
"""The most steps an interval is cut into: an estimate this small is noise, not a step size."""
DEFAULT_INTERVAL = 1.0 / 30.0
"""s: `Simulator.dt` where `accuracy` is given without it."""
PROBE = 0.2
"""s: the motion over which `cheaper_order` compares the orders (at least two intervals)."""
PILOT_TIGHTENING = 0.01
"""`cheaper_order` measures the orders' gaps at this share of the run's joint tolerance (at least 1e-12)."""
PROBE_POWER = 2.0
"""The steepest growth of the error with time, t^m, that `cheaper_order` projects its pilot with: from rest the
error grows faster at first than it goes on to (t^3 over the first 0.2 s on the arm and the chain, where order 2
is the cheaper at 1e-2 m)."""
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


def plan(model: Model, accuracy, dt: float | None, tolerance: float | None, order: int, probe) -> Plan:
    """The order, tolerance and interval for `accuracy` (m) on `model`; a ValueError names what cannot be
    controlled (contacts, batched worlds, an order given with it). `probe(model, dt, tolerance=, order=)` builds
    a Simulator of the model (the caller's class) for `cheaper_order`."""
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
    if model.limit_count > 0:
        return Plan(accuracy, dt, 2, tolerance, ROWS_NOTE)
    return Plan(accuracy, dt, cheaper_order(model, accuracy, dt, tolerance, probe), tolerance, "")


def cheaper_order(model: Model, accuracy: float, dt: float, tolerance: float, probe) -> int:
    """The order (of `ORDERS`) that reaches `accuracy` (m) over `DEFAULT_HORIZON` in the least work, from a pilot
    of each over the first `PROBE` s of the motion. The gap between its run in steps of dt / 2 and in steps of
    dt / 4 is (1 - 2^-p) G (dt / 2)^p, G its trajectory error constant (steps of dt are beyond where the error
    goes as h^p at order 4 on the humanoid); G is taken to grow as t^m to the horizon's end (m from the gaps at
    half the window and at its end, as the controller's), which gives the whole steps of the interval the order
    needs (`START` times more, as the controller's first step). Each step costs its stages' predictions and
    linear solves, counted alike.

    The gaps come from runs at `PILOT_TIGHTENING` times the tolerance (the run's own where those fail): at the
    run's own, what each step leaves in the joints is most of order 4's gap (the humanoid at 1e-3 m: 3.6e-5 m at
    a tolerance of 2e-5, 4.9e-6 m at 2e-7), and order 4 looked costlier than it is. The solves come from runs at
    the run's tolerance, in steps of dt / 2 and dt / 4, and are taken to grow with the step as they grew between
    the two (to at most dt): a step of dt takes more iterations than those (the humanoid at order 4: 21 solves a
    step of 1/20 s, 5 of 1/40 s).

    The work of the two orders is what decides, not the accuracy alone: order 4 at the largest step, dt, may be
    far below the accuracy asked (a tree of 127 bodies at 1e-3 m: 0.02 of it, where order 2 at dt / 4 costs a
    third as much), and which order is cheaper at a given accuracy differs between scenes. Both pilots see the
    same motion, so what the motion later does to the errors moves both alike. The pilot runs once, as the
    simulator is built (four Simulators of the model and their steps), from the model's start state."""
    half = max(1, round(PROBE / (2.0 * dt)))  # intervals in half the window
    window, h = 2 * half * dt, 0.5 * dt
    tight = max(composition.TOLERANCE_FLOOR, PILOT_TIGHTENING * tolerance)
    work = {}
    for p in ORDERS:
        sim = probe(model, h, tolerance=tolerance, order=p)
        gaps, (coarse, fine) = _pilot_runs(sim, half, h)
        try:
            gaps, _ = _pilot_runs(probe(model, h, tolerance=tight, order=p), half, h)
        except SimulationError:  # a tolerance under what the scene's round-off reaches: the run's own gaps
            pass
        power = min(PROBE_POWER, _growth(gaps[0], gaps[1], 2.0))
        constant = gaps[1] / ((1.0 - 2.0**-p) * h**p) * (DEFAULT_HORIZON / window) ** power  # m/s^p at the end
        steps = max(1.0, START * dt * (constant / (SAFETY * accuracy)) ** (1.0 / p))  # blocks mix (`_aim`)
        growth = math.log(max(coarse, 1.0) / max(fine, 1.0), 2.0)  # solves a step as (step size)^growth
        solves = max(fine, 1.0) * min(4.0, max(1.0, 4.0 / steps)) ** max(0.0, growth)  # a step of dt / steps
        work[p] = steps * (len(sim.scheme.stages) + solves)
    return min(ORDERS, key=lambda p: (work[p], -p))


def _pilot_runs(sim, half: int, h: float) -> tuple[list[float], tuple[float, float]]:
    """`cheaper_order`'s runs of `sim` (built at steps of h) over 2 * half intervals, in steps of h and of h / 2:
    the largest distance (m) of a body centre between the two at half the window and at its end, and the linear
    solves a step of h and of h / 2."""
    coarse, solves = [], 0
    for _ in range(2):  # the positions at half the window and at its end
        solves += sim.step(2 * half).linear_iterations
        coarse.append(sim.positions())
    sim.reset()
    sim._set_step_size(0.5 * h)
    gaps, fine = [], 0
    for c in coarse:
        fine += combined(sim._steps(4 * half)).linear_iterations
        gaps.append(float(np.linalg.norm(c - sim.positions(), axis=1).max(initial=0.0)))
    return gaps, (solves / (4 * half), fine / (8 * half))


def _pilot_steps(gap: float, p: int, h: float, tolerance: float, accuracy: float, horizon: float) -> float:
    """Steps an interval h is cut into at order p, from the gap (m) between one step of h and two of h / 2:
    the local error constant C of C h^(p+1) a step, summed over the horizon to `SAFETY` accuracy, `START` times
    more steps. The gap is taken as at least `NOISE_MARGIN` tolerances (what each step may leave)."""
    constant = max(gap, NOISE_MARGIN * tolerance) / ((0.5 * h) ** (p + 1) * (2.0 ** (p + 1) - 2.0))
    wanted = SAFETY * accuracy / horizon
    return START * h * (constant / wanted) ** (1.0 / p)


class Controller:
    """Steps a Simulator interval by interval (`Simulator.dt`), each in whole steps whose size follows the
    estimated trajectory error, with a shadow Simulator at twice the step alongside (Richardson on the whole
    trajectory). `horizon` (s) is the time over which the accuracy is meant."""

    def __init__(self, sim, chosen: Plan) -> None:  # sim: the Simulator it steps (which imports this module)
        self.sim = sim
        self.plan = chosen
        self.interval = chosen.dt
        self.horizon = DEFAULT_HORIZON
        # the order of the steps actually taken: 2 where rows make the composed step fall back
        self.order = 2 if sim.model.limit_count else sim.order
        looser = 2.0**sim.order  # the shadow's error is 2^p the trajectory's: its tolerance the same share of it
        self.shadow = type(sim)(
            sim.model, chosen.dt, tolerance=sim.tolerance * looser, velocity_tolerance=sim.velocity_tolerance * looser,
            solver=sim.solver_name, max_iterations=sim.max_iterations, on_max_iterations=sim.on_max_iterations,
            order=sim.order, options=replace(sim.options, max_rotation=None),
        )  # fmt: skip
        """The same model at twice the step: the gap to it is (2^p - 1) times the trajectory's own error. Its joint
        tolerance is 2^p the trajectory's (the same share of its error: the iterations it saves are a tenth of the
        run's solves on the humanoid). Its steps are never split for a fast spin (a split step of 2h would be the
        trajectory's own); the trajectory's are, as asked, and a block in which they were is followed by steps as
        small as the split ones."""
        cpu = sim.model.device.is_cpu
        fields = ("body_x", "body_q", "body_v", "body_w")
        self._pairs = _views([(getattr(self.shadow._state, f), getattr(sim._state, f)) for f in fields]
                             + [(self.shadow.drive_integral, sim.drive_integral), (self.shadow._carry, sim._carry),
                                (self.shadow._carry_past, sim._carry_past)], cpu)  # fmt: skip
        """(shadow's array, trajectory's) of what `_sync` copies."""
        self._centres = _views([(sim._state.body_x, self.shadow._state.body_x)], cpu)[0]
        self.reset()

    def reset(self) -> None:
        """Start the estimate again from the present state (a new run, or a state set from outside)."""
        self.steps = 0  # per interval; 0: not yet chosen (`_pilot` at the next interval)
        self.estimate = 0.0  # m: the trajectory error estimated at the last block's end
        self._done = 0  # intervals of the present block taken
        self._debt = 0.0  # s^(p+1): what the blocks' h^p took above the aim (<= 0: below), times their time
        self._mean = 0.0  # s^(p+1): the sum of h^p times the time it was taken, since the start
        self._split = 1.0  # the most substeps a step of the present block was split into (a fast spin)
        self._spins = (0.0, 0.0)  # rad/s: the fastest turn of a body in the last block, and in the present one
        self._start = self._last = (0.0, 0.0)  # (s, m): the start, and the last block's end with the largest estimate
        self._least = 1  # the fewest steps an interval: raised where the shadow's steps were found costly (`COSTLY`)
        self._work = 0  # the trajectory's linear solves in the present block

    @property
    def step_size(self) -> float:
        """s: the step now taken."""
        return self.interval / max(self.steps, 1)

    # ------------------------------------------------------------------ stepping
    def step(self, n: int) -> StepStats:
        """n intervals; their stats combined as `Simulator.step` combines steps (the shadow's steps counted in),
        with the step size (the smallest used) and the trajectory error estimated now (m)."""
        sim = self.sim
        parts = []
        try:
            for _ in range(n):
                parts.append(self._interval())
        finally:
            sim.dt = self.interval
        if n == 1:
            return parts[0]
        stats = combined(parts)
        stats.error_estimate = self.estimate
        return stats

    def _block(self) -> int:
        """Intervals between two comparisons with the shadow (even, so that it takes whole steps of 2h): a
        `BLOCKS`th of the horizon, or two intervals."""
        return 2 * max(1, round(self.horizon / (2 * BLOCKS * self.interval)))

    def _interval(self) -> StepStats:
        """One interval of whole steps of the current size; at a block's end the shadow's steps over the block,
        the comparison, and the step size of the next block."""
        sim = self.sim
        if not self.steps:
            self._pilot()
        k, h = self.steps, self.step_size
        end = (round(sim.time / self.interval) + 1) * self.interval  # frames land on f * dt exactly
        if sim.dt != h:
            sim._set_step_size(h)
        parts = sim._steps(k, combine=True)
        stats = parts[0] if len(parts) == 1 else combined(parts)
        self._work += stats.linear_iterations
        if stats.substeps > k:  # split for a fast spin: the next block's steps are no larger than these
            self._split = max(self._split, stats.substeps / k)
        self._spins = (self._spins[0], max(self._spins[1], float(sim._spin)))
        sim.time = end
        sim._clock = (end, sim.step_count)  # the clock counts on from the frame time
        self._done += 1
        if self._done >= self._block():
            count = k * self._done // 2  # the shadow's steps of 2h over the block
            try:
                shadow = self._shadow_steps(2.0 * h, count, end)
            except SimulationError:  # steps of 2h fail where those of h hold: no estimate, smaller steps, again
                self._aim(k * SHRINK)
                self._sync()
                self._done, self._work = 0, 0
            else:
                whole = combined(shadow)  # its work counted in the stats
                stats.joint_iterations += whole.joint_iterations
                stats.velocity_iterations += whole.velocity_iterations
                stats.linear_iterations += whole.linear_iterations
                self._adopt(end, whole.substeps > count, whole.linear_iterations)
                self._done = 0
        stats.step_size = h
        stats.error_estimate = self.estimate
        return stats

    def _shadow_steps(self, h: float, n: int, end: float) -> list[StepStats]:
        """The shadow's n steps of h, under the loads the trajectory had (`set_external_forces`, drive targets)."""
        sim, shadow = self.sim, self.shadow
        if shadow._user_force is not sim._user_force or shadow._user_torque is not sim._user_torque:
            shadow._user_force, shadow._user_torque, shadow._active_forces = sim._user_force, sim._user_torque, None
        if sim.model.drive_count:
            wp.copy(shadow.drive_target, sim.drive_target)
            shadow._follow_elements()
        if shadow.dt != h:
            shadow._set_step_size(h)
        parts = shadow._steps(n, combine=True)
        shadow.time = end
        shadow._clock = (end, shadow.step_count)
        return parts

    def _gap(self) -> float:
        """m: the largest distance of a body centre from the shadow's."""
        d = np.subtract(*self._host_centres())
        return math.sqrt(np.einsum("ij,ij->i", d, d).max(initial=0.0))

    def _host_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) body centres (m) of the trajectory and of the shadow, as numpy arrays."""
        a, b = self._centres
        return (a, b) if isinstance(a, np.ndarray) else (a.numpy(), b.numpy())

    def _adopt(self, now: float, halved: bool, solves: int) -> None:
        """The trajectory error now, (gap to the shadow) / (2^p - 1), and the step of the next block.

        The trajectory error of a run of steps of h is G h^p (Richardson). The error so far, its largest g at t
        since the start, is taken to grow as t^m to the horizon's end T (m from the last two blocks: 1 where
        errors just add up, more where the motion amplifies them, in [1, `GROWTH_POWER`]), and G is that
        projection over the mean h^p of the steps so far; the next block's step is the h whose G h^p is
        `SAFETY` accuracy. Sized from the mean of all steps, not the last, a step never shrinks without end
        for an error that smaller steps now cannot take back. Where the fastest body turned faster in this block
        than in the last by a factor r, the next is taken to speed up as much again, and its step is r^((p+1)/p)
        smaller (a step's error grows as (spin h)^(p+1)): the error of a chain's whip is made within a block. It
        grows by at most GROWTH a block and shrinks by at most SHRINK. A block whose shadow steps were halved, or
        took more than `COSTLY` times the trajectory's solves, raises the fewest steps an interval (`_least`) to
        twice the block's for the rest of the run."""
        p = self.order
        self.estimate = self._gap() / (2.0**p - 1.0)
        h = self.step_size
        ours, self._work = self._work, 0
        if halved or solves > COSTLY * ours:  # the shadow's steps of the block: halved, their linear solves
            self._least = max(self._least, 2 * self.steps)
        (t0, _), (t1, g1) = self._start, self._last
        t = now - t0
        self._mean += h**p * self._done * self.interval
        g = max(self.estimate, g1)
        self._last = (now, g)
        end = max(self.horizon, t + self._block() * self.interval)
        power = _growth(g1, g, t / (t1 - t0)) if t1 > t0 else 1.0
        projected = g * (end / t) ** power
        mean = (self._mean / t) ** (1.0 / p)  # s: the mean step, as its h^p
        wanted = mean * (SAFETY * self.plan.accuracy / projected) ** (1.0 / p) if projected > 0.0 else math.inf
        spin, self._spins = self._spins, (self._spins[1], 0.0)
        if 0.0 < spin[0] < spin[1]:  # the motion sped up over the block: as much again in the next
            wanted *= (spin[0] / spin[1]) ** ((p + 1.0) / p)
        factor = min(GROWTH, max(1.0 / SHRINK, wanted / h))
        split, self._split = self._split, 1.0
        self._aim(self.steps * (max(split, 1.0 / factor) if split > 1.0 else 1.0 / factor))

    def _aim(self, steps: float) -> None:
        """The next block's steps an interval for `steps` wanted (a real number, at least `_least`): whole, so that
        frames land on their times, but blocks alternate between the whole numbers below and above it so that the
        mean h^p of the steps, which the trajectory error grows with, is the wanted step's (error diffusion:
        `_debt` carries what the blocks so far took above the aim, never more than nothing, and at most one
        block's credit below it). Rounding up alone leaves the error up to 2^p below the aim at one or two steps
        an interval (order 4 at dt against dt / 2: 16x, the tree of 127 bodies at 0.02 E)."""
        wanted = min(float(MAX_STEPS), max(float(self._least), steps))
        p, span = self.order, self._block() * self.interval
        aim = (self.interval / wanted) ** p
        k = max(1, math.floor(wanted))
        if k < wanted and self._debt + ((self.interval / k) ** p - aim) * span > 0.0:
            k += 1
        self._debt = max(-aim * span, self._debt + ((self.interval / k) ** p - aim) * span)
        self.steps = k

    def _pilot(self) -> None:
        """The first step size, from the start state: the local error of one step of the interval against two of
        half of it (step doubling, on the shadow), summed over the horizon to `SAFETY` accuracy; then the
        shadow starts from the trajectory's state."""
        sim, h = self.sim, self.interval
        self._sync()
        self._shadow_steps(h, 1, sim.time + h)
        coarse = self._host_centres()[1].copy()
        self._sync()
        self._shadow_steps(0.5 * h, 2, sim.time + h)
        gap = float(np.linalg.norm(coarse - self._host_centres()[1], axis=1).max(initial=0.0))
        self._aim(_pilot_steps(gap, self.order, h, sim.tolerance, self.plan.accuracy, self.horizon))
        self._sync()
        self._start = self._last = (sim.time, 0.0)
        self._done = 0

    def _sync(self) -> None:
        """The shadow at the trajectory's state, time, drives' integrals and carried right-hand sides (a start for
        its first iteration: `Simulator._set_step_size`), its frames made for the state."""
        sim, shadow = self.sim, self.shadow
        for dst, src in self._pairs:
            _copy(dst, src)
        shadow._update_frames()
        shadow._handout = sim._handout  # a velocity correction still due travels with the state (`Simulator.state`)
        shadow.time, shadow.step_count = sim.time, sim.step_count
        shadow._clock = (sim.time, sim.step_count)


def _growth(before: float, after: float, ratio: float) -> float:
    """The power m of an error that grew from `before` to `after` (m) as time grew `ratio` times (t^m), in
    [1, `GROWTH_POWER`]: 1 where errors just add up, more where the motion amplifies them."""
    if before <= 0.0 or after <= before:
        return 1.0
    return min(GROWTH_POWER, max(1.0, math.log(after / before) / math.log(ratio)))


def _views(pairs: list[tuple], cpu: bool) -> list[tuple]:
    """The arrays as they are copied: on a CPU numpy views, copied without a launch (~1 us against ~15 us)."""
    return [(a.numpy(), b.numpy()) for a, b in pairs] if cpu else pairs


def _copy(dst, src) -> None:
    if isinstance(dst, np.ndarray):
        np.copyto(dst, src)
    else:
        wp.copy(dst, src)
