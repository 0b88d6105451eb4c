"""Final states of 25 scenes, hashed: the check that a refactor changed no arithmetic.

Each scene runs a fixed number of steps from its built state; the hash covers every body's position,
orientation and velocities (float64 bytes) and the drives' integrals. A refactor that moves code must leave
every hash as it was; a change that alters arithmetic shows which scenes it touches.

    python benchmarks/state_hashes.py --write benchmarks/results/state_hashes.json   # record
    python benchmarks/state_hashes.py --check benchmarks/results/state_hashes.json   # compare, exit 1 on a change
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import warnings
from pathlib import Path

import numpy as np

import warpimpulse as wi
from warpimpulse import scenes


def _limited_chain() -> wi.SceneBuilder:
    b = scenes.chain(10)
    for j in range(1, 10, 2):
        b.add_joint_limit(j, -0.3, 0.3)
    return b


def _servo_chain() -> wi.SceneBuilder:
    b = scenes.chain(6)
    b.add_motor(1, "position", target=0.4, kp=80.0, ki=30.0, kd=5.0)
    b.add_motor(3, "velocity", target=0.3, kp=20.0, ki=40.0, max_force=3.0)
    b.add_motor(5, "velocity", target=0.5, max_force=50.0, stiff=True)
    return b


def _springs() -> wi.SceneBuilder:
    b = scenes.chain(10)
    for j in range(0, 10, 3):
        b.add_joint_spring(j, stiffness=5.0, damping=0.5)
    return b


def _rope() -> wi.SceneBuilder:
    b = scenes.binary_tree(31)
    top = b.bodies[20].position
    b.add_distance(None, 20, top + (0.0, 0.0, 0.3), top, max_distance=0.2, name="rope")
    return b


# name: (builder, dt, steps, settings, performance switches)
SCENES = {
    "chain10": (lambda: scenes.chain(10), 1 / 60, 60, {}, {}),
    "chain50": (lambda: scenes.chain(50), 1 / 60, 60, {}, {}),
    "tree127": (lambda: scenes.binary_tree(127), 1 / 60, 60, {}, {}),
    "double_pendulum": (scenes.double_pendulum, 1 / 120, 120, {}, {}),
    "star31_body": (lambda: scenes.star(31), 1 / 60, 30, {}, {"formulation": "body"}),
    "four_bar": (scenes.four_bar, 1 / 60, 60, {}, {}),
    "walker": (scenes.walking_machine, 1 / 60, 60, {}, {}),
    "car": (scenes.car, 1 / 60, 60, {}, {}),
    "box_stack": (lambda: scenes.box_stack(4), 1 / 60, 60, {"tolerance": 1e-4}, {}),
    "pile": (lambda: scenes.pile(30, seed=1), 1 / 60, 40, {"tolerance": 1e-4}, {}),
    "servo_chain": (_servo_chain, 1 / 60, 60, {}, {}),
    "limited_chain": (_limited_chain, 1 / 60, 60, {}, {}),
    "springs_chain10": (_springs, 1 / 60, 60, {}, {}),
    "rope_tree31": (_rope, 1 / 60, 60, {}, {}),
    "tree31_order4": (lambda: scenes.binary_tree(31), 1 / 60, 30, {"order": 4}, {}),
    "chain10_order6": (lambda: scenes.chain(10), 1 / 60, 30, {"order": 6}, {}),
    "chain10_parallel": (lambda: scenes.chain(10), 1 / 60, 60, {}, {"schedule": "parallel"}),
    "tree127_parallel": (lambda: scenes.binary_tree(127), 1 / 60, 30, {}, {"schedule": "parallel"}),
    "chain10_cg": (lambda: scenes.chain(10), 1 / 60, 30, {"solver": "cg"}, {}),
    "tree31_iterative": (lambda: scenes.binary_tree(31), 1 / 60, 30, {"solver": "iterative"}, {}),
    "chain10_newton": (lambda: scenes.chain(10), 1 / 60, 60, {}, {"newton": True}),
    "chain10_no_carry_no_defer": (
        lambda: scenes.chain(10),
        1 / 60,
        60,
        {},
        {"carry": False, "defer_velocities": False},
    ),
    "mixed_kinds": (
        lambda: scenes.chain(7, joint=["ball", "revolute", "prismatic", "universal", "cylindrical", "planar", "fixed"]),
        1 / 60,
        30,
        {},
        {},
    ),  # fmt: skip
    "worlds4_chain5": (lambda: scenes.chain(5).replicate(4), 1 / 60, 30, {}, {}),
    "bent_chain_whole_steps": (scenes.bent_chain, 1 / 30, 30, {}, {"max_rotation": None}),
}


def _simulator(model, dt: float, settings: dict, switches: dict):
    if hasattr(wi, "StepOptions"):
        return wi.Simulator(model, dt, **settings, options=wi.StepOptions(**switches))
    return wi.Simulator(model, dt, **settings, **switches)


def state_hash(name: str) -> str:
    make, dt, steps, settings, switches = SCENES[name]
    sim = _simulator(make().finalize("cpu"), dt, settings, switches)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(steps):
            sim.step()
    h = hashlib.sha256()
    for a in (sim.state.body_x, sim.state.body_q, sim.state.body_v, sim.state.body_w, sim.drive_integral):
        h.update(np.ascontiguousarray(a.numpy(), dtype=np.float64).tobytes())
    return h.hexdigest()[:16]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--write", type=Path, help="record the hashes in this JSON file")
    p.add_argument("--check", type=Path, help="compare with the hashes in this JSON file (exit 1 on a change)")
    p.add_argument("--only", nargs="*", default=None, help="these scenes only")
    args = p.parse_args(argv)
    names = args.only or list(SCENES)
    hashes = {}
    for name in names:
        hashes[name] = state_hash(name)
        print(f"{name:28s} {hashes[name]}", flush=True)
    if args.write:
        args.write.write_text(json.dumps(hashes, indent=1) + "\n")
    if args.check:
        want = json.loads(args.check.read_text())
        changed = [n for n in names if want.get(n) != hashes[n]]
        print(
            f"{len(names) - len(changed)} of {len(names)} scenes hash as recorded"
            + (f"; changed: {changed}" if changed else "")
        )
        return 1 if changed else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
