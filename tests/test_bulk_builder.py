"""The bulk builder path (add_bodies, add_joints) and the one-at-a-time path (add_body, add_joint) are one:
the same scene either way gives the same Model bit for bit and the same trajectory; vectorised checks name
the body or joint at fault and leave nothing half-added."""

import math

import numpy as np
import pytest

import warpimpulse as wi
from warpimpulse import SceneError, scenes


def _host(model: wi.Model) -> dict:
    """Everything the Model holds on the host, and its names."""
    out = {k: np.asarray(v) for k, v in vars(model.host).items()}
    out.update(body_name=model.body_name, joint_name=model.joint_name, joint_type=model.joint_type,
               constraint_joint=model.constraint_joint)  # fmt: skip
    return out


def _assert_same_models(a: wi.Model, b: wi.Model) -> None:
    ha, hb = _host(a), _host(b)
    assert ha.keys() == hb.keys()
    for k in ha:
        if isinstance(ha[k], list):
            assert ha[k] == hb[k], k
        else:
            assert ha[k].dtype == hb[k].dtype and ha[k].shape == hb[k].shape, k
            assert ha[k].tobytes() == hb[k].tobytes(), f"{k} differs"  # bit for bit


def _one_by_one(body_args: dict, joint_kind: str, joint_args: dict) -> wi.SceneBuilder:
    """The scene of one add_bodies and one add_joints call, added a body and a joint at a time."""
    b = wi.SceneBuilder()
    n = len(body_args["mass"])
    shapes, index = body_args.get("shape"), body_args.get("shape_index")
    for i in range(n):
        row = {k: (v[i] if np.ndim(v) and len(v) == n else v) for k, v in body_args.items()
               if k not in ("name", "shape", "shape_index")}  # fmt: skip
        shape = shapes[index[i]] if index is not None else shapes
        b.add_body(**row, name=body_args["name"].format(i), shape=shape)
    for j, (p, c) in enumerate(zip(joint_args["parent"].tolist(), joint_args["child"].tolist())):
        anchor = joint_args["anchor"][j]
        axis, axis_child = (joint_args.get(k) for k in ("axis", "axis_child"))
        axis = axis[j] if axis is not None and np.ndim(axis) == 2 else axis
        axis_child = axis_child[j] if axis_child is not None and np.ndim(axis_child) == 2 else axis_child
        b.add_joint(joint_kind, None if p < 0 else p, c, anchor, axis, axis_child, joint_args["name"].format(j))
    return b


def _trajectory(model: wi.Model, steps: int = 10) -> list[np.ndarray]:
    sim = wi.Simulator(model, 1 / 60)
    out = []
    for _ in range(steps):
        sim.step()
        out += [sim.positions(), sim.orientations(), sim.linear_velocities(), sim.angular_velocities()]
    return out


def test_bulk_tree_is_the_tree_built_body_by_body():
    """scenes.binary_tree (one add_bodies, one add_joints) against the same arrays added one at a time: the
    same Model arrays bit for bit, and the same 10-step trajectory bit for bit."""
    args = scenes.tree_arrays(63)
    bulk = scenes.binary_tree(63)
    single = _one_by_one(args["bodies"], "ball", args["joints"])
    single.add_force(0, torque=(scenes.START_TORQUE, 0.0, 0.0), until=scenes.START_TORQUE_DURATION)
    a, b = bulk.finalize(), single.finalize()
    _assert_same_models(a, b)
    for x, y in zip(_trajectory(a), _trajectory(b)):
        assert x.tobytes() == y.tobytes()


def _random_scene(rng, n: int) -> tuple[dict, dict]:
    """A chain of n revolute joints between bodies of random mass, full inertia tensors and orientations."""
    q = rng.normal(size=(n, 4))
    rot = np.linalg.qr(rng.normal(size=(n, 3, 3)))[0]
    moments = rng.uniform(1.0, 2.0, size=(n, 3))
    inertia = rot @ (moments[:, :, None] * np.eye(3)) @ rot.transpose(0, 2, 1)
    bodies = dict(mass=rng.uniform(0.5, 2.0, n), inertia=inertia, position=rng.normal(size=(n, 3)),
                  orientation=q / np.linalg.norm(q, axis=1, keepdims=True), linear_velocity=rng.normal(size=(n, 3)),
                  angular_velocity=rng.normal(size=(n, 3)), name="r{}")  # fmt: skip
    joints = dict(parent=np.arange(-1, n - 1), child=np.arange(n), anchor=rng.normal(size=(n, 3)),
                  axis=rng.normal(size=(n, 3)), name="h{}")  # fmt: skip
    return bodies, joints


def test_bulk_bodies_and_joints_equal_one_at_a_time():
    """Random bodies (full tensors, turned, moving) on revolute joints: bulk and one at a time agree bit for bit."""
    rng = np.random.default_rng(7)
    bodies, joints = _random_scene(rng, 12)
    bulk = wi.SceneBuilder()
    assert bulk.add_bodies(**bodies).tolist() == list(range(12))
    assert bulk.add_joints("revolute", **joints).tolist() == list(range(12))
    a, b = bulk.finalize(), _one_by_one(bodies, "revolute", joints).finalize()
    _assert_same_models(a, b)
    for x, y in zip(_trajectory(a, 5), _trajectory(b, 5)):
        assert x.tobytes() == y.tobytes()


@pytest.mark.parametrize("kind", sorted(wi.joints.JOINT_TYPES))
def test_every_joint_type_bulk_equals_one_at_a_time(kind):
    """A one-row add computes its geometry on Python floats, a batch on arrays (`joint_builder._parts`): for every
    joint type (axes, child axes, rest angles), from orientations a little off unit length (normalised without
    a warning), both give the same Model bit for bit."""
    rng = np.random.default_rng(11)
    bodies, joints = _random_scene(rng, 9)
    bodies["orientation"] = bodies["orientation"] * (1.0 + 4e-7)
    joints["axis_child"] = rng.normal(size=(9, 3))
    if kind not in ("revolute", "prismatic", "cylindrical", "universal", "planar"):
        del joints["axis"], joints["axis_child"]
    elif kind != "universal":
        del joints["axis_child"]
    bulk = wi.SceneBuilder()
    bulk.add_bodies(**bodies)
    bulk.add_joints(kind, **joints)
    _assert_same_models(bulk.finalize(), _one_by_one(bodies, kind, joints).finalize())


def _tree_builder() -> wi.SceneBuilder:
    b = wi.SceneBuilder()
    b.add_bodies(np.ones(4), np.tile([0.1, 0.1, 0.1], (4, 1)), np.zeros((4, 3)), name="link_{}")
    return b


@pytest.mark.parametrize(
    "change, message",
    [
        ({"mass": [1.0, 1.0, 0.0, 1.0]}, "body 'b_2': mass must be positive and finite, got 0.0"),
        ({"mass": [1.0, -3.0, 1.0, 1.0]}, "body 'b_1': mass must be positive and finite, got -3.0"),
        ({"mass": [1.0, 1.0, 1.0, math.nan]}, "body 'b_3': mass must be positive"),
        ({"inertia": [[1, 1, 1], [1, 1, 1], [1, -1, 1], [1, 1, 1]]}, "body 'b_2': inertia tensor is not positive"),
        ({"inertia": np.stack([np.eye(3)] * 3 + [np.diag([1.0, 1.0, 3.0])])}, "body 'b_3': principal moments"),
        (
            {"inertia": np.stack([np.eye(3), np.eye(3) + np.triu(np.ones((3, 3)), 1), np.eye(3), np.eye(3)])},
            "body 'b_1': inertia tensor is not symmetric",
        ),  # fmt: skip
        ({"inertia": [[1, 1, 1], [1, math.inf, 1], [1, 1, 1], [1, 1, 1]]}, "body 'b_1': inertia contains NaN or Inf"),
        ({"position": [[0, 0, 0], [0, 0, 0], [0, math.nan, 0], [0, 0, 0]]}, "body 'b_2' position contains NaN"),
        ({"orientation": [[0, 0, 0, 1], [0, 0, 0, 0], [0, 0, 0, 1], [0, 0, 0, 1]]}, "body 'b_1': orientation .* zero"),
        ({"name": ["a", "b", "link_1", "c"]}, "body 'link_1': a body of that name already exists"),
        ({"name": ["a", "b", "c", "b"]}, "body 'b': a body of that name already exists"),
        ({"name": ["a", "b", "", "c"]}, "body 6 name must be a non-empty string"),
        ({"friction": [0.5, 0.5, 0.5, -1.0]}, "body 'b_3': friction must be a finite number >= 0"),
        ({"mass": np.ones((4, 1))}, "add_bodies: mass must be a 1-D array"),
        ({"inertia": np.ones((3, 3))}, "bodies 'b_0'..'b_3': inertia must be 3 moments or a 3x3 tensor per body"),
    ],
)
def test_add_bodies_names_the_bad_body(change, message):
    """Vectorised checks find the first bad row and name it; nothing of the batch is added."""
    b = _tree_builder()
    args = dict(
        mass=np.ones(4),
        inertia=np.tile([1.0, 1.0, 1.0], (4, 1)),
        position=np.zeros((4, 3)),
        name=[f"b_{k}" for k in range(4)],
    )
    with pytest.raises(SceneError, match=message):
        b.add_bodies(**(args | change))
    assert len(b.bodies) == 4 and b.add_body(1.0, (1, 1, 1), (0, 0, 0), name="b_2") == 4  # the names are free


@pytest.mark.parametrize(
    "change, message",
    [
        ({"parent": [-1, 0, 9, 1]}, "joint 'j_2' parent: body index 9 does not exist \\(5 bodies\\)"),
        ({"parent": [-1, 0, -2, 1]}, "joint 'j_2' parent: body index -2 does not exist"),
        ({"child": [0, 1, 2, -1]}, "joint 'j_3': the child must be a body, not the world"),
        ({"parent": [-1, 1, 1, 2]}, "joint 'j_1': connects body 'link_1' to itself"),
        ({"parent": [-1, 0, 1, -1], "child": [0, 1, 2, 4]}, "joint 'j_3': both bodies are static"),
        ({"axis": [[0, 1, 0], [0, 1, 0], [0, 0, 0], [0, 1, 0]]}, "joint 'j_2' axis is a zero vector"),
        ({"anchor": [[0, 0, 0], [0, 0, math.inf], [0, 0, 0], [0, 0, 0]]}, "joint 'j_1' anchor contains NaN or Inf"),
        ({"child": [0, 1, 2]}, "add_joints: 4 parents for 3 children"),
        ({"parent": [-1.0, 0.0, 1.0, 2.0]}, "add_joints: parent must be a 1-D array of body indices"),
    ],
)
def test_add_joints_names_the_bad_joint(change, message):
    b = _tree_builder()
    b.add_static_body((0.0, 0.0, 0.0), name="ground")
    args = dict(parent=[-1, 0, 1, 2], child=[0, 1, 2, 3], anchor=np.zeros((4, 3)), axis=(0.0, 1.0, 0.0), name="j_{}")
    with pytest.raises(SceneError, match=message):
        b.add_joints("revolute", **(args | change))
    assert len(b.joints) == 0 and len(b.constraints) == 0  # nothing half-added


def test_unknown_joint_type_and_body_name_in_bulk():
    b = _tree_builder()
    with pytest.raises(SceneError, match="unknown joint type 'hinge'"):
        b.add_joints("hinge", [-1], [0], (0.0, 0.0, 0.0))
    with pytest.raises(SceneError, match="joint 'j' child: no body named 'nobody'"):
        b.add_joint_ball(None, "nobody", (0, 0, 0), name="j")


def test_views_read_and_write_the_columns_through_growth():
    """builder.bodies[i] reads the stored row, writes through in place and by assignment, and keeps its values
    while the columns grow; joint views give the catalogue kind, axes (None where none) and constraints."""
    b = wi.SceneBuilder()
    first = b.add_body(2.0, (1.0, 2.0, 2.5), (1.0, 2.0, 3.0), name="first")
    b.bodies[first].linear_velocity[:] = (0.0, 0.0, 1.0)
    b.bodies[first].mass *= 2.0
    b.add_bodies(np.ones(100), np.ones((100, 3)), np.zeros((100, 3)))  # the columns grow past their capacity
    body = b.bodies[first]
    assert body.name == "first" and body.mass == 4.0 and body.position.tolist() == [1.0, 2.0, 3.0]
    assert body.linear_velocity.tolist() == [0.0, 0.0, 1.0] and body.inertia[2, 2] == 2.5
    assert b.bodies[-1].name == "body100" and len(b.bodies) == 101
    b.add_joint_ball(None, 0, (0, 0, 0), name="ball")
    b.add_joint_universal(0, 1, (0, 0, 0), (1, 0, 0), (0, 1, 0), name="cardan")
    ball, cardan = b.joints
    assert ball.kind == "ball" and ball.axis is None and ball.constraints == [0]
    assert cardan.kind == "universal" and cardan.axis_child.tolist() == [0.0, 1.0, 0.0] and cardan.constraints == [1, 2]
    assert [c.kind.name for c in b.constraints] == ["POINT", "POINT", "ANGLE"] and b.constraints[2].joint == 1
