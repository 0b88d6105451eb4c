"""Issue 14, the API side: wrong argument types, checkpoints, divergence reports, mass ratios, devices.

Every user mistake gets one SceneError / ValueError naming the argument or body at fault; a failed checkpoint
load leaves the simulator untouched; no failure message is vague or false.
"""

from __future__ import annotations

import re
import zipfile

import numpy as np
import pytest
import warp as wp

import warpimpulse as wi
from warpimpulse import scenes
from warpimpulse.builder import SceneBuilder, SceneError
from warpimpulse.simulator import CheckpointError, SimulationError, Simulator
from warpimpulse.solver import SingularSystemError


def _one_body() -> SceneBuilder:
    b = SceneBuilder()
    b.add_body(1.0, (1.0, 1.0, 1.0), (0.0, 0.0, 0.0), name="box")
    return b


# ------------------------------------------------------------------------------------------- argument types
BUILDER_MISTAKES = [
    ("inertia string", lambda b: b.add_body(1.0, "abc", (0, 0, 0), name="a"), r"body 'a': inertia .*string"),
    ("inertia numeric string", lambda b: b.add_body(1.0, "1", (0, 0, 0), name="a"), r"'a': inertia .*string"),
    ("inertia None", lambda b: b.add_body(1.0, None, (0, 0, 0), name="a"), r"'a': inertia must be a number, got None"),
    ("inertia ragged", lambda b: b.add_body(1.0, [[1, 0, 0], [0, 1]], 0, name="a"), r"'a': inertia .*ragged"),
    ("position string", lambda b: b.add_body(1.0, (1, 1, 1), "abc", name="a"), r"body 'a' position .*string"),
    ("position ragged", lambda b: b.add_body(1.0, (1, 1, 1), [[1, 2], [3]], name="a"), r"'a' position .*ragged"),
    ("position None", lambda b: b.add_body(1.0, (1, 1, 1), None, name="a"), r"'a' position must be a number, got None"),
    ("position boolean", lambda b: b.add_body(1.0, (1, 1, 1), True, name="a"), r"'a' position .*boolean"),
    ("position huge", lambda b: b.add_body(1.0, (1, 1, 1), (1e200, 0, 0), name="a"), r"'a' position is too large"),
    (
        "velocity objects",
        lambda b: b.add_body(1.0, (1, 1, 1), 0, linear_velocity=[1, None, 2], name="a"),
        r"'a' linear",
    ),
    ("mass True", lambda b: b.add_body(True, (1, 1, 1), 0, name="a"), r"'a': mass .*boolean"),
    ("mass string", lambda b: b.add_body("2", (1, 1, 1), 0, name="a"), r"'a': mass .*string"),
    ("mass None", lambda b: b.add_body(None, (1, 1, 1), 0, name="a"), r"'a': mass must be a number, got None"),
    ("mass list", lambda b: b.add_body([1, 2], (1, 1, 1), 0, name="a"), r"'a': mass must be a single number"),
    ("name not a string", lambda b: b.add_body(1.0, (1, 1, 1), 0, name=5), r"body 1 name"),
    ("shape not a Shape", lambda b: b.add_body(1.0, (1, 1, 1), 0, name="a", shape="box"), r"'a': shape"),
    ("body index float", lambda b: b.add_joint_ball(None, 0.0, 0, name="j"), r"joint 'j' child: .*0\.0"),
    ("body index True", lambda b: b.add_joint_ball(None, True, 0, name="j"), r"joint 'j' child"),
    ("anchor string", lambda b: b.add_joint_ball(None, 0, "x", name="j"), r"joint 'j' anchor .*string"),
    (
        "axis None",
        lambda b: b.add_joint_revolute(None, 0, 0, None, name="j"),
        r"joint 'j' axis must be a number, got None",
    ),
    ("joint type list", lambda b: b.add_joint(["ball"], None, 0, 0, name="j"), r"joint 'j': unknown joint type"),
    ("until string", lambda b: b.add_force("box", (1, 0, 0), until="3"), r"force on body 'box': until .*string"),
    ("force ragged", lambda b: b.add_force("box", [[1], [2, 3]]), r"force on body 'box': force .*ragged"),
]


@pytest.mark.parametrize("case,call,match", BUILDER_MISTAKES, ids=[c[0] for c in BUILDER_MISTAKES])
def test_builder_names_the_argument_of_a_wrong_type(case, call, match):
    b = _one_body()
    with pytest.raises(SceneError, match=match):
        call(b)
    assert len(b.bodies) == 1 and not b.joints and not b.forces  # nothing half-added


def test_gravity_of_a_wrong_type():
    with pytest.raises(SceneError, match="gravity must be a number, got None"):
        SceneBuilder(gravity=None)
    with pytest.raises(SceneError, match="gravity must be numeric"):
        SceneBuilder(gravity="down")


@pytest.mark.parametrize(
    "field,value,match",
    [
        ("linear_velocity", "fast", r"body 'box' linear_velocity .*string"),
        ("position", [0, 0], r"body 'box' position must have 3 components"),
        ("orientation", [0, 0, np.nan, 1], r"body 'box' orientation contains NaN"),
        ("inertia", np.ones(3), r"body 'box' inertia must be a finite 3x3"),
        ("mass", True, r"body 'box': mass must be numeric, got the boolean True"),
        ("angular_velocity", [1e300, 0, 0], r"body 'box' angular_velocity is too large"),
    ],
)
def test_a_body_field_set_after_add_is_checked(field, value, match):
    """Scenes may set body fields after add_body: a value of the wrong type, shape or a non-finite one is
    refused as it is set (the builder keeps bodies in typed columns), naming the body; values written in place
    are checked by finalize (test_builder.test_finalize_rechecks_values_changed_after_adding)."""
    b = _one_body()
    with pytest.raises(SceneError, match=match):
        setattr(b.bodies[0], field, value)


SIMULATOR_MISTAKES = [
    ({"tolerance": "1e-6"}, r"tolerance must be numeric, got the string '1e-6'"),
    ({"order": 4.0}, r"order must be an integer"),  # (tolerance=None is the order's default tolerance)
    ({"order": 3}, r"order must be one of"),
    ({"velocity_tolerance": -1.0}, r"velocity_tolerance must be positive"),
    ({"dt": True}, r"dt must be numeric, got the boolean True"),
    ({"dt": "0.01"}, r"dt must be numeric"),
    ({"dt": 0.0}, r"dt must be positive"),
    ({"max_rotation": "1"}, r"max_rotation must be numeric"),
    ({"max_iterations": 10.0}, r"max_iterations must be an integer"),
    ({"max_iterations": True}, r"max_iterations must be an integer"),
    ({"max_substep_depth": -1}, r"max_substep_depth must be an integer >= 0"),
    ({"solver": ["cg"]}, r"unknown solver"),
    ({"formulation": 3}, r"unknown formulation"),
    ({"on_max_iterations": None}, r"on_max_iterations must be one of"),
]


@pytest.mark.parametrize("kwargs,match", SIMULATOR_MISTAKES, ids=[next(iter(k)) for k, _ in SIMULATOR_MISTAKES])
def test_simulator_names_the_argument_of_a_wrong_type(kwargs, match):
    model = _one_body().finalize()
    kwargs = {"dt": 0.01, **kwargs}
    with pytest.raises(ValueError, match=match):
        Simulator(model, **wi.StepOptions.fold(kwargs))


def test_simulator_refuses_a_builder_for_a_model():
    with pytest.raises(TypeError, match="model must be a Model"):
        Simulator(_one_body(), 0.01)


@pytest.mark.parametrize("value,match", [([[1, 2], [3]], "ragged"), ("x", "string"), (np.ones((2, 3)), "shape")])
def test_external_forces_of_a_wrong_type(value, match):
    sim = Simulator(_one_body().finalize(), 0.01)
    with pytest.raises(ValueError, match=f"force.*{match}"):
        sim.set_external_forces(force=value)


# ------------------------------------------------------------------------------------------------ devices
def test_unavailable_device_is_one_clear_error():
    """Warp raises RuntimeError for "cuda" without a GPU and ValueError for an unknown name: both become one
    SceneError naming the device and the devices this machine has."""
    b = _one_body()
    for device in ["tpu", "cuda:99"] + ([] if wp.get_cuda_device_count() else ["cuda"]):
        with pytest.raises(SceneError, match=rf"device '{re.escape(device)}' is not available.*this machine has: cpu"):
            b.finalize(device)


# ------------------------------------------------------------------------------------------------ divergence
def _tree_sim(n: int = 15, solver: str = "cholesky") -> Simulator:
    return Simulator(scenes.binary_tree(n).finalize(), 1 / 30, solver=solver)


def test_divergence_report_counts_and_names_the_bodies():
    """The device counts a body whose squared state overflows (finite, yet |v| ~ 1e160) as diverged: the report
    counts the same way, so it never says "in 0 bodies"."""
    sim = _tree_sim()
    v = sim.state.body_v.numpy()
    v[3] = (1e160, 0.0, 0.0)
    sim.state.body_v.assign(v)
    with pytest.raises(SimulationError, match=r"values up to 1e\+160, too large to square\) in 1 body: 'b3'$"):
        sim._check_finite(sim.state, 0)
    v[3], v[4] = (np.nan, 0.0, 0.0), (np.inf, 0.0, 0.0)
    sim.state.body_v.assign(v)
    with pytest.raises(SimulationError, match=r"\(NaN or Inf\) in 2 bodies: 'b3', 'b4'$"):
        sim._check_finite(sim.state, 0)


def test_divergence_during_a_step_names_the_body():
    sim = _tree_sim()
    v = sim.state.body_v.numpy()
    v[5] = (1e160, 0.0, 0.0)
    sim.state.body_v.assign(v)
    with pytest.raises(SimulationError) as err:
        sim.step()
    assert "0 bodies" not in str(err.value) and "'b5'" in str(err.value)


# ------------------------------------------------------------------------------------------------ mass ratios
@pytest.mark.parametrize(
    "field,value,error,match",
    [
        ("mass", 1e-30, SingularSystemError, r"mass ratio between jointed bodies 'b0' .* and 'b2' \(1e-30 kg\)"),
        ("inertia", 1e-30, SingularSystemError, r"principal moments of inertia .*body 'b2': 1e-30 kg m\^2"),
        ("mass", 1e30, SimulationError, r"mass ratio between jointed bodies 'b2' \(1e\+30 kg\)"),
    ],
)
def test_extreme_mass_ratio_is_named_not_called_redundant(field, value, error, match):
    """Masses or inertias 1e30 apart make K lose its small terms: the failure names the bodies and the ratio
    instead of calling the joints redundant."""
    b = scenes.binary_tree(7)
    setattr(b.bodies[2], field, value if field == "mass" else value * np.eye(3))
    with pytest.raises(error, match=match) as err:
        sim = Simulator(b.finalize(), 1 / 30)
        for _ in range(60):
            sim.step()
    assert "redundant" not in str(err.value)


def test_a_genuinely_redundant_joint_is_still_called_redundant():
    """Two balls at one point on the root (loop joints: the tree holds the root already) repeat each other:
    their redundant rows are regularised, counted and reported as information (docs/mechanisms.md); the
    augmented matrix, which has no assembled diagonal to judge them by, still stops naming them redundant."""
    b = scenes.binary_tree(3)
    b.add_joint_ball(None, 0, b.bodies[0].position + (0.0, 0.0, 1.0), name="twin")  # a second ball on the root
    b.add_joint_ball(None, 0, b.bodies[0].position + (0.0, 0.0, 1.0), name="twin2")
    sim = Simulator(b.finalize(), 1 / 30, solver="cholesky")
    assert sim.redundant_rows == 4  # 9 rows on the root, 5 degrees of freedom removed
    assert sim.step().converged and sim.joint_errors().max() <= 1e-6
    with pytest.raises(SingularSystemError, match="redundant"):
        Simulator(b.finalize(), 1 / 30, solver="cholesky", options=wi.StepOptions(formulation="body")).step()


# ------------------------------------------------------------------------------------------------ checkpoints
def _state(sim: Simulator) -> list[np.ndarray]:
    return [getattr(sim.state, f"body_{n}").numpy().copy() for n in ("x", "q", "v", "w")] + [
        np.array([sim.time, sim.step_count])
    ]


def _unchanged(before: list[np.ndarray], sim: Simulator) -> bool:
    return all(np.array_equal(a, b) for a, b in zip(before, _state(sim)))


def test_checkpoint_of_another_scene_with_the_same_count_and_dt_is_refused(tmp_path):
    """Same body count, same dt, different masses / joints / forces: each is refused, naming what differs."""
    path = tmp_path / "ck.npz"
    saved = wi.Simulator(scenes.binary_tree(15).finalize(), 1 / 30)
    for _ in range(3):
        saved.step()
    saved.save_checkpoint(path)
    heavier = scenes.binary_tree(15)
    heavier.bodies[4].mass *= 1.01
    star = scenes.star(15)
    pushed = scenes.binary_tree(15)
    pushed.add_force(3, (1.0, 0.0, 0.0))
    for builder, what in [(heavier, "bodies"), (star, "joints"), (pushed, "gravity and forces")]:
        other = wi.Simulator(builder.finalize(), 1 / 30)
        before = _state(other)
        with pytest.raises(CheckpointError, match=rf"ck.npz: checkpoint of another scene: its {what} differ"):
            other.load_checkpoint(path)
        assert _unchanged(before, other)
    same = wi.Simulator(scenes.binary_tree(15).finalize(), 1 / 30)
    same.load_checkpoint(path)
    assert same.step_count == 3


def _save(path, sim: Simulator, **changes) -> None:
    sim.save_checkpoint(path)
    with np.load(path) as npz:
        data = {k: npz[k] for k in npz.files}
    for key, value in changes.items():
        if value is None:
            del data[key]
        else:
            data[key] = value
    np.savez(path, **data)


BAD_CHECKPOINTS = {
    "missing key": ({"v": None}, r"it has no v"),
    "old version (no fingerprint)": ({"scene_bodies": None}, r"it has no scene_bodies"),
    "wrong shape": ({"w": np.zeros((15, 2))}, r"'w' has shape \(15, 2\), expected \(15, 3\)"),
    "NaN (assigned after x)": ({"v": np.full((15, 3), np.nan)}, r"'v' contains NaN"),
    "strings": ({"time": np.array("soon")}, r"'time' is not a number"),
    "pickled objects": ({"x": np.array([None] * 15, dtype=object)}, r"not a readable warpimpulse checkpoint"),
    "not unit quaternions": ({"q": np.full((15, 4), 2.0)}, r"not a unit quaternion"),
    "negative step": ({"step_count": np.array(-4)}, r"step count -4"),
}


@pytest.mark.parametrize("case", BAD_CHECKPOINTS)
def test_a_bad_checkpoint_leaves_the_state_untouched(tmp_path, case):
    changes, match = BAD_CHECKPOINTS[case]
    path = tmp_path / "ck.npz"
    writer = _tree_sim()
    for _ in range(2):
        writer.step()
    _save(path, writer, **changes)
    sim = _tree_sim()
    sim.step()
    before = _state(sim)
    with pytest.raises(CheckpointError, match=rf"^{re.escape(str(path))}: .*{match}") as err:
        sim.load_checkpoint(path)
    assert "allow_pickle" not in str(err.value)
    assert _unchanged(before, sim)
    sim.step()  # still usable


def test_unreadable_checkpoint_files_name_the_path(tmp_path):
    sim = _tree_sim()
    good = tmp_path / "good.npz"
    sim.save_checkpoint(good)
    text = tmp_path / "notes.npz"
    text.write_text("not a checkpoint\n")
    truncated = tmp_path / "cut.npz"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    array = tmp_path / "array.npy"
    np.save(array, np.zeros(3))
    empty_zip = tmp_path / "empty.npz"
    zipfile.ZipFile(empty_zip, "w").close()
    cases = {
        tmp_path / "absent.npz": "no such checkpoint file",
        tmp_path: "not a readable warpimpulse checkpoint",
        text: "not a readable warpimpulse checkpoint",
        truncated: "not a readable warpimpulse checkpoint",
        array: "not a readable warpimpulse checkpoint",
        empty_zip: "not a warpimpulse checkpoint of this version: it has no x",
    }
    before = _state(sim)
    for path, match in cases.items():
        with pytest.raises(CheckpointError, match=rf"^{re.escape(str(path))}: {match}"):
            sim.load_checkpoint(path)
    assert _unchanged(before, sim)


def test_checkpoint_of_another_solver_resumes(tmp_path):
    """CG's warm starts in a checkpoint are not used by Cholesky (and the reverse), instead of crashing."""
    path = tmp_path / "ck.npz"
    cg = _tree_sim(solver="cg")
    for _ in range(3):
        cg.step()
    cg.save_checkpoint(path)
    chol = _tree_sim(solver="cholesky")
    chol.load_checkpoint(path)
    chol.step()
    assert chol.step_count == 4 and chol.joint_errors().max() < 1e-6


def test_save_checkpoint_leaves_no_temporary_file_on_failure(tmp_path):
    sim = _tree_sim()
    target = tmp_path / "dir.npz"
    target.mkdir()  # os.replace cannot replace a directory with a file
    with pytest.raises(OSError):
        sim.save_checkpoint(target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir.npz"]


# ------------------------------------------------------------------------------------------------ usd.record
def test_record_refuses_a_duration_without_a_frame(tmp_path):
    sim = _tree_sim(7)
    out = tmp_path / "o.usdc"
    with pytest.raises(ValueError, match="fps 30: a frame lasts 0.0333333 s, longer than the duration 0.01 s"):
        wi.usd.record(sim, out, duration=0.01, fps=30)
    assert not out.exists() and sim.step_count == 0


def test_record_warns_of_an_energy_gain_and_records_it(tmp_path):
    from pxr import Sdf

    sim = Simulator(scenes.binary_tree(31).finalize(), 0.5, options=wi.StepOptions(max_rotation=None))
    out = tmp_path / "o.usdc"
    with pytest.warns(RuntimeWarning, match=r"the energy grew by \d+\.\d% .* above the 5% threshold"):
        wi.usd.record(sim, out, duration=6.0, fps=2)
    data = Sdf.Layer.FindOrOpen(str(out)).customLayerData
    assert data["warpimpulse:energyGain"] > 0.05
