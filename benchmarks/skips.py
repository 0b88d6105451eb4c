"""What each skip of the project's standard saves ("skip what a scene does not need"), on real scenes.

    python benchmarks/skips.py [--rounds 31] [--json benchmarks/results/skips.json]

1. Joint-type specialization: step time and the frames + position-error kernels, compiled for the scene's
   constraint kinds against all six kinds, and the cold compile time of the scene's module of constraint
   kernels (one per set of kinds; the all-six module is the mixed scene's).
2. No loop system for trees: tree127 and star127 under the constraint matrix K and the augmented body
   matrix; "auto" should pick K for the tree and the body matrix for the star.
3. Corrections within tolerance: how often a tree127 step skips its joint correction (the first prediction
   holds) or its velocity solve, and what one skipped solve costs (its captured graph replayed).
4. Dormant force elements: gymnasium's ant and dm_control's reacher (benchmarks/scene_kinds.py's models: their
   effort motors at control 0) stepped with the motors dormant, each body predicted alone and the velocity
   correction deferred (`Simulator._follow_elements`), against the same simulator with one control at 1e-12,
   which keeps the coupled RK4 prediction and a velocity correction a stage. Needs the [bench] and
   [mjcf-robots] extras; a scene whose package is missing is said and left out.
Variants of a case are timed in turn, round after round, so load on the machine hits them alike; every
figure is a median over the rounds.
"""

from __future__ import annotations

import argparse
import gc
import json
import platform
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import warp as wp
from warpimpulse.kernels import constraints

import warpimpulse as wi
from warpimpulse import scenes
from warpimpulse.bench.harness import quiet_warp
from warpimpulse.joints import JOINT_TYPES

TREE_DT, CHAIN_DT = 1.0 / 30.0, 1.0 / 60.0
SPECIALIZE_SCENES = {  # name: (builder, dt)
    "tree127": (lambda: scenes.binary_tree(127), TREE_DT),
    "chain50": (lambda: scenes.chain(50, "revolute"), CHAIN_DT),
    "mixed21": (lambda: scenes.chain(21, tuple(JOINT_TYPES)), CHAIN_DT),  # all seven joint types, three of each
}
BLOCK = 10  # steps per timed block: the runs stay within ~5 s of simulated time (chain50 at 1e-6 fails near 12 s)
KERNEL_REPEATS = 100  # launches of the kernels per timed replay


def cold_compile(module: wp.Module) -> float:
    """Seconds to build `module` with an empty kernel cache (best of two, so Warp's compiler start-up is not
    counted). Call it before any launch of the module is recorded: it reloads the module."""
    saved, best = wp.config.kernel_cache_dir, float("inf")
    for _ in range(2):
        with tempfile.TemporaryDirectory() as cache:
            wp.config.kernel_cache_dir = cache
            module.unload()
            start = time.perf_counter()
            wp.load_module(module, device="cpu")
            best = min(best, time.perf_counter() - start)
    wp.config.kernel_cache_dir = saved
    return best


def in_turn(work: dict[str, Callable[[], object]], rounds: int, per_call: int = 1) -> dict[str, float]:
    """Median seconds of one of the `per_call` units each `work` item does per call, the items called in turn."""
    times: dict[str, list[float]] = {name: [] for name in work}
    for fn in work.values():
        fn()  # warm-up
    gc.collect()
    gc.disable()
    try:
        for _ in range(rounds):
            for name, fn in work.items():
                start = time.perf_counter()
                fn()
                times[name].append((time.perf_counter() - start) / per_call)
    finally:
        gc.enable()
    return {name: statistics.median(t) for name, t in times.items()}


def steps(sim: wi.Simulator, n: int) -> Callable[[], None]:
    def run() -> None:
        for _ in range(n):
            sim.step()

    return run


def replay(graph: wp.Graph) -> Callable[[], None]:
    return lambda: wp.capture_launch(graph)


def specialization(rounds: int) -> list[dict]:
    kinds = {name: constraints.specialized(frozenset(build().finalize().kinds)) for name, (build, _) in
             SPECIALIZE_SCENES.items()}  # fmt: skip
    compile_s = {name: cold_compile(k.frames.module) for name, k in kinds.items()}  # before any launch records
    rows = []
    for name, (build, dt) in SPECIALIZE_SCENES.items():
        sims = {s: wi.Simulator(build().finalize(), dt, options=wi.StepOptions(specialize=s)) for s in (True, False)}
        # The kernels the specialization changes, KERNEL_REPEATS times in one graph: no launch overhead.
        kernels = {s: sim._capture(*[sim._frames, sim._position_errors] * KERNEL_REPEATS) for s, sim in sims.items()}
        step = in_turn({s: steps(sim, BLOCK) for s, sim in sims.items()}, rounds, BLOCK)
        kernel = in_turn({s: replay(g) for s, g in kernels.items()}, 10 * rounds, KERNEL_REPEATS)
        rows.append({
            "scene": name, "kinds": [int(k) for k in kinds[name].kinds], "dt": dt,
            "step_us": {"specialized": 1e6 * step[True], "all_kinds": 1e6 * step[False]},
            "kernels_us": {"specialized": 1e6 * kernel[True], "all_kinds": 1e6 * kernel[False]},
            "cold_compile_s": compile_s[name],
        })  # fmt: skip
    return rows


def formulations(rounds: int) -> list[dict]:
    rows = []
    for name, build in (("tree127", lambda: scenes.binary_tree(127)), ("star127", lambda: scenes.star(127))):
        sims = {
            f: wi.Simulator(build().finalize(), TREE_DT, options=wi.StepOptions(formulation=f))
            for f in ("constraint", "body")
        }
        auto = wi.Simulator(build().finalize(), TREE_DT).linear.pattern.formulation
        step = in_turn({f: steps(sim, BLOCK) for f, sim in sims.items()}, rounds, BLOCK)
        factor = in_turn({f: replay(sim._frames_graph) for f, sim in sims.items()}, 10 * rounds)
        rows.append({"scene": name, "auto_picks": auto, "step_us": {f: 1e6 * t for f, t in step.items()},
                     "assemble_factor_us": {f: 1e6 * t for f, t in factor.items()}})  # fmt: skip
    return rows


def tolerance_skips(rounds: int, run_steps: int = 150) -> dict:
    """Skip counts over `run_steps` steps of tree127 per tolerance, and the cost of one skipped solve."""
    runs = []
    for tol in (1e-2, 1e-4, 1e-6):
        sim = wi.Simulator(scenes.binary_tree(127).finalize(), TREE_DT, tolerance=tol)
        stats, times = [], []
        for _ in range(run_steps):
            start = time.perf_counter()
            stats.append(sim.step())
            times.append(time.perf_counter() - start)
        runs.append({
            "tolerance": tol, "steps": run_steps, "step_us": 1e6 * statistics.median(times),
            "joint_skipped": sum(s.joint_iterations == 0 for s in stats),
            "velocity_skipped": sum(s.velocity_iterations == 0 for s in stats),
            "joint_iterations_mean": statistics.fmean(s.joint_iterations for s in stats),
        })  # fmt: skip
    sim = wi.Simulator(scenes.binary_tree(127).finalize(), TREE_DT)
    steps(sim, 10)()  # replays below change this simulator's state: it is used for timing only
    # One solve as the step runs it: the captured graph, then the largest error read back to the host.
    cost = in_turn({
        "joint_solve": lambda: (wp.capture_launch(sim._iterate), sim._max_error("joint")),
        "velocity_solve": lambda: (wp.capture_launch(sim._velocity_fix), sim._max_error("velocity")),
    }, 20 * rounds)  # fmt: skip
    cost_us = {k: 1e6 * v for k, v in cost.items()}
    for r in runs:
        skipped = r["joint_skipped"] * cost_us["joint_solve"] + r["velocity_skipped"] * cost_us["velocity_solve"]
        saved = skipped / r["steps"]
        r.update(saved_us_per_step=saved, saved_fraction=saved / (r["step_us"] + saved))
    return {"solve_us": cost_us, "runs": runs}


DORMANT_SCENES = ("ant", "reacher")
DORMANT_CONFIGS = ((4, 1.0 / 120.0, 1e-5), (2, 1.0 / 120.0, 1e-4))  # order, h (s), tolerance: on the error front


def dormant_elements(rounds: int) -> list[dict]:
    """Step time with the scene's motors dormant (control 0) and acting (one control at 1e-12), one step a call
    and BLOCK steps a call, per scene and configuration."""
    try:
        import scene_kinds
    except ImportError as e:  # mujoco (the [bench] extra) reads the models
        return [{"scene": name, "skipped": str(e)} for name in DORMANT_SCENES]
    rows = []
    for name in DORMANT_SCENES:
        kind = next(k for k in scene_kinds.KINDS if k.name == name)
        try:
            model = scene_kinds.load(kind).model
        except FileNotFoundError as e:
            rows.append({"scene": name, "skipped": str(e)})
            continue
        for order, h, tol in DORMANT_CONFIGS:
            sims = {k: wi.Simulator(model, h, tolerance=tol, order=order) for k in ("dormant", "acting")}
            sims["acting"].set_controls({0: 1e-12})
            per_call = in_turn({k: steps(sim, BLOCK) for k, sim in sims.items()}, rounds, BLOCK)
            one_call = in_turn({k: (lambda sim=sim: sim.step(BLOCK)) for k, sim in sims.items()}, rounds, BLOCK)
            rows.append({
                "scene": name, "order": order, "dt": h, "tolerance": tol,
                "deferred": {k: sim.defer_velocities for k, sim in sims.items()},
                "per_call_us": {k: 1e6 * t for k, t in per_call.items()},
                "one_call_us": {k: 1e6 * t for k, t in one_call.items()},
            })  # fmt: skip
    return rows


def table(result: dict) -> list[str]:
    lines = ["1. joint-type specialization (us; specialized / all six kinds)",
             f"{'scene':9} {'kinds':>14} {'step':>17} {'kernels':>13} {'cold compile':>13}"]  # fmt: skip
    for r in result["specialization"]:
        s, k = r["step_us"], r["kernels_us"]
        kinds = ",".join(map(str, r["kinds"]))
        lines.append(
            f"{r['scene']:9} {kinds:>14} {s['specialized']:8.1f}/{s['all_kinds']:<8.1f} "
            f"{k['specialized']:6.2f}/{k['all_kinds']:<6.2f} {r['cold_compile_s']:12.2f}s"
        )
    lines += ["", "2. no loop system for trees (us; constraint K / body matrix)",
              f"{'scene':9} {'auto picks':>10} {'step':>19} {'assemble+factor':>19}"]  # fmt: skip
    for r in result["formulations"]:
        s, f = r["step_us"], r["assemble_factor_us"]
        lines.append(
            f"{r['scene']:9} {r['auto_picks']:>10} {s['constraint']:9.1f}/{s['body']:<9.1f} "
            f"{f['constraint']:9.1f}/{f['body']:<9.1f}"
        )
    t = result["tolerance_skips"]
    cost = t["solve_us"]
    lines += [
        "",
        f"3. corrections within tolerance, tree127 (one solve: joint {cost['joint_solve']:.1f} us, "
        f"velocity {cost['velocity_solve']:.1f} us)",
        f"{'tolerance':>9} {'step us':>8} {'joint skips':>12} {'velocity skips':>15} {'saved us/step':>17}",
    ]
    for r in t["runs"]:
        n = r["steps"]
        lines.append(
            f"{r['tolerance']:9.0e} {r['step_us']:8.1f} {r['joint_skipped']:>7}/{n:<4} "
            f"{r['velocity_skipped']:>10}/{n:<4} {r['saved_us_per_step']:9.1f} ({100 * r['saved_fraction']:.0f}%)"
        )
    lines += ["", "4. dormant force elements (us a step; dormant / acting)",
              f"{'scene':8} {'order':>5} {'h':>7} {'one step a call':>17} {'steps in one call':>19}"]  # fmt: skip
    for r in result.get("dormant_elements", []):
        if "skipped" in r:
            lines.append(f"{r['scene']:8} left out: {r['skipped']}")
            continue
        p, o = r["per_call_us"], r["one_call_us"]
        lines.append(
            f"{r['scene']:8} {r['order']:>5} 1/{round(1 / r['dt']):<5} {p['dormant']:7.1f}/{p['acting']:<9.1f} "
            f"{o['dormant']:7.1f}/{o['acting']:<9.1f}"
        )
    return lines


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=31, help="timed rounds per variant (default 31)")
    parser.add_argument("--json", type=Path, default=Path(__file__).parent / "results" / "skips.json")
    args = parser.parse_args(argv)
    quiet_warp()
    wp.init()
    result = {
        "machine": {"processor": platform.processor() or platform.machine(), "warp": wp.config.version},
        "rounds": args.rounds,
        "specialization": specialization(args.rounds),
        "formulations": formulations(args.rounds),
        "tolerance_skips": tolerance_skips(args.rounds),
        "dormant_elements": dormant_elements(args.rounds),
    }
    print("\n".join(table(result)))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1))
    print(f"\nwrote {args.json}")
    return result


if __name__ == "__main__":
    main()
