"""USD in, USD out: UsdPhysics import, time-sampled export, round trip through a fresh process, validation,
and a clear error naming the prim for each kind of bad input."""

from __future__ import annotations

import glob
import json
import math
import os
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdPhysics  # noqa: E402

from warpimpulse import SceneBuilder, SceneError, Shape, run, scenes, usd  # noqa: E402
from warpimpulse.cli import main as cli_main  # noqa: E402
from warpimpulse.usd import writer  # noqa: E402
from warpimpulse.usd.scene import builder_from_model  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DT, FPS, TOL = 1e-3, 50.0, 1e-6


# ---------------------------------------------------------------------------------------------- authoring
def _body(stage, path, pos, mass=None, inertia=None, com=None, axes=None, shape=None, density=None):
    x = UsdGeom.Xform.Define(stage, path)
    x.AddTranslateOp().Set(Gf.Vec3d(*pos))
    x.AddOrientOp().Set(Gf.Quatf(1.0))  # float orient on purpose: the export must not clash with it
    UsdPhysics.RigidBodyAPI.Apply(x.GetPrim())
    if mass is not None or density is not None or com is not None:
        m = UsdPhysics.MassAPI.Apply(x.GetPrim())
        if mass is not None:
            m.CreateMassAttr(mass)
        if density is not None:
            m.CreateDensityAttr(density)
        if inertia is not None:
            m.CreateDiagonalInertiaAttr(Gf.Vec3f(*inertia))
        if com is not None:
            m.CreateCenterOfMassAttr(Gf.Vec3f(*com))
        if inertia is not None:  # the validator wants principal axes authored along with the inertia
            m.CreatePrincipalAxesAttr(Gf.Quatf(*(axes or (1.0, 0.0, 0.0, 0.0))))
    if shape == "cube":
        g = UsdGeom.Cube.Define(stage, path + "/geom")
        g.CreateSizeAttr(0.25)
        UsdPhysics.CollisionAPI.Apply(g.GetPrim())
    elif shape == "capsule":
        g = UsdGeom.Capsule.Define(stage, path + "/geom")
        g.CreateRadiusAttr(0.0625)
        g.CreateHeightAttr(0.25)
        g.CreateAxisAttr("X")
        UsdPhysics.CollisionAPI.Apply(g.GetPrim())
    return x.GetPrim()


def _joint(stage, path, schema, body0, body1, pos0, pos1, rot0=(1, 0, 0, 0), rot1=(1, 0, 0, 0), axis=None):
    j = schema.Define(stage, path)
    if body0:
        j.CreateBody0Rel().SetTargets([body0])
    if body1:
        j.CreateBody1Rel().SetTargets([body1])
    j.CreateLocalPos0Attr(Gf.Vec3f(*pos0))
    j.CreateLocalPos1Attr(Gf.Vec3f(*pos1))
    j.CreateLocalRot0Attr(Gf.Quatf(*rot0))
    j.CreateLocalRot1Attr(Gf.Quatf(*rot1))
    if axis is not None:
        j.CreateAxisAttr(axis)
    return j.GetPrim()


def _lock(prim, *dofs):
    for dof in dofs:
        limit = UsdPhysics.LimitAPI.Apply(prim, dof)
        limit.CreateLowAttr(1.0)
        limit.CreateHighAttr(-1.0)


def author_mechanism(path: str, meters_per_unit: float = 1.0) -> None:
    """Every joint type on bodies under a translated, rotated, uniformly scaled parent; centre-of-mass
    offsets, principal axes, mass from shapes, a world joint, a loop-closing flag. Anchors are dyadic so
    both joint frames coincide exactly in float."""
    stage = Usd.Stage.CreateNew(path)
    UsdGeom.SetStageUpAxis(stage, "Z")
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    scene = UsdPhysics.Scene.Define(stage, "/World/physics")
    scene.CreateGravityDirectionAttr(Gf.Vec3f(0, 0, -1))
    scene.CreateGravityMagnitudeAttr(9.81 / meters_per_unit)
    rig = UsdGeom.Xform.Define(stage, "/World/Rig")
    rig.AddTranslateOp().Set(Gf.Vec3d(0.5, 0.0, 1.0))
    rig.AddRotateZOp().Set(30.0)
    rig.AddScaleOp().Set(Gf.Vec3f(2.0, 2.0, 2.0))
    r = "/World/Rig/"
    _body(stage, r + "base", (0.0, 0.0, 0.0), mass=2.0, inertia=(0.5, 0.25, 0.375), com=(0.0625, 0.0, 0.0),
          axes=(0.9238795, 0.0, 0.3826834, 0.0))  # fmt: skip
    _body(stage, r + "slider", (0.5, 0.0, 0.0), density=800.0, shape="cube")
    _body(stage, r + "ball", (0.0, 0.5, 0.0), mass=1.0, inertia=(0.125, 0.125, 0.125))
    _body(stage, r + "welded", (0.0, 0.75, 0.0), mass=0.5, inertia=(0.0625, 0.0625, 0.0625), shape="capsule")
    _body(stage, r + "cross", (-0.5, 0.0, 0.0), mass=1.0, inertia=(0.125, 0.125, 0.125))
    _body(stage, r + "tube", (-0.5, 0.0, -0.5), mass=1.0, inertia=(0.125, 0.125, 0.125))
    _body(stage, r + "plate", (0.0, -0.5, 0.0), mass=1.0, inertia=(0.125, 0.125, 0.125))
    _body(stage, r + "free", (0.0, 0.0, 0.5), mass=1.0, inertia=(0.125, 0.125, 0.125))
    j = "/World/Rig/joints/"
    UsdGeom.Scope.Define(stage, "/World/Rig/joints")
    hinge = _joint(stage, j + "hinge", UsdPhysics.RevoluteJoint, None, r + "base", (0.5, 0, 1), (0, 0, 0), axis="Y")
    hinge.GetAttribute("physics:localPos0").Set(Gf.Vec3f(0.5, 0.0, 1.0))  # world frame: the rig's origin
    rot30 = Gf.Rotation(Gf.Vec3d(0, 0, 1), 30.0).GetQuat()
    hinge.GetAttribute("physics:localRot0").Set(Gf.Quatf(rot30))
    _joint(stage, j + "slide", UsdPhysics.PrismaticJoint, r + "base", r + "slider", (0.5, 0, 0), (0, 0, 0), axis="X")
    _joint(stage, j + "sphere", UsdPhysics.SphericalJoint, r + "base", r + "ball", (0, 0.5, 0), (0, 0, 0))
    _joint(stage, j + "weld", UsdPhysics.FixedJoint, r + "ball", r + "welded", (0, 0.25, 0), (0, 0, 0))
    u = _joint(stage, j + "universal", UsdPhysics.Joint, r + "base", r + "cross", (-0.5, 0, 0), (0, 0, 0))
    _lock(u, "transX", "transY", "transZ", "rotX")
    c = _joint(stage, j + "cylinder", UsdPhysics.Joint, r + "cross", r + "tube", (0, 0, -0.5), (0, 0, 0),
               rot0=(0.70710678, 0, 0.70710678, 0), rot1=(0.70710678, 0, 0.70710678, 0))  # fmt: skip
    _lock(c, "transY", "transZ", "rotY", "rotZ")
    p = _joint(stage, j + "planar", UsdPhysics.Joint, r + "base", r + "plate", (0, -0.5, 0), (0, 0, 0))
    _lock(p, "transX", "rotY", "rotZ")
    line = _joint(stage, j + "line", UsdPhysics.Joint, r + "base", r + "free", (0, 0, 0.5), (0, 0, 0))
    _lock(line, "transY", "transZ")
    ang = _joint(stage, j + "angle", UsdPhysics.Joint, r + "base", r + "free", (0, 0, 0.5), (0, 0, 0))
    _lock(ang, "rotX")
    UsdPhysics.Joint(ang).CreateExcludeFromArticulationAttr(True)
    stage.Save()


# ---------------------------------------------------------------------------------------------- helpers
def simulate(scene: usd.UsdScene, out: str, frames: int, **writer_args) -> tuple[np.ndarray, np.ndarray]:
    """Run the real simulator and export; returns the simulator's (F, N, 3) positions and orientations."""
    from warpimpulse import Simulator

    sim = Simulator(scene.builder.finalize("cpu"), DT, tolerance=TOL)
    xs, qs = [], []
    with usd.AnimationWriter(out, scene, FPS, {"dt": DT, "tolerance": TOL, "solver": "auto"}, **writer_args) as w:

        class Tap:  # records what the writer was given
            dt = DT

            def step(self, n=1):
                sim.step(n)

            def positions(self):
                xs.append(sim.positions())
                return xs[-1]

            def orientations(self):
                qs.append(sim.orientations())
                return qs[-1]

        run.record_frames(Tap(), w, frames / FPS, progress=False)
    return np.array(xs), np.array(qs)


READER = textwrap.dedent(
    """
    import json, sys
    import numpy as np
    from pxr import Usd, UsdGeom, UsdPhysics
    from warpimpulse import usd
    path, out = sys.argv[1], sys.argv[2]
    anim = usd.read_animation(path)
    stage = Usd.Stage.Open(path)
    mpu = UsdGeom.GetStageMetersPerUnit(stage)
    gaps = {}
    for prim in stage.Traverse():
        if not prim.IsA(UsdPhysics.Joint):
            continue
        worst = 0.0
        for t in anim.time_codes:
            cache = UsdGeom.XformCache(Usd.TimeCode(t))
            ends = []
            for side in (0, 1):
                local = np.array(prim.GetAttribute(f"physics:localPos{side}").Get(), dtype=float)
                targets = prim.GetRelationship(f"physics:body{side}").GetTargets()
                if targets:
                    m = np.array(cache.GetLocalToWorldTransform(stage.GetPrimAtPath(targets[0])))
                    ends.append((np.append(local, 1.0) @ m)[:3] * mpu)
                else:
                    ends.append(local * mpu)
            worst = max(worst, float(np.linalg.norm(ends[0] - ends[1])))
        gaps[str(prim.GetPath())] = worst
    np.savez(out, times=anim.time_codes, x=anim.positions, q=anim.orientations)
    print(json.dumps({"paths": anim.body_paths, "gaps": gaps, "errors": usd.validate(path),
                      "sublayers": list(stage.GetRootLayer().subLayerPaths),
                      "complete": bool(stage.GetRootLayer().customLayerData["warpimpulse:complete"])}))
    """
)


def read_in_fresh_process(path: str, tmp_path) -> tuple[dict, dict]:
    npz = str(tmp_path / f"{os.path.basename(path)}.npz")
    proc = subprocess.run(
        [sys.executable, "-c", READER, path, npz], capture_output=True, text=True, cwd=ROOT, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1]), dict(np.load(npz))


def quat_close(a: np.ndarray, b: np.ndarray) -> float:
    """Largest rotation difference measure, sign-insensitive (q and -q are one rotation)."""
    return float(np.max(1.0 - np.abs(np.sum(a * b, axis=-1))))


# ---------------------------------------------------------------------------------------------- import
@pytest.fixture(scope="module")
def mechanism(tmp_path_factory) -> str:
    path = str(tmp_path_factory.mktemp("usd") / "mechanism.usda")
    author_mechanism(path)
    return path


def test_load_mechanism_maps_every_joint_type(mechanism):
    scene = usd.load_stage(mechanism)
    b = scene.builder
    kinds = {j.name.rsplit("/", 1)[-1]: j.kind for j in b.joints}
    assert kinds == {
        "hinge": "revolute", "slide": "prismatic", "sphere": "ball", "weld": "fixed", "universal": "universal",
        "cylinder": "cylindrical", "planar": "planar", "line": "line", "angle": "angle",
    }  # fmt: skip
    assert scene.loop_joints == ["/World/Rig/joints/angle"]
    names = [body.name for body in b.bodies]
    assert [n.rsplit("/", 1)[-1] for n in names] == ["base", "slider", "ball", "welded", "cross", "tube",
                                                      "plate", "free"]  # fmt: skip
    np.testing.assert_allclose(b.gravity, [0, 0, -9.81], rtol=1e-6)
    base = b.bodies[names.index("/World/Rig/base")]
    rig_q = np.array([0, 0, np.sin(np.radians(15)), np.cos(np.radians(15))])
    np.testing.assert_allclose(base.orientation, rig_q, atol=1e-12)
    # centre of mass: rig origin + R(30 deg) * (scale 2 * (0.0625, 0, 0))
    np.testing.assert_allclose(base.position, [0.5 + 0.125 * np.cos(np.radians(30)), 0.125 * 0.5, 1.0], atol=1e-12)
    assert base.mass == 2.0
    axes = np.array(Gf.Matrix3d(Gf.Rotation(Gf.Quatd(0.9238795, 0, 0.3826834, 0))).GetTranspose())  # columns
    np.testing.assert_allclose(base.inertia, axes @ np.diag([0.5, 0.25, 0.375]) @ axes.T, atol=1e-6)
    slider = b.bodies[names.index("/World/Rig/slider")]
    assert slider.mass == pytest.approx(800.0 * 0.5**3, rel=1e-6)  # cube of edge 0.25, scaled by 2
    np.testing.assert_allclose(slider.inertia, np.eye(3) * slider.mass * 0.5**2 / 6.0, rtol=1e-5, atol=1e-9)
    hinge = b.joints[[j.name for j in b.joints].index("/World/Rig/joints/hinge")]
    assert hinge.parent == -1
    np.testing.assert_allclose(hinge.anchor, [0.5, 0.0, 1.0], atol=1e-7)
    np.testing.assert_allclose(hinge.axis, [-np.sin(np.radians(30)), np.cos(np.radians(30)), 0], atol=1e-7)


def test_units_are_converted(tmp_path):
    path = str(tmp_path / "cm.usda")
    stage = Usd.Stage.CreateNew(path)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    UsdGeom.SetStageUpAxis(stage, "Y")
    UsdPhysics.SetStageKilogramsPerUnit(stage, 0.001)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/W").GetPrim())
    UsdPhysics.Scene.Define(stage, "/W/scene")  # gravity defaults: 981 cm/s^2 down the up axis
    prim = _body(stage, "/W/b", (100.0, 0.0, 0.0), mass=1000.0, inertia=(1e7, 1e7, 1e7))
    UsdPhysics.RigidBodyAPI(prim).CreateVelocityAttr(Gf.Vec3f(0, 50, 0))
    UsdPhysics.RigidBodyAPI(prim).CreateAngularVelocityAttr(Gf.Vec3f(0, 0, 180))
    _joint(stage, "/W/j", UsdPhysics.SphericalJoint, None, "/W/b", (0, 0, 0), (-100, 0, 0))
    stage.Save()
    b = usd.load_stage(path).builder
    body = b.bodies[0]
    assert body.mass == pytest.approx(1.0)
    np.testing.assert_allclose(np.diag(body.inertia), 1.0, rtol=1e-6)  # 1e7 g cm^2 = 1 kg m^2
    np.testing.assert_allclose(body.position, [1, 0, 0])
    np.testing.assert_allclose(body.linear_velocity, [0, 0.5, 0], rtol=1e-6)
    np.testing.assert_allclose(body.angular_velocity, [0, 0, np.pi], rtol=1e-6)
    np.testing.assert_allclose(b.gravity, [0, -9.81, 0], rtol=1e-5)  # Y up: down is -y
    np.testing.assert_allclose(b.joints[0].anchor, 0.0, atol=1e-9)


# ---------------------------------------------------------------------------------------------- round trip
@pytest.mark.parametrize("flatten", [False, True])
def test_round_trip_through_a_fresh_process(mechanism, tmp_path, flatten):
    scene = usd.load_stage(mechanism)
    out = str(tmp_path / ("flat.usd" if flatten else "anim.usd"))
    xs, qs = simulate(scene, out, frames=10, flatten=flatten)
    assert len(xs) == 11
    info, data = read_in_fresh_process(out, tmp_path)
    assert info["errors"] == []
    assert info["complete"]
    assert info["paths"] == scene.body_paths
    # The output keeps the input's time codes per second (24 where it authors none), so frame f at 50 fps is
    # time code 24 f / 50: time codes mean the same instant in the output and the input's layer stack.
    np.testing.assert_allclose(data["times"], np.arange(11) * 24.0 / FPS, rtol=0, atol=1e-12)
    assert np.abs(data["x"] - xs).max() < 1e-12
    assert quat_close(data["q"], qs) < 1e-12  # orientations are written as quatd
    assert np.abs(xs[-1] - xs[0]).max() > 1e-3  # something moved
    point_joints = ["hinge", "sphere", "weld", "universal"]
    for name in point_joints:
        assert info["gaps"][f"/World/Rig/joints/{name}"] < 2 * TOL, (name, info["gaps"])
    if flatten:
        assert info["sublayers"] == []  # self-contained
    else:
        assert info["sublayers"] == ["../usd0/mechanism.usda"]  # relative to the output's folder


def test_output_layer_is_small_and_keeps_the_input(mechanism, tmp_path):
    scene = usd.load_stage(mechanism)
    out = str(tmp_path / "anim.usda")
    with usd.AnimationWriter(out, scene, 24.0, {"dt": 0.01}) as w:
        x = np.array([b.position for b in scene.builder.bodies])
        q = np.array([b.orientation for b in scene.builder.bodies])
        w.write_frame(0, x, q)
        w.write_frame(1, x + 0.25, q)
    layer = Sdf.Layer.FindOrOpen(out)
    assert list(layer.subLayerPaths) == ["../usd0/mechanism.usda"]
    assert layer.timeCodesPerSecond == layer.framesPerSecond == 24.0
    assert (layer.startTimeCode, layer.endTimeCode) == (0.0, 1.0)
    assert layer.customLayerData["warpimpulse:dt"] == 0.01
    for path in scene.body_paths:
        spec = layer.GetPrimAtPath(path)
        assert spec.specifier == Sdf.SpecifierOver
        assert spec.attributes["xformOpOrder"].default[0].startswith("xformOp:translate")
    stage = Usd.Stage.Open(out)
    assert UsdGeom.GetStageUpAxis(stage) == "Z" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    anim = usd.read_animation(out, scene)
    np.testing.assert_allclose(anim.positions[1], x + 0.25, atol=1e-12)


def test_procedural_export_is_a_physics_scene(tmp_path):
    b = mechanism_builder()
    out = str(tmp_path / "proc.usda")
    x0 = np.array([body.position for body in b.bodies])
    q0 = np.array([body.orientation for body in b.bodies])
    with usd.AnimationWriter(out, b, 30.0, {"dt": 1e-3}) as w:
        for f in range(3):
            w.write_frame(f, x0 + [0.0, 0.0, 0.125 * f], q0)
    assert usd.validate(out) == []
    back = usd.load_stage(out)
    assert [j.kind for j in back.builder.joints] == ["revolute", "ball", "fixed", "prismatic", "cylindrical",
                                                     "universal", "planar", "line", "angle"]  # fmt: skip
    for orig, new in zip(b.joints, back.builder.joints):
        np.testing.assert_allclose(new.anchor, orig.anchor, atol=1e-6)
        if orig.axis is not None:
            np.testing.assert_allclose(new.axis, orig.axis, atol=1e-6)
        if orig.axis_child is not None:
            np.testing.assert_allclose(new.axis_child, orig.axis_child, atol=1e-6)
    for orig, new in zip(b.bodies, back.builder.bodies):
        np.testing.assert_allclose(new.position, orig.position, atol=1e-12)  # default = frame 0, double
        np.testing.assert_allclose(new.inertia, orig.inertia, rtol=1e-5, atol=1e-7 * np.abs(orig.inertia).max())
        assert new.mass == pytest.approx(orig.mass, rel=1e-6)
    assert len(back.builder.forces) == 1 and back.builder.forces[0].until == 0.5
    assert back.loop_joints == ["/World/Joints/angle"]  # line + angle on one pair: the second closes a loop
    layer = Sdf.Layer.FindOrOpen(out)
    root = layer.pseudoRoot
    assert (root.GetInfo("upAxis"), root.GetInfo("metersPerUnit"), root.GetInfo("kilogramsPerUnit")) == ("Z", 1.0, 1.0)
    assert layer.timeCodesPerSecond == layer.framesPerSecond == 30.0
    assert (layer.startTimeCode, layer.endTimeCode) == (0.0, 2.0)
    data = layer.customLayerData
    assert data["warpimpulse:dt"] == 1e-3 and data["warpimpulse:mode"] == "procedural" and data["warpimpulse:version"]
    anim = usd.read_animation(out)
    np.testing.assert_allclose(anim.positions[2], x0 + [0, 0, 0.25], atol=1e-12)
    stage = Usd.Stage.Open(out)
    assert stage.GetPrimAtPath("/World/base/geom").GetTypeName() == "Capsule"
    assert stage.GetPrimAtPath("/World/box/geom").GetTypeName() == "Cube"


def mechanism_builder() -> SceneBuilder:
    """Every builder joint type and basic constraint on a procedural scene."""
    b = SceneBuilder()
    cap = Shape("capsule", radius=0.05, length=0.4, color=(0.8, 0.2, 0.2))
    base = b.add_body(1.0, cap.inertia(1.0), (0, 0, 0), (0, 0.3826834, 0, 0.9238795), name="base", shape=cap)
    box = Shape("box", size=(0.2, 0.1, 0.3))
    bx = b.add_body(2.0, box.inertia(2.0), (0.5, 0, 0), name="box", shape=box)
    sph = Shape("sphere", radius=0.1)
    s = b.add_body(1.0, sph.inertia(1.0), (0, 0.5, 0), name="sphere", shape=sph)
    cyl = Shape("cylinder", radius=0.05, length=0.2)
    c = b.add_body(1.0, cyl.inertia(1.0), (0, 0.75, 0), name="cyl", shape=cyl)
    others = [b.add_body(1.0, [0.01, 0.01, 0.01], (-0.5 * i, 0, -0.5), name=f"o{i}") for i in range(1, 5)]
    b.add_joint_revolute(None, base, (0, 0, 0.25), (0, 1, 0), name="hinge")
    b.add_joint_ball(base, s, (0, 0.25, 0), name="ball")
    b.add_joint_fixed(s, c, (0, 0.625, 0), name="weld")
    b.add_joint_prismatic(base, bx, (0.25, 0, 0), (1, 0, 0), name="slide")
    b.add_joint_cylindrical(base, others[0], (-0.25, 0, -0.25), (0.6, 0, 0.8), name="cyl")
    b.add_joint_universal(others[0], others[1], (-0.75, 0, -0.5), (0, 1, 0), (0, 0, 1), name="u")
    b.add_joint_planar(others[1], others[2], (-1.25, 0, -0.5), (0, 0, 1), name="planar")
    b.add_constraint("line", others[2], others[3], (-1.75, 0, -0.5), (1, 0, 0), name="line")
    b.add_constraint("angle", others[2], others[3], (-1.75, 0, -0.5), (0, 1, 0), (0, 0.6, 0.8), name="angle")
    b.add_force(base, torque=(0, 0, 1.0), until=0.5)
    return b


def test_a_model_rebuilds_the_builder_it_came_from():
    """A model keeps no builder; builder_from_model (what wi.usd.record writes from) finalizes to the same
    arrays: every joint type and basic constraint, a static body, a force."""
    b = mechanism_builder()
    post = b.add_static_body((0, 0, 2), name="post")
    b.add_joint_ball(post, "box", (0.5, 0, 1), name="tether")
    model = b.finalize("cpu")
    again = builder_from_model(model).finalize("cpu")
    assert (again.body_name, again.joint_name, again.joint_type) == (
        model.body_name,
        model.joint_name,
        model.joint_type,
    )
    for name, value in vars(model.host).items():
        np.testing.assert_allclose(getattr(again.host, name), value, rtol=0, atol=1e-12, err_msg=name)


def test_procedural_round_trip_with_simulator(tmp_path):
    b = scenes.chain(4)
    out = str(tmp_path / "chain.usdc")
    xs, qs = simulate(usd.scene_from_builder(b), out, frames=5)
    info, data = read_in_fresh_process(out, tmp_path)
    assert info["errors"] == []
    assert np.abs(data["x"] - xs).max() < 1e-12
    assert quat_close(data["q"], qs) < 1e-12
    assert max(info["gaps"].values()) < 2 * TOL


def test_instancer_mode(tmp_path):
    b = scenes.binary_tree(15)
    out = str(tmp_path / "inst.usd")
    x0 = np.array([body.position for body in b.bodies])
    q0 = np.array([body.orientation for body in b.bodies])
    with usd.AnimationWriter(out, b, 30.0, instancer=True) as w:
        assert w.instancer
        for f in range(4):
            w.write_frame(f, x0 + 0.1 * f, q0)
    assert usd.validate(out) == []
    anim = usd.read_animation(out)
    assert anim.positions.shape == (4, 15, 3)
    np.testing.assert_allclose(anim.positions[3], x0 + 0.3, rtol=1e-6, atol=1e-6)
    assert quat_close(anim.orientations[3], q0) < 1e-3  # half precision
    stage = Usd.Stage.Open(out)
    protos = UsdGeom.PointInstancer(stage.GetPrimAtPath("/World/Instancer")).GetPrototypesRel().GetTargets()
    assert len(protos) == 4  # one per tree level


def test_auto_instancer_threshold():
    big = SceneBuilder()
    for i in range(usd.INSTANCER_AUTO_BODIES + 1):
        big.add_body(1.0, [1, 1, 1], (i, 0, 0), name=f"b{i}")
    w = usd.AnimationWriter("/nonexistent/never_written.usd", big, 30.0)
    assert w.instancer
    w.discard()


# ---------------------------------------------------------------------------------------------- safety
def test_interrupt_keeps_frames_done_so_far(tmp_path):
    b = scenes.chain(3)
    out = tmp_path / "partial.usda"
    x0 = np.array([body.position for body in b.bodies])
    q0 = np.array([body.orientation for body in b.bodies])
    with pytest.raises(KeyboardInterrupt):
        with usd.AnimationWriter(str(out), b, 30.0) as w:
            for f in range(100):
                if f == 3:
                    raise KeyboardInterrupt
                w.write_frame(f, x0, q0)
    assert os.listdir(tmp_path) == ["partial.usda"]  # no temporary file left behind
    layer = Sdf.Layer.FindOrOpen(str(out))
    assert layer.customLayerData["warpimpulse:complete"] is False
    assert layer.customLayerData["warpimpulse:stoppedEarly"] == "interrupted (SIGINT)"
    assert layer.endTimeCode == 2.0
    assert len(usd.read_animation(str(out)).time_codes) == 3
    assert usd.validate(str(out)) == []


def test_failed_write_leaves_old_file(tmp_path, monkeypatch):
    out = tmp_path / "keep.usda"
    out.write_text("#usda 1.0\n")
    w = usd.AnimationWriter(str(out), scenes.chain(2), 30.0)

    def boom(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError):
        w.close()
    assert out.read_text() == "#usda 1.0\n"
    assert os.listdir(tmp_path) == ["keep.usda"]


def test_frames_cross_chunk_boundaries(tmp_path, monkeypatch):
    monkeypatch.setattr(writer, "CHUNK_FRAMES", 3)  # 8 frames: chunks of 3, 3 and 2
    b = scenes.chain(3)
    x0 = np.array([body.position for body in b.bodies])
    q0 = np.array([body.orientation for body in b.bodies])
    out = str(tmp_path / "chunks.usdc")
    with usd.AnimationWriter(out, b, 30.0) as w:
        assert w.chunk_frames == 3
        for f in range(8):
            w.write_frame(f, x0 + [0.0, 0.0, 0.1 * f], q0)
    anim = usd.read_animation(out)
    np.testing.assert_array_equal(anim.time_codes, np.arange(8))
    np.testing.assert_array_equal(anim.positions - x0, [[[0.0, 0.0, 0.1 * f]] * 3 for f in range(8)])


def test_progress_bar(capsys):
    class Still:
        dt = 0.1

        def step(self, n=1):
            pass

        def positions(self):
            return np.zeros((1, 3))

        def orientations(self):
            return np.array([[0.0, 0.0, 0.0, 1.0]])

    b = SceneBuilder()
    b.add_body(1.0, [1, 1, 1], (0, 0, 0))
    for progress in (True, None):  # None: only on a terminal, and stderr is not one under pytest
        w = usd.AnimationWriter("/nonexistent/never_written.usd", b, 10.0)
        assert run.record_frames(Still(), w, 1.0, progress=progress) == 11
        w.discard()
        err = capsys.readouterr().err
        assert ("[" + "#" * 30 + "] 10/10 frames" in err and err.endswith("\n")) if progress else err == ""


def test_frames_and_steps():
    assert run.frame_steps(1e-3, 50.0) == 20
    assert run.frame_steps(1.0 / 300.0, 30.0) == 10
    with pytest.raises(ValueError, match="not a whole multiple"):
        run.frame_steps(0.003, 30.0)


def test_record_writes_duration_times_fps_plus_one_frames(tmp_path):
    class Still:
        dt = 1.0 / 300.0
        steps = 0

        def __init__(self, b):
            self.x = np.array([body.position for body in b.bodies])
            self.q = np.array([body.orientation for body in b.bodies])

        def step(self, n=1):
            self.steps += n

        def positions(self):
            return self.x

        def orientations(self):
            return self.q

    b = scenes.chain(2)
    sim = Still(b)
    with usd.AnimationWriter(str(tmp_path / "r.usda"), b, 30.0) as w:
        assert run.record_frames(sim, w, 1.0, progress=False) == 31
    assert sim.steps == 300
    assert Sdf.Layer.FindOrOpen(str(tmp_path / "r.usda")).endTimeCode == 30.0


def test_record_from_python(tmp_path):
    """wi.usd.record: the file holds duration * fps + 1 time samples on every moving body, each the pose the
    simulator had at that frame, and the simulator's settings."""
    import warpimpulse as wi

    dt, fps = 1.0 / 120.0, 30.0
    sim = wi.Simulator(wi.scenes.chain(3).finalize("cpu"), dt)
    twin = wi.Simulator(wi.scenes.chain(3).finalize("cpu"), dt)  # stepped by hand, frame by frame
    out = tmp_path / "out" / "chain.usdc"  # the folder does not exist yet
    rec = wi.usd.record(sim, out, duration=0.5, fps=fps)
    assert (rec.path, rec.frames, rec.fps, rec.steps) == (str(out), 16, fps, 60)
    stage = Usd.Stage.Open(str(out))
    for prim in stage.Traverse():
        if prim.HasAPI(UsdPhysics.RigidBodyAPI):
            assert UsdGeom.Xformable(prim).GetTimeSamples() == [float(f) for f in range(16)], prim.GetPath()
    data = stage.GetRootLayer().customLayerData
    assert (data["warpimpulse:dt"], data["warpimpulse:tolerance"], data["warpimpulse:complete"]) == (dt, 1e-6, True)
    anim = wi.usd.read_animation(out)
    assert anim.time_codes.tolist() == list(range(16))
    for f in range(16):
        if f:
            twin.step(4)  # a frame a call, as the recorder steps
            twin.energy()  # which the recorder reads each frame, correcting the velocities (`Simulator.state`)
        np.testing.assert_allclose(anim.positions[f], twin.positions(), rtol=0, atol=1e-12)
        dots = np.abs(np.einsum("ij,ij->i", anim.orientations[f], twin.orientations()))  # q and -q: one rotation
        np.testing.assert_allclose(dots, 1.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(anim.positions[-1], sim.positions(), rtol=0, atol=1e-12)
    assert [j.kind for j in wi.usd.load_stage(out).builder.joints] == ["revolute"] * 3  # a scene, joints and all
    with pytest.raises(ValueError, match="not a whole multiple"):
        wi.usd.record(sim, tmp_path / "bad.usdc", duration=0.1, fps=7.0)
    assert not (tmp_path / "bad.usdc").exists()


# ---------------------------------------------------------------------------------------------- bad input
def _bad_stage(tmp_path, name, build) -> str:
    path = str(tmp_path / f"{name}.usda")
    stage = Usd.Stage.CreateNew(path)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/W").GetPrim())
    UsdPhysics.Scene.Define(stage, "/W/scene")
    _body(stage, "/W/a", (0, 0, 0), mass=1.0, inertia=(1, 1, 1))
    build(stage)
    stage.Save()
    return path


NAN, INF = float("nan"), float("inf")
F, F3, Q = Sdf.ValueTypeNames.Float, Sdf.ValueTypeNames.Float3, Sdf.ValueTypeNames.Quatf


def _author(path, name, value, type_name=F):
    """A build step: set attribute `name` of prim `path`, creating it if the prim lacks it."""

    def build(stage):
        prim = stage.GetPrimAtPath(path)
        (prim.GetAttribute(name) or prim.CreateAttribute(name, type_name)).Set(value)

    return build


def _hinge(name, value, type_name=F):
    """A build step: a revolute joint /W/j from the world to /W/a, with attribute `name` set to `value`."""

    def build(stage):
        _joint(stage, "/W/j", UsdPhysics.RevoluteJoint, None, "/W/a", (0, 0, 0), (0, 0, 0), axis="X")
        _author("/W/j", name, value, type_name)(stage)

    return build


def _d6_nan_limit(stage):
    j = _joint(stage, "/W/j", UsdPhysics.Joint, None, "/W/a", (0, 0, 0), (0, 0, 0))
    _lock(j, "transX", "transY", "transZ")
    UsdPhysics.LimitAPI.Apply(j, "rotX").CreateHighAttr(NAN)


def _nan_matrix_parent(stage):
    UsdGeom.Xform.Define(stage, "/W/m").AddTransformOp().Set(Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(NAN, 0, 0)))
    _body(stage, "/W/m/b", (1, 0, 0), mass=1.0, inertia=(1, 1, 1))


def _cube_size(size):
    def build(stage):
        _body(stage, "/W/c", (1, 0, 0), density=1.0, shape="cube")
        stage.GetPrimAtPath("/W/c/geom").GetAttribute("size").Set(size)

    return build


BAD = {
    "missing_target": (
        lambda s: _joint(s, "/W/j", UsdPhysics.RevoluteJoint, "/W/nothing", "/W/a", (0, 0, 0), (0, 0, 0)),
        ["/W/j", "/W/nothing", "does not exist"],
    ),
    "no_mass_no_shapes": (lambda s: _body(s, "/W/empty", (1, 0, 0)), ["/W/empty", "neither a mass"]),
    "bad_inertia": (lambda s: _body(s, "/W/neg", (1, 0, 0), mass=1.0, inertia=(1, -1, 1)), ["/W/neg", "inertia"]),
    "flat_inertia": (
        lambda s: _body(s, "/W/flat", (1, 0, 0), mass=1.0, inertia=(1, 1, 3)),
        ["/W/flat", "principal moments", "triangle inequality"],
    ),
    "both_empty": (
        lambda s: _joint(s, "/W/j", UsdPhysics.SphericalJoint, None, None, (0, 0, 0), (0, 0, 0)),
        ["/W/j", "both"],
    ),
    "unsupported_feature": (
        lambda s: UsdPhysics.Joint(
            _joint(s, "/W/weak", UsdPhysics.FixedJoint, None, "/W/a", (0, 0, 0), (0, 0, 0))
        ).CreateBreakForceAttr(100.0),
        ["/W/weak", "break force", "not simulated", "--ignore-unsupported"],
    ),
    "non_uniform_parent": (
        lambda s: (
            UsdGeom.Xform.Define(s, "/W/squash").AddScaleOp().Set(Gf.Vec3f(1, 2, 1)),
            _body(s, "/W/squash/b", (1, 0, 0), mass=1.0, inertia=(1, 1, 1)),
        ),
        ["/W/squash/b", "non-uniformly scaled parent", "[1.0, 2.0, 1.0]", "bake the scale"],
    ),
    # Zero and non-finite values, each named with its prim and attribute (not silently read as something else,
    # nor reported as another attribute's fault after numpy RuntimeWarnings).
    "orient_zero": (
        _author("/W/a", "xformOp:orient", Gf.Quatf(0, 0, 0, 0)),
        ["/W/a", "xformOp:orient", "zero quaternion"],
    ),
    "orient_nan": (_author("/W/a", "xformOp:orient", Gf.Quatf(NAN, 0, 0, 0)), ["/W/a", "xformOp:orient", "not finite"]),
    "translate_nan": (_author("/W/a", "xformOp:translate", Gf.Vec3d(NAN, 0, 0)), ["/W/a", "xformOp:translate"]),
    "scale_inf": (
        lambda s: UsdGeom.Xformable(s.GetPrimAtPath("/W/a")).AddScaleOp().Set(Gf.Vec3f(INF, 1, 1)),
        ["/W/a", "xformOp:scale", "not finite"],
    ),
    "parent_matrix_nan": (_nan_matrix_parent, ["/W/m", "xformOp:transform", "not finite"]),
    "density_nan": (_author("/W/a", "physics:density", NAN), ["/W/a", "physics:density"]),
    "center_of_mass_nan": (
        _author("/W/a", "physics:centerOfMass", Gf.Vec3f(NAN, 0, 0), F3),
        ["/W/a", "physics:centerOfMass", "not finite"],
    ),
    "center_of_mass_inf": (
        _author("/W/a", "physics:centerOfMass", Gf.Vec3f(INF, 0, 0), F3),
        ["/W/a", "physics:centerOfMass", "not finite"],
    ),
    "principal_axes_nan": (
        _author("/W/a", "physics:principalAxes", Gf.Quatf(NAN, 0, 0, 0)),
        ["/W/a", "physics:principalAxes", "not finite"],
    ),
    "principal_axes_inf": (
        _author("/W/a", "physics:principalAxes", Gf.Quatf(INF, 0, 0, 0)),
        ["/W/a", "physics:principalAxes", "not finite"],
    ),
    "velocity_inf": (
        _author("/W/a", "physics:velocity", Gf.Vec3f(INF, 0, 0), F3),
        ["/W/a", "physics:velocity", "not finite"],
    ),
    "angular_velocity_inf": (
        _author("/W/a", "physics:angularVelocity", Gf.Vec3f(INF, 0, 0), F3),
        ["/W/a", "physics:angularVelocity", "not finite"],
    ),
    "local_pos1_inf": (_hinge("physics:localPos1", Gf.Vec3f(INF, 0, 0), F3), ["/W/j", "physics:localPos1"]),
    "local_rot0_nan": (_hinge("physics:localRot0", Gf.Quatf(NAN, 0, 0, 0), Q), ["/W/j", "physics:localRot0"]),
    "local_rot1_zero": (
        _hinge("physics:localRot1", Gf.Quatf(0, 0, 0, 0), Q),
        ["/W/j", "physics:localRot1", "zero quaternion"],
    ),
    "axis_token": (_hinge("physics:axis", "W"), ["/W/j", "physics:axis", "X, Y or Z", "'W'"]),
    "lower_limit_nan": (_hinge("physics:lowerLimit", NAN), ["/W/j", "physics:lowerLimit", "not finite"]),
    "d6_limit_nan": (_d6_nan_limit, ["/W/j", "limit:rotX:physics:high", "not finite"]),
    "gravity_inf": (_author("/W/scene", "physics:gravityMagnitude", INF), ["/W/scene", "physics:gravityMagnitude"]),
    "meters_per_unit_zero": (lambda s: UsdGeom.SetStageMetersPerUnit(s, 0.0), ["metersPerUnit", "positive"]),
    "kilograms_per_unit_zero": (
        lambda s: UsdPhysics.SetStageKilogramsPerUnit(s, 0.0),
        ["kilogramsPerUnit", "positive"],
    ),
    "cube_size_nan": (_cube_size(NAN), ["/W/c/geom", "size", "not finite"]),
    "cube_size_negative": (_cube_size(-1.0), ["/W/c/geom", "size", "negative"]),
    "mass_zero_no_shapes": (
        lambda s: _body(s, "/W/zero", (1, 0, 0), mass=0.0, inertia=(1, 1, 1)),
        ["/W/zero", "physics:mass = 0", "collision shapes"],
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_names_the_prim(tmp_path, case):
    build, words = BAD[case]
    path = _bad_stage(tmp_path, case, build)
    with pytest.raises(SceneError) as info, warnings.catch_warnings():
        warnings.simplefilter("error")  # the error alone: no numpy RuntimeWarning on the way to it
        usd.load_stage(path)
    for word in words:
        assert word in str(info.value), (case, str(info.value))


@pytest.mark.parametrize("case", ["orient_zero", "translate_nan", "angular_velocity_inf", "local_rot1_zero"])
def test_cli_reports_bad_input_in_one_line(tmp_path, capsys, case):
    build, words = BAD[case]
    path = _bad_stage(tmp_path, case, build)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        code = cli_main(["simulate", path, "--duration", "0.1", "--out", str(tmp_path / "out.usda")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "Traceback" not in err[0], err
    assert all(word in err[0] for word in words), err


def test_joint_to_a_disabled_body_attaches_to_it_as_static(tmp_path):
    """The parser leaves a body with physics:rigidBodyEnabled = false out of a joint's body0; it is a
    static body here, and the joint holds the other body to it (not 'not a rigid body')."""

    def build(s):
        UsdPhysics.RigidBodyAPI(s.GetPrimAtPath("/W/a")).CreateRigidBodyEnabledAttr(False)
        _body(s, "/W/b", (1, 0, 0), mass=1.0, inertia=(1, 1, 1))
        _joint(s, "/W/j", UsdPhysics.RevoluteJoint, "/W/a", "/W/b", (0.5, 0, 0), (-0.5, 0, 0), axis="Y")

    scene = usd.load_stage(_bad_stage(tmp_path, "disabled", build))
    (joint,) = scene.builder.joints
    assert scene.builder.bodies[joint.parent].name == "/W/a" and scene.builder.bodies[joint.parent].static
    assert scene.builder.bodies[joint.child].name == "/W/b"


@pytest.mark.parametrize("content", [b"this is not a scene\n", b"\x00\x01PXR-USDC garbage", b""])
def test_not_usd_is_a_clear_error(tmp_path, content):
    path = tmp_path / "scene.usd"
    path.write_bytes(content)
    with pytest.raises(usd.UsdSceneError, match="scene.usd"):
        usd.load_stage(str(path))
    with pytest.raises(usd.UsdSceneError, match="no such file"):
        usd.load_stage(str(tmp_path / "missing.usda"))


def _with_drive(s):
    """A drive toward a position and a velocity at once (a PID servo has one target)."""
    j = _joint(s, "/W/j", UsdPhysics.RevoluteJoint, None, "/W/a", (0, 0, 0), (0, 0, 0))
    drive = UsdPhysics.DriveAPI.Apply(j, "angular")
    drive.CreateStiffnessAttr(10.0)
    drive.CreateTargetVelocityAttr(5.0)


def _with_limit(s):
    """A spherical joint's cone limit (limits are on one coordinate)."""
    j = _joint(s, "/W/j", UsdPhysics.SphericalJoint, None, "/W/a", (0, 0, 0), (0, 0, 0))
    UsdPhysics.SphericalJoint(j).CreateConeAngle0LimitAttr(30.0)
    UsdPhysics.SphericalJoint(j).CreateConeAngle1LimitAttr(30.0)


def _with_d6_limit(s):
    j = _joint(s, "/W/j", UsdPhysics.Joint, None, "/W/a", (0, 0, 0), (0, 0, 0))
    _lock(j, "transX", "transY", "transZ")
    limit = UsdPhysics.LimitAPI.Apply(j, "rotX")
    limit.CreateLowAttr(-30.0)
    limit.CreateHighAttr(30.0)


def _with_distance_limit(s):
    j = _joint(s, "/W/j", UsdPhysics.Joint, None, "/W/a", (0, 0, 0), (0, 0, 0))  # dropped with a warning
    limit = UsdPhysics.LimitAPI.Apply(j, "distance")
    limit.CreateLowAttr(0.0)
    limit.CreateHighAttr(1.0)
    _joint(s, "/W/ball", UsdPhysics.SphericalJoint, None, "/W/a", (0, 0, 0), (0, 0, 0))  # kept


@pytest.mark.parametrize(
    "build,word",
    [(_with_drive, "drive"), (_with_limit, "limit"), (_with_d6_limit, "rotX"),
     (_with_distance_limit, "Distance limit")],
)  # fmt: skip
def test_unsupported_features_error_or_warn(tmp_path, build, word):
    path = _bad_stage(tmp_path, word, build)
    with pytest.raises(usd.UnsupportedFeatureError, match=f"/W/j: .*{word}"):
        usd.load_stage(path)
    with pytest.warns(UserWarning, match=f"/W/j: .*{word}"):
        scene = usd.load_stage(path, ignore_unsupported=True)
    assert len(scene.builder.joints) == 1
    out = tmp_path / "out.usda"  # and the command line runs it, with a warning on stderr
    assert cli_main(["simulate", path, "--duration", "0.1", "--out", str(out), "--ignore-unsupported"]) == 0
    assert usd.validate(str(out)) == []


# ---------------------------------------------------------------------------------------------- mechanisms
def _driven_stage(tmp_path, build) -> str:
    """Two bodies: /W/a on a revolute joint about z to the world (body1 empty: the world on the child side
    swaps the joint, so the coordinate's sign flips), /W/b on a prismatic joint along x to /W/a."""

    def both(s):
        UsdGeom.SetStageMetersPerUnit(s, 1.0)  # SI here; the units' conversion is the reader's, tested above
        _body(s, "/W/b", (1, 0, 0), mass=2.0, inertia=(1, 1, 1))
        hinge = _joint(s, "/W/hinge", UsdPhysics.RevoluteJoint, "/W/a", None, (0, 0, 0), (0, 0, 0), axis="Z")
        slide = _joint(s, "/W/slide", UsdPhysics.PrismaticJoint, "/W/a", "/W/b", (1, 0, 0), (0, 0, 0), axis="X")
        build(s, hinge, slide)

    return _bad_stage(tmp_path, "driven", both)


def test_usd_limits_and_drives_become_limits_motors_and_joint_springs(tmp_path):
    """Angular values in degrees (gains per degree), linear ones in metres; a drive with a stiffness is a
    position motor, one without a velocity motor; warpimpulse's extras mark a joint spring, a stiff motor, ki."""

    def build(s, hinge, slide):
        UsdPhysics.RevoluteJoint(hinge).CreateLowerLimitAttr(-30.0)
        UsdPhysics.RevoluteJoint(hinge).CreateUpperLimitAttr(45.0)
        drive = UsdPhysics.DriveAPI.Apply(hinge, "angular")
        drive.CreateStiffnessAttr(2.0)
        drive.CreateDampingAttr(0.5)
        drive.CreateTargetPositionAttr(20.0)
        drive.CreateMaxForceAttr(7.0)
        hinge.CreateAttribute("warpimpulse:drive:ki", Sdf.ValueTypeNames.Double, custom=True).Set(0.25)
        UsdPhysics.PrismaticJoint(slide).CreateLowerLimitAttr(-0.2)
        UsdPhysics.PrismaticJoint(slide).CreateUpperLimitAttr(0.3)
        drive = UsdPhysics.DriveAPI.Apply(slide, "linear")
        drive.CreateDampingAttr(40.0)
        drive.CreateTargetVelocityAttr(0.1)
        slide.CreateAttribute("warpimpulse:drive:stiff", Sdf.ValueTypeNames.Bool, custom=True).Set(True)

    b = usd.load_stage(_driven_stage(tmp_path, build)).builder
    per_degree = 180.0 / math.pi
    (hinge_limit, slide_limit) = b.limits
    np.testing.assert_allclose([hinge_limit.lower, hinge_limit.upper], np.radians([-45.0, 30.0]), rtol=1e-6)
    np.testing.assert_allclose([slide_limit.lower, slide_limit.upper], [-0.2, 0.3], rtol=1e-6)
    hinge, slide = b.drives
    assert hinge.motor and not hinge.stiff and hinge.mode == 0 and hinge.max_force == pytest.approx(7.0)
    np.testing.assert_allclose(
        [hinge.target, hinge.kp, hinge.ki, hinge.kd],
        [-math.radians(20.0), 2.0 * per_degree, 0.25 * per_degree, 0.5 * per_degree],
        rtol=1e-6,
    )
    assert slide.motor and slide.stiff and slide.mode == 1 and slide.target == pytest.approx(0.1)
    assert slide.kp == pytest.approx(40.0) and slide.max_force == math.inf


def test_usd_drive_tracking_position_and_velocity_is_refused_naming_the_joint(tmp_path):
    def build(s, hinge, slide):
        drive = UsdPhysics.DriveAPI.Apply(slide, "linear")
        drive.CreateStiffnessAttr(10.0)
        drive.CreateTargetVelocityAttr(1.0)

    with pytest.raises(usd.UsdSceneError, match="/W/slide: a drive with a stiffness and a targetVelocity"):
        usd.load_stage(_driven_stage(tmp_path, build))


def test_usd_exclude_from_articulation_picks_the_loop_joint(tmp_path):
    """The four-bar written with its loop joint marked reads back with that joint closing the loop."""
    for loop in ("A", "D"):
        b = scenes.four_bar()
        b.mark_loop_joint(loop)
        path = str(tmp_path / f"four_bar_{loop}.usda")
        usd.save_scene(b, path)
        model = usd.load_stage(path).builder.finalize()
        assert [model.joint_name[j].rsplit("/", 1)[1] for j in model.topology.loop_joints] == [loop]


@pytest.mark.parametrize("name", ["four_bar", "car", "walking_machine"])
def test_mechanism_scenes_round_trip_and_run_from_their_files(tmp_path, name, capsys):
    """scenes/NAME.usda (scenes/make_scenes.py) holds the scene's drives, limits and loops and runs with
    `warpimpulse simulate`; the Python scene written again reads back with the same mechanisms."""
    builder = getattr(scenes, name)()
    path = os.path.join(ROOT, "scenes", f"{name}.usda")
    again = usd.load_stage(path).builder
    key = lambda d: (d.joint, d.motor)  # noqa: E731
    for d0, d1 in zip(sorted(builder.drives, key=key), sorted(again.drives, key=key), strict=True):
        assert (d0.joint, d0.mode, d0.motor, d0.stiff) == (d1.joint, d1.mode, d1.motor, d1.stiff)
        np.testing.assert_allclose([d0.target, d0.kp, d0.ki, d0.kd], [d1.target, d1.kp, d1.ki, d1.kd], rtol=1e-6)
    assert len(again.limits) == len(builder.limits)
    out = tmp_path / "out.usdc"
    assert cli_main(["simulate", path, "--duration", "0.5", "--out", str(out)]) == 0


# ---------------------------------------------------------------------------------------------- command line
def test_cli_refuses_a_dt_that_does_not_divide_the_frame_time(tmp_path, capsys):
    out = tmp_path / "x.usda"
    assert cli_main(["simulate", "--scene", "chain", "--fps", "30", "--dt", "0.003", "--out", str(out)]) == 2
    assert "not a whole multiple" in capsys.readouterr().err
    assert not out.exists()


def test_cli_ctrl_c_keeps_a_valid_file_with_the_frames_done(tmp_path, monkeypatch, capsys):
    from warpimpulse import simulator

    real_step, calls = simulator.Simulator.step, []

    def step(self, n=1):
        calls.append(1)
        if len(calls) == 5:  # the steps to frame 5 (one call a frame)
            raise KeyboardInterrupt
        return real_step(self, n)

    monkeypatch.setattr(simulator.Simulator, "step", step)
    out = tmp_path / "stopped.usdc"
    argv = ["simulate", "--scene", "chain", "--duration", "10", "--out", str(out)]
    assert cli_main(argv) == 130
    assert "interrupted" in capsys.readouterr().err
    assert os.listdir(tmp_path) == ["stopped.usdc"]
    layer = Sdf.Layer.FindOrOpen(str(out))
    assert layer.customLayerData["warpimpulse:stoppedEarly"] == "interrupted (SIGINT)"
    assert usd.read_animation(str(out)).time_codes.tolist() == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert usd.validate(str(out)) == []


# ---------------------------------------------------------------------------------------------- scenes/
SCENE_FILES = sorted(glob.glob(os.path.join(ROOT, "scenes", "*.usda")))


def test_scene_files_exist():
    names = {os.path.basename(p) for p in SCENE_FILES}
    assert {"tree31.usda", "tree127.usda", "tree255.usda", "star127.usda", "chain.usda", "mechanism.usda"} <= names


@pytest.mark.parametrize("path", SCENE_FILES, ids=os.path.basename)
def test_scene_files_load_and_validate(path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = usd.load_stage(path)
    assert scene.builder.bodies and (scene.builder.joints or scene.builder.grounds)  # something holds them
    assert usd.validate(path) == []
    name = os.path.splitext(os.path.basename(path))[0]
    if name in scenes.SCENES:
        ref = scenes.SCENES[name]()
        assert len(ref.bodies) == len(scene.builder.bodies)
        assert [j.kind for j in ref.joints] == [j.kind for j in scene.builder.joints]
        assert len(ref.forces) == len(scene.builder.forces)


@pytest.mark.parametrize("path", SCENE_FILES, ids=os.path.basename)
def test_scene_files_run_with_the_cli(path, tmp_path):
    out = tmp_path / "out.usda"
    assert cli_main(["simulate", path, "--duration", "0.1", "--out", str(out)]) == 0
    layer = Sdf.Layer.FindOrOpen(str(out))
    # 0.1 s at the file's 60 time codes per second (save_scene's default), one frame a time code
    assert (layer.startTimeCode, layer.endTimeCode, layer.timeCodesPerSecond) == (0.0, 6.0, 60.0)
    assert layer.customLayerData["warpimpulse:complete"] is True
    assert layer.customLayerData["warpimpulse:dt"] == (usd.load_stage(path).dt or 1.0 / 60.0)  # the file's, if any
    assert usd.validate(str(out)) == []


def test_a_scene_file_may_record_its_step_size(tmp_path, capsys):
    path = tmp_path / "chain.usda"
    usd.save_scene(scenes.chain(2), path, dt=0.005)
    assert usd.load_stage(path).dt == 0.005
    assert usd.load_stage(os.path.join(ROOT, "scenes", "tree31.usda")).dt is None
    out = str(tmp_path / "o.usda")
    assert cli_main(["simulate", str(path), "--duration", "0.1", "--out", out, "--fps", "30"]) == 2  # 1/30 / 0.005
    assert "warpimpulse:dt; pass --dt" in capsys.readouterr().err
    assert cli_main(["simulate", str(path), "--duration", "0.1", "--out", out, "--fps", "40"]) == 0
    assert Sdf.Layer.FindOrOpen(out).customLayerData["warpimpulse:dt"] == 0.005
    layer = Sdf.Layer.FindOrOpen(str(path))
    layer.customLayerData = dict(layer.customLayerData) | {"warpimpulse:dt": -1.0}
    layer.Save()
    with pytest.raises(usd.UsdSceneError, match="chain.usda: customLayerData warpimpulse:dt must be a positive"):
        usd.load_stage(path)


def test_static_bodies_are_not_sampled_and_signs_stay_continuous(tmp_path):
    b = SceneBuilder()
    post = b.add_static_body((0, 0, 1), name="post", shape=Shape("box", size=(0.1, 0.1, 0.1)))
    arm = b.add_body(1.0, [0.1, 0.1, 0.1], (0.5, 0, 1), name="arm")
    b.add_joint_revolute(post, arm, (0, 0, 1), (0, 1, 0), name="hinge")
    out = str(tmp_path / "static.usda")
    x = np.array([body.position for body in b.bodies])
    q = np.array([body.orientation for body in b.bodies])
    with usd.AnimationWriter(out, b, 30.0) as w:
        for f in range(4):
            w.write_frame(f, x, q * (-1.0) ** f)  # the simulator may hand over -q: the file must not flip
    layer = Sdf.Layer.FindOrOpen(out)
    assert layer.GetNumTimeSamplesForPath("/World/post.xformOp:translate") == 0
    samples = [layer.QueryTimeSample("/World/arm.xformOp:orient", t) for t in range(4)]
    assert len({(s.GetReal(), *s.GetImaginary()) for s in samples}) == 1
    back = usd.load_stage(out)
    assert back.builder.bodies[0].static and not back.builder.bodies[1].static
    assert usd.validate(out) == []


def test_a_model_with_mechanisms_is_rebuilt_whole():
    """wi.usd.record(sim) writes the model: builder_from_model brings back its drives, limits, springs and
    loop marks, so the rebuilt scene finalizes to the same mechanism arrays."""
    b = scenes.car()
    b.add_joint_limit(1, -0.05, 0.05)
    b.add_spring(None, 0, (0.0, 0.0, 2.0), (0.0, 0.0, 0.8), 10.0, 1.0)
    b.mark_loop_joint(0)
    model = b.finalize()
    again = builder_from_model(model).finalize()
    for name in ("drive_joint", "drive_mode", "drive_target", "drive_gains", "drive_max_force", "drive_motor",
                 "drive_stiff", "limit_joint", "limit_bounds", "limit_drive", "spring_body0", "spring_body1",
                 "spring_anchor0", "spring_anchor1", "spring_params", "joint_loop"):  # fmt: skip
        np.testing.assert_allclose(getattr(again.host, name), getattr(model.host, name), atol=1e-12, err_msg=name)
