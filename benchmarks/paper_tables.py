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
from warpimpulse.bench.harness import quiet_warp
from warpimpulse.bench.report import paper_markdown

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
    quiet_warp()
    wp.init()

    rows = []
    for n in args.sizes:
        for solver in ("iterative", "cholesky"):
            for tol in TOLERANCES:
                r = measure(scenes.binary_tree(n), solver, tol, args.steps)
                r["scene"] = f"tree{n}"
                rows.append(r)
    star = [measure(scenes.star(127), s, 1e-4, args.steps) | {"scene": "star127"} for s in ("iterative", "cholesky")]
    result = {
        "machine": {"processor": platform.processor() or platform.machine(), "python": platform.python_version(),
                    "warp": wp.config.version},
        "dt": DT,
        "rows": rows,
        "star": star,
        "paper": {"without_sle": PAPER_WITHOUT, "with_sle": PAPER_WITH, "table1": PAPER_TABLE1},
    }  # fmt: skip
    print("\n".join(paper_markdown(result)))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1))
    print(f"\nwrote {args.json}")
    return result


if __name__ == "__main__":
    main()
