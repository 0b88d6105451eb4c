"""Issue 31's probes of what was added since the first round of faults (checkpoints with force elements, orders
that fall back, setters after build, sweeps, degenerate loops, runaway loads, huge counts): each is one clear
line naming the culprit (exit 2 on the command line) or correct behaviour, and a refused load changes nothing."""

from __future__ import annotations

import re

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run
from pxr import Sdf

import warpimpulse as wi
from warpimpulse import scenes
from warpimpulse.simulator import ROWS_FALLBACK, CheckpointError, SimulationError, Simulator
from warpimpulse.solver import SingularSystemError

DT = 0.01


# ------------------------------------------------------------------------------------------------ checkpoints
def _pendulum(motors: int = 0, spring: bool = False, limit: bool = False, ground: bool = False,
              kp: float = 5.0) -> wi.SceneBuilder:  # fmt: skip
    """Two hinged links; `motors` PID motors (gain `kp`) on the hinges, a spring between the links, a limit, a
    ground."""
    b = wi.SceneBuilder()
    shape = wi.Shape("sphere", radius=0.1, collide=ground)
    a = b.add_body(1.0, (0.1, 0.1, 0.1), (0.0, 0.0, -1.0), name="a", shape=shape)
    c = b.add_body(1.0, (0.1, 0.1, 0.1), (0.0, 0.0, -2.0), name="c", shape=shape)
    hinges = [b.add_joint_revolute(None, a, (0, 0, 0), (1, 0, 0), name="j0"),
              b.add_joint_revolute(a, c, (0, 0, -1), (1, 0, 0), name="j1")]  # fmt: skip
    for j in hinges[:motors]:
        b.add_motor(j, target=0.3, kp=kp)
    if spring:
        b.add_spring(a, c, (0, 0, -1), (0, 0, -2), stiffness=10.0)
    if limit:
        b.add_joint_limit(hinges[1], -0.5, 0.5)
    if ground:
        b.add_ground(height=-5.0)
    return b


def _everything(sim: Simulator) -> list[np.ndarray]:
    """The state, the clock and the motors' targets and integrals, to compare bit for bit."""
    arrays = [getattr(sim.state, f"body_{n}").numpy().copy() for n in ("x", "q", "v", "w")]
    return [*arrays, np.array([sim.time, sim.step_count]), sim.drive_target.numpy().copy(),
            sim.drive_integral.numpy().copy()]  # fmt: skip


CHECKPOINT_MISMATCHES = {
    "two motors into one": (_pendulum(2), _pendulum(1), {},
                            r"motors and joint springs differ .*\(2 in the checkpoint, 1 here\)"),
    "one motor into two": (_pendulum(1), _pendulum(2), {},
                           r"motors and joint springs differ .*\(1 in the checkpoint, 2 here\)"),
    "other gains": (_pendulum(1), _pendulum(1, kp=6.0), {},
                    r"motors and joint springs differ .*\(1, with other values\)"),
    "a spring": (_pendulum(1, spring=True), _pendulum(1), {}, r"springs differ .*\(1 in the checkpoint, 0 here\)"),
    "a limit": (_pendulum(1), _pendulum(1, limit=True), {}, r"joint limits, distance rows and stiff motors differ"),
    "colliders": (_pendulum(ground=True), _pendulum(), {}, r"colliders and grounds differ"),
    "contact margin": (_pendulum(ground=True), _pendulum(ground=True), {"contact_margin": 0.01},
                       r"contact settings differ"),
}  # fmt: skip


@pytest.mark.parametrize("case", CHECKPOINT_MISMATCHES)
def test_a_checkpoint_of_other_force_elements_is_refused_and_changes_nothing(tmp_path, case):
    saved_scene, scene, settings, match = CHECKPOINT_MISMATCHES[case]
    path = tmp_path / "ck.npz"
    saver = Simulator(saved_scene.finalize(), DT)
    saver.step(3)
    saver.save_checkpoint(path)
    sim = Simulator(scene.finalize(), DT, **settings)
    sim.step(2)
    if sim.model.drive_count:
        sim.set_motor_target(0, 0.7)
    before = _everything(sim)
    with pytest.raises(CheckpointError, match=rf"^{re.escape(str(path))}: checkpoint of another scene: .*{match}"):
        sim.load_checkpoint(path)
    assert all(np.array_equal(a, b) for a, b in zip(before, _everything(sim)))


@pytest.mark.parametrize("key", ["drive_target", "drive_integral", "carry", "fallback"])
def test_a_checkpoint_with_text_for_numbers_is_refused_and_changes_nothing(tmp_path, key):
    """Every array is checked for its type before numpy would choke on it (np.isfinite of strings is a TypeError)."""
    path = tmp_path / "ck.npz"
    sim = Simulator(_pendulum(2).finalize(), DT)
    sim.step(2)
    sim.save_checkpoint(path)
    with np.load(path) as npz:
        data = {k: npz[k] for k in npz.files}
    data[key] = np.full(data[key].shape, 1.0) if key == "fallback" else np.full(data[key].shape, "x")
    np.savez(path, **data)
    sim.step()
    before = _everything(sim)
    with pytest.raises(CheckpointError, match=rf"^{re.escape(str(path))}: '{key}' (is not|has shape)"):
        sim.load_checkpoint(path)
    assert all(np.array_equal(a, b) for a, b in zip(before, _everything(sim)))


def test_a_checkpoint_of_the_same_force_elements_resumes_bit_for_bit(tmp_path):
    path = tmp_path / "ck.npz"
    first = Simulator(_pendulum(2, spring=True, limit=True).finalize(), DT)
    first.step(2)
    first.set_motor_target(1, -0.4)
    first.save_checkpoint(path)
    first.step(3)
    second = Simulator(_pendulum(2, spring=True, limit=True).finalize(), DT)
    second.load_checkpoint(path)
    second.step(3)
    assert all(np.array_equal(a, b) for a, b in zip(_everything(first), _everything(second)))


# ------------------------------------------------------------------------------------------------ fallbacks
def test_a_fallback_is_recorded_and_said_once_with_verbose(capsys):
    sim = Simulator(_pendulum(1, limit=True).finalize(), DT, order=4, verbose=True)
    for _ in range(3):
        assert sim.step().fallback == ROWS_FALLBACK
    said = [line for line in capsys.readouterr().err.splitlines() if "order 4 was asked" in line]
    assert said == [f"warpimpulse: order 4 was asked, but steps from t = 0 s on were taken at order 2 because of "
                    f"{ROWS_FALLBACK}"], said  # fmt: skip
    assert list(sim.fallbacks) == [ROWS_FALLBACK]
    sim.reset()
    assert sim.fallbacks == {}


def test_the_command_line_says_a_fallback_once_and_records_it(tmp_path, capsys):
    """The four-bar's crank is a stiff motor, a row of the correction loop: --order 4 runs at order 2."""
    out = tmp_path / "o.usda"
    code, lines = run(["simulate", "--scene", "four_bar", "--order", "4", "--duration", "0.2", "--fps", "30",
                       "--out", str(out)], capsys)  # fmt: skip
    assert code == 0, lines
    said = [line for line in lines if "order 4 was asked" in line]
    assert len(said) == 1 and ROWS_FALLBACK in said[0], lines
    data = dict(Sdf.Layer.FindOrOpen(str(out)).customLayerData)
    assert list(data["warpimpulse:fallbacks"]) == [said[0].removeprefix("warpimpulse: ")]
    assert data["warpimpulse:schedule"] in ("fused", "parallel")


# ------------------------------------------------------------------------------------------------ setters
SETTER_MISTAKES = {
    "triangle inequality": (lambda s: s.set_masses(inertia=[(1, 1, 10), (1, 1, 1)]),
                            r"set_masses: body 'a': principal moments \[1.0, 1.0, 10.0\] break the triangle "
                            r"inequality"),
    "zero mass": (lambda s: s.set_masses(mass=[1.0, 0.0]), r"set_masses: body 'c': mass must be positive and finite"),
    "asymmetric inertia": (lambda s: s.set_masses(inertia=[np.eye(3), [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]]),
                           r"set_masses: body 'c': inertia tensor is not symmetric"),
    "NaN force": (lambda s: s.set_external_forces(force=[[0, 0, 0], [np.nan, 0, 0]]),
                  r"body 'c': force contains NaN or Inf"),
    "huge torque": (lambda s: s.set_external_forces(torque=[[1e200, 0, 0], [0, 0, 0]]),
                    r"body 'a': torque is too large for double precision"),
    "Inf velocity": (lambda s: s.set_state(linear_velocities=[[0, 0, 0], [0, np.inf, 0]]),
                     r"body 'c': linear_velocities contains NaN or Inf"),
    "NaN motor target": (lambda s: s.set_motor_target(0, np.nan), r"motor 0 \('j0.motor'\): target must be finite"),
}  # fmt: skip


@pytest.mark.parametrize("case", SETTER_MISTAKES)
def test_setters_after_build_run_the_builders_checks_and_name_the_body(case):
    change, match = SETTER_MISTAKES[case]
    sim = Simulator(_pendulum(1).finalize(), DT)
    before = _everything(sim) + [sim.model.host.body_mass.copy(), sim.model.host.body_inertia.copy()]
    with pytest.raises(ValueError, match=match):
        change(sim)
    after = _everything(sim) + [sim.model.host.body_mass, sim.model.host.body_inertia]
    assert all(np.array_equal(a, b) for a, b in zip(before, after))


# ------------------------------------------------------------------------------------------------ sweeps
SWEEP_FILES = {
    "empty": ("[params]\ndt = []\n", r"empty.toml: params.dt = \[\]: no value to sweep"),
    "reversed range": ("[random]\nsamples = 4\n[random.ranges]\ndt = [0.02, 0.001]\n",
                       r"reversed range.toml: random.ranges.dt = \[0.02, 0.001\]: low is above high"),
    "no samples": ("[random]\nsamples = 0\n[random.ranges]\ndt = [0.001, 0.02]\n",
                   r"no samples.toml: random.samples must be an integer >= 1, got 0"),
    "huge": ("[random]\nsamples = 2000000000\n[random.ranges]\ndt = [0.001, 0.02]\n",
             r"huge.toml: the sweep: 2,000,000,000 points would take about 8 TB of memory \(4 kB a point\), more than "
             r"this machine has free"),
    "nothing": ("[random]\nseed = 3\n",
                r"nothing.toml: nothing to sweep: no \[params\] values and no \[random.ranges\]"),
}  # fmt: skip


@pytest.mark.parametrize("case", SWEEP_FILES)
def test_a_bad_sweep_file_is_one_line_naming_the_file_and_the_parameter(tmp_path, capsys, case):
    text, match = SWEEP_FILES[case]
    config = tmp_path / f"{case}.toml"
    config.write_text(text)
    code, lines = run(["sweep", str(config), "--out", str(tmp_path / "out"), "--backend", "pool"], capsys)
    assert code == 2 and len(lines) == 1 and re.search(match, lines[0]), lines
    assert not (tmp_path / "out" / "sweep.csv").exists()


def test_a_failing_sweep_point_says_why_on_the_console(tmp_path, capsys, monkeypatch):
    """A scene with contacts does not replicate into batched worlds: the reason, not only a count. The chunks run
    in this process (the pool's spawned workers would take seconds to start); a chunk that raises becomes its
    points' error rows, as on the pool."""
    from warpimpulse import sweep

    def here(chunks, workers):
        for chunk in chunks:
            try:
                yield sweep.run_chunk(chunk)
            except Exception as exc:
                yield sweep.error_rows(chunk, exc)

    monkeypatch.setattr(sweep, "on_pool", here)
    argv = ["sweep", "--param", "scene=box_stack", "--param", "duration=0.05", "--out", str(tmp_path), "--backend",
            "pool", "--workers", "1", "--no-plot"]  # fmt: skip
    code, lines = run(argv, capsys)
    assert code == 1
    assert any(line.startswith("warpimpulse: error in 1 point (0): SceneError: replicate: the scene has colliding "
                               "shapes") for line in lines), lines  # fmt: skip


# ------------------------------------------------------------------------------------------------ sizes
def test_a_huge_replicate_names_the_count_and_its_memory():
    with pytest.raises(wi.SceneError, match=r"replicate: 1,000,000,000 worlds would take about .*B of memory \(.* a "
                                            r"world\), more than this machine has free"):  # fmt: skip
        scenes.binary_tree(31).replicate(10**9)


def test_a_usd_sphere_collider_of_radius_zero_is_named(tmp_path, capsys):
    path = tmp_path / "ball.usda"
    path.write_text("""#usda 1.0
(
    upAxis = "Z"
    metersPerUnit = 1
)
def Xform "World"
{
    def Sphere "Ball" (
        prepend apiSchemas = ["PhysicsRigidBodyAPI", "PhysicsCollisionAPI"]
    )
    {
        double radius = 0
        double3 xformOp:translate = (0, 0, 1)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
}
""")
    assert_one_line_error(["simulate", str(path), "--out", str(tmp_path / "o.usdc")],
                          "/World/Ball: the Sphere collider has zero size (radius 0", capsys)  # fmt: skip


# ------------------------------------------------------------------------------------------------ failures named
def test_a_degenerate_loop_is_named_when_the_simulator_is_built():
    """Three ball joints in line close a loop whose middle joint may move sideways to first order only."""
    b = wi.SceneBuilder()
    a = b.add_body(1.0, (0.1, 0.1, 0.1), (0.5, 0, 0), name="a")
    c = b.add_body(1.0, (0.1, 0.1, 0.1), (1.5, 0, 0), name="c")
    b.add_joint_ball(None, a, (0, 0, 0), name="j0")
    b.add_joint_ball(a, c, (1, 0, 0), name="j1")
    b.add_joint_ball(None, c, (2, 0, 0), name="j2")
    model = b.finalize()
    for tolerance in (1e-6, 1e-3):
        with pytest.raises(SingularSystemError, match=r"joints 'j0', 'j1', 'j2' form a degenerate loop"):
            Simulator(model, DT, tolerance=tolerance)


def test_a_runaway_force_is_named_as_such():
    b = scenes.chain(3)
    b.add_force(2, (1e30, 0.0, 0.0))
    sim = Simulator(b.finalize(), DT, on_max_iterations="warn")
    runaway = r"a runaway force: 1e\+30 N on body 'link2' \(7.59 kg\) would move it 6.59e\+24 m in one step of 0.01 s"
    singular = rf"^the system matrix is singular at joint 'j2' \(revolute, constraint 4\): {runaway}$"
    with pytest.warns(RuntimeWarning, match=runaway), pytest.raises(SingularSystemError, match=singular):
        sim.step()


def test_the_command_line_prints_a_warning_as_one_line(tmp_path, capsys):
    """--on-max-iterations warn: each warning is one line, without the library's source line."""
    argv = ["simulate", "--scene", "chain", "--tolerance", "1e-12", "--max-iterations", "1", "--on-max-iterations",
            "warn", "--duration", "0.1", "--fps", "30", "--out", str(tmp_path / "o.usdc")]  # fmt: skip
    code, lines = run(argv, capsys)
    assert code == 0
    warned = [line for line in lines if "warning" in line]
    assert warned and all(line.startswith("warpimpulse: warning: step ") for line in warned), lines
    assert not any("simulator.py" in line or line.startswith(" ") for line in lines), lines


def test_the_iterative_velocity_correction_says_its_sweeps():
    sim = Simulator(scenes.chain(10).finalize(), DT, solver="iterative", max_iterations=20)
    with pytest.raises(SimulationError, match=r"the velocity correction left [\d.e+-]+ after 20 sweeps, over its "
                                              r"tolerance of 1e-06; worst joints: 'j0'"):  # fmt: skip
        sim.step(5)


def test_a_runaway_force_on_the_command_line_is_named_in_one_line_each(tmp_path, capsys):
    """A scene file with a 1e30 N force under --on-max-iterations warn: one line a warning, each naming the
    runaway force, then the stop naming it where the pivot is lost (exit 1, the frames done kept)."""
    from warpimpulse import usd

    b = scenes.chain(3)
    b.add_force(2, (1e30, 0.0, 0.0))
    path = tmp_path / "runaway.usda"
    usd.save_scene(b, path, fps=30)
    argv = ["simulate", str(path), "--on-max-iterations", "warn", "--duration", "0.1", "--fps", "30", "--out",
            str(tmp_path / "o.usdc")]  # fmt: skip
    code, lines = run(argv, capsys)
    assert code == 1 and all(line.startswith("warpimpulse: ") for line in lines), lines
    runaway = "a runaway force: 1e+30 N on body '/World/link2' (7.59 kg)"
    warned = [line for line in lines if line.startswith("warpimpulse: warning: step 1 ")]
    assert warned and all(runaway in line for line in warned), lines
    assert any(
        line.startswith(
            "warpimpulse: stopped at t = 0 s: the system matrix is singular at joint "
            f"'/World/Joints/j2' (revolute, constraint 4): {runaway}"
        )
        for line in lines
    ), lines
