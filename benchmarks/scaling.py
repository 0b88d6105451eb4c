"""Scaling: time per step and per body per step, binary trees of 31..65535 bodies and chains to 10,000 links.

    python benchmarks/scaling.py [--quick] [--json FILE] [--plots DIR] [--report FILE] [--scaling-budget SECONDS]

A thin wrapper over `warpimpulse.bench.cli` (the same options as `warpimpulse bench`), without the sweep.
"""

import sys

from warpimpulse.bench.cli import bench

if __name__ == "__main__":
    raise SystemExit(bench(["--no-sweep", *sys.argv[1:]]))
