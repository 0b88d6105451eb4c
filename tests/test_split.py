"""One tree on several threads (`warpimpulse/split.py`): the cut, and the split step against the fused step on
one thread, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

import warpimpulse as wi
from warpimpulse.simulator import Simulator
from warpimpulse.split import SEPARATOR, CutError, SplitSimulator, cut

pytestmark = pytest.mark.fused  # the split runs the fused step's stages

DT = 1.0 / 60.0
# The split step factors K at every step; a Simulator's fused step keeps it where it serves (`reuse_factor`).
FACTOR_EVERY_STEP = wi.StepOptions(reuse_factor=False)


def state_of(sim) -> list[np.ndarray]:
    return [sim.positions(), sim.orientations(), sim.linear_velocities(), sim.angular_velocities()]


def run_both(model, steps: int, threads: int = 2, **settings):
    one = Simulator(model, DT, **wi.StepOptions.fold(settings))
    split = SplitSimulator(model, DT, threads=threads, **wi.StepOptions.fold(settings))
    return one, [one.step() for _ in range(steps)], split, [split.step() for _ in range(steps)]


@pytest.mark.parametrize("threads", [2, 3])
def test_split_step_is_the_fused_step_bit_for_bit(threads):
    """127-body tree, 90 steps (the start torque, then free swinging): every body's state and every step's
    stats as the fused step on one thread gives them; and so with the velocities corrected every step, which
    exercises the split step's own velocity correction (deferred, the read of the state takes it with the
    one-thread kernel)."""
    model = wi.scenes.binary_tree(127).finalize()
    for steps, defer in ((90, None), (10, False)):
        one, a, split, b = run_both(model, steps, threads, defer_velocities=defer)
        assert one.schedule == "fused" and split.threads == threads, split.split_note
        assert a == b
        for x, y in zip(state_of(one), state_of(split)):
            assert np.array_equal(x, y)
        assert min(s.joint_iterations for s in b) >= 1  # every step's correction solved: the solve was exercised
        assert all(s.velocity_iterations == int(defer is False) for s in b)  # so was the velocity correction's
        split.close()


def test_split_step_n_sums_up_as_the_fused_step():
    """step(n) takes its stats from the launch's summary row, which the fused kernel writes and the split step
    writes on the host: the same figures, and the same state."""
    model = wi.scenes.binary_tree(63).finalize()
    one, split = Simulator(model, DT, options=FACTOR_EVERY_STEP), SplitSimulator(model, DT, threads=2)
    a, b = one.step(30), split.step(30)
    assert a == b and b.substeps == 30 and b.joint_iterations >= 30
    for x, y in zip(state_of(one), state_of(split)):
        assert np.array_equal(x, y)
    split.close()


def test_split_hands_hard_steps_to_the_parallel_schedule_as_the_fused_step_does():
    """A leaf spinning fast: its steps split into substeps (handed back, taken by the parallel schedule), then
    go on in the split step; still the fused run bit for bit."""
    model = wi.scenes.binary_tree(63).finalize()
    spin = np.zeros((63, 3))
    spin[-1] = (0.0, 0.0, 80.0)
    one, split = Simulator(model, DT), SplitSimulator(model, DT, threads=2)
    for sim in (one, split):
        sim.set_state(angular_velocities=spin)
    a = [one.step() for _ in range(40)]
    b = [split.step() for _ in range(40)]
    assert any(s.substeps > 1 for s in b)
    assert a == b
    for x, y in zip(state_of(one), state_of(split)):
        assert np.array_equal(x, y)
    split.close()


def test_cut_takes_the_root_out_and_halves_the_tree():
    model = wi.scenes.binary_tree(255).finalize()
    sim = Simulator(model, DT)
    parts = cut(model, sim.linear.pattern, 2)
    assert parts.separator["part_bodies"].tolist() == [0]  # the root
    assert [len(p["part_bodies"]) for p in parts.parts] == [127, 127]
    # Every column is a part's or the separator's once; the separator's are the root's joints.
    columns = np.sort(np.concatenate([parts.separator["part_columns"], *(p["part_columns"] for p in parts.parts)]))
    assert np.array_equal(columns, np.arange(model.constraint_count))
    assert sorted(sim.linear.pattern.perm[parts.separator["part_columns"]].tolist()) == [0, 1, 2]
    # A part's bodies are one subtree: the parts own the two halves below the root.
    assert set(np.flatnonzero(parts.owner == SEPARATOR).tolist()) == {0}


def test_cut_deals_many_subtrees_to_fewer_threads():
    """Three threads on a binary tree: the cut goes below the root (the two halves do not deal out to three)
    and keeps the cut whose largest share plus separator is smallest."""
    model = wi.scenes.binary_tree(255).finalize()
    parts = cut(model, Simulator(model, DT).linear.pattern, 3)
    sizes = [len(p["part_bodies"]) for p in parts.parts]
    separator = len(parts.separator["part_bodies"])
    assert sum(sizes) + separator == 255 and min(sizes) > 0
    assert 1 < separator and max(sizes) + separator < 0.4 * 255  # the root alone: 127 + 1


def test_a_chain_runs_on_one_thread_and_says_why():
    model = wi.scenes.chain(40).finalize()
    sim = SplitSimulator(model, DT, threads=2)
    assert sim.threads == 1 and "does not split" in sim.split_note
    one = Simulator(model, DT, options=FACTOR_EVERY_STEP)
    sim.step(5)
    one.step(5)
    assert np.array_equal(sim.positions(), one.positions())


def test_a_scene_off_the_fused_schedule_runs_on_one_thread_and_says_why():
    model = wi.scenes.car().finalize()
    sim = SplitSimulator(model, DT, threads=2)
    assert sim.threads == 1 and sim.split_note.startswith("the fused schedule does not run: ")


def test_a_composed_step_runs_on_one_thread_and_says_why():
    sim = SplitSimulator(wi.scenes.binary_tree(31).finalize(), DT, threads=2, order=4)
    assert sim.threads == 1 and sim.split_note == "orders 4 and 6 compose base steps; the split step takes order 2"


def test_force_elements_run_on_one_thread_and_say_why():
    """Springs couple the bodies' predictions (the fused step's coupled RK4), which the parts do not share."""
    builder = wi.scenes.binary_tree(31)
    builder.add_spring(None, 5, builder.bodies[5].position + (0.0, 0.0, 0.3), builder.bodies[5].position, 50.0)
    model = builder.finalize()
    sim, one = SplitSimulator(model, DT, threads=2), Simulator(model, DT)
    assert sim.threads == 1 and "force elements" in sim.split_note
    sim.step(5)
    one.step(5)
    assert np.array_equal(sim.positions(), one.positions())


def test_rows_run_on_one_thread_and_say_why():
    """A distance constraint is a row of one dense system over the whole model (kernels/limits.py): the fused
    step takes it, the parts could not."""
    builder = wi.scenes.binary_tree(31)
    top = builder.bodies[20].position
    builder.add_distance(None, 20, top + (0.0, 0.0, 0.3), top, max_distance=0.2, name="rope")
    model = builder.finalize()
    sim, one = SplitSimulator(model, DT, threads=2), Simulator(model, DT)
    assert sim.threads == 1 and "distance constraints" in sim.split_note and one.schedule == "fused"
    sim.step(5)
    one.step(5)
    assert np.array_equal(sim.positions(), one.positions())


def test_a_loop_is_not_cut():
    model = wi.scenes.four_bar().finalize()
    with pytest.raises(CutError, match="closes a loop"):
        cut(model, Simulator(model, DT).linear.pattern, 2)


def test_the_augmented_matrix_is_not_cut():
    model = wi.scenes.star(31).finalize()
    with pytest.raises(CutError, match="'body' formulation"):
        cut(model, Simulator(model, DT, options=wi.StepOptions(formulation="body")).linear.pattern, 2)


def test_threaded_simulator_of_one_world_splits_its_tree():
    model = wi.scenes.binary_tree(127).finalize()
    one = Simulator(model, DT)
    with wi.ThreadedSimulator(model, DT, threads=2) as sim:
        assert sim.threads == 2 and sim.split_note == ""
        for _ in range(20):
            assert sim.step() == one.step()
        assert np.array_equal(sim.positions(0), one.positions())
        assert np.array_equal(sim.angular_velocities()[0], one.angular_velocities())


def test_threads_must_be_a_positive_integer():
    model = wi.scenes.binary_tree(7).finalize()
    with pytest.raises(ValueError, match="threads must be an integer >= 1"):
        SplitSimulator(model, DT, threads=0)


def test_split_hands_failed_corrections_to_the_parallel_schedule_as_the_fused_step_does():
    """One joint iteration allowed: from the third step the correction needs two, fails (the velocities of t0
    put back) and the step is taken again as two halves (`Simulator._halved`); the run is still the fused run
    bit for bit. (Without `carry`, with which every step here takes one iteration.)"""
    model = wi.scenes.binary_tree(63).finalize()
    one, a, split, b = run_both(model, 10, 2, max_iterations=1, max_substep_depth=1, carry=False)
    assert [s.substeps for s in b] == [1, 1] + [2] * 8
    assert a == b
    for x, y in zip(state_of(one), state_of(split)):
        assert np.array_equal(x, y)
    split.close()


def test_simulate_with_threads_writes_the_one_thread_run(tmp_path, capsys):
    from cli_helpers import run

    from warpimpulse import usd

    out = {n: tmp_path / f"tree{n}.usda" for n in (1, 2)}
    for n, path in out.items():
        code, lines = run(["simulate", "--scene", "tree127", "--duration", "0.5", "--threads", str(n), "-o",
                           str(path), "--no-progress"], capsys)  # fmt: skip
        assert code == 0 and not any("one thread" in line for line in lines), lines
    assert np.array_equal(usd.read_animation(out[1]).positions, usd.read_animation(out[2]).positions)
    code, lines = run(["simulate", "--scene", "chain", "--duration", "0.1", "--threads", "2", "-o",
                       str(tmp_path / "chain.usda"), "--no-progress"], capsys)  # fmt: skip
    assert code == 0 and any("warpimpulse: one thread: the tree does not split" in line for line in lines), lines
