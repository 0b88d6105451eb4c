"""Write the stored reference trajectories that `make test` compares the engine with, without MuJoCo installed.

    python benchmarks/make_reference.py [--out tests/data/reference_trajectories.npz]

MuJoCo RK4 at h = 1/3000 in reduced coordinates (the benchmark harness's reference and its MuJoCo export) on
- tree127: the paper's 127-body tree of ball joints, driven by its start torque for the first second;
- bent_chain: six links bent in 3D on ball, universal and revolute joints, the tip pushed for half a second
  (`scenes.bent_chain`).
For a few probe bodies at a few times it stores centre-of-mass positions and orientations (x, y, z, w), with
each scene's probe positions at t = 0 (so a changed scene is noticed) and the reference's own error: the
largest distance from a run at h = 1/6000. Needs `pip install -e .[bench]`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import mujoco
import numpy as np

from warpimpulse import scenes
from warpimpulse.bench.peers.mujoco import MujocoRunner, MujocoScene, mujoco_available

RATE, CHECK_RATE = 3000, 6000
# name: (scene, probe bodies, times in s). The tree's probes: the root, a body of every level, leaves on both
# sides. The chain is chaotic after ~1.2 s (errors of 1e-3 m grow to 0.2 m by 1.5 s), so it is stored to 1 s.
SCENES = {
    "tree127": (lambda: scenes.binary_tree(127), [0, 1, 2, 4, 9, 20, 42, 63, 85, 106, 126], (0.5, 1.0, 1.5, 2.0)),
    "bent_chain": (scenes.bent_chain, [0, 1, 2, 3, 4, 5], (0.25, 0.5, 0.75, 1.0)),
}
OUT = Path(__file__).parents[1] / "tests" / "data" / "reference_trajectories.npz"


def trajectory(builder, probes: list[int], times, rate: int) -> tuple[np.ndarray, np.ndarray]:
    """(positions (T, P, 3), orientations (T, P, 4)) of the probe bodies at `times`."""
    runner = MujocoRunner(MujocoScene.from_builder(builder, 1.0 / rate), "RK4", rate)
    marks = {int(round(t * rate)): k for k, t in enumerate(times)}
    x, q = np.zeros((len(times), len(probes), 3)), np.zeros((len(times), len(probes), 4))
    for step in range(1, max(marks) + 1):
        runner.step()
        if step in marks:
            runner.check()
            pos, quat = runner.poses()
            x[marks[step]], q[marks[step]] = pos[probes], quat[probes]
    return x, q


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    missing = mujoco_available()
    if missing:
        raise SystemExit(missing)
    data: dict[str, np.ndarray] = {"rate": np.array(RATE)}
    for name, (make, probes, times) in SCENES.items():
        builder = make()
        x, q = trajectory(builder, probes, times, RATE)
        x_check, _ = trajectory(builder, probes, times, CHECK_RATE)
        residual = float(np.linalg.norm(x - x_check, axis=2).max())
        data[f"{name}_times"] = np.array(times)
        data[f"{name}_probes"] = np.array(probes)
        data[f"{name}_start"] = np.array([builder.bodies[b].position for b in probes])
        data[f"{name}_x"], data[f"{name}_q"] = x, q
        data[f"{name}_self_check"] = np.array(residual)
        print(f"{name}: {len(probes)} probes at t = {times} s; h = 1/{RATE} against 1/{CHECK_RATE}: {residual:.2e} m")
    data["mujoco_version"] = np.array(mujoco.__version__)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out, **data)
    print(f"wrote {args.out} ({args.out.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
