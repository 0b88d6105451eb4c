"""Contacts: the 1,000-body pile against MuJoCo, the stages of a contact step, the contact solvers, and the cost
of the contact stage to scenes without colliders.

    python benchmarks/contacts.py [--bodies 1000] [--duration 4] [--json benchmarks/results/contacts.json]
                                  [--baseline CHECKOUT]
    python benchmarks/contacts.py --grounded [--baseline CHECKOUT] [--json benchmarks/results/grounded.json]
    python benchmarks/contacts.py --solvers [--json benchmarks/results/contact_solvers.json]

1. The pile (`scenes.pile`: spheres and capsules dropped into a box) and the stack of 10 boxes, each in one run
   on both engines: median time per step, the deepest penetration at the states of the last second, the
   kinetic energy at the end and its mean and largest over the last second (at rest: 0), and the total energy
   lost. Ours in three variants (`VARIANTS`): as now, as before (the position phase closing contacts to 0,
   each phase pushing alone), and with the warm start. MuJoCo gets the same bodies, shapes, friction and ground
   (`bench.peers.mujoco.to_spec(contacts=True)`) and the implicitfast integrator, with its CG and PGS solvers
   (its default Newton solver took 14-33 s a step once the pile had landed, 7,500 constraint rows, on the
   shared 2-core machine). warpimpulse runs at `--tolerance` (m), and again at the smallest penetration
   MuJoCo reached (the same accuracy).
2. The stages of our step at the pile's final state, medians of repeated runs: broad phase (swept boxes, BVH
   rebuild, pair query) against testing all pairs, narrow phase (pairs and planes), and the rest of the step
   (the contact and joint solves, predictions, velocity phase).
3. The contact solvers "pgs" and "paper" on the stack of 10 boxes and a 200-body pile: time per step, outer
   iterations (predictions), sweeps, deepest penetration, at the same tolerance and iteration limit (100); a
   step that does not reach the tolerance in it is counted (`steps_not_converged`), not redone smaller.
4. tree127 (no colliders: no contact stage) time per step; with --baseline, the same in another checkout of
   the project (its main branch), in turn, so the two share the machine's load.
5. Contacts on jointed bodies (`--grounded`): the car on the ground driving straight (tolerance 1e-6, 1 s) and
   steering (1e-4, 2 s), the 10-box stack (1e-4, 1 s: no joints, the same path as before), the walking machine
   on its six feet at 1 rad/s (1e-6, 4 s), gymnasium's ant on its floor (1e-6, 1 s at h = 0.01, with the
   [mjcf-robots] extra): joint-loop iterations (predictions) a step, substeps, steps not converged, ms a step
   of a second run from `reset()` (the first records the launches of each step size: `first_run_ms_per_step`),
   and where the run stopped; MuJoCo's ant on its floor as its file sets it beside; with --baseline, the same
   in the other checkout, in a process of its own.
With --baseline, each checkout's process imports that checkout's warpimpulse and kernels (`CHECKOUT_IMPORTS`).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import warp as wp
from warpimpulse.kernels import contact_solve

import warpimpulse as wi
from warpimpulse import scenes
from warpimpulse.bench.harness import quiet_warp
from warpimpulse.transforms import quat_to_matrix

CHECKOUT_IMPORTS = """
import importlib.abc, importlib.util, pathlib, sys
root = pathlib.Path({root!r}).resolve()
sys.path.insert(0, str(root))
class _CheckoutKernels(importlib.abc.MetaPathFinder):
    # warpimpulse.kernels is the checkout's top-level kernels/ (pyproject's package-dir): without this, the
    # editable install's finder would give another checkout this one's kernels
    def find_spec(self, name, path=None, target=None):
        if name != "warpimpulse.kernels" and not name.startswith("warpimpulse.kernels."):
            return None
        where = root.joinpath("kernels", *name.split(".")[2:])
        if where.is_dir():
            return importlib.util.spec_from_file_location(name, where / "__init__.py",
                                                          submodule_search_locations=[str(where)])
        return importlib.util.spec_from_file_location(name, where.with_suffix(".py"))
sys.meta_path.insert(0, _CheckoutKernels())
import warpimpulse, warpimpulse.kernels
for module in (warpimpulse, warpimpulse.kernels):
    assert pathlib.Path(module.__file__).resolve().is_relative_to(root), (module.__file__, str(root))
"""
"""Runs first in a checkout's process (`checkout_code`): that checkout's warpimpulse and kernels, or an error."""


GROUNDED_SNIPPET = """
import json, math, time, warnings, numpy as np, warp as wp
import warpimpulse as wi
from warpimpulse import scenes
wp.config.quiet = True
warnings.simplefilter("ignore")
def ant():
    if {ant!r} is None:
        raise FileNotFoundError("gymnasium is not installed (the [mjcf-robots] extra)")
    return wi.load_mjcf({ant!r})
cases = {{"car_straight": (lambda: scenes.car(steering=0.0, ground=True), 1e-6, 1.0, 1 / 60),
         "car_steering": (lambda: scenes.car(ground=True), 1e-4, 2.0, 1 / 60),
         "box_stack10": (lambda: scenes.box_stack(10), 1e-4, 1.0, 1 / 60),
         "walking_machine": (lambda: scenes.walking_machine(crank_speed=1.0, ground=True), 1e-6, 4.0, 1 / 60),
         "ant_on_its_floor": (ant, 1e-6, 1.0, 0.01)}}
out = {{}}
for name, (make, tol, seconds, dt) in cases.items():
    try:
        builder = make()
    except Exception as e:  # a scene this checkout (or this environment) does not have
        out[name] = {{"error": repr(e)[:200]}}
        continue
    sim = wi.Simulator(builder.finalize(), dt=dt, tolerance=tol, on_max_iterations="warn")
    stats, error, walls = [], "", []
    for run in range(2):  # the first run records the launches of each step size; the second is timed
        sim.reset()
        stats, t0 = [], time.perf_counter()
        try:
            for _ in range(round(seconds / dt)):
                stats.append(sim.step())
        except Exception as e:
            error = repr(e)[:200]
        walls.append(time.perf_counter() - t0)
    n = max(len(stats), 1)
    out[name] = {{"steps": len(stats), "iterations_per_step": sum(s.joint_iterations for s in stats) / n,
                 "substeps_per_step": sum(s.substeps for s in stats) / n,
                 "steps_not_converged": sum(not s.converged for s in stats), "ms_per_step": 1e3 * walls[1] / n,
                 "first_run_ms_per_step": 1e3 * walls[0] / n,
                 "body_moved_m": (sim.positions()[0] - builder.bodies[0].position).round(4).tolist(),
                 "error": error}}
print(json.dumps(out))
"""

TREE_SNIPPET = """
import time, statistics, warp as wp
import warpimpulse as wi
from warpimpulse import scenes
sim = wi.Simulator(scenes.binary_tree(127).finalize(), dt=1.0 / 30.0)
for _ in range(30): sim.step()
times = []
for _ in range({steps}):
    t = time.perf_counter(); sim.step(); times.append(time.perf_counter() - t)
print(statistics.median(times) * 1e3)
"""


def kinetic(sim: wi.Simulator) -> float:
    h = sim.model.host
    v, w = sim.linear_velocities(), sim.angular_velocities()
    r = quat_to_matrix(sim.orientations())
    iw = np.einsum("nij,njk,nlk->nil", r, h.body_inertia, r)
    return float(0.5 * np.sum(h.body_mass * np.sum(v * v, axis=1)) + 0.5 * np.einsum("ni,nij,nj->", w, iw, w))


VARIANTS = {"now": {}, "before": {"take_back": False, "position_slop": 0.0}, "warm_start": {"warm_start": True}}
"""The contact stage's switches (`ContactStage.take_back`, `position_slop`, `warm_start`) per variant: "before"
is main before the position phase left half the tolerance and the velocity phase could take back its push."""


def run_ours(
    builder, dt: float, duration: float, tolerance: float, solver: str = "pgs", variant: str = "now", **options
) -> tuple[dict, wi.Simulator]:
    sim = wi.Simulator(
        builder.finalize(),
        dt=dt,
        tolerance=tolerance,
        contact_solver=solver,
        on_max_iterations="warn",
        **wi.StepOptions.fold(options),
    )
    for name, value in VARIANTS[variant].items():
        setattr(sim.contact_stage, name, value)
    steps = int(round(duration / dt))
    last = steps - int(round(1.0 / dt))
    e0 = sim.energy()
    times, iterations, sweeps, depth, failed, energies = [], [], [], 0.0, 0, []
    for k in range(steps):
        t = time.perf_counter()
        stats = sim.step()
        times.append(time.perf_counter() - t)
        iterations.append(stats.joint_iterations)
        sweeps.append(stats.contact_sweeps)
        failed += not stats.converged
        if k >= last:
            c = sim.contacts()
            depth = max(depth, float(c.depth.max()) if len(c) else 0.0)  # depth > 0: penetration
            energies.append(kinetic(sim))
    return {
        "variant": variant,
        "ms_per_step": statistics.median(times) * 1e3,
        "mean_ms_per_step": statistics.fmean(times) * 1e3,
        "max_penetration_m": depth,
        "kinetic_end_J": kinetic(sim),
        "kinetic_last_second_mean_J": statistics.fmean(energies),
        "kinetic_last_second_max_J": max(energies),
        "energy_change_J": sim.energy() - e0,
        "outer_iterations_mean": statistics.fmean(iterations),
        "sweeps_mean": statistics.fmean(sweeps),
        "contacts_end": len(sim.contacts()),
        "steps_not_converged": failed,
    }, sim


def run_mujoco(builder, dt: float, duration: float, solver: str) -> dict:
    import mujoco

    from warpimpulse.bench.peers.mujoco import MujocoScene

    scene = MujocoScene.from_builder(builder, dt, integrator="implicitfast", contacts=True)
    scene.model.opt.solver = getattr(mujoco.mjtSolver, f"mjSOL_{solver.upper()}")
    scene.set_energy(True)
    data = scene.make_data()
    mujoco.mj_forward(scene.model, data)
    e0 = scene.energy(data)
    steps = int(round(duration / dt))
    times, depth, energies = [], 0.0, []
    for k in range(steps):
        t = time.perf_counter()
        mujoco.mj_step(scene.model, data)
        times.append(time.perf_counter() - t)
        if k >= steps - int(round(1.0 / dt)):
            if data.ncon:
                depth = max(depth, float(-data.contact.dist[: data.ncon].min()))
            mujoco.mj_energyPos(scene.model, data)
            mujoco.mj_energyVel(scene.model, data)
            energies.append(float(data.energy[1]))
    mujoco.mj_forward(scene.model, data)
    return {
        "ms_per_step": statistics.median(times) * 1e3,
        "mean_ms_per_step": statistics.fmean(times) * 1e3,
        "max_penetration_m": depth,
        "kinetic_end_J": float(data.energy[1]),
        "kinetic_last_second_mean_J": statistics.fmean(energies),
        "kinetic_last_second_max_J": max(energies),
        "energy_change_J": scene.energy(data) - e0,
        "contacts_end": int(data.ncon),
        "solver": solver,
        "integrator": "implicitfast",
    }


def median_ms(fn, rounds: int = 21) -> float:
    times = []
    for _ in range(rounds):
        t = time.perf_counter()
        fn()
        wp.synchronize()
        times.append(time.perf_counter() - t)
    return statistics.median(times) * 1e3


def stages(sim: wi.Simulator) -> dict:
    """Each detection stage on the simulator's current state (its last prediction is re-made first)."""
    cs, h = sim.contact_stage, sim.dt
    sim.pred.copy_from(sim.state)
    sim._use_step_size(h)
    sim._predict.launch()
    run = cs._launches(h)
    data = cs.data

    def broad():
        run.bounds.launch()
        cs.bvh.rebuild()
        data.pair_count.zero_()
        run.broad.launch()

    def narrow():
        data.contact_count.zero_()
        run.narrow.launch()
        run.planes.launch()

    all_pairs = cs._record(
        contact_solve.all_pairs, cs.geometry.collider_count, lowers=cs.geometry.lowers, uppers=cs.geometry.uppers
    )

    def brute():
        run.bounds.launch()
        data.pair_count.zero_()
        all_pairs.launch()

    out = {"broad_bvh_ms": median_ms(broad), "pairs": int(data.pair_count.numpy()[0])}
    out["broad_all_pairs_ms"] = median_ms(brute)
    out["pairs_all_pairs"] = int(data.pair_count.numpy()[0])
    broad()
    out["narrow_ms"] = median_ms(narrow)
    out["contacts"] = int(data.contact_count.numpy()[0])
    return out


def contact_solvers(dt: float, tolerance: float) -> dict:
    """Section 3: "pgs" and "paper" on the 10-box stack and a 200-body pile."""
    solvers = {}
    for name, builder, duration in (("box_stack10", lambda: scenes.box_stack(10), 1.0),
                                    ("pile200", lambda: scenes.pile(200), 2.0)):  # fmt: skip
        for solver in ("pgs", "paper"):  # a step that runs out of iterations is counted, not halved
            r, _ = run_ours(builder(), dt, duration, tolerance, solver, max_substep_depth=0)
            solvers[f"{name}/{solver}"] = r
            print(f"  {name} {solver}", json.dumps(r), flush=True)
    return solvers


def ant_file() -> str | None:
    """gymnasium's ant.xml where pip put it (the [mjcf-robots] extra), or None: section 5's robot on its floor."""
    import importlib.util

    spec = importlib.util.find_spec("gymnasium")
    return None if spec is None or spec.origin is None else str(Path(spec.origin).parent / "envs/mujoco/assets/ant.xml")


def mujoco_ant(steps: int = 100, runs: int = 5) -> dict:
    """MuJoCo on gymnasium's ant on its floor as the file sets it (its integrator and step, soft contacts), beside
    section 5's `ant_on_its_floor`: ms a step, the least of `runs` runs of `steps` from the start after a first
    run. Not the same contacts (MuJoCo's are soft, ours hold to the tolerance): the figure places the scale."""
    try:
        import mujoco
    except ImportError as e:
        return {"error": repr(e)}
    if ant_file() is None:
        return {"error": "gymnasium is not installed (the [mjcf-robots] extra)"}
    m = mujoco.MjModel.from_xml_path(ant_file())
    d = mujoco.MjData(m)
    walls = []
    for _ in range(1 + runs):
        mujoco.mj_resetData(m, d)
        start = time.perf_counter()
        for _ in range(steps):
            mujoco.mj_step(m, d)
        walls.append(time.perf_counter() - start)
    integrator = mujoco.mjtIntegrator(m.opt.integrator).name
    return {"ms_per_step": 1e3 * min(walls[1:]) / steps, "integrator": integrator, "dt": m.opt.timestep,
            "contacts_at_the_end": int(d.ncon)}  # fmt: skip


def checkout_code(cwd: str | None, code: str) -> str:
    """`code` to run in the checkout `cwd` (None: this one), its imports that checkout's (`CHECKOUT_IMPORTS`)."""
    root = Path(cwd) if cwd else Path(__file__).resolve().parent.parent
    return CHECKOUT_IMPORTS.format(root=str(root.resolve())) + code


def grounded(cwd: str | None) -> dict:
    """Section 5 in the checkout `cwd` (None: this one), in a fresh process."""
    code = checkout_code(cwd, GROUNDED_SNIPPET.format(ant=ant_file()))
    out = subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def tree_ms(cwd: str | None, steps: int) -> float:
    code = checkout_code(cwd, TREE_SNIPPET.format(steps=steps))
    out = subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bodies", type=int, default=1000)
    parser.add_argument("--duration", type=float, default=4.0, help="simulated seconds of the pile and the stack")
    parser.add_argument("--dt", type=float, default=1.0 / 60.0)
    parser.add_argument("--tolerance", type=float, default=1e-4, help="our contact (and joint) tolerance, m")
    parser.add_argument(
        "--mujoco-solvers",
        default="CG,PGS",
        help="MuJoCo's solvers to run (its default Newton took 14-33 s a step on the landed 1,000-body pile)",
    )
    parser.add_argument("--baseline", help="another checkout of the project to time tree127 in (its main)")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--grounded", action="store_true", help="only section 5: contacts on jointed bodies")
    parser.add_argument("--solvers", action="store_true", help="only section 3: the contact solvers")
    args = parser.parse_args()
    quiet_warp()
    wp.init()
    warnings.simplefilter("ignore", RuntimeWarning)  # steps that run out of iterations are counted instead
    result = {"machine": platform.platform(), "processor": platform.processor(), "dt": args.dt}
    if args.solvers:
        result["contact_solvers"] = contact_solvers(args.dt, args.tolerance)
        if args.json:
            args.json.write_text(json.dumps(result, indent=2) + "\n")
        return
    if args.grounded:
        result["grounded"] = {"this_branch": grounded(None), "mujoco_ant_on_its_floor": mujoco_ant()}
        print("  grounded, this branch", json.dumps(result["grounded"]["this_branch"]), flush=True)
        print("  grounded, MuJoCo's ant", json.dumps(result["grounded"]["mujoco_ant_on_its_floor"]), flush=True)
        if args.baseline:
            result["grounded"]["baseline"] = grounded(args.baseline)
            print("  grounded, baseline", json.dumps(result["grounded"]["baseline"]), flush=True)
        if args.json:
            args.json.write_text(json.dumps(result, indent=2) + "\n")
        return

    sim = None
    for name, make in (("pile", lambda: scenes.pile(args.bodies)), ("box_stack10", lambda: scenes.box_stack(10))):
        print(f"{name}, {args.duration} s at dt = {args.dt:.4g} s", flush=True)
        result[name] = {"bodies": len(make().bodies), "duration_s": args.duration}
        for variant in VARIANTS:
            ours, last = run_ours(make(), args.dt, args.duration, args.tolerance, variant=variant)
            sim = last if name == "pile" and variant == "now" else sim
            ours["tolerance_m"] = args.tolerance
            print(f"  warpimpulse {variant}", json.dumps(ours), flush=True)
            result[name][f"warpimpulse_{variant}"] = ours
        deepest = math.inf
        for solver in args.mujoco_solvers.split(","):
            theirs = run_mujoco(make(), args.dt, args.duration, solver)
            print(f"  mujoco {solver:<6}", json.dumps(theirs), flush=True)
            result[name][f"mujoco_{solver}"] = theirs
            deepest = min(deepest, theirs["max_penetration_m"])
        if math.isfinite(deepest) and deepest > args.tolerance:  # ours at MuJoCo's penetration: equal accuracy
            for variant in VARIANTS:
                matched, _ = run_ours(make(), args.dt, args.duration, deepest, variant=variant)
                matched["tolerance_m"] = deepest
                print(f"  warpimpulse {variant} at MuJoCo's penetration", json.dumps(matched), flush=True)
                result[name][f"warpimpulse_{variant}_at_mujoco_penetration"] = matched

    result["stages"] = stages(sim)
    result["stages"]["step_ms"] = result["pile"]["warpimpulse_now"]["ms_per_step"]
    print("  stages", json.dumps(result["stages"]), flush=True)

    result["contact_solvers"] = contact_solvers(args.dt, args.tolerance)

    steps = 300
    trees = {"this_branch_ms": [], "baseline_ms": []}
    for _ in range(3):
        trees["this_branch_ms"].append(tree_ms(None, steps))
        if args.baseline:
            trees["baseline_ms"].append(tree_ms(args.baseline, steps))
    if args.baseline:
        head = subprocess.run(["git", "-C", args.baseline, "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True).stdout.strip()  # fmt: skip
        trees["baseline_commit"] = head
    result["tree127_no_colliders"] = trees
    print("  tree127", json.dumps(trees), flush=True)
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
