"""Every MJCF model of gymnasium's MuJoCo assets and dm_control's suite loaded and run at orders 2 and 4.

    python benchmarks/mjcf_robots.py [--models g/ant d/humanoid ...] [--duration 2]
                                     [--json benchmarks/results/mjcf_robots.json]
                                     [--markdown benchmarks/results/mjcf_robots.md] [--from-json]

Needs the `[test]` extra (gymnasium, dm_control, mujoco). Each model is MuJoCo's compiled model
(`MjModel.from_xml_path`) loaded with `wi.load_mjcf` as it is, or with ignore_unsupported=True where strict
loading refuses it (the refusal kept in the table). Contacts are off (the fused step has no contact stage;
contacts are docs/contacts.md's). Two variants of each:
- "shipped": the model's own limits, springs, dampers and motors (armature as `load_mjcf` maps it);
- "bare": limits and dampers off, armature and dry friction 0, as `benchmarks/scene_kinds.py` takes robots
  so that MuJoCo and we run the very same equations: stiff springs are then undamped.
From the model's qpos0 with unit random joint rates (seed 0), `--duration` s at order 2 and order 4, each at
the model's own timestep and at twice it, tolerance 1e-6. Each run reports: the one-line failure, else the
linear solves a step, the substeps a step (spin splits and halvings), the largest joint error a step ended
with, and CPU time a step (the first step, which compiles, excluded). Beside it, MuJoCo with the model's own
integrator at the same step and the same variant: whether it diverged (a bad-qacc warning) within the time.
This is a probe of robustness, not of speed against MuJoCo (benchmarks/scene_kinds.py is that).
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
from pathlib import Path

import numpy as np

from warpimpulse.bench.peers.mujoco import comparable

ROOT = Path(__file__).resolve().parents[1]
TOLERANCE = 1e-6
SEED = 0


def model_paths() -> dict[str, Path]:
    """g/<name>: gymnasium's MuJoCo assets; d/<name>: dm_control's suite (the packages as installed)."""
    import dm_control
    import gymnasium

    folders = {
        "g": Path(gymnasium.__file__).parent / "envs/mujoco/assets",
        "d": Path(dm_control.__file__).parent / "suite",
    }
    return {f"{key}/{p.stem}": p for key, folder in folders.items() for p in sorted(folder.glob("*.xml"))}


def one_line(err: BaseException) -> str:
    return (str(err).splitlines() or [type(err).__name__])[0]


def compiled(path: Path, bare: bool):
    """MuJoCo's model of `path`, contacts off; `bare`: limits and dampers off, armature and dry friction 0."""
    import mujoco

    m = mujoco.MjModel.from_xml_path(str(path))
    if bare:
        return comparable(m, ("contact", "limit", "damper"))
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    return m


def mujoco_diverged(m, qvel: np.ndarray, h: float, duration: float) -> bool:
    """Whether MuJoCo, with the model's own integrator at steps of h (set on `m`, the variant's compiled model),
    warned of a bad acceleration (it resets the state then) within `duration` s from joint rates `qvel`."""
    import mujoco

    m.opt.timestep = h
    d = mujoco.MjData(m)
    d.qvel[:] = qvel
    mujoco.mj_step(m, d, nstep=max(1, round(duration / h)))
    return int(d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number) > 0


def run(model, order: int, h: float, duration: float, budget: float) -> dict:
    """One run of ours, in chunks of 0.1 s, stopped where its CPU time passes `budget` s (`reached` says where)."""
    import warpimpulse as wi

    steps = max(1, round(duration / h))
    chunk = max(1, round(0.1 / h))
    solves = substeps = taken = 0
    worst = 0.0
    try:
        sim = wi.Simulator(model, h, tolerance=TOLERANCE, order=order)
        sim.step(1)  # compiles the kernels (cached on disk after the first model of a kind)
        start = time.process_time()
        while taken < steps - 1 and time.process_time() - start < budget:
            n = min(chunk, steps - 1 - taken)
            stats = sim.step(n)
            solves, substeps = solves + stats.linear_iterations, substeps + stats.substeps
            worst = max(worst, stats.max_joint_error) if math.isfinite(stats.max_joint_error) else worst
            taken += n
        seconds = time.process_time() - start
    except (wi.SimulationError, wi.SceneError, ValueError) as err:
        return {"failed": one_line(err)}
    if not taken:
        return {"failed": None, "solves": None, "substeps": None, "joint_error": None, "us_per_step": None}
    return {
        "failed": None,
        "reached": (taken + 1) * h,  # s: the simulated time, `duration` unless the budget ran out
        "solves": solves / taken,
        "substeps": substeps / taken,
        "joint_error": worst,
        "us_per_step": 1e6 * seconds / taken,
    }


def probe(name: str, path: Path, duration: float, budget: float) -> dict:
    """Every run of one model (both variants, both orders, both step sizes)."""
    import warpimpulse as wi

    row: dict = {"model": name, "variants": {}}
    for variant in ("shipped", "bare"):
        bare = variant == "bare"
        m = compiled(path, bare)
        qvel = np.random.default_rng(SEED).standard_normal(m.nv)
        entry: dict = {"load": "ok", "refused": ""}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                try:
                    builder = wi.load_mjcf(m, qvel=qvel)
                except wi.SceneError as err:
                    entry.update(load="ignore_unsupported", refused=one_line(err))
                    builder = wi.load_mjcf(m, qvel=qvel, ignore_unsupported=True)
                model = builder.finalize("cpu")
            except (wi.SceneError, ValueError) as err:
                entry.update(load="refused", refused=one_line(err))
                row["variants"][variant] = entry
                continue
        entry["bodies"] = len(builder.bodies)
        timestep = float(m.opt.timestep)
        entry["timestep"] = timestep
        entry["runs"] = []
        for scale in (1, 2):
            h = scale * timestep
            diverged = mujoco_diverged(m, qvel, h, duration)  # after load_mjcf, which read m's own step
            for order in (2, 4):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    result = run(model, order, h, duration, budget)
                entry["runs"].append({"order": order, "h": h, "mujoco_diverged": diverged, **result})
        row["variants"][variant] = entry
    return row


def cell(r: dict, duration: float) -> str:
    if r["failed"]:
        return "failed"
    if r["solves"] is None:
        return ""
    sub = "" if r["substeps"] <= 1.0 else f", {r['substeps']:.2f} sub"
    short = f" (to {r['reached']:.2g} s: the budget)" if r["reached"] < duration - r["h"] else ""
    return f"{r['solves']:.1f}{sub}{short}"


def markdown(results: dict) -> str:
    """The table: solves a step (and substeps a step above 1) per run; failures listed below it."""
    lines = [
        "| model | variant | bodies | h (s) | MuJoCo at h / 2h | order 2 at h | order 4 at h | order 2 at 2h "
        "| order 4 at 2h |",
        "|---|---|---:|---:|---|---|---|---|---|",
    ]
    notes = []
    for row in results["models"]:
        for variant, e in row["variants"].items():
            if e["load"] == "refused":
                notes.append(f"- {row['model']} ({variant}): refused: {e['refused']}")
                continue
            if e["refused"]:
                notes.append(f"- {row['model']} ({variant}): loaded with ignore_unsupported; strict: {e['refused']}")
            runs = {(r["order"], round(r["h"] / e["timestep"])): r for r in e["runs"]}
            mj = "/".join("diverged" if runs[(2, s)]["mujoco_diverged"] else "ok" for s in (1, 2))
            cells = [cell(runs[(o, s)], results["meta"]["duration"]) for s in (1, 2) for o in (2, 4)]
            lines.append(
                f"| {row['model']} | {variant} | {e['bodies']} | {e['timestep']:g} | {mj} | " + " | ".join(cells) + " |"
            )
            for r in e["runs"]:
                if r["failed"]:
                    notes.append(f"- {row['model']} ({variant}), order {r['order']}, h = {r['h']:g}: {r['failed']}")
    meta = results["meta"]
    head = (f"Measured {meta['date']} on {meta['machine']} ({meta['seconds']:.0f} s), {meta['duration']:g} s a run, "
            f"tolerance {TOLERANCE:g}; cells: linear solves a step (and substeps a step where steps were split or "
            "halved). `python benchmarks/mjcf_robots.py`.\n\n")  # fmt: skip
    return head + "\n".join(lines) + ("\n\nFailures and refusals:\n\n" + "\n".join(notes) if notes else "") + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", nargs="*", default=None, help="g/<name> or d/<name>; default: all")
    parser.add_argument("--duration", type=float, default=2.0)
    parser.add_argument("--budget", type=float, default=10.0, help="CPU seconds a run at most (its row says so)")
    parser.add_argument("--json", default=str(ROOT / "benchmarks/results/mjcf_robots.json"))
    parser.add_argument("--markdown", default=str(ROOT / "benchmarks/results/mjcf_robots.md"))
    parser.add_argument("--from-json", action="store_true", help="only the table again, from the JSON")
    args = parser.parse_args(argv)
    if args.from_json:
        Path(args.markdown).write_text(markdown(json.loads(Path(args.json).read_text())))
        return 0
    from warpimpulse.bench.harness import quiet_warp

    quiet_warp()
    paths = model_paths()
    names = args.models or list(paths)
    unknown = [n for n in names if n not in paths]
    if unknown:
        print(f"mjcf_robots: unknown model {unknown[0]!r}; known: {', '.join(paths)}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    rows = []
    for name in names:
        rows.append(probe(name, paths[name], args.duration, args.budget))
        print(f"{name}: done", file=sys.stderr, flush=True)
    results = {
        "meta": {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "seconds": time.perf_counter() - start,
                 "machine": f"{platform.machine()}, {os.cpu_count()} cores", "duration": args.duration, "seed": SEED,
                 "tolerance": TOLERANCE},
        "models": rows,
    }  # fmt: skip
    Path(args.json).write_text(json.dumps(results, indent=1))
    Path(args.markdown).write_text(markdown(results))
    print(markdown(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
