"""The parallel schedule's correction loops decided on the device (`kernels/loop.py`, `Simulator._capture_loop`):
one graph replay a loop, no error array read back per iteration, and the same steps, iteration counts and
failures as the host's loop it replaced (the fused schedule, written independently, agrees bit for bit:
tests/test_schedules.py)."""

from __future__ import annotations

import numpy as np
import pytest

import warpimpulse as wi
from warpimpulse import scenes
from warpimpulse.steps import SimulationError


def _host_loop(sim: wi.Simulator) -> None:
    """Make `sim` decide its loops on the host (the path the fused schedule's rare parallel steps and batched
    worlds keep)."""
    sim._device_loops = lambda: None


def _limited_chain() -> wi.SceneBuilder:
    """chain10 with every hinge limited to +-0.05 rad: the loop's error is the joints' and the limits' largest."""
    b = scenes.chain(10)
    for j in range(len(b.joints)):
        b.add_joint_limit(j, -0.05, 0.05)
    return b


def _run(make, dt: float, steps: int, host: bool):
    sim = wi.Simulator(make().finalize("cpu"), dt, tolerance=1e-6, options=wi.StepOptions(schedule="parallel"))
    if host:
        _host_loop(sim)
    stats = [sim.step() for _ in range(steps)]
    return sim, stats


@pytest.mark.parametrize(
    "make, dt",
    [
        (lambda: scenes.binary_tree(31), 1 / 60),
        (lambda: scenes.chain(10), 1 / 60),
        (scenes.double_pendulum, 1 / 120),
        (_limited_chain, 1 / 60),
    ],
    ids=["tree31", "chain10", "double_pendulum", "limited_chain10"],
)
def test_device_loop_takes_the_host_loops_steps(make, dt):
    device, dstats = _run(make, dt, 40, host=False)
    host, hstats = _run(make, dt, 40, host=True)
    for a, b in zip(dstats, hstats, strict=True):
        assert (a.joint_iterations, a.velocity_iterations, a.max_joint_error, a.max_velocity_error) == (
            b.joint_iterations,
            b.velocity_iterations,
            b.max_joint_error,
            b.max_velocity_error,
        )
    np.testing.assert_array_equal(device.positions(), host.positions())
    np.testing.assert_array_equal(device.angular_velocities(), host.angular_velocities())
    assert sum(s.joint_iterations for s in dstats) >= 40  # the loop iterated


def test_device_loop_reads_no_errors_back(monkeypatch):
    sim = wi.Simulator(
        scenes.chain(10).finalize("cpu"), 1 / 60, tolerance=1e-6, options=wi.StepOptions(schedule="parallel")
    )
    sim.step(3)
    reads = []
    monkeypatch.setattr(wi.Simulator, "_max_error", lambda self, what: reads.append(what))
    stats = [sim.step() for _ in range(10)]
    assert sum(s.joint_iterations for s in stats) >= 10
    assert reads == []


def test_device_loop_stops_at_the_iteration_limit_and_names_the_joints():
    make = lambda: scenes.chain(10)  # noqa: E731
    messages = []
    for host in (False, True):
        sim = wi.Simulator(
            make().finalize("cpu"),
            1 / 60,
            tolerance=1e-12,
            max_iterations=2,
            options=wi.StepOptions(schedule="parallel"),
        )
        sim.max_substep_depth = 0
        if host:
            _host_loop(sim)
        with pytest.raises(SimulationError) as failure:
            sim.step(5)
        messages.append(str(failure.value))
    assert "did not reach 1e-12 in 2 iterations" in messages[0]
    assert messages[0] == messages[1]


def test_batched_worlds_decide_their_loops_on_the_device(monkeypatch):
    """Batched worlds iterate each world on the device until its own tolerance (`worlds.Batch.device_loop`):
    the host reads per-world errors only for the velocity correction, not once an iteration."""
    from warpimpulse.worlds import Batch

    sim = wi.Simulator(scenes.chain(10).replicate(4).finalize("cpu"), 1 / 60, tolerance=1e-6)
    sim.step(3)
    reads = []
    world_max = Batch.world_max
    monkeypatch.setattr(Batch, "world_max", lambda self: reads.append(1) or world_max(self))
    stats = [sim.step() for _ in range(10)]
    assert sum(s.joint_iterations for s in stats) >= 10
    assert len(reads) <= 2 * len(stats)
    assert all(s.converged for s in stats)
