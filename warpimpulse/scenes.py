"""Procedural scenes. Each returns a SceneBuilder, so a user can add to it before finalize()."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .builder import SceneBuilder
from .shapes import Shape
from .transforms import quat_between, quat_from_axis_angle, quat_rotate

DENSITY = 1000.0  # kg/m^3, equal for every body, as in the paper's trees
ROOT_LENGTH, LEAF_LENGTH = 11.4, 1.0  # metres (method paper, section 5)
BRANCH_ANGLE = math.radians(15.0)
START_TORQUE = 2.0e5  # N m about world x on the top body, during the first second
START_TORQUE_DURATION = 1.0


def _capsule_body(builder: SceneBuilder, top, direction, length, name, color) -> tuple[int, np.ndarray]:
    """A capsule of total `length` hanging from `top` along `direction`. Returns (body, bottom point)."""
    radius = length / 20.0
    span = length - 2.0 * radius  # distance between the cap centres, where joints sit
    shape = Shape("capsule", radius=radius, length=span, color=color, collide=False)
    mass, inertia = shape.mass_properties(DENSITY)
    centre = top + direction * (0.5 * span)
    q = quat_between([0.0, 0.0, 1.0], direction)
    body = builder.add_body(mass, inertia, centre, q, name=name, shape=shape)
    return body, top + direction * span


def _tree_levels(bodies: int) -> int:
    levels = int(round(math.log2(bodies + 1)))
    if bodies < 1 or 2**levels - 1 != bodies:
        raise ValueError(f"a binary tree has 2^k - 1 bodies (1, 3, 7, ..., 127, 255, ...), got {bodies}")
    return levels


def _tree(bodies: int, to_root: bool, joint: str = "ball") -> SceneBuilder:
    levels = _tree_levels(bodies)
    builder = SceneBuilder()
    lengths = np.linspace(ROOT_LENGTH, LEAF_LENGTH, levels) if levels > 1 else [ROOT_LENGTH]
    down = np.array([0.0, 0.0, -1.0])
    root, bottom = _capsule_body(builder, np.zeros(3), down, lengths[0], "b0", (0.55, 0.35, 0.2))
    builder.add_joint_ball(None, root, np.zeros(3), name="j0")
    frontier = [(root, bottom, down)]
    for level in range(1, levels):
        # Branch in the x-z plane on even levels and the y-z plane on odd ones.
        bend_axis = np.array([0.0, 1.0, 0.0]) if level % 2 else np.array([1.0, 0.0, 0.0])
        shade = level / max(levels - 1, 1)
        color = (0.55 - 0.35 * shade, 0.35 + 0.4 * shade, 0.2)
        next_frontier = []
        for parent, top, direction in frontier:
            for sign in (-1.0, 1.0):
                d = quat_rotate(quat_from_axis_angle(bend_axis, sign * BRANCH_ANGLE), direction)
                i = len(builder.bodies)
                child, child_bottom = _capsule_body(builder, top, d, lengths[level], f"b{i}", color)
                builder.add_joint(joint, root if to_root else parent, child, top, None, None, f"j{i}")
                next_frontier.append((child, child_bottom, d))
        frontier = next_frontier
    builder.add_force(root, torque=(START_TORQUE, 0.0, 0.0), until=START_TORQUE_DURATION)
    return builder


def binary_tree(bodies: int = 127) -> SceneBuilder:
    """The paper's tree (section 5): capsules 11.4 m at the root down to 1 m at the leaves, equal density,
    ball joints, the root hung from a world point, a torque on the top body at the start."""
    return _tree(bodies, to_root=False)


def star(bodies: int = 127) -> SceneBuilder:
    """The paper's star: the tree's bodies, each jointed to the root instead of its parent."""
    return _tree(bodies, to_root=True)


def chain(links: int = 10, joint: str | Sequence[str] = "revolute", link_length: float = 1.0) -> SceneBuilder:
    """A horizontal chain of capsules hinged about y, the first one to a world point at the origin. A sequence
    of joint types is cycled along the chain (a scene with several constraint kinds)."""
    builder = SceneBuilder()
    x_axis, y_axis, z_axis = np.eye(3)
    joints = [joint] if isinstance(joint, str) else list(joint)
    top = np.zeros(3)
    parent = None
    for i in range(links):
        body, bottom = _capsule_body(builder, top, x_axis, link_length, f"link{i}", (0.3, 0.5, 0.8))
        builder.add_joint(joints[i % len(joints)], parent, body, top, y_axis, z_axis, f"j{i}")
        parent, top = body, bottom
    return builder


def double_pendulum(length: float = 1.0, mass: float = 1.0, angles=(math.pi / 2, math.pi / 2)) -> SceneBuilder:
    """Two uniform rods (capsules) on hinges about y; `angles` from the downward vertical."""
    builder = SceneBuilder()
    radius = 0.02 * length
    shape = Shape("capsule", radius=radius, length=length - 2.0 * radius, color=(0.8, 0.3, 0.3), collide=False)
    inertia = shape.inertia(mass)
    y_axis = np.array([0.0, 1.0, 0.0])
    top, parent = np.zeros(3), None
    for i, theta in enumerate(angles):
        # Angle theta about y from -z: direction (sin, 0, -cos) in x-z.
        d = np.array([math.sin(theta), 0.0, -math.cos(theta)])
        q = quat_between([0.0, 0.0, 1.0], d)
        body = builder.add_body(mass, inertia, top + 0.5 * length * d, q, name=f"rod{i}", shape=shape)
        builder.add_joint_revolute(parent, body, top, y_axis, name=f"hinge{i}")
        parent, top = body, top + length * d
    return builder


def box_stack(boxes: int = 10, size: float = 0.2, density: float = 500.0) -> SceneBuilder:
    """`boxes` cubes of edge `size` (m) stacked on the ground, touching, at rest."""
    builder = SceneBuilder()
    shape = Shape("box", size=(size, size, size), color=(0.7, 0.5, 0.3))
    mass, inertia = shape.mass_properties(density)
    for i in range(boxes):
        builder.add_body(mass, inertia, (0.0, 0.0, size * (i + 0.5)), shape=shape, name=f"box{i}")
    builder.add_ground()
    return builder


def pile(bodies: int = 1000, seed: int = 0) -> SceneBuilder:
    """`bodies` spheres and capsules (radius 5 cm, capsules 20 cm long; alternating) on a grid of 24 cm cells,
    ten by ten per layer, with random orientations and small offsets, dropped into a box 2.4 m wide (the ground
    and four static walls 2.6 m high). No two start closer than 4 cm."""
    rng = np.random.default_rng(seed)
    builder = SceneBuilder()
    per_row, cell, wall, height = 10, 0.24, 0.1, 2.6
    width = per_row * cell
    half = 0.5 * (width + wall)
    side = Shape("box", size=(width + 2 * wall, wall, height), color=(0.6, 0.6, 0.6))
    end = Shape("box", size=(wall, width, height), color=(0.6, 0.6, 0.6))
    walls = [((0, half, 0.5 * height), side), ((0, -half, 0.5 * height), side),
             ((half, 0, 0.5 * height), end), ((-half, 0, 0.5 * height), end)]  # fmt: skip
    for i, (pos, shape) in enumerate(walls):
        builder.add_static_body(pos, name=f"wall{i}", shape=shape)
    builder.add_ground()
    sphere = Shape("sphere", radius=0.05, color=(0.2, 0.5, 0.8))
    capsule = Shape("capsule", radius=0.05, length=0.1, color=(0.8, 0.3, 0.2))
    for i in range(bodies):
        shape = sphere if i % 2 == 0 else capsule
        mass, inertia = shape.mass_properties(DENSITY)
        layer, index = divmod(i, per_row * per_row)
        row, col = divmod(index, per_row)
        x = -0.5 * width + cell * (col + 0.5) + rng.uniform(-0.01, 0.01)
        y = -0.5 * width + cell * (row + 0.5) + rng.uniform(-0.01, 0.01)
        q = quat_from_axis_angle(rng.normal(size=3), rng.uniform(0.0, math.pi))
        builder.add_body(mass, inertia, (x, y, 0.15 + cell * layer), q, name=f"{shape.kind}{i}", shape=shape)
    return builder


SCENES = {
    "tree31": lambda: binary_tree(31),
    "tree63": lambda: binary_tree(63),
    "tree127": lambda: binary_tree(127),
    "tree255": lambda: binary_tree(255),
    "star127": lambda: star(127),
    "chain": lambda: chain(10),
    "chain50": lambda: chain(50),
    "double_pendulum": double_pendulum,
    "box_stack": box_stack,
    "pile": pile,
}
