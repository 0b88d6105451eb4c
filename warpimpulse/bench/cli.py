"""The harness's commands: `warpimpulse bench` (run time against error and scaling, with MuJoCo and pinocchio
as peers) and `warpimpulse stress` (the stress suite). `warpimpulse.cli` dispatches here.

`warpimpulse bench` measures and writes JSON, plots and the markdown report where asked; it never edits
README.md (`python -m warpimpulse.bench.report --readme`, run by `make bench`, does).
`benchmarks/run_vs_error.py` and `benchmarks/scaling.py` call `bench` with one half switched off.
"""

from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path

from ..cliutil import EXIT_USAGE, ArgumentParser
from ..types import SOLVERS
from . import report, stress
from .harness import (
    MUJOCO_RATES,
    QUICK_MUJOCO_RATES,
    QUICK_ORDERS,
    QUICK_RATES,
    QUICK_SCALING_BUDGET,
    QUICK_SCALING_CHAINS,
    QUICK_SCALING_TREES,
    QUICK_SCENES,
    QUICK_TOLERANCES,
    SCALING_BUDGET,
    SCALING_CHAINS,
    SCALING_REPEATS,
    SCALING_STEPS,
    SCALING_TREES,
    SWEEP_ORDERS,
    SWEEP_RATES,
    SWEEP_SCENES,
    SWEEP_TOLERANCES,
    metadata,
    quiet_warp,
    run_vs_error,
    scaling,
)

BENCH_MODULES = ("mujoco", "pinocchio", "matplotlib")  # what the `bench` extra installs, by import name
INSTALL_HINT = "pip install 'warpimpulse[bench]' (in a checkout: pip install -e '.[bench]')"


def missing_modules(names: tuple[str, ...] = BENCH_MODULES) -> list[str]:
    """The modules among `names` that do not import."""
    missing = []
    for name in names:
        try:
            importlib.import_module(name)
        except ImportError:
            missing.append(name)
    return missing


def parser() -> ArgumentParser:
    p = ArgumentParser(prog="warpimpulse bench", description="run time against error and scaling, against MuJoCo "
                       "and pinocchio; `python -m warpimpulse.bench.report` writes up earlier JSON")  # fmt: skip
    p.add_argument("--quick", action="store_true", help="reduced sweep and scaling, under 5 minutes on 2 cores")
    p.add_argument("--json", type=Path, help="write every raw number here")
    p.add_argument("--plots", type=Path, help="write the PNG plots into this directory")
    p.add_argument("--report", type=Path, help="write the full markdown report (the stdout table) here too")
    p.add_argument("--scenes", nargs="+", help=f"scenes of the sweep (default {' '.join(SWEEP_SCENES)})")
    p.add_argument("--solver", default="auto", choices=SOLVERS)
    p.add_argument("--orders", type=int, nargs="+", choices=(2, 4, 6),
                   help="our orders in time (default 2 4 6, quick 2 4); 4, 6 at their default tolerance")  # fmt: skip
    p.add_argument("--repeats", type=int, help="timed repeats per configuration (default 5, quick 3)")
    p.add_argument("--no-sweep", action="store_true", help="skip run time against error")
    p.add_argument("--no-scaling", action="store_true", help="skip scaling")
    p.add_argument("--trees", type=int, nargs="*", help="tree sizes of the scaling (default 31 ... 65535, quick "
                   "31 ... 2047); 2^k - 1 bodies")  # fmt: skip
    p.add_argument("--chains", type=int, nargs="*", help="chain lengths of the scaling (default 10 ... 10000)")
    p.add_argument("--scaling-budget", type=float, help="seconds allowed per scaling point (default 300, quick 40)")
    p.add_argument("--no-progress", action="store_true")
    return p


def bench(argv: list[str]) -> int:
    """`warpimpulse bench`: measure, then write the JSON, the plots and the report where asked."""
    args = parser().parse_args(argv)
    missing = missing_modules()
    if missing:
        print(f"warpimpulse bench: error: needs the bench extra ({', '.join(missing)} missing): {INSTALL_HINT}",
              file=sys.stderr)  # fmt: skip
        return EXIT_USAGE
    quiet_warp()
    meta = metadata(argv)
    results: dict = {}
    repeats = args.repeats or (3 if args.quick else 5)
    if not args.no_sweep:
        results["run_vs_error"] = run_vs_error(
            args.scenes or (QUICK_SCENES if args.quick else SWEEP_SCENES),
            QUICK_RATES if args.quick else SWEEP_RATES,
            QUICK_TOLERANCES if args.quick else SWEEP_TOLERANCES,
            repeats, args.solver, not args.no_progress,
            args.orders or (QUICK_ORDERS if args.quick else SWEEP_ORDERS),
            QUICK_MUJOCO_RATES if args.quick else MUJOCO_RATES,
        ) | {"meta": meta}  # fmt: skip
    if not args.no_scaling:
        budget = args.scaling_budget or (QUICK_SCALING_BUDGET if args.quick else SCALING_BUDGET)
        rows = scaling(
            args.trees if args.trees is not None else QUICK_SCALING_TREES if args.quick else SCALING_TREES,
            args.chains if args.chains is not None else QUICK_SCALING_CHAINS if args.quick else SCALING_CHAINS,
            steps=SCALING_STEPS, repeats=SCALING_REPEATS, budget_s=budget, progress=not args.no_progress,
        )  # fmt: skip
        results["scaling"] = {"meta": meta, "budget_s": budget, "steps": SCALING_STEPS,
                              "repeats": SCALING_REPEATS, "rows": rows}  # fmt: skip
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=1))
    sys.stdout.write(report.write(results, args.plots, args.report))
    return 0


def main(command: str, argv: list[str]) -> int:
    """Run `warpimpulse bench` or `warpimpulse stress` with the arguments after the command."""
    if command == "stress":
        return stress.main(argv)
    return bench(argv)
