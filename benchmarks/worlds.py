"""Many worlds, every core: batched worlds against separate simulators, and the speed-up per thread count.

    python benchmarks/worlds.py [--worlds 256] [--bodies 31] [--rounds 7] [--json benchmarks/results/worlds.json]

1. Batched: `worlds` copies of the binary tree (`scenes.binary_tree(bodies)`) as one Model
   (`SceneBuilder.replicate`) on one thread, against `worlds` separate Simulators stepped in a loop: world-steps
   per second of each, and their ratio. Both start from the same state and run the same steps, and the
   batched run is checked to end bit for bit where the separate ones do.
2. Every core: `ThreadedSimulator` on 1, 2, ... cores for 2 worlds of tree4095, 16 of tree255 and the
   batched case above (a share must have kernel work to run in parallel: two worlds of tree31 are mostly
   host work, which holds the GIL): world-steps per second and the speed-up over one thread, with the
   process's CPU time over wall time (near the thread count when the threads really run at once; well under
   it when the machine is busy with other work).
3. A hard world: one world spinning fast takes its steps alone, as substeps; the others' joint iterations are
   counted against a run without it (they should be equal).
Variants are timed in turn, round after round, so load on the machine hits them alike; figures are medians
over the rounds. The machine's load average is recorded with the results, and a control: the speed-up the
same thread counts give a workload that certainly runs in parallel (hashlib's SHA-256 of a large buffer,
which releases the GIL). On a shared or throttled machine the control falls short of the thread count too,
and the simulator's speed-ups should be read against it.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np
import warp as wp

import warpimpulse as wi
from warpimpulse.bench.harness import quiet_warp
from warpimpulse.simulator import Simulator
from warpimpulse.threads import ThreadedSimulator

DT = 1.0 / 60.0
BLOCK = 10  # steps per timed block


def timed(step, steps: int) -> tuple[float, float]:
    """(wall, process CPU) seconds of `steps` calls."""
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(steps):
        step()
    return time.perf_counter() - wall, time.process_time() - cpu


def control(rounds: int, cores: list[int]) -> dict:
    """Speed-up of SHA-256 over a 16 MB buffer per thread (GIL released) on 1, 2, ... threads: what the
    machine allows now."""
    from concurrent.futures import ThreadPoolExecutor

    data = os.urandom(16 * 2**20)

    def work(_=None) -> None:
        hashlib.sha256(data).digest()

    walls: dict[int, list[float]] = {n: [] for n in cores}
    for _ in range(rounds):
        for n in cores:
            with ThreadPoolExecutor(n) as pool:
                start = time.perf_counter()
                list(pool.map(work, range(4 * n)))  # n times the work on n threads
                walls[n].append((time.perf_counter() - start) / n)
    base = statistics.median(walls[cores[0]])
    return {str(n): base / statistics.median(walls[n]) for n in cores}


def batched_vs_separate(worlds: int, bodies: int, rounds: int) -> dict:
    model = wi.scenes.binary_tree(bodies).replicate(worlds).finalize()
    batched = Simulator(model, DT)
    separate = [Simulator(wi.scenes.binary_tree(bodies).finalize(), DT) for _ in range(worlds)]

    def step_separate() -> None:
        for sim in separate:
            sim.step()

    batched.step()
    step_separate()
    t_batched, t_separate = [], []
    for _ in range(rounds):
        t_batched.append(timed(batched.step, BLOCK)[0])
        t_separate.append(timed(step_separate, BLOCK)[0])
    same = all(
        np.array_equal(batched.positions(w), sim.positions()) and np.array_equal(batched.orientations(w),
                                                                                 sim.orientations())
        for w, sim in enumerate(separate)
    )  # fmt: skip
    rate_b = worlds * BLOCK / statistics.median(t_batched)
    rate_s = worlds * BLOCK / statistics.median(t_separate)
    return {
        "worlds": worlds,
        "bodies": bodies,
        "batched_world_steps_per_s": rate_b,
        "separate_world_steps_per_s": rate_s,
        "ratio": rate_b / rate_s,
        "batched_ms_per_step": 1e3 * statistics.median(t_batched) / BLOCK,
        "separate_ms_per_step": 1e3 * statistics.median(t_separate) / BLOCK,
        "bit_identical": same,
    }


def threads_scaling(worlds: int, bodies: int, rounds: int, cores: list[int]) -> dict:
    model = wi.scenes.binary_tree(bodies).replicate(worlds).finalize()
    sims = {n: ThreadedSimulator(model, DT, threads=n) for n in cores}
    for sim in sims.values():
        sim.step()
    walls: dict[int, list[float]] = {n: [] for n in cores}
    usage: dict[int, list[float]] = {n: [] for n in cores}
    for _ in range(rounds):
        for n, sim in sims.items():
            wall, cpu = timed(sim.step, BLOCK)
            walls[n].append(wall)
            usage[n].append(cpu / wall)
    base = statistics.median(walls[cores[0]])
    out = {
        str(n): {
            "world_steps_per_s": worlds * BLOCK / statistics.median(walls[n]),
            "speedup": base / statistics.median(walls[n]),
            "cpu_over_wall": statistics.median(usage[n]),
        }
        for n in cores
    }
    ref = sims[cores[0]]
    same = all(np.array_equal(ref.positions(), sim.positions()) for sim in sims.values())
    for sim in sims.values():
        sim.close()
    return {"worlds": worlds, "bodies": bodies, "by_threads": out, "bit_identical": same}


def hard_world(worlds: int, bodies: int, steps: int = 10) -> dict:
    def run(spin: float) -> Simulator:
        sim = Simulator(wi.scenes.binary_tree(bodies).replicate(worlds).finalize(), DT)
        w = np.zeros((worlds, bodies, 3))
        w[0, -1] = (0.0, 0.0, spin)
        sim.set_state(angular_velocities=w)
        return sim

    calm, hard = run(0.0), run(300.0)
    iterations = {"calm": [], "hard": []}
    alone_steps = 0
    for _ in range(steps):
        calm.step()
        hard.step()
        iterations["calm"].append(calm.world_stats.joint_iterations[1:].tolist())
        iterations["hard"].append(hard.world_stats.joint_iterations[1:].tolist())
        alone_steps += int(hard.world_stats.alone[0])
    return {
        "worlds": worlds,
        "steps": steps,
        "hard_world_substeps_last_step": int(hard.world_stats.substeps[0]),
        "hard_world_steps_alone": alone_steps,
        "others_iterations_equal": iterations["calm"] == iterations["hard"],
        "others_joint_iterations_total": int(np.sum(iterations["hard"])),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--worlds", type=int, default=256)
    parser.add_argument("--bodies", type=int, default=31)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--json", type=Path, default=Path(__file__).parent / "results" / "worlds.json")
    args = parser.parse_args()
    quiet_warp()
    cores = list(range(1, (os.cpu_count() or 1) + 1))
    started = time.perf_counter()
    load_before = os.getloadavg()
    results = {
        "machine": {
            "platform": platform.platform(),
            "cpus": os.cpu_count(),
            "warp": wp.config.version,
            "load_average_before": load_before,
        },  # fmt: skip
        "batched": batched_vs_separate(args.worlds, args.bodies, args.rounds),
        "threads": [
            threads_scaling(w, b, args.rounds, cores) for w, b in ((2, 4095), (16, 255), (args.worlds, args.bodies))
        ],
        "control_speedup": control(args.rounds, cores),
        "hard_world": hard_world(8, args.bodies),
    }
    results["machine"]["load_average_after"] = os.getloadavg()
    results["seconds"] = time.perf_counter() - started
    b = results["batched"]
    rates = f"batched {b['batched_world_steps_per_s']:.0f}, separate {b['separate_world_steps_per_s']:.0f}"
    print(f"{b['worlds']} worlds of {b['bodies']} bodies, world-steps/s: {rates}: {b['ratio']:.2f}x "
          f"(bit identical: {b['bit_identical']})")  # fmt: skip
    for t in results["threads"]:
        line = ", ".join(f"{n} threads {v['speedup']:.2f}x (cpu/wall {v['cpu_over_wall']:.2f})"
                         for n, v in t["by_threads"].items())  # fmt: skip
        print(f"{t['worlds']} worlds of {t['bodies']} bodies: {line}")
    print("control (SHA-256, GIL released): " + ", ".join(f"{n} threads {v:.2f}x"
                                                          for n, v in results["control_speedup"].items()))  # fmt: skip
    h = results["hard_world"]
    print(f"hard world: taken alone in {h['hard_world_steps_alone']} of {h['steps']} steps; the others' iterations "
          f"unchanged: {h['others_iterations_equal']}")  # fmt: skip
    print(f"load average {load_before} -> {results['machine']['load_average_after']}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
