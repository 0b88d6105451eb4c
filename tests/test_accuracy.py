"""Accuracy on request (`Simulator(accuracy=E)`, `warpimpulse.accuracy`): the trajectory stays within the asked
error of an independent reference (reduced coordinates, tests/reference.py), frames land on their times, and bad
values are one clear line. Nothing here is timed."""

from __future__ import annotations

import math

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run
from rigs import ball_chain

import warpimpulse as wi
from warpimpulse import accuracy
from warpimpulse.run import record_frames

FRAME = 0.1  # s: the interval step() advances, the largest step
DURATION = 1.0


def pendulum():
    """One rod on a ball joint, released 60 degrees out and spinning about its axis: a conical swing."""
    return ball_chain([(0.8, 0.3, -0.5)], [1.0], [1.0], [(0.0, 0.0, 2.0)])


def chain():
    """Three rods on ball joints hung 30-45 degrees out in 3D, the lowest spinning: a swinging chain. (A chain
    released horizontal tumbles chaotically and amplifies early errors beyond what a local estimate sees:
    docs/accuracy.md.)"""
    return ball_chain([(0.6, 0.0, -1.0), (0.3, 0.8, -1.0), (-0.5, 0.4, -1.0)], [0.6, 0.5, 0.4], [1.0, 0.8, 0.6],
                      [(0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 3.0)])  # fmt: skip


def error_against_reference(make, target: float) -> tuple[float, wi.Simulator, float, float, float]:
    """The largest centre-of-mass distance from the reference at the frames of DURATION s, with accuracy `target`
    over that horizon; the simulator; the error and the estimate reported (`StepStats.error_estimate`) at the
    end; the largest step taken (s)."""
    builder, ref = make()
    frames = int(round(DURATION / FRAME))
    com, _, _ = ref.solve(np.arange(frames + 1) * FRAME)
    sim = wi.Simulator(builder.finalize(), FRAME, accuracy=target)
    sim.accuracy.horizon = DURATION
    error = last = largest = 0.0
    for f in range(1, frames + 1):
        stats = sim.step()
        largest = max(largest, stats.step_size)
        last = float(np.linalg.norm(sim.positions() - com[f], axis=1).max())
        error = max(error, last)
    return error, sim, last, stats.error_estimate, largest


@pytest.mark.parametrize("make", [pendulum, chain])
@pytest.mark.parametrize("target", [1e-2, 1e-4])
def test_error_stays_near_the_asked_accuracy(make, target):
    """The measured error is within the asked accuracy, and not wastefully below it: the controller sizes the step
    for SAFETY E, it does not simply take tiny steps. (At one step an interval the step can be no larger, and
    order 4 may then be below E: the bound allows 2^(p+1).) The error it reports (the gap to its shadow run at
    twice the step, over 2^p - 1) is at least half the error measured against the reference, and at most twice
    it where the shadow's steps were all in the range where the error goes as h^p, here at most half an interval:
    the chain at 1e-2 m runs at order 4 with steps of half the interval, whose shadow's steps of 0.1 s overstate
    the error 5x (and the shadow keeps that error to the end); the controller then takes smaller steps than it
    needs, not larger ones."""
    error, sim, last, estimate, largest = error_against_reference(make, target)
    print(f"\n{make.__name__} E={target:g}: error {error:.3g} m (now {last:.3g}, estimated {estimate:.3g}), "
          f"order {sim.order}, {sim.step_count} steps")  # fmt: skip
    assert error <= target
    assert error >= accuracy.SAFETY * target / 2.0 ** (sim.order + 1)
    assert last / 2.0 <= estimate
    if largest <= FRAME / 4:  # the shadow's steps of 2h at most half an interval: where Richardson holds here
        assert estimate <= 2.0 * last


def test_order_and_tolerance_follow_the_accuracy():
    """Order 2 at loose accuracies, 4 at tight ones (on this pendulum; `cheaper_order` compares their work); the joint
    tolerance a share of E (at most its cap)."""
    model = pendulum()[0].finalize()
    loose, tight = wi.Simulator(model, accuracy=1e-2), wi.Simulator(model, accuracy=1e-5)
    assert (loose.order, tight.order) == (2, 4)
    assert loose.tolerance == accuracy.TOLERANCE_CAP
    assert tight.tolerance == pytest.approx(accuracy.TOLERANCE_SHARE * 1e-5)
    assert loose.dt == accuracy.DEFAULT_INTERVAL


def test_frames_land_on_their_times():
    """Each step() advances exactly one interval, taken as whole steps of dt / k; the recorder's frames are at f / fps
    and the step size and error estimate are reported."""
    builder, _ = chain()
    sim = wi.Simulator(builder.finalize(), FRAME, accuracy=1e-4)
    sizes = set()
    for f in range(1, 11):
        stats = sim.step()
        assert sim.time == f * FRAME
        assert sim.dt == FRAME
        steps = FRAME / stats.step_size
        assert steps == pytest.approx(round(steps), rel=1e-12)
        assert math.isfinite(stats.error_estimate) and stats.error_estimate >= 0.0
        sizes.add(stats.step_size)
    assert sim.step_count > 10 and len(sizes) > 1  # more than one step a frame, sized as the motion asks

    class Writer:
        fps = 1.0 / FRAME

        def __init__(self):
            self.times = []

        def write_frame(self, frame, positions, orientations):
            self.times.append(sim.time)

    sim.reset()
    writer = Writer()
    assert record_frames(sim, writer, 10 * FRAME, progress=False) == 11
    assert writer.times == [f * FRAME for f in range(11)]


def test_fixed_steps_report_no_estimate():
    """Without `accuracy` the step is dt and nothing is estimated: both figures are NaN, as in every StepStats the
    schedules compare bit for bit."""
    sim = wi.Simulator(pendulum()[0].finalize(), 0.01)
    for stats in (sim.step(), sim.step(3)):
        assert math.isnan(stats.step_size) and math.isnan(stats.error_estimate)


@pytest.mark.parametrize("value", [0.0, -1e-3, math.nan, math.inf, "1e-3", True])
def test_bad_accuracy_is_one_clear_line(value):
    model = pendulum()[0].finalize()
    with pytest.raises(ValueError, match="accuracy must be positive and finite|accuracy must be numeric") as info:
        wi.Simulator(model, accuracy=value)
    assert "\n" not in str(info.value)


def test_what_accuracy_cannot_control_is_refused():
    model = pendulum()[0].finalize()
    with pytest.raises(ValueError, match="dt .* is required unless accuracy"):
        wi.Simulator(model)
    with pytest.raises(ValueError, match="accuracy chooses the order"):
        wi.Simulator(model, accuracy=1e-3, order=4)
    with pytest.raises(ValueError, match="accuracy: the scene has contacts"):
        wi.Simulator(wi.scenes.box_stack(2).finalize(), accuracy=1e-3)


def test_limits_are_controlled_at_order_two():
    """A scene whose steps fall back to order 2 (a joint limit) is controlled at order 2, and the plan says so."""
    b = wi.scenes.double_pendulum()
    b.add_joint_limit("hinge1", -1.0, 1.0)
    sim = wi.Simulator(b.finalize(), accuracy=1e-5)
    assert sim.order == 2 and "order 2" in sim.accuracy.plan.note
    sim.step(2)
    assert sim.time == 2 * sim.dt


def test_cli_accuracy(tmp_path, capsys):
    """`--accuracy E` runs with the controller, records E in the file, and a bad value is one line, exit 2."""
    from pxr import Sdf

    out = tmp_path / "x.usda"
    argv = ["simulate", "--scene", "double_pendulum", "--duration", "0.2", "--out", str(out)]
    code, _ = run([*argv, "--accuracy", "1e-3"], capsys)
    assert code == 0
    data = Sdf.Layer.FindOrOpen(str(out)).customLayerData
    # the order is the pilot's choice (`accuracy.cheaper_order`), for the CLI's simulator and its settings
    assert data["warpimpulse:accuracy"] == 1e-3 and data["warpimpulse:order"] in accuracy.ORDERS
    assert_one_line_error([*argv, "--accuracy", "0"], "--accuracy: must be positive", capsys)
    assert_one_line_error([*argv, "--accuracy", "nan"], "--accuracy: must be positive", capsys)
    assert_one_line_error([*argv, "--accuracy", "1e-3", "--order", "6"], "accuracy chooses the order", capsys)


def test_the_shadow_steps_where_its_steps_converge():
    """A shadow step of 2h that has to be halved is beyond where the joint iteration converges (and beyond where its
    error goes as (2h)^p): the trajectory's steps then stay at most h for the rest of the run, so no shadow step size
    is halved twice. A 20-link chain released horizontal at 1e-3 m: its shadow's steps of 0.1 s, then of 0.05 s,
    were halved three and two times (130 solves where the trajectory's two steps took 24); now once each."""
    sim = wi.Simulator(wi.scenes.chain(20).finalize(), 1.0 / 20.0, accuracy=1e-3)
    sim.accuracy.horizon = 2.0
    controller, halved = sim.accuracy, []
    shadow_steps = controller._shadow_steps

    def counted(h, n, end):
        parts = shadow_steps(h, n, end)
        if sum(p.substeps for p in parts) > n:
            halved.append(h)
        return parts

    controller._shadow_steps = counted
    for _ in range(40):
        sim.step()
    assert sim.order == 4 and halved  # the case this is about: order 4 steps of 2h beyond convergence
    assert len(set(halved)) == len(halved), halved
    assert controller._least >= 2
