"""Run time against error: warpimpulse, MuJoCo (Euler, implicitfast, RK4) and pinocchio (RK4) on the sweep's scenes.

    python benchmarks/run_vs_error.py [--quick] [--json FILE] [--plots DIR] [--report FILE] [--readme README.md] [...]

A thin wrapper over `warpimpulse.benchmark` (the same options as `warpimpulse bench`), without scaling.
"""

import sys

from warpimpulse.benchmark import main

if __name__ == "__main__":
    raise SystemExit(main(["--no-scaling", *sys.argv[1:]]))
