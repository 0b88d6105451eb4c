"""One coupled RK4 prediction of a robot against one uncoupled prediction (docs/history.md, "The coupled
prediction, second round").

A scene with force elements (every actuator of the MJCF robots of `scene_kinds.py` is a drive) predicts its bodies
with the coupled RK4 (`kernels/step.py` `coupled_predict_all`) 1 + (joint iterations) times a stage. Here a kernel
calls it `--calls` times in a loop in one launch, from the robot's state after 20 steps at order 2 and h = 1/120,
and another calls the uncoupled `predict_all` on the same state: the time of one call, min over `--repeats`
launches, in thread CPU time (on a shared machine, time descheduled is not the kernel's). The loop keeps the
code and data in the caches, so this is a floor, not the share of a step.

    python benchmarks/coupled_prediction.py                  # reacher, ant, dm_humanoid
    python benchmarks/coupled_prediction.py --scenes ant --repeats 25
"""

from __future__ import annotations

import argparse
import time

import scene_kinds
import warp as wp
from warpimpulse.kernels.step import ForceElements, coupled_predict_all, predict_all

from warpimpulse.simulator import Simulator

wp.set_module_options({"enable_backward": False})

f64, vec3d, quatd, mat33d = wp.float64, wp.vec3d, wp.quatd, wp.mat33d
ROBOTS = ("reacher", "ant", "dm_humanoid")


@wp.kernel
def coupled_calls(
    calls: int,
    body_count: int,
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    gravity: vec3d,
    h: f64,
    el: ForceElements,
    x: wp.array(dtype=vec3d),
    q: wp.array(dtype=quatd),
    v: wp.array(dtype=vec3d),
    w: wp.array(dtype=vec3d),
    force: wp.array(dtype=vec3d),
    torque: wp.array(dtype=vec3d),
    px: wp.array(dtype=vec3d),
    pq: wp.array(dtype=quatd),
    pv: wp.array(dtype=vec3d),
    pw: wp.array(dtype=vec3d),
):
    """`calls` coupled predictions from the same state."""
    for _ in range(calls):
        coupled_predict_all(
            body_count, body_inv_mass, body_inertia, body_inv_inertia, gravity, h, el, x, q, v, w, force, torque,
            px, pq, pv, pw,
        )  # fmt: skip


@wp.kernel
def uncoupled_calls(
    calls: int,
    body_count: int,
    body_inv_mass: wp.array(dtype=f64),
    body_inertia: wp.array(dtype=mat33d),
    body_inv_inertia: wp.array(dtype=mat33d),
    body_principal: wp.array(dtype=int),
    body_euler: wp.array(dtype=vec3d),
    body_axes: wp.array(dtype=quatd),
    gravity: vec3d,
    h: f64,
    x: wp.array(dtype=vec3d),
    q: wp.array(dtype=quatd),
    v: wp.array(dtype=vec3d),
    w: wp.array(dtype=vec3d),
    force: wp.array(dtype=vec3d),
    torque: wp.array(dtype=vec3d),
    px: wp.array(dtype=vec3d),
    pq: wp.array(dtype=quatd),
    pv: wp.array(dtype=vec3d),
    pw: wp.array(dtype=vec3d),
):
    """`calls` uncoupled predictions from the same state."""
    for _ in range(calls):
        predict_all(
            body_count, body_inv_mass, body_inertia, body_inv_inertia, body_principal, body_euler, body_axes, gravity,
            h, x, q, v, w, force, torque, px, pq, pv, pw,
        )  # fmt: skip


def per_call_us(kernel, inputs: list, calls: int, repeats: int, device) -> float:
    """Thread CPU time of one call of the kernel's loop (us), min over `repeats` launches."""
    best = float("inf")
    for _ in range(repeats):
        wp.synchronize()
        start = time.thread_time()
        wp.launch(kernel, 1, inputs=[calls, *inputs], device=device)
        wp.synchronize()
        best = min(best, time.thread_time() - start)
    return best / calls * 1e6


def measure(name: str, calls: int, repeats: int) -> tuple[int, int, float, float]:
    """(bodies, force elements, coupled us, uncoupled us) of robot `name` (a `scene_kinds.KINDS` name)."""
    kind = {k.name: k for k in scene_kinds.KINDS}[name]
    h = 1.0 / 120.0
    sim = Simulator(scene_kinds.load(kind).model, h, tolerance=1e-4, order=2)
    sim.step(20)
    m, s, p, c = sim.model, sim.state, sim.pred, sim.control
    state = [s.body_x, s.body_q, s.body_v, s.body_w, c.body_force, c.body_torque, p.body_x, p.body_q, p.body_v,
             p.body_w]  # fmt: skip
    inertia = [m.body_count, m.body_inv_mass, m.body_inertia, m.body_inv_inertia]
    coupled = [*inertia, m.gravity, f64(h), sim._force_elements(), *state]
    uncoupled = [*inertia, m.body_principal, m.body_euler, m.body_axes, m.gravity, f64(h), *state]
    return (
        m.body_count,
        m.element_count,
        per_call_us(coupled_calls, coupled, calls, repeats, m.device),
        per_call_us(uncoupled_calls, uncoupled, calls, repeats, m.device),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=list(ROBOTS), choices=[k.name for k in scene_kinds.KINDS])
    parser.add_argument("--calls", type=int, default=2000, help="predictions a launch")
    parser.add_argument("--repeats", type=int, default=15, help="launches, the min taken")
    args = parser.parse_args()
    print(f"{'scene':14s} {'bodies':>6s} {'elements':>8s} {'coupled us':>10s} {'uncoupled us':>12s}")
    for name in args.scenes:
        bodies, elements, coupled, uncoupled = measure(name, args.calls, args.repeats)
        print(f"{name:14s} {bodies:6d} {elements:8d} {coupled:10.3f} {uncoupled:12.3f}")


if __name__ == "__main__":
    main()
