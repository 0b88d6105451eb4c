"""The joint tolerance of the composed steps (order 4 and 6) against the trajectory error they reach.

Each base step of a composition leaves up to the tolerance in every joint, and the composition does not cancel it,
so a tolerance near the step's own error caps the order; a tighter one costs joint iterations for nothing. This
measures, on the MJCF scenes of benchmarks/scene_kinds.py (both engines' model; MuJoCo RK4 at h = 1/32000 the
reference), for each order and step: the error at a tight tolerance (`TIGHT`), the error, joint iterations and CPU
time a step at each tolerance of `TOLERANCES` and at the default rule (`composition.default_tolerance`), and the
loosest tolerance whose error stays within `WITHIN` of the tight one (a smaller error counts as within). Spin
splits are off (`max_rotation=None`) so that the tolerance is the only thing that changes; 2 s in one `step(n)`
call, a warm-up run and one timed run (CPU time, `time.process_time`; iterations and errors are deterministic).

    .venv/bin/python benchmarks/tolerances.py              # measure -> results/tolerances.json, docs/tolerance.md
    .venv/bin/python benchmarks/tolerances.py --from-json  # docs/tolerance.md again from the JSON
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import warpimpulse as wi

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
import scene_kinds  # noqa: E402  (a sibling script: its scenes and MuJoCo reference)

JSON = ROOT / "benchmarks/results/tolerances.json"
DOC = ROOT / "docs/tolerance.md"
SCENES = ("arm7", "chain30", "double_pendulum_3d", "humanoid", "tree127")
RATES = {4: (30, 60, 120, 240), 6: (15, 30, 60, 120)}  # 1/h
TOLERANCES = (1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
TIGHT = 1e-12
WITHIN = 0.05  # the error may grow by this share of the tight-tolerance error


def run(scene: scene_kinds.Loaded, ref, order: int, rate: int, tolerance: float | None) -> dict:
    """One configuration over the scene's window: error (m), joint iterations and CPU seconds a step."""
    sim = wi.Simulator(scene.model, 1.0 / rate, tolerance=tolerance, order=order,
                       options=wi.StepOptions(max_rotation=None))  # fmt: skip
    n = int(round(scene.kind.window * rate))
    out = {"tolerance": sim.tolerance, "rule": tolerance is None}
    for _ in range(2):  # a warm-up (kernels loaded), then the timed run
        sim.reset()
        start = time.process_time()
        try:
            stats = sim.step(n)
        except wi.SimulationError as e:
            return out | {"failed": str(e).split(";")[0][:160]}
        seconds = time.process_time() - start
    points = scene.probe.points(sim.positions(), sim.orientations())
    error = float(np.linalg.norm(points - ref, axis=1).max())
    return out | {"error": error, "iterations": stats.joint_iterations / n, "time_per_step": seconds / n}


def measure(names: tuple[str, ...]) -> dict:
    meta = scene_kinds.meta([]) | {"command": "python benchmarks/tolerances.py " + " ".join(sys.argv[1:])}
    results = {"meta": meta, "within": WITHIN, "tight": TIGHT, "scenes": {}}
    for name in names:
        kind = next(k for k in scene_kinds.KINDS if k.name == name)
        scene = scene_kinds.load(kind)
        ref = scene_kinds.reference(scene)["points"]
        rows = []
        for order, rates in RATES.items():
            for rate in rates:
                for tol in (TIGHT, None, *TOLERANCES):
                    rows.append({"order": order, "rate": rate} | run(scene, ref, order, rate, tol))
                    print(name, rows[-1], flush=True)
        results["scenes"][name] = rows
    return results


def summary(rows: list[dict], within: float) -> list[dict]:
    """A line per (order, rate): the tight error, the rule's tolerance and error ratio, the loosest listed
    tolerance within `within` of the tight error, and the iterations a step at each."""
    out = []
    for key in dict.fromkeys((r["order"], r["rate"]) for r in rows):
        group = [r for r in rows if (r["order"], r["rate"]) == key and "error" in r]
        tight = next((r for r in group if r["tolerance"] == TIGHT and not r["rule"]), None)
        rule = next((r for r in group if r["rule"]), None)
        if tight is None or rule is None:
            continue
        fine = [r for r in group if not r["rule"] and r["error"] <= (1 + within) * tight["error"]]
        loosest = max(fine, key=lambda r: r["tolerance"])
        out.append({"order": key[0], "rate": key[1], "tight": tight, "rule": rule, "loosest": loosest})
    return out


def doc(results: dict) -> str:
    within = results["within"]
    lines = [
        "# The joint tolerance of the composed steps",
        "",
        "<!-- generated from benchmarks/results/tolerances.json by `python benchmarks/tolerances.py --from-json` -->",
        f"Measured {results['meta'].get('date', '')} on {results['meta'].get('machine', '')}. "
        "Error: the largest distance of a tracked point from MuJoCo RK4 at h = 1/32000 after the scene's "
        'window (2 s), one `step(n)` call, spin splits off. "rule": `composition.default_tolerance` '
        "(10 h^5 at order 4, 200 h^7 at 6, in [1e-12, 1e-6]). "
        f'"loosest": the loosest of {", ".join(f"{t:g}" for t in TOLERANCES)} '
        f"whose error is at most {1 + within:g} x the error at tolerance {results['tight']:g}. Iterations: joint "
        "iterations a step (all stages), deterministic; us: CPU time a step of one run on a shared machine.",
        "",
        "| scene | order | h | error, tol 1e-12 | rule: tol | error / tight | iterations | us | loosest | "
        "error / tight | iterations | us |",
        "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, rows in results["scenes"].items():
        for s in summary(rows, within):
            t, r, lo = s["tight"], s["rule"], s["loosest"]
            lines.append(
                f"| {name} | {s['order']} | 1/{s['rate']} | {t['error']:.3g} | {r['tolerance']:.2g} | "
                f"{r['error'] / t['error']:.3f} | {r['iterations']:.2f} | {r['time_per_step'] * 1e6:.0f} | "
                f"{lo['tolerance']:g} | {lo['error'] / t['error']:.3f} | {lo['iterations']:.2f} | "
                f"{lo['time_per_step'] * 1e6:.0f} |"
            )
    off = [f"{name} order {s['order']} 1/{s['rate']} ({s['rule']['error'] / s['tight']['error']:.2f})"
           for name, rows in results["scenes"].items() for s in summary(rows, within)
           if s["rule"]["error"] > (1 + within) * s["tight"]["error"]]  # fmt: skip
    lines += [
        "",
        f"Where the rule's error is more than {1 + within:g} x the tight one: " + (", ".join(off) or "nowhere") + ".",
        "",
        "What it says, and why the rule stays a function of h alone: see docs/time-order.md.",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", nargs="+", choices=SCENES, default=list(SCENES))
    p.add_argument("--from-json", action="store_true")
    args = p.parse_args(argv)
    if args.from_json:
        results = json.loads(JSON.read_text())
    else:
        scene_kinds.quiet_warp()
        results = measure(tuple(args.scenes))
        JSON.write_text(json.dumps(results, indent=1) + "\n")
    DOC.write_text(doc(results))
    print(DOC.read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
