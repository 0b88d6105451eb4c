"""The two schedules of a step (`Simulator(schedule=...)`, kernels/step.py): the fused one (whole steps, many a
launch, the stage funcs in serial loops) and the parallel one (a launch per stage, the host deciding) run the same
operations in the same order on a CPU, so they agree bit for bit: states, stats and failure messages. The fused
one takes a batch of steps in one launch and hands the host only the steps it must split, halve or report."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from rigs import welded_hinge
from warpimpulse.kernels import step as step_kernels

import warpimpulse as wi
from warpimpulse import scenes
from warpimpulse.bench import stress
from warpimpulse.split import SplitSimulator
from warpimpulse.steps import combined


def _spinning_pendulum(omega: float) -> wi.SceneBuilder:
    builder = wi.SceneBuilder()
    body, _ = stress.capsule(builder, np.zeros(3), [0.0, 0.0, -1.0], 1.0, "rod")
    builder.bodies[body].angular_velocity[:] = (0.0, 0.0, omega)
    builder.add_joint_ball(None, body, np.zeros(3), name="hang")
    return builder


def _free_bodies() -> wi.SceneBuilder:
    builder = wi.SceneBuilder()
    for i in range(3):
        builder.add_body(1.0 + i, np.diag([0.1, 0.2, 0.3]), [i, 0.0, 1.0], angular_velocity=[0.0, 1.0, 3.0 * i])
    return builder


def _sprung_chain(links: int = 10) -> wi.SceneBuilder:
    """A hinged chain, each link hung from a spring-damper to a world point above its tip, one spring between
    two links: forces in every RK4 stage (the coupled prediction)."""
    b = scenes.chain(links)
    for j in range(links):
        tip = b.bodies[j].position
        b.add_spring(None, j, tip + (0.0, 0.0, 0.5), tip, 200.0, damping=2.0)
    b.add_spring(1, links - 2, b.bodies[1].position, b.bodies[links - 2].position, 30.0, damping=0.5)
    return b


def _servo_chain(links: int = 6) -> wi.SceneBuilder:
    """Hinges and sliders with every kind of force drive: joint springs on an angle and an offset, PID position
    and velocity servos with integrals (one clamped by max_force, its integral winding up to the bound), a torque
    that ends within the run, a spring between two links."""
    b = scenes.chain(links, joint=["revolute", "prismatic"])
    b.add_joint_spring(0, 40.0, damping=1.0, rest=0.2)
    b.add_joint_spring(1, 60.0, damping=2.0, rest=-0.1)
    b.add_motor(2, "position", target=0.4, kp=80.0, ki=30.0, kd=5.0)
    b.add_motor(3, "velocity", target=0.3, kp=20.0, ki=40.0, max_force=3.0)
    b.add_motor(4, "velocity", target=1.5, kp=10.0, ki=5.0)
    b.add_spring(0, links - 1, b.bodies[0].position, b.bodies[links - 1].position, 25.0, damping=0.3)
    b.add_force(links - 1, torque=(0.0, 3.0, 0.0), until=0.4)
    return b


def _servo_chain50() -> wi.SceneBuilder:
    """chain50 with PID servos (integrals) on a few hinges: at h = 1/15 with yoshida3 a later stage of some steps
    fails, so the drives' integrals of the stages before it must be undone with the state."""
    b = scenes.chain(50)
    for j in (0, 7, 20, 41):
        b.add_motor(j, "position", target=0.2, kp=20.0, ki=10.0, kd=1.0)
    return b


def _limited_chain(links: int = 10, bound: float = 0.3) -> wi.SceneBuilder:
    """A hinged chain with a +-bound limit on every hinge: it swings into its stops (push-only rows that become
    active, release and hit again)."""
    b = scenes.chain(links)
    for j in range(links):
        b.add_joint_limit(j, -bound, bound)
    return b


def _motor_chain(links: int = 10) -> wi.SceneBuilder:
    """A hinged chain with a stiff motor on every hinge (rows of the correction loop, coupled through the
    joints): velocity servos, position servos, and one too weak to hold (it saturates at max_force)."""
    b = scenes.chain(links)
    for j in range(links):
        if j % 3 == 2:
            b.add_motor(j, "position", target=0.2 * (j % 2) - 0.1, max_force=1e4, stiff=True)
        else:
            b.add_motor(j, "velocity", target=0.5 if j else 0.2, max_force=1e4 if j else 2.0, stiff=True)
    return b


def _roped_chain(links: int = 6) -> wi.SceneBuilder:
    """A hinged chain whose tip hangs from a rope to a world point (it goes taut as the chain swings down), a
    strut keeping two links apart, and a sprung slider: distance rows with joints and force elements."""
    b = scenes.chain(links, joint=["revolute", "revolute", "prismatic"])
    tip = b.bodies[links - 1].position
    b.add_distance(None, links - 1, tip + (0.0, 0.0, 1.0), tip, max_distance=1.5, name="rope")
    b.add_distance(0, links - 2, b.bodies[0].position, b.bodies[links - 2].position, min_distance=3.5, name="strut")
    b.add_joint_spring(2, 40.0, damping=1.0)
    b.add_joint_limit(1, -0.1, 0.1)
    return b


def _sprung_limited_chain() -> wi.SceneBuilder:
    """The sprung chain with limits on its hinges: force elements (the coupled prediction) and rows together."""
    b = _sprung_chain()
    for j in range(0, 10, 2):
        b.add_joint_limit(j, -0.2, 0.2)
    return b


def _gimbal_drives() -> wi.SceneBuilder:
    """A pendulum's arm on two hinges and a slider through two light bodies (`chain_joints`, MJCF's joints in one
    body), the first hinge read by two drives: a position servo and an effort motor on it, a velocity servo on
    the second, a spring on the slider (a force at the hinges' anchor). The drives read their chain's other rows'
    axes and points, formed once a stage for them all (`forces.coordinate_geometry`)."""
    b = wi.SceneBuilder()
    anchor = np.array([0.0, 0.0, 1.0])
    base = b.add_body(2.0, (0.02, 0.03, 0.04), anchor + (0.0, 0.0, 0.1), name="base")
    b.add_joint_revolute(None, base, anchor + (0.0, 0.0, 0.1), (0.0, 0.0, 1.0))
    parent = base
    for i, axis in enumerate(np.eye(3)):
        light = i < 2
        body = b.add_body(1e-6 if light else 1.0, (1e-8,) * 3 if light else (0.01, 0.05, 0.05),
                          anchor if light else anchor + (0.4, 0.0, -0.2), name=f"link{i}")  # fmt: skip
        b.add_joint("revolute" if light else "prismatic", parent, body, anchor, axis)
        parent = body
    b.chain_joints([1, 2, 3])
    b.add_motor(1, "position", target=0.3, kp=20.0, ki=2.0, kd=1.0)
    b.add_motor(1, "effort", target=0.5)
    b.add_motor(2, "velocity", target=0.2, kp=5.0, max_force=4.0)
    b.add_joint_spring(3, 10.0, damping=0.5, rest=0.1)
    return b


MIXED = ["ball", "prismatic", "universal", "fixed", "cylindrical", "planar", "revolute"]
# (scene, dt, steps, Simulator options): every solver the fused schedule has, both formulations, every
# constraint kind, model forces that end within the run, fast spins (split steps), failing steps (halved).
CASES = {
    "double_pendulum": (scenes.double_pendulum, 1 / 120, 120, {}),
    "chain10": (lambda: scenes.chain(10), 1 / 60, 60, {}),
    "tree31_torque_ends": (lambda: scenes.binary_tree(31), 1 / 30, 45, {}),
    "star31_body_matrix": (lambda: scenes.star(31), 1 / 60, 30, {"formulation": "body"}),
    "mixed_kinds": (lambda: scenes.chain(7, joint=MIXED), 1 / 60, 60, {}),
    "mixed_kinds_unspecialized": (lambda: scenes.chain(7, joint=MIXED), 1 / 60, 20, {"specialize": False}),
    "tree15_iterative": (lambda: scenes.binary_tree(15), 1 / 30, 40, {"solver": "iterative", "tolerance": 1e-8}),
    "free_bodies": (_free_bodies, 1 / 60, 30, {}),
    "spin_split": (lambda: _spinning_pendulum(100.0), 1 / 60, 20, {}),
    "spin_split_iterative": (lambda: _spinning_pendulum(100.0), 1 / 60, 10, {"solver": "iterative"}),
    "loop_redundant_rows": (welded_hinge, 1 / 60, 60, {}),
    "chain50_halved": (lambda: scenes.chain(50), 1 / 30, 60, {}),
    # Compositions (order 4, 6): the stages of a step in the launch, backward ones too; spin splits and halvings
    # of whole composed steps; a stage after the first that fails (yoshida3's -1.70 h at h = 1/15).
    "chain10_order4": (lambda: scenes.chain(10), 1 / 60, 30, {"order": 4}),
    "tree31_order6_torque_ends": (lambda: scenes.binary_tree(31), 1 / 30, 45, {"order": 6}),
    "mixed_kinds_order4": (lambda: scenes.chain(7, joint=MIXED), 1 / 60, 20, {"order": 4}),
    "star31_body_matrix_order4": (lambda: scenes.star(31), 1 / 60, 15, {"formulation": "body", "order": 4}),
    "chain50_yoshida3_halved": (
        lambda: scenes.chain(50),
        1 / 15,
        20,
        {"order": 4, "scheme": "yoshida3", "tolerance": 1e-6},
    ),
    "spin_split_order4": (lambda: _spinning_pendulum(100.0), 1 / 60, 10, {"order": 4}),
    "tree15_iterative_order4": (
        lambda: scenes.binary_tree(15),
        1 / 30,
        20,
        {"solver": "iterative", "tolerance": 1e-8, "order": 4},
    ),
    # Force elements (springs, joint springs, PID drives): the coupled RK4 prediction, the drives' integrals.
    "chain10_springs": (_sprung_chain, 1 / 60, 60, {}),
    "chain10_springs_order4": (_sprung_chain, 1 / 60, 30, {"order": 4}),
    "servo_chain": (_servo_chain, 1 / 60, 60, {}),
    "gimbal_drives": (_gimbal_drives, 1 / 120, 60, {}),
    "servo_chain_order4": (_servo_chain, 1 / 60, 40, {"order": 4}),
    "servo_chain_body_matrix_order6": (_servo_chain, 1 / 60, 20, {"order": 6, "formulation": "body"}),
    "servo_chain50_yoshida3_halved": (
        _servo_chain50,
        1 / 15,
        20,
        {"order": 4, "scheme": "yoshida3", "tolerance": 1e-6},
    ),
    # Rows of the correction loop (limits, stiff motors, distance constraints; kernels/limits.py): their position
    # pass in every iteration, the rows' system S at each new state, their velocity pass; steps taken at order 2
    # when 4 or 6 is asked (ROWS_FALLBACK); a step that fails in a batch is handed back and halved.
    "chain10_limits": (_limited_chain, 1 / 60, 90, {}),
    "chain10_stiff_motors": (_motor_chain, 1 / 60, 60, {}),
    "chain6_distances": (_roped_chain, 1 / 60, 60, {}),
    "chain10_springs_limits": (_sprung_limited_chain, 1 / 60, 60, {}),
    "walker_held": (lambda: scenes.walking_machine(collide=False), 1 / 60, 40, {}),
    "car_held": (lambda: scenes.car(collide=False), 1 / 60, 40, {}),
    "chain10_limits_order4": (_limited_chain, 1 / 60, 40, {"order": 4}),
    "chain10_limits_body_matrix_order6": (_limited_chain, 1 / 60, 30, {"order": 6, "formulation": "body"}),
    "chain50_limits_halved": (lambda: _limited_chain(50, 0.5), 1 / 20, 30, {}),
    # The first iteration's Newton step (`newton`): every kind, both formulations, rows, force elements, a loop's
    # redundant rows, compositions, halved steps.
    "chain10_newton": (lambda: scenes.chain(10), 1 / 60, 60, {"newton": True}),
    "mixed_kinds_newton": (lambda: scenes.chain(7, joint=MIXED), 1 / 60, 60, {"newton": True}),
    "star31_body_matrix_newton": (lambda: scenes.star(31), 1 / 60, 30, {"formulation": "body", "newton": True}),
    "loop_redundant_rows_newton": (welded_hinge, 1 / 60, 60, {"newton": True}),
    "chain50_halved_newton": (lambda: scenes.chain(50), 1 / 30, 60, {"newton": True}),
    "mixed_kinds_order4_newton": (lambda: scenes.chain(7, joint=MIXED), 1 / 60, 20, {"order": 4, "newton": True}),
    "servo_chain_newton": (_servo_chain, 1 / 60, 60, {"newton": True}),
    "chain10_limits_newton": (_limited_chain, 1 / 60, 90, {"newton": True}),
}


def _run(case: str, schedule: str, batched: bool):
    make, dt, steps, options = CASES[case]
    # The same maths in both: the fused step's kept factor of K (`reuse_factor`, fused only) off.
    switches = {**options, "schedule": schedule, "reuse_factor": False}
    sim = wi.Simulator(make().finalize(), dt, **wi.StepOptions.fold(switches))
    stats = sim.simulate(steps * dt) if batched else [sim.step() for _ in range(steps)]
    state = [getattr(sim.state, f"body_{n}").numpy().copy() for n in "xqvw"] + [sim.drive_integral.numpy().copy()]
    state += [sim.limit_impulse.numpy().copy(), sim.limit_velocity_impulse.numpy().copy()]
    return sim, stats, state


@pytest.mark.parametrize("case", CASES)
def test_fused_and_parallel_agree_bit_for_bit(case):
    """The fused schedule's steps in one call against the parallel schedule's: in one call too where the steps
    defer their velocity corrections to the next (`defer_velocities`: only the call's last is corrected), else a
    call a step (the same steps then)."""
    fused, fused_stats, fused_state = _run(case, "fused", batched=True)
    parallel, parallel_stats, parallel_state = _run(case, "parallel", batched=fused.defer_velocities)
    assert fused.schedule == "fused" and parallel.schedule == "parallel"
    assert fused_stats == parallel_stats
    for a, b in zip(fused_state, parallel_state):
        np.testing.assert_array_equal(a, b)
    assert fused.step_count == parallel.step_count and fused.time == parallel.time
    assert fused.redundant_rows == parallel.redundant_rows


def test_the_cases_reach_the_host_paths():
    """The cases above do exercise the hand-overs: splits, halvings, force changes within a batch."""
    assert max(s.substeps for s in _run("spin_split", "fused", True)[1]) == 4
    assert max(s.substeps for s in _run("chain50_halved", "fused", True)[1]) > 1
    assert max(s.substeps for s in _run("spin_split_order4", "fused", True)[1]) == 4


def _row_history(case: str) -> tuple[np.ndarray, list]:
    """Each step's row impulses (N s or N m s) and stats of a case, by the fused schedule."""
    make, dt, steps, options = CASES[case]
    sim = wi.Simulator(make().finalize(), dt, **wi.StepOptions.fold(options))
    assert sim.schedule == "fused", sim.schedule_note
    impulses, stats = [], []
    for _ in range(steps):
        stats.append(sim.step())
        impulses.append(sim.limit_impulse.numpy().copy())
    return np.array(impulses), stats


@pytest.mark.fused
def test_the_row_cases_reach_their_paths():
    """The row cases do exercise what they name: limits that push on some steps and not others, every row of
    the distances case, a saturated motor (|impulse| = max_force h), halved steps handed back from a batch, and
    order 4 taken at order 2 with its reason."""
    limits, _ = _row_history("chain10_limits")
    pushing = np.count_nonzero(limits, axis=1)
    assert pushing.max() == 10 and (pushing == 0).any()
    distances, _ = _row_history("chain6_distances")
    assert np.all(np.count_nonzero(distances, axis=0) > 0)  # the limit, the rope and the strut
    motors, _ = _row_history("chain10_stiff_motors")
    assert np.all(np.abs(np.abs(motors[:, 0]) - 2.0 / 60) < 1e-12)  # the weak servo gives all it has
    _, stats = _row_history("chain50_limits_halved")
    assert max(s.substeps for s in stats) > 1 and min(s.substeps for s in stats) == 1
    _, stats = _row_history("chain10_limits_order4")
    assert {(s.order, s.fallback) for s in stats} == {(2, wi.simulator.ROWS_FALLBACK)}


@pytest.mark.fused
@pytest.mark.parametrize("case", ["chain10_limits", "chain10_stiff_motors", "chain6_distances", "walker_held"])
def test_steps_with_rows_are_taken_by_the_fused_kernel(case, monkeypatch):
    """A batch of steps with rows is one launch and hands no step back (a fused kernel that failed every step
    would still agree with the parallel schedule, which would take them all)."""
    make, dt, steps, options = CASES[case]
    sim = wi.Simulator(make().finalize(), dt, **wi.StepOptions.fold(options))
    counts = _count_launches(sim, monkeypatch)
    stats = sim.step(steps)
    assert counts == {"launches": 1, "parallel_steps": 0, "substep_launches": 0} and stats.converged


def test_a_composed_step_that_fails_in_a_later_stage_is_redone_from_its_start(monkeypatch):
    """yoshida3 at h = 1/15 on chain50: a stage after the first fails, the fused kernel restores the start of the
    composed step and the host its frames (they were the last stage's), then the parallel schedule halves it."""
    make, dt, steps, options = CASES["chain50_yoshida3_halved"]
    sim = wi.Simulator(make().finalize(), dt, **wi.StepOptions.fold(options))
    redone, update = [], sim._update_frames

    def update_frames():
        before = sim.frames.jac_ang.numpy().copy()
        update()
        redone.append(not np.array_equal(before, sim.frames.jac_ang.numpy()))

    monkeypatch.setattr(sim, "_update_frames", update_frames)
    stats = sim.simulate(steps * dt)
    assert any(redone) and max(s.substeps for s in stats) > 1 and all(s.order == 4 for s in stats)


class Counted:
    """A packed launch whose calls are counted in `counts[key]`."""

    def __init__(self, launch, counts: dict, key: str):
        self.inner, self.counts, self.key = launch, counts, key

    def launch(self):
        self.counts[self.key] += 1
        self.inner.launch()


def _count_launches(sim: wi.Simulator, monkeypatch) -> dict:
    """Count the fused launches (calls of the packed launch) and the steps handed to the parallel schedule."""
    counts = {"launches": 0, "parallel_steps": 0, "substep_launches": 0}
    launch_for, step_parallel = sim._fused_launch, sim._step_parallel

    def parallel(*args):
        counts["parallel_steps"] += 1
        return step_parallel(*args)

    monkeypatch.setattr(sim, "_fused_launch", lambda h: Counted(launch_for(h), counts, "launches"))
    launch_for(sim.dt)  # recorded now, and then counted where `step` finds it (`Simulator._fused_by_h`)
    sim._fused_by_h = {h: Counted(launch, counts, "launches") for h, launch in sim._fused_by_h.items()}
    monkeypatch.setattr(sim, "_step_parallel", parallel)
    return counts


@pytest.mark.fused
def test_a_batch_of_steps_is_one_launch(monkeypatch):
    """tree31's start torque ends at t = 1 s: 90 steps of 1/60 are two launches (before and after), no step
    goes to the host; a spin that needs splitting is handed back and its substeps are fused launches of their
    own (`_split_step`), not the parallel schedule's."""
    sim = wi.Simulator(scenes.binary_tree(31).finalize(), 1 / 60)
    counts = _count_launches(sim, monkeypatch)
    stats = sim.step(90)
    assert counts == {"launches": 2, "parallel_steps": 0, "substep_launches": 0}
    assert sim.step_count == 90 and stats.substeps == 90 and stats.converged

    sim = wi.Simulator(_spinning_pendulum(100.0).finalize(), 1 / 60)
    counts = _count_launches(sim, monkeypatch)
    substeps = sim._substep_launch
    monkeypatch.setattr(sim, "_substep_launch", lambda depth: Counted(substeps(depth), counts, "substep_launches"))
    stats = sim.step(3)
    assert counts["parallel_steps"] == 0 and counts["substep_launches"] >= 1 and stats.substeps > 3


@pytest.mark.parametrize("case", ["tree31_torque_ends", "spin_split", "chain50_halved", "chain10_limits_order4"])
def test_step_n_stats_are_the_steps_combined(case):
    """step(n) builds its stats from the batch's status rows at once (`Simulator._fused_stats`): they are what
    combining the n steps' own stats gives, also where steps were handed to the host (splits, halvings) or taken
    at order 2, and the state is the same."""
    make, dt, steps, options = CASES[case]
    whole = wi.Simulator(make().finalize(), dt, **wi.StepOptions.fold(options))
    single = wi.Simulator(make().finalize(), dt, **wi.StepOptions.fold(options))
    together = whole.step(steps)
    assert together == combined(single.simulate(steps * dt))  # one call too, a StepStats a step
    assert together.substeps >= steps
    np.testing.assert_array_equal(whole.positions(), single.positions())
    assert whole.step_count == single.step_count == steps and whole.time == single.time


def test_step_n_is_n_steps():
    a = wi.Simulator(scenes.chain(5).finalize(), 1 / 60)
    b = wi.Simulator(scenes.chain(5).finalize(), 1 / 60)
    combined = a.step(25)
    single = b.simulate(25 / 60)  # one call too (`defer_velocities`), a StepStats a step
    np.testing.assert_array_equal(a.positions(), b.positions())
    assert combined.joint_iterations == sum(s.joint_iterations for s in single)
    assert combined.max_joint_error == max(s.max_joint_error for s in single)
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="n must be"):
            a.step(bad)


@pytest.mark.fused
def test_schedule_choice():
    model = scenes.chain(3).finalize()
    assert wi.Simulator(model, 1 / 60).schedule == "fused"  # auto, on a CPU
    assert wi.Simulator(model, 1 / 60, options=wi.StepOptions(schedule="parallel")).schedule == "parallel"
    cg = wi.Simulator(model, 1 / 60, solver="cg", options=wi.StepOptions(schedule="fused"))
    assert cg.schedule == "parallel" and "CG" in cg.schedule_note
    with pytest.raises(ValueError, match="unknown schedule 'gpu'"):
        wi.Simulator(model, 1 / 60, options=wi.StepOptions(schedule="gpu"))
    assert wi.Simulator(_servo_chain().finalize(), 1 / 60).schedule == "fused"  # force elements run fused
    limited = scenes.chain(3)
    limited.add_joint_limit(0, -0.3, 0.3)
    assert wi.Simulator(limited.finalize(), 1 / 60).schedule == "fused"  # rows run fused
    ropes = wi.SceneBuilder()
    a, b = (ropes.add_body(1.0, (0.1, 0.1, 0.1), (x, 0.0, 0.0)) for x in (0.0, 1.0))
    ropes.add_distance(a, b, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), max_distance=0.5)
    sim = wi.Simulator(ropes.finalize(), 1 / 60)
    assert sim.schedule == "parallel" and "distance constraints without joints" in sim.schedule_note
    held = wi.Simulator(scenes.walking_machine().finalize(), 1 / 60)  # colliding shapes: a contact stage
    assert held.schedule == "parallel" and "contacts" in held.schedule_note
    free = wi.SceneBuilder()
    a, b = (free.add_body(1.0, (0.1, 0.1, 0.1), (x, 0.0, 0.0)) for x in (0.0, 1.0))
    free.add_spring(a, b, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 10.0, rest_length=0.5)
    sim = wi.Simulator(free.finalize(), 1 / 60)
    assert sim.schedule == "parallel" and "without joints" in sim.schedule_note


def _failure(schedule: str, make, **options) -> str:
    sim = wi.Simulator(make(), **wi.StepOptions.fold({**options, "schedule": schedule}))
    with pytest.raises((wi.SimulationError, RuntimeError)) as info:
        sim.simulate(1.0)
    return str(info.value)


def _nan_at_step_4(schedule: str) -> str:
    sim = wi.Simulator(scenes.binary_tree(15).finalize(), 1 / 60, options=wi.StepOptions(schedule=schedule))
    sim.step(3)
    v = sim.state.body_v.numpy()
    v[5, 0] = np.nan
    sim.state.body_v.assign(v)
    with pytest.raises(wi.SimulationError) as info:
        sim.step(10)
    return str(info.value)


def test_failures_found_by_the_fused_kernel_name_step_joints_and_bodies():
    """The fused kernel stops at a failing step and the host reports it exactly as the parallel schedule does."""
    nan = _nan_at_step_4("fused")
    assert nan == _nan_at_step_4("parallel")
    assert nan.startswith("step 4: ") and "NaN or Inf" in nan

    def tree(**options):
        return lambda schedule: _failure(
            schedule, lambda: scenes.binary_tree(31).finalize(), dt=1 / 10, max_substep_depth=0, **options
        )

    limit = tree(max_iterations=1)
    assert limit("fused") == limit("parallel")
    assert limit("fused").startswith("step 1 ") and "worst joints: 'j" in limit("fused")

    def limited(schedule):  # the rows' errors count in the joint correction's: it stops on its limit
        return _failure(schedule, lambda: _limited_chain(10, 0.05).finalize(), dt=1 / 10, max_iterations=2,
                        max_substep_depth=0)  # fmt: skip

    assert limited("fused") == limited("parallel") and "worst joints" in limited("fused")


@pytest.mark.parametrize("solver", ["cholesky", "iterative"])
def test_warn_policy_agrees(solver):
    def run(schedule):
        sim = wi.Simulator(
            scenes.binary_tree(31).finalize(),
            1 / 10,
            solver=solver,
            max_iterations=1,
            on_max_iterations="warn",
            options=wi.StepOptions(max_substep_depth=0, schedule=schedule),
        )
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            stats = sim.simulate(0.3)
        return stats, [str(w.message) for w in caught], sim.positions()

    fused, parallel = run("fused"), run("parallel")
    assert fused[0] == parallel[0] and fused[1] == parallel[1]
    np.testing.assert_array_equal(fused[2], parallel[2])
    assert not fused[0][0].converged


def test_status_columns_are_distinct():
    columns = [
        step_kernels.STATUS_CODE, step_kernels.STATUS_JOINT_ITERATIONS, step_kernels.STATUS_VELOCITY_ITERATIONS,
        step_kernels.STATUS_JOINT_ERROR, step_kernels.STATUS_VELOCITY_ERROR, step_kernels.STATUS_LINEAR_ITERATIONS,
        step_kernels.STATUS_SPIN, step_kernels.STATUS_FAILED_VELOCITY,
    ]  # fmt: skip
    assert sorted(int(c) for c in columns) == list(range(step_kernels.STATUS_WIDTH))


def test_the_readme_step_time_block_is_the_committed_json():
    """docs/results.md's step-time block is generated by benchmarks/step_breakdown.py from its JSON, never typed."""
    import importlib.util
    import json
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    spec = importlib.util.spec_from_file_location("step_breakdown", root / "benchmarks/step_breakdown.py")
    breakdown = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(breakdown)
    result = json.loads((root / "benchmarks/results/step_breakdown.json").read_text())
    text = (root / "docs/results.md").read_text()
    block = text[text.index("<!-- step-time:begin -->") + 24 : text.index("<!-- step-time:end -->")]
    assert block.strip() == breakdown.table(result).strip()


@pytest.mark.fused
@pytest.mark.parametrize("order", [2, 4, 6])
def test_order_and_fall_back_under_the_fused_schedule(order, monkeypatch):
    """Composed steps (order 4, 6) run by the fused schedule, a batch a launch; a step recorded with fall_back()
    is taken by the parallel one, at order 2 with its reason, and the fused schedule goes on after it."""
    model = scenes.chain(5).finalize()
    composed = wi.Simulator(model, 1 / 60, order=order)
    counts = _count_launches(composed, monkeypatch)
    stats = composed.step(20)
    assert composed.schedule == "fused" and counts == {"launches": 1, "parallel_steps": 0, "substep_launches": 0}
    assert stats.order == order and stats.converged
    fused, parallel = (
        wi.Simulator(model, 1 / 60, order=order, options=wi.StepOptions(schedule=s, reuse_factor=False))
        for s in ("fused", "parallel")
    )
    results = []
    for sim in (fused, parallel):
        sim.step(3)
        sim.fall_back("an impact")
        results.append([sim.step(), *sim.simulate(5 / 60)])
    assert results[0] == results[1] and results[0][0].fallback == "an impact"
    assert results[0][0].order == 2 and all(s.order == order for s in results[0][1:])
    np.testing.assert_array_equal(fused.positions(), parallel.positions())


def test_a_halved_composed_step_undoes_the_drives_integrals_of_its_failed_attempt():
    """A composed step whose later stage fails is redone as two halves from its start: the drives' integrals too
    (the first stages' increments are undone with the state), so the halves are two steps of h/2 bit for bit."""
    make, dt, _, options = CASES["servo_chain50_yoshida3_halved"]
    sim = wi.Simulator(make().finalize(), dt, **wi.StepOptions.fold({**options, "schedule": "parallel"}))
    halves = wi.Simulator(
        make().finalize(),
        dt / 2,
        **wi.StepOptions.fold({**options, "schedule": "parallel", "max_substep_depth": 6}),
    )
    for _ in range(20):
        start = _state(sim) + [sim.drive_integral.numpy().copy()]
        stats = sim.step()
        if stats.substeps == 2:
            break
    assert stats.substeps == 2 and stats.joint_iterations > 0
    for name, values in zip("xqvw", start):  # as they are (set_state would normalise the quaternions)
        getattr(halves.state, f"body_{name}").assign(values)
    halves._update_frames()
    halves.drive_integral.assign(start[4])
    halves.step_count, halves.time = 2 * (sim.step_count - 1), sim.time - dt
    halves.step(2)
    np.testing.assert_array_equal(sim.drive_integral.numpy(), halves.drive_integral.numpy())
    for a, b in zip(_state(sim), _state(halves)):
        np.testing.assert_array_equal(a, b)


def _state(sim: wi.Simulator) -> list[np.ndarray]:
    return [getattr(sim.state, f"body_{n}").numpy().copy() for n in "xqvw"]


def test_motor_targets_set_between_batches_agree():
    """A new motor target between two batches reaches the fused kernel (it reads the targets each launch)."""
    results = []
    for schedule in ("fused", "parallel"):
        sim = wi.Simulator(_servo_chain().finalize(), 1 / 60, options=wi.StepOptions(schedule=schedule))
        sim.simulate(0.5)
        sim.set_motor_target(0, -0.3)
        sim.set_motor_target(1, 2.0)
        stats = sim.simulate(0.5)
        results.append((stats, _state(sim), sim.drive_integral.numpy()))
    assert results[0][0] == results[1][0]
    for a, b in zip([*results[0][1], results[0][2]], [*results[1][1], results[1][2]]):
        np.testing.assert_array_equal(a, b)
    assert np.all(results[0][2][2:] != 0.0)  # the three servos' integrals moved (drives 0, 1 are joint springs)


def test_stiff_motor_targets_set_between_batches_agree():
    """A stiff motor's new target (a row's goal) between two batches reaches the fused kernel: the held car
    steers the other way and its wheels speed up, as under the parallel schedule."""
    results = []
    for schedule in ("fused", "parallel"):
        sim = wi.Simulator(scenes.car(collide=False).finalize(), 1 / 60, options=wi.StepOptions(schedule=schedule))
        sim.simulate(0.25)
        sim.set_motor_target(4, -0.2)  # the steering servos (motors 4, 5: one target)
        sim.set_motor_target(0, 9.0)  # the front-left wheel
        stats = sim.simulate(0.25)
        results.append((stats, _state(sim), sim.joint_coordinates("front_left_steering")))
    assert results[0][0] == results[1][0]
    for a, b in zip(results[0][1], results[1][1]):
        np.testing.assert_array_equal(a, b)
    assert results[0][2][0] < 0.0  # it turned to the new target's side


# Every reader of a point constraint's J_ang: K's column and slot assembly, the augmented matrix, the serial sweeps,
# the rows' coupling and reaction, contacts on jointed bodies, the split systems, one tree on several threads.
POINT_READERS = {
    "chain10": (CASES["chain10"], ("fused", "parallel")),
    "star31_body_matrix": (CASES["star31_body_matrix"], ("fused", "parallel")),
    "tree15_iterative": (CASES["tree15_iterative"], ("fused", "parallel")),
    "chain10_limits": (CASES["chain10_limits"], ("fused", "parallel")),
    "chain6_distances": (CASES["chain6_distances"], ("fused", "parallel")),
    "tree31_cg": ((lambda: scenes.binary_tree(31), 1 / 60, 20, {"solver": "cg"}), ("parallel",)),
    "car_on_ground": ((lambda: scenes.car(ground=True), 1 / 60, 20, {}), ("parallel",)),
    "four_bar_split_systems": ((scenes.four_bar, 1 / 60, 20, {"formulation": "split"}), ("parallel",)),
}


def _without_point_blocks(sim: wi.Simulator) -> None:
    """NaN in every point constraint's rows of jac_ang, which no frames pass writes: a point's J_ang lives in
    jac_skew alone (`constraints.constraint_frame`), so a reader of these rows makes the step NaN."""
    point = np.repeat(sim.model.host.constraint_kind == int(wi.types.ConstraintKind.POINT), 2)
    assert point.any()
    blocks = sim.frames.jac_ang.numpy()
    blocks[point] = np.nan
    sim.frames.jac_ang.assign(blocks)


def _states(sim, steps: int, dt: float) -> list[np.ndarray]:
    sim.simulate(steps * dt)
    return [getattr(sim.state, f"body_{n}").numpy().copy() for n in "xqvw"]


@pytest.mark.parametrize(("case", "schedule"), [(c, s) for c, (_, ss) in POINT_READERS.items() for s in ss])
def test_point_constraints_read_no_angular_block(case, schedule):
    """The steps are those of the same simulator with NaN in its points' jac_ang rows, bit for bit."""
    (make, dt, steps, options), _ = POINT_READERS[case]
    plain = wi.Simulator(make().finalize(), dt, **wi.StepOptions.fold({**options, "schedule": schedule}))
    blind = wi.Simulator(make().finalize(), dt, **wi.StepOptions.fold({**options, "schedule": schedule}))
    _without_point_blocks(blind)
    assert blind.schedule == schedule
    for a, b in zip(_states(plain, steps, dt), _states(blind, steps, dt)):
        np.testing.assert_array_equal(a, b)


@pytest.mark.fused
def test_one_tree_on_several_threads_reads_no_angular_block():
    """As above, for the split step (`warpimpulse/split.py`) of a 127-body tree on 2 threads."""
    model = scenes.binary_tree(127).finalize()
    plain = SplitSimulator(model, 1 / 60, threads=2)
    blind = SplitSimulator(model, 1 / 60, threads=2)
    _without_point_blocks(blind)
    assert blind.threads == 2, blind.split_note
    for a, b in zip(_states(plain, 20, 1 / 60), _states(blind, 20, 1 / 60)):
        np.testing.assert_array_equal(a, b)
    plain.close()
    blind.close()
