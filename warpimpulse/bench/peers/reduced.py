"""The builder's joints as a tree of elementary joints (ball, hinge, slide), as reduced-coordinate engines
(MuJoCo, pinocchio) describe a scene: each body carries the joints that connect it to its parent.
"""

from __future__ import annotations

import numpy as np

from ...builder import WORLD, Joint, SceneBuilder


def parent_joints(builder: SceneBuilder) -> list[Joint | None]:
    """The joint that connects each body to its parent, or None for roots.

    The peers' bodies form a tree: a body with two parent joints, or joints forming a cycle, would need
    loop-closing equality constraints, which this conversion does not describe.
    """
    parents: list[Joint | None] = [None] * len(builder.bodies)
    for joint in builder.joints:
        child = builder.bodies[joint.child]
        if parents[joint.child] is not None:
            raise NotImplementedError(
                f"peer export: body {child.name!r} has two parent joints ({parents[joint.child].name!r} and "
                f"{joint.name!r}); kinematic loops are not supported"
            )
        if child.static:
            raise NotImplementedError(f"peer export: joint {joint.name!r} has the static body {child.name!r} as child")
        parents[joint.child] = joint
    # Every body must reach a root by following parents, otherwise the joints form a cycle.
    for start in range(len(builder.bodies)):
        seen, b = set(), start
        while parents[b] is not None and parents[b].parent != WORLD:
            if b in seen:
                raise NotImplementedError(
                    f"peer export: the joints through body {builder.bodies[start].name!r} form a loop"
                )
            seen.add(b)
            b = parents[b].parent
    return parents


def _in_plane(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(normal, u)


def joint_elements(joint: Joint, to_local) -> list[tuple[str, np.ndarray]]:
    """(elementary joint: ball, hinge or slide; its axis via `to_local`, the child frame) for each part of `joint`."""
    kind = joint.kind
    if kind == "ball":
        return [("ball", np.array([0.0, 0.0, 1.0]))]
    if kind == "fixed":
        return []
    axis = to_local(joint.axis)
    if kind == "revolute":
        return [("hinge", axis)]
    if kind == "prismatic":
        return [("slide", axis)]
    if kind == "cylindrical":
        return [("slide", axis), ("hinge", axis)]
    if kind == "universal":
        # Rotation about the parent's axis, then about the child's axis: keeps their angle constant.
        return [("hinge", axis), ("hinge", to_local(joint.axis_child))]
    if kind == "planar":
        u, v = _in_plane(joint.axis)
        return [("slide", to_local(u)), ("slide", to_local(v)), ("hinge", axis)]
    raise NotImplementedError(f"peer export: joint {joint.name!r} of kind {kind!r} has no MuJoCo equivalent")
