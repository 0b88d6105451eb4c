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

Each run is labelled (`--label before|after`) and merged into the JSON, so one code version's numbers can be
set beside another's (their timings are then from separate processes: say so with them); with both labels in
the JSON the figure is drawn.

    .venv/bin/python benchmarks/iterations.py --label after [--json benchmarks/results/iterations.json]
    .venv/bin/python benchmarks/iterations.py --plot
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

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
import scene_kinds  # noqa: E402  (a sibling script: its scenes and MuJoCo reference)

JSON = ROOT / "benchmarks/results/iterations.json"
FIGURE = ROOT / "docs/images/iterations.png"
H, TOLERANCE, WINDOW, BATCH, ROUNDS = 1 / 120, 1e-6, 2.0, 100, 7
BUILT = {"chain20": lambda: scenes.chain(20), "arm7": scene_kinds.arm7, "tree127": lambda: scenes.binary_tree(127)}
MJCF = ("arm7", "chain30", "tree127")


def iterations(make) -> dict:
    """Iterations a step both ways of calling, and the median CPU us of a body-step in step(BATCH)."""
    model = make().finalize("cpu")
    sim = wi.Simulator(model, H, tolerance=TOLERANCE)
    steps = int(round(WINDOW / H))
    per_call = sum(sim.step().joint_iterations for _ in range(steps)) / steps
    times, batched = [], 0.0
    for _ in range(ROUNDS + 1):  # the first round compiles and warms up
        sim.reset()
        its, start = 0, time.process_time()
        for _ in range(steps // BATCH):
            its += sim.step(BATCH).joint_iterations
        times.append((time.process_time() - start) / (steps // BATCH * BATCH) / model.body_count * 1e6)
        batched = its / (steps // BATCH * BATCH)
    timed = times[1:]
    return {"bodies": model.body_count, "iterations_batched": batched, "iterations_per_call": per_call,
            "us_per_body_step": statistics.median(timed), "us_spread": [min(timed), max(timed)]}  # fmt: skip


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


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--label", choices=("before", "after"))
    p.add_argument("--json", type=Path, default=JSON)
    p.add_argument("--plot", action="store_true", help="only the figure, from the JSON")
    args = p.parse_args(argv)
    results = json.loads(args.json.read_text()) if args.json.exists() else {}
    if args.label:
        scene_kinds.quiet_warp()
        run = {"iterations": {n: iterations(make) for n, make in BUILT.items()}}
        run["errors"] = {n: errors(n) for n in MJCF}
        command = "python benchmarks/iterations.py " + " ".join(sys.argv[1:])
        run["meta"] = scene_kinds.meta([]) | {"command": command, "commit": _commit()}
        results[args.label] = run
        args.json.write_text(json.dumps(results, indent=1) + "\n")
        print(json.dumps(run, indent=1))
    if len(results) >= 2 or args.plot:
        print("figure:", plot(results))
    return 0


def _commit() -> str:
    import subprocess

    return subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT
    ).stdout.strip()


if __name__ == "__main__":
    raise SystemExit(main())
