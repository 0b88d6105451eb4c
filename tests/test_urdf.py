"""URDF in (`wi.load_urdf`), USD out (`warpimpulse convert`): the mapping on small URDFs written here, the
motion against pinocchio, real robots of example-robot-data (the `[robots]` extra; skipped without it) and
the round trip through a UsdPhysics file."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run

import warpimpulse as wi
from warpimpulse import usd
from warpimpulse.shapes import PIECE_SHARES
from warpimpulse.transforms import quat_to_matrix
from warpimpulse.urdf import example_robots

ROBOTS = example_robots()
pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")  # the loaders' notes (asserted where they matter)
needs_robots = pytest.mark.skipif(ROBOTS is None, reason="example-robot-data not installed (the [robots] extra)")

# A pendulum of two links on revolute joints, a tool welded to the second (merged), a massless frame on a joint
# (dropped), primitive and mesh visuals with colours, a limit whose range excludes 0, damping and friction.
ARM = """<?xml version="1.0"?>
<robot name="arm">
  <material name="red"><color rgba="0.9 0.1 0.1 1"/></material>
  <link name="world"/>
  <link name="base">
    <inertial><mass value="2"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><geometry><box size="0.2 0.2 0.1"/></geometry><material name="red"/></visual>
  </link>
  <joint name="anchor" type="fixed"><parent link="world"/><child link="base"/><origin xyz="0 0 1"/></joint>
  <link name="upper">
    <inertial><origin xyz="0 0 -0.25" rpy="0.3 0 0"/><mass value="1.5"/>
      <inertia ixx="0.03" iyy="0.031" izz="0.004" ixy="0.001" ixz="0" iyz="0"/></inertial>
    <visual><origin xyz="0 0 -0.25"/><geometry><cylinder radius="0.03" length="0.5"/></geometry>
      <material name="blue"><color rgba="0.1 0.2 0.9 1"/></material></visual>
    <collision><origin xyz="0 0 -0.25" rpy="0.3 0 0"/><geometry><cylinder radius="0.03" length="0.5"/></geometry>
    </collision>
  </link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/>
    <origin xyz="0 0 -0.05" rpy="0 0 0.2"/><axis xyz="1 0 0"/>
    <limit lower="-2" upper="2" effort="10" velocity="3"/><dynamics damping="0.05" friction="0.1"/></joint>
  <link name="lower">
    <inertial><origin xyz="0 0 -0.2"/><mass value="1"/>
      <inertia ixx="0.0135" iyy="0.0135" izz="0.0005" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><origin xyz="0 0 -0.2"/><geometry><mesh filename="part.obj" scale="1 1 2"/></geometry></visual>
  </link>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="lower"/>
    <origin xyz="0 0 -0.5"/><axis xyz="0 1 1"/><limit lower="0.3" upper="2.5" effort="5" velocity="2"/></joint>
  <link name="tool">
    <inertial><origin xyz="0.05 0 0"/><mass value="0.5"/>
      <inertia ixx="0.001" iyy="0.002" izz="0.002" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><geometry><sphere radius="0.05"/></geometry><material name="red"/></visual>
    <collision><geometry><box size="0.1 0.1 0.1"/></geometry></collision>
  </link>
  <joint name="weld" type="fixed"><parent link="lower"/><child link="tool"/><origin xyz="0 0 -0.4"/></joint>
  <link name="camera"/>
  <joint name="camera_joint" type="continuous"><parent link="lower"/><child link="camera"/><axis xyz="0 0 1"/>
  </joint>
  <gazebo reference="lower"><mu1>0.5</mu1></gazebo>
</robot>
"""
OBJ = "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 2 3\nf 1 2 4\nf 1 3 4 2\n"


def _write(folder: Path, text: str, name: str = "arm.urdf") -> Path:
    (folder / "part.obj").write_text(OBJ)
    path = folder / name
    path.write_text(text)
    return path


def _load(path, **kw) -> tuple[wi.SceneBuilder, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        builder = wi.load_urdf(path, **kw)
    return builder, [str(w.message) for w in caught]


def _rot(rpy) -> np.ndarray:
    from warpimpulse.urdf import _rpy_matrix

    return _rpy_matrix(np.asarray(rpy, dtype=float))


def test_links_joints_and_merged_mass_properties(tmp_path):
    """Bodies at their centres of mass with the URDF's inertia; the welded tool merged into 'lower' (mass,
    centre of mass and inertia composed by hand here); the massless camera dropped; the world link and the
    base merged into the world; every note one line naming its elements."""
    b, notes = _load(_write(tmp_path, ARM))
    # The tool's box, off the centre of mass of lower + tool, collides as a piece welded to it.
    assert [x.name for x in b.bodies] == ["upper", "lower", "lower/collision0"]
    assert [j.name for j in b.joints] == ["shoulder", "elbow", "lower/collision0"]  # the URDF's joints first
    # The elbow's limits exclude 0: built at 0.3 (the nearest end), its limit shifted to [0, 2.2].
    assert [(lim.lower, lim.upper) for lim in b.limits] == [(-2.0, 2.0), (0.0, pytest.approx(2.2))]
    rz = _rot([0, 0, 0.2])
    shoulder = np.array([0, 0, 0.95])
    upper = b.bodies[0]
    np.testing.assert_allclose(upper.position, shoulder + rz @ [0, 0, -0.25], atol=1e-15)
    # Its collision cylinder is centred on the centre of mass: the body takes the cylinder's frame (the
    # inertial frame here too), the URDF's tensor as it is, and the cylinder as its shape.
    r = _rot([0.3, 0, 0])
    np.testing.assert_allclose(quat_to_matrix(upper.orientation), rz @ r, atol=1e-15)
    tensor = np.array([[0.03, 0.001, 0], [0.001, 0.031, 0], [0, 0, 0.004]])
    np.testing.assert_allclose(upper.inertia, tensor, atol=1e-15)
    assert (upper.shape.kind, upper.shape.radius, upper.shape.length) == ("cylinder", 0.03, 0.5)
    # lower + tool, in lower's frame: elbow turned 0.3 rad about (0, 1, 1)/sqrt(2) from upper's frame.
    axis = np.array([0, 1, 1]) / math.sqrt(2)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    turn = np.eye(3) + math.sin(0.3) * k + (1 - math.cos(0.3)) * k @ k
    frame = rz @ turn
    origin = shoulder + rz @ [0, 0, -0.5]
    c_lower, c_tool = origin + frame @ [0, 0, -0.2], origin + frame @ [0.05, 0, -0.4]
    com = (1.0 * c_lower + 0.5 * c_tool) / 1.5
    lower, piece = b.bodies[1], b.bodies[2]
    box = origin + frame @ [0, 0, -0.4]  # the tool's origin, where its box is
    np.testing.assert_allclose(piece.position, box, atol=1e-14)
    assert (piece.shape.kind, piece.shape.size) == ("box", (0.1, 0.1, 0.1))
    assert lower.mass + piece.mass == pytest.approx(1.5, rel=1e-14)
    assert any(piece.mass == pytest.approx(share * 1.5) for share in PIECE_SHARES)  # half, or less: 0.25 here
    np.testing.assert_allclose((lower.mass * lower.position + piece.mass * piece.position) / 1.5, com, atol=1e-14)

    def about(m, inertia, d):
        return inertia + m * (d @ d * np.eye(3) - np.outer(d, d))

    world_inertia = about(1.0, frame @ np.diag([0.0135, 0.0135, 0.0005]) @ frame.T, c_lower - com) + about(
        0.5, frame @ np.diag([0.001, 0.002, 0.002]) @ frame.T, c_tool - com
    )
    # The two bodies together have the merged link's inertia about its centre of mass, exactly.
    together = sum(
        about(x.mass, quat_to_matrix(x.orientation) @ x.inertia @ quat_to_matrix(x.orientation).T, x.position - com)
        for x in (lower, piece)
    )
    np.testing.assert_allclose(together, world_inertia, atol=1e-14)
    assert b.joints[2].kind == "fixed"
    # The joints: anchors at the child links' origins, axes turned into the world.
    np.testing.assert_allclose(b.joints[1].anchor, origin, atol=1e-15)
    np.testing.assert_allclose(b.joints[1].axis, rz @ axis, atol=1e-15)
    # The shoulder's damper (stiffness 0); friction, effort/velocity, gazebo, the camera: one line each.
    assert [(d.kp, d.kd, d.motor) for d in b.drives] == [(0.0, 0.05, False)]
    for words in ("<gazebo> (1)", "'shoulder': <dynamics friction>", "'shoulder', 'elbow': <limit effort/velocity>",
                  "links 'camera' have no mass"):  # fmt: skip
        assert sum(words in n for n in notes) == 1, (words, notes)
    assert all("\n" not in n for n in notes)


def test_visuals_keep_colours_meshes_and_frames(tmp_path):
    b, _ = _load(_write(tmp_path, ARM))
    kinds = [(v.body, v.kind, v.rgba) for v in b.visuals]
    red, blue = (0.9, 0.1, 0.1, 1.0), (0.1, 0.2, 0.9, 1.0)
    grey = (0.7, 0.7, 0.7, 1.0)
    assert kinds == [(wi.WORLD, "box", red), (0, "cylinder", blue), (1, "mesh", grey), (1, "sphere", red)]
    mesh = b.visuals[2]
    assert mesh.size == (1.0, 1.0, 2.0) and mesh.vertices.shape == (4, 3)
    assert mesh.faces.tolist() == [[0, 1, 2], [0, 1, 3], [0, 2, 3], [0, 3, 1]]  # the quad fanned
    assert mesh.mesh_path == str(tmp_path / "part.obj")
    # The base's box stays where the URDF puts it, in the world: z = 1.
    np.testing.assert_allclose(b.visuals[0].position, [0, 0, 1], atol=1e-15)
    # The cylinder is centred on upper's centre of mass along the link's z: in the body's frame (the collision
    # cylinder's, turned 0.3 rad about x) it is turned back by -0.3 rad.
    np.testing.assert_allclose(b.visuals[1].position, 0.0, atol=1e-15)
    np.testing.assert_allclose(quat_to_matrix(b.visuals[1].orientation), _rot([-0.3, 0, 0]), atol=1e-15)


@pytest.mark.parametrize(
    "change, message",
    [
        (('<joint name="elbow" type="revolute">', '<joint name="elbow" type="revolute"><mimic joint="shoulder"/>'),
         "<mimic> of joints 'elbow'"),
        (('<link name="upper">\n    <inertial><origin xyz="0 0 -0.25" rpy="0.3 0 0"/><mass value="1.5"/>',
          '<link name="upper">\n    <inertial><origin xyz="0 0 -0.25" rpy="0.3 0 0"/><mass value="0"/>'),
         "link 'upper' has no mass on joint 'shoulder', and bodies move beyond it"),
        (('<child link="lower"/>', '<child link="upper"/>'), "link 'upper' is the child of two joints"),
        (('<axis xyz="0 1 1"/>', '<axis xyz="0 0 0"/>'), "joint 'elbow': axis is a zero vector"),
        (('type="revolute"><parent link="upper"/>', 'type="screw"><parent link="upper"/>'),
         "joint 'elbow': type 'screw' is not a URDF joint type"),
        (('<limit lower="0.3" upper="2.5"', '<limit lower="2.5" upper="0.3"'),
         "joint 'elbow': limit lower 2.5 > upper 0.3"),
        (('<sphere radius="0.05"/>', '<cone radius="0.05"/>'), "link 'tool' visual 0: geometry <cone>"),
        (('ixx="0.03" iyy="0.031" izz="0.004"', 'ixx="0.03" iyy="0.031" izz="0.1"'),
         "body 'upper': principal moments"),
    ],
)  # fmt: skip
def test_bad_or_unsupported_elements_are_one_line_naming_them(tmp_path, change, message, capsys):
    path = _write(tmp_path, ARM.replace(*change))
    with pytest.raises(wi.SceneError) as err:
        _load(path)
    assert message in str(err.value) and "\n" not in str(err.value)
    code, lines = run(["convert", str(path), "-o", str(tmp_path / "x.usda")], capsys)
    errors = [line for line in lines if "error: " in line]
    assert code == 2 and len(errors) == 1 and message in errors[0], lines
    assert not (tmp_path / "x.usda").exists()
    if "mimic" in message or "<cone>" in message:  # unsupported, not wrong: dropped with a warning when asked
        _, notes = _load(path, ignore_unsupported=True)
        assert any(message in n and "ignored" in n for n in notes)


def test_floating_base_and_configuration(tmp_path):
    path = _write(tmp_path, ARM)
    b, _ = _load(path, floating=True, configuration={"shoulder": 0.5, "elbow": 1.0})
    assert [x.name for x in b.bodies] == ["base", "upper", "lower", "lower/collision0"]  # world link: a frame on base
    assert b.joints[0].parent == 0 and b.bodies[0].mass == 2.0
    assert [(lim.lower, lim.upper) for lim in b.limits] == [(-2.5, 1.5), (pytest.approx(-0.7), pytest.approx(1.5))]
    with pytest.raises(wi.SceneError, match="joint 'elbow' = 3.0 is outside its limits"):
        wi.load_urdf(path, configuration={"elbow": 3.0})
    floating = ARM.replace('<joint name="anchor" type="fixed">', '<joint name="anchor" type="floating">')
    b, _ = _load(_write(tmp_path, floating, "free.urdf"))
    assert [x.name for x in b.bodies] == ["base", "upper", "lower", "lower/collision0"]  # the URDF says: free base
    assert b.joints[0].parent == 0


def _pendulum_against_pinocchio(path: Path, configuration: dict, duration: float, dt: float) -> float:
    """The largest difference (rad) of the joint angles from pinocchio's ABA integrated by RK4 at dt / 10,
    starting at rest at `configuration`."""
    pin = pytest.importorskip("pinocchio")
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    names = [model.names[i] for i in range(1, model.njoints)]
    b = wi.load_urdf(path, configuration=configuration, collisions=False, visuals=False, ignore_unsupported=True)
    sim = wi.Simulator(b.finalize(), dt)
    steps = round(duration / dt)
    sim.step(steps)
    q, v, h = np.array([configuration.get(n, 0.0) for n in names]), np.zeros(model.nv), dt / 10
    tau = np.zeros(model.nv)
    for _ in range(10 * steps):
        k1q, k1v = v, pin.aba(model, data, q, v, tau)
        k2q, k2v = v + 0.5 * h * k1v, pin.aba(model, data, q + 0.5 * h * k1q, v + 0.5 * h * k1v, tau)
        k3q, k3v = v + 0.5 * h * k2v, pin.aba(model, data, q + 0.5 * h * k2q, v + 0.5 * h * k2v, tau)
        k4q, k4v = v + h * k3v, pin.aba(model, data, q + h * k3q, v + h * k3v, tau)
        q, v = q + h / 6 * (k1q + 2 * k2q + 2 * k3q + k4q), v + h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
    ours = np.array([configuration.get(n, 0.0) + sim.joint_coordinates(n)[0] for n in names])
    return float(np.abs(ours - q).max())


def test_arm_moves_as_pinocchio_says(tmp_path):
    """The merged, damper-free arm (limits not reached) against pinocchio over 0.3 s: the URDF's frames, axes,
    inertias and the merge agree with an independent reduced-coordinate model. Order 2: the difference falls
    4x when h halves."""
    text = ARM.replace('<dynamics damping="0.05" friction="0.1"/>', "").replace('lower="0.3"', 'lower="-2.5"')
    camera = text.index('  <link name="camera"/>')
    text = text[:camera] + text[text.index("  <gazebo") :]  # pinocchio gives the massless frame a coordinate
    path = _write(tmp_path, text)
    cfg = {"shoulder": 0.4, "elbow": 0.6}
    coarse, fine = (_pendulum_against_pinocchio(path, cfg, 0.3, dt) for dt in (2e-3, 1e-3))
    assert fine < 5e-6 and 3.0 < coarse / fine < 5.0, (coarse, fine)  # measured 1.36e-6, ratio 4.0


@needs_robots
def test_ur5_moves_as_pinocchio_says():
    """example-robot-data's UR5 from rest at a seeded pose, 0.3 s at h = 1 ms: 2.7e-6 rad (6.9e-7 at 0.5 ms)."""
    path = Path(ROBOTS) / "ur_description/urdf/ur5_robot.urdf"
    rng = np.random.default_rng(7)
    names = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
             "wrist_3_joint"]  # fmt: skip
    cfg = dict(zip(names, 0.5 * rng.standard_normal(6)))
    assert _pendulum_against_pinocchio(path, cfg, 0.3, 1e-3) < 1e-5  # measured 2.7e-6 rad


@needs_robots
@pytest.mark.parametrize(
    "urdf, bodies, strict",
    [
        ("ur_description/urdf/ur5_robot.urdf", 6, True),
        ("panda_description/urdf/panda.urdf", 9, False),  # a mimic finger
        ("solo_description/robots/solo12.urdf", 13, True),
        ("go1_description/urdf/go1.urdf", 13, True),
        ("g1_description/urdf/g1_29dof_rev_1_0.urdf", 30, True),
        ("talos_data/robots/talos_reduced.urdf", 33, False),  # mimic gripper joints
    ],
)
def test_real_robots_load_in_one_call_and_hold_their_joints(urdf, bodies, strict):
    """An arm, a Panda, two quadrupeds (free bases) and two humanoids (free bases): one call each, then 0.2 s
    under gravity at h = 1 ms without NaN, every joint within the tolerance (1e-6)."""
    path = Path(ROBOTS) / urdf
    floating = "solo" in urdf or "go1" in urdf or "g1" in urdf or "talos" in urdf
    arm = "ur_" in urdf or "panda" in urdf  # the arms' meshes are read too (the others' are large Collada files)
    builder = wi.load_urdf(path, ignore_unsupported=not strict, floating=floating, collisions=False, visuals=arm)
    assert len(builder.bodies) == bodies
    assert bool(builder.visuals) == arm
    sim = wi.Simulator(builder.finalize(), 1e-3)
    stats = sim.step(200)
    assert np.isfinite(sim.positions()).all()
    assert stats.max_joint_error <= 1e-6 and sim.joint_errors().max() <= 1e-6
    if floating:  # a free robot falls as a whole: g t^2 / 2 of its centre of mass
        m = np.array([b.mass for b in builder.bodies])
        com0 = m @ np.array([b.position for b in builder.bodies]) / m.sum()
        drop = (m @ sim.positions() / m.sum() - com0)[2]
        assert drop == pytest.approx(-0.5 * 9.81 * 0.2**2, rel=1e-6)


def _same_motion(a: wi.SceneBuilder, b: wi.SceneBuilder, duration: float) -> float:
    sims = [wi.Simulator(x.finalize(), 1e-3) for x in (a, b)]
    for s in sims:
        s.step(round(duration / 1e-3))
    return float(np.abs(sims[0].positions() - sims[1].positions()).max())


def test_convert_round_trip(tmp_path, capsys):
    """`warpimpulse convert arm.urdf -o arm.usda`: valid (UsdValidation), colours as UsdPreviewSurface materials
    bound to the visuals, limits and the damper read back, and the same motion over 1 s to 1e-6 m."""
    path = _write(tmp_path, ARM)
    out = tmp_path / "arm.usda"
    code, lines = run(["convert", str(path), "-o", str(out)], capsys)
    assert code == 0, lines
    assert usd.validate(out) == []
    builder, _ = _load(path)
    scene = usd.load_stage(out)
    assert scene.notes == []
    again = scene.builder
    bounds = [(lim.lower, lim.upper) for lim in again.limits]
    np.testing.assert_allclose(bounds, [(-2.0, 2.0), (0.0, 2.2)], atol=1e-6)  # degrees in float32 and back
    assert [(d.kp, d.kd) for d in again.drives] == [(0.0, pytest.approx(0.05))]
    from pxr import Usd, UsdShade

    stage = Usd.Stage.Open(str(out))
    colours = {}
    for prim in stage.Traverse():
        if prim.GetName().startswith("visual"):
            material = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0]
            shader = UsdShade.Shader(stage.GetPrimAtPath(material.GetPath().AppendChild("PreviewSurface")))
            colours[str(prim.GetPath())] = tuple(round(c, 6) for c in shader.GetInput("diffuseColor").Get())
    assert colours == {"/World/upper/visual0": (0.1, 0.2, 0.9), "/World/lower/visual0": (0.7, 0.7, 0.7),
                       "/World/lower/visual1": (0.9, 0.1, 0.1), "/World/Visuals/visual0": (0.9, 0.1, 0.1)}  # fmt: skip
    assert stage.GetPrimAtPath("/World/lower/visual0").GetTypeName() == "Mesh"
    assert _same_motion(builder, again, 1.0) < 1e-6


@needs_robots
@pytest.mark.slow  # 5 s warm, 20 s on a loaded machine: eleven Collada meshes read and written twice
def test_convert_a_real_robot_round_trip(tmp_path, capsys):
    """Panda (Collada visuals through pycollada, a mimic finger dropped with --ignore-unsupported): the file
    validates, draws every link with a mesh, and moves as the URDF does (1e-6 m over 0.5 s)."""
    pytest.importorskip("collada")
    path = Path(ROBOTS) / "panda_description/urdf/panda.urdf"
    out = tmp_path / "panda.usda"
    code, lines = run(["convert", str(path), "-o", str(out), "--ignore-unsupported"], capsys)
    assert code == 0 and any("<mimic>" in line for line in lines), lines
    assert usd.validate(out) == []
    builder = wi.load_urdf(path, ignore_unsupported=True)
    again = usd.load_stage(out).builder
    assert len(again.bodies) == len(builder.bodies) and len(again.limits) == 9
    assert sum("/collision" not in x.name for x in builder.bodies) == 9  # and the links' collision pieces
    assert sum(v.kind == "mesh" for v in builder.visuals) == 11
    assert _same_motion(builder, again, 0.5) < 1e-6


@needs_robots
def test_simulate_a_real_urdf_writes_its_motion_with_meshes_and_colours(tmp_path, capsys):
    """`warpimpulse simulate ur5_robot.urdf -o ur5.usda`: the robot as `convert` writes it (its Collada meshes,
    UsdPreviewSurface colours; valid), animated: 0.1 s at h = 1 ms, the arm falling from its zero pose as the
    library run does (the same numbers). A URDF flag on an MJCF, and a bad URDF, are one line and exit 2."""
    pytest.importorskip("collada")
    path = Path(ROBOTS) / "ur_description/urdf/ur5_robot.urdf"
    out = tmp_path / "ur5.usda"
    code, lines = run(["simulate", str(path), "-o", str(out), "--duration", "0.1", "--fps", "20", "--dt", "0.001"],
                      capsys)  # fmt: skip
    assert code == 0, lines
    assert usd.validate(out) == []
    from pxr import Usd

    stage = Usd.Stage.Open(str(out))
    types = [p.GetTypeName() for p in stage.Traverse()]
    assert types.count("Mesh") == 7 and "Shader" in types
    anim = usd.read_animation(out)
    sim = wi.Simulator(wi.load_urdf(path).finalize(), 1e-3)
    sim.step(100)
    assert len(anim.time_codes) == 3 and np.abs(anim.positions[-1] - anim.positions[0]).max() > 1e-3
    np.testing.assert_allclose(anim.positions[-1], sim.positions(), atol=1e-9)
    (tmp_path / "arm.xml").write_text(MJCF_ARM)
    assert_one_line_error(["simulate", str(tmp_path / "arm.xml"), "--floating", "-o", str(out)],
                          "arm.xml: --floating/--no-floating is for a URDF", capsys)  # fmt: skip
    bad = _write(tmp_path, ARM.replace('<limit lower="0.3" upper="2.5"', '<limit lower="2.5" upper="0.3"'))
    assert_one_line_error(["simulate", str(bad), "-o", str(out)], "joint 'elbow': limit lower 2.5 > upper 0.3", capsys)


# A link hung from the world by three hinges through one point, two massless links between them (a ball, as
# humanoid URDFs write their hips and shoulders), and a second link by two (a universal joint).
HINGES = """<?xml version="1.0"?>
<robot name="hinges">
  <link name="world"/>
  <link name="v1"/> <link name="v2"/> <link name="v3"/>
  <link name="upper"><inertial><origin xyz="0.1 0 -0.3"/><mass value="2"/>
    <inertia ixx="0.02" iyy="0.025" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="lower"><inertial><origin xyz="0 0.05 -0.2"/><mass value="1"/>
    <inertia ixx="0.01" iyy="0.012" izz="0.004" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="hz" type="revolute"><parent link="world"/><child link="v1"/><origin xyz="0 0 1"/>
    <axis xyz="0 0 1"/><limit lower="-9" upper="9" effort="1" velocity="1"/></joint>
  <joint name="hx" type="revolute"><parent link="v1"/><child link="v2"/><axis xyz="1 0 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="hy" type="revolute"><parent link="v2"/><child link="upper"/><axis xyz="0 1 0"/>
    <limit lower="-9" upper="9" effort="1" velocity="1"/></joint>
  <joint name="kx" type="revolute"><parent link="upper"/><child link="v3"/><origin xyz="0 0 -0.6"/>
    <axis xyz="1 0 0"/><limit lower="-9" upper="9" effort="1" velocity="1"/></joint>
  <joint name="ky" type="revolute"><parent link="v3"/><child link="lower"/><axis xyz="0 1 1"/>
    <limit lower="-9" upper="9" effort="1" velocity="1"/></joint>
</robot>
"""


def test_hinges_through_massless_links_compose_into_ball_and_universal_joints(tmp_path):
    """The serial hinges become a ball and a universal joint (their limits said, not applied); the links
    move as pinocchio's five-hinge chain does (the massless links add no dynamics), from rest at a pose away
    from the gimbal's lock, within 2e-4 m over 0.3 s at h = 1 ms."""
    pin = pytest.importorskip("pinocchio")
    path = tmp_path / "hinges.urdf"
    path.write_text(HINGES)
    cfg = {"hz": 0.3, "hx": 0.4, "hy": 0.5, "kx": -0.6, "ky": 0.7}
    b, notes = _load(path, configuration=cfg)
    assert [(j.name, j.kind) for j in b.joints] == [("hy", "ball"), ("ky", "universal")]
    said = "ball 'hy' from 'hz', 'hx', 'hy' (limits and dampers of 'hz', 'hx', 'hy' not applied)"
    assert sum(said in n for n in notes) == 1
    sim = wi.Simulator(b.finalize(), 1e-3)
    sim.step(300)
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    q = np.array([cfg[model.names[i]] for i in range(1, model.njoints)])
    v, tau, h = np.zeros(model.nv), np.zeros(model.nv), 1e-4
    for _ in range(3000):
        k1q, k1v = v, pin.aba(model, data, q, v, tau)
        k2q, k2v = v + 0.5 * h * k1v, pin.aba(model, data, q + 0.5 * h * k1q, v + 0.5 * h * k1v, tau)
        k3q, k3v = v + 0.5 * h * k2v, pin.aba(model, data, q + 0.5 * h * k2q, v + 0.5 * h * k2v, tau)
        k4q, k4v = v + h * k3v, pin.aba(model, data, q + h * k3q, v + h * k3v, tau)
        q, v = q + h / 6 * (k1q + 2 * k2q + 2 * k3q + k4q), v + h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
    pin.forwardKinematics(model, data, q)
    coms = [data.oMi[model.getJointId(j)].act(model.inertias[model.getJointId(j)].lever) for j in ("hy", "ky")]
    moved = np.abs(sim.positions() - np.array([x.position for x in b.bodies])).max()
    assert moved > 0.05 and np.abs(sim.positions() - np.array(coms)).max() < 2e-4, moved


MJCF_ARM = """<mujoco model="arm">
  <worldbody>
    <body name="upper" pos="0 0 1">
      <joint name="shoulder" type="hinge" axis="1 0 0" range="-2 2" limited="true" damping="0.05"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.5" size="0.03" rgba="0.1 0.2 0.9 1" contype="0" conaffinity="0"/>
      <body name="lower" pos="0 0 -0.5" euler="0.3 0 0">
        <joint name="elbow" type="hinge" axis="0 1 1"/>
        <geom type="box" pos="0 0 -0.2" size="0.02 0.03 0.2" rgba="0.9 0.1 0.1 1" contype="0" conaffinity="0"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def test_convert_mjcf_round_trip(tmp_path, capsys):
    """`warpimpulse convert arm.xml -o arm.usda` (MuJoCo's compiler through `wi.load_mjcf`): valid, and the file
    moves as the MJCF's builder does (1e-6 m over 1 s)."""
    pytest.importorskip("mujoco")
    path = tmp_path / "arm.xml"
    path.write_text(MJCF_ARM)
    out = tmp_path / "arm.usda"
    code, lines = run(["convert", str(path), "-o", str(out)], capsys)
    assert code == 0, lines
    assert usd.validate(out) == []
    builder = wi.load_mjcf(str(path))
    again = usd.load_stage(out).builder
    assert len(again.bodies) == 2 and len(again.limits) == 1 and len(again.drives) == len(builder.drives) == 1
    assert _same_motion(builder, again, 1.0) < 1e-6


def _mujoco_rest_height(path: Path, ground: float, duration: float) -> float:
    """The height (m) of the root body's centre of mass over `ground` after `duration` s, by MuJoCo (implicitfast,
    h = 1 ms) on the same URDF, free: its meshes stripped (MuJoCo reads no Collada) and the near-zero base
    inertia that MuJoCo refuses (off-diagonal as large as its diagonal) made diagonal."""
    import re

    mujoco = pytest.importorskip("mujoco")
    text = path.read_text()
    for element in ("visual", "gazebo", "transmission"):
        text = re.sub(rf"<{element}\b.*?</{element}>", "", text, flags=re.S)
    text = re.sub(r"<collision>(?:(?!</collision>).)*<mesh(?:(?!</collision>).)*</collision>", "", text, flags=re.S)
    text = re.sub(r'(ix[yz]|iyz)="1e-6"', r'\1="0"', text)
    spec = mujoco.MjSpec.from_string(text)
    spec.worldbody.first_body().add_freejoint()
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[5, 5, 0.1], pos=[0, 0, ground])
    m = spec.compile()
    m.opt.timestep, m.opt.integrator = 1e-3, mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    d = mujoco.MjData(m)
    mujoco.mj_step(m, d, round(duration / 1e-3))
    return float(d.xipos[1, 2] - ground)


@needs_robots
def test_a_legged_robot_lies_on_the_ground_as_in_mujoco():
    """Unitree A1, free and unactuated, dropped from its built pose onto a ground just under its feet: its feet,
    thighs and hips collide as pieces welded to their links (the links' own primitives are off their centres of
    mass), it folds and lies on its trunk, at the height MuJoCo gives the same URDF (within 2 mm: MuJoCo's soft
    contacts sink ~0.4 mm), and its joints hold."""
    path = Path(ROBOTS) / "a1_description/urdf/a1.urdf"
    b, _ = _load(path, floating=True, visuals=False)
    assert sum("/collision" in x.name for x in b.bodies) >= 4  # at least the four feet
    ground = min(x.position[2] - x.shape.bounding_radius() for x in b.bodies if x.shape is not None) - 1e-3
    b.add_ground(height=ground)
    sim = wi.Simulator(b.finalize(), 1e-3)
    stats = sim.step(1000)
    assert stats.converged and stats.max_joint_error <= 1e-6 and stats.contacts > 0
    ours = float(sim.positions()[0, 2] - ground)
    theirs = _mujoco_rest_height(path, ground, 1.0)
    assert abs(ours - theirs) < 2e-3, (ours, theirs)  # measured 0.0550 against 0.0554 m


@needs_robots
def test_self_collisions_filter_as_mujoco_does():
    """With self_collisions, A1's hip pieces collide with each other (siblings) but not with the trunk's pieces
    (their links are jointed), nor with their own link's other pieces; without, no two of its bodies collide."""
    path = Path(ROBOTS) / "a1_description/urdf/a1.urdf"
    on, _ = _load(path, floating=True, visuals=False, self_collisions=True)
    off, _ = _load(path, floating=True, visuals=False)
    index = {x.name: i for i, x in enumerate(on.bodies)}
    names = ("trunk/collision0", "FR_hip/collision0", "FR_hip/collision1", "FL_hip/collision0")
    trunk, fr0, fr1, fl0 = (index[n] for n in names)
    assert [x.name for x in on.bodies] == [x.name for x in off.bodies]
    assert (min(fr0, fl0), max(fr0, fl0)) not in on.collision_filters  # siblings collide
    assert {(min(trunk, fr0), max(trunk, fr0)), (min(fr0, fr1), max(fr0, fr1))} <= on.collision_filters
    shaped = [i for i, x in enumerate(off.bodies) if x.shape is not None]
    assert len(off.collision_filters) == len(shaped) * (len(shaped) - 1) // 2
