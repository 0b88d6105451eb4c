"""Benchmark harness: run time against error, for warpimpulse, MuJoCo and pinocchio on the same scenes.

Users pick a simulator by how fast it reaches the accuracy they need, so every configuration (engine,
integrator or tolerance, step size) is measured twice, apart:
- an accuracy run (not timed): trajectory error at t = 2 s against a reference, energy drift over 10 s
  of free motion after the scene's forces stop, joint position error;
- timing runs: the same first 2 s, repeated after a warm-up run, nothing but steps in the timed loop;
  median time per step.

The reference is MuJoCo RK4 at h = 1/3000 in reduced coordinates, an independent implementation; it is
checked against itself at h = 1/6000 and against pinocchio (ABA, RK4) at h = 1/3000, and both residuals
printed. The peers, MuJoCo's Euler, implicitfast and RK4 and pinocchio's RK4, run the same scene, built by
`warpimpulse.mjcf` and `warpimpulse.pinocchio_peer`. Peers are optional: a missing one is reported and
skipped. Scaling points run in child processes under a time budget, so a size too slow or too big is
reported, not waited for.

Entry point: `main(argv)`, as `warpimpulse bench` and `python -m warpimpulse.benchmark`;
`benchmarks/run_vs_error.py` and `benchmarks/scaling.py` call it with one half switched off.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import math
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from . import scenes
from .builder import WORLD, SceneBuilder
from .transforms import quat_rotate

SWEEP_RATES = (30, 60, 120, 300)  # steps per second: h = 1/30 ... 1/300
SWEEP_TOLERANCES = (1e-2, 1e-4, 1e-6, 1e-8)
SWEEP_SCENES = ("double_pendulum", "tree31", "tree127", "chain50", "star127")
QUICK_RATES = (30, 60, 120)
QUICK_TOLERANCES = (1e-4, 1e-8)
QUICK_SCENES = ("double_pendulum", "tree31", "tree127")
MUJOCO_INTEGRATORS = ("Euler", "implicitfast", "RK4")
REFERENCE_RATE, CHECK_RATE = 3000, 6000
ERROR_TIME = 2.0  # s: trajectory error is measured here
DRIFT_DURATION = 10.0  # s of conservative motion after the last force stops
SAMPLE_RATE = 30  # Hz: energy and joint-error samples (divides every rate of the sweep)
SCALING_TREES = tuple(2**k - 1 for k in range(5, 17))  # 31 ... 65535 bodies
SCALING_CHAINS = (10, 100, 1000, 3000, 10000)
QUICK_SCALING_TREES = (31, 127, 511, 2047)
QUICK_SCALING_CHAINS = (10, 100, 500)
SCALING_RATE = 60
SCALING_TOLERANCE = 1e-6
SCALING_STEPS, SCALING_REPEATS = 20, 3  # timed blocks of steps per scaling point, after one warm-up block
SCALING_BUDGET, QUICK_SCALING_BUDGET = 300.0, 40.0  # s per scaling point, set-up included
BAR_SCENE = "tree127"


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
class StepFailed(RuntimeError):
    """The engine diverged or gave up (did not converge); the configuration is reported as failed."""


class MujocoRunner:
    """MuJoCo on the exported scene. Forces are switched off by step count, so the timed loop holds only
    mj_step and a comparison, as fair to MuJoCo as our loop is to us."""

    def __init__(self, mscene, integrator: str, rate: int, energy: bool = False) -> None:
        import mujoco

        self._mj = mujoco
        self.scene = mscene
        mscene.set_integrator(integrator, 1.0 / rate)
        mscene.set_energy(energy)
        self.model = mscene.model
        self.data = mscene.make_data()  # forces of the first step applied
        self.steps = 0
        self.rate = rate
        # Steps at which some force switches off (the first step starting at or after its `until`).
        switches = {math.ceil(f.until * rate - 1e-6) for f in mscene.builder.forces}
        self._switches = sorted(switches, reverse=True)
        self._next_switch = self._switches.pop() if self._switches else -1

    def step(self) -> None:
        if self.steps == self._next_switch:
            self.scene.apply_forces(self.data)
            self._next_switch = self._switches.pop() if self._switches else -1
        self._mj.mj_step(self.model, self.data)
        self.steps += 1

    def check(self) -> None:
        if self.scene.diverged(self.data):
            raise StepFailed(f"MuJoCo diverged (bad qacc) before t = {self.steps / self.rate:.4g} s")

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        return self.scene.positions(self.data), self.scene.orientations(self.data)

    def energy(self) -> tuple[float, float]:
        """(total, kinetic) at the current state; mj_forward recomputes it without changing the state."""
        self._mj.mj_forward(self.model, self.data)
        return float(self.data.energy[0] + self.data.energy[1]), float(self.data.energy[1])


class WarpimpulseRunner:
    """Our Simulator; a SimulationError (NaN, or no convergence in max_iterations) fails the configuration."""

    def __init__(self, builder: SceneBuilder, rate: int, tolerance: float, solver: str = "auto", model=None):
        from .simulator import Simulator

        self.sim = Simulator(
            model if model is not None else builder.finalize("cpu"), 1.0 / rate, tolerance=tolerance, solver=solver
        )
        self.joint_iterations = self.velocity_iterations = self.linear_iterations = 0
        self.max_joint_iterations = 0
        self.max_step_error = 0.0
        self.steps = 0

    def step(self) -> None:
        from .simulator import SimulationError

        try:
            stats = self.sim.step()
        except SimulationError as e:
            raise StepFailed(str(e).split(";")[0]) from e
        self.steps += 1
        self.joint_iterations += stats.joint_iterations
        self.velocity_iterations += stats.velocity_iterations
        self.linear_iterations += stats.linear_iterations
        self.max_joint_iterations = max(self.max_joint_iterations, stats.joint_iterations)
        self.max_step_error = max(self.max_step_error, stats.max_joint_error)

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


def warpimpulse_available() -> str | None:
    """None when our Simulator imports, else why not (the harness then runs the peers alone)."""
    try:
        from .simulator import Simulator  # noqa: F401
    except ImportError as e:
        return f"warpimpulse Simulator not importable ({e})"
    return None


def mujoco_available() -> str | None:
    try:
        import mujoco
    except ImportError:
        return "mujoco is not installed (pip install -e .[bench])"
    # MuJoCo would print every instability warning and append it to MUJOCO_LOG.TXT in the working
    # directory; the harness reads the warning counters instead.
    mujoco.set_mju_user_warning(lambda msg: None)
    return None


def pinocchio_available() -> str | None:
    from .pinocchio_peer import pinocchio_available

    return pinocchio_available()


# ------------------------------------------------------------------------------------------ measuring
def accuracy_run(runner, rate: int, probe: Probe, duration: float) -> dict:
    """Step to `duration`, sampling energy and anchor gap at SAMPLE_RATE, tracked points at ERROR_TIME."""
    n_total = int(round(duration * rate))
    n_error = int(round(ERROR_TIME * rate))
    every = rate // SAMPLE_RATE
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


def time_steps(
    factory: Callable[[], object], rate: int, repeats: int, duration: float = ERROR_TIME, min_total: float = 0.5
) -> list[float]:
    """Seconds per step for each repeat of the first `duration` seconds, from a fresh state each time.

    One extra run first is the warm-up (kernels loaded, caches warm) and is discarded. Cheap runs are
    repeated until `min_total` seconds are timed (at most 100 repeats), so a short interruption by another
    process moves the median little. Python's garbage collector is off inside the timed loop, which holds
    nothing but step().
    """
    n = int(round(duration * rate))
    per_step: list[float] = []
    wanted = repeats
    gc.collect()
    while len(per_step) < wanted:
        runner = factory()
        gc.disable()
        try:
            start = time.perf_counter()
            for _ in range(n):
                runner.step()
            elapsed = time.perf_counter() - start
        except StepFailed:
            return []
        finally:
            gc.enable()
        per_step.append(elapsed / n)
        if len(per_step) == 1:  # the warm-up: discard it, and size the repeats from it
            wanted = 1 + min(100, max(repeats, math.ceil(min_total / max(elapsed, 1e-9))))
    return per_step[1:]


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
        from .pinocchio_peer import PinocchioRunner

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
) -> dict:
    """The accuracy/time sweep of every scene, for every engine that is available."""
    from .mjcf import MujocoScene
    from .pinocchio_peer import PinocchioRunner, PinocchioScene

    scene_names, rates, tolerances = list(scene_names), list(rates), list(tolerances)
    ours_missing, mujoco_missing, pin_missing = warpimpulse_available(), mujoco_available(), pinocchio_available()
    if mujoco_missing:
        raise RuntimeError(f"the reference needs MuJoCo: {mujoco_missing}")
    if ours_missing:
        log(f"note: {ours_missing}; measuring the peers only")
    if pin_missing:
        log(f"note: {pin_missing}; no pinocchio peer, no cross-check of the reference")
    configs = [("mujoco", integ, None) for integ in MUJOCO_INTEGRATORS]
    configs += [] if pin_missing else [("pinocchio", "RK4", None)]
    configs += [] if ours_missing else [("warpimpulse", solver, tol) for tol in tolerances]
    per_scene = len(rates) * len(configs)
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
        model = None if ours_missing else builder.finalize("cpu")
        for engine, variant, tol in configs:
            for rate in rates:
                if engine == "mujoco":
                    factory = partial(MujocoRunner, mscene, variant, rate)
                    runner = MujocoRunner(mscene, variant, rate, energy=True)
                elif engine == "pinocchio":
                    factory = partial(PinocchioRunner, pscene, rate)
                    runner = factory()
                else:
                    factory = partial(WarpimpulseRunner, builder, rate, tol, solver, model)
                    runner = WarpimpulseRunner(builder, rate, tol, solver, model)
                acc = accuracy_run(runner, rate, probe, duration)
                row = {"scene": name, "engine": engine, "variant": variant, "rate": rate, "h": 1.0 / rate,
                       "tolerance": tol}  # fmt: skip
                row.update(summarize(acc, ref, t_forces))
                if engine == "warpimpulse":
                    row["joint_error_internal_max"] = runner.max_step_error
                    row.update(runner.iteration_stats())
                times = time_steps(factory, rate, repeats) if acc["failed"] is None else []
                row["time_per_step_runs"] = times
                row["time_per_step"] = statistics.median(times) if times else None
                rows.append(row)
                bar.advance(f"{name} {engine} {variant} 1/{rate}" + (f" tol {tol:g}" if tol else ""))
    missing = {"warpimpulse": ours_missing, "mujoco": mujoco_missing, "pinocchio": pin_missing}
    return {"references": refs, "runs": rows, "missing": missing}


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
    ours_missing, mujoco_missing = warpimpulse_available(), mujoco_available()
    families = [("tree", n) for n in trees] + [("chain", n) for n in chains]
    engines = ([] if ours_missing else [("warpimpulse", "auto")]) + (
        [] if mujoco_missing else [("mujoco", "implicitfast"), ("mujoco", "RK4")]
    )
    bar = Progress(len(families) * len(engines), progress)
    rows: list[dict] = []
    history: dict[tuple, list[dict]] = {}
    for family, n in families:
        plan = []
        for engine, variant in engines:
            row = {"family": family, "bodies": n, "engine": engine, "variant": variant, "rate": SCALING_RATE}
            row["skipped"] = _over_budget(history.get((family, engine, variant), []), family, engine, n,
                                          steps * (repeats + 1), budget_s)  # fmt: skip
            plan.append(row)
        builder, build_s = None, None
        for row in plan:
            if row["skipped"] is None:
                if builder is None:
                    start = time.perf_counter()
                    builder = scenes.binary_tree(n) if family == "tree" else scenes.chain(n)
                    build_s = time.perf_counter() - start
                point = partial(scaling_point, builder, row["engine"], row["variant"], steps, repeats)
                row.update(_isolated(point, budget_s), scene_build_s=build_s)
                history.setdefault((family, row["engine"], row["variant"]), []).append(row)
            rows.append(row)
            bar.advance(f"{family}{n} {row['engine']} {row['variant']}" + (" skipped" if row["skipped"] else ""))
    return rows


# Growth exponents (cost ~ bodies^k) assumed before two sizes are measured: set-up, then per step. MuJoCo's
# chain has a dense mass matrix (per step ~ n^2) and its compiler solves with it once per body (~ n^3).
_GROWTH = {("chain", "mujoco"): (3.0, 2.0)}
_PROJECT_FROM_S = 0.5  # below this a cost is mostly fixed overhead and says nothing about growth


def _over_budget(done: list[dict], family: str, engine: str, n: int, steps: int, budget_s: float) -> str | None:
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


def scaling_point(builder: SceneBuilder, engine: str, variant: str, steps: int, repeats: int) -> dict:
    """One scaling measurement (run in a child process): set-up time, then timed blocks of steps."""
    import warp as wp

    from .mjcf import MujocoScene

    quiet_warp()
    with _stderr_to_devnull():  # Warp's native "no CUDA driver" line, once per child, would break the progress bar
        wp.init()
    mujoco_available()  # silences MuJoCo's warnings in this process too
    n = len(builder.bodies)
    start = time.perf_counter()
    if engine == "mujoco":
        runner = MujocoRunner(MujocoScene.from_builder(builder, 1.0 / SCALING_RATE), variant, SCALING_RATE)
    else:
        runner = WarpimpulseRunner(builder, SCALING_RATE, SCALING_TOLERANCE, variant, builder.finalize("cpu"))
    row: dict = {"setup_s": time.perf_counter() - start}
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


def _isolated(fn: Callable[[], dict], budget_s: float) -> dict:
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


def _time_block(runner, steps: int, repeats: int) -> list[float]:
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


# ------------------------------------------------------------------------------------------ the bar
def speed_ratios(runs: list[dict], scene: str = BAR_SCENE) -> list[dict]:
    """For each of our configurations on `scene`: the cheapest MuJoCo configuration whose trajectory error is
    at most ours, and the ratio of its cost to ours (> 1: we are faster).

    Cost is run time per simulated second (time per step / h), not per step: configurations with different
    step sizes reach the same simulated time in different numbers of steps.
    """
    ok = [r for r in runs if r["scene"] == scene and r["failed"] is None and r["time_per_step"] is not None]
    ours = [r for r in ok if r["engine"] == "warpimpulse"]
    peers = [r for r in ok if r["engine"] == "mujoco" and r["trajectory_error"] is not None]
    out = []
    for r in sorted(ours, key=lambda r: r["trajectory_error"]):
        match = [p for p in peers if p["trajectory_error"] <= r["trajectory_error"]]
        best = min(match, key=lambda p: p["time_per_step"] * p["rate"]) if match else None
        cost = r["time_per_step"] * r["rate"]
        out.append({
            "rate": r["rate"], "tolerance": r["tolerance"], "trajectory_error": r["trajectory_error"],
            "time_per_step": r["time_per_step"], "time_per_second": cost,
            "mujoco": None if best is None else f"{best['variant']} 1/{best['rate']}",
            "mujoco_error": None if best is None else best["trajectory_error"],
            "mujoco_time_per_step": None if best is None else best["time_per_step"],
            "mujoco_time_per_second": None if best is None else best["time_per_step"] * best["rate"],
            "ratio": None if best is None else best["time_per_step"] * best["rate"] / cost,
        })  # fmt: skip
    return out


# ------------------------------------------------------------------------------------------ reports
def _num(value, fmt: str = ".3g") -> str:
    return "—" if value is None else format(value, fmt)


def _us(seconds) -> str:
    return "—" if seconds is None else f"{seconds * 1e6:.1f}"


def markdown(results: dict) -> str:
    """The full report (RESULTS.md): references, one table per scene, where we win and lose, the tree127 bar,
    scaling."""
    lines = ["# warpimpulse benchmark", ""]
    if results.get("paper_tables"):
        lines += paper_markdown(results["paper_tables"])
    sweep, scale = results.get("run_vs_error"), results.get("scaling")
    if sweep:
        lines += ["## Run time against error", "", *_provenance(sweep),
                  f"Reference: MuJoCo RK4 at h = 1/{REFERENCE_RATE}, checked against itself at h = 1/{CHECK_RATE} and "
                  f"against pinocchio (ABA, RK4) at h = 1/{REFERENCE_RATE}. Trajectory error: max distance at "
                  f"t = {ERROR_TIME:g} s over every centre of mass and leaf tip. Energy drift: max |E(t) - E(t_f)| "
                  f"over {DRIFT_DURATION:g} s after the forces stop (t_f), divided by the work the forces did (trees) "
                  "or the peak kinetic energy (no forces). Joint error: max distance between a point joint's two "
                  "anchors over the run, from body poses, for every engine (reduced coordinates keep it at "
                  "round-off); ours also reports its own max joint error (m or rad) after each step. Time: median "
                  f"over repeats of the mean time per step over the first {ERROR_TIME:g} s, after a warm-up run. "
                  "pinocchio's RK4 is stepped from Python (four ABA calls a step), so its small scenes time the "
                  "Python loop more than pinocchio.", "",
                  *summary_markdown(sweep)]  # fmt: skip
        for name, ref in sweep["references"].items():
            lines += [f"### {name}", "", f"Energy scale {ref['energy_scale']:.4g} J.", "",
                      "| engine | variant | h | tolerance | µs/step | trajectory error (m) | energy drift | "
                      "anchor gap (m) | our joint error | joint it/step | note |",
                      "|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
            for r in (r for r in sweep["runs"] if r["scene"] == name):
                lines.append(
                    f"| {r['engine']} | {r['variant']} | 1/{r['rate']} | {_num(r['tolerance'], 'g')} | "
                    f"{_us(r['time_per_step'])} | {_num(r['trajectory_error'])} | {_num(r['energy_drift'])} | "
                    f"{_num(r['joint_error_anchor_gap'])} | {_num(r.get('joint_error_internal_max'))} | "
                    f"{_num(r.get('joint_iterations_mean'), '.2f')} | {(r['failed'] or '')[:60]} |"
                )
            lines.append("")
        lines += bar_markdown(sweep["runs"])
    if scale:
        lines += scaling_markdown(scale)
    return "\n".join(lines) + "\n"


def paper_markdown(tables: dict, level: str = "##") -> list[str]:
    """The method paper's Tables 1-3 and its star beside ours, from `benchmarks/paper_tables.py`'s JSON."""
    tolerances = sorted({r["tolerance"] for r in tables["rows"]}, reverse=True)
    sizes = sorted({int(r["scene"][4:]) for r in tables["rows"]})
    paper = tables["paper"]

    def cell(n: int, solver: str, tol: float) -> dict:
        return next(
            r for r in tables["rows"] if r["scene"] == f"tree{n}" and r["solver"] == solver and r["tolerance"] == tol
        )

    machine = tables["machine"]
    lines = [
        f"{level} The paper's tables",
        "",
        f"`python benchmarks/paper_tables.py` on {machine['processor']} (Python {machine['python']}, Warp "
        f"{machine['warp']}), h = 1/{round(1 / tables['dt'])} s, median time per step over "
        f"{tables['rows'][0]['steps']} steps; the paper's figures are from a Pentium 4 at 3.4 GHz.",
    ]
    if 127 in sizes and 1e-6 in tolerances:  # Table 1 is the 127-body tree at 1e-6
        header = "| | paper without SLE | ours without SLE | paper with SLE | ours with SLE |"
        lines += ["", "Table 1: the 127-body tree, tolerance 1e-6.", "", header, "|---|---:|---:|---:|---:|"]
        it, ch = cell(127, "iterative", 1e-6), cell(127, "cholesky", 1e-6)
        p_it, p_ch = paper["table1"]["iterative"], paper["table1"]["cholesky"]
        table1 = (
            ("time per step (ms)", "ms", "median_ms"),
            ("joint-correction iterations", "jc", "joint_iterations"),
            ("velocity-correction iterations", "vc", "velocity_iterations"),
        )
        for label, key, ours in table1:
            digits = 3 if key == "ms" else 2
            lines.append(f"| {label} | {p_it[key]} | {it[ours]:.{digits}f} | {p_ch[key]} | {ch[ours]:.{digits}f} |")
    for title, solver, figures in (
        ("Table 3: with the system", "cholesky", paper["with_sle"]),
        ("Table 2: without the system", "iterative", paper["without_sle"]),
    ):
        lines += [
            "",
            f"{title} (ms per step, paper / ours, mean joint iterations in brackets).",
            "",
            "| | " + " | ".join(f"{t:g}" for t in tolerances) + " |",
            "|---|" + "---:|" * len(tolerances),
        ]
        for n in sizes:
            ref = figures.get(str(n), figures.get(n))
            cells = [
                f"{'—' if ref is None else ref[k]} / {cell(n, solver, t)['median_ms']:.3f} "
                f"({cell(n, solver, t)['joint_iterations']:.1f})"
                for k, t in enumerate(tolerances)
            ]
            lines.append(f"| tree {n} | " + " | ".join(cells) + " |")
    star = {r["solver"]: r for r in tables["star"]}
    s_it, s_ch = star["iterative"], star["cholesky"]
    lines += [
        "",
        f"The star of 127 (every joint on the root), tolerance {s_ch['tolerance']:g}: "
        f"{s_ch['median_ms']:.3f} ms "
        f"a step with the system against {s_it['median_ms']:.3f} ms without "
        f"({s_it['median_ms'] / s_ch['median_ms']:.1f}x; the paper reports almost 80x).",
        "",
    ]
    return lines


def _provenance(section: dict) -> list[str]:
    """Which command measured a section, where and when; which peers were missing."""
    lines = []
    meta = section.get("meta")
    if meta:
        quick = " (the reduced `--quick` sweep)" if "--quick" in meta["command"].split() else ""
        where = f"{meta['machine']}, {meta['date']} ({meta['versions']})"
        lines += [f"Measured with `{meta['command']}`{quick} on {where}.", ""]
    missing = [f"> Not measured: {why}" for why in filter(None, section.get("missing", {}).values())]
    return lines + (missing + [""] if missing else [])


def summary_markdown(sweep: dict, level: str = "##") -> list[str]:
    """Per scene: how far the references agree, and in how many of our configurations we beat MuJoCo."""
    lines = [f"{level} Where we win and lose", "",
             "Per scene, each of our configurations (h, tolerance) against the cheapest MuJoCo configuration "
             "(integrator, h) whose trajectory error is at most ours; ratio = its run time per simulated second "
             "over ours (> 1: we are faster).", "",
             "| scene | bodies | reference self-check (m) | pinocchio vs reference (m) | we are faster | "
             "best ratio | worst ratio |", "|---|---|---|---|---|---|---|"]  # fmt: skip
    for name, ref in sweep["references"].items():
        ratios = speed_ratios(sweep["runs"], name)
        wins = [r for r in ratios if r["ratio"] is None or r["ratio"] > 1.0]
        known = [r for r in ratios if r["ratio"] is not None]
        best = max(known, key=lambda r: r["ratio"], default=None)
        worst = min(known, key=lambda r: r["ratio"], default=None)
        lines.append(
            f"| {name} | {ref['bodies']} | {ref['self_check_residual']:.2e} | {_num(ref.get('pinocchio_residual'))} "
            f"| {len(wins)} of {len(ratios)} | {_ratio_cell(best)} | {_ratio_cell(worst)} |"
        )
    return lines + [""]


def _ratio_cell(r: dict | None) -> str:
    return "—" if r is None else f"{r['ratio']:.3g} (1/{r['rate']}, tol {r['tolerance']:g} vs {r['mujoco']})"


def bar_markdown(runs: list[dict], scene: str = BAR_SCENE, level: str = "##") -> list[str]:
    if not any(r["scene"] == scene for r in runs):
        return []
    ratios = speed_ratios(runs, scene)
    if not ratios:
        return [f"{level} The bar ({scene})", "", "No warpimpulse run on this scene.", ""]
    lines = [f"{level} The bar: {scene} at matched trajectory error", "",
             "Ratio = run time per simulated second of the fastest MuJoCo configuration whose error is at most "
             "ours, over ours (> 1: warpimpulse is faster). Per second, not per step: h differs between the two.",
             "",
             "| our h | tolerance | our error (m) | our µs/step | our ms/sim s | fastest MuJoCo at ≤ that error | "
             "its error (m) | its µs/step | its ms/sim s | ratio |",
             "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in ratios:
        theirs = r["mujoco_time_per_second"]
        lines.append(
            f"| 1/{r['rate']} | {r['tolerance']:g} | {r['trajectory_error']:.3g} | {_us(r['time_per_step'])} | "
            f"{r['time_per_second'] * 1e3:.1f} | {r['mujoco'] or 'none reaches it'} | {_num(r['mujoco_error'])} | "
            f"{_us(r['mujoco_time_per_step'])} | {'—' if theirs is None else f'{theirs * 1e3:.1f}'} | "
            f"{_num(r['ratio'], '.3g')} |"
        )
    wins = [r for r in ratios if r["ratio"] is None or r["ratio"] > 1.0]
    losses = [r for r in ratios if r["ratio"] is not None and r["ratio"] <= 1.0]
    lines += ["", f"We win in {len(wins)} of {len(ratios)} configurations and lose in {len(losses)}."]
    if wins:
        best = max(wins, key=lambda r: math.inf if r["ratio"] is None else r["ratio"])
        lines.append(f"Best: h=1/{best['rate']}, tol {best['tolerance']:g}, error {best['trajectory_error']:.3g} m, "
                     + ("no MuJoCo configuration of the sweep is that accurate." if best["ratio"] is None
                        else f"{best['ratio']:.2f}x faster than MuJoCo {best['mujoco']}."))  # fmt: skip
        lines.append("We win at: " + ", ".join(f"1/{r['rate']} tol {r['tolerance']:g}" for r in wins) + ".")
    if losses:
        worst = min(losses, key=lambda r: r["ratio"])
        lines.append(f"Worst: h=1/{worst['rate']}, tol {worst['tolerance']:g}, error {worst['trajectory_error']:.3g} "
                     f"m, {1.0 / worst['ratio']:.2f}x slower than MuJoCo {worst['mujoco']}.")  # fmt: skip
    return lines + [""]


def scaling_markdown(scale: dict, level: str = "##") -> list[str]:
    rows = scale["rows"]
    lines = [f"{level} Scaling", "", *_provenance(scale),
             f"h = 1/{SCALING_RATE}; warpimpulse at tolerance {SCALING_TOLERANCE:g}. Each point runs in its own "
             f"process, stopped at the budget of {scale['budget_s']:.0f} s (set-up and timing); a size projected "
             f"past it is skipped. Time: median of {scale['repeats']} blocks of {scale['steps']} steps after a "
             "warm-up block. Set-up: our model and symbolic analysis, or MuJoCo's compiler (not the scene "
             "description, built once for all engines).", "",
             "| family | bodies | engine | variant | set-up (s) | µs/step | µs/body/step | joint it/step (max) | "
             "linear it/step | note |",
             "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        note = " ".join((r.get("skipped") or r.get("failed") or "").split())
        per_body = r.get("time_per_body_step")
        iters = r.get("joint_iterations_mean")
        lines.append(
            f"| {r['family']} | {r['bodies']} | {r['engine']} | {r['variant']} | {_num(r.get('setup_s'), '.2f')} | "
            f"{_us(r.get('time_per_step'))} | {'—' if per_body is None else f'{per_body * 1e6:.3f}'} | "
            + ("—" if iters is None else f"{iters:.2f} ({r['joint_iterations_max']})")
            + f" | {_num(r.get('linear_iterations_mean'), '.1f')} | {note} |"
        )
    return lines + [""] + growth_lines(rows) + [""]


def growth_lines(rows: list[dict]) -> list[str]:
    """How time per step and our iteration counts grow with size: log-log slopes over sizes of 100 and up."""
    lines = []
    for family in dict.fromkeys(r["family"] for r in rows):
        for key in dict.fromkeys((r["engine"], r["variant"]) for r in rows if r["family"] == family):
            mine = [r for r in rows if r["family"] == family and (r["engine"], r["variant"]) == key]
            pts = [(r["bodies"], r["time_per_step"]) for r in mine if r.get("time_per_step")]
            big = [(n, t) for n, t in pts if n >= 100]
            if len(big) >= 2:
                slope = np.polyfit(np.log([n for n, _ in big]), np.log([t for _, t in big]), 1)[0]
                lines.append(f"- {family}s, {' '.join(key)}: time per step ~ n^{slope:.2f} "
                             f"({big[0][0]} to {big[-1][0]} bodies).")  # fmt: skip
        ours = [r for r in rows if r["family"] == family and r["engine"] == "warpimpulse" and r.get("time_per_step")]
        if ours:
            counts = ", ".join(f"{r['joint_iterations_mean']:.2f} at {r['bodies']}" for r in ours)
            lines.append(f"- {family}s, warpimpulse joint-correction iterations per step: {counts}.")
    return lines


README_BEGIN, README_END = "<!-- results:begin -->", "<!-- results:end -->"


def readme_block(results: dict, plots_dir: str = "benchmarks/results") -> str:
    """The README's benchmark section, generated from the JSON so it is never typed by hand."""
    lines = [
        "<!-- generated from benchmarks/results/*.json by `python -m warpimpulse.benchmark --from-json ... --readme "
        "README.md` (make bench): edit the generator, not this text -->",
        "",
    ]
    if results.get("paper_tables"):
        lines += paper_markdown(results["paper_tables"], "###")
    sweep, scale = results.get("run_vs_error"), results.get("scaling")
    if sweep:
        runs = sweep["runs"]
        rates = sorted({r["rate"] for r in runs})
        tolerances = sorted({r["tolerance"] for r in runs if r["tolerance"] is not None}, reverse=True)
        grid = (
            f"h in {{{', '.join(f'1/{r}' for r in rates)}}} and tolerance in "
            f"{{{', '.join(f'{t:g}' for t in tolerances)}}}"
        )
        peers = ", ".join(dict.fromkeys(f"{r['engine']} {r['variant']}" for r in runs if r["engine"] != "warpimpulse"))
        lines += [f"`warpimpulse bench` (`pip install -e .[bench]`; `make bench` regenerates the JSON, the plots, "
                  f"[RESULTS.md]({plots_dir}/RESULTS.md) and this section) runs {grid} "
                  f"on {', '.join(sweep['references'])} against {peers}, with MuJoCo RK4 at h = 1/{REFERENCE_RATE} as "
                  f"the reference (checked against h = 1/{CHECK_RATE} and against pinocchio).", "",
                  *_provenance(sweep), *summary_markdown(sweep, "###"), *bar_markdown(runs, level="###")]  # fmt: skip
        lines += [f"![Pareto {name}]({plots_dir}/pareto_{name}.png)" for name in sweep["references"]]
        lines += ["", f"![Energy drift]({plots_dir}/energy_drift.png)", ""]
    if scale:
        lines += scaling_markdown(scale, "###") + [f"![Scaling]({plots_dir}/scaling.png)", ""]
    return "\n".join(lines)


def write_readme_block(path: Path, block: str) -> None:
    """Replace the text between the results markers of `path`, and nothing else."""
    text = path.read_text()
    begin, end = text.find(README_BEGIN), text.find(README_END)
    if begin < 0 or end < begin:
        raise ValueError(f"{path} has no {README_BEGIN} ... {README_END} block to regenerate")
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text[: begin + len(README_BEGIN)] + "\n" + block.strip() + "\n" + text[end:])
    tmp.replace(path)


def plots(results: dict, directory: Path) -> list[Path]:
    """Pareto plot per scene, energy drift over time, log-log scaling; returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    directory.mkdir(parents=True, exist_ok=True)
    written = []
    sweep = results.get("run_vs_error")
    if sweep:
        for name in sweep["references"]:
            # Left: per step, as measured. Right: per simulated second, the cost at equal simulated time.
            fig, axes = plt.subplots(1, 2, figsize=(12, 5))
            for ax, per_second in zip(axes, (False, True)):
                for label, curve in _curves(sweep["runs"], name).items():
                    ok = [r for r in curve if r["trajectory_error"] is not None and r["time_per_step"] is not None]
                    ys = [r["time_per_step"] * (r["rate"] * 1e3 if per_second else 1e6) for r in ok]
                    if not ok:
                        continue
                    ax.plot([r["trajectory_error"] for r in ok], ys,
                            "o-" if label.startswith("warpimpulse") else "s--", label=label)  # fmt: skip
                    for r, y in zip(ok, ys):
                        ax.annotate(f"1/{r['rate']}", (r["trajectory_error"], y), fontsize=6)
                ylabel = "run time per simulated second (ms)" if per_second else "time per step (µs)"
                ax.set(xscale="log", yscale="log", xlabel=f"trajectory error at t = {ERROR_TIME:g} s (m)",
                       ylabel=ylabel, title=f"{name} (lower left is better)")  # fmt: skip
                ax.grid(True, which="both", alpha=0.3)
                ax.legend(fontsize=7)
            written.append(_save(fig, directory / f"pareto_{name}.png"))
        names = list(sweep["references"])
        fig, axes = plt.subplots(len(names), 1, figsize=(7, 2.6 * len(names)), squeeze=False)
        for ax, name in zip(axes[:, 0], names):
            for label, curve in _curves(sweep["runs"], name).items():
                # One step size for readability: the finest of the sweep that every curve has.
                for r in curve:
                    if r["rate"] == max(c["rate"] for c in curve) and r["energy_series"]:
                        t, d = np.array(r["energy_series"]).T
                        ax.plot(t, np.abs(d) + 1e-16, label=f"{label} h=1/{r['rate']}")
            ax.set(yscale="log", title=name, ylabel="|ΔE| / scale")
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=6, ncol=2)
        axes[-1, 0].set_xlabel("time (s)")
        written.append(_save(fig, directory / "energy_drift.png"))
    if results.get("scaling"):
        rows = [r for r in results["scaling"]["rows"] if r.get("time_per_step")]
        panels = (("time per step (µs)", lambda r: r["time_per_step"] * 1e6),
                  ("time per body per step (µs)", lambda r: r["time_per_body_step"] * 1e6),
                  ("our joint iterations per step", lambda r: r.get("joint_iterations_mean")))  # fmt: skip
        fig, axes = plt.subplots(len(panels), 2, figsize=(11, 3.6 * len(panels)), squeeze=False)
        for col, family in enumerate(("tree", "chain")):
            mine = [r for r in rows if r["family"] == family]
            for ax, (ylabel, of) in zip(axes[:, col], panels):
                for key in sorted({(r["engine"], r["variant"]) for r in mine}):
                    pts = sorted((r["bodies"], of(r)) for r in mine if (r["engine"], r["variant"]) == key)
                    pts = [p for p in pts if p[1] is not None]
                    if pts:
                        ax.plot(*zip(*pts), "o-", label=" ".join(key))
                ax.set(xscale="log", yscale="log", xlabel="bodies", ylabel=ylabel, title=f"{family}s")
                ax.grid(True, which="both", alpha=0.3)
                ax.legend(fontsize=8)
        written.append(_save(fig, directory / "scaling.png"))
    return written


def _curves(runs: list[dict], scene: str) -> dict[str, list[dict]]:
    curves: dict[str, list[dict]] = {}
    for r in runs:
        if r["scene"] != scene:
            continue
        label = (
            f"warpimpulse tol {r['tolerance']:g}" if r["engine"] == "warpimpulse" else f"{r['engine']} {r['variant']}"
        )
        curves.setdefault(label, []).append(r)
    return curves


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


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
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


# ------------------------------------------------------------------------------------------ entry point
def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="warpimpulse bench", description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="reduced sweep and scaling, under 5 minutes on 2 cores")
    p.add_argument("--json", type=Path, help="write every raw number here")
    p.add_argument("--plots", type=Path, help="write the PNG plots into this directory")
    p.add_argument("--report", type=Path, help="write the full markdown report (the stdout table) here too")
    p.add_argument("--readme", type=Path,
                   help=f"regenerate the block between {README_BEGIN} and {README_END} in this file")  # fmt: skip
    p.add_argument(
        "--from-json",
        type=Path,
        nargs="+",
        help="report and plot earlier --json files (merged; paper_tables.json too); measure nothing",
    )
    p.add_argument("--scenes", nargs="+", help=f"scenes of the sweep (default {' '.join(SWEEP_SCENES)})")
    p.add_argument("--solver", default="auto", choices=("auto", "cholesky", "cg", "iterative"))
    p.add_argument("--repeats", type=int, help="timed repeats per configuration (default 5, quick 3)")
    p.add_argument("--no-sweep", action="store_true", help="skip run time against error")
    p.add_argument("--no-scaling", action="store_true", help="skip scaling")
    p.add_argument("--scaling-budget", type=float, help="seconds allowed per scaling point (default 300, quick 40)")
    p.add_argument("--no-progress", action="store_true")
    return p


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser().parse_args(argv)
    if args.from_json:
        results: dict = {}
        for path in args.from_json:  # e.g. the paper's tables, the sweep and the scaling, measured apart
            data = json.loads(path.read_text())
            results.update({"paper_tables": data} if "paper" in data else data)
    else:
        quiet_warp()
        meta = metadata(argv)
        results = {}
        repeats = args.repeats or (3 if args.quick else 5)
        if not args.no_sweep:
            results["run_vs_error"] = run_vs_error(
                args.scenes or (QUICK_SCENES if args.quick else SWEEP_SCENES),
                QUICK_RATES if args.quick else SWEEP_RATES,
                QUICK_TOLERANCES if args.quick else SWEEP_TOLERANCES,
                repeats, args.solver, not args.no_progress,
            ) | {"meta": meta}  # fmt: skip
        if not args.no_scaling:
            budget = args.scaling_budget or (QUICK_SCALING_BUDGET if args.quick else SCALING_BUDGET)
            rows = scaling(
                QUICK_SCALING_TREES if args.quick else SCALING_TREES,
                QUICK_SCALING_CHAINS if args.quick else SCALING_CHAINS,
                steps=SCALING_STEPS, repeats=SCALING_REPEATS, budget_s=budget, progress=not args.no_progress,
            )  # fmt: skip
            results["scaling"] = {"meta": meta, "budget_s": budget, "steps": SCALING_STEPS,
                                  "repeats": SCALING_REPEATS, "rows": rows}  # fmt: skip
        if args.json:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps(results, indent=1))
    if args.plots:
        for path in plots(results, args.plots):
            log(f"wrote {path}")
    report = markdown(results)
    if args.report:
        args.report.parent.mkdir(parents=True, exist_ok=True)
        args.report.write_text(report)
    if args.readme:
        plots_dir = os.path.relpath(args.plots or Path("benchmarks/results"), args.readme.resolve().parent)
        write_readme_block(args.readme, readme_block(results, Path(plots_dir).as_posix()))
        log(f"regenerated the results block of {args.readme}")
    sys.stdout.write(report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
