"""Every URDF of example-robot-data loaded and run: `make robots` (needs the `[robots]` extra).

    python benchmarks/robots.py [--duration 10] [--dt 0.001] [--processes 2] [--budget 300]
                                [--json benchmarks/results/robots.json] [--markdown benchmarks/results/robots.md]

Each robot is loaded with `wi.load_urdf` as it is (strict: an unsupported element refuses it with one line
naming it); a refused robot is loaded again with ignore_unsupported=True and run, its refusal kept in the table.
The base is fixed to the world (the URDF's default), collisions off (contacts off), gravity on, the built pose
each joint at 0 (or at the nearest end of its limits). It then runs `--duration` s at h = `--dt` (tolerance
1e-6, the default solver) and reports: NaN or not, the largest joint error any step ended with (StepStats
max_joint_error, m or rad) and the largest measured from the state every 0.1 s (`Simulator.joint_errors`), the
wall time of the run (first step's kernel compilation excluded: it is timed apart) and the steps per second.
A robot whose first 0.1 s projects past `--budget` seconds of wall time runs only as far as the budget allows;
the row says so. Robots run in `--processes` processes at once (the machine was shared: see the JSON's host).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CHUNK = 0.1  # s between state checks


def one_line(err: BaseException) -> str:
    """An error's message without the file's folder (the table names the robot)."""
    text = str(err).splitlines()[0] if str(err) else type(err).__name__
    return text.split(".urdf: ", 1)[-1]


def run_robot(path: str, duration: float, dt: float, budget: float) -> dict:
    """Load and run one URDF; every figure of its row."""
    import warpimpulse as wi
    from warpimpulse.bench.harness import quiet_warp

    quiet_warp()
    row: dict = {"urdf": path, "load": "ok", "refused": "", "warnings": []}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        start = time.perf_counter()
        settings = dict(collisions=False, visuals=False)
        try:
            try:
                builder = wi.load_urdf(path, **settings)
            except wi.SceneError as err:
                if "nothing moves" not in str(err):
                    raise
                row["note"] = "one rigid body: run as a free body (floating=True)"
                settings["floating"] = True
                builder = wi.load_urdf(path, **settings)
        except wi.SceneError as err:
            row["refused"] = one_line(err)
            try:
                builder = wi.load_urdf(path, ignore_unsupported=True, **settings)
                row["load"] = "ignore_unsupported"
            except wi.SceneError as err2:
                row.update(load="refused", refused=one_line(err2), load_seconds=time.perf_counter() - start)
                return row
        row["load_seconds"] = time.perf_counter() - start
    row["warnings"] = [one_line(w.message) for w in caught]
    row.update(bodies=len(builder.bodies), joints=len(builder.joints), limits=len(builder.limits),
               dampers=len(builder.drives))  # fmt: skip
    try:
        start = time.perf_counter()
        sim = wi.Simulator(builder.finalize(), dt)
        stats = sim.step(1)  # compiles the kernels (cached on disk after the first robot of a kind)
        row["first_step_seconds"] = time.perf_counter() - start
        step_error, state_error, steps, chunk = stats.max_joint_error, 0.0, 1, round(CHUNK / dt)
        total = round(duration / dt)
        start = time.perf_counter()
        while steps < total:
            n = min(chunk, total - steps)
            stats = sim.step(n)
            steps += n
            step_error = max(step_error, stats.max_joint_error)
            if not (np.isfinite(sim.positions()).all() and np.isfinite(sim.orientations()).all()):
                row.update(run=f"NaN at t = {sim.time:.3f} s")
                break
            state_error = max(state_error, float(sim.joint_errors().max(initial=0.0)))
            elapsed = time.perf_counter() - start
            if elapsed * total / steps > budget and elapsed + elapsed / steps * n > budget:
                row["note"] = f"stopped at {sim.time:.2f} s: the full run projects to {elapsed * total / steps:.0f} s"
                break
        else:
            row["run"] = "ok"
        row.setdefault("run", "ok (partial)")
        wall = time.perf_counter() - start
        row.update(simulated_seconds=steps * dt, wall_seconds=wall, steps_per_second=(steps - 1) / max(wall, 1e-9),
                   max_step_joint_error=step_error, max_state_joint_error=state_error)  # fmt: skip
    except (wi.SimulationError, wi.SingularSystemError, FloatingPointError, wi.SceneError) as err:
        row.update(run=f"failed: {one_line(err)}")
    except Exception as err:  # anything else is the harness's or the engine's fault: kept in the row, not fatal
        row.update(run=f"error: {type(err).__name__}: {one_line(err)}")
    return row


def robot_name(path: str, root: str) -> str:
    rel = os.path.relpath(path, root)
    return f"{rel.split(os.sep)[0].removesuffix('_description').removesuffix('_data')}/{Path(path).stem}"


def markdown(rows: list[dict], duration: float, dt: float) -> str:
    """The table: one row a robot."""
    lines = [
        f"| robot | bodies | joints | load | run ({duration:g} s at h = {dt:g} s) | max joint error (m or rad) | "
        "wall time (s) | steps/s |",
        "|---|---:|---:|---|---|---:|---:|---:|",
    ]
    loads = {"ok": "ok", "refused": "refused: {}", "ignore_unsupported": "strict: refused ({}); ran ignoring it"}
    for r in rows:
        load = loads[r["load"]].format(r["refused"]).replace("|", "/")
        run = r.get("run", "-") + (f" ({r['note']})" if r.get("note") else "")
        err = max(r.get("max_step_joint_error", math.nan), r.get("max_state_joint_error", math.nan))
        timed = "wall_seconds" in r
        figures = [f"{err:.2e}" if timed else "-", f"{r['wall_seconds']:.1f}" if timed else "-",
                   f"{r['steps_per_second']:.0f}" if timed else "-"]  # fmt: skip
        lines.append(f"| {r['robot']} | {r.get('bodies', '-')} | {r.get('joints', '-')} | {load} | {run} | "
                     + " | ".join(figures) + " |")  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from warpimpulse.urdf import example_robots

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=10.0)
    p.add_argument("--dt", type=float, default=1e-3)
    p.add_argument("--processes", type=int, default=2)
    p.add_argument("--budget", type=float, default=300.0, help="wall seconds a robot may run at most")
    p.add_argument("--only", nargs="*", default=None, help="robots whose name contains one of these")
    p.add_argument("--json", type=Path, default=ROOT / "benchmarks/results/robots.json")
    p.add_argument("--markdown", type=Path, default=ROOT / "benchmarks/results/robots.md")
    args = p.parse_args(argv)
    root = example_robots()
    if root is None:
        print("robots.py: example-robot-data is not installed (pip install -e '.[robots]')", file=sys.stderr)
        return 2
    paths = sorted(str(x) for x in Path(root).rglob("*.urdf"))
    if args.only:
        paths = [x for x in paths if any(o in robot_name(x, root) for o in args.only)]
    start = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.processes) as pool:
        futures = [pool.submit(run_robot, x, args.duration, args.dt, args.budget) for x in paths]
        rows = []
        for x, f in zip(paths, futures):
            row = f.result()
            row["robot"] = robot_name(x, root)
            row["urdf"] = os.path.relpath(x, root)
            rows.append(row)
            print(f"{row['robot']}: load {row['load']} run {row.get('run', '-')} "
                  f"{row.get('wall_seconds', 0.0):.1f} s", file=sys.stderr, flush=True)  # fmt: skip
    summary = {
        "urdfs": len(rows),
        "loaded_strict": sum(r["load"] == "ok" for r in rows),
        "loaded_ignoring_unsupported": sum(r["load"] == "ignore_unsupported" for r in rows),
        "refused": sum(r["load"] == "refused" for r in rows),
        "ran_ok": sum(r.get("run") == "ok" for r in rows),
        "nan": sum(str(r.get("run", "")).startswith("NaN") for r in rows),
        "wall_seconds": time.perf_counter() - start,
    }
    out = {"duration": args.duration, "dt": args.dt, "tolerance": 1e-6, "processes": args.processes,
           "host": {"machine": platform.machine(), "cpus": os.cpu_count(), "python": platform.python_version(),
                    "note": "2 shared cores, loaded by other jobs"},
           "summary": summary, "robots": rows}  # fmt: skip
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=1) + "\n")
    args.markdown.write_text(markdown(rows, args.duration, args.dt) + "\n" + json.dumps(summary) + "\n")
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
