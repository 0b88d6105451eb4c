"""The SceneBuilder's one-at-a-time adds: add_body, add_joint_revolute and a whole scenes.chain(n), timed as
medians of repeated runs (`timeit`), written to benchmarks/results/builder.json.

The bulk path (add_bodies / add_joints) is measured by benchmarks/scaling.py (tree set-up); this one guards the
path that the USD reader, hand-written scenes and every non-tree scene take: one call per body or joint.

    python benchmarks/builder.py [--chain 5000] [--repeat 7] [--out benchmarks/results/builder.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import timeit
from pathlib import Path

import numpy as np

from warpimpulse import scenes
from warpimpulse.builder import SceneBuilder

ROWS = 2000  # adds per timed run: enough to amortise the timer, few enough to stay in the builder's small sizes


def per_add_us(stmt, setup, repeat: int) -> float:
    """The median over `repeat` runs of one add's time (us), each run doing ROWS adds on a fresh builder."""
    runs = []
    for _ in range(repeat):
        state = setup()
        start = timeit.default_timer()
        stmt(state)
        runs.append((timeit.default_timer() - start) / ROWS * 1e6)
    return statistics.median(runs)


def add_bodies_one_by_one(builder: SceneBuilder) -> None:
    for i in range(ROWS):
        builder.add_body(1.0, (0.1, 0.2, 0.25), (float(i), 0.0, 0.0))


def add_hinges_one_by_one(builder: SceneBuilder) -> None:
    for i in range(ROWS):
        builder.add_joint_revolute(i - 1 if i else None, i, (i - 0.5, 0.0, 0.0), (0.0, 1.0, 0.0))


def with_bodies() -> SceneBuilder:
    builder = SceneBuilder()
    add_bodies_one_by_one(builder)
    return builder


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--chain", type=int, default=5000, help="links of the timed scenes.chain")
    parser.add_argument("--repeat", type=int, default=7, help="timed runs per figure (the median is kept)")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "builder.json")
    args = parser.parse_args()
    body_us = per_add_us(add_bodies_one_by_one, SceneBuilder, args.repeat)
    joint_us = per_add_us(add_hinges_one_by_one, with_bodies, args.repeat)
    chain_s = statistics.median(timeit.repeat(lambda: scenes.chain(args.chain), number=1, repeat=args.repeat))
    result = {
        "add_body_us": round(body_us, 2),
        "add_joint_revolute_us": round(joint_us, 2),
        f"chain{args.chain}_build_s": round(chain_s, 4),
        "repeat": args.repeat,
        "rows_per_run": ROWS,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "machine": platform.machine(),
    }
    print(json.dumps(result, indent=2))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
