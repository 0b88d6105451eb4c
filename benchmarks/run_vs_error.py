"""Run time against error: warpimpulse, MuJoCo (Euler, implicitfast, RK4) and pinocchio (RK4) on the sweep's scenes.

    python benchmarks/run_vs_error.py [--quick] [--json FILE] [--plots DIR] [--report FILE] [...]

A thin wrapper over `warpimpulse.bench.cli` (the same options as `warpimpulse bench`), without scaling.
"""

import sys

from warpimpulse.bench.cli import bench

if __name__ == "__main__":
    raise SystemExit(bench(["--no-scaling", *sys.argv[1:]]))
