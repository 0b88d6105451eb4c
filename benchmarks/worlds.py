"""Many worlds, every core: batched worlds against separate simulators, and the speed-up per thread count.

    python benchmarks/worlds.py [--worlds 256] [--bodies 31] [--rounds 7] [--json benchmarks/results/worlds.json]
                                [--readme docs/guide.md] [--from-json]

1. Batched: `worlds` copies of the binary tree (`scenes.binary_tree(bodies)`) as one Model
   (`SceneBuilder.replicate`) on one thread, against `worlds` separate Simulators stepped in a loop: world-steps
   per second of each, and their ratio. Both start from the same state and run the same steps, and the
   batched run is checked to end bit for bit where the separate ones do.
2. Every core: `ThreadedSimulator` on 1, 2, ... cores for 2 worlds of tree4095, 16 of tree255 and the
   batched case above, `step(10)` a timed call (these scenes run fused: each world a one-world share, its 10
   steps one launch that releases the GIL; "shares" in the JSON), timed in turn with batched shares (one
   batched Simulator a thread, the parallel schedule asked: how they ran before): world-steps per second and
   the speed-up over one thread, with the
   process's CPU time over wall time (near the thread count when the threads really run at once; well under
   it when the machine is busy with other work).
3. One tree on every core: `ThreadedSimulator` of one world (`split.SplitSimulator`: the tree cut at its root, a
   part a thread) on 1, 2, ... threads for the binary trees of 16,383 and 65,535 bodies: ms per step, the
   speed-up over one thread (which is the fused step itself), CPU time over wall time, and whether every thread
   count ends bit for bit where one thread does; and, for the most threads, the speed-up estimated from CPU
   times as if each thread had a core of its own (`idle_core_estimate`).
4. A hard world: one world spinning fast takes its steps alone, as substeps; the others' joint iterations are
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
from warpimpulse.bench.blocks import write_block
from warpimpulse.bench.harness import quiet_warp
from warpimpulse.simulator import Simulator
from warpimpulse.split import SplitSimulator
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
    """The worlds on 1, 2, ... threads in the shares the ThreadedSimulator picks, and, timed in turn with them,
    in batched shares (the parallel schedule asked: every share a batched Simulator, as before the fused
    shares): both start alike and must end bit for bit alike."""
    model = wi.scenes.binary_tree(bodies).replicate(worlds).finalize()
    kinds = {"picked": {}, "batched": {"schedule": "parallel"}}
    sims = {
        (k, n): ThreadedSimulator(model, DT, threads=n, **wi.StepOptions.fold(settings))
        for k, settings in kinds.items()
        for n in cores
    }
    for sim in sims.values():
        sim.step()
    walls: dict[tuple, list[float]] = {key: [] for key in sims}
    usage: dict[tuple, list[float]] = {key: [] for key in sims}
    for _ in range(rounds):
        for key, sim in sims.items():
            wall, cpu = timed(lambda: sim.step(BLOCK), 1)  # noqa: B023 (called at once)
            walls[key].append(wall)
            usage[key].append(cpu / wall)

    def by_threads(kind: str) -> dict:
        base = statistics.median(walls[(kind, cores[0])])
        return {
            str(n): {
                "world_steps_per_s": worlds * BLOCK / statistics.median(walls[(kind, n)]),
                "speedup": base / statistics.median(walls[(kind, n)]),
                "cpu_over_wall": statistics.median(usage[(kind, n)]),
            }
            for n in cores
        }

    ref = sims[("picked", cores[0])]
    same = all(np.array_equal(ref.positions(), sim.positions()) for sim in sims.values())
    shares = "fused" if ref.fused_shares else "batched"
    for sim in sims.values():
        sim.close()
    return {"worlds": worlds, "bodies": bodies, "shares": shares, "by_threads": by_threads("picked"),
            "batched_shares": by_threads("batched"), "bit_identical": same}  # fmt: skip


def split_scaling(bodies: int, rounds: int, cores: list[int], seconds: float = 0.3) -> dict:
    """One tree of `bodies` on 1, 2, ... threads (see the module docstring)."""
    model = wi.scenes.binary_tree(bodies).finalize()
    sims = {n: ThreadedSimulator(model, DT, threads=n) for n in cores}
    for sim in sims.values():
        sim.step()
    first = sims[cores[0]]
    block = max(1, round(seconds / timed(first.step, 1)[0]))
    for sim in sims.values():
        if sim is not first:
            sim.step()
    walls: dict[int, list[float]] = {n: [] for n in cores}
    usage: dict[int, list[float]] = {n: [] for n in cores}
    for _ in range(rounds):
        for n, sim in sims.items():
            wall, cpu = timed(sim.step, block)
            walls[n].append(wall / block)
            usage[n].append(cpu / (wall or 1.0))
    base = statistics.median(walls[cores[0]])
    out = {
        str(n): {
            "threads_used": sims[n].threads,
            "ms_per_step": 1e3 * statistics.median(walls[n]),
            "speedup": base / statistics.median(walls[n]),
            "cpu_over_wall": statistics.median(usage[n]),
        }
        for n in cores
    }
    same = all(np.array_equal(first.positions(), sim.positions()) for sim in sims.values())
    same &= all(np.array_equal(first.angular_velocities(), sim.angular_velocities()) for sim in sims.values())
    for sim in sims.values():
        sim.close()
    estimate = idle_core_estimate(model, cores[-1], block, rounds) if len(cores) > 1 else None
    return {"bodies": bodies, "steps_per_block": block, "by_threads": out, "bit_identical": same,
            "idle_core_estimate": estimate}  # fmt: skip


class TimedSplit(SplitSimulator):
    """A SplitSimulator that adds up its parts' CPU time (each part's thread's own clock): all of it, and the
    longest part of each phase."""

    parts_cpu = 0.0
    critical_cpu = 0.0

    def _parts(self, graphs) -> None:
        def run(graph) -> float:
            start = time.thread_time()
            wp.capture_launch(graph)
            return time.thread_time() - start

        pending = [self._pool.submit(run, g) for g in graphs[1:]]
        times = [run(graphs[0]), *(f.result() for f in pending)]
        self.parts_cpu += sum(times)
        self.critical_cpu += max(times)


def idle_core_estimate(model, threads: int, steps: int, rounds: int) -> dict:
    """What `threads` cores of its own would give the split step, from CPU times, which other work on the
    machine does not lengthen (much): the one-thread step's CPU time over the split step's with each phase of
    the parts counted at its longest part (the separator, the host and the barriers' CPU as they are). A model,
    not a measurement of wall time: it leaves out the time a thread waits to be woken."""
    one, split = SplitSimulator(model, DT, threads=1), TimedSplit(model, DT, threads=threads)
    one.step(), split.step()
    cpu_one, cpu_split, parts, critical = [], [], [], []
    for _ in range(rounds):
        cpu_one.append(timed(lambda: one.step(), steps)[1] / steps)
        split.parts_cpu = split.critical_cpu = 0.0
        cpu_split.append(timed(lambda: split.step(), steps)[1] / steps)
        parts.append(split.parts_cpu / steps)
        critical.append(split.critical_cpu / steps)
    split.close()
    path = [c - p + k for c, p, k in zip(cpu_split, parts, critical)]
    return {
        "threads": threads,
        "fused_cpu_ms": 1e3 * statistics.median(cpu_one),
        "split_cpu_ms": 1e3 * statistics.median(cpu_split),
        "critical_path_ms": 1e3 * statistics.median(path),
        "speedup": statistics.median(cpu_one) / statistics.median(path),
    }


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


def markdown(results: dict) -> str:
    """The README's block of these results: tables per thread count, with the load they were measured under."""
    m, b = results["machine"], results["batched"]
    load = f"load average {m['load_average_before'][0]:.2f} before, {m['load_average_after'][0]:.2f} after"
    control = ", ".join(f"{n} thread{'s' if n != '1' else ''} {v:.2f}x" for n, v in results["control_speedup"].items())
    cores = list(results["control_speedup"])
    lines = [
        "<!-- generated from benchmarks/results/worlds.json by `python benchmarks/worlds.py --from-json "
        "--readme docs/guide.md` -->",
        "",
        f"`python benchmarks/worlds.py` on {m['cpus']} cores ({load}; Warp {m['warp']}), medians over rounds that "
        "time the variants in turn. Batched: "
        f"{b['worlds']} worlds of tree{b['bodies']} as one Model run {b['ratio']:.2f}x the world-steps per second of "
        f"{b['worlds']} separate simulators stepped in a loop ({b['batched_world_steps_per_s']:.0f} against "
        f"{b['separate_world_steps_per_s']:.0f}; bit for bit the same: {b['bit_identical']}).",
        "",
        "| workload | " + " | ".join(f"{n} thread{'s' if n != '1' else ''}" for n in cores) + " | bit for bit |",
        "|---|" + "---:|" * len(cores) + "---|",
    ]

    def cells(by: dict, key: str, unit: str) -> str:
        return " | ".join(
            f"{v[key]:.4g} {unit}, {v['speedup']:.2f}x (cpu/wall {v['cpu_over_wall']:.2f})" for v in by.values()
        )

    rows = []
    for t in results["threads"]:
        name = f"{t['worlds']} worlds of tree{t['bodies']}"
        rows.append((f"{name} ({t.get('shares', 'batched')} shares)", t, "world_steps_per_s", "world-steps/s"))
        if t.get("shares") == "fused":
            batched = {**t, "by_threads": t["batched_shares"]}
            rows.append((f"{name} (batched shares)", batched, "world_steps_per_s", "world-steps/s"))
    rows += [(f"one tree{t['bodies']}, cut at its root", t, "ms_per_step", "ms/step") for t in results.get("split", [])]
    for name, t, key, unit in rows:
        lines.append(f"| {name} | {cells(t['by_threads'], key, unit)} | {t['bit_identical']} |")
    estimates = [(t["bodies"], t.get("idle_core_estimate")) for t in results.get("split", [])]
    if any(e for _, e in estimates):
        told = "; ".join(f"tree{b}: {e['speedup']:.2f}x on {e['threads']} (CPU {e['fused_cpu_ms']:.1f} ms a step on "
                         f"one thread, {e['split_cpu_ms']:.1f} ms split, {e['critical_path_ms']:.1f} ms on the longest "
                         "path)" for b, e in estimates if e)  # fmt: skip
        lines += ["", "The split step on cores of its own, estimated from CPU times (which the machine's other load "
                  f"lengthens little; each phase of the parts counted at its longest part): {told}."]  # fmt: skip
    h = results["hard_world"]
    lines += [
        "",
        f"The control, SHA-256 on threads that release the GIL, gave {control}: what the machine allowed while "
        "these ran (cpu/wall is the process's CPU time over wall time: near the thread count when the threads "
        "really ran at once). A hard world (spinning fast) took "
        f"{h['hard_world_steps_alone']} of {h['steps']} steps alone; the others' iterations were unchanged: "
        f"{h['others_iterations_equal']}.",
    ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--worlds", type=int, default=256)
    parser.add_argument("--bodies", type=int, default=31)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--json", type=Path, default=Path(__file__).parent / "results" / "worlds.json")
    parser.add_argument("--readme", type=Path, default=None, help="rewrite README.md's worlds block")
    parser.add_argument("--from-json", action="store_true", help="only regenerate the README block from --json")
    args = parser.parse_args()
    if args.from_json:
        results = json.loads(args.json.read_text())
    else:
        results = measure(args)
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    text = markdown(results)
    print(text)
    if args.readme:
        write_block(args.readme, "worlds", text)


def measure(args) -> dict:
    quiet_warp()
    cores = list(range(1, (os.cpu_count() or 1) + 1))
    started = time.perf_counter()
    results = {
        "machine": {
            "platform": platform.platform(),
            "cpus": os.cpu_count(),
            "warp": wp.config.version,
            "load_average_before": os.getloadavg(),
        },  # fmt: skip
        "batched": batched_vs_separate(args.worlds, args.bodies, args.rounds),
        "threads": [
            threads_scaling(w, b, args.rounds, cores) for w, b in ((2, 4095), (16, 255), (args.worlds, args.bodies))
        ],
        "split": [split_scaling(b, args.rounds, cores) for b in (16383, 65535)],
        "control_speedup": control(args.rounds, cores),
        "hard_world": hard_world(8, args.bodies),
    }
    results["machine"]["load_average_after"] = os.getloadavg()
    results["seconds"] = time.perf_counter() - started
    return results


if __name__ == "__main__":
    main()
