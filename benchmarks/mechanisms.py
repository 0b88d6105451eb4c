"""What the paper's mechanisms cost per step, and the car's speed against real time (method paper, section 5:
"the simulation of the joints of this car ran nearly six times faster than real-time").

    python benchmarks/mechanisms.py [--rounds 15] [--json benchmarks/results/mechanisms.json]

1. The car (4 wheel servos, 2 steering servos, 4 sprung sliders, chassis held) and the walking machine
   (4 legs, one loop each): simulated seconds per wall-clock second at h = 1/60 s, tolerance 1e-6.
2. Each mechanism on a 10-link hinged chain (h = 1/60 s): the chain alone, with a spring-damper between
   each link and the world (forces in every RK4 stage, the coupled prediction), with a PID joint spring on
   every hinge, with a stiff velocity motor on every hinge (rows of the correction loop), with a +-0.3 rad
   limit on every hinge (active as the chain swings). The first row is the fast path: a scene without force
   elements keeps the single-body prediction; "zero springs" adds 10 springs of stiffness 0 to show what the
   coupled prediction itself costs, which the fast path skips.
3. The loop system: the planar four-bar (3 redundant rows regularised in the loop joint's pivots) against
   the same linkage cut open (its loop joint removed: a tree), the four-bar under CG (the solver that held it
   before the loop pivots were regularised), and the four-bar and the walking machine with the paper's two
   systems side by side (formulation "split": the tree's and the loop joints' systems apart, iterated
   together) against one matrix with the loop joints last ("auto").
Variants are timed in turn, round after round, so load on the machine hits them alike; figures are medians.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import warpimpulse as wi
from warpimpulse import scenes
from warpimpulse.bench.harness import quiet_warp

DT = 1.0 / 60.0
BLOCK = 30  # steps per timed block


def chain(kind: str) -> wi.SceneBuilder:
    """scenes.chain(10) with one mechanism on every link."""
    b = scenes.chain(10)
    for j in range(len(b.joints)):
        link = b.joints[j].child
        tip = b.bodies[link].position
        if kind == "springs":
            b.add_spring(None, link, tip + (0.0, 0.0, 0.5), tip, 200.0, damping=2.0)
        elif kind == "zero springs":
            b.add_spring(None, link, tip + (0.0, 0.0, 0.5), tip, 0.0)
        elif kind == "joint springs":
            b.add_joint_spring(j, 50.0, damping=1.0)
        elif kind == "stiff motors":
            b.add_motor(j, "velocity", target=0.5, max_force=1e4, stiff=True)
        elif kind == "limits":
            b.add_joint_limit(j, -0.3, 0.3)
    return b


def four_bar_open() -> wi.SceneBuilder:
    """The four-bar without its loop-closing joint C (coupler to rocker): a tree of the same bodies; the motor
    stays on joint A (index 0)."""
    full = scenes.four_bar()
    cut = wi.SceneBuilder(full.gravity)
    for b in full.bodies:
        cut.add_body(b.mass, b.inertia, b.position, b.orientation, name=b.name, shape=b.shape)
    for j in full.joints:  # every joint but the loop's, in order
        if j.name != "C":
            parent = None if j.parent < 0 else j.parent
            cut.add_joint(j.kind, parent, j.child, j.anchor, j.axis, j.axis_child, j.name)
    cut.drives = list(full.drives)  # the motor on joint A (index 0 in both)
    return cut


def interleaved(cases: dict[str, Callable[[], wi.Simulator]], rounds: int, slow: set[str]) -> dict[str, dict]:
    """Per case: median ms per step and mean joint iterations over blocks of BLOCK steps, the cases timed in
    turn within each round so that load on the machine hits them alike; a case that stops is reported so."""
    sims, its, times, out = {}, {}, {}, {}
    for name, make in cases.items():
        try:
            sims[name] = make()
            for _ in range(BLOCK):  # compile, warm up
                sims[name].step()
        except wi.SimulationError as err:
            out[name] = {"failed": str(err)}
        its[name], times[name] = [], []
    for r in range(rounds):
        for name, sim in list(sims.items()):
            if name in slow and r >= 3:
                continue
            try:
                start = time.perf_counter()
                for _ in range(BLOCK):
                    its[name].append(sim.step().joint_iterations)
                times[name].append(1e3 * (time.perf_counter() - start) / BLOCK)
            except wi.SimulationError as err:
                out[name] = {"failed": str(err)}
                del sims[name]
    for name in sims:
        ms = statistics.median(times[name])
        out[name] = {"ms_per_step": round(ms, 4), "joint_iterations": round(statistics.fmean(its[name]), 2),
                     "real_time_ratio": round(1e3 * DT / ms, 1)}  # fmt: skip
    return {name: out[name] for name in cases}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--json", type=Path, default=Path(__file__).parent / "results" / "mechanisms.json")
    args = parser.parse_args()
    quiet_warp()
    cases: dict[str, Callable[[], wi.Simulator]] = {
        "car": lambda: wi.Simulator(scenes.car().finalize(), DT),
        "walking_machine": lambda: wi.Simulator(scenes.walking_machine().finalize(), DT),
    }
    for kind in ("none", "zero springs", "springs", "joint springs", "stiff motors", "limits"):
        cases[f"chain10 {kind}"] = lambda kind=kind: wi.Simulator(chain(kind).finalize(), DT)
    cases["four_bar"] = lambda: wi.Simulator(scenes.four_bar().finalize(), DT)
    cases["four_bar cut open (tree)"] = lambda: wi.Simulator(four_bar_open().finalize(), DT)
    slow = {"four_bar cg"}  # ~0.5 s a step: timed over 3 rounds
    cases["four_bar cg"] = lambda: wi.Simulator(scenes.four_bar().finalize(), DT, solver="cg")
    for name in ("four_bar", "walking_machine"):  # the paper's two systems side by side (section 4.6)
        make = getattr(scenes, name)
        cases[f"{name} split"] = lambda make=make: wi.Simulator(
            make().finalize(), DT, options=wi.StepOptions(formulation="split")
        )
    results = interleaved(cases, args.rounds, slow)
    for name, r in results.items():
        if "failed" in r:
            print(f"{name:28s} failed: {r['failed']}")
        else:
            print(
                f"{name:28s} {r['ms_per_step']:8.3f} ms/step  {r['joint_iterations']:7.2f} iterations  "
                f"{r['real_time_ratio']:7.1f}x real time"
            )
    base = results["chain10 none"]["ms_per_step"]
    for name in list(results):
        if name.startswith("chain10 ") and name != "chain10 none" and "failed" not in results[name]:
            results[name]["extra_ms_per_step"] = round(results[name]["ms_per_step"] - base, 4)
    out = {
        "machine": platform.platform(),
        "processor": platform.processor(),
        "dt": DT,
        "tolerance": 1e-6,
        "rounds": args.rounds,
        "steps_per_round": BLOCK,
        "results": results,
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
