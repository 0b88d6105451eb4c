"""UsdPhysics scenes as their authors mean them, modelled on OpenUSD's own examples (pxr/usd/usdPhysics/examples):
each scene is run with the plain `warpimpulse simulate FILE` and its motion checked against what it describes.

Joints that target a prim that is no rigid body attach to the world at that prim's transform (a static collider,
the default prim); a target inside a body stands for the body; the stage's time range and rate set the run;
colliders, not simulated yet, give one warning that the output records.
"""

from __future__ import annotations

import textwrap
import warnings

import numpy as np
import pytest

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
    assert len(warnings_of(err)) == 1 and "1 collider is ignored (/Rig/Body)" in err


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


def test_colliders_on_a_ground_box_give_one_warning_recorded_in_the_output(tmp_path, capsys):
    """Contacts are not simulated yet: the crate falls through the floor, and the run says so once, naming the
    count and the floor; the output's layer data records it. The crate's collider still gives its mass."""
    path = write(tmp_path, "box_on_box.usda", BOX_ON_BOX)
    anim, _, err, layer = simulate(path, tmp_path, capsys, "--duration", "1", "--fps", "10")
    (warning,) = warnings_of(err)
    assert "2 colliders are ignored (e.g. /World/Floor)" in warning and "contacts" in warning
    assert layer.customLayerData["warpimpulse:collidersIgnored"] == 2
    assert list(layer.customLayerData["warpimpulse:warnings"]) == [warning.split("warning: ", 1)[1]]
    assert load(path).builder.bodies[0].mass == pytest.approx(125.0)  # 1000 kg/m^3
    np.testing.assert_allclose(anim.positions[-1, 0], [0.0, 0.0, 2.0 - 0.5 * G], atol=1e-9)


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
