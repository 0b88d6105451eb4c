"""Batched worlds (`SceneBuilder.replicate`): each world of a batched run is, bit for bit, the run of that world
alone; one world's hard step costs the others no iterations; one world's failure stops only that world."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import warpimpulse as wi
from warpimpulse.builder import SceneError
from warpimpulse.simulator import SimulationError, Simulator

DT = 1.0 / 60.0
WORLDS = 3
BODIES = 7


def state_of(sim: Simulator, world: int | None = None) -> list[np.ndarray]:
    return [sim.positions(world), sim.orientations(world), sim.linear_velocities(world), sim.angular_velocities(world)]


def worlds_setup():
    """Per-world masses, loads and initial spins that differ from world to world."""
    base = wi.scenes.binary_tree(BODIES).finalize().host
    mass = np.stack([base.body_mass * (1.0 + 0.5 * w) for w in range(WORLDS)])
    force = np.zeros((WORLDS, BODIES, 3))
    force[1, 3] = (0.0, 2000.0, 0.0)
    spin = np.zeros((WORLDS, BODIES, 3))
    spin[2, 6] = (0.0, 0.0, 3.0)
    return mass, force, spin


def alone(world: int, steps: int, mass, force, spin, **settings) -> tuple[Simulator, list]:
    """A world of the batch alone, every (sub)step's velocities corrected as batched worlds do (`defer_velocities`)."""
    sim = Simulator(
        wi.scenes.binary_tree(BODIES).finalize(), DT, **wi.StepOptions.fold({"defer_velocities": False, **settings})
    )
    sim.set_masses(mass=mass[world])
    sim.set_external_forces(force=force[world])
    sim.set_state(angular_velocities=spin[world])
    stats = [sim.step() for _ in range(steps)]
    return sim, stats


def batched(steps: int, mass, force, spin, **settings) -> tuple[Simulator, list]:
    sim = Simulator(wi.scenes.binary_tree(BODIES).replicate(WORLDS).finalize(), DT, **wi.StepOptions.fold(settings))
    sim.set_masses(mass=mass)
    sim.set_external_forces(force=force)
    sim.set_state(angular_velocities=spin)
    stats = []
    for _ in range(steps):
        sim.step()
        stats.append(sim.world_stats)
    return sim, stats


@pytest.mark.parametrize(("formulation", "newton"), [("constraint", False), ("body", False), ("constraint", True)])
def test_batched_run_matches_each_world_alone_bit_for_bit(formulation, newton):
    mass, force, spin = worlds_setup()
    sim, stats = batched(30, mass, force, spin, formulation=formulation, newton=newton)
    assert sim.positions().shape == (WORLDS, BODIES, 3)
    for w in range(WORLDS):
        one, one_stats = alone(w, 30, mass, force, spin, formulation=formulation, newton=newton)
        for a, b in zip(state_of(one), state_of(sim, w)):
            assert np.array_equal(a, b), f"world {w} differs from its run alone"
        assert [s.joint_iterations for s in one_stats] == [int(s.joint_iterations[w]) for s in stats]
        assert one.energy() == sim.energy(w) == sim.energy()[w]
        assert np.array_equal(one.joint_errors(), sim.joint_errors(w))
        assert np.array_equal(one.joint_errors(), sim.joint_errors()[w])
        assert np.array_equal(one.joint_coordinates("j3"), sim.joint_coordinates("j3", world=w))
        assert np.array_equal(one.joint_velocities(5), sim.joint_velocities(f"world{w}/j5"))
    # The worlds differ from each other (the per-world values took effect).
    assert not np.array_equal(sim.positions(0), sim.positions(1))


def test_hard_step_in_one_world_costs_the_others_nothing():
    """A world spinning fast takes its steps as substeps alone; the others take the iterations they take alone."""
    mass, force, spin = worlds_setup()
    spin[0, 6] = (0.0, 0.0, 200.0)  # world 0 must split its steps
    sim, stats = batched(5, mass, force, spin)
    assert all(s.alone[0] and s.substeps[0] > 1 for s in stats)
    for w in (1, 2):
        _, one_stats = alone(w, 5, mass, force, spin)
        assert [s.joint_iterations for s in one_stats] == [int(s.joint_iterations[w]) for s in stats]
        assert not any(s.alone[w] for s in stats)
    hard, _ = alone(0, 5, mass, force, spin)
    for a, b in zip(state_of(hard), state_of(sim, 0)):
        assert np.array_equal(a, b)


def test_a_failing_world_stops_alone_with_its_index():
    mass, force, spin = worlds_setup()
    force[1, 6] = (0.0, 0.0, 1e13)  # world 1's correction cannot converge
    with pytest.raises(SimulationError) as alone_error:
        alone(1, 10, mass, force, spin, max_iterations=10)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sim, _ = batched(10, mass, force, spin, max_iterations=10)
    assert list(sim.stopped) == [1]
    assert sim.stopped[1].startswith("world 1: step 1 ")
    assert "world1/j6" in sim.stopped[1]
    assert str(alone_error.value).split(";")[0] in sim.stopped[1]  # the same failure as alone
    assert any("world 1:" in str(w.message) for w in caught)
    for w in (0, 2):  # the others went on, exactly as alone
        one, _ = alone(w, 10, mass, force, spin, max_iterations=10)
        for a, b in zip(state_of(one), state_of(sim, w)):
            assert np.array_equal(a, b)
    # The stopped world stays at its last good state: the start.
    start = Simulator(wi.scenes.binary_tree(BODIES).finalize(), DT)
    assert np.array_equal(sim.positions(1), start.positions())


def test_every_world_stopped_raises():
    sim = Simulator(
        wi.scenes.binary_tree(BODIES).replicate(2).finalize(),
        DT,
        max_iterations=5,
        options=wi.StepOptions(max_substep_depth=0),
    )
    force = np.zeros((2, BODIES, 3))
    force[:, 6] = (0.0, 0.0, 1e13)
    sim.set_external_forces(force=force)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim.step()
        assert sorted(sim.stopped) == [0, 1]
        with pytest.raises(SimulationError, match="every one of the 2 worlds has stopped"):
            sim.step()


def test_replicate_layout_and_names():
    builder = wi.scenes.binary_tree(BODIES).replicate(WORLDS)
    model = builder.finalize()
    assert (model.world_count, model.world_body_count, model.body_count) == (WORLDS, BODIES, WORLDS * BODIES)
    assert model.body_name[BODIES] == "world1/b0" and model.joint_name[-1] == f"world{WORLDS - 1}/j6"
    single = wi.scenes.binary_tree(BODIES).finalize()
    assert np.array_equal(model.host.constraint_body1[: single.constraint_count], single.host.constraint_body1)
    assert np.array_equal(
        model.host.constraint_body1[single.constraint_count : 2 * single.constraint_count],
        single.host.constraint_body1 + BODIES,
    )
    nb, nc, n = BODIES, single.constraint_count, WORLDS * BODIES

    def shifted(u, w):  # an unknown of the augmented matrix alone -> in world w: linear, angular, constraint parts
        return np.where(u < nb, u + w * nb, np.where(u < 2 * nb, u - nb + n + w * nb, u - 2 * nb + 2 * n + w * nc))

    # Each world's columns together, in the order they have alone.
    alone, batch = single.topology.pattern("constraint").perm, model.topology.pattern("constraint").perm
    assert np.array_equal(batch, np.concatenate([alone + w * nc for w in range(WORLDS)]))
    alone, batch = single.topology.pattern("body").perm, model.topology.pattern("body").perm
    assert np.array_equal(batch, np.concatenate([shifted(alone, w) for w in range(WORLDS)]))
    part = model.worlds(1, 3)
    assert part.world_count == 2 and part.body_name[0] == "world1/b0"
    assert np.array_equal(part.host.joint_parent, model.host.joint_parent[: 2 * BODIES])
    assert np.array_equal(part.host.force_body, model.host.force_body[:2])
    assert wi.scenes.binary_tree(BODIES).replicate(1).finalize().body_name[0] == "b0"


def test_replicate_refuses_bad_input():
    builder = wi.scenes.binary_tree(BODIES)
    with pytest.raises(SceneError, match="count must be an integer >= 1"):
        builder.replicate(0)
    limited = wi.scenes.chain(3)
    limited.add_joint_limit(1, -0.5, 0.5)
    with pytest.raises(SceneError, match="the scene has 1 limits; batched worlds do not take limits yet"):
        limited.replicate(2)
    stiff = wi.scenes.chain(3)
    stiff.add_motor(0, "velocity", target=1.0, max_force=50.0, stiff=True)
    with pytest.raises(SceneError, match="1 stiff motors; batched worlds do not take stiff motors yet"):
        stiff.replicate(2)
    many = builder.replicate(2)
    with pytest.raises(SceneError, match="takes no additions"):
        wi.scenes.chain(3).replicate(2).add_joint_limit(0, -1.0, 1.0)
    with pytest.raises(SceneError, match="takes no additions"):
        many.add_body(1.0, (1.0, 1.0, 1.0), (0.0, 0.0, 0.0))
    with pytest.raises(SceneError, match="already replicated"):
        many.replicate(2)
    model = many.finalize()
    with pytest.raises(ValueError, match="cholesky"):
        Simulator(model, DT, solver="cg")
    sim = Simulator(model, DT)
    with pytest.raises(ValueError, match="world 2 does not exist"):
        sim.positions(world=2)
    with pytest.raises(ValueError, match=r"force must have shape \(2, 7, 3\)"):
        sim.set_external_forces(force=np.zeros((BODIES, 3)))
    with pytest.raises(ValueError, match="world1/b0.*must be positive"):
        sim.set_masses(mass=np.zeros(BODIES), world=1)


def test_per_world_values_change_one_world_only():
    sim = Simulator(wi.scenes.binary_tree(BODIES).replicate(2).finalize(), DT)
    sim.set_state(linear_velocities=np.ones((BODIES, 3)), world=1)
    assert np.all(sim.linear_velocities(1) == 1.0) and np.all(sim.linear_velocities(0) == 0.0)
    before = sim.model.host.body_mass.copy()
    sim.set_masses(mass=2.0 * before[:BODIES], world=0)
    assert np.array_equal(sim.model.host.body_mass[:BODIES], 2.0 * before[:BODIES])
    assert np.array_equal(sim.model.host.body_mass[BODIES:], before[BODIES:])
    sim.reset()
    assert np.all(sim.linear_velocities() == 0.0) and sim.stopped == {}


# Shares of the ThreadedSimulator: batched ones (the parallel schedule asked: two worlds and one on 2 threads)
# and one-world fused ones (each world a share, n steps a launch), with how each is stepped n times.
SHARES = {
    "batched": ({"schedule": "parallel"}, lambda sim, n: [sim.step() for _ in range(n)]),
    "fused": ({}, lambda sim, n: sim.step(n)),
}


@pytest.mark.fused
@pytest.mark.parametrize("shares", SHARES)
def test_threads_give_the_batched_run_and_stop_worlds_alone(shares):
    """Shares of two worlds and of one (3 worlds on 2 threads), or of one world each: the same run as one batched
    Simulator, bit for bit; a failure in any kind of share stops that world only, by its index in the whole
    model."""
    from warpimpulse.threads import ThreadedSimulator

    settings, steps = SHARES[shares]
    mass, force, spin = worlds_setup()
    force[1, 6] = force[2, 6] = (0.0, 0.0, 1e13)  # world 1 in the two-world share, world 2 alone in its share
    with pytest.warns(RuntimeWarning, match="the world stops"):
        ref, _ = batched(5, mass, force, spin, max_iterations=10)
    with ThreadedSimulator(wi.scenes.binary_tree(BODIES).replicate(WORLDS).finalize(), DT, threads=2,
                           max_iterations=10, **wi.StepOptions.fold(settings)) as sim:  # fmt: skip
        assert sim.fused_shares == (shares == "fused")
        assert [p.model.world_count for p in sim.parts] == ([2, 1] if shares == "batched" else [1, 1, 1])
        sim.set_masses(mass=mass)
        sim.set_external_forces(force=force)
        sim.set_state(angular_velocities=spin)
        with pytest.warns(RuntimeWarning, match="world 2: step 1"):
            steps(sim, 5)
        assert sorted(sim.stopped) == [1, 2] and sim.stopped[1].startswith("world 1: ")
        for a, b in zip(state_of(ref), state_of(sim)):
            assert np.array_equal(a, b)
        assert np.array_equal(sim.positions(2), ref.positions(2))
        assert sim.energy().shape == (WORLDS,) and sim.step_count == 5


def test_a_batched_run_records_every_world(tmp_path):
    sim = Simulator(wi.scenes.binary_tree(BODIES).replicate(2).finalize(), 1.0 / 30.0)
    rec = wi.usd.record(sim, tmp_path / "worlds.usda", duration=0.1, fps=30)
    anim = wi.usd.read_animation(rec.path)
    assert anim.positions.shape == (4, 2 * BODIES, 3)
    assert np.allclose(anim.positions[-1], sim.positions().reshape(-1, 3))


@pytest.mark.parametrize("shares", SHARES)
def test_threads_with_split_steps_give_the_batched_run(shares):
    """Worlds whose steps split into substeps, in a two-world share (alone, after the threads), in a one-world
    share (on its thread, with every substep size recorded beforehand) or in fused one-world shares (the fused
    launch hands the step to the parallel schedule)."""
    from warpimpulse.threads import ThreadedSimulator

    settings, steps = SHARES[shares]
    mass, force, spin = worlds_setup()
    spin[0, 6] = spin[2, 6] = (0.0, 0.0, 200.0)
    ref, ref_stats = batched(4, mass, force, spin)
    assert ref_stats[-1].substeps[0] > 1 and ref_stats[-1].substeps[2] > 1
    model = wi.scenes.binary_tree(BODIES).replicate(WORLDS).finalize()
    with ThreadedSimulator(model, DT, threads=2, **wi.StepOptions.fold(settings)) as sim:
        sim.set_masses(mass=mass)
        sim.set_external_forces(force=force)
        sim.set_state(angular_velocities=spin)
        steps(sim, 4)
        for a, b in zip(state_of(ref), state_of(sim)):
            assert np.array_equal(a, b)
        assert np.array_equal(sim.world_stats.substeps, ref_stats[-1].substeps)
        assert np.array_equal(sim.world_stats.joint_iterations, ref_stats[-1].joint_iterations)


def mechanism_scene() -> wi.SceneBuilder:
    """A hinged chain with a PID motor (an integral term), a joint spring and a spring to the world."""
    builder = wi.scenes.chain(4)
    builder.add_motor(0, "velocity", target=1.5, kp=40.0, ki=20.0, max_force=200.0)
    builder.add_joint_spring(2, stiffness=30.0, damping=2.0)
    builder.add_spring(None, 3, (4.0, 0.0, -1.0), (0.5, 0.0, 0.0), stiffness=50.0, damping=1.0)
    return builder


def test_batched_worlds_with_a_motor_and_springs_match_each_world_alone_bit_for_bit():
    """Per-world masses, motor targets and spins; world 0 spins fast enough to take its steps alone as substeps
    (its motor's integral goes with it and comes back)."""
    count, steps = 3, 40
    bodies = len(mechanism_scene().bodies)
    base = mechanism_scene().finalize().host
    mass = np.stack([base.body_mass * (1.0 + 0.3 * w) for w in range(count)])
    spin = np.zeros((count, bodies, 3))
    spin[0, -1] = (0.0, 80.0, 0.0)  # alone in steps 1-5, 14, 25 and 28, in the batch between
    targets = [1.5, -2.0, 0.5]
    sim = Simulator(mechanism_scene().replicate(count).finalize(), DT)
    sim.set_masses(mass=mass)
    sim.set_state(angular_velocities=spin)
    for w, target in enumerate(targets):
        sim.set_motor_target(w, target)
    alone_steps = 0
    for _ in range(steps):
        sim.step()
        alone_steps += int(sim.world_stats.alone[0])
    assert 0 < alone_steps < steps and not sim.stopped
    for w in range(count):
        one = Simulator(mechanism_scene().finalize(), DT)
        one.set_masses(mass=mass[w])
        one.set_state(angular_velocities=spin[w])
        one.set_motor_target(0, targets[w])
        for _ in range(steps):
            one.step()
        for a, b in zip(state_of(one), state_of(sim, w)):
            assert np.array_equal(a, b), f"world {w} differs from its run alone"
        assert one.energy() == sim.energy(w) == sim.energy()[w]  # gravity, the springs' and the joint spring's
        drives = one.model.drive_count  # the motor and the joint spring, world-major
        assert np.array_equal(one.drive_integral.numpy(), sim.drive_integral.numpy()[w * drives : (w + 1) * drives])
        assert one.drive_integral.numpy()[0] != 0.0  # the motor's integral term worked
    assert not np.array_equal(sim.positions(1), sim.positions(2))


def test_a_stopped_world_keeps_its_motor_integral():
    """The batch integrates every world's drives; a world that leaves the step gets its integral back."""
    sim = Simulator(mechanism_scene().replicate(2).finalize(), DT, max_iterations=10)
    force = np.zeros((2, len(mechanism_scene().bodies), 3))
    force[1, -1] = (0.0, 0.0, 1e13)
    sim.step(3)
    before = sim.drive_integral.numpy().copy()
    sim.set_external_forces(force=force)
    with pytest.warns(RuntimeWarning, match="world 1: "):
        sim.step(3)
    assert list(sim.stopped) == [1]
    after = sim.drive_integral.numpy()
    assert np.array_equal(after[2:], before[2:]) and not np.array_equal(after[:2], before[:2])


@pytest.mark.fused
@pytest.mark.parametrize("shares", SHARES)
def test_threads_share_worlds_with_a_motor_and_springs(shares):
    """Shares of worlds with springs and motors (`Model.worlds` takes their rows): the batched run."""
    from warpimpulse.threads import ThreadedSimulator

    settings, steps = SHARES[shares]
    model = mechanism_scene().replicate(3).finalize()
    ref = Simulator(model, DT)
    with ThreadedSimulator(model, DT, threads=2, **wi.StepOptions.fold(settings)) as sim:
        batched_shares = shares == "batched"
        assert [p.model.spring_count for p in sim.parts] == ([2, 1] if batched_shares else [1, 1, 1])
        firsts = [0, 2] if batched_shares else [0, 1, 2]
        assert [p.model.drive_name[0] for p in sim.parts] == [f"world{w}/j0.motor" for w in firsts]
        ref.step(20)
        steps(sim, 20)
        for a, b in zip(state_of(ref), state_of(sim)):
            assert np.array_equal(a, b)


@pytest.mark.fused
def test_a_world_failing_inside_a_fused_launch_stops_at_the_start_of_its_step():
    """A world whose step fails inside one call of 30 steps (a torque spins it up; no halving allowed: step 26
    of 30 as measured), on fused one-world shares: it stops at its state of the start of that step, as in the
    batched run, and the others run all 30 steps, bit for bit."""
    import re

    from warpimpulse.threads import ThreadedSimulator

    settings = {"max_iterations": 10, "max_substep_depth": 0}
    model = wi.scenes.binary_tree(BODIES).replicate(WORLDS).finalize()
    torque = np.zeros((WORLDS, BODIES, 3))
    torque[1, 6] = (0.0, 0.0, 100.0)
    ref = Simulator(model, DT, **wi.StepOptions.fold(settings))
    ref.set_external_forces(torque=torque)
    with pytest.warns(RuntimeWarning, match="world 1: step ") as record:
        ref.step(30)
    failing = int(re.search(r"world 1: step (\d+) ", str(record[0].message)).group(1))
    assert 1 < failing < 30  # inside the launch, not at either end
    with ThreadedSimulator(model, DT, threads=2, **wi.StepOptions.fold(settings)) as sim:
        assert sim.fused_shares
        sim.set_external_forces(torque=torque)
        with pytest.warns(RuntimeWarning, match=f"world 1: step {failing} "):
            stats = sim.step(30)
        assert not stats.converged and sim.step_count == 30 and sim.time == ref.time
        assert sim.stopped == ref.stopped
        for a, b in zip(state_of(ref), state_of(sim)):
            assert np.array_equal(a, b)
        assert not sim.world_stats.converged[1] and sim.world_stats.converged[[0, 2]].all()
        assert np.array_equal(sim.world_stats.joint_iterations, ref.world_stats.joint_iterations)
        sim.step(2)  # the stopped world stays, the others go on
        ref.step(2)
        for a, b in zip(state_of(ref), state_of(sim)):
            assert np.array_equal(a, b)


@pytest.mark.fused
def test_threads_simulate_on_fused_shares_gives_the_batched_run_step_by_step():
    """`simulate` over more steps than a fused launch takes (256): the batched run's states and per-step stats."""
    from warpimpulse.threads import ThreadedSimulator

    mass, force, spin = worlds_setup()
    model = wi.scenes.binary_tree(BODIES).replicate(WORLDS).finalize()
    ref = Simulator(model, DT)
    with ThreadedSimulator(model, DT, threads=2) as sim:
        for s in (ref, sim):
            s.set_masses(mass=mass)
            s.set_external_forces(force=force)
            s.set_state(angular_velocities=spin)
        expected, got = ref.simulate(300 * DT), sim.simulate(300 * DT)
        assert sim.fused_shares and len(got) == 300 and sim.step_count == 300
        assert [s.joint_iterations for s in got] == [s.joint_iterations for s in expected]
        assert [s.max_joint_error for s in got] == [s.max_joint_error for s in expected]
        for a, b in zip(state_of(ref), state_of(sim)):
            assert np.array_equal(a, b)
