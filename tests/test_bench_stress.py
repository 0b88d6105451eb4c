"""The stress suite's machinery on very small cases, and the simulator's failure handling: checkpoint and
resume bit-identical for every solver, NaN/Inf detection naming the step and the bodies, the raise/warn
policy at the iteration limit."""

from __future__ import annotations

import dataclasses
import json
import warnings

import numpy as np
import pytest

import warpimpulse as wi
from warpimpulse import scenes
from warpimpulse.bench import stress


def _case(name: str, **changes) -> stress.Case:
    case = next(c for c in stress.cases(quick=True) if c.name == name)
    return dataclasses.replace(case, **changes)


# ------------------------------------------------------------------------------------------------ the suite
def test_every_case_group_is_in_both_modes():
    for quick in (True, False):
        groups = {c.group for c in stress.cases(quick)}
        assert groups == {"mass ratio", "size", "high spin", "large steps", "long run", "near-singular", "redundant"}
        names = {c.name for c in stress.cases(quick)}
        assert {"mass_ratio_1e6_tip", "mass_ratio_1e6_root", "chain_1000", "star_1023", "tree_16383",
                "long_run_tree31", "hinge_through_com", "redundant_fixed_hinge_cholesky"} <= names  # fmt: skip
    full = {c.name: c for c in stress.cases(False)}
    assert full["long_run_tree31"].steps == 100_000
    assert {c.dt for c in full.values() if c.group == "large steps"} == {0.1, 0.2}


def test_a_case_that_holds_passes():
    res = stress.run_case(_case("hinge_through_com", steps=20))
    assert res.status == "PASS", res.reasons
    assert res.outcome == "held" and res.steps_done == 20
    assert res.max_joint_error <= 1e-6 and res.final_joint_error <= 1e-6
    assert res.energy_drift is not None and res.iterations_mean >= 1.0


def test_heavy_root_mass_ratio_holds():
    res = stress.run_case(_case("mass_ratio_1e6_root", steps=30))
    assert res.status == "PASS", (res.reasons, res.error)


def test_redundant_constraints_hold_with_cholesky():
    """The loop joint's redundant rows are regularised (tests/test_loops.py counts them), so the pair holds."""
    res = stress.run_case(_case("redundant_fixed_hinge_cholesky"))
    assert res.status == "PASS" and res.outcome == "held", (res.reasons, res.error)


def test_the_builder_refuses_parallel_universal_axes():
    res = stress.run_case(_case("universal_axes_1e-06_rad"))
    assert res.status == "PASS" and "SceneError" in res.error and "'universal'" in res.error


def test_a_hold_case_that_stops_fails_and_an_unclear_error_fails():
    # A time step far too large with one iteration allowed: a clear stop, but the case demands holding.
    res = stress.run_case(_case("hinge_through_com", dt=0.5, max_iterations=1, steps=5))
    assert res.status == "FAIL" and res.outcome == "stopped"
    builder = scenes.chain(2)
    clear, _ = stress.clear_error(wi.SimulationError("step 3: did not reach 1e-6 in 5 iterations; 'j1'"), builder)
    assert clear
    clear, why = stress.clear_error(wi.SimulationError("did not converge"), builder)
    assert not clear and "step" in why and "joints" in why
    assert not stress.clear_error(RuntimeError("boom"), builder)[0]


def test_main_exit_status_and_json(tmp_path, monkeypatch, capsys):
    out = tmp_path / "stress.json"
    assert stress.main(["--quick", "--case", "redundant_fixed_hinge_cholesky", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["mode"] == "quick" and doc["failed"] == 0 and doc["cases"][0]["status"] == "PASS"
    printed = capsys.readouterr().out
    assert "redundant_fixed_hinge_cholesky" in printed and "PASS" in printed

    # A case expecting an error from a scene that holds: FAIL, exit status 1.
    bad = stress.Case("holds_but_error_expected", "redundant", lambda: scenes.chain(2), dt=0.01, steps=3,
                      expect="error", expected_errors=("SingularSystemError",))  # fmt: skip
    monkeypatch.setattr(stress, "cases", lambda quick: [bad])
    assert stress.main(["--quick", "--json", str(out)]) == 1
    assert json.loads(out.read_text())["cases"][0]["status"] == "FAIL"
    assert stress.main(["--quick", "--case", "no-such-case"]) == 2


def test_table_rows_line_up_with_the_header():
    res = stress.Result("case", "group", status="PASS", outcome="held", bodies=3, steps_planned=2, steps_done=2,
                        max_joint_error=1e-7, energy_drift=0.01, iterations_mean=2.0, iterations_max=3,
                        ms_per_step=0.5, setup_s=0.1, run_s=0.2)  # fmt: skip
    row = stress.table_row(res)
    for label, value in (("max joint", "1.00e-07"), ("E drift", "+1.00e-02"), ("it/step", "2.00/3"),
                         ("ms/step", "0.50"), ("setup s", "0.10"), ("total s", "0.30")):  # fmt: skip
        assert stress.HEADER.index(label) + len(label) == row.index(value) + len(value), (label, row)


def test_isolated_case_runs_in_a_child():
    res = stress.run_isolated(_case("universal_axes_1e-06_rad", budget_s=120.0), quick=True)
    assert res.status == "PASS" and "SceneError" in res.error  # the child's error comes back


# ------------------------------------------------------------------------------------------------ checkpoints
@pytest.mark.parametrize("solver", ["cholesky", "cg", "iterative"])
def test_checkpoint_resume_is_bit_identical(tmp_path, solver):
    """Save mid-run (while the start torque still acts), resume in a fresh simulator, compare bit for bit."""

    def make():
        return wi.Simulator(scenes.binary_tree(15).finalize(), 1 / 30, solver=solver, tolerance=1e-8)

    straight = make()
    for _ in range(24):
        straight.step()
    first = make()
    for _ in range(12):
        first.step()
    path = tmp_path / "ck.npz"
    first.save_checkpoint(path)
    resumed = make()
    resumed.load_checkpoint(path)
    assert resumed.step_count == 12 and resumed.time == first.time
    stats = [resumed.step() for _ in range(12)]
    for name in ("x", "q", "v", "w"):
        a, b = getattr(straight.state, f"body_{name}").numpy(), getattr(resumed.state, f"body_{name}").numpy()
        assert np.array_equal(a, b), f"{solver}: {name} differs by {np.abs(a - b).max():.3g} after resume"
    assert resumed.time == straight.time and all(s.converged for s in stats)


def test_checkpoint_refuses_another_scene(tmp_path):
    sim = wi.Simulator(scenes.binary_tree(15).finalize(), 1 / 30)
    sim.save_checkpoint(tmp_path / "ck.npz")
    other = wi.Simulator(scenes.binary_tree(7).finalize(), 1 / 30)
    with pytest.raises(ValueError, match="15 bodies"):
        other.load_checkpoint(tmp_path / "ck.npz")


# ------------------------------------------------------------------------------------------------ NaN / Inf
@pytest.mark.parametrize("solver", ["cholesky", "cg", "iterative"])
@pytest.mark.parametrize("field,body,value", [("v", 5, np.nan), ("w", 7, np.inf), ("x", 3, np.nan), ("q", 9, np.nan)])
def test_nan_in_the_state_stops_naming_the_body(solver, field, body, value):
    builder = scenes.binary_tree(15)
    sim = wi.Simulator(builder.finalize(), 1 / 60, solver=solver)
    for _ in range(3):
        sim.step()
    arr = getattr(sim.state, f"body_{field}").numpy()
    arr[body, 0] = value
    getattr(sim.state, f"body_{field}").assign(arr)
    with pytest.raises(wi.SimulationError, match=r"step \d+") as info:
        sim.step()
    msg = str(info.value)
    assert "NaN or Inf" in msg and repr(builder.bodies[body].name) in msg


def test_nan_message_names_the_step_being_computed():
    sim = wi.Simulator(scenes.binary_tree(15).finalize(), 1 / 60)
    for _ in range(3):
        sim.step()
    v = sim.state.body_v.numpy()
    v[5, 0] = np.nan
    sim.state.body_v.assign(v)
    with pytest.raises(wi.SimulationError, match=r"^step 4\b"):
        sim.step()


def test_external_forces_refuse_nan():
    sim = wi.Simulator(scenes.chain(2).finalize(), 1 / 60)
    with pytest.raises(ValueError, match="NaN"):
        sim.set_external_forces(force=np.full((2, 3), np.nan))


# ------------------------------------------------------------------------------------------------ policy
@pytest.mark.parametrize("solver", ["cholesky", "cg", "iterative"])
def test_iteration_limit_raise_names_step_iterations_and_joints(solver):
    sim = wi.Simulator(
        scenes.binary_tree(31).finalize(),
        1 / 10,
        solver=solver,
        max_iterations=1,
        options=wi.StepOptions(max_substep_depth=0),
    )
    with pytest.raises(wi.SimulationError) as info:
        sim.step()
    msg = str(info.value)
    assert msg.startswith("step 1 ") and "in 1 iterations" in msg
    assert "worst joints: 'j" in msg


def test_failing_step_is_redone_as_substeps():
    """A chain whipping at h = 1/30 fails its joint correction at full steps; halving rescues it."""
    sim = wi.Simulator(scenes.chain(50).finalize(), 1 / 30, options=wi.StepOptions(max_substep_depth=0))
    with pytest.raises(wi.SimulationError, match="correction"):
        sim.simulate(2.0)
    sim = wi.Simulator(scenes.chain(50).finalize(), 1 / 30)
    stats = sim.simulate(2.0)
    assert max(s.substeps for s in stats) > 1
    assert all(s.converged for s in stats)
    assert sim.joint_errors().max() <= 1e-6


def _spinning_pendulum(omega: float) -> wi.SceneBuilder:
    """A rod hanging on a world ball joint, spinning about its own (vertical) axis at omega rad/s."""
    builder = wi.SceneBuilder()
    body, _ = stress.capsule(builder, np.zeros(3), [0.0, 0.0, -1.0], 1.0, "rod")
    builder.bodies[body].angular_velocity[:] = (0.0, 0.0, omega)
    builder.add_joint_ball(None, body, np.zeros(3), name="hang")
    return builder


@pytest.mark.parametrize("solver", ["cholesky", "iterative"])
def test_a_fast_spin_splits_the_step(solver):
    """100 rad/s at h = 1/60 turns 1.67 rad a step: 4 substeps of 0.42 rad at the default max_rotation 0.5."""
    model = _spinning_pendulum(100.0).finalize()
    assert wi.Simulator(model, 1 / 60, solver=solver).step().substeps == 4
    assert wi.Simulator(model, 1 / 60, solver=solver, options=wi.StepOptions(max_rotation=None)).step().substeps == 1
    assert wi.Simulator(model, 1 / 60, solver=solver, options=wi.StepOptions(max_rotation=2.0)).step().substeps == 1
    assert (
        wi.Simulator(model, 1 / 60, solver=solver, options=wi.StepOptions(max_rotation=0.5, max_substep_depth=1))
        .step()
        .substeps
        == 2
    )


@pytest.mark.parametrize("bad", [0.0, -0.5, float("nan"), float("inf")])
def test_max_rotation_is_validated(bad):
    with pytest.raises(ValueError, match="max_rotation"):
        wi.Simulator(scenes.chain(2).finalize(), 1 / 60, options=wi.StepOptions(max_rotation=bad))


def _energy_gain(sim: wi.Simulator, steps: int) -> float:
    """The largest energy gain over the run, as a fraction of the largest kinetic energy seen (the stress
    suite's energy scale)."""
    e0, gain, scale = sim.energy(), 0.0, 0.0
    for _ in range(steps):
        sim.step()
        scale = max(scale, stress.kinetic_energy(sim))
        gain = max(gain, sim.energy() - e0)
    return gain / scale


def test_a_whipping_chain_is_split_where_it_spins_up():
    """A heavy root (1:1e6) whips its light chain to ~80 rad/s: whole steps of 1/100 gain energy, then fail;
    the steps the whip turns too far in are halved and the energy holds."""
    model = stress.mass_ratio_chain(1e6, "root").finalize()
    sim = wi.Simulator(
        model, 1 / 100, on_max_iterations="warn", options=wi.StepOptions(max_rotation=None, max_substep_depth=0)
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        whole = _energy_gain(sim, 300)
    assert not whole <= 0.05  # NaN (diverged) counts as a gain
    sim = wi.Simulator(model, 1 / 100)
    assert _energy_gain(sim, 300) < 0.01
    assert sim.joint_errors().max() <= 1e-6


@pytest.mark.parametrize("solver", ["cholesky", "cg", "iterative"])
def test_iteration_limit_warn_goes_on_and_records_it(solver):
    sim = wi.Simulator(
        scenes.binary_tree(31).finalize(),
        1 / 10,
        solver=solver,
        max_iterations=1,
        on_max_iterations="warn",
        options=wi.StepOptions(max_substep_depth=0),
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        stats = [sim.step() for _ in range(3)]
    assert sim.step_count == 3
    assert not stats[0].converged and stats[0].max_joint_error > sim.tolerance
    assert any("did not reach" in str(w.message) and w.category is RuntimeWarning for w in caught)
    assert all(np.all(np.isfinite(getattr(sim.state, f"body_{n}").numpy())) for n in "xqvw")
