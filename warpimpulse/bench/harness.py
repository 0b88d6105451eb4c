"""The benchmark's measurements: run time against error, for warpimpulse, MuJoCo and pinocchio on the same
scenes, and scaling with the number of bodies.

Users pick a simulator by how fast it reaches the accuracy they need, so every configuration (engine,
integrator or tolerance, step size) is measured twice, apart:
- an accuracy run (not timed): trajectory error at t = 2 s against a reference, energy drift over 10 s
  of free motion after the scene's forces stop, joint position error;
- timing runs: the same first 2 s, repeated after a warm-up run, nothing but steps in the timed loop;
  median time per step.

The reference is MuJoCo RK4 at h = 1/3000 in reduced coordinates, an independent implementation; it is
checked against itself at h = 1/6000 and against pinocchio (ABA, RK4) at h = 1/3000, and both residuals
printed. The peers, MuJoCo's Euler, implicitfast and RK4 and pinocchio's RK4, run the same scene, built by
`peers.mujoco` and `peers.pinocchio`. pinocchio is optional here: without it the cross-check is reported
as missing and skipped. Scaling points run in child processes under a time budget, so a size too slow or
too big is reported, not waited for.

This module measures and returns plain dicts (the JSON); `report` writes them up, `cli` is the command.
"""

from __future__ import annotations

import contextlib
import gc
import math
import os
import platform
import resource
import statistics
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import partial

import numpy as np

from .. import scenes
from ..builder import WORLD, SceneBuilder
from ..options import StepOptions
from ..simulator import SimulationError, Simulator
from ..steps import StepStats
from ..transforms import quat_rotate
from .peers.mujoco import INTEGRATORS as MUJOCO_INTEGRATORS
from .peers.mujoco import MujocoRunner, MujocoScene, mujoco_available
from .peers.pinocchio import PinocchioRunner, PinocchioScene, pinocchio_available
from .runner import Runner, StepFailed, advance

SWEEP_RATES = (30, 60, 120, 300)  # steps per second of ours and pinocchio: h = 1/30 ... 1/300
# MuJoCo's, from h = 1/10 to 1/1000 and fine enough that its front is not read between far-apart points.
MUJOCO_RATES = (10, 15, 20, 30, 40, 60, 80, 120, 160, 240, 320, 480, 640, 1000)
QUICK_MUJOCO_RATES = (10, 30, 100, 300, 1000)
SWEEP_TOLERANCES = (1e-2, 1e-4, 1e-6, 1e-8)
# Orders in time of ours: 2 (the paper's step) at every tolerance above; 4 and 6 (its compositions) at the
# tolerance that follows h and the order (`composition.default_tolerance`), since a looser one caps the order.
SWEEP_ORDERS = (2, 4, 6)
SWEEP_SCENES = ("double_pendulum", "tree31", "tree127", "chain50", "star127")
QUICK_RATES = (30, 60, 120)
QUICK_TOLERANCES = (1e-4, 1e-8)
QUICK_ORDERS = (2, 4)
QUICK_SCENES = ("double_pendulum", "tree31", "tree127")
REFERENCE_RATE, CHECK_RATE = 3000, 6000
ERROR_TIME = 2.0  # s: trajectory error is measured here
DRIFT_DURATION = 10.0  # s of conservative motion after the last force stops
SAMPLE_RATE = 30  # Hz: energy and joint-error samples (every round(rate / 30) steps; every step below 45)
SCALING_TREES = tuple(2**k - 1 for k in range(5, 17))  # 31 ... 65535 bodies
SCALING_CHAINS = (10, 100, 1000, 3000, 10000)
QUICK_SCALING_TREES = (31, 127, 511, 2047)
QUICK_SCALING_CHAINS = (10, 100, 500)
SCALING_RATE = 60
SCALING_TOLERANCE = 1e-6
SCALING_STEPS, SCALING_REPEATS = 20, 3  # timed blocks of steps per scaling point, after one warm-up block
SCALING_BUDGET, QUICK_SCALING_BUDGET = 300.0, 40.0  # s per scaling point, set-up included


# ------------------------------------------------------------------------------------------ scenes
def make_scene(name: str) -> SceneBuilder:
    """The sweep's scenes by name; `tree<N>` and `chain<N>` for any size (scaling)."""
    if name in scenes.SCENES:
        return scenes.SCENES[name]()
    if name.startswith("tree"):
        return scenes.binary_tree(int(name[4:]))
    if name.startswith("chain"):
        return scenes.chain(int(name[5:]))
    raise ValueError(f"unknown scene {name!r}")


def forces_end(builder: SceneBuilder) -> float:
    """When the last force stops (0 without forces): the conservative part of the run starts here."""
    ends = [f.until for f in builder.forces]
    if any(math.isinf(e) for e in ends):
        raise ValueError("a force never stops: energy drift needs conservative motion")
    return max(ends, default=0.0)


@dataclass
class Probe:
    """The points whose trajectories are compared (every centre of mass, every leaf tip) and the joints
    whose anchor gap is measured, all in body frames so any engine's poses give world positions."""

    bodies: np.ndarray
    local: np.ndarray
    gap_parent: np.ndarray  # joints with a point constraint: parent body (WORLD allowed)
    gap_parent_local: np.ndarray  # anchor in the parent frame (world frame for WORLD)
    gap_child: np.ndarray
    gap_child_local: np.ndarray

    @classmethod
    def from_builder(cls, builder: SceneBuilder) -> Probe:
        n = len(builder.bodies)
        has_child = np.zeros(n, dtype=bool)
        for j in builder.joints:
            if j.parent != WORLD:
                has_child[j.parent] = True
        bodies, local = list(range(n)), [np.zeros(3)] * n
        # A leaf's tip: its parent joint's anchor mirrored through the centre of mass (a capsule's far end).
        for j in builder.joints:
            if not has_child[j.child]:
                child = builder.bodies[j.child]
                bodies.append(j.child)
                local.append(-_to_body(child.position, child.orientation, j.anchor))
        gp, gpl, gc_, gcl = [], [], [], []
        for j in builder.joints:
            if j.kind not in ("ball", "revolute", "universal", "fixed"):
                continue
            gp.append(j.parent)
            if j.parent == WORLD:
                gpl.append(j.anchor)
            else:
                p = builder.bodies[j.parent]
                gpl.append(_to_body(p.position, p.orientation, j.anchor))
            c = builder.bodies[j.child]
            gc_.append(j.child)
            gcl.append(_to_body(c.position, c.orientation, j.anchor))
        as_arr = lambda rows: np.array(rows, dtype=np.float64).reshape(-1, 3)  # noqa: E731
        return cls(
            np.array(bodies), as_arr(local), np.array(gp, dtype=np.int64), as_arr(gpl),
            np.array(gc_, dtype=np.int64), as_arr(gcl),
        )  # fmt: skip

    def points(self, x: np.ndarray, q: np.ndarray) -> np.ndarray:
        return x[self.bodies] + quat_rotate(q[self.bodies], self.local)

    def anchor_gap(self, x: np.ndarray, q: np.ndarray) -> float:
        """Max distance between a joint's anchor on the parent and on the child, metres (point joints)."""
        if not len(self.gap_child):
            return 0.0
        world = (self.gap_parent == WORLD)[:, None]
        parent = self.gap_parent.clip(0)
        a = np.where(world, self.gap_parent_local, x[parent] + quat_rotate(q[parent], self.gap_parent_local))
        b = x[self.gap_child] + quat_rotate(q[self.gap_child], self.gap_child_local)
        return float(np.linalg.norm(a - b, axis=1).max())


def _to_body(position: np.ndarray, orientation: np.ndarray, point: np.ndarray) -> np.ndarray:
    inverse = orientation * np.array([-1.0, -1.0, -1.0, 1.0])
    return quat_rotate(inverse, point - position)


# ------------------------------------------------------------------------------------------ engines
class WarpimpulseRunner:
    """Our Simulator; a SimulationError (NaN, or no convergence in max_iterations) fails the configuration."""

    def __init__(
        self,
        builder: SceneBuilder | None,
        rate: int,
        tolerance: float | None,
        solver: str = "auto",
        model=None,
        order=2,
        **settings,
    ):
        """settings: more `Simulator` keyword arguments."""
        model = model if model is not None else builder.finalize("cpu")
        self.sim = Simulator(
            model, 1.0 / rate, tolerance=tolerance, solver=solver, order=order, **StepOptions.fold(settings)
        )
        self.joint_iterations = self.velocity_iterations = self.linear_iterations = 0
        self.max_joint_iterations = 0
        self.max_step_error = 0.0
        self.steps = 0

    def step(self) -> None:
        stats = self.run(1)
        self.max_joint_iterations = max(self.max_joint_iterations, stats.joint_iterations)
        self.max_step_error = max(self.max_step_error, stats.max_joint_error)

    def run(self, steps: int) -> StepStats:
        """`steps` steps in one step(n) call, their stats combined (`step` keeps the per-step maxima)."""
        try:
            stats = self.sim.step(steps)
        except SimulationError as e:
            raise StepFailed(str(e).split(";")[0]) from e
        self.steps += steps
        self.joint_iterations += stats.joint_iterations
        self.velocity_iterations += stats.velocity_iterations
        self.linear_iterations += stats.linear_iterations
        return stats

    def check(self) -> None:
        """SimulationError in step() already covers NaN and non-convergence."""

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        return self.sim.positions(), self.sim.orientations()

    def energy(self) -> tuple[float, float]:
        return self.sim.energy(), math.nan

    def iteration_stats(self) -> dict:
        n = max(self.steps, 1)
        return {
            "joint_iterations_mean": self.joint_iterations / n,
            "joint_iterations_max": self.max_joint_iterations,
            "velocity_iterations_mean": self.velocity_iterations / n,
            "linear_iterations_mean": self.linear_iterations / n,
        }


# ------------------------------------------------------------------------------------------ measuring
def accuracy_run(runner: Runner, rate: int, probe: Probe, duration: float) -> dict:
    """Step to `duration`, sampling energy and anchor gap at SAMPLE_RATE, tracked points at ERROR_TIME."""
    n_total = int(round(duration * rate))
    n_error = int(round(ERROR_TIME * rate))
    every = max(1, round(rate / SAMPLE_RATE))  # about SAMPLE_RATE samples a second at any rate
    e0, k0 = runner.energy()
    times, energy, kinetic, gaps = [0.0], [e0], [k0], [probe.anchor_gap(*runner.poses())]
    points = None
    out: dict = {"failed": None}
    try:
        for k in range(1, n_total + 1):
            runner.step()
            if k % every == 0 or k == n_error:
                runner.check()
                x, q = runner.poses()
                if not np.all(np.isfinite(x)):
                    raise StepFailed(f"non-finite positions at t = {k / rate:.4g} s")
                if k == n_error:
                    points = probe.points(x, q)
                if k % every == 0:
                    e, ke = runner.energy()
                    times.append(k / rate)
                    energy.append(e)
                    kinetic.append(ke)
                    gaps.append(probe.anchor_gap(x, q))
    except StepFailed as e:
        out["failed"] = str(e)
    out.update(points=points, times=np.array(times), energy=np.array(energy), kinetic=np.array(kinetic))
    out["anchor_gap"] = float(max(gaps))
    return out


TIMING = (  # how `time_steps` times a configuration, as the report states it
    f"Run time: the median over repeats of the first {ERROR_TIME:g} s from the scene's start, each engine's steps "
    "in one call where it has one (our `step(n)`, MuJoCo's `mj_step` with nstep), pinocchio's one step a call; "
    "the trajectory error is read from the final state of those very runs; the clock is the process's CPU time"
)


@dataclass
class Timed:
    """Seconds per step of each timed run, what `finish` read from each run's final state (its error, say),
    and why the runs stopped where they failed (then both lists are empty)."""

    per_step: list[float]
    finals: list
    failed: str | None = None


def time_steps(
    factory: Callable[[], Runner],
    rate: int,
    repeats: int,
    duration: float = ERROR_TIME,
    min_total: float = 0.5,
    finish: Callable[[Runner], object] | None = None,
) -> Timed:
    """Seconds per step for each repeat of the first `duration` seconds, from a fresh state each time, and
    `finish(runner)` of each timed run, called after its clock stopped: the error of the very run that is timed.

    The n steps are one call where the engine has one (`runner.advance`: our step(n), MuJoCo's mj_step with
    nstep, split where a force switches off), else one step() a step. One extra run first is the warm-up
    (kernels loaded, caches warm) and is discarded. Cheap runs are repeated until `min_total` seconds are timed
    (at most 100 repeats), so a short interruption by another process moves the median little. The clock is the
    process's CPU time (every thread): on a shared machine wall time counts other processes' time slices, the
    more the longer the run, which would favour the configurations that run shortest. Python's garbage
    collector is off inside the timed loop, which holds nothing but the steps. A run that fails (StepFailed from
    the engine or from `finish`) fails the configuration.
    """
    n = int(round(duration * rate))
    per_step: list[float] = []
    finals: list = []
    wanted = repeats
    gc.collect()
    while len(per_step) < wanted:
        runner = factory()
        gc.disable()
        try:
            start = time.process_time()
            advance(runner, n)
            elapsed = time.process_time() - start
        except StepFailed as e:
            return Timed([], [], str(e))
        finally:
            gc.enable()
        try:
            final = finish(runner) if finish is not None else None
        except StepFailed as e:
            return Timed([], [], str(e))
        per_step.append(elapsed / n)
        finals.append(final)
        if len(per_step) == 1:  # the warm-up: discard it, and size the repeats from it
            wanted = 1 + min(100, max(repeats, math.ceil(min_total / max(elapsed, 1e-9))))
    return Timed(per_step[1:], finals[1:])


def final_points(probe: Probe) -> Callable[[Runner], np.ndarray]:
    """`time_steps`' finish: the tracked points of a run's final state, after checking it did not diverge."""

    def points(runner: Runner) -> np.ndarray:
        runner.check()
        x, q = runner.poses()
        if not np.all(np.isfinite(x)):
            raise StepFailed("non-finite positions at the end of the timed run")
        return probe.points(x, q)

    return points


@dataclass
class Reference:
    points: np.ndarray
    energy_scale: float  # J: work done by the scene's forces, or the peak kinetic energy without forces
    self_check: float  # m: max distance of the tracked points, h = 1/3000 against 1/6000, at ERROR_TIME
    pinocchio_residual: float | None  # m: pinocchio RK4 at h = 1/3000 against it, at ERROR_TIME (None: absent)
    seconds: float


def reference(mscene, pscene, probe: Probe, duration: float, t_forces: float) -> Reference:
    """MuJoCo RK4 at 1/3000 over the whole run, checked against itself at 1/6000 and, where installed, against
    pinocchio's ABA with RK4 at 1/3000 (an independent implementation) over the first ERROR_TIME seconds.

    `mscene`: a `MujocoScene`; `pscene`: a `PinocchioScene`, or None without pinocchio."""
    start = time.perf_counter()
    ref = accuracy_run(MujocoRunner(mscene, "RK4", REFERENCE_RATE, energy=True), REFERENCE_RATE, probe, duration)
    check = accuracy_run(MujocoRunner(mscene, "RK4", CHECK_RATE, energy=True), CHECK_RATE, probe, ERROR_TIME)
    if ref["failed"] or check["failed"]:
        raise RuntimeError(f"the MuJoCo reference failed: {ref['failed'] or check['failed']}")
    if t_forces > 0.0:
        i = int(np.searchsorted(ref["times"], t_forces - 1e-9))
        scale = abs(ref["energy"][i] - ref["energy"][0])
    else:
        scale = float(ref["kinetic"].max())
    residual = float(np.linalg.norm(ref["points"] - check["points"], axis=1).max())
    cross = None
    if pscene is not None:
        pin = accuracy_run(PinocchioRunner(pscene, REFERENCE_RATE), REFERENCE_RATE, probe, ERROR_TIME)
        if pin["failed"]:
            raise RuntimeError(f"the pinocchio cross-check failed: {pin['failed']}")
        cross = float(np.linalg.norm(ref["points"] - pin["points"], axis=1).max())
    return Reference(ref["points"], scale, residual, cross, time.perf_counter() - start)


def summarize(acc: dict, ref: Reference, t_forces: float) -> dict:
    """Errors of one accuracy run against the reference (None where the run failed before measuring)."""
    row: dict = {"failed": acc["failed"], "joint_error_anchor_gap": acc["anchor_gap"]}
    if acc["points"] is not None:
        dist = np.linalg.norm(acc["points"] - ref.points, axis=1)
        row["trajectory_error"] = float(dist.max())
        row["trajectory_error_rms"] = float(np.sqrt(np.mean(dist * dist)))
    else:
        row["trajectory_error"] = row["trajectory_error_rms"] = None
    times, energy = acc["times"], acc["energy"]
    after = times >= t_forces - 1e-9
    if acc["failed"] is None and after.any():
        drift = (energy[after] - energy[after][0]) / ref.energy_scale
        row["energy_drift"] = float(np.abs(drift).max())
        row["energy_drift_final"] = float(drift[-1])
        row["energy_series"] = [[round(float(t), 6), float(d)] for t, d in zip(times[after], drift)]
    else:
        row["energy_drift"] = row["energy_drift_final"] = None
        row["energy_series"] = []
    return row


# ------------------------------------------------------------------------------------------ progress
class Progress:
    """A one-line progress bar on stderr, so stdout stays a clean markdown report."""

    def __init__(self, total: int, enabled: bool = True) -> None:
        self.total, self.done, self.enabled, self.start = max(total, 1), 0, enabled, time.perf_counter()

    def advance(self, label: str) -> None:
        self.done += 1
        if not self.enabled:
            return
        width = 30
        filled = int(width * self.done / self.total)
        elapsed = time.perf_counter() - self.start
        eta = elapsed / self.done * (self.total - self.done)
        bar = "#" * filled + "." * (width - filled)
        sys.stderr.write(f"\r[{bar}] {self.done}/{self.total} {elapsed:5.0f}s eta {eta:4.0f}s {label[:48]:<48}")
        if self.done >= self.total:
            sys.stderr.write("\n")
        sys.stderr.flush()


def quiet_warp() -> None:
    """No banner or module-load lines from Warp inside the report (Warp 1.19 logs them at INFO level)."""
    import warp as wp

    wp.config.quiet = True
    wp.config.log_level = wp.LOG_WARNING


def log(msg: str) -> None:
    sys.stderr.write(msg + "\n")
    sys.stderr.flush()


# ------------------------------------------------------------------------------------------ sweeps
def run_vs_error(
    scene_names: Iterable[str],
    rates: Iterable[int],
    tolerances: Iterable[float],
    repeats: int,
    solver: str = "auto",
    progress: bool = True,
    orders: Iterable[int] = (2,),
    mujoco_rates: Iterable[int] | None = None,
) -> dict:
    """The accuracy/time sweep of every scene, for every engine that is available; ours at order 2 for every
    tolerance, and at each other order of `orders` with the tolerance that order takes by default. MuJoCo runs
    at `mujoco_rates` (default `rates`), the others at `rates`.

    Each row's trajectory error is that of its timed runs (`time_steps`' finish; they run one call for all
    steps where the engine has one); "trajectory_error_stepwise" is the accuracy run's, one step a call, which
    also gives the energy drift and the anchor gap. A row that failed anywhere (the accuracy run's 10 s after
    the forces included) has no time, and the report lists it as excluded."""
    scene_names, rates, tolerances = list(scene_names), list(rates), list(tolerances)
    mujoco_rates = rates if mujoco_rates is None else list(mujoco_rates)
    mujoco_missing, pin_missing = mujoco_available(), pinocchio_available()
    if mujoco_missing:
        raise RuntimeError(f"the reference needs MuJoCo: {mujoco_missing}")
    if pin_missing:
        log(f"note: {pin_missing}; no pinocchio peer, no cross-check of the reference")
    configs = [("mujoco", integ, None, None) for integ in MUJOCO_INTEGRATORS]
    configs += [] if pin_missing else [("pinocchio", "RK4", None, None)]
    configs += [("warpimpulse", solver, tol, 2) for tol in tolerances]
    configs += [("warpimpulse", solver, None, order) for order in orders if order != 2]
    per_scene = sum(len(mujoco_rates if c[0] == "mujoco" else rates) for c in configs)
    bar = Progress(len(scene_names) * (per_scene + 1), progress)
    rows, refs = [], {}
    for name in scene_names:
        builder = make_scene(name)
        probe = Probe.from_builder(builder)
        t_forces = forces_end(builder)
        duration = t_forces + DRIFT_DURATION
        mscene = MujocoScene.from_builder(builder, 1.0 / REFERENCE_RATE)
        pscene = None if pin_missing else PinocchioScene.from_builder(builder)
        ref = reference(mscene, pscene, probe, duration, t_forces)
        refs[name] = {
            "rate": REFERENCE_RATE, "check_rate": CHECK_RATE, "self_check_residual": ref.self_check,
            "energy_scale": ref.energy_scale, "seconds": ref.seconds, "bodies": len(builder.bodies),
            "tracked_points": len(probe.bodies), "forces_end": t_forces, "duration": duration,
            "pinocchio_residual": ref.pinocchio_residual,
        }  # fmt: skip
        log(f"\n{name}: reference MuJoCo RK4 h=1/{REFERENCE_RATE} vs 1/{CHECK_RATE}: residual {ref.self_check:.3g} m"
            + ("" if ref.pinocchio_residual is None
               else f"; vs pinocchio RK4 h=1/{REFERENCE_RATE}: residual {ref.pinocchio_residual:.3g} m"))  # fmt: skip
        bar.advance(f"{name} reference")
        model = builder.finalize("cpu")
        finish = final_points(probe)
        for engine, variant, tol, order in configs:
            for rate in mujoco_rates if engine == "mujoco" else rates:
                if engine == "mujoco":
                    factory = partial(MujocoRunner, mscene, variant, rate)
                    runner = MujocoRunner(mscene, variant, rate, energy=True)
                elif engine == "pinocchio":
                    factory = partial(PinocchioRunner, pscene, rate)
                    runner = factory()
                else:
                    factory = partial(WarpimpulseRunner, builder, rate, tol, solver, model, order)
                    runner = factory()
                acc = accuracy_run(runner, rate, probe, duration)
                row = {"scene": name, "engine": engine, "variant": variant, "rate": rate, "h": 1.0 / rate,
                       "tolerance": tol, "order": order}  # fmt: skip
                row.update(summarize(acc, ref, t_forces))
                if engine == "warpimpulse":
                    row["tolerance"] = runner.sim.tolerance  # the order's own where none was given
                    row["joint_error_internal_max"] = runner.max_step_error
                    row.update(runner.iteration_stats())
                row["trajectory_error_stepwise"] = row.pop("trajectory_error")
                row["trajectory_error"] = None
                timed = Timed([], []) if acc["failed"] else time_steps(factory, rate, repeats, finish=finish)
                if timed.failed:
                    row["failed"] = f"timed run: {timed.failed}"
                elif timed.finals:
                    errors = [float(np.linalg.norm(p - ref.points, axis=1).max()) for p in timed.finals]
                    row["trajectory_error"], row["trajectory_error_spread"] = max(errors), max(errors) - min(errors)
                row["error_source"] = "timed run"
                row["time_per_step_runs"] = timed.per_step
                row["time_per_step"] = statistics.median(timed.per_step) if timed.per_step else None
                rows.append(row)
                bar.advance(f"{name} {engine} {variant} 1/{rate}" + (f" tol {tol:g}" if tol else "")
                            + (f" order {order}" if order not in (None, 2) else ""))  # fmt: skip
    missing = {"mujoco": mujoco_missing, "pinocchio": pin_missing}
    return {"references": refs, "runs": rows, "missing": missing, "timing": TIMING}


def scaling(
    trees: Iterable[int],
    chains: Iterable[int],
    steps: int = 20,
    repeats: int = 3,
    budget_s: float = 120.0,
    progress: bool = True,
) -> list[dict]:
    """Time per step against body count (h = 1/60; ours at tolerance 1e-6; MuJoCo implicitfast and RK4).

    Each point runs in a child process stopped at `budget_s` seconds (set-up plus timing), so a size that
    is too slow, or too big for memory, is reported instead of hanging the run. A size whose projected
    cost already exceeds the budget is skipped without trying, with the projection as the reason.
    """
    families = [("tree", n) for n in trees] + [("chain", n) for n in chains]
    engines = [("warpimpulse", "auto")]
    if mujoco_available() is None:
        engines += [("mujoco", "implicitfast"), ("mujoco", "RK4")]
    bar = Progress(len(families) * len(engines), progress)
    rows: list[dict] = []
    history: dict[tuple, list[dict]] = {}
    for family, n in families:
        plan = []
        for engine, variant in engines:
            row = {"family": family, "bodies": n, "engine": engine, "variant": variant, "rate": SCALING_RATE}
            row["skipped"] = over_budget(history.get((family, engine, variant), []), family, engine, n,
                                          steps * (repeats + 1), budget_s)  # fmt: skip
            plan.append(row)
        for row in plan:
            if row["skipped"] is None:
                point = partial(scaling_point, family, n, row["engine"], row["variant"], steps, repeats)
                row.update(isolated(point, budget_s))
                history.setdefault((family, row["engine"], row["variant"]), []).append(row)
            rows.append(row)
            bar.advance(f"{family}{n} {row['engine']} {row['variant']}" + (" skipped" if row["skipped"] else ""))
    return rows


# Growth exponents (cost ~ bodies^k) assumed before two sizes are measured: set-up, then per step. MuJoCo's
# chain has a dense mass matrix (per step ~ n^2) and its compiler solves with it once per body (~ n^3).
_GROWTH = {("chain", "mujoco"): (3.0, 2.0)}
_PROJECT_FROM_S = 0.5  # below this a cost is mostly fixed overhead and says nothing about growth


def over_budget(done: list[dict], family: str, engine: str, n: int, steps: int, budget_s: float) -> str | None:
    """Why size `n` is not tried (None: try it), from the smaller sizes already measured for this engine.

    Only costs big enough to grow are projected; the child's hard stop at the budget covers the rest.
    """
    if not done:
        return None
    last = done[-1]
    if last.get("over_budget"):
        return f"a smaller size ({last['bodies']}) already ran past the budget"
    if last.get("time_per_step") is None:
        return None  # failed for another reason: the next size may run
    growth = dict(zip(("setup", "steps"), _GROWTH.get((family, engine), (1.0, 1.0))))
    cost = {"setup": lambda r: r["setup_s"], "steps": lambda r: steps * r["time_per_step"]}
    measured = [r for r in done if r.get("time_per_step") is not None]
    projected, exponents = 0.0, []
    for part, of in cost.items():
        if of(last) < _PROJECT_FROM_S:
            continue
        k = growth[part]
        if len(measured) >= 2 and of(measured[-2]) >= _PROJECT_FROM_S:
            a, b = measured[-2], measured[-1]
            k = min(3.0, max(1.0, math.log(of(b) / of(a)) / math.log(b["bodies"] / a["bodies"])))
        projected += of(last) * (n / last["bodies"]) ** k
        exponents.append(f"{part} ~n^{k:.1f}")
    if projected > budget_s:
        return f"projected {projected:.0f} s ({', '.join(exponents)}) > budget {budget_s:.0f} s"
    return None


def scaling_point(family: str, n: int, engine: str, variant: str, steps: int, repeats: int) -> dict:
    """One scaling measurement (run in a child process): set-up, from the scene builder call to an engine ready
    to step (ours: the Model, its symbolic analysis and the Simulator; MuJoCo: its compiler), with the peak
    memory of the process so far; then timed blocks of steps."""
    import warp as wp

    quiet_warp()
    with _stderr_to_devnull():  # Warp's native "no CUDA driver" line, once per child, would break the progress bar
        wp.init()
    mujoco_available()  # silences MuJoCo's warnings in this process too
    start = time.perf_counter()
    builder = scenes.binary_tree(n) if family == "tree" else scenes.chain(n)
    build_s = time.perf_counter() - start
    if engine == "mujoco":
        runner = MujocoRunner(MujocoScene.from_builder(builder, 1.0 / SCALING_RATE), variant, SCALING_RATE)
    else:
        model = builder.finalize("cpu")
        del builder  # done with, as when a script finalizes a scene function's builder: its memory is free again
        runner = WarpimpulseRunner(None, SCALING_RATE, SCALING_TOLERANCE, variant, model)
    row: dict = {
        "setup_s": time.perf_counter() - start,
        "scene_build_s": build_s,
        "setup_peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e9,
    }  # KiB on Linux
    try:
        runs = _time_block(runner, steps, repeats)
    except StepFailed as e:
        return row | {"failed": " ".join(str(e).split())[:200]}
    row.update(time_per_step_runs=runs, time_per_step=statistics.median(runs))
    row["time_per_body_step"] = row["time_per_step"] / n
    if isinstance(runner, WarpimpulseRunner):
        row.update(runner.iteration_stats())
    return row


@contextlib.contextmanager
def _stderr_to_devnull():
    saved = os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


def isolated(fn: Callable[[], dict], budget_s: float) -> dict:
    """fn() in a fresh process, stopped after `budget_s` seconds; its result, or why there is none."""
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")  # not fork: Warp and MuJoCo hold threads and caches
    receive, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(fn, send), daemon=True)
    proc.start()
    send.close()
    try:
        if receive.poll(budget_s):
            return receive.recv()
        return {"skipped": f"stopped at the budget of {budget_s:.0f} s", "over_budget": True}
    except EOFError:
        proc.join()
        return {"failed": f"the measuring process died (exit code {proc.exitcode}; out of memory?)"}
    finally:
        if proc.is_alive():
            proc.kill()
        proc.join()


def _child(fn: Callable[[], dict], send) -> None:
    try:
        result = fn()
    except Exception as e:  # any failure of the engine is a result to report
        result = {"failed": f"{type(e).__name__}: {' '.join(str(e).split())[:200]}"}
    send.send(result)
    send.close()


def _time_block(runner: Runner, steps: int, repeats: int) -> list[float]:
    """Seconds per step of `repeats` timed blocks of `steps` steps, after `steps` warm-up steps."""
    for _ in range(steps):
        runner.step()
    runs = []
    for _ in range(repeats):
        gc.collect()
        gc.disable()
        try:
            start = time.perf_counter()
            for _ in range(steps):
                runner.step()
            runs.append((time.perf_counter() - start) / steps)
        finally:
            gc.enable()
    runner.check()
    return runs


def metadata(argv: list[str]) -> dict:
    versions = {"python": platform.python_version(), "numpy": np.__version__}
    for module in ("warp", "mujoco", "pinocchio"):
        try:
            versions[module] = __import__(module).__version__
        except ImportError:
            versions[module] = None
    return {
        "command": "warpimpulse bench " + " ".join(argv),
        "machine": f"{platform.processor() or platform.machine()}, {_cpu_count()} cores, {platform.system()}",
        "versions": ", ".join(f"{k} {v}" for k, v in versions.items() if v),
        "date": time.strftime("%Y-%m-%d %H:%M"),
    }


def _cpu_count() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


# ------------------------------------------------------------------------------------------ entry point
