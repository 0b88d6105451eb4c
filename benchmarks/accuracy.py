"""Accuracy on request, measured: `Simulator(model, accuracy=E)` against a grid of fixed configurations.

For each scene and each asked accuracy E (1e-2 .. 1e-5 m):
- the trajectory error of the accuracy-controlled run: the largest distance of a body centre from the reference
  at any frame (every 1/20 s) of the first 2 s, with `accuracy.horizon` set to those 2 s;
- its cost: wall time of the steps of that run, repeated after `reset()` (the fastest taken: the first run,
  which records launches for each new step size, is reported apart as `cold_time`);
- the cheapest configuration of a grid of (order, h, tolerance) whose error is at most E, measured the same way.
Pass: error within 3x of E (E/3 .. 3E) and cost at most 1.5x the grid's cheapest at E.

Both are called the same way: one `step()` per frame of 1/20 s (a fixed configuration takes its steps of the
frame as one `step(n)`; the controller's steps are at most a frame long). Reference: MuJoCo RK4 at
h = 1/4000, checked against h = 1/8000 (the residual is in the JSON).

    .venv/bin/python benchmarks/accuracy.py                 # -> benchmarks/results/accuracy.json, .md
    .venv/bin/python benchmarks/accuracy.py --from-json     # only the table again (docs/accuracy.md)
    .venv/bin/python benchmarks/accuracy.py --scenes arm7 --quick
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import platform
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np

from warpimpulse import scenes
from warpimpulse.bench.harness import quiet_warp
from warpimpulse.bench.peers.mujoco import MujocoRunner, MujocoScene
from warpimpulse.builder import SceneBuilder
from warpimpulse.shapes import Shape
from warpimpulse.simulator import SimulationError, Simulator
from warpimpulse.transforms import quat_between

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results" / "accuracy.json"
TABLE = ROOT / "benchmarks" / "results" / "accuracy.md"
DOC = ROOT / "docs" / "accuracy.md"
DURATION = 2.0  # s
FPS = 20  # frames a second: the error is measured at each frame, step() is called once a frame
ACCURACIES = (1e-2, 1e-3, 1e-4, 1e-5)
REFERENCE_RATES = (4000, 8000)
GRID = {  # order -> (steps per second, joint tolerances)
    2: ((20, 40, 60, 80, 120, 160, 240, 320, 480, 640, 960, 1280, 1920, 2560), (1e-4, 1e-5, 1e-6)),
    4: ((20, 40, 60, 80, 100, 120, 160, 200, 240, 320), (1e-5, 1e-6, 1e-7, 1e-8)),
    6: ((20, 40, 60, 80, 120), (1e-8, 1e-10)),
}
QUICK_GRID = {2: ((20, 40, 80, 160, 320, 640), (1e-4, 1e-6)), 4: ((20, 40, 80, 160), (1e-6, 1e-8))}
CANDIDATES, ROUNDS = 3, 5  # grid configurations timed again beside the controller (`beside`), runs in turns
REPEATS = 3  # timed runs of each configuration after the first (the same steps: the runs are deterministic)
ERROR_WITHIN, COST_WITHIN = 3.0, 1.5


# ------------------------------------------------------------------------------------------ scenes
def _rod(builder: SceneBuilder, start, end, radius: float, name: str, density: float = 1000.0) -> int:
    """A capsule body from `start` to `end` (the cap centres, where joints sit)."""
    start, end = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    axis = end - start
    shape = Shape("capsule", radius=radius, length=float(np.linalg.norm(axis)), collide=False)
    mass, inertia = shape.mass_properties(density)
    q = quat_between([0.0, 0.0, 1.0], axis / np.linalg.norm(axis))
    return builder.add_body(mass, inertia, 0.5 * (start + end), q, name=name, shape=shape)


def double_pendulum_3d() -> SceneBuilder:
    """Two ball-jointed capsules (1 m), hung from a world point: the upper 60 degrees from the vertical in x-z,
    the lower horizontal along y, released at rest (3D motion)."""
    b = SceneBuilder()
    top = np.zeros(3)
    mid = np.array([math.sin(math.pi / 3), 0.0, -math.cos(math.pi / 3)])
    tip = mid + np.array([0.0, 1.0, 0.0])
    upper = _rod(b, top, mid, 0.03, "upper")
    lower = _rod(b, mid, tip, 0.03, "lower")
    b.add_joint("ball", None, upper, top, name="shoulder")
    b.add_joint("ball", upper, lower, mid, name="elbow")
    return b


def arm7() -> SceneBuilder:
    """A 7-hinge robot arm of 0.35 m links, pitch and roll hinges alternating, the base hinge on the world;
    released bent (each link 20 degrees lower than the last, in x-z), so the roll hinges swing it out of
    the plane."""
    b = SceneBuilder()
    point, parent = np.zeros(3), None
    for i in range(7):
        angle = -math.radians(20.0) * i
        direction = np.array([math.cos(angle), 0.0, math.sin(angle)])
        end = point + 0.35 * direction
        link = _rod(b, point, end, 0.04, f"link{i}")
        tilt = np.array([0.0, 0.3, 1.0]) / math.hypot(0.3, 1.0)  # a roll axis off the link: it turns under gravity
        axis = np.array([0.0, 1.0, 0.0]) if i % 2 == 0 else np.cross(direction, tilt)
        b.add_joint_revolute(parent, link, point, axis, name=f"hinge{i}")
        point, parent = end, link
    return b


def humanoid() -> SceneBuilder:
    """A humanoid-like tree of 16 bodies: a torso hung by a ball joint at its top, a head on a ball joint, two
    arms of three hinges (shoulder, elbow, wrist) held out sideways, two legs of four hinges (hip twice, knee,
    ankle), one leg raised forward; released at rest, it swings and folds in 3D."""
    b = SceneBuilder()
    x, y, z = np.eye(3)
    neck, pelvis = np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, -0.6])
    torso = _rod(b, neck, pelvis, 0.12, "torso")
    b.add_joint("ball", None, torso, neck, name="hang")
    head = _rod(b, neck + 0.05 * z, neck + 0.25 * z, 0.09, "head")
    b.add_joint("ball", torso, head, neck + 0.05 * z, name="neck")
    for side in (1.0, -1.0):
        shoulder = neck + side * 0.2 * y
        elbow, wrist, hand = shoulder + side * 0.3 * y, shoulder + side * 0.55 * y + 0.05 * z, None
        hand = wrist + side * 0.12 * y
        parent = torso
        for k, (a, c, axis) in enumerate(((shoulder, elbow, x), (elbow, wrist, z), (wrist, hand, y))):
            link = _rod(b, a, c, 0.04, f"arm{'LR'[side < 0]}{k}")
            b.add_joint_revolute(parent, link, a, axis, name=f"arm{'LR'[side < 0]}_hinge{k}")
            parent = link
        hip = pelvis + side * 0.1 * y
        forward = 0.25 if side > 0 else 0.0  # the left leg raised forward
        knee = hip + np.array([forward, 0.0, -0.45])
        ankle = knee + np.array([0.0, 0.0, -0.4])
        toe = ankle + np.array([0.15, 0.0, -0.02])
        thigh_top = hip - 0.08 * z  # the two hip hinges: a short hip link, then the thigh
        parent = torso
        for k, (a, c, axis) in enumerate(((hip, thigh_top, x), (thigh_top, knee, y), (knee, ankle, y),
                                          (ankle, toe, y))):  # fmt: skip
            link = _rod(b, a, c, 0.06, f"leg{'LR'[side < 0]}{k}")
            b.add_joint_revolute(parent, link, a, axis, name=f"leg{'LR'[side < 0]}_hinge{k}")
            parent = link
    return b


SCENES = {
    "double_pendulum_3d": double_pendulum_3d,
    "arm7": arm7,
    "chain20": lambda: scenes.chain(20),
    "tree127": lambda: scenes.binary_tree(127),
    "humanoid": humanoid,
}


# ------------------------------------------------------------------------------------------ measuring
def reference(builder: SceneBuilder) -> tuple[np.ndarray, dict]:
    """Body centres at each frame (frames, bodies, 3) by MuJoCo RK4 at the finest rate, and its residual
    against the coarser one."""
    frames = int(round(DURATION * FPS))
    runs = []
    for rate in REFERENCE_RATES:
        runner = MujocoRunner(MujocoScene.from_builder(builder, 1.0 / rate), "RK4", rate)
        out = []
        for _ in range(frames):
            runner.run(rate // FPS)
            out.append(runner.poses()[0])
        runs.append(np.array(out))
    residual = float(np.linalg.norm(runs[0] - runs[1], axis=2).max())
    info = {"reference": f"MuJoCo RK4 h=1/{REFERENCE_RATES[1]}", "residual_vs_half_rate": residual}
    return runs[1], info


def run(make, ref: np.ndarray, frame_steps: int = 1) -> dict:
    """`make()` a simulator and run it, one step(frame_steps) a frame: its error at the frames (the first run), and
    its time: the least of REPEATS runs after `reset()`, so that what a simulator records once per step size
    (launches, graphs) is not counted, as in a long run (the first run's time is kept as `cold_time`)."""
    sim = make()
    times, positions, failed, solves = [], [], None, 0
    for repeat in range(1 + REPEATS):
        if repeat:
            sim.reset()
        gc.collect()
        gc.disable()
        elapsed = 0.0
        try:
            for _ in range(len(ref)):
                start = time.perf_counter()
                stats = sim.step(frame_steps)
                elapsed += time.perf_counter() - start
                if not repeat:
                    positions.append(sim.positions())
                    solves += stats.linear_iterations
        except SimulationError as e:
            failed = str(e).split(";")[0]
        finally:
            gc.enable()
        if failed:
            break
        times.append(elapsed)
    if failed or not np.all(np.isfinite(positions)):
        return {"failed": failed or "non-finite", "error": None, "time": None}
    error = float(np.linalg.norm(np.array(positions) - ref, axis=2).max())
    return {"failed": None, "error": error, "time": min(times[1:]), "times": times[1:], "cold_time": times[0],
            "steps": sim.step_count, "solves": solves}  # fmt: skip


def grid_rows(model, ref: np.ndarray, grid: dict) -> list[dict]:
    rows = []
    for order, (rates, tolerances) in grid.items():
        for tol in tolerances:
            for rate in rates:
                make = partial(Simulator, model, 1.0 / rate, tolerance=tol, order=order)
                row = run(make, ref, rate // FPS)
                row.update(order=order, rate=rate, h=1.0 / rate, tolerance=tol)
                rows.append(row)
                err = "failed" if row["error"] is None else f"{row['error']:.3g} m"
                print(f"  grid order {order} 1/{rate} tol {tol:g}: {err}", file=sys.stderr, flush=True)
    return rows


def accuracy_rows(model, ref: np.ndarray, grid: list[dict]) -> list[dict]:
    rows = []
    for target in ACCURACIES:

        def make(target=target):
            sim = Simulator(model, 1.0 / FPS, accuracy=target)
            sim.accuracy.horizon = DURATION
            return sim

        row = run(make, ref)
        probe = make()
        row.update(accuracy=target, order=probe.order, tolerance=probe.tolerance)
        if row["error"] is not None:
            row["beside"] = beside(make, model, [g for g in grid if g["error"] is not None and g["error"] <= target],
                                   len(ref))  # fmt: skip
        rows.append(row)
        err = "failed" if row["error"] is None else f"{row['error']:.3g} m"
        print(f"  accuracy {target:g}: {err}, {row['time']}", file=sys.stderr, flush=True)
    return rows


def beside(make, model, reach: list[dict], frames: int) -> dict:
    """The controller and the grid's likely cheapest at E (the CANDIDATES fastest of the grid's own timing and
    the one of fewest solves) timed again in turns, ROUNDS runs each, medians: the grid's times were taken minutes
    apart on a shared machine, and its least time over many configurations favours a lucky one."""
    if not reach:
        return {}
    chosen = sorted(reach, key=lambda g: g["time"])[:CANDIDATES]
    fewest = min(reach, key=lambda g: g["solves"])
    chosen += [fewest] if fewest not in chosen else []
    sims = [(make(), 1)] + [(Simulator(model, g["h"], tolerance=g["tolerance"], order=g["order"]), g["rate"] // FPS)
                            for g in chosen]  # fmt: skip
    times: list[list[float]] = [[] for _ in sims]
    for r in range(1 + ROUNDS):  # the first round records launches, untimed
        for (sim, per_frame), out in zip(sims, times):
            sim.reset()
            gc.collect()
            gc.disable()
            start = time.perf_counter()
            for _ in range(frames):
                sim.step(per_frame)
            elapsed = time.perf_counter() - start
            gc.enable()
            if r:
                out.append(elapsed)
    medians = [float(np.median(t)) for t in times]
    best = min(range(len(chosen)), key=lambda i: medians[1 + i])
    return {"time": medians[0], "times": times[0],
            "best": {**{k: chosen[best][k] for k in ("order", "rate", "tolerance", "error")}, "time": medians[1 + best],
                     "times": times[1 + best]},
            "candidates": [{k: g[k] for k in ("order", "rate", "tolerance")} | {"time": m}
                           for g, m in zip(chosen, medians[1:])]}  # fmt: skip


def judge(acc: list[dict], grid: list[dict]) -> list[dict]:
    """Per asked accuracy: the grid's cheapest that reaches it (its candidates timed again in turns with the
    controller where `beside` did), and the two criteria."""
    out = []
    for row in acc:
        target = row["accuracy"]
        reach = [g for g in grid if g["error"] is not None and g["error"] <= target]
        best = min(reach, key=lambda g: g["time"]) if reach else None
        fewest = min(reach, key=lambda g: g["solves"]) if reach else None
        ratio_err = None if row["error"] is None else row["error"] / target
        again = row.get("beside") or {}
        if again:  # timed in turns with the controller: the fairer figures
            best = again["best"]
        elapsed = again.get("time", row["time"])
        ratio_cost = None if best is None or elapsed is None else elapsed / best["time"]
        out.append({
            "accuracy": target, "error": row["error"], "time": elapsed, "steps": row.get("steps"),
            "order": row["order"], "tolerance": row["tolerance"], "error_ratio": ratio_err,
            "best": None if best is None else {k: best[k] for k in ("order", "rate", "tolerance", "error", "time")},
            "cost_ratio": ratio_cost,
            "solves": row.get("solves"),
            "solves_ratio": None if fewest is None or row["error"] is None else row["solves"] / fewest["solves"],
            "error_ok": ratio_err is not None and 1.0 / ERROR_WITHIN <= ratio_err <= ERROR_WITHIN,
            "cost_ok": ratio_cost is not None and ratio_cost <= COST_WITHIN,
        })  # fmt: skip
    return out


# ------------------------------------------------------------------------------------------ report
def table(results: dict) -> str:
    lines = [
        "| scene | asked E (m) | error (m) | error / E | order, tol | steps | cost (ms) | grid's cheapest at E "
        "| cost / cheapest | solves / fewest |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, scene in results["scenes"].items():
        for j in scene["judged"]:
            err = "failed" if j["error"] is None else f"{j['error']:.2g}"
            ratio = "" if j["error_ratio"] is None else f"{j['error_ratio']:.2f}" + ("" if j["error_ok"] else " ✗")
            best = j["best"]
            cheapest = "none reached E" if best is None else (
                f"order {best['order']}, h=1/{best['rate']}, tol {best['tolerance']:g}: {best['time'] * 1e3:.1f} ms"
            )  # fmt: skip
            cost = "" if j["cost_ratio"] is None else f"{j['cost_ratio']:.2f}" + ("" if j["cost_ok"] else " ✗")
            t = "" if j["time"] is None else f"{j['time'] * 1e3:.1f}"
            solves = "" if j.get("solves_ratio") is None else f"{j['solves_ratio']:.2f}"
            lines.append(f"| {name} | {j['accuracy']:g} | {err} | {ratio} | {j['order']}, {j['tolerance']:g} | "
                         f"{j['steps']} | {t} | {cheapest} | {cost} | {solves} |")  # fmt: skip
    meta = results["meta"]
    lines += [
        "",
        f"Error: the largest distance of a body centre from the reference at any of the {int(DURATION * FPS)} "
        f"frames of {DURATION:g} s; cost: wall time of the steps of that run, the median of {ROUNDS} runs taken in "
        f"turns with the grid's likely cheapest configurations at E (its {CANDIDATES} fastest in the grid's own "
        "timing and the one of fewest solves; the cheapest is the least of their medians), after a first untimed "
        f"run of each (launches recorded), on {meta['machine']} (2 cores, load average "
        f"{meta.get('load', math.nan):.1f} at the end of the run). "
        f"✗: outside E/{ERROR_WITHIN:g} .. {ERROR_WITHIN:g} E, or over {COST_WITHIN:g}x the cheapest. Solves / "
        "fewest: the linear solves of the run (its shadow run's included) against the fewest of a grid configuration "
        "that reaches E, a count that no machine load moves. "
        f"Reference residuals (RK4 1/{REFERENCE_RATES[0]} against 1/{REFERENCE_RATES[1]}): "
        + ", ".join(f"{n} {s['reference']['residual_vs_half_rate']:.1g} m" for n, s in results["scenes"].items())
        + ". Generated by benchmarks/accuracy.py from benchmarks/results/accuracy.json.",
    ]
    return "\n".join(lines) + "\n"


def write_tables(results: dict) -> None:
    text = table(results)
    TABLE.write_text(text)
    if DOC.exists():
        doc = DOC.read_text()
        start, end = "<!-- accuracy table -->\n", "<!-- end accuracy table -->"
        if start in doc and end in doc:
            head, rest = doc.split(start, 1)
            DOC.write_text(head + start + text + rest[rest.index(end) :])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", nargs="*", choices=sorted(SCENES), default=list(SCENES))
    parser.add_argument("--quick", action="store_true", help="a small grid (a check of the script, not results)")
    parser.add_argument("--from-json", action="store_true", help="only regenerate the table from the JSON")
    parser.add_argument("--reuse-grid", action="store_true", help="the grid of fixed configurations from the JSON")
    args = parser.parse_args()
    if args.from_json:
        write_tables(json.loads(RESULTS.read_text()))
        return
    quiet_warp()
    results = json.loads(RESULTS.read_text()) if RESULTS.exists() and not args.quick else {"scenes": {}}
    results["meta"] = {"machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
                       "python": platform.python_version(), "duration": DURATION, "fps": FPS}  # fmt: skip
    for name in args.scenes:
        builder = SCENES[name]()
        ref, info = reference(builder)
        print(f"{name}: {info}", file=sys.stderr, flush=True)
        model = builder.finalize("cpu")
        kept = results["scenes"].get(name, {}).get("grid")
        grid = kept if args.reuse_grid and kept else grid_rows(model, ref, QUICK_GRID if args.quick else GRID)
        acc = accuracy_rows(model, ref, grid)
        results["scenes"][name] = {"bodies": len(builder.bodies), "reference": info, "grid": grid,
                                   "accuracy": acc, "judged": judge(acc, grid)}  # fmt: skip
        results["meta"]["load"] = os.getloadavg()[0]  # the machine's, over the last minute of the run
        if not args.quick:
            RESULTS.write_text(json.dumps(results, indent=1))
    if not args.quick:
        write_tables(results)
    print(table(results))


if __name__ == "__main__":
    main()
