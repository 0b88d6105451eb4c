"""Joint iterations a step on serial mechanisms, their cost, and the error they leave (issue 28: the first
iteration's carried right-hand side extrapolated, kernels/carry.py).

Part one, iterations and time: a 20-hinge chain released horizontal (`scenes.chain(20)`), the 7-hinge arm of
benchmarks/scene_kinds.py and the paper's 127-body ball-joint tree, at h = 1/120 and tolerance 1e-6 from rest
for `WINDOW` s. Iterations a step (deterministic: `StepStats.joint_iterations`) both ways a user calls a step
(`step(100)`: velocity corrections deferred; `step()` one a call), and the CPU time (`time.process_time`) of a
body-step in `step(100)`, the median of `ROUNDS` runs of the window.

Part two, error: the same settings on the MJCF scenes of benchmarks/scene_kinds.py that MuJoCo also reads
(arm7, chain30, tree127 with its root torque), the largest distance of a tracked point from MuJoCo RK4 at
h = 1/32000 at the end of the window, both ways of calling.

Part three, iterations over step sizes: chains of 10, 20, 30 and 50 hinges, the arm, the tree and the planar
double pendulum at h = 1/60 and 1/120 (`GRID`), 2 s from rest in `step(20)` calls: iterations a step.

Part four, what changed: the 25 scenes of benchmarks/state_hashes.py as it runs them (one `step()` a call):
their iterations a step and final positions, so that two code versions' can be compared body by body.

Each run is labelled (`--label before|after`) and merged into the JSON, so one code version's numbers can be
set beside another's. Their timings then come from separate processes on a machine others share: run the
timing part of the two versions in turn, several times (`--parts iterations`); each run's rounds are added to
the label's, and the median is taken over all of them. With both labels in the JSON the figure is drawn and
the state comparison printed.

    .venv/bin/python benchmarks/iterations.py --label after [--parts iterations errors states]
    .venv/bin/python benchmarks/iterations.py --plot --doc   # figure and docs/results.md's block from the JSON
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import warpimpulse as wi
from warpimpulse import scenes
from warpimpulse.bench.blocks import write_block

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
import scene_kinds  # noqa: E402  (a sibling script: its scenes and MuJoCo reference)

JSON = ROOT / "benchmarks/results/iterations.json"
FIGURE = ROOT / "docs/images/iterations.png"
DOC = ROOT / "docs/results.md"
BLOCK = "iterations"  # docs/results.md's block (`blocks.write_block`)
H, TOLERANCE, WINDOW, BATCH, ROUNDS = 1 / 120, 1e-6, 2.0, 100, 7
BUILT = {"chain20": lambda: scenes.chain(20), "arm7": scene_kinds.arm7, "tree127": lambda: scenes.binary_tree(127)}
MJCF = ("arm7", "chain30", "tree127")
PARTS = ("iterations", "errors", "grid", "states")
GRID = (  # name, builder, 1/h
    ("chain10", lambda: scenes.chain(10), 60), ("chain20", lambda: scenes.chain(20), 60),
    ("chain30", lambda: scenes.chain(30), 60), ("chain50", lambda: scenes.chain(50), 60),
    ("arm7", scene_kinds.arm7, 60), ("tree127", lambda: scenes.binary_tree(127), 60),
    ("chain20", lambda: scenes.chain(20), 120), ("chain30", lambda: scenes.chain(30), 120),
    ("chain50", lambda: scenes.chain(50), 120), ("arm7", scene_kinds.arm7, 120),
    ("tree127", lambda: scenes.binary_tree(127), 120), ("double_pendulum", scenes.double_pendulum, 120),
)  # fmt: skip


def iterations(make) -> dict:
    """Iterations a step both ways of calling, and the median CPU us of a body-step in step(BATCH)."""
    model = make().finalize("cpu")
    sim = wi.Simulator(model, H, tolerance=TOLERANCE)
    steps = int(round(WINDOW / H))
    per_call = sum(sim.step().joint_iterations for _ in range(steps)) / steps
    rounds, batched = [], 0.0
    for _ in range(ROUNDS + 1):  # the first round compiles and warms up
        sim.reset()
        its, start = 0, time.process_time()
        for _ in range(steps // BATCH):
            its += sim.step(BATCH).joint_iterations
        rounds.append((time.process_time() - start) / (steps // BATCH * BATCH) / model.body_count * 1e6)
        batched = its / (steps // BATCH * BATCH)
    return {"bodies": model.body_count, "iterations_batched": batched, "iterations_per_call": per_call,
            "us_rounds": rounds[1:]}  # fmt: skip


def merge_timings(old: dict | None, new: dict) -> dict:
    """`new` with the rounds of `old` (an earlier run of the same label) added, and their median and range."""
    for name, row in new.items():
        if old and name in old:
            row["us_rounds"] = old[name]["us_rounds"] + row["us_rounds"]
        row["us_per_body_step"] = statistics.median(row["us_rounds"])
        row["us_spread"] = [min(row["us_rounds"]), max(row["us_rounds"])]
    return new


def grid() -> dict:
    """Iterations a step over `WINDOW` s from rest in step(20) calls, a scene and step size of `GRID` each."""
    out = {}
    for name, make, rate in GRID:
        sim = wi.Simulator(make().finalize("cpu"), 1.0 / rate, tolerance=TOLERANCE)
        steps = int(round(WINDOW * rate))
        out[f"{name} h=1/{rate}"] = sum(sim.step(20).joint_iterations for _ in range(steps // 20)) / steps
    return out


def compare_grid(results: dict) -> list[str]:
    before, after = results["before"]["grid"], results["after"]["grid"]
    return [f"{k:28s} {before[k]:6.3f} -> {after[k]:6.3f} it/step ({after[k] / before[k] - 1:+.1%})" for k in after]


def states() -> dict:
    """Iterations a step and final positions of benchmarks/state_hashes.py's scenes, run as it runs them."""
    import warnings

    import state_hashes

    out = {}
    for name, (make, dt, steps, settings, switches) in state_hashes.SCENES.items():
        sim = state_hashes._simulator(make().finalize("cpu"), dt, settings, switches)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            its = sum(sim.step().joint_iterations for _ in range(steps))
        out[name] = {"iterations": its / steps, "positions": sim.positions().tolist()}
    return out


def compare_states(results: dict) -> list[str]:
    """A line a scene: iterations a step before -> after and the largest difference of a final position (m)."""
    before, after = results["before"]["states"], results["after"]["states"]
    lines = []
    for name in after:
        moved = float(np.abs(np.array(after[name]["positions"]) - np.array(before[name]["positions"])).max())
        lines.append(f"{name:28s} {before[name]['iterations']:7.3f} -> {after[name]['iterations']:7.3f} it/step, "
                     f"final positions differ by {moved:.1e} m")  # fmt: skip
    return lines


def errors(name: str) -> dict:
    """The error against MuJoCo RK4 at 1/32000 of one run each way of calling."""
    kind = next(k for k in scene_kinds.KINDS if k.name == name)
    scene = scene_kinds.load(kind)
    ref = scene_kinds.reference(scene)
    out = {"reference_floor": ref["floor"]}
    for mode in ("one_call", "per_call"):
        m = scene_kinds.Measured(scene_kinds.OursRun(scene, round(1 / H), 2, TOLERANCE), mode)
        m.once(ref["points"], kind.window, timed=False)
        out[f"error_{mode}"] = m.errors[0] if m.errors else m.failed
    return out


def plot(results: dict) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [label for label in ("before", "after") if label in results]
    names = list(BUILT)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    for ax, key, title in ((axes[0], "iterations_batched", "joint iterations a step, step(100)"),
                           (axes[1], "us_per_body_step", "CPU us a body-step, step(100)")):  # fmt: skip
        for k, label in enumerate(labels):
            values = [results[label]["iterations"][n][key] for n in names]
            bars = ax.bar(np.arange(len(names)) + 0.4 * k - 0.2, values, 0.4, label=label)
            ax.bar_label(bars, fmt="%.2f", fontsize=8)
        ax.set_xticks(np.arange(len(names)), names)
        ax.set_title(title, fontsize=10)
    axes[0].legend()
    fig.suptitle(f"h = 1/{round(1 / H)}, tolerance {TOLERANCE:g}, {WINDOW:g} s from rest (2 shared cores)", fontsize=9)
    fig.tight_layout()
    FIGURE.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURE, dpi=100)
    return FIGURE


def doc_block(results: dict) -> str:
    """docs/results.md's block: the figure, the tables of iterations, time and error, before and after."""
    before, after = results["before"], results["after"]
    rows = ["| scene | iterations a step, step(100) | step() a call | CPU µs a body-step, step(100): median (range) |",
            "|---|---:|---:|---:|"]  # fmt: skip
    for n, a in after["iterations"].items():
        b = before["iterations"][n]
        rows.append(f"| {n} | {b['iterations_batched']:.3f} -> {a['iterations_batched']:.3f} | "
                    f"{b['iterations_per_call']:.3f} -> {a['iterations_per_call']:.3f} | "
                    f"{b['us_per_body_step']:.3f} ({b['us_spread'][0]:.2f}-{b['us_spread'][1]:.2f}) -> "
                    f"{a['us_per_body_step']:.3f} ({a['us_spread'][0]:.2f}-{a['us_spread'][1]:.2f}) |")  # fmt: skip
    rounds = len(next(iter(after["iterations"].values()))["us_rounds"])
    errors = [
        "| MJCF scene | error, step(n) (m) | error, step() a call (m) | reference floor (m) |",
        "|---|---:|---:|---:|",
    ]
    for n, a in after["errors"].items():
        b = before["errors"][n]
        one, per = (f"{b[k]:.6g} -> {a[k]:.6g}" for k in ("error_one_call", "error_per_call"))
        errors.append(f"| {n} | {one} | {per} | {a['reference_floor']:.1e} |")
    grid_rows = ["| scene, h | iterations a step, step(20) |", "|---|---:|"]
    grid_rows += [f"| {k} | {before['grid'][k]:.3f} -> {v:.3f} ({v / before['grid'][k] - 1:+.1%}) |"
                  for k, v in after["grid"].items()]  # fmt: skip
    codes = f"before: {before['meta'][0]['code']}; after: {after['meta'][0]['code']}"
    return "\n".join([
        f"Joint iterations and cost at h = 1/{round(1 / H)}, tolerance {TOLERANCE:g}, {WINDOW:g} s from rest, before "
        f"and after the carried right-hand side was extrapolated (kernels/carry.py). Iterations are deterministic; the "
        f"times are CPU time (`time.process_time`), the median of {rounds} rounds from processes of the two versions "
        "run in turn on a loaded 2-core machine (their ranges overlap: read the iterations, and the time only where "
        "it moves with them).", "", "![iterations](images/iterations.png)", "", *rows, "",
        "The error at the end of the window against MuJoCo RK4 at h = 1/32000 (the MJCF scenes of "
        "benchmarks/scene_kinds.py that both engines read):", "", *errors, "",
        "Iterations a step over step sizes (2 s from rest):", "", *grid_rows, "",
        f"{codes}; `python benchmarks/iterations.py --label before|after`, then `--plot --doc`.",
    ])  # fmt: skip


def write_doc(results: dict) -> None:
    write_block(DOC, BLOCK, doc_block(results))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--label", choices=("before", "after"))
    p.add_argument("--parts", nargs="+", choices=PARTS, default=PARTS)
    p.add_argument("--json", type=Path, default=JSON)
    p.add_argument("--plot", action="store_true", help="only the figure, from the JSON")
    p.add_argument("--doc", action="store_true", help=f"write {DOC.name}'s block from the JSON")
    args = p.parse_args(argv)
    results = json.loads(args.json.read_text()) if args.json.exists() else {}
    if args.label:
        scene_kinds.quiet_warp()
        run = results.setdefault(args.label, {})
        if "iterations" in args.parts:
            fresh = {n: iterations(make) for n, make in BUILT.items()}
            run["iterations"] = merge_timings(run.get("iterations"), fresh)
        if "errors" in args.parts:
            run["errors"] = {n: errors(n) for n in MJCF}
        if "grid" in args.parts:
            run["grid"] = grid()
        if "states" in args.parts:
            run["states"] = states()
        command = "python benchmarks/iterations.py " + " ".join(sys.argv[1:])
        run.setdefault("meta", []).append(scene_kinds.meta([]) | {"command": command, "code": _code()})
        args.json.write_text(json.dumps(results, indent=1) + "\n")
        print(json.dumps({k: v for k, v in run.items() if k != "states"}, indent=1))
    if len(results) >= 2 or args.plot:
        print("figure:", plot(results))
    if args.doc:
        write_doc(results)
    for part, compare in (("grid", compare_grid), ("states", compare_states)):
        if all(part in results.get(label, {}) for label in ("before", "after")):
            print("\n".join(compare(results)))
    return 0


def _code() -> str:
    """The commit checked out, and a note where warpimpulse/ or kernels/ differ from it (a version under test)."""
    import subprocess

    def git(*a: str) -> str:
        return subprocess.run(["git", *a], capture_output=True, text=True, cwd=ROOT).stdout.strip()

    changed = git("status", "--porcelain", "--", "warpimpulse", "kernels")
    return git("rev-parse", "--short", "HEAD") + (" with warpimpulse/, kernels/ changed" if changed else "")


if __name__ == "__main__":
    raise SystemExit(main())
