"""Reproduce the method paper's Tables 1-3 (section 5) on this machine, beside the paper's figures.

    python benchmarks/paper_tables.py [--steps 90] [--json benchmarks/results/paper_tables.json]

Trees of 31-255 bodies at tolerances 1e-2, 1e-4, 1e-6, with the system of linear equations (SLE,
our sparse Cholesky) and without it (the paper's iterative method); the 127-body star at 1e-4.
Time per step is the median over the run after a warm-up; iterations are means.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import warp as wp

import warpimpulse as wi
from warpimpulse import scenes

# Pentium 4 3.4 GHz, ms per step (Tables 2 and 3) and Table 1's iteration counts.
PAPER_WITHOUT = {
    31: (0.97, 6.78, 14.31),
    63: (2.48, 28.46, 67.50),
    127: (6.25, 87.05, 228.57),
    255: (15.86, 246.71, 703.48),
}
PAPER_WITH = {31: (3.23, 3.54, 3.79), 63: (7.12, 7.14, 7.69), 127: (18.78, 18.95, 20.09), 255: (62.06, 63.21, 63.61)}
PAPER_TABLE1 = {"iterative": {"ms": 228.57, "jc": 518.15, "vc": 745.54}, "cholesky": {"ms": 20.09, "jc": 2, "vc": 1}}
TOLERANCES = (1e-2, 1e-4, 1e-6)
DT = 1.0 / 30.0


def measure(builder: wi.SceneBuilder, solver: str, tolerance: float, steps: int, warmup: int = 3) -> dict:
    sim = wi.Simulator(builder.finalize(), DT, tolerance=tolerance, solver=solver, max_iterations=100_000)
    times, jc, vc = [], [], []
    for i in range(warmup + steps):
        t = time.perf_counter()
        stats = sim.step()
        if i >= warmup:
            times.append(time.perf_counter() - t)
            jc.append(stats.joint_iterations)
            vc.append(stats.velocity_iterations)
    return {
        "solver": solver,
        "tolerance": tolerance,
        "steps": steps,
        "median_ms": 1e3 * statistics.median(times),
        "mean_ms": 1e3 * statistics.fmean(times),
        "joint_iterations": statistics.fmean(jc),
        "velocity_iterations": statistics.fmean(vc),
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=90, help="timed steps per case (default: 3 s at 30 Hz)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[31, 63, 127, 255])
    parser.add_argument("--json", type=Path, default=Path(__file__).parent / "results" / "paper_tables.json")
    args = parser.parse_args(argv)
    wp.config.quiet = True
    wp.init()

    rows = []
    for n in args.sizes:
        for solver in ("iterative", "cholesky"):
            for tol in TOLERANCES:
                r = measure(scenes.binary_tree(n), solver, tol, args.steps)
                r["scene"] = f"tree{n}"
                rows.append(r)
    star = [measure(scenes.star(127), s, 1e-4, args.steps) | {"scene": "star127"} for s in ("iterative", "cholesky")]

    def cell(scene, solver, tol):
        return next(r for r in rows if r["scene"] == scene and r["solver"] == solver and r["tolerance"] == tol)

    print("## Table 1: tree of 127 bodies, h = 1/30 s, tolerance 1e-6\n")
    print("| | paper without SLE | ours without SLE | paper with SLE | ours with SLE |")
    print("|---|---:|---:|---:|---:|")
    it, ch = cell("tree127", "iterative", 1e-6), cell("tree127", "cholesky", 1e-6)
    p_it, p_ch = PAPER_TABLE1["iterative"], PAPER_TABLE1["cholesky"]
    print(f"| time per step (ms) | {p_it['ms']} | {it['median_ms']:.3f} | {p_ch['ms']} | {ch['median_ms']:.3f} |")
    print(f"| joint-correction iterations | {p_it['jc']} | {it['joint_iterations']:.2f} | {p_ch['jc']} | "
          f"{ch['joint_iterations']:.2f} |")  # fmt: skip
    print(f"| velocity-correction iterations | {p_it['vc']} | {it['velocity_iterations']:.2f} | {p_ch['vc']} | "
          f"{ch['velocity_iterations']:.2f} |\n")  # fmt: skip

    for title, solver, paper in (
        ("Table 2: without SLE", "iterative", PAPER_WITHOUT),
        ("Table 3: with SLE", "cholesky", PAPER_WITH),
    ):
        print(f"## {title}, ms per step (paper / ours), mean joint iterations in brackets\n")
        print("| | " + " | ".join(f"{t:g}" for t in TOLERANCES) + " |")
        print("|---|" + "---:|" * len(TOLERANCES))
        for n in args.sizes:
            cells = []
            for k, tol in enumerate(TOLERANCES):
                r = cell(f"tree{n}", solver, tol)
                ref = paper[n][k] if n in paper else float("nan")
                cells.append(f"{ref} / {r['median_ms']:.3f} ({r['joint_iterations']:.1f})")
            print(f"| tree {n} | " + " | ".join(cells) + " |")
        print()
    s_it, s_ch = star
    print("## Star of 127 (all joints on the root), tolerance 1e-4\n")
    print("| | without SLE | with SLE | speed-up |")
    print("|---|---:|---:|---:|")
    speedup = s_it["median_ms"] / s_ch["median_ms"]
    print(f"| ms per step | {s_it['median_ms']:.3f} | {s_ch['median_ms']:.3f} | {speedup:.1f}x (paper: almost 80x) |")
    print(f"| joint iterations | {s_it['joint_iterations']:.1f} | {s_ch['joint_iterations']:.1f} | |")

    result = {
        "machine": {"processor": platform.processor() or platform.machine(), "python": platform.python_version(),
                    "warp": wp.config.version},
        "dt": DT,
        "rows": rows,
        "star": star,
        "paper": {"without_sle": PAPER_WITHOUT, "with_sle": PAPER_WITH, "table1": PAPER_TABLE1},
    }  # fmt: skip
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1))
    print(f"\nwrote {args.json}")
    return result


if __name__ == "__main__":
    main()
