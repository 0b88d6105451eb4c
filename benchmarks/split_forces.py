"""Force elements split into half kicks about each base step, against the coupled RK4 prediction.

`StepOptions.split_forces` (on by default where every element depends on the poses alone) kicks the bodies by
M^-1 F(q) h/2 before each base step's prediction and again at its accepted poses; off, the prediction is the
coupled RK4 of all bodies that evaluates every element at each of its stages, for every joint iteration. This
times both on the scene-kinds robots whose elements act (benchmarks/scene_kinds.py's models and set-up:
contacts, limits and damping off, joint velocities drawn standard normal):

- the dm_control humanoid: 19 undamped joint springs (its 21 effort motors at control 0);
- gymnasium's ant and dm_control's reacher with their effort motors at a control drawn uniform in a small
  part of its range (seed 1; `CASES`), the same control on MuJoCo's side. Without damping or armature the
  ant's legs are light: at a hundredth of the range (1.5 N m) they move its points 0.6 m in 0.2 s, and at
  2 s no step of the grid follows them.

Each configuration (order, h) runs 2 s from the initial state `--rounds` times, both variants in turn; the
time is the process's CPU time of `step(n)` (median and least), the error the largest distance of a centre
of mass from MuJoCo's RK4 at h = 1/32000 with the same controls, read from the timed run.

Then robots as shipped (`SHIPPED`: benchmarks/mjcf_robots.py's files, contacts off, their limits and joint
dampers on), at their own time step with every control at 0.05: their dampers are stiff there and taken
implicitly, beside the kicks. MuJoCo's soft limits are other physics, so the error here is against our own
coupled prediction at a 32nd of the step, over 0.5 s (both variants are first order with implicit dampers).

    python benchmarks/split_forces.py [--rounds 7] [--json benchmarks/results/split_forces.json]
    python benchmarks/split_forces.py --from-json     # only the docs/mechanisms.md table
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import scene_kinds as sk  # noqa: E402 (a sibling script: its scenes and reference)

import warpimpulse as wi  # noqa: E402
from warpimpulse.bench.blocks import write_block  # noqa: E402

JSON = ROOT / "benchmarks" / "results" / "split_forces.json"
DOC, BLOCK = ROOT / "docs" / "mechanisms.md", "split-forces"
CASES = {  # scene: (control as a fraction of each actuator's range, (order, rate) pairs)
    "dm_humanoid": (0.0, ((2, 60), (2, 120), (4, 40), (4, 80))),
    "ant": (1e-4, ((2, 60), (2, 120), (4, 20), (4, 40))),  # its light legs: 1.5 N m spins them up in 0.2 s
    "reacher": (0.01, ((2, 40), (2, 120), (4, 20), (4, 40))),
}
WINDOW = 2.0  # s
SHIPPED = ("g/ant", "g/half_cheetah", "d/cheetah", "d/reacher")  # `mjcf_robots.model_paths` keys
SHIPPED_WINDOW, SHIPPED_CONTROL, SHIPPED_REFINE = 0.5, 0.05, 32


def controls(scene: sk.Loaded, fraction: float) -> np.ndarray:
    """Each actuator's control, uniform in `fraction` of its range (seed 1); zeros where fraction is 0."""
    m = scene.mscene.model
    low, high = m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1]
    u = np.random.default_rng(1).uniform(-1.0, 1.0, m.nu)
    return fraction * (0.5 * (low + high) + 0.5 * (high - low) * u)


def reference(scene: sk.Loaded, ctrl: np.ndarray) -> np.ndarray:
    """MuJoCo RK4 at 1/(2 REFERENCE_RATE) over the window with the controls: the tracked points at its end."""
    run = sk.MujocoRun(scene, 2 * sk.REFERENCE_RATE, "RK4")
    run.start()
    run.data.ctrl[:] = ctrl
    run.one_call(int(round(WINDOW * run.rate)))
    return run.points()


def measure(scene: sk.Loaded, ctrl: np.ndarray, ref: np.ndarray, order: int, rate: int, rounds: int) -> dict:
    """Both variants at (order, rate), timed in turn: per variant the median and least CPU time a step, the
    error and the linear solves a step."""
    n = int(round(WINDOW * rate))
    sims = {}
    for split in (False, None):
        sim = wi.Simulator(scene.model, 1.0 / rate, order=order, options=wi.StepOptions(split_forces=split))
        sims["split" if split is None else "coupled"] = sim

    def error(sim: wi.Simulator) -> float:
        points = scene.probe.points(sim.positions(), sim.orientations())
        return float(np.linalg.norm(points - ref, axis=1).max())

    return {"order": order, "rate": rate} | timed(sims, ctrl, n, rounds, error)


def timed(sims: dict, ctrl: np.ndarray, n: int, rounds: int, error) -> dict:
    """Each simulator of `sims` run n steps from its reset with the controls, `rounds` times in turn: per name,
    the median and least CPU time a step (us), `error(sim)` of the last run, its linear solves a step and
    whether it kicked."""
    times = {name: [] for name in sims}
    out = {}
    for _ in range(rounds):
        for name, sim in sims.items():
            sim.reset()
            sim.set_controls(ctrl)
            start = time.process_time()
            stats = sim.step(n)
            times[name].append((time.process_time() - start) / n)
            out[name] = {"kicked": bool(sim._kicked), "error": error(sim), "solves": stats.linear_iterations / n}
    for name in sims:
        out[name] |= {"us": statistics.median(times[name]) * 1e6, "us_min": min(times[name]) * 1e6}
    return out


def shipped(name: str, rounds: int) -> dict:
    """A robot as shipped at its own step, both variants timed in turn over `SHIPPED_WINDOW`, each one's error
    against the coupled prediction at a `SHIPPED_REFINE`th of the step."""
    import mjcf_robots

    m = mjcf_robots.compiled(mjcf_robots.model_paths()[name], bare=False)
    model = wi.load_mjcf(m, qvel=np.random.default_rng(0).standard_normal(m.nv)).finalize()
    dt, ctrl = float(m.opt.timestep), np.full(m.nu, SHIPPED_CONTROL)

    def simulator(h: float, split: bool | None) -> wi.Simulator:
        sim = wi.Simulator(model, h, options=wi.StepOptions(split_forces=split))
        sim.set_controls(ctrl)
        return sim

    reference = simulator(dt / SHIPPED_REFINE, False)
    reference.step(int(round(SHIPPED_WINDOW * SHIPPED_REFINE / dt)))
    n = int(round(SHIPPED_WINDOW / dt))
    sims = {"coupled": simulator(dt, False), "split": simulator(dt, None)}

    def error(sim: wi.Simulator) -> float:
        return float(np.abs(sim.positions() - reference.positions()).max())

    return {"dt": dt, "implicit_dampers": len(sims["split"].implicit_dampers)} | timed(sims, ctrl, n, rounds, error)


def table(results: dict) -> str:
    """The docs table: per scene and configuration, both variants' time a step and error, and their ratios."""
    lines = [
        f"<!-- generated from {JSON.relative_to(ROOT)} by `python benchmarks/split_forces.py --from-json` -->",
        f"Measured {results['meta']['date']} on {results['meta']['machine']}: CPU time a step (median of "
        f"{results['meta']['rounds']} runs of 2 s, both variants in turn), error: the largest distance of a centre "
        "of mass from MuJoCo's RK4 at h = 1/32000 with the same controls after 2 s.",
        "",
        "| scene | order, h | coupled RK4: us a step, error (m) | split: us a step, error (m) | time split / "
        "coupled | error split / coupled |",
        "|---|---|---|---|---:|---:|",
    ]
    for name, scene in results["scenes"].items():
        for row in scene["runs"]:
            c, s = row["coupled"], row["split"]
            lines.append(
                f"| {name} ({scene['what']}) | {row['order']}, 1/{row['rate']} | {c['us']:.1f}, {c['error']:.2g} | "
                f"{s['us']:.1f}, {s['error']:.2g} | {s['us'] / c['us']:.2f} | {s['error'] / c['error']:.2f} |"
            )
    if results.get("shipped"):
        lines += [
            "",
            f"As shipped (contacts off, limits and dampers on), every control at {SHIPPED_CONTROL}, "
            f"{SHIPPED_WINDOW} s at the robot's own step, error against the coupled prediction at 1/"
            f"{SHIPPED_REFINE} of it:",
            "",
            "| robot | h (s), implicit dampers | coupled RK4: us a step, error (m) | split: us a step, error (m) | "
            "time split / coupled | error split / coupled |",
            "|---|---|---|---|---:|---:|",
        ]
        for name, row in results["shipped"].items():
            c, s = row["coupled"], row["split"]
            lines.append(
                f"| {name} | {row['dt']:g}, {row['implicit_dampers']} | {c['us']:.1f}, {c['error']:.2g} | "
                f"{s['us']:.1f}, {s['error']:.2g} | {s['us'] / c['us']:.2f} | {s['error'] / c['error']:.2f} |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--rounds", type=int, default=7)
    p.add_argument("--json", type=Path, default=JSON)
    p.add_argument("--from-json", action="store_true", help="only the docs table, from the JSON")
    args = p.parse_args(argv)
    if args.from_json:
        results = json.loads(args.json.read_text())
    else:
        missing = sk.mujoco_available()
        if missing:
            print(f"split_forces: {missing}", file=sys.stderr)
            return 2
        sk.quiet_warp()
        argv = sys.argv[1:] if argv is None else argv
        command = "python benchmarks/split_forces.py " + " ".join(argv)
        results = {"meta": sk.meta(argv) | {"command": command.strip(), "rounds": args.rounds}, "scenes": {}}
        for name, (fraction, configs) in CASES.items():
            scene = sk.load(next(k for k in sk.KINDS if k.name == name))
            ctrl = controls(scene, fraction)
            ref = reference(scene, ctrl)
            what = "joint springs" if fraction == 0.0 else f"motors at {fraction:g} of their range"
            runs = [measure(scene, ctrl, ref, order, rate, args.rounds) for order, rate in configs]
            results["scenes"][name] = {"what": what, "controls": ctrl.tolist(), "runs": runs}
            print(f"{name}: done", file=sys.stderr)
        results["shipped"] = {name: shipped(name, args.rounds) for name in SHIPPED}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=1))
    text = table(results)
    print(text)
    write_block(DOC, BLOCK, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
