"""What reusing K's factor across steps (`StepOptions.reuse_factor`) saves, against factoring at every step.

For each scene (the 7-hinge arm of benchmarks/models/arm7.xml, hinge chains of 20 and 50, the paper's tree of 127
ball joints, benchmark/scene_kinds.py's humanoid), step size and order (tolerance 1e-6): two simulators, reuse off
and on, each timed in blocks of `STEPS` steps as one `step(STEPS)` and as one `step()` a call, every block from
the same state (`reset()` and one untimed step), the two interleaved, `ROUNDS` rounds; CPU time of this process
(`time.process_time`), the garbage collector held off during a block; the median block. Per step: joint solves,
K's factorizations by the fused kernel (`Simulator.factorizations`); and the largest difference of the body
centres after the blocks (m), reuse on against off, which should be about the tolerance.

    python benchmarks/reuse_factor.py [--rounds 5] [--json benchmarks/results/reuse_factor.json]
"""

from __future__ import annotations

import argparse
import gc
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import warpimpulse as wi
from warpimpulse import scenes
from warpimpulse.bench.harness import metadata

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
import scene_kinds  # noqa: E402

JSON = ROOT / "benchmarks/results/reuse_factor.json"
STEPS = 240
TOLERANCE = 1e-6
SCENES = {
    "arm7": lambda: wi.load_mjcf(ROOT / "benchmarks/models/arm7.xml"),
    "chain20": lambda: scenes.chain(20),
    "chain50": lambda: scenes.chain(50),
    "tree127": lambda: scenes.binary_tree(127),
    "humanoid": scene_kinds.humanoid,
}


def block(sim: wi.Simulator, one_a_call: bool) -> tuple[float, float, float, np.ndarray]:
    """(CPU s, joint solves, factorizations) of STEPS steps from the built state, and the centres after."""
    sim.reset()
    sim.step()
    before = sim.factorizations
    gc.disable()
    start = time.process_time()
    if one_a_call:
        stats = [sim.step() for _ in range(STEPS)]
    else:
        stats = [sim.step(STEPS)]
    spent = time.process_time() - start
    gc.enable()
    solves = sum(s.joint_iterations for s in stats)
    return spent, solves, sim.factorizations - before, sim.state.body_x.numpy().copy()


def measure(name: str, rate: int, order: int, rounds: int) -> dict:
    model = SCENES[name]().finalize("cpu")
    sims = {
        reuse: wi.Simulator(model, 1.0 / rate, tolerance=TOLERANCE, order=order,
                            options=wi.StepOptions(reuse_factor=reuse))
        for reuse in (False, True)
    }  # fmt: skip
    row = dict(scene=name, rate=rate, order=order, bodies=model.body_count)
    for mode in ("many", "one"):
        times = {False: [], True: []}
        last = {}
        for _ in range(rounds):
            for reuse, sim in sims.items():
                spent, solves, factors, x = block(sim, mode == "one")
                times[reuse].append(spent)
                last[reuse] = (solves, factors, x)
        for reuse in (False, True):
            key = f"{mode}_{'reuse' if reuse else 'always'}"
            row[f"{key}_us"] = statistics.median(times[reuse]) / STEPS * 1e6
            row[f"{key}_solves"] = last[reuse][0] / STEPS
            row[f"{key}_factors"] = last[reuse][1] / STEPS
        row[f"{mode}_dx"] = float(np.abs(last[True][2] - last[False][2]).max())
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--scenes", nargs="*", default=list(SCENES))
    p.add_argument("--json", type=Path, default=JSON)
    args = p.parse_args()
    rows = []
    for name in args.scenes:
        for rate in (120, 480):
            for order in (2, 4):
                row = measure(name, rate, order, args.rounds)
                rows.append(row)
                print(
                    f"{name:9s} 1/{rate} order {order}: step({STEPS}) {row['many_always_us']:.1f} -> "
                    f"{row['many_reuse_us']:.1f} us, solves {row['many_always_solves']:.2f} -> "
                    f"{row['many_reuse_solves']:.2f}, factors {row['many_always_factors']:.2f} -> "
                    f"{row['many_reuse_factors']:.2f}, dx {row['many_dx']:.1e}; step() {row['one_always_us']:.1f} -> "
                    f"{row['one_reuse_us']:.1f} us, dx {row['one_dx']:.1e}",
                    flush=True,
                )
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps(dict(meta=metadata(sys.argv), steps=STEPS, tolerance=TOLERANCE, rows=rows), indent=1)
    )


if __name__ == "__main__":
    main()
