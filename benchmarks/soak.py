"""Soak test: long runs with checkpoints and resumes, watching joint drift, energy drift and memory.

    python benchmarks/soak.py [--tree31-steps 1000000] [--tree127-steps 100000] [--checkpoint-every 10000]
                              [--json benchmarks/results/soak.json]

Each scene (the paper's binary trees, ball joints, h = 1/30 s, tolerance 1e-6) runs its steps in one
process. Every `--checkpoint-every` steps the run saves a checkpoint, drops its simulator, builds the scene
and a new simulator from scratch (as a restarted process would) and resumes from the file; the resumed
state must equal the saved one bit for bit. Reported over the run:
- joint drift: the largest joint error any step ended with (StepStats) and the largest error measured
  from the state at the checkpoints (Simulator.joint_errors), in m or rad; both must stay <= the tolerance;
- energy drift: `EnergyWatch`, sampled every `--energy-every` steps after the start torque (first second):
  the worst gain and the final drift, as fractions of the largest kinetic energy seen;
- memory: the process's resident set size and its anonymous part (heap and arrays, what a leak grows) at
  every checkpoint. The anonymous part must stay flat: from the first checkpoint to the last it may grow by
  at most 16 MiB (allocator noise), else the exit status is 1.
"""

from __future__ import annotations

import argparse
import gc
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from warpimpulse import scenes
from warpimpulse.bench.harness import quiet_warp
from warpimpulse.energy import EnergyWatch
from warpimpulse.simulator import Simulator

DT, TOLERANCE = 1.0 / 30.0, 1e-6
MEMORY_SLACK_MIB = 16.0


def memory_mib() -> tuple[float, float]:
    """(resident set size, its anonymous part) of this process, MiB (Linux /proc). The anonymous part (heap,
    arrays) is what a leak grows; the rest is mapped files (libraries, Warp's kernels), which the kernel may
    drop from memory and read back at will."""
    fields = dict(line.split(":", 1) for line in Path("/proc/self/status").read_text().splitlines() if ":" in line)
    return tuple(int(fields.get(k, "0 kB").split()[0]) / 1024.0 for k in ("VmRSS", "RssAnon"))


def _simulator(bodies: int) -> Simulator:
    return Simulator(scenes.binary_tree(bodies).finalize("cpu"), DT, tolerance=TOLERANCE)


def soak(bodies: int, steps: int, every: int, energy_every: int, folder: Path) -> dict:
    """Run `steps` steps of the `bodies`-body tree with a checkpoint and a resume every `every` steps."""
    sim = _simulator(bodies)
    watch = EnergyWatch(sim)
    path = folder / f"tree{bodies}.npz"
    step_error, state_error, resumes, memory = 0.0, 0.0, 0, []
    start = time.perf_counter()
    for k in range(1, steps + 1):
        stats = sim.step()
        step_error = max(step_error, stats.max_joint_error)
        if k % energy_every == 0:
            watch.sample()
        if k % every == 0 or k == steps:
            state_error = max(state_error, float(sim.joint_errors().max()))
            sim.save_checkpoint(path)
            saved = [a.numpy().copy() for a in (sim.state.body_x, sim.state.body_q, sim.state.body_v, sim.state.body_w)]
            del sim
            gc.collect()
            sim = _simulator(bodies)  # a restarted process: new scene, model and simulator
            sim.load_checkpoint(path)
            resumed = [a.numpy() for a in (sim.state.body_x, sim.state.body_q, sim.state.body_v, sim.state.body_w)]
            if not all(np.array_equal(a, b) for a, b in zip(saved, resumed)):
                raise SystemExit(f"tree{bodies}: the resumed state differs from the saved one at step {k}")
            watch.sim = sim
            resumes += 1
            memory.append((k, *memory_mib()))
            elapsed = time.perf_counter() - start
            print(
                f"tree{bodies}: step {k:>8d}  joint error {step_error:.2e} (state {state_error:.2e})  "
                f"energy gain {watch.gain if watch.gain is not None else float('nan'):+.2e}  "
                f"RSS {memory[-1][1]:.1f} MiB (anonymous {memory[-1][2]:.1f})  {elapsed:.0f} s",
                file=sys.stderr,
                flush=True,
            )
    elapsed = time.perf_counter() - start
    growth = memory[-1][2] - memory[0][2]
    return {
        "scene": f"tree{bodies}",
        "steps": steps,
        "simulated_s": steps * DT,
        "checkpoint_every": every,
        "resumes": resumes,
        "seconds": elapsed,
        "ms_per_step": 1e3 * elapsed / steps,
        "max_step_joint_error": step_error,
        "max_state_joint_error": state_error,
        "joints_held": step_error <= TOLERANCE and state_error <= TOLERANCE,
        "energy_gain": watch.gain,
        "energy_drift": watch.drift,
        "energy_scale_J": watch.scale,
        "rss_mib": [[k, round(m, 2)] for k, m, _ in memory],
        "anonymous_mib": [[k, round(a, 2)] for k, _, a in memory],
        "anonymous_growth_mib": growth,
        "memory_flat": growth <= MEMORY_SLACK_MIB,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--tree31-steps", type=int, default=1_000_000)
    p.add_argument("--tree127-steps", type=int, default=100_000)
    p.add_argument("--checkpoint-every", type=int, default=10_000)
    p.add_argument("--energy-every", type=int, default=1_000)
    p.add_argument("--json", type=Path, help="write the results here")
    args = p.parse_args(argv)
    quiet_warp()
    results = []
    with tempfile.TemporaryDirectory() as folder:
        for bodies, steps in ((31, args.tree31_steps), (127, args.tree127_steps)):
            if steps > 0:
                every = min(args.checkpoint_every, steps)
                results.append(soak(bodies, steps, every, min(args.energy_every, every), Path(folder)))
    ok = all(r["joints_held"] and r["memory_flat"] for r in results)
    report = {"machine": platform.processor() or platform.machine(), "dt": DT, "tolerance": TOLERANCE,
              "memory_slack_mib": MEMORY_SLACK_MIB, "ok": ok, "runs": results}  # fmt: skip
    text = json.dumps(report, indent=1)
    if args.json:
        args.json.write_text(text + "\n")
    for r in results:
        print(
            f"{r['scene']}: {r['steps']} steps ({r['resumes']} resumes) in {r['seconds']:.0f} s, "
            f"joint error <= {max(r['max_step_joint_error'], r['max_state_joint_error']):.2e}, "
            f"energy gain {r['energy_gain']:+.2e} drift {r['energy_drift']:+.2e}, "
            f"anonymous memory {r['anonymous_mib'][0][1]:.1f} -> {r['anonymous_mib'][-1][1]:.1f} MiB "
            f"(RSS {r['rss_mib'][0][1]:.1f} -> {r['rss_mib'][-1][1]:.1f})"
        )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
