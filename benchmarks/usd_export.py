"""USD export speed: our Sdf-API writer vs a plain UsdGeom / attr.Set writer vs the PointInstancer mode.

    python benchmarks/usd_export.py                 # 1,000 bodies x 300 frames and 10,000 x 100, 3 runs each
    python benchmarks/usd_export.py --cases 200x50 --repeats 1  # a quick look

Every writer gets the same bodies (capsules) and the same frames (a cheap closed-form motion, generated
frame by frame, so no writer holds the whole animation) and writes a binary .usd file. Each run is a
fresh process so that its peak resident memory is its own; the methods take turns, run by run, so that a
busy spell on a shared machine hits them alike. Prints medians and per-run speed-ups and writes
benchmarks/results/usd_export.json. The bar (issue 3): writer >= 3x faster than plain, instancer >= 50x.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
METHODS = ("plain", "writer", "instancer")


def rss_mb() -> float:
    """Current resident set size (Linux), MiB."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def make_builder(n: int):
    from warpimpulse import SceneBuilder, Shape

    b = SceneBuilder()
    shape = Shape("capsule", radius=0.05, length=0.4, color=(0.3, 0.5, 0.8))
    inertia = shape.inertia(1.0)
    side = int(np.ceil(np.sqrt(n)))
    for i in range(n):
        b.add_body(1.0, inertia, (i % side, i // side, 0.0), name=f"b{i}", shape=shape)
    return b


GEN = {"wall": 0.0, "cpu": 0.0}  # time spent making frames, subtracted from every writer's time


def frame(base: np.ndarray, f: int) -> tuple[np.ndarray, np.ndarray]:
    """Positions and unit quaternions (x, y, z, w) of every body at frame f (its cost is not counted)."""
    w0, c0 = time.perf_counter(), time.process_time()
    x, q = _frame(base, f)
    GEN["wall"] += time.perf_counter() - w0
    GEN["cpu"] += time.process_time() - c0
    return x, q


def _frame(base: np.ndarray, f: int) -> tuple[np.ndarray, np.ndarray]:
    n = len(base)
    t = 0.04 * f
    phase = np.arange(n) * 0.01
    x = base + np.stack([np.sin(t + phase), np.cos(t + phase), 0.1 * t * np.ones(n)], axis=1)
    half = 0.5 * (t + phase)
    q = np.stack([np.zeros(n), np.sin(half) * 0.6, np.sin(half) * 0.8, np.cos(half)], axis=1)
    return x, q


def run_plain(b, path: str, frames: int, fps: float) -> None:
    """What a straightforward script does: UsdGeom schemas and attr.Set per body per frame."""
    from pxr import Gf, Usd, UsdGeom

    stage = Usd.Stage.CreateNew(path)
    UsdGeom.SetStageUpAxis(stage, "Z")
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(frames - 1)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    ops = []
    for body in b.bodies:
        x = UsdGeom.Xform.Define(stage, f"/World/{body.name}")
        t_op = x.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble)
        q_op = x.AddOrientOp(UsdGeom.XformOp.PrecisionDouble)
        g = UsdGeom.Capsule.Define(stage, f"/World/{body.name}/geom")
        g.CreateRadiusAttr(body.shape.radius)
        g.CreateHeightAttr(body.shape.length)
        g.CreateAxisAttr("Z")
        g.CreateDisplayColorAttr([Gf.Vec3f(*body.shape.color)])
        ops.append((t_op.GetAttr(), q_op.GetAttr()))
    base = np.array([body.position for body in b.bodies])
    for f in range(frames):
        x, q = frame(base, f)
        for (ta, qa), xi, qi in zip(ops, x.tolist(), q.tolist()):
            ta.Set(Gf.Vec3d(*xi), f)
            qa.Set(Gf.Quatd(qi[3], qi[0], qi[1], qi[2]), f)
    stage.Save()


def run_writer(b, path: str, frames: int, fps: float, instancer: bool) -> None:
    from warpimpulse import usd

    base = np.array([body.position for body in b.bodies])
    with usd.AnimationWriter(path, b, fps, {"benchmark": "usd_export"}, instancer=instancer) as w:
        for f in range(frames):
            w.write_frame(f, *frame(base, f))


def child(method: str, n: int, frames: int, out: str) -> dict:
    """One measured run, in this process (started fresh by `main`)."""
    from warpimpulse import usd

    warm = make_builder(2)  # load the USD plugins (file formats, schemas) before the clock starts
    run_writer(warm, out, 2, 30.0, instancer=False)
    run_plain(warm, out, 2, 30.0)
    os.unlink(out)
    usd.load_stage  # noqa: B018
    b = make_builder(n)
    GEN.update(wall=0.0, cpu=0.0)
    rss0 = rss_mb()
    t0, c0 = time.perf_counter(), time.process_time()
    if method == "plain":
        run_plain(b, out, frames, 30.0)
    else:
        run_writer(b, out, frames, 30.0, instancer=(method == "instancer"))
    seconds = time.perf_counter() - t0 - GEN["wall"]
    cpu = time.process_time() - c0 - GEN["cpu"]
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return {
        "method": method,
        "bodies": n,
        "frames": frames,
        "seconds": seconds,
        "cpu_seconds": cpu,
        "us_per_body_frame": 1e6 * seconds / (n * frames),
        "peak_rss_mb": peak,
        "peak_rss_over_start_mb": peak - rss0,
        "file_mb": os.path.getsize(out) / 2**20,
    }


def summarize(rows: list[dict], cases: list[tuple[int, int]], methods: list[str]) -> list[dict]:
    """Per case and method: medians over the repeats, the speed-up of the medians against plain, and the
    speed-up run by run (repeat r of a method against repeat r of plain, which ran just before it)."""
    out = []
    for n, frames in cases:
        group = {m: [r for r in rows if (r["bodies"], r["frames"], r["method"]) == (n, frames, m)] for m in methods}
        plain = group.get("plain", [])
        base = {k: float(np.median([r[k] for r in plain])) for k in ("seconds", "cpu_seconds")} if plain else None
        for m, runs in group.items():
            row = {"method": m, "bodies": n, "frames": frames, "runs": len(runs)}
            row |= {k: float(np.median([r[k] for r in runs])) for k in runs[0] if isinstance(runs[0][k], float)}
            row["speedup_vs_plain"] = base["seconds"] / row["seconds"] if base else None
            row["cpu_speedup_vs_plain"] = base["cpu_seconds"] / row["cpu_seconds"] if base else None
            row["speedup_per_run"] = [p["seconds"] / r["seconds"] for p, r in zip(plain, runs)]
            out.append(row)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", default="1000x300,10000x100", help="BODIESxFRAMES, comma separated")
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--repeats", type=int, default=3, help="runs of each method per case; medians are reported")
    ap.add_argument("--json", default=os.path.join(HERE, "results", "usd_export.json"))
    ap.add_argument("--child", nargs=4, metavar=("METHOD", "BODIES", "FRAMES", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        m, n, f, out = args.child
        print(json.dumps(child(m, int(n), int(f), out)))
        return
    cases = [tuple(int(v) for v in c.split("x")) for c in args.cases.split(",")]
    methods = args.methods.split(",")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n, frames in cases:
            for rep in range(args.repeats):  # methods interleaved, so that a busy spell hits them alike
                for m in methods:
                    out = os.path.join(tmp, f"{m}_{n}x{frames}.usd")
                    proc = subprocess.run(
                        [sys.executable, __file__, "--child", m, str(n), str(frames), out],
                        capture_output=True, text=True, cwd=ROOT,
                    )  # fmt: skip
                    if proc.returncode != 0:
                        sys.exit(f"{m} {n}x{frames} failed:\n{proc.stderr}")
                    row = json.loads(proc.stdout.strip().splitlines()[-1]) | {"repeat": rep}
                    rows.append(row)
                    print(f"  {m:9s} {n:6d} x {frames:4d} #{rep}: {row['seconds']:8.2f} s", flush=True)
    summary = summarize(rows, cases, methods)
    print(f"\nmedians of {args.repeats} runs each")
    print(f"{'bodies x frames':>16} {'method':>10} {'wall s':>9} {'cpu s':>9} {'us/body/frame':>14} {'speed-up':>9} "
          f"{'(cpu)':>7} {'runs':>16} {'peak RSS MiB':>13} {'(+ start)':>10} {'file MiB':>9}")  # fmt: skip
    for r in summary:
        case = f"{r['bodies']} x {r['frames']}"
        sp = f"{r['speedup_vs_plain']:.1f}x" if r["speedup_vs_plain"] else "-"
        csp = f"{r['cpu_speedup_vs_plain']:.1f}x" if r["cpu_speedup_vs_plain"] else "-"
        runs = ",".join(f"{v:.1f}" for v in r["speedup_per_run"])
        print(f"{case:>16} {r['method']:>10} {r['seconds']:9.2f} {r['cpu_seconds']:9.2f} "
              f"{r['us_per_body_frame']:14.2f} {sp:>9} {csp:>7} {runs:>16} {r['peak_rss_mb']:13.1f} "
              f"{r['peak_rss_over_start_mb']:10.1f} {r['file_mb']:9.2f}")  # fmt: skip
    from pxr import Usd

    result = {
        "benchmark": "usd_export",
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "usd": Usd.GetVersion()},
        "bar": {"writer_vs_plain": 3.0, "instancer_vs_plain": 50.0},
        "repeats": args.repeats,
        "summary": summary,
        "rows": rows,
    }
    os.makedirs(os.path.dirname(args.json), exist_ok=True)
    with open(args.json, "w") as f:
        json.dump(result, f, indent=2)
    print(f"\nwrote {os.path.relpath(args.json, ROOT)}")


if __name__ == "__main__":
    main()
