"""Procedural scenes. Each returns a SceneBuilder, so a user can add to it before finalize()."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .builder import SceneBuilder
from .shapes import Shape
from .transforms import quat_between, quat_from_axis_angle, quat_rotate, quat_to_matrix

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


def tree_arrays(bodies: int, to_root: bool = False) -> dict:
    """The paper's tree (or star) as the arguments of one `SceneBuilder.add_bodies` call ("bodies") and one
    `add_joints` call ("joints"): body i's parent is (i - 1) // 2, its children 2i + 1 (bent by -15 degrees) and
    2i + 2 (+15 degrees), computed a level at a time (each level one vectorised step)."""
    levels = _tree_levels(bodies)
    lengths = np.linspace(ROOT_LENGTH, LEAF_LENGTH, levels) if levels > 1 else np.array([ROOT_LENGTH])
    spans = lengths - 2.0 * (lengths / 20.0)  # capsule radius = length / 20; joints sit at the cap centres
    level = np.repeat(np.arange(levels), 2 ** np.arange(levels))
    index = np.arange(bodies)
    parent = (index - 1) // 2  # WORLD (-1) for the root
    direction = np.zeros((bodies, 3))
    top = np.zeros((bodies, 3))
    direction[0] = (0.0, 0.0, -1.0)
    for lv in range(1, levels):
        # Branch in the x-z plane on even levels and the y-z plane on odd ones.
        bend_axis = np.array([0.0, 1.0, 0.0]) if lv % 2 else np.array([1.0, 0.0, 0.0])
        turns = np.array([quat_from_axis_angle(bend_axis, s * BRANCH_ANGLE) for s in (1.0, -1.0)])
        kids = index[2**lv - 1 : 2 ** (lv + 1) - 1]
        up = parent[kids]
        direction[kids] = quat_rotate(turns[kids % 2], direction[up])  # odd children bend by -15 degrees
        top[kids] = top[up] + direction[up] * spans[lv - 1, None]
    shades = np.arange(levels) / max(levels - 1, 1)
    shapes = [
        Shape("capsule", radius=length / 20.0, length=span, color=(0.55 - 0.35 * shade, 0.35 + 0.4 * shade, 0.2),
              collide=False)
        for length, span, shade in zip(lengths.tolist(), spans.tolist(), shades.tolist())
    ]  # fmt: skip
    mass, inertia = zip(*(shape.mass_properties(DENSITY) for shape in shapes))
    body_args = dict(
        mass=np.array(mass)[level], inertia=np.array(inertia)[level],
        position=top + direction * (0.5 * spans[level, None]),
        orientation=quat_between([0.0, 0.0, 1.0], direction), name="b{}", shape=shapes, shape_index=level,
    )  # fmt: skip
    joint_args = dict(parent=np.where(index == 0, -1, 0) if to_root else parent, child=index, anchor=top, name="j{}")
    return {"bodies": body_args, "joints": joint_args}


def _tree(bodies: int, to_root: bool, joint: str = "ball") -> SceneBuilder:
    builder = SceneBuilder()
    args = tree_arrays(bodies, to_root)
    builder.add_bodies(**args["bodies"])
    builder.add_joints(joint, **args["joints"])
    builder.add_force(0, torque=(START_TORQUE, 0.0, 0.0), until=START_TORQUE_DURATION)
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


# ---------------------------------------------------------------- the paper's mechanisms (section 5)
STEEL = 7800.0  # kg/m^3, the mechanisms' links


def _link(builder: SceneBuilder, start, end, width: float, name: str, color, collide: bool = True) -> int:
    """A box bar of square section `width` from `start` to `end` (its local z along the bar)."""
    start, end = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    length = float(np.linalg.norm(end - start))
    shape = Shape("box", size=(width, width, length), color=color, collide=collide)
    mass, inertia = shape.mass_properties(STEEL)
    q = quat_between([0.0, 0.0, 1.0], (end - start) / length)
    return builder.add_body(mass, inertia, 0.5 * (start + end), q, name=name, shape=shape)


FOUR_BAR = (0.4, 0.1, 0.35, 0.3)  # ground d, crank a, coupler b, rocker c (m): a Grashof crank-rocker


def four_bar_points(crank_angle: float, lengths=FOUR_BAR) -> tuple[np.ndarray, np.ndarray]:
    """B (crank tip) and C (coupler-rocker hinge) of the planar four-bar in the x-z plane, A at the origin and
    D at (d, 0, 0), for a crank angle from +x towards +z; C on the upper branch."""
    d, a, b, c = lengths
    bp = np.array([a * math.cos(crank_angle), 0.0, a * math.sin(crank_angle)])
    dp = np.array([d, 0.0, 0.0])
    span = float(np.linalg.norm(dp - bp))
    along = (b * b - c * c + span * span) / (2.0 * span)  # from B towards D
    e = (dp - bp) / span
    normal = np.array([-e[2], 0.0, e[0]])  # e turned +90 degrees in x-z
    cp = bp + along * e + math.sqrt(b * b - along * along) * normal
    return bp, cp


def four_bar(crank_speed: float = 2.0 * math.pi, lengths=FOUR_BAR, crank_angle: float = 0.5 * math.pi) -> SceneBuilder:
    """The planar four-bar: three links and the world, four parallel hinges about -y (so angles grow from +x
        towards +z), redundant in 3D (20 constraint rows for 18 degrees of freedom and one mobility). A velocity
        motor turns the crank at `crank_speed` (rad/s) against gravity: a stiff one (a velocity constraint), since the
    light crank would need a PID gain beyond the explicit prediction's stability. The rocker's hinge to the world closes
        the loop."""
    builder = SceneBuilder()
    axis = (0.0, -1.0, 0.0)
    bp, cp = four_bar_points(crank_angle, lengths)
    dp = np.array([lengths[0], 0.0, 0.0])
    crank = _link(builder, np.zeros(3), bp, 0.02, "crank", (0.8, 0.3, 0.2))
    coupler = _link(builder, bp, cp, 0.02, "coupler", (0.3, 0.6, 0.8))
    rocker = _link(builder, dp, cp, 0.02, "rocker", (0.3, 0.8, 0.4))
    drive = builder.add_joint_revolute(None, crank, np.zeros(3), axis, name="A")
    builder.add_joint_revolute(crank, coupler, bp, axis, name="B")
    builder.add_joint_revolute(coupler, rocker, cp, axis, name="C")
    builder.add_joint_revolute(None, rocker, dp, axis, name="D")
    builder.add_motor(drive, "velocity", target=crank_speed, max_force=50.0, stiff=True)
    return builder


def _solid(builder: SceneBuilder, shape: Shape, density: float, position, orientation, name: str) -> int:
    mass, inertia = shape.mass_properties(density)
    return builder.add_body(mass, inertia, position, orientation, name=name, shape=shape)


CAR_WHEEL_SPEED = 5.0  # rad/s, the wheel servos' initial target
CAR_STEERING = 0.3  # rad, the steering servos' initial target (to the left)


def car(
    wheel_speed: float = CAR_WHEEL_SPEED, steering: float = CAR_STEERING, ground: bool = False, collide: bool = True
) -> SceneBuilder:
    """The paper's car (section 5): a chassis; per wheel a strut on a slider with a spring-damper along z (the
    suspension, its spring preloaded so that the built pose is the rest pose), a front knuckle on a steering
    hinge about z (front wheels), and the wheel on a hinge about y driven by a velocity servo. The two
    steering hinges carry position servos with one target: the steering servo. The servos are stiff motors
    (`SceneBuilder.add_motor`): a PID torque on the light knuckle would need a gain too low to steer.
    Without `ground` the chassis is fixed to the world ("hold"), so the wheels spin and steer in the air; with
    it the car is free and stands on its wheels on a ground (friction 1) that touches them, and drives.
    `collide` False (held only): the shapes are for display and mass, so the step has no contact stage (held,
    nothing touches: the paper's car is joints, motors and springs alone).

    Motors, in add order: wheels front-left, front-right, rear-left, rear-right, then steering left, right.
    """
    _held_if_not_colliding(ground, collide)
    builder = SceneBuilder()
    z_axis, y_axis = np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])
    chassis = _solid(builder, Shape("box", size=(2.4, 1.2, 0.3), color=(0.7, 0.1, 0.1), collide=collide), 300.0,
                     (0.0, 0.0, 0.8), (0.0, 0.0, 0.0, 1.0), "chassis")  # fmt: skip
    if not ground:
        builder.add_joint_fixed(None, chassis, (0.0, 0.0, 0.8), name="hold")
    k, c, strut_mass = 2.0e4, 400.0, 15.0
    wheel_shape = Shape("cylinder", radius=0.3, length=0.2, color=(0.15, 0.15, 0.15), collide=collide)
    upright = quat_between([0.0, 0.0, 1.0], y_axis)  # the cylinder's axis along y
    g = float(np.linalg.norm(builder.gravity))
    wheels, steering_hinges = [], []
    for name, x, y in (("front_left", 0.9, 0.7), ("front_right", 0.9, -0.7), ("rear_left", -0.9, 0.7),
                       ("rear_right", -0.9, -0.7)):  # fmt: skip
        top = np.array([x, y, 0.8])
        hub = np.array([x, y, 0.35])
        strut = builder.add_body(strut_mass, (0.2, 0.2, 0.05), 0.5 * (top + hub), name=f"{name}_strut")
        slider = builder.add_joint_prismatic(chassis, strut, 0.5 * (top + hub), z_axis, name=f"{name}_suspension")
        carrier = strut
        hung = strut_mass  # the mass the spring carries: strut, knuckle, wheel
        if name.startswith("front"):
            carrier = builder.add_body(2.0, (0.02, 0.02, 0.02), hub, name=f"{name}_knuckle")
            steering_hinges.append(builder.add_joint_revolute(strut, carrier, hub, z_axis, name=f"{name}_steering"))
            hung += 2.0
        wheel = _solid(builder, wheel_shape, 350.0, hub, upright, f"{name}_wheel")
        builder.bodies[wheel].friction = 1.0
        builder.filter_collision(chassis, wheel)  # the wheel turns in the wheel arch
        hung += builder.bodies[wheel].mass
        wheels.append(builder.add_joint_revolute(carrier, wheel, hub, y_axis, name=f"{name}_axle"))
        builder.add_joint_spring(slider, k, damping=c, rest=hung * g / k)
    for joint in wheels:
        builder.add_motor(joint, "velocity", target=wheel_speed, max_force=300.0, stiff=True)
    for joint in steering_hinges:
        builder.add_motor(joint, "position", target=steering, max_force=50.0, stiff=True)
    if ground:
        builder.add_ground(height=0.35 - wheel_shape.radius, friction=1.0)
    return builder


WALKER_LEGS = ((0.5, 0.35, 0.0), (-0.5, 0.35, 0.5), (0.5, -0.35, 0.5), (-0.5, -0.35, 0.0))
"""(x, y, crank phase in turns) of each leg of the walking machine."""

WALKER_TRIPODS = (
    (0.5, 0.35, 0.0),
    (0.0, 0.5, 0.5),
    (-0.5, 0.35, 0.0),
    (0.5, -0.35, 0.5),
    (0.0, -0.5, 0.0),
    (-0.5, -0.35, 0.5),
)
"""(x, y, crank phase in turns) of the six legs of the walking machine on the ground: two tripods (front and rear
of one side with the middle of the other) half a turn apart, the middle legs 15 cm further out than their
neighbours, whose feet pass them."""

WALKER_FOOT = Shape("box", size=(0.24, 0.12, 0.02), color=(0.3, 0.3, 0.3))
"""The walking machine's foot plates on the ground: two diagonal feet carry it at a time (a trot), and on points
it would tip about the diagonal; plates 24 cm long keep its centre of mass 11 cm inside their support."""

ALUMINIUM = 2700.0  # kg/m^3


def walker_leg_points(phase: float, crank: float = 0.12, sleeve_height: float = 0.35, foot: float = 0.55):
    """Crank pivot O (origin), crank tip P, sleeve pivot S and foot F of one leg in its x-z plane for a crank
    angle `phase` (rad, from +x towards +z): the leg passes through P and S and reaches `foot` beyond P."""
    o = np.zeros(3)
    p = np.array([crank * math.cos(phase), 0.0, crank * math.sin(phase)])
    s = np.array([0.0, 0.0, sleeve_height])
    u = (p - s) / np.linalg.norm(p - s)
    return o, p, s, p + foot * u


def _held_if_not_colliding(ground: bool, collide: bool) -> None:
    if ground and not collide:
        raise ValueError("a mechanism on the ground needs colliding shapes: collide=False is for the held one")


def walking_machine(crank_speed: float = 2.0 * math.pi, ground: bool = False, collide: bool = True) -> SceneBuilder:
    """The paper's walking machine (section 5): per leg one servo motor (a stiff velocity motor on the crank's
    hinge), two hinges (crank to leg, body to sleeve) and one slider (the leg through the sleeve): one closed
    loop per leg, a crank-driven slotted lever whose foot traces a closed curve each crank turn. Four legs,
    cranks half a turn apart on each side. Without `ground` the body is fixed to the world ("hold"); with it
    the body is free, each leg ends in a foot plate on an ankle hinge (`WALKER_FOOT`), and the machine stands on
    its four feet on a ground (friction 1) and walks along -x (docs/contacts.md, "The walking machine").
    `collide` False (held only): the shapes are for display and mass, so the step has no contact stage (held,
    no two parts touch: the paper's walking machine is joints and motors alone)."""
    _held_if_not_colliding(ground, collide)
    builder = SceneBuilder()
    axis = np.array([0.0, -1.0, 0.0])  # angles grow from +x towards +z
    height = 1.0
    body = _solid(builder, Shape("box", size=(1.4, 0.5, 0.2), color=(0.3, 0.3, 0.7), collide=collide), 500.0,
                  (0.0, 0.0, height + 0.3), (0.0, 0.0, 0.0, 1.0), "body")  # fmt: skip
    if not ground:
        builder.add_joint_fixed(None, body, (0.0, 0.0, height + 0.3), name="hold")
    for i, (x, y, phase) in enumerate(WALKER_TRIPODS if ground else WALKER_LEGS):
        origin = np.array([x, y, height])
        o, p, s, f = (origin + v for v in walker_leg_points(2.0 * math.pi * phase))
        u = (p - s) / np.linalg.norm(p - s)
        crank = _link(builder, o, p, 0.03, f"leg{i}_crank", (0.8, 0.6, 0.2), collide)
        sleeve = _link(builder, s - 0.05 * u, s + 0.05 * u, 0.06, f"leg{i}_sleeve", (0.5, 0.5, 0.5), collide)
        leg = _link(builder, s - 0.15 * u, f, 0.03, f"leg{i}_leg", (0.2, 0.6, 0.3), collide)
        servo = builder.add_joint_revolute(body, crank, o, axis, name=f"leg{i}_servo")
        builder.add_joint_revolute(crank, leg, p, axis, name=f"leg{i}_knee")
        builder.add_joint_revolute(body, sleeve, s, axis, name=f"leg{i}_hip")
        builder.add_joint_prismatic(sleeve, leg, s, u, name=f"leg{i}_slider")
        builder.add_motor(servo, "velocity", target=crank_speed, max_force=500.0, stiff=True)
        builder.filter_collision(body, leg)  # the leg slides through the sleeve, past the body
        if ground:  # a foot plate on an ankle hinge at the foot, which lies flat while it carries
            plate = _solid(builder, WALKER_FOOT, ALUMINIUM, f - np.array([0.0, 0.0, 0.5 * WALKER_FOOT.size[2]]),
                           (0.0, 0.0, 0.0, 1.0), f"leg{i}_foot")  # fmt: skip
            builder.add_joint_revolute(leg, plate, f, axis, name=f"leg{i}_ankle")
    if ground:
        feet = [b for b in builder.bodies if b.name.endswith("_foot")]
        builder.add_ground(height=min(_lowest(b) for b in feet), friction=1.0)
    return builder


def _lowest(body) -> float:
    """The height of a box body's lowest corner (m)."""
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * 0.5 * body.shape.size
    return float((body.position + corners @ quat_to_matrix(body.orientation).T)[:, 2].min())


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


def bent_chain(links: int = 6) -> SceneBuilder:
    """A chain of stubby capsules (0.5 m long, 0.15 m radius) bent in 3D, each link turned 100 degrees about z
    from the last and tilted down, on ball, universal and revolute joints in turn, the first hung from the world
    origin; its tip pushed sideways for the first half second. Gravity and the push move it in 3D: the stored
    MuJoCo reference trajectory of the tests (benchmarks/make_reference.py). Thin links would make a stiff
    system (a fast twist of little inertia), on which even MuJoCo's RK4 at h = 1/3000 is not converged."""
    builder = SceneBuilder()
    length, radius = 0.5, 0.15
    shape = Shape("capsule", radius=radius, length=length - 2.0 * radius, color=(0.3, 0.5, 0.8))
    mass, inertia = shape.mass_properties(DENSITY)
    top, parent = np.zeros(3), None
    for i in range(links):
        turn = math.radians(100.0) * i
        direction = np.array([math.cos(turn), math.sin(turn), -0.4])
        direction /= np.linalg.norm(direction)
        q = quat_between([0.0, 0.0, 1.0], direction)
        body = builder.add_body(mass, inertia, top + 0.5 * length * direction, q, name=f"link{i}", shape=shape)
        across = np.cross(direction, [0.0, 0.0, 1.0])
        kind = ("ball", "universal", "revolute")[i % 3]
        builder.add_joint(kind, parent, body, top, across, np.cross(direction, across), f"j{i}")
        parent, top = body, top + length * direction
    builder.add_force(parent, force=(0.0, 100.0, 50.0), until=0.5)
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
    "four_bar": four_bar,
    "car": car,
    "walking_machine": walking_machine,
    "box_stack": box_stack,
    "pile": pile,
}
