"""What one `step()` a call costs over a step inside `step(n)`, beside MuJoCo's `mj_step` timed the same way.

A controller calls `step()` once a tick. For each scene (a 7-hinge arm, a 20-hinge chain, the paper's tree of
127 ball joints; h = 1/120, tolerance 1e-6): blocks of `STEPS` steps taken one `step()` a call and as one
`step(STEPS)`, and MuJoCo's Euler step on the same model (`MujocoScene.from_builder`) as one `mj_step` a call and
as `mj_step(m, d, nstep=STEPS)`; every block starts from the same state (ours: `reset()` and one untimed step;
MuJoCo: its first state copied back and one untimed step), the kinds of block interleaved, `ROUNDS` rounds. CPU
time of this process (`time.process_time`), the garbage collector held off during a block. The overhead of a
call is the median of one-a-call minus the median of many-a-call; the spread is the quartiles of each; on a
shared machine the least block of each kind is the least disturbed, so the overhead of the least blocks is given
too. Where the velocity correction is deferred (`Simulator.defer_velocities`), a step leaves it to the next step
or to the first read of the velocities (`Simulator.state`), so `ours_one` hands nothing out; `ours_one_read`
reads `sim.state` after every `step()`, which corrects the velocities each call, as a controller that reads them
each tick would (MuJoCo's velocities are there after `mj_step` without a call). The kernel's part is timed apart
(`kernel_one_us`: the fused launch of one step whose velocities are corrected, called directly, without the
Python of `step()`; `kernel_one_deferred_us`: the same step, its velocity correction deferred).

    python benchmarks/call_overhead.py [--rounds 15] [--json benchmarks/results/call_overhead.json]
    python benchmarks/call_overhead.py --from-json   # docs/results.md's block again from the JSON
"""

from __future__ import annotations

import argparse
import functools
import gc
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

import warpimpulse as wi
from warpimpulse import scenes
from warpimpulse.bench.blocks import write_block
from warpimpulse.bench.harness import metadata
from warpimpulse.shapes import Shape
from warpimpulse.transforms import quat_between

ROOT = Path(__file__).resolve().parent.parent
JSON = ROOT / "benchmarks/results/call_overhead.json"
DOC = ROOT / "docs/results.md"  # its "call-overhead" block (`doc_block`)
STEPS = 120  # steps a timed block: 1 s at h = 1/120
ROUNDS = 15
H = 1.0 / 120.0
TOLERANCE = 1e-6


def arm(links: int = 7, length: float = 0.3, radius: float = 0.04, bend: float = 0.4) -> wi.SceneBuilder:
    """A robot arm: `links` capsules (`length` m, 1000 kg/m^3) hung from the world, on hinges whose axes alternate
    between y and x, released bent `bend` rad from the vertical about y."""
    builder = wi.SceneBuilder()
    shape = Shape("capsule", radius=radius, length=length - 2.0 * radius, collide=False)
    mass, inertia = shape.mass_properties(1000.0)
    direction = np.array([math.sin(bend), 0.0, -math.cos(bend)])
    orientation = quat_between([0.0, 0.0, 1.0], direction)
    top, parent = np.zeros(3), None
    for i in range(links):
        body = builder.add_body(mass, inertia, top + 0.5 * length * direction, orientation, name=f"link{i}",
                                shape=shape)  # fmt: skip
        axis = np.eye(3)[1 - i % 2]  # y, x, y, ...
        builder.add_joint_revolute(parent, body, top, axis, name=f"joint{i}")
        parent, top = body, top + length * direction
    return builder


SCENES = {"arm7": arm, "chain20": lambda: scenes.chain(20), "tree127": lambda: scenes.binary_tree(127)}


def _block(run, start) -> float:
    """CPU seconds of `run()` after an untimed `start()`, the garbage collector held off."""
    gc.collect()
    gc.disable()
    try:
        start()
        begin = time.process_time()
        run()
        return time.process_time() - begin
    finally:
        gc.enable()


def _kernel_one(sim: wi.Simulator, hand_out: bool):
    """One step by the fused kernel's launch alone: the words `step()` writes, then the call (a packed launch
    on a CPU, `Simulator._fused_launch`; a captured graph's replay before it)."""
    batch, spin = sim._views[-2:]
    launch = sim._fused_launch(sim.dt)
    call = functools.partial(wp.capture_launch, launch) if isinstance(launch, wp.Graph) else launch.launch

    def run() -> None:
        for _ in range(STEPS):
            batch[0], batch[1], spin[0] = 1, int(hand_out), 0.0
            call()

    return run


def scene_point(name: str, rounds: int) -> dict:
    import mujoco

    from warpimpulse.bench.peers.mujoco import MujocoScene

    sim = wi.Simulator(SCENES[name]().finalize("cpu"), H, tolerance=TOLERANCE)
    mscene = MujocoScene.from_builder(SCENES[name](), H, "Euler")
    m, d = mscene.model, mscene.make_data()
    start = mujoco.MjData(m)
    mujoco.mj_copyData(start, m, d)

    def ours_start() -> None:
        sim.reset()
        sim.step()

    def mujoco_start() -> None:
        mujoco.mj_copyData(d, m, start)
        mujoco.mj_step(m, d)

    def ours_one() -> None:
        for _ in range(STEPS):
            sim.step()

    def ours_one_read() -> None:
        for _ in range(STEPS):
            sim.step()
            sim.state  # noqa: B018 (the read hands the state out)

    def mujoco_one() -> None:
        for _ in range(STEPS):
            mujoco.mj_step(m, d)

    blocks = {
        "ours_one": (ours_one, ours_start),
        "ours_one_read": (ours_one_read, ours_start),
        "ours_many": (lambda: sim.step(STEPS), ours_start),
        "mujoco_one": (mujoco_one, mujoco_start),
        "mujoco_many": (lambda: mujoco.mj_step(m, d, nstep=STEPS), mujoco_start),
    }
    if sim.schedule == "fused" and sim._views is not None:
        blocks["kernel_one"] = (_kernel_one(sim, True), ours_start)
        blocks["kernel_one_deferred"] = (_kernel_one(sim, False), ours_start)
    for run, begin in blocks.values():  # compile and warm
        _block(run, begin)
    times: dict[str, list[float]] = {k: [] for k in blocks}
    for _ in range(rounds):
        for key, (run, begin) in blocks.items():
            times[key].append(_block(run, begin) / STEPS * 1e6)
    point = {"bodies": sim.model.body_count, "h": H, "tolerance": TOLERANCE, "steps": STEPS, "rounds": rounds}
    for key, values in times.items():
        q1, median, q3 = np.percentile(values, [25, 50, 75])
        point[f"{key}_us"] = median
        point[f"{key}_quartiles_us"] = [q1, q3]
        point[f"{key}_least_us"] = min(values)  # the least disturbed block, on a shared machine
    point["ours_overhead_us"] = point["ours_one_us"] - point["ours_many_us"]
    point["ours_read_overhead_us"] = point["ours_one_read_us"] - point["ours_many_us"]
    point["mujoco_overhead_us"] = point["mujoco_one_us"] - point["mujoco_many_us"]
    point["ours_overhead_least_us"] = point["ours_one_least_us"] - point["ours_many_least_us"]
    point["mujoco_overhead_least_us"] = point["mujoco_one_least_us"] - point["mujoco_many_least_us"]
    return point


def doc_block(result: dict) -> str:
    """The table of docs/results.md: each scene's µs a step, both engines both ways, medians and least blocks."""
    meta = result["meta"]
    lines = [
        f"CPU µs a step (`python benchmarks/call_overhead.py`, {meta['date']}, {meta['machine']}; medians of "
        f"{next(iter(result['scenes'].values()))['rounds']} rounds of {STEPS}-step blocks, the least block in "
        'brackets). "over" is one call a step less many steps a call; ours "+ read" reads `sim.state` after '
        "every `step()`, which takes the velocity correction a step leaves (`Simulator.state`).",
        "",
        "| scene | ours: `step()` a call | + read | `step(120)` | over | MuJoCo: `mj_step` a call | `nstep=120` "
        "| over |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, p in result["scenes"].items():
        cells = [f"{p[k + '_us']:.2f} ({p[k + '_least_us']:.2f})" for k in ("ours_one", "ours_many", "ours_overhead",
                                                                             "mujoco_one", "mujoco_many",
                                                                             "mujoco_overhead")]  # fmt: skip
        lines.append(f"| {name} | {cells[0]} | {p['ours_one_read_us']:.2f} | " + " | ".join(cells[1:]) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=ROUNDS)
    parser.add_argument("--scenes", nargs="*", default=list(SCENES), choices=list(SCENES))
    parser.add_argument("--json", default=str(JSON))
    parser.add_argument("--from-json", action="store_true", help="only write docs/results.md's block from the JSON")
    args = parser.parse_args(argv)
    if args.from_json:
        write_block(DOC, "call-overhead", doc_block(json.loads(Path(args.json).read_text())))
        return 0
    result = {"meta": metadata(sys.argv if argv is None else argv), "scenes": {}}
    for name in args.scenes:
        p = result["scenes"][name] = scene_point(name, args.rounds)
        print(f"{name}: ours one {p['ours_one_us']:.2f} many {p['ours_many_us']:.2f} over "
              f"{p['ours_overhead_us']:.2f} us (reading the state too {p['ours_read_overhead_us']:.2f}) | "
              f"MuJoCo one {p['mujoco_one_us']:.2f} many {p['mujoco_many_us']:.2f} "
              f"over {p['mujoco_overhead_us']:.2f} us | least blocks: ours over {p['ours_overhead_least_us']:.2f}, "
              f"MuJoCo over {p['mujoco_overhead_least_us']:.2f}"
              + (f" | kernel one {p['kernel_one_us']:.2f}, deferred {p['kernel_one_deferred_us']:.2f}"
                 if "kernel_one_us" in p else ""), flush=True)  # fmt: skip
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1) + "\n")
        if Path(args.json).resolve() == JSON:
            write_block(DOC, "call-overhead", doc_block(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
