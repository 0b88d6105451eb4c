"""Order in time: trajectory error against run time for the paper's step (order 2), its symmetric compositions
(orders 4 and 6, every scheme in `warpimpulse.composition.SCHEMES`), Richardson extrapolation of the paper's
step followed by a projection onto the constraints, and MuJoCo's integrators, on the same scenes.

Error: the largest distance of a tracked point (every centre of mass and leaf tip) from the reference at
t = 2 s. Reference: MuJoCo RK4 at h = 1/3000 (checked against 1/6000); without MuJoCo, our own order 6 at
h = 1/960. Cost: median CPU time (`time.process_time`) per simulated second over repeated runs of the first
2 s (one warm-up run discarded), nothing but steps in the timed loop; the error is that of those very runs.

    .venv/bin/python benchmarks/orders.py                # all scenes -> benchmarks/results/orders.json
    .venv/bin/python benchmarks/orders.py --from-json    # only the tables again: docs/time-order.md, docs/results.md

The "Order in time" table of docs/results.md and docs/time-order.md are generated from the JSON (`--from-json`).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np
import warp as wp

from warpimpulse import composition
from warpimpulse.bench import pareto
from warpimpulse.bench.blocks import write_block
from warpimpulse.bench.harness import ERROR_TIME, MUJOCO_RATES, Probe, final_points, make_scene, quiet_warp, time_steps
from warpimpulse.bench.peers.mujoco import MujocoRunner, MujocoScene, mujoco_available
from warpimpulse.bench.runner import StepFailed
from warpimpulse.options import StepOptions
from warpimpulse.simulator import SimulationError, Simulator
from warpimpulse.transforms import quat_mul

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results" / "orders.json"
DOC = ROOT / "docs" / "time-order.md"
README = ROOT / "docs" / "results.md"  # its orders block
SCENES = ("tree127", "double_pendulum", "chain50")
LEVELS = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6)  # m: the error levels of the tables
OURS = {  # scheme -> steps per second
    "base": (30, 60, 120, 240, 480, 960),
    "suzuki5": (8, 10, 15, 30, 60, 120, 240),
    "mclachlan5": (8, 10, 15, 30, 60, 120, 240),
    "yoshida3": (15, 30, 60, 120, 240),
    "kahanli9": (6, 8, 10, 15, 30, 60, 120),
    "yoshida7": (10, 15, 30, 60, 120),
}
RICHARDSON_RATES = (30, 60, 120, 240)
MUJOCO = {"Euler": MUJOCO_RATES, "implicitfast": MUJOCO_RATES, "RK4": MUJOCO_RATES}  # h = 1/10 ... 1/1000
TOLERANCE_STUDY = {"tree127": [("suzuki5", 60), ("suzuki5", 120), ("kahanli9", 30), ("kahanli9", 60)]}
TOLERANCES = (1e-6, 1e-8, 1e-10, 1e-12)
QUICK = {"scenes": ("double_pendulum",), "rates": 2}
BAR = ("tree127", 1e-3, 6)  # scene, error level, rounds: ours against MuJoCo there, timed turn about


# ------------------------------------------------------------------------------------------ runners
class Ours:
    """The Simulator at an order and scheme; the benchmark harness's runner interface (step, poses)."""

    def __init__(self, model, rate: int, scheme: str, tolerance: float | None = None) -> None:
        order = composition.SCHEMES[scheme].order
        self.sim = Simulator(model, 1.0 / rate, tolerance=tolerance, order=order, options=StepOptions(scheme=scheme))
        self.linear_iterations = self.steps = 0

    def step(self) -> None:
        self.run(1)

    def run(self, steps: int) -> None:
        """`steps` steps in one step(n) call (`warpimpulse.bench.runner.advance`)."""
        try:
            self.linear_iterations += self.sim.step(steps).linear_iterations
        except SimulationError as e:
            raise StepFailed(str(e).split(";")[0]) from e
        self.steps += steps

    def poses(self):
        return self.sim.positions(), self.sim.orientations()

    def check(self) -> None:
        """A failed step already raised StepFailed in `run`."""


class Richardson(Ours):
    """Local Richardson extrapolation of the paper's step: one step of h and two of h/2 from the same state,
    combined as (4 y_{h/2} - y_h) / 3 (the step is symmetric, so its local error has odd powers of h only and
    the combination is locally O(h^5): order 4), then projected back onto the joints (positions by
    impulse-sized displacements, Newton with K re-assembled, then the exact velocity projection).
    Three base steps and a projection a step; the projection runs from Python, so its time is an upper bound."""

    run = None  # no call for many steps: each is three base steps and a projection from Python

    def __init__(self, model, rate: int, tolerance: float | None = None) -> None:
        super().__init__(model, rate, "base", tolerance or composition.default_tolerance(1.0 / rate, 4))
        self.half = Simulator(model, 0.5 / rate, tolerance=self.sim.tolerance)

    def step(self) -> None:
        full, half = self.sim, self.half
        half.state.copy_from(full.state)
        half.step_count, half.time = 2 * full.step_count, full.time
        half._update_frames()
        try:
            self.linear_iterations += full.step().linear_iterations
            self.linear_iterations += sum(half.step().linear_iterations for _ in range(2))
        except SimulationError as e:
            raise StepFailed(str(e).split(";")[0]) from e
        s, t = full.state, half.state
        for name in ("body_x", "body_v", "body_w"):
            a, b = getattr(s, name), getattr(t, name)
            a.assign((4.0 * b.numpy() - a.numpy()) / 3.0)  # a new array before assign
        q1, q2 = s.body_q.numpy().copy(), t.body_q.numpy().copy()
        q2 *= np.sign(np.sum(q1 * q2, axis=1))[:, None]  # the same hemisphere
        q = (4.0 * q2 - q1) / 3.0
        s.body_q.assign(q / np.linalg.norm(q, axis=1)[:, None])
        self.linear_iterations += self._project()
        self.steps += 1

    def _project(self) -> int:
        sim, h = self.sim, self.sim.dt
        s, solves = sim.state, 0
        sim._update_frames()
        for _ in range(sim.max_iterations):
            sim.pred.copy_from(s)
            sim._position_errors.launch()  # errors, and rhs = -P d / h
            if float(sim.errors.numpy().max()) <= sim.tolerance:
                break
            v0, w0 = s.body_v.numpy().copy(), s.body_w.numpy().copy()  # on a CPU, numpy() is a view
            for launch in sim.linear.solve_launches(sim.rhs, sim.impulse):
                launch.launch()
            sim._apply.launch()  # v += M^-1 J^T lambda: the displacement over h is the correction
            dx, dw = h * (s.body_v.numpy() - v0), h * (s.body_w.numpy() - w0)
            s.body_x.assign(s.body_x.numpy() + dx)
            angle = np.linalg.norm(dw, axis=1)
            axis = dw / np.maximum(angle, 1e-300)[:, None]
            turn = np.concatenate([axis * np.sin(0.5 * angle)[:, None], np.cos(0.5 * angle)[:, None]], axis=1)
            s.body_q.assign(quat_mul(turn, s.body_q.numpy()))
            s.body_v.assign(v0)
            s.body_w.assign(w0)
            sim._update_frames()
            solves += 1
        else:
            raise StepFailed(f"the projection did not reach {sim.tolerance:g}")
        sim._velocity_errors.launch()
        wp.capture_launch(sim._velocity_fix)
        return solves + 1


# ------------------------------------------------------------------------------------------ measuring
def error_at(runner, rate: int, probe: Probe, ref: np.ndarray) -> tuple[float | None, str | None]:
    try:
        for _ in range(int(round(ERROR_TIME * rate))):
            runner.step()
    except StepFailed as e:
        return None, str(e)
    points = probe.points(*runner.poses())
    if not np.all(np.isfinite(points)):
        return None, "non-finite"
    return float(np.linalg.norm(points - ref, axis=1).max()), None


def measure(factory, rate: int, probe: Probe, ref: np.ndarray, repeats: int, **row) -> dict:
    """Time the first ERROR_TIME seconds `repeats` times (after a warm-up run) and take the error from those
    very runs' final states: the runs timed are the runs measured."""
    runners = []

    def finish(runner) -> float:
        runners.append(runner)
        return float(np.linalg.norm(final_points(probe)(runner) - ref, axis=1).max())

    timed = time_steps(factory, rate, repeats, min_total=0.3, finish=finish)
    times, errors = timed.per_step, timed.finals
    per_step = statistics.median(times) if times else None
    row.update(rate=rate, h=1.0 / rate, error=max(errors) if errors else None, failed=timed.failed,
               time_per_step=per_step, time_per_second=None if per_step is None else per_step * rate,
               time_per_step_min=min(times, default=None), time_per_step_max=max(times, default=None),
               repeats=len(times), error_spread=max(errors) - min(errors) if errors else None)  # fmt: skip
    runner = runners[-1] if runners else factory()
    if isinstance(runner, Ours):
        row["solves_per_step"] = runner.linear_iterations / max(runner.steps, 1)
        row["tolerance"] = runner.sim.tolerance
    failed = timed.failed
    err = row["error"]
    ms = "failed" if per_step is None else f"{per_step * rate * 1e3:8.2f} ms/s"
    err_s = failed if err is None else f"{err:.3g} m"
    print(f"  {row.get('engine')} {row.get('variant')} 1/{rate}: {err_s}, {ms}", file=sys.stderr, flush=True)
    return row


def reference(builder, probe: Probe) -> tuple[np.ndarray, dict]:
    if mujoco_available() is None:
        mscene = MujocoScene.from_builder(builder, 1.0 / 3000)
        pts = []
        for rate in (3000, 6000):
            runner = MujocoRunner(mscene, "RK4", rate)
            for _ in range(int(round(ERROR_TIME * rate))):
                runner.step()
            pts.append(probe.points(*runner.poses()))
        residual = float(np.linalg.norm(pts[0] - pts[1], axis=1).max())
        return pts[0], {"reference": "MuJoCo RK4 h=1/3000", "residual_vs_half_step": residual}
    runner = Ours(builder.finalize("cpu"), 960, "kahanli9")
    err, failed = error_at(runner, 960, probe, np.zeros((len(probe.bodies), 3)))
    if failed:
        raise RuntimeError(f"the reference failed: {failed}")
    return probe.points(*runner.poses()), {"reference": "warpimpulse order 6 (kahanli9) h=1/960"}


def run_scene(name: str, repeats: int, quick: bool) -> dict:
    builder = make_scene(name)
    probe = Probe.from_builder(builder)
    ref, info = reference(builder, probe)
    print(f"{name}: {info}", file=sys.stderr, flush=True)
    model = builder.finalize("cpu")
    cut = (lambda rates: rates[: QUICK["rates"]]) if quick else (lambda rates: rates)
    rows = []
    for scheme, rates in OURS.items():
        for rate in cut(rates):
            factory = partial(Ours, model, rate, scheme)
            rows.append(measure(factory, rate, probe, ref, repeats, engine="warpimpulse", variant=scheme,
                                order=composition.SCHEMES[scheme].order))  # fmt: skip
    for rate in cut(RICHARDSON_RATES):
        rows.append(measure(partial(Richardson, model, rate), rate, probe, ref, repeats, engine="warpimpulse",
                            variant="richardson", order=4))  # fmt: skip
    for scheme, rate in [] if quick else TOLERANCE_STUDY.get(name, []):
        for tol in TOLERANCES:
            factory = partial(Ours, model, rate, scheme, tol)
            rows.append(measure(factory, rate, probe, ref, repeats, engine="warpimpulse", variant=scheme,
                                order=composition.SCHEMES[scheme].order, study="tolerance"))  # fmt: skip
    if mujoco_available() is None:
        mscene = MujocoScene.from_builder(builder, 1.0 / 60)
        for integrator, rates in MUJOCO.items():
            for rate in cut(rates):
                factory = partial(MujocoRunner, mscene, integrator, rate)
                rows.append(measure(factory, rate, probe, ref, repeats, engine="mujoco", variant=integrator))
    out = {"bodies": len(builder.bodies), **info, "runs": rows}
    if name == BAR[0] and not quick:
        out["bar"] = head_to_head(rows, model, mscene if mujoco_available() is None else None, *BAR[1:])
    return out


def head_to_head(rows: list[dict], model, mscene, level: float, rounds: int) -> dict | None:
    """Our cheapest configuration at `level` against MuJoCo's, timed in turns (`rounds` each), so that the
    load of a shared machine falls on both alike; the sweep's single timings are taken minutes apart."""
    ours, theirs = _cheapest(rows, level, "warpimpulse"), _cheapest(rows, level, "mujoco")
    if ours is None or theirs is None or mscene is None:
        return None
    factories = {
        "ours": (partial(Ours, model, ours["rate"], ours["variant"]), ours["rate"]),
        "mujoco": (partial(MujocoRunner, mscene, theirs["variant"], theirs["rate"]), theirs["rate"]),
    }
    times: dict[str, list[float]] = {k: [] for k in factories}
    for _ in range(rounds):
        for key, (factory, rate) in factories.items():
            times[key] += [t * rate for t in time_steps(factory, rate, 3, min_total=0.3).per_step]
    out = {"level": level, "rounds": rounds, "ours": ours, "mujoco": theirs}
    for key, ts in times.items():
        out[f"{key}_time_per_second"] = statistics.median(ts)
        out[f"{key}_time_per_second_min"] = min(ts)
    out["ratio"] = out["mujoco_time_per_second"] / out["ours_time_per_second"]
    return out


def five_stage_family(a: float) -> list[tuple[float, ...]]:
    """The symmetric 5-stage compositions (a, b, c, b, a) of order 4 with first coefficient a: a + b + c/2 = 1/2
    and 2a^3 + 2b^3 + c^3 = 0, a cubic in b. Suzuki's is a = b; McLachlan's a = 0.28."""
    c0 = 1.0 - 2.0 * a  # = 2b + c
    roots = np.roots([-6.0, 12.0 * c0, -6.0 * c0**2, c0**3 + 2.0 * a**3])
    return [(a, b, c0 - 2.0 * b, b, a) for b in sorted(r.real for r in roots if abs(r.imag) < 1e-12)]


def scan(name: str, rate: int) -> list[dict]:
    """Error of every member of the 5-stage family at one h (`--scan`): which coefficients suit the engine."""
    builder = make_scene(name)
    probe = Probe.from_builder(builder)
    ref, _ = reference(builder, probe)
    model, rows = builder.finalize("cpu"), []
    for a in np.arange(0.20, 0.50, 0.02):
        for stages in five_stage_family(float(a)):
            composition.SCHEMES["scan"] = composition.Scheme("scan", 4, stages, "benchmarks/orders.py --scan")
            runner = Ours(model, rate, "scan")
            err, failed = error_at(runner, rate, probe, ref)
            rows.append({"scene": name, "rate": rate, "stages": stages, "error": err, "failed": failed})
            print(f"  a = {a:.2f}: {stages} -> {err if failed is None else failed}", file=sys.stderr, flush=True)
    del composition.SCHEMES["scan"]
    return rows


def scan_lines(results: dict) -> list[str]:
    rows = results.get("scan")
    if not rows:
        return []
    lines = ["| a | b | c | error (m) |", "|---:|---:|---:|---:|"]
    for r in rows:
        a, b, c = r["stages"][:3]
        err = "failed" if r["error"] is None else f"{r['error']:.3g}"
        lines.append(f"| {a:.3f} | {b:.4f} | {c:.4f} | {err} |")
    return lines


# ------------------------------------------------------------------------------------------ tables
def _cheapest(runs: list[dict], level: float, engine: str, study: bool = False) -> dict | None:
    # Richardson is measured beside the compositions but is not a Simulator option: it is left out here.
    ok = [r for r in runs if r["engine"] == engine and r["error"] is not None and r["error"] <= level
          and r["time_per_second"] is not None and ("study" in r) == study
          and r["variant"] != "richardson"]  # fmt: skip
    return min(ok, key=lambda r: r["time_per_second"], default=None)


def _config(r: dict | None) -> str:
    if r is None:
        return "not reached"
    what = r["variant"] if r["engine"] == "mujoco" else f"order {r['order']} {r['variant']}"
    return f"{what} 1/{r['rate']} ({r.get('measured_error', r['error']):.2g} m, {r['time_per_second'] * 1e3:.1f} ms)"


def _floor(scene: dict) -> float:
    """The reference's distance from itself at half its step (0 where it has no such check)."""
    return scene.get("residual_vs_half_step", 0.0)


def _front_points(runs: list[dict], engine: str) -> list[dict]:
    # Richardson is measured beside the compositions but is not a Simulator option: it is left out here.
    keep = [r for r in runs if r["engine"] == engine and "study" not in r and r["variant"] != "richardson"]
    return [r | {"cost": r["time_per_second"]} for r in keep if r["error"] is not None and r["time_per_second"]]


def cheapest_table(results: dict) -> list[str]:
    """Per scene and level: each engine's cost read off its Pareto front (`warpimpulse.bench.pareto`), the
    cheapest measured configuration that reaches the level, and the ratio only where both reached it."""
    lines = ["| scene | error | ours: cheapest measured (error, ms per simulated s) | MuJoCo: cheapest measured | "
             "ours on the front | MuJoCo on the front | MuJoCo / ours |",
             "|---|---:|---|---|---:|---:|---:|"]  # fmt: skip
    for name, scene in results["scenes"].items():
        ours, theirs = _front_points(scene["runs"], "warpimpulse"), _front_points(scene["runs"], "mujoco")
        for level in LEVELS:
            cell = pareto.compare(ours, theirs, level, _floor(scene))
            if cell["status"] in ("reached by neither", "below the reference floor"):
                lines.append(f"| {name} | {level:g} m | — | — | — | — | {cell['status']} |")
                continue
            a, b = cell["ours"], cell["theirs"]
            on_front = [
                "—" if not c["reached"] else f"{'<= ' if c['bound'] else ''}{c['cost'] * 1e3:.1f} ms" for c in (a, b)
            ]
            lines.append(f"| {name} | {level:g} m | {_config(a['grid'])} | {_config(b['grid'])} | {on_front[0]} | "
                         f"{on_front[1]} | {pareto.ratio_text(cell)} |")  # fmt: skip
    return lines


def exclusion_lines(results: dict) -> list[str]:
    """Every configuration that failed or diverged, so none is dropped without a word."""
    out = [f"- {name}: {r['engine']} {r['variant']} 1/{r['rate']}: {r['failed']}"
           for name, scene in results["scenes"].items() for r in scene["runs"] if r["failed"]]  # fmt: skip
    return ["Excluded (failed or diverged within the 2 s):", "", *out] if out else ["No configuration failed."]


def error_constants(results: dict) -> list[str]:
    """C in error = C h^p, and the observed order between the two smallest h that are above round-off."""
    lines = ["| scene | scheme | order | base steps | observed order | C (m s^-p) | C x base steps^p |",
             "|---|---|---:|---:|---:|---:|---:|"]  # fmt: skip
    for name, scene in results["scenes"].items():
        for variant in [*OURS, "richardson"]:
            runs = sorted((r for r in scene["runs"] if r["variant"] == variant and "study" not in r
                           and r["error"] is not None and r["error"] > 1e-9), key=lambda r: r["rate"])  # fmt: skip
            if len(runs) < 2:
                continue
            a, b = runs[-2], runs[-1]
            p_obs = math.log(a["error"] / b["error"]) / math.log(b["rate"] / a["rate"])
            p = runs[0]["order"]
            c = b["error"] * b["rate"] ** p
            cost = 3 if variant == "richardson" else composition.SCHEMES[variant].cost
            lines.append(f"| {name} | {variant} | {p} | {cost} | {p_obs:.2f} | {c:.3g} | {c * cost**p:.3g} |")
    return lines


def tolerance_table(results: dict) -> list[str]:
    lines = [
        "| scene | scheme | h | tolerance | error | solves a step | ms per simulated s |",
        "|---|---|---|---:|---:|---:|---:|",
    ]
    for name, scene in results["scenes"].items():
        study = [r for r in scene["runs"] if r.get("study") == "tolerance"]
        default = [r for r in scene["runs"] if "study" not in r and r["engine"] == "warpimpulse"]
        for r in study + [d for d in default if any(d["variant"] == s["variant"] and d["rate"] == s["rate"]
                                                    for s in study)]:  # fmt: skip
            tol = f"{r['tolerance']:g}" + (" (rule)" if "study" not in r else "")
            err = "failed" if r["error"] is None else f"{r['error']:.3g}"
            t = "—" if r["time_per_second"] is None else f"{r['time_per_second'] * 1e3:.1f}"
            lines.append(f"| {name} | {r['variant']} | 1/{r['rate']} | {tol} | {err} | "
                         f"{r.get('solves_per_step', 0):.1f} | {t} |")  # fmt: skip
    return lines


def bar_lines(results: dict) -> list[str]:
    bar = next((s["bar"] for s in results["scenes"].values() if s.get("bar")), None)
    if bar is None:
        return []
    ours, theirs, x = bar["ours"], bar["mujoco"], bar["ratio"]
    verdict = f"{x:.2f}x faster" if x >= 1.0 else f"{1.0 / x:.2f}x slower"
    return [
        f"Head to head at {bar['level']:g} m on {BAR[0]}, timed in turns ({bar['rounds']} rounds): ours "
        f"(order {ours['order']} {ours['variant']} 1/{ours['rate']}, {ours['error']:.2g} m) "
        f"{bar['ours_time_per_second'] * 1e3:.1f} ms per simulated s (median; best "
        f"{bar['ours_time_per_second_min'] * 1e3:.1f}), MuJoCo {theirs['variant']} 1/{theirs['rate']} "
        f"({theirs['error']:.2g} m) {bar['mujoco_time_per_second'] * 1e3:.1f} ms (best "
        f"{bar['mujoco_time_per_second_min'] * 1e3:.1f}): ours is {verdict}.",
    ]


def write_tables(results: dict) -> None:
    table = cheapest_table(results) + [""] + exclusion_lines(results) + [""] + bar_lines(results)
    note = "<!-- generated from benchmarks/results/orders.json by `python benchmarks/orders.py --from-json` -->"
    write_block(README, "orders", note + "\n" + "\n".join(table))
    meta = results["meta"]
    refs = "; ".join(f"{n}: {s['reference']}" + (f" (vs h/2: {s['residual_vs_half_step']:.2g} m)"
                     if "residual_vs_half_step" in s else "") for n, s in results["scenes"].items())  # fmt: skip
    doc = [
        "# Order in time: the paper's step, composed",
        "",
        "<!-- generated from benchmarks/results/orders.json by `python benchmarks/orders.py --from-json` -->",
        f"Measured {meta['date']} on {meta['machine']} ({meta['seconds']:.0f} s). Error: the largest distance of a "
        f"tracked point (centres of mass, leaf tips) from the reference at t = {ERROR_TIME:g} s. References: {refs}. "
        "Time: median CPU time (`time.process_time`) per simulated second, CPU.",
        "",
        "## What is composed, and the conditions it needs",
        "",
        "The paper's step is symmetric: the impulses at t0 are applied along J(t0) and land the prediction on "
        "the constraints; the velocity projection at t0+h is the exact K^-1 solve along J(t0+h). Run with -h from "
        "its end, the step finds the impulse that undoes the projection and lands on the start, then projects "
        "the impulse of t0 away. That needs J to be the same function at both ends (one frames kernel computes "
        "it for both corrections) and the derivative of the error that the joint correction drives to zero "
        "(tests/test_order.py::test_jacobian_is_the_constraint_gradient checks it for every joint type, so for "
        "all six basic constraints, against the independent numpy errors of tests/conftest.py). The RK4 free "
        "flight is reversible up to O(h^5); translation is exact. Measured directly (step(h), then step(-h), "
        "tolerance 1e-13, 4-link chains under a tilted gravity; tests/test_order.py::test_step_is_symmetric): "
        "the largest state difference from the start is 1.4e-9 at h = 1/30 and 1.1e-11 at 1/60 for revolute "
        "joints, 1.3e-8 / 2.1e-10 prismatic, 5.1e-10 / 6.3e-12 cylindrical, 5.8e-11 / 5.1e-13 planar (ratios "
        "63 to 121 per halving, h^6 to h^7), and round-off (1e-14 to 1e-13) for ball, universal and fixed.",
        "",
        "A symmetric composition S(g_s h) ... S(g_1 h) with sum g = 1 and sum g^3 = 0 then has order 4; two more "
        "conditions give 6. Negative g run the step backwards: every kernel takes h < 0 (the RK4 rotation "
        "substeps count |h|, the spin split sizes steps by the largest |g| h). The spin split and the halving "
        "of a failed step apply to whole composed steps; a failed stage restores the state of the composed "
        "step's start. The split is worth its substeps at order 4 too (MJCF scenes of "
        "benchmarks/scene_kinds.py, 2 s, default tolerance, split at 0.5 rad against none): arm7 at h = 1/30 "
        "1.83e-3 m against 3.75e-2 (1.27 substeps a step, 84 against 68 us a step), 1/15 6.8e-3 against 0.28; "
        "the humanoid at 1/30 4.7e-3 against 2.1e-2; the paper's tree pushed 100x harder at 1/30 2.8e-2 "
        "against 1.73 m, cheaper too (44 against 125 joint iterations a step). A split step's substeps run in "
        "fused launches of their size (docs/architecture.md), where the parallel schedule cost about 13x. "
        "`Simulator.fall_back(reason)` takes the next step at order 2 (for non-reversible events: "
        "contacts, impacts, friction) and StepStats.order / StepStats.fallback record it.",
        "",
        "The joint tolerance: each base step leaves up to the tolerance as error, which the composition does not "
        "cancel, so a tolerance near the step error caps the order (the study below: the error stops falling "
        "once the tolerance is about a tenth of it), and a tighter one costs joint iterations for nothing. "
        "Without a user tolerance the simulator takes 10 dt^5 at order 4 and 200 dt^7 at order 6, clamped to "
        "[1e-12, 1e-6] (1e-6 at order 2, as before): the loosest coefficients that keep the trajectory error "
        "of five MJCF scenes (arm7, chain30, the 3D double pendulum, the humanoid, the paper's tree) within 5% "
        "of its error at tolerance 1e-12 at every h measured (benchmarks/tolerances.py, docs/tolerance.md). The "
        "paper's tree binds: slow, accurate, and 127 joints adding up what each leaves (order 4 at 1/60: 1e-8 "
        "keeps 1.01 of its tight error, 1e-7 1.33). A rule of h alone cannot be looser for the other scenes, "
        "whose loosest tolerances within 5% are 100 to 10^5 times the tree's (arm7 at order 4: 1e-5 at 1/60 and "
        "1/120, 16 -> 6 joint iterations a step): their cheapest configuration sets the tolerance "
        "(benchmarks/scene_kinds.py searches order 4 at 1e-6 too), or `accuracy=` ties it to the error asked. "
        "At order 6 the coefficient was 10: 200 takes 14 to 18% fewer joint iterations for the same error (at "
        "h = 1/15 arm7 and the humanoid end 2.8x and 8x from their error at 1e-12 at every tolerance above "
        "1e-10, the old rule's too: at 1e-12 their steps are halved more often).",
        "",
        "## The cheapest configuration per error level",
        "",
        *table,
        "",
        "Timings on a shared machine are noisy: the sweep times each configuration once (a median of repeats), "
        "minutes apart from its peers; the head-to-head line times two configurations in turns.",
        "",
        "## Error constants (error = C h^p at the smallest h measured)",
        "",
        "C x (base steps)^p compares schemes at equal work: smaller is better.",
        "",
        *error_constants(results),
        "",
        "## Which 5-stage coefficients",
        "",
        "Every symmetric 5-stage composition (a, b, c, b, a) of order 4 has one free coefficient. Scanned on "
        + (
            f"{results['scan'][0]['scene']} at h = 1/{results['scan'][0]['rate']} (`--scan`): "
            if results.get("scan")
            else "(not measured: `--scan`) "
        )
        + "Suzuki's a = b = 0.4145 sits at the smallest error, McLachlan's a = 0.28 (optimised for a "
        "different error norm) is 1.9x above it. Blanes & Moan's optimised methods are splitting methods (they "
        "alternate the flows of two parts of the equations), which the paper's step does not offer, so they do "
        "not apply here.",
        "",
        *scan_lines(results),
        "",
        "## The joint tolerance against the order",
        "",
        *tolerance_table(results),
        "",
    ]
    DOC.parent.mkdir(exist_ok=True)
    DOC.write_text("\n".join(doc))


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenes", nargs="+", default=list(SCENES))
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--quick", action="store_true", help="the double pendulum at the two largest steps only")
    p.add_argument("--from-json", action="store_true", help="only regenerate the tables from the JSON")
    p.add_argument("--scan", action="store_true", help="only scan the 5-stage family on tree127 at h = 1/15 "
                   "into the JSON, then regenerate the tables")  # fmt: skip
    p.add_argument("--out", type=Path, default=RESULTS)
    args = p.parse_args(argv)
    if args.scan:
        quiet_warp()
        results = json.loads(args.out.read_text())
        results["scan"] = scan("tree127", 15)
        args.out.write_text(json.dumps(results, indent=1))
    elif not args.from_json:
        quiet_warp()
        start = time.perf_counter()
        scenes = QUICK["scenes"] if args.quick else args.scenes
        results = {"scenes": {name: run_scene(name, args.repeats, args.quick) for name in scenes}}
        results["meta"] = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "seconds":
                           time.perf_counter() - start, "machine": f"{platform.machine()} {platform.processor()}",
                           "python": platform.python_version(), "warp": wp.__version__}  # fmt: skip
        if args.out.exists() and "scan" in (old := json.loads(args.out.read_text())):
            results["scan"] = old["scan"]  # the --scan study, kept: it is run apart
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=1))
        if args.quick:
            print("\n".join(cheapest_table(results) + [""] + error_constants(results)))
            return
    write_tables(json.loads(args.out.read_text()))
    print(DOC.read_text())


if __name__ == "__main__":
    main()
