"""Regenerate the UsdPhysics scene files in this folder: `python scenes/make_scenes.py`.

Each file is a procedural scene written by `warpimpulse.usd.save_scene` (bodies at their initial pose,
UsdPhysics schemas, display geometry), so `warpimpulse simulate scenes/NAME.usda` runs it as it is.
"""

from __future__ import annotations

import math
import os

import numpy as np

from warpimpulse import SceneBuilder, Shape, scenes, usd
from warpimpulse.transforms import quat_between

HERE = os.path.dirname(os.path.abspath(__file__))


def _rod(builder: SceneBuilder, a, b, name: str, color, radius: float = 0.03, density: float = 1000.0) -> int:
    """A capsule body from point a to point b (cap centres), density-based mass."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    d = b - a
    length = float(np.linalg.norm(d))
    shape = Shape("capsule", radius=radius, length=length, color=color, collide=False)
    mass, inertia = shape.mass_properties(density)
    return builder.add_body(mass, inertia, 0.5 * (a + b), quat_between([0, 0, 1], d), name=name, shape=shape)


def _block(builder: SceneBuilder, centre, size, name: str, color, density: float = 1000.0) -> int:
    shape = Shape("box", size=tuple(size), color=color, collide=False)
    mass, inertia = shape.mass_properties(density)
    return builder.add_body(mass, inertia, centre, name=name, shape=shape)


def mechanism() -> SceneBuilder:
    """A small machine with one joint of every type: revolute crank, ball pendulum, universal link,
    prismatic carriage with a fixed weight, cylindrical sleeve, planar puck."""
    b = SceneBuilder()
    x, y, z = np.eye(3)
    red, blue, green, grey, gold = (0.8, 0.2, 0.2), (0.2, 0.4, 0.8), (0.2, 0.7, 0.3), (0.5, 0.5, 0.5), (0.9, 0.7, 0.2)
    # Revolute: a crank about y, hinged to the world at height 2, pointing along +x.
    crank = _rod(b, (0, 0, 2), (0.6, 0, 2), "crank", red, radius=0.04)
    b.add_joint_revolute(None, crank, (0, 0, 2), y, name="crank_hinge")
    # Ball: a pendulum hanging from the crank's tip, tilted so it swings in 3-D.
    tip = np.array([0.6, 0.0, 2.0])
    pend_end = tip + 0.8 * np.array([math.sin(0.4), 0.2, -math.cos(0.4)]) / np.linalg.norm([math.sin(0.4), 0.2, 1])
    pendulum = _rod(b, tip, pend_end, "pendulum", blue)
    b.add_joint_ball(crank, pendulum, tip, name="pendulum_ball")
    # Universal: a Cardan pendulum hung from the world beside the crank, axes x (world side) and y (link
    # side), tilted so that it swings in 3-D. (Hung from the pendulum's tip it made a chaotic triple pendulum
    # whose whipping tip the default step of 1/30 s cannot follow.)
    hook = np.array([1.6, 0.0, 2.0])
    link = _rod(b, hook, hook + 0.6 * np.array([0.3, 0.4, -1.0]) / np.linalg.norm([0.3, 0.4, 1.0]), "link", green)
    b.add_joint_universal(None, link, hook, x, y, name="link_universal")
    # Prismatic: a carriage on a rail along x at height 1, beside the crank.
    carriage = _block(b, (-1.0, 0.0, 1.0), (0.3, 0.2, 0.1), "carriage", grey)
    b.add_joint_prismatic(None, carriage, (-1.0, 0.0, 1.0), (1.0, 0.0, 0.3), name="rail")
    # Fixed: a weight welded under the carriage.
    weight = _block(b, (-1.0, 0.0, 0.85), (0.15, 0.15, 0.2), "weight", gold, density=3000.0)
    b.add_joint_fixed(carriage, weight, (-1.0, 0.0, 0.95), name="weld")
    # Cylindrical: a sleeve that slides and turns on a post along z beside the rail.
    sleeve = _rod(b, (-2.0, 0.0, 1.0), (-2.0, 0.3, 1.0), "sleeve", red)
    b.add_joint_cylindrical(None, sleeve, (-2.0, 0.0, 1.0), z, name="post")
    # Planar: a puck that moves in the vertical x-z plane through y = 1 and turns about y.
    puck = b.add_body(0.5, Shape("cylinder", radius=0.1, length=0.05).inertia(0.5), (0.0, 1.0, 1.0),
                      quat_between([0, 0, 1], y), name="puck",
                      shape=Shape("cylinder", radius=0.1, length=0.05, color=blue, collide=False))  # fmt: skip
    b.add_joint_planar(None, puck, (0.0, 1.0, 1.0), y, name="puck_plane")
    b.bodies[puck].linear_velocity[:] = (0.5, 0.0, 1.0)
    return b


SCENES = {
    "tree31": lambda: scenes.binary_tree(31),
    "tree127": lambda: scenes.binary_tree(127),
    "tree255": lambda: scenes.binary_tree(255),
    "star127": lambda: scenes.star(127),
    "chain": lambda: scenes.chain(10),
    "mechanism": mechanism,
    "four_bar": scenes.four_bar,  # the paper's mechanisms (section 5), at h = 1/60 s as their tests
    "car": scenes.car,
    "walking_machine": scenes.walking_machine,
    "box_stack": lambda: scenes.box_stack(10),
    "pile": lambda: scenes.pile(1000),
    "car_on_ground": lambda: scenes.car(ground=True),
    "walking_machine_on_ground": lambda: scenes.walking_machine(crank_speed=1.0, ground=True),
}
# Step sizes recorded in the files, where the default 1/fps is too coarse: the chain falling from the
# horizontal whips its last links and diverges at t = 6.9 s with h = 1/30 (runs to 10 s with h = 1/120).
DT = {"chain": 1.0 / 120.0, "four_bar": 1.0 / 60.0, "car": 1.0 / 60.0, "walking_machine": 1.0 / 60.0,
      "car_on_ground": 1.0 / 60.0, "walking_machine_on_ground": 1.0 / 60.0}  # fmt: skip


def main() -> None:
    for name, make in SCENES.items():
        path = os.path.join(HERE, f"{name}.usda")
        usd.save_scene(make(), path, dt=DT.get(name))
        print(f"wrote {os.path.relpath(path)}")


if __name__ == "__main__":
    main()
