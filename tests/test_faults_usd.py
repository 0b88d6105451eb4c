"""Issue 14, scene files: input that would be read wrong is refused with one line naming the prim or file."""

from __future__ import annotations

import pytest
from cli_helpers import assert_one_line_error, run

from warpimpulse import usd

SCENE = """#usda 1.0
(
    metersPerUnit = 1
    upAxis = "{up}"
){layers}

def Xform "World"
{{
    def Xform "a" (
        prepend apiSchemas = ["PhysicsRigidBodyAPI", "PhysicsMassAPI"]
    )
    {{
        float physics:mass = 1
        float3 physics:diagonalInertia = (1, 1, 1)
        {velocity}
        double3 xformOp:translate{translate}
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}

    def PhysicsSphericalJoint "hook"
    {{
        rel physics:body1 = </World/a>
        point3f physics:localPos0 = (0, 0, 1)
        point3f physics:localPos1 = {pos1}
    }}
}}
"""
GOOD = {"up": "Z", "layers": "", "velocity": "", "translate": " = (0, 0, 0)", "pos1": "(0, 0, 1)"}


def _scene(tmp_path, **changes) -> str:
    path = tmp_path / "scene.usda"
    path.write_text(SCENE.format(**{**GOOD, **changes}))
    return str(path)


def test_the_template_is_a_good_scene(tmp_path, capsys):
    code, lines = run(["simulate", _scene(tmp_path), "--duration", "0.1", "--out", str(tmp_path / "o.usda")], capsys)
    assert code == 0 and not lines, lines


@pytest.mark.parametrize(
    "changes,message",
    [
        # a transform authored only as time samples has no value at the default time the scene is read at
        (
            {"translate": ".timeSamples = { 0: (0, 0, 1.5), 10: (0, 0, 2) }"},
            "/World/a: xformOp:translate is authored only as time samples (2, from time 0)",
        ),
        (
            {"velocity": "vector3f physics:velocity.timeSamples = { 0: (1, 0, 0) }"},
            "/World/a: physics:velocity is authored only as time samples",
        ),
        # the joint's two frames 2 m apart: it would silently take body0's and yank body1 across
        (
            {"pos1": "(0, 0, 3)"},
            "/World/hook: its frames on body0 and body1 (physics:localPos0, physics:localPos1) "
            "are 2 m apart at the start",
        ),
        ({"up": "X"}, "the stage's upAxis must be Y or Z, got 'X'"),
    ],
    ids=["sampled transform", "sampled velocity", "joint gap", "up axis"],
)
def test_scene_read_wrong_is_refused(changes, message, tmp_path, capsys):
    path = _scene(tmp_path, **changes)
    assert_one_line_error(["simulate", path, "--out", str(tmp_path / "o.usda")], message, capsys)
    with pytest.raises(usd.UsdSceneError, match="^" + path if "upAxis" in message else message.split(":")[0]):
        usd.load_stage(path)


def test_a_default_beside_time_samples_is_read(tmp_path):
    """The default value is the start pose; time samples beside it (an animation in the file) are not read."""
    path = _scene(tmp_path, translate=" = (0, 0, 0)\n        double3 xformOp:translate.timeSamples = { 0: (5, 0, 0) }")
    scene = usd.load_stage(path)
    assert list(scene.builder.bodies[0].position) == [0.0, 0.0, 0.0]


def test_missing_parts_are_named(tmp_path, capfd):
    """A missing sublayer (or reference) would leave part of the scene out: an error naming it, and USD's own
    warnings stay off the terminal."""
    (tmp_path / "part.usda").write_text('#usda 1.0\nover "World"\n{\n}\n')
    path = tmp_path / "scene.usda"
    path.write_text(SCENE.format(**{**GOOD, "layers": ""}).replace(
        '    upAxis = "Z"\n)', '    upAxis = "Z"\n    subLayers = [@part.usda@, @missing_part.usda@]\n)'))  # fmt: skip
    code, lines = run(["simulate", str(path), "--out", str(tmp_path / "o.usda")], capfd)
    assert code == 2 and len(lines) == 1, lines
    assert lines[0] == (f"warpimpulse: error: {path}: part of the scene cannot be opened: Could not load sublayer "
                        f"@missing_part.usda@ of layer @{path}@; skipping.")  # fmt: skip


def test_not_usd_errors_have_no_cpp_fragment(tmp_path, capfd):
    text = tmp_path / "notes.usda"
    text.write_text("hello\n")
    broken = tmp_path / "broken.usda"
    broken.write_text('#usda 1.0\ndef Xform "W" (\n    prepend apiSchemas = []\n)\n{\n}\n')
    for path, detail in [(text, f"<{text}> is not a valid usda layer"), (broken, f"{broken}:3:27: parse error at ']'")]:
        code, lines = run(["simulate", str(path), "--out", str(tmp_path / "o.usda")], capfd)
        assert code == 2 and len(lines) == 1 and "pxrInternal" not in lines[0] and " at line " not in lines[0]
        assert lines[0].startswith(f"warpimpulse: error: {path}: not a USD file that can be opened ({detail}"), lines


def test_usd_parser_warnings_are_one_line_each(tmp_path, capfd):
    """A CollisionAPI on a prim that is not geometry: USD's C++ warning becomes one `warpimpulse: warning:` line."""
    path = _scene(tmp_path)
    text = open(path).read().replace('"PhysicsMassAPI"]', '"PhysicsMassAPI", "PhysicsCollisionAPI"]')
    open(path, "w").write(text)
    code, lines = run(["simulate", path, "--duration", "0.1", "--out", str(tmp_path / "o.usda")], capfd)
    assert code == 0, lines
    assert lines == [
        f"warpimpulse: warning: {path}: CollisionAPI applied to an unknown UsdGeomGPrim type, prim /World/a.",
        "warpimpulse: warning: 1 collider does not collide (/World/a: not a collision geometry): bodies pass "
        "through it; colliders still give their bodies mass",
    ], lines
