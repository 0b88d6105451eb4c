"""UsdPhysics scenes as their authors mean them, modelled on OpenUSD's own examples (pxr/usd/usdPhysics/examples):
each scene is run with the plain `warpimpulse simulate FILE` and its motion checked against what it describes.

Joints that target a prim that is no rigid body attach to the world at that prim's transform (a static collider,
the default prim); a target inside a body stands for the body; the stage's time range and rate set the run;
colliders that do not collide give one warning that the output records; drives and limits of one-DOF joints (D6
included) are motors and limits; distance joints are distance constraints (rows of the same correction loop).
"""

from __future__ import annotations

import os
import textwrap
import warnings

import numpy as np
import pytest
from numpy_checks import momenta, sim_state

pytest.importorskip("pxr")
from pxr import Sdf  # noqa: E402

from warpimpulse import usd  # noqa: E402
from warpimpulse.cli import main as cli_main  # noqa: E402

G = 9.81


def load(path: str) -> usd.UsdScene:
    """The scene, quietly: the reader's warnings are checked where they matter, as the CLI prints them."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return usd.load_stage(path, ignore_unsupported=True)


def write(
    tmp_path, name: str, body: str, meta: str = 'defaultPrim = "World"\n    metersPerUnit = 1\n    upAxis = "Z"'
) -> str:
    """A usda file `name` in tmp_path: the layer metadata `meta`, then `body`."""
    path = tmp_path / name
    path.write_text(f"#usda 1.0\n(\n    {meta}\n)\n" + textwrap.dedent(body))
    return str(path)


def simulate(path: str, tmp_path, capsys, *flags: str) -> tuple[usd.Animation, str, str, Sdf.Layer]:
    """`warpimpulse simulate path [flags]`, its output validated: the animation read back, stdout, stderr and the
    output layer."""
    out = str(tmp_path / f"out{len(list(tmp_path.glob('out*.usda')))}.usda")  # a new file: layers are cached
    code = cli_main(["simulate", path, "--out", out, *flags])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    # The output adds no validation error to the input's (e.g. an over of another value type on a float3 scale).
    assert set(usd.validate(out)) <= set(usd.validate(path))
    return usd.read_animation(out, load(path)), captured.out, captured.err, Sdf.Layer.FindOrOpen(out)


def warnings_of(err: str) -> list[str]:
    return [line for line in err.splitlines() if "warning:" in line]


# A 0.1 x 1 x 0.1 m bar, hinged about world X at its end: a compound pendulum, modelled on usdPhysicsJoints.usda
# (whose D6 joint's body0 is a static collider, not a rigid body).
BAR = """
    def Cube "Bar" (
        prepend apiSchemas = ["PhysicsRigidBodyAPI", "PhysicsMassAPI", "PhysicsCollisionAPI"]
    )
    {
        float physics:mass = 2
        double size = 1
        float3 xformOp:scale = (0.1, 1, 0.1)
        double3 xformOp:translate = (0.7, 1.2, 3)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
    }
"""


def test_a_joint_to_a_static_collider_holds_the_body_at_the_collider(tmp_path, capsys):
    """body0 is a static box (CollisionAPI, no RigidBodyAPI) translated, turned and scaled: the joint frame is
    the collider's, at its world transform, and the bar swings about it from horizontal."""
    path = write(
        tmp_path,
        "static.usda",
        f"""
        def Xform "World"
        {{
            def PhysicsScene "scene"
            {{
            }}
            def Cube "Wall" (
                prepend apiSchemas = ["PhysicsCollisionAPI"]
            )
            {{
                double size = 1
                float3 xformOp:scale = (0.2, 2, 0.2)
                quatf xformOp:orient = (0.70710678, 0, 0, 0.70710678)
                double3 xformOp:translate = (0.35, 0.7, 3)
                uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:orient", "xformOp:scale"]
            }}
            {BAR}
            def PhysicsRevoluteJoint "Hinge"
            {{
                rel physics:body0 = </World/Wall>
                rel physics:body1 = </World/Bar>
                uniform token physics:axis = "Y"
                point3f physics:localPos0 = (0, -0.175, 0)
                point3f physics:localPos1 = (0, -0.5, 0)
                quatf physics:localRot1 = (0.70710678, 0, 0, 0.70710678)
            }}
        }}
    """,
    )
    # The wall is turned 90 degrees about z, so its local -y (scaled by 2) is world +x: localPos0 is at
    # (0.35, 0.7, 3) + (0.35, 0, 0) = (0.7, 0.7, 3), the bar's end; the joint's Y axis is the wall's, world -x.
    scene = load(path)
    (joint,) = scene.builder.joints
    assert joint.parent == -1  # the world
    np.testing.assert_allclose(joint.anchor, [0.7, 0.7, 3.0], atol=1e-6)
    np.testing.assert_allclose(np.abs(joint.axis), [1.0, 0.0, 0.0], atol=1e-6)
    anim, _, err, _ = simulate(path, tmp_path, capsys, "--duration", "1", "--fps", "60")
    x = anim.positions[:, 0]
    arm = np.linalg.norm(x - [0.7, 0.7, 3.0], axis=1)
    np.testing.assert_allclose(arm, 0.5, atol=1e-5)  # the centre stays 0.5 m from the hinge: it holds
    assert np.all(np.abs(x[:, 0] - 0.7) < 1e-6)  # in the plane normal to the axis
    assert x[:, 2].min() < 3.0 - 0.45  # swung down through the bottom
    assert "not a rigid body" not in err


def test_a_fixed_joint_to_the_default_prim_holds_the_body_where_it_is(tmp_path, capsys):
    """Modelled on usdPhysicsNestedArticulation.usda: a fixed joint's body0 is the default prim, an Xform that is
    no rigid body, placed away from the origin: the body stays put under gravity, at the default prim's offset."""
    path = write(
        tmp_path,
        "fixed.usda",
        """
        def PhysicsScene "PhysicsScene"
        {
        }
        def Xform "Rig"
        {
            double3 xformOp:translate = (2, 0, 1)
            uniform token[] xformOpOrder = ["xformOp:translate"]
            def Cube "Body" (
                prepend apiSchemas = ["PhysicsRigidBodyAPI", "PhysicsCollisionAPI"]
            )
            {
                double size = 0.2
                double3 xformOp:translate = (0, 0.5, 1)
                uniform token[] xformOpOrder = ["xformOp:translate"]
                def PhysicsFixedJoint "Weld"
                {
                    rel physics:body0 = <../..>
                    rel physics:body1 = <..>
                    point3f physics:localPos0 = (0, 0.5, 1)
                    point3f physics:localPos1 = (0, 0, 0)
                }
            }
        }
    """,
        meta='defaultPrim = "Rig"\n    metersPerUnit = 1\n    upAxis = "Z"',
    )
    anim, _, err, _ = simulate(path, tmp_path, capsys, "--duration", "1", "--fps", "30")
    np.testing.assert_allclose(anim.positions[:, 0], np.tile([2.0, 0.5, 2.0], (31, 1)), atol=1e-6)
    assert warnings_of(err) == []  # its collider collides (with nothing here)


NESTED = """
    def PhysicsScene "PhysicsScene"
    {
    }
    def Xform "Arm"
    {
        def Xform "Base" (
            prepend apiSchemas = ["PhysicsRigidBodyAPI", "PhysicsMassAPI"]
        )
        {
            float physics:mass = 3
            float3 physics:diagonalInertia = (0.1, 0.1, 0.1)
            point3f physics:centerOfMass = (0, 0, 0)
            double3 xformOp:translate = (0, 0, 2)
            uniform token[] xformOpOrder = ["xformOp:translate"]
            def Cube "Knuckle" (
                prepend apiSchemas = ["PhysicsCollisionAPI"]
            )
            {
                double size = 0.1
                double3 xformOp:translate = (0, 0.3, 0)
                uniform token[] xformOpOrder = ["xformOp:translate"]
            }
            def Xform "Link" (
                prepend apiSchemas = ["PhysicsRigidBodyAPI", "PhysicsMassAPI"]
            )
            {
                float physics:mass = 1
                float3 physics:diagonalInertia = (0.02, 0.001, 0.02)
                double3 xformOp:translate = (0, 0.8, 0)
                uniform token[] xformOpOrder = ["xformOp:translate"]
                def PhysicsRevoluteJoint "Elbow"
                {
                    uniform token physics:axis = "X"
                    rel physics:body0 = <../../Knuckle>
                    rel physics:body1 = <..>
                    point3f physics:localPos0 = (0, 0, 0)
                    point3f physics:localPos1 = (0, -0.5, 0)
                }
            }
            def PhysicsFixedJoint "Mount"
            {
                rel physics:body0 = </Arm>
                rel physics:body1 = <..>
                point3f physics:localPos0 = (0, 0, 2)
            }
        }
    }
"""


def test_nested_bodies_and_a_target_inside_a_body(tmp_path, capsys):
    """A link nested in its base (its transform relative to the base), hinged to a collider inside the base: the
    target stands for the nearest enclosing rigid body, as in PhysX. The base is welded to the default prim; the
    link swings down about x through the knuckle at (0, 0.3, 2)."""
    path = write(tmp_path, "nested.usda", NESTED, meta='defaultPrim = "Arm"\n    metersPerUnit = 1\n    upAxis = "Z"')
    scene = load(path)
    names = [b.name for b in scene.builder.bodies]
    elbow = next(j for j in scene.builder.joints if j.name.endswith("Elbow"))
    assert names[elbow.parent] == "/Arm/Base" and names[elbow.child] == "/Arm/Base/Link"
    np.testing.assert_allclose(elbow.anchor, [0.0, 0.3, 2.0], atol=1e-9)
    anim, _, _, _ = simulate(path, tmp_path, capsys, "--duration", "1.5", "--fps", "40")
    base, link = anim.positions[:, names.index("/Arm/Base")], anim.positions[:, names.index("/Arm/Base/Link")]
    np.testing.assert_allclose(base, np.tile([0.0, 0.0, 2.0], (len(base), 1)), atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(link - [0.0, 0.3, 2.0], axis=1), 0.5, atol=1e-5)
    assert link[:, 2].min() < 2.0 - 0.45 and np.abs(link[:, 0]).max() < 1e-6
    # Energy: a rigid compound pendulum released from horizontal (I about the pivot 0.02 + 1 * 0.5^2 = 0.27)
    # passes the bottom at w^2 = 2 m g l / I.
    lowest = int(np.argmin(link[:, 2]))
    speed = np.linalg.norm(np.gradient(link, 1 / 40.0, axis=0)[lowest])
    assert speed == pytest.approx(0.5 * np.sqrt(2 * G * 0.5 / 0.27), rel=0.05)


def test_a_joint_between_two_prims_that_are_no_bodies_is_skipped_with_a_warning(tmp_path, capsys):
    path = write(
        tmp_path,
        "nobody.usda",
        """
        def Xform "World"
        {
            def Xform "A"
            {
            }
            def Xform "B"
            {
            }
            def Xform "Ball" (
                prepend apiSchemas = ["PhysicsRigidBodyAPI", "PhysicsMassAPI"]
            )
            {
                float physics:mass = 1
                float3 physics:diagonalInertia = (1, 1, 1)
            }
            def PhysicsFixedJoint "Pointless"
            {
                rel physics:body0 = </World/A>
                rel physics:body1 = </World/B>
            }
        }
    """,
    )
    anim, _, err, _ = simulate(path, tmp_path, capsys, "--duration", "0.5", "--fps", "10")
    assert any("/World/Pointless" in w and "skipped" in w for w in warnings_of(err)), err
    assert anim.positions[-1, 0, 2] == pytest.approx(-0.5 * G * 0.25, rel=1e-6)  # free fall


# ---------------------------------------------------------------------------------------------- timing
FALLING_CM = """
    def Xform "World"
    {
        def PhysicsScene "PhysicsScene"
        {
        }
        def Xform "Ball" (
            prepend apiSchemas = ["PhysicsRigidBodyAPI", "PhysicsMassAPI"]
        )
        {
            float physics:mass = 1
            float3 physics:diagonalInertia = (1e4, 1e4, 1e4)
            vector3f physics:velocity = (100, 0, 200)
            double3 xformOp:translate = (0, 0, 500)
            uniform token[] xformOpOrder = ["xformOp:translate"]
        }
    }
"""
CM_24 = 'defaultPrim = "World"\n    metersPerUnit = 0.01\n    upAxis = "Z"\n    timeCodesPerSecond = 24\n    '


def test_the_stage_sets_the_time_range_and_rate(tmp_path, capsys):
    """Modelled on usdPhysicsBoxOnBox.usda: time codes 0-100 at 24 per second, in centimetres. Without flags
    the run is those 100 / 24 s, one frame a time code, and the output keeps the rate."""
    path = write(tmp_path, "cm24.usda", FALLING_CM, meta=CM_24 + "startTimeCode = 0\n    endTimeCode = 100")
    anim, out, _, layer = simulate(path, tmp_path, capsys)
    assert "time codes 0-100 at 24 per second" in out and "24 fps" in out
    assert (layer.timeCodesPerSecond, layer.startTimeCode, layer.endTimeCode) == (24.0, 0.0, 100.0)
    np.testing.assert_array_equal(anim.time_codes, np.arange(101))
    t = anim.time_codes / 24.0
    g = -load(path).builder.gravity[2]  # 981 cm/s^2, parsed as a float
    assert g == pytest.approx(G, rel=1e-7)
    expected = np.column_stack([1.0 * t, 0 * t, 5.0 + 2.0 * t - 0.5 * g * t**2])  # m, from 100 cm/s etc.
    np.testing.assert_allclose(anim.positions[:, 0], expected, atol=1e-9)


def test_flags_override_the_stage_time_and_time_codes_keep_their_meaning(tmp_path, capsys):
    """--fps 48 on a 24 time codes per second stage starting at 10: frames every half time code from 10,
    and time code c is still t = (c - 10) / 24 s; --duration sets the end."""
    path = write(tmp_path, "cm24.usda", FALLING_CM, meta=CM_24 + "startTimeCode = 10\n    endTimeCode = 34")
    anim, out, _, layer = simulate(path, tmp_path, capsys, "--fps", "48")
    assert "time codes 10-34 at 24 per second" in out and "fps (the stage" not in out
    assert (layer.timeCodesPerSecond, layer.framesPerSecond) == (24.0, 48.0)
    np.testing.assert_allclose(anim.time_codes, 10.0 + 0.5 * np.arange(49))
    t = (anim.time_codes - 10.0) / 24.0
    np.testing.assert_allclose(anim.seconds, t)
    g = -load(path).builder.gravity[2]
    np.testing.assert_allclose(anim.positions[:, 0, 2], 5.0 + 2.0 * t - 0.5 * g * t**2, atol=1e-9)
    anim, out, _, layer = simulate(path, tmp_path, capsys, "--duration", "0.5", "--fps", "24")
    assert out.startswith("wrote")  # nothing chosen from the stage to report
    assert (layer.startTimeCode, layer.endTimeCode) == (10.0, 22.0)


# ---------------------------------------------------------------------------------------------- colliders
BOX_ON_BOX = """
    def Xform "World"
    {
        def PhysicsScene "PhysicsScene"
        {
        }
        def Cube "Crate" (
            prepend apiSchemas = ["PhysicsCollisionAPI", "PhysicsRigidBodyAPI"]
        )
        {
            double size = 0.5
            double3 xformOp:translate = (0, 0, 2)
            uniform token[] xformOpOrder = ["xformOp:translate"]
        }
        def Cube "Floor" (
            prepend apiSchemas = ["PhysicsCollisionAPI"]
        )
        {
            float3 xformOp:scale = (5, 5, 0.1)
            uniform token[] xformOpOrder = ["xformOp:scale"]
        }
    }
"""


def test_a_crate_falls_onto_a_static_box_and_rests_on_it(tmp_path, capsys):
    """OpenUSD's box-on-box: the floor is a Cube collider without a rigid body, scaled to 10 x 10 x 0.2 m (a
    Cube's size is 2 unless authored): a static body. The crate (0.5 m, its mass from its collider) lands on the
    floor's top at z = 0.1 and rests there, its centre at 0.35 m; nothing is ignored, nothing warned."""
    path = write(tmp_path, "box_on_box.usda", BOX_ON_BOX)
    anim, _, err, layer = simulate(path, tmp_path, capsys, "--duration", "2", "--fps", "10")
    assert not warnings_of(err)
    assert "warpimpulse:collidersIgnored" not in layer.customLayerData
    assert load(path).builder.bodies[0].mass == pytest.approx(125.0)  # 1000 kg/m^3
    assert anim.body_paths == ["/World/Crate", "/World/Floor"]
    np.testing.assert_allclose(anim.positions[-5:, 0], [[0.0, 0.0, 0.35]] * 5, atol=1e-3)  # the last 0.5 s
    np.testing.assert_allclose(anim.positions[:, 1], [[0.0, 0.0, 0.0]] * len(anim.time_codes), atol=1e-12)


def test_the_static_colliders_scene_runs_as_authored(tmp_path, capsys):
    """scenes/static_colliders.usda, written by hand as UsdPhysics authors static colliders (CollisionAPI, no
    RigidBodyAPI): a Cube pedestal, a Cube ramp turned 20 degrees and scaled flat, a Cylinder log along y, a
    ground Plane. Run by the plain command: the crate rests on the pedestal, the plank across the log, level;
    the ball bounces on the ramp, rolls down it and along the ground into the pedestal's side, never
    through anything."""
    path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scenes", "static_colliders.usda")
    anim, _, err, _ = simulate(path, tmp_path, capsys)
    assert not warnings_of(err) and anim.seconds[-1] == pytest.approx(3.0)
    crate, ball, plank = (anim.body_paths.index(f"/World/{name}") for name in ("Crate", "Ball", "Plank"))
    last = anim.seconds >= 2.0
    np.testing.assert_allclose(anim.positions[last, crate], [[0.1, 0.05, 0.7]] * last.sum(), atol=1e-3)
    np.testing.assert_allclose(anim.positions[last, plank], [[-2.0, 0.0, 0.45]] * last.sum(), atol=1e-3)
    np.testing.assert_allclose(np.abs(anim.orientations[-1, plank]), [0.0, np.sqrt(0.5), 0.0, np.sqrt(0.5)], atol=1e-3)
    x, z = anim.positions[:, ball, 0], anim.positions[:, ball, 2]
    # On the ramp (its top at 0.6 + 0.05 / cos 20deg + (x - 3) tan 20deg, the ball's centre 0.1 above it, along
    # its normal) and then on the ground.
    on_ramp = np.abs(x - 3.0) < 1.4
    top = 0.6 + (0.05 + 0.1) / np.cos(np.radians(20.0)) + (x - 3.0) * np.tan(np.radians(20.0))
    assert np.all(z[on_ramp] >= top[on_ramp] - 1e-3) and np.all(z >= 0.1 - 1e-3)
    assert np.any(np.diff(z[x > 3.0]) > 0.0)  # it bounced on the ramp
    assert x.min() >= 0.5 + 0.1 - 1e-3  # it rolls up to the pedestal's side (at x = 0.5) and back, not into it
    assert x.min() < 0.7 and x[-1] < 2.0 and z[-1] == pytest.approx(0.1, abs=1e-3)


def test_the_walking_machine_walks_in_its_scene_file(tmp_path, capsys):
    """scenes/walking_machine_on_ground.usda (`scenes.walking_machine(crank_speed=1, ground=True)` written by
    scenes/make_scenes.py) through the plain command for 2 s: the body moves along -x by at least 80% of what
    its feet sweep (`walker_stride`, m per radian of crank), straight and level; the redundant loop rows are
    noted only."""
    from test_contacts import walker_stride

    path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scenes",
                        "walking_machine_on_ground.usda")  # fmt: skip
    anim, _, err, _ = simulate(path, tmp_path, capsys, "--duration", "2")
    assert not warnings_of(err)
    body = next(i for i, p in enumerate(anim.body_paths) if p.endswith("/body"))
    moved = anim.positions[0, body] - anim.positions[-1, body]
    assert moved[0] >= 0.8 * walker_stride() * 2.0 and abs(moved[1]) < 0.01
    assert np.all(np.abs(anim.orientations[:, body, :2]) < np.sin(np.radians(0.5)))  # level: no roll or pitch


ROCK = """
        def Mesh "Rock" (
            prepend apiSchemas = ["PhysicsCollisionAPI"]
        )
        {
            int[] faceVertexCounts = [3, 3, 3, 3]
            int[] faceVertexIndices = [0, 1, 2, 0, 3, 1, 0, 2, 3, 1, 3, 2]
            point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
            float3[] extent = [(0, 0, 0), (1, 1, 1)]
        }
    }
"""


def test_a_mesh_collider_is_refused_or_with_the_flag_one_warning_recorded_in_the_output(tmp_path, capsys):
    """warpimpulse collides no mesh: a Mesh collider is refused in one line naming the prim (exit 2);
    --ignore-unsupported runs without it, saying so once, naming the count and the mesh with why, and the output's
    layer data records it."""
    path = write(tmp_path, "rock.usda", BOX_ON_BOX.rstrip()[:-1] + ROCK)
    assert cli_main(["simulate", path, "--out", str(tmp_path / "o.usda"), "--duration", "0.1"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "/World/Rock: a Mesh collider" in line and "not simulated" in line
    _, _, err, layer = simulate(path, tmp_path, capsys, "--duration", "0.2", "--fps", "10", "--ignore-unsupported")
    (warning,) = warnings_of(err)
    assert "1 collider does not collide (/World/Rock: a Mesh collider" in warning
    assert layer.customLayerData["warpimpulse:collidersIgnored"] == 1
    assert list(layer.customLayerData["warpimpulse:warnings"]) == [warning.split("warning: ", 1)[1]]


def test_a_prim_of_an_unknown_type_with_physics_properties_is_named(tmp_path, capsys):
    """OpenUSD's distance joint example spells its joint `DistancePhysicsJoint`, a type no schema defines: USD
    ignores the prim, so the run says so, with the likely meant type."""
    path = write(
        tmp_path,
        "typo.usda",
        """
        def Xform "World"
        {
            def Xform "Ball" (
                prepend apiSchemas = ["PhysicsRigidBodyAPI", "PhysicsMassAPI"]
            )
            {
                float physics:mass = 1
                float3 physics:diagonalInertia = (1, 1, 1)
            }
            def DistancePhysicsJoint "Rope"
            {
                rel physics:body1 = </World/Ball>
                float physics:maxDistance = 1
            }
        }
    """,
    )
    _, _, err, layer = simulate(path, tmp_path, capsys, "--duration", "0.1", "--fps", "10")
    (warning,) = warnings_of(err)
    assert (
        "/World/Rope" in warning
        and "DistancePhysicsJoint" in warning
        and "did you mean PhysicsDistanceJoint" in warning
    )
    assert "warpimpulse:collidersIgnored" not in layer.customLayerData


M_FROM_10 = (
    'defaultPrim = "World"\n    metersPerUnit = 1\n    upAxis = "Z"\n    startTimeCode = 10\n    endTimeCode = 20'
)


def test_a_joint_target_is_where_it_is_at_the_stage_start(tmp_path, capsys):
    """A static collider animated in its layer: the joint attaches at its transform at startTimeCode (10), not
    at its default or first sample; the ball hangs from that point."""
    path = write(
        tmp_path,
        "animated.usda",
        """
        def Xform "World"
        {
            def Cube "Hook" (
                prepend apiSchemas = ["PhysicsCollisionAPI"]
            )
            {
                double size = 0.1
                double3 xformOp:translate = (9, 9, 9)
                double3 xformOp:translate.timeSamples = {
                    0: (0, 0, 0),
                    10: (1, 0, 2),
                    20: (5, 0, 2),
                }
                uniform token[] xformOpOrder = ["xformOp:translate"]
            }
            def Xform "Ball" (
                prepend apiSchemas = ["PhysicsRigidBodyAPI", "PhysicsMassAPI"]
            )
            {
                float physics:mass = 1
                float3 physics:diagonalInertia = (0.01, 0.01, 0.01)
                double3 xformOp:translate = (1, 0, 1.5)
                uniform token[] xformOpOrder = ["xformOp:translate"]
            }
            def PhysicsSphericalJoint "Rope"
            {
                rel physics:body0 = </World/Hook>
                rel physics:body1 = </World/Ball>
                point3f physics:localPos1 = (0, 0, 0.5)
            }
        }
    """,
        meta=M_FROM_10,
    )
    (joint,) = load(path).builder.joints
    np.testing.assert_allclose(joint.anchor, [1.0, 0.0, 2.0], atol=1e-12)
    anim, _, _, _ = simulate(path, tmp_path, capsys, "--duration", "0.5", "--fps", "20")
    np.testing.assert_allclose(anim.positions[:, 0], np.tile([1.0, 0.0, 1.5], (11, 1)), atol=1e-9)  # hangs still


SLIDER = """
    def Xform "World"
    {
        def Xform "Slider" (
            prepend apiSchemas = ["PhysicsRigidBodyAPI", "PhysicsMassAPI"]
        )
        {
            float physics:mass = 1
            float3 physics:diagonalInertia = (0.1, 0.1, 0.1)
            vector3f physics:velocity = (0.5, 0, 0)
            double3 xformOp:translate = (1, 0, 1)
            uniform token[] xformOpOrder = ["xformOp:translate"]
        }
        def PhysicsPrismaticJoint "Rail"
        {
            rel physics:body0 = </World>
            rel physics:body1 = </World/Slider>
            uniform token physics:axis = "X"
            point3f physics:localPos0 = POS0
        }
    }
"""


def test_a_prismatic_joint_may_start_apart_along_its_axis_not_across(tmp_path, capsys):
    """Frames 0.1 m apart along the rail are where the slider starts on it (it slides on, held up); 0.2 m apart
    across the rail is a joint that does not hold at the start: refused naming the joint and the gap."""
    path = write(tmp_path, "along.usda", SLIDER.replace("POS0", "(0.9, 0, 1)"))
    anim, _, _, _ = simulate(path, tmp_path, capsys, "--duration", "1", "--fps", "10")
    np.testing.assert_allclose(anim.positions[:, 0], np.column_stack([1.0 + 0.5 * anim.seconds, 0 * anim.seconds,
                                                                      1.0 + 0 * anim.seconds]), atol=1e-6)  # fmt: skip
    path = write(tmp_path, "across.usda", SLIDER.replace("POS0", "(0.9, 0.2, 1)"))
    assert cli_main(["simulate", path, "--out", str(tmp_path / "o.usda"), "--duration", "0.1"]) == 2
    assert "/World/Rail: its frames on body0 and body1" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------- drives, limits
def d6_scene(body0: str, body1: str, pos0, pos1) -> str:
    """Modelled on usdPhysicsJoints.usda (centimetres, 24 time codes per second): a D6 joint with every DOF
    locked but rotZ, which a velocity drive turns at 30 degrees a second, between a static collider (no rigid
    body) and a bar whose centre is 60 cm from the joint along y."""
    return f"""
        def Xform "World"
        {{
            def PhysicsScene "physicsScene"
            {{
            }}
            def Cube "StaticBox" (
                prepend apiSchemas = ["PhysicsCollisionAPI"]
            )
            {{
                double size = 100
                float3 xformOp:scale = (0.1, 1, 0.1)
                double3 xformOp:translate = (0, 0, 1000)
                uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
            }}
            def Cube "DynamicBox" (
                prepend apiSchemas = ["PhysicsCollisionAPI", "PhysicsRigidBodyAPI"]
            )
            {{
                double size = 100
                float3 xformOp:scale = (0.1, 1, 0.1)
                double3 xformOp:translate = (0, 120, 1000)
                uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
            }}
            def PhysicsJoint "D6Joint" (
                prepend apiSchemas = ["PhysicsLimitAPI:transX", "PhysicsLimitAPI:transY", "PhysicsLimitAPI:transZ",
                                      "PhysicsLimitAPI:rotX", "PhysicsLimitAPI:rotY", "PhysicsDriveAPI:rotZ"]
            )
            {{
                rel physics:body0 = <{body0}>
                rel physics:body1 = <{body1}>
                float limit:rotX:physics:high = -1
                float limit:rotX:physics:low = 1
                float limit:rotY:physics:high = -1
                float limit:rotY:physics:low = 1
                float limit:transX:physics:high = -1
                float limit:transX:physics:low = 1
                float limit:transY:physics:high = -1
                float limit:transY:physics:low = 1
                float limit:transZ:physics:high = -1
                float limit:transZ:physics:low = 1
                float drive:rotZ:physics:targetVelocity = 30
                float drive:rotZ:physics:damping = 1e4
                point3f physics:localPos0 = {pos0}
                point3f physics:localPos1 = {pos1}
            }}
        }}
    """


CM_24_RANGE = CM_24 + "startTimeCode = 0\n    endTimeCode = 48"


@pytest.mark.parametrize("dynamic_is_body1", [True, False])
def test_a_d6_velocity_drive_turns_the_joint_at_its_target_velocity(tmp_path, capsys, dynamic_is_body1):
    """The bar turns about the vertical through the joint at (0, 60, 1000) cm at 30 deg/s, its locked DOFs
    holding. The drive turns body1 against body0: with the static box as body1, the bar turns the other way."""
    if dynamic_is_body1:
        body = d6_scene("/World/StaticBox", "/World/DynamicBox", "(0, 60, 0)", "(0, -60, 0)")
    else:
        body = d6_scene("/World/DynamicBox", "/World/StaticBox", "(0, -60, 0)", "(0, 60, 0)")
    anim, _, err, _ = simulate(write(tmp_path, "d6.usda", body, meta=CM_24_RANGE), tmp_path, capsys)
    assert "drive" not in err and len(anim.time_codes) == 49  # 2 s, run plainly
    assert "energy" not in err  # the motor does work: no energy-gain warning
    x = anim.positions[:, 0] - [0.0, 0.6, 10.0]  # from the joint, m
    np.testing.assert_allclose(np.linalg.norm(x, axis=1), 0.6, atol=1e-6)
    np.testing.assert_allclose(x[:, 2], 0.0, atol=1e-6)
    turned = np.unwrap(np.arctan2(-x[:, 0], x[:, 1]))  # about +z, from +y
    sign = 1.0 if dynamic_is_body1 else -1.0
    np.testing.assert_allclose(turned, sign * np.radians(30.0) * anim.time_codes / 24.0, atol=1e-6)


def test_a_revolute_limit_in_degrees_stops_the_swing(tmp_path, capsys):
    """The nested arm's elbow limited to [-60, 10] degrees (as usdPhysicsNestedArticulation.usda limits its
    hinge): the link swings down from horizontal, stops at -60 degrees, and stays within the limit."""
    limited = NESTED.replace(
        "point3f physics:localPos1 = (0, -0.5, 0)",
        "point3f physics:localPos1 = (0, -0.5, 0)\n                    float physics:lowerLimit = -60\n"
        "                    float physics:upperLimit = 10",
    )
    path = write(tmp_path, "limited.usda", limited, meta='defaultPrim = "Arm"\n    metersPerUnit = 1\n    upAxis = "Z"')
    anim, _, err, _ = simulate(path, tmp_path, capsys, "--duration", "2", "--fps", "60")
    assert "limit" not in err
    link = anim.positions[:, [b.name for b in load(path).builder.bodies].index("/Arm/Base/Link")]
    angle = np.arctan2(link[:, 2] - 2.0, link[:, 1] - 0.3)  # about +x, from +y
    assert angle.min() > np.radians(-60.0) - 1e-5
    np.testing.assert_allclose(angle[-30:], np.radians(-60.0), atol=1e-4)  # resting on the limit
    np.testing.assert_allclose(np.linalg.norm(link - [0.0, 0.3, 2.0], axis=1), 0.5, atol=1e-5)


def test_a_prismatic_position_drive_is_a_spring_damper_to_its_target(tmp_path, capsys):
    """A 1 kg slider on a horizontal prismatic joint, its frames 0.1 m apart as authored (the joint's position
    is 0.1), driven to 0.3 by stiffness 100 N/m and damping 20 N s/m: critically damped,
    x(t) = 0.3 - 0.2 (1 + w t) exp(-w t) with w = 10 /s."""
    path = write(
        tmp_path,
        "slider.usda",
        """
        def Xform "World"
        {
            def PhysicsScene "scene"
            {
            }
            def Xform "Slider" (
                prepend apiSchemas = ["PhysicsRigidBodyAPI", "PhysicsMassAPI"]
            )
            {
                float physics:mass = 1
                float3 physics:diagonalInertia = (0.1, 0.1, 0.1)
                double3 xformOp:translate = (1, 0, 1)
                uniform token[] xformOpOrder = ["xformOp:translate"]
            }
            def PhysicsPrismaticJoint "Rail" (
                prepend apiSchemas = ["PhysicsDriveAPI:linear"]
            )
            {
                rel physics:body0 = </World>
                rel physics:body1 = </World/Slider>
                uniform token physics:axis = "X"
                point3f physics:localPos0 = (0.9, 0, 1)
                float drive:linear:physics:targetPosition = 0.3
                float drive:linear:physics:stiffness = 100
                float drive:linear:physics:damping = 20
            }
        }
    """,
    )
    anim, _, _, _ = simulate(path, tmp_path, capsys, "--duration", "1", "--fps", "120")
    t = anim.time_codes / 24.0  # the stage's rate: 24 time codes per second where it authors none
    x = anim.positions[:, 0, 0] - 0.9
    np.testing.assert_allclose(x, 0.3 - 0.2 * (1 + 10 * t) * np.exp(-10 * t), atol=1e-4)
    np.testing.assert_allclose(anim.positions[:, 0, 1:], np.tile([0.0, 1.0], (len(t), 1)), atol=1e-9)


def test_a_distance_joint_keeps_its_anchors_within_its_range(tmp_path, capsys):
    """Modelled on usdPhysicsDistanceJoint.usda (with the schema's type name, PhysicsDistanceJoint): a box hangs
    from a static box by a rope of 10-50 cm, released 30 cm to the side of the anchor: it falls until the rope
    is taut, then swings on it, the anchors never further apart than 50 cm."""
    path = write(
        tmp_path,
        "rope.usda",
        """
        def Xform "World"
        {
            def PhysicsScene "physicsScene"
            {
            }
            def Cube "StaticBox" (
                prepend apiSchemas = ["PhysicsCollisionAPI"]
            )
            {
                double size = 100
                float3 xformOp:scale = (0.1, 1, 0.1)
                double3 xformOp:translate = (0, 0, 1000)
                uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
            }
            def Cube "DynamicBox" (
                prepend apiSchemas = ["PhysicsCollisionAPI", "PhysicsRigidBodyAPI"]
            )
            {
                double size = 20
                double3 xformOp:translate = (30, 60, 1000)
                uniform token[] xformOpOrder = ["xformOp:translate"]
            }
            def PhysicsDistanceJoint "DistanceJoint"
            {
                rel physics:body0 = </World/StaticBox>
                rel physics:body1 = </World/DynamicBox>
                point3f physics:localPos0 = (0, 60, 0)
                point3f physics:localPos1 = (0, 0, 0)
                float physics:maxDistance = 50
                float physics:minDistance = 10
            }
        }
    """,
        meta=CM_24_RANGE,
    )
    anim, _, err, _ = simulate(path, tmp_path, capsys)
    assert "Distance" not in err
    x = anim.positions[:, 0]
    gap = np.linalg.norm(x - [0.0, 0.6, 10.0], axis=1)  # the box's centre is its anchor
    assert gap.max() < 0.5 + 1e-6 and gap.min() > 0.1 - 1e-6
    taut = np.flatnonzero(gap > 0.5 - 1e-6)
    assert taut.size > 10 and x[taut[0], 2] > 10.0 - 0.5  # taut while still above the lowest point ...
    assert x[:, 2].min() == pytest.approx(10.0 - 0.5, abs=1e-3)  # ... and swinging through it
    assert x[:, 0].min() < -0.1  # to the other side
    # As in OpenUSD's example, the anchors meeting at the start (inside minDistance) is said: the first step
    # pushes them 10 cm apart, which adds energy.
    path = write(tmp_path, "meet.usda", open(path).read().split(")\n", 1)[1].replace("(30, 60, 1000)", "(0, 60, 1000)"),
                 meta=CM_24_RANGE)  # fmt: skip
    anim, _, err, _ = simulate(path, tmp_path, capsys, "--duration", "0.5")
    assert "/World/DistanceJoint: its anchors start 0 apart, outside [10, 50]" in err
    assert np.linalg.norm(anim.positions[1:, 0] - [0.0, 0.6, 10.0], axis=1).min() > 0.1 - 1e-6


def test_distance_constraints_round_trip_through_a_scene_file(tmp_path):
    """save_scene writes a builder's distance constraints as PhysicsDistanceJoint prims, and so does a recording
    of the bare model (builder_from_model): both read back as the same constraint."""
    from warpimpulse import SceneBuilder, Simulator

    b = SceneBuilder()
    ball = b.add_body(2.0, np.eye(3) * 0.02, [0.3, 0.0, -0.2], name="ball")
    b.add_distance(None, ball, [0.0, 0.0, 0.5], [0.3, 0.0, -0.2], 0.25, 1.5, name="rope")
    usd.save_scene(b, tmp_path / "rope.usda")
    sim = Simulator(b.finalize("cpu"), 1 / 60)
    usd.record(sim, tmp_path / "model.usda", duration=0.1, fps=30)
    for name in ("rope.usda", "model.usda"):
        scene = load(str(tmp_path / name))
        (rope,) = scene.builder.distances
        assert (rope.body0, rope.body1, rope.lower, rope.upper) == (-1, 0, 0.25, 1.5)
        np.testing.assert_allclose(rope.anchor0, [0.0, 0.0, 0.5], atol=1e-7)
        np.testing.assert_allclose(rope.anchor1, 0.0, atol=1e-7)
        assert scene.distance_paths == ["/World/Joints/rope"]


@pytest.mark.parametrize("solver", ["auto", "cg"])
def test_a_distance_constraint_holds_with_the_joints_of_a_chain(solver):
    """A three-link hinged chain released horizontal, its tip tied by a 0.6 m rope to a point under the chain:
    the rope holds (push-only rows in the joints' correction loop) while the joints do."""
    from warpimpulse import SceneBuilder, Simulator
    from warpimpulse.transforms import quat_rotate

    b = SceneBuilder()
    link = None
    for k in range(3):
        body = b.add_body(1.0, np.diag([0.01, 0.1, 0.1]), [0.25 + 0.5 * k, 0.0, 0.0], name=f"link{k}")
        b.add_joint_revolute(link, body, [0.5 * k, 0.0, 0.0], [0.0, 1.0, 0.0])
        link = body
    b.add_distance(None, link, [1.0, 0.0, -0.3], [1.5, 0.0, 0.0], 0.0, 0.6, name="rope")
    sim = Simulator(b.finalize("cpu"), 1 / 120, solver=solver)
    gaps = []
    for _ in range(240):
        assert sim.step().max_joint_error < 1e-6
        tip = sim.positions()[2] + quat_rotate(sim.orientations()[2], np.array([0.25, 0.0, 0.0]))
        gaps.append(np.linalg.norm(tip - [1.0, 0.0, -0.3]))
    assert max(gaps) < 0.6 + 2e-6 and sum(g > 0.6 - 1e-6 for g in gaps) > 10  # taut, and held


def test_a_rope_between_free_bodies_keeps_momentum():
    """Two free bodies flying apart on a 1 m rope, no gravity: the rope's impulses are equal and opposite along
    one line, so linear and angular momentum stay what they were when it snaps taut."""
    from warpimpulse import SceneBuilder, Simulator
    from warpimpulse.transforms import quat_rotate

    b = SceneBuilder(gravity=(0.0, 0.0, 0.0))
    inertia = np.diag([0.02, 0.03, 0.04])
    a = b.add_body(2.0, inertia, [0.0, 0.0, 0.0], linear_velocity=[-0.5, 0.2, 0.0], name="a")
    c = b.add_body(1.0, inertia, [0.5, 0.0, 0.0], linear_velocity=[1.0, 0.0, 0.3], angular_velocity=[0, 0, 2], name="c")
    b.add_distance(a, c, [0.1, 0.0, 0.0], [0.4, 0.0, 0.0], 0.0, 1.0, name="rope")
    sim = Simulator(b.finalize("cpu"), 1 / 200)
    p0, l0 = momenta(b, *sim_state(sim))
    gaps = []
    for _ in range(400):
        sim.step()
        x, q = sim.positions(), sim.orientations()
        ends = x + quat_rotate(q, np.array([[0.1, 0.0, 0.0], [-0.1, 0.0, 0.0]]))  # anchors in the bodies
        gaps.append(np.linalg.norm(ends[1] - ends[0]))
    p1, l1 = momenta(b, *sim_state(sim))
    np.testing.assert_allclose(p1, p0, atol=1e-9)
    np.testing.assert_allclose(l1, l0, atol=1e-6)
    assert max(gaps) < 1.0 + 1e-6 and gaps[-1] > 1.0 - 1e-6  # the rope went taut and holds them


def test_a_joint_that_starts_outside_its_limits_is_refused_in_its_own_units(tmp_path, capsys):
    limited = NESTED.replace(
        "point3f physics:localPos1 = (0, -0.5, 0)",
        "point3f physics:localPos1 = (0, -0.5, 0)\n                    float physics:lowerLimit = 20\n"
        "                    float physics:upperLimit = 30",
    )
    path = write(tmp_path, "outside.usda", limited, meta='defaultPrim = "Arm"\n    metersPerUnit = 1\n    upAxis = "Z"')
    assert cli_main(["simulate", path, "--out", str(tmp_path / "o.usda"), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert "/Arm/Base/Link/Elbow: the joint starts at 0 degrees, outside its limits [20.0, 30.0]" in err


def test_distance_constraints_are_not_replicated_yet():
    """Batched worlds take no limit rows yet: a scene with a distance constraint is refused by replicate, and a
    replicated scene takes none (not dropped without a word)."""
    from warpimpulse import SceneBuilder, SceneError

    b = SceneBuilder()
    ball = b.add_body(1.0, [0.01, 0.01, 0.01], [0.0, 0.0, -0.5], name="ball")
    b.add_joint_ball(None, ball, [0.0, 0.0, 0.0])
    plain = b.replicate(2)
    b.add_distance(None, ball, [0.0, 0.0, 0.0], [0.0, 0.0, -0.5], 0.0, 1.0, name="rope")
    with pytest.raises(SceneError, match="1 distance constraints; batched worlds do not take"):
        b.replicate(2)
    with pytest.raises(SceneError, match="distance 'rope': a replicated scene takes no additions"):
        plain.add_distance(None, 0, [0.0, 0.0, 0.0], [0.0, 0.0, -0.5], 0.0, 1.0, name="rope")


def test_collision_groups_are_refused_by_default_and_dropped_with_a_warning(tmp_path, capsys):
    """Modelled on usdPhysicsGroupFiltering.usda: a PhysicsCollisionGroup filtering its boxes from each other is
    not simulated (they would collide): refused naming the group; --ignore-unsupported warns and runs."""
    path = write(
        tmp_path,
        "groups.usda",
        BOX_ON_BOX.replace(
            '''        def Cube "Floor"''',
            '''        def PhysicsCollisionGroup "Group" (
            prepend apiSchemas = ["CollectionAPI:colliders"]
        )
        {
            prepend rel collection:colliders:includes = [</World/Crate>]
            prepend rel physics:filteredGroups = [</World/Group>]
        }
        def Cube "Floor"''',
        ),
    )
    assert cli_main(["simulate", path, "--out", str(tmp_path / "o.usda"), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert "/World/Group: collision-group filtering (a PhysicsCollisionGroup) is not simulated" in err
    _, _, err, _ = simulate(path, tmp_path, capsys, "--duration", "0.1", "--ignore-unsupported")
    assert any("/World/Group: collision-group filtering" in w and "ignored" in w for w in warnings_of(err))
