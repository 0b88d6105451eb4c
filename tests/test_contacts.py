"""Contacts against analytic results: bounce heights, a box on a slope (stick and slide), rolling without
slipping, a resting stack, no tunnelling, and the errors for bad collision input."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from numpy_checks import rotations

import warpimpulse as wi
from warpimpulse import scenes
from warpimpulse.transforms import quat_from_axis_angle, quat_to_matrix

G = 9.81


def _ball(height: float, restitution: float) -> wi.Simulator:
    b = wi.SceneBuilder()
    s = wi.Shape("sphere", radius=0.1)
    m, inertia = s.mass_properties(1000.0)
    b.add_body(m, inertia, (0.0, 0.0, height), shape=s, restitution=restitution, name="ball")
    b.add_ground(restitution=restitution)
    return wi.Simulator(b.finalize(), dt=1.0 / 240.0)


def test_bounce_returns_e_squared_of_the_height():
    e = 0.8
    sim = _ball(1.1, e)
    apex, v_prev = [1.0], 0.0
    for _ in range(int(3.0 * 240)):
        sim.step()
        z, v = sim.positions()[0, 2] - 0.1, sim.linear_velocities()[0, 2]
        if v_prev > 0.0 >= v:
            apex.append(z)
        v_prev = v
    assert len(apex) >= 4
    ratios = np.array(apex[1:4]) / np.array(apex[0:3])
    np.testing.assert_allclose(ratios, e * e, rtol=0.01)


def _on_slope(theta: float, mu: float, shape: wi.Shape, dt: float = 1.0 / 60.0) -> wi.Simulator:
    """A body resting on a plane through the origin tilted by theta about y (it slides towards -x)."""
    b = wi.SceneBuilder()
    n = np.array([-math.sin(theta), 0.0, math.cos(theta)])
    m, inertia = shape.mass_properties(500.0)
    lift = shape.size[2] / 2 if shape.kind == "box" else shape.radius
    b.add_body(m, inertia, n * lift, quat_from_axis_angle([0, 1, 0], -theta), shape=shape, friction=mu, name="b")
    b.add_ground(normal=n, friction=mu)
    return wi.Simulator(b.finalize(), dt=dt)


def _travel(sim: wi.Simulator, seconds: float) -> float:
    x0 = sim.positions()[0]
    sim.simulate(seconds)
    return float(np.linalg.norm(sim.positions()[0] - x0))


def test_box_sticks_on_a_slope_below_the_friction_angle():
    theta, mu = math.radians(20.0), 0.5
    assert math.tan(theta) < mu
    sim = _on_slope(theta, mu, wi.Shape("box", size=(0.2, 0.2, 0.2)))
    assert _travel(sim, 5.0) <= 1e-3


def test_box_slides_with_coulomb_deceleration():
    theta, mu, t = math.radians(20.0), 0.2, 2.0
    sim = _on_slope(theta, mu, wi.Shape("box", size=(0.2, 0.2, 0.2)))
    a = 2.0 * _travel(sim, t) / t**2
    assert a == pytest.approx(G * (math.sin(theta) - mu * math.cos(theta)), rel=0.01)


def test_sphere_rolls_without_slipping_at_five_sevenths_g_sin_theta():
    theta, t = math.radians(20.0), 2.0
    sim = _on_slope(theta, 0.8, wi.Shape("sphere", radius=0.1))
    a = 2.0 * _travel(sim, t) / t**2
    assert a == pytest.approx(5.0 / 7.0 * G * math.sin(theta), rel=0.01)
    # Rolling: the contact point does not slip (v = w x r).
    v, w = sim.linear_velocities()[0], sim.angular_velocities()[0]
    n = np.array([-math.sin(theta), 0.0, math.cos(theta)])
    assert np.linalg.norm(v + np.cross(w, -0.1 * n)) < 1e-3 * np.linalg.norm(v)


def _stack(boxes: int) -> wi.Simulator:
    return wi.Simulator(scenes.box_stack(boxes).finalize(), dt=1.0 / 60.0)


def _rests(sim: wi.Simulator, seconds: float) -> None:
    x0, e0 = sim.positions(), sim.energy()
    for _ in range(int(round(seconds / sim.dt))):
        stats = sim.step()
        assert stats.max_penetration <= sim.tolerance
    assert np.abs(sim.positions() - x0).max() <= 1e-3
    assert sim.energy() - e0 <= 1e-6 * abs(e0)  # no energy gained (round-off of the potential aside)


def test_short_stack_rests():
    _rests(_stack(4), 1.0)


@pytest.mark.slow
def test_stack_of_ten_rests_ten_seconds():
    _rests(_stack(10), 10.0)


def _kinetic(sim: wi.Simulator) -> float:
    h = sim.model.host
    v, w = sim.linear_velocities(), sim.angular_velocities()
    r = quat_to_matrix(sim.orientations())
    inertia = np.einsum("nij,njk,nlk->nil", r, h.body_inertia, r)
    return float(0.5 * np.sum(h.body_mass * np.sum(v * v, axis=1)) + 0.5 * np.einsum("ni,nij,nj->", w, inertia, w))


def test_a_pile_comes_to_rest_at_a_coarse_tolerance():
    """100 spheres and capsules dropped 15 cm, at 5 mm: over the last 0.5 s of 3 s the kinetic energy stays below
    0.03 J (0.014 J measured; with the position phase closing contacts to 0 and each phase pushing alone, as
    before, the pile jittered: a mean of 0.10 J, up to 0.35 J)."""
    sim = wi.Simulator(scenes.pile(100).finalize(), dt=1.0 / 60.0, tolerance=5e-3)
    energies = []
    for _ in range(180):
        stats = sim.step()
        assert stats.max_penetration <= sim.tolerance
        energies.append(_kinetic(sim))
    assert np.mean(energies[-30:]) < 0.03
    assert max(energies[-30:]) < 0.06


def test_warm_start_takes_fewer_sweeps_to_the_same_rest():
    """Two boxes stacked, 1 s: starting each step from the last step's matched impulses takes under half the
    sweeps (1,490 against 5,016 measured) and ends at the same heights to the tolerance, gaining no energy."""
    runs = []
    for warm in (False, True):
        sim = wi.Simulator(scenes.box_stack(2).finalize(), dt=1.0 / 60.0, tolerance=1e-4)
        sim.contact_stage.warm_start = warm
        e0 = sim.energy()
        sweeps = sum(sim.step().contact_sweeps for _ in range(60))
        assert sim.energy() - e0 <= 1e-6 * abs(e0)
        runs.append((sweeps, sim.positions()))
    (cold, x_cold), (warm, x_warm) = runs
    assert warm < 0.5 * cold
    assert np.abs(x_warm - x_cold).max() <= 1e-4


def test_fast_small_sphere_does_not_tunnel_through_a_thin_box():
    b = wi.SceneBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_static_body((0.0, 0.0, 0.0), name="plate", shape=wi.Shape("box", size=(1.0, 1.0, 0.01)))
    s = wi.Shape("sphere", radius=0.01)
    m, inertia = s.mass_properties(1000.0)
    b.add_body(m, inertia, (0.0, 0.0, 0.2), linear_velocity=(0.0, 0.0, -50.0), shape=s, name="bullet")
    sim = wi.Simulator(b.finalize(), dt=1.0 / 60.0)  # 0.83 m a step, the plate 1 cm thick
    sim.simulate(0.5)
    assert sim.positions()[1, 2] >= 0.005 + 0.01 - 1e-5
    assert sim.linear_velocities()[1, 2] >= -1e-6


def _box_on(base: str) -> wi.Simulator:
    """A 0.4 m box resting on a 1 m box: `base` "static" (a static body) or "dynamic" (on the ground)."""
    b = wi.SceneBuilder()
    big, small = wi.Shape("box", size=(1.0, 1.0, 1.0)), wi.Shape("box", size=(0.4, 0.4, 0.4))
    if base == "static":
        b.add_static_body((0.0, 0.0, 0.5), name="base", shape=big)
    else:
        b.add_body(*big.mass_properties(500.0), (0.0, 0.0, 0.5), shape=big, name="base")
        b.add_ground()
    b.add_body(*small.mass_properties(500.0), (0.1, -0.2, 1.2), quat_from_axis_angle([0, 0, 1], 0.3), shape=small,
               name="top")  # fmt: skip
    return wi.Simulator(b.finalize(), dt=1.0 / 60.0)


def test_a_box_rests_on_a_static_box_on_four_points_without_creep():
    """A static box holds a box as a dynamic one does: the same four corners, the box's weight over a step, and
    no creep over 5 s; a static body is in no joint system (the scene has none)."""
    sim = _box_on("static")
    assert sim.model.joint_count == 0
    x0 = sim.positions()[1].copy()
    for stats in sim.simulate(5.0):
        assert stats.max_penetration <= sim.tolerance
    assert np.abs(sim.positions()[1] - x0).max() <= 1e-3
    assert np.abs(sim.positions()[0] - [0.0, 0.0, 0.5]).max() == 0.0  # it does not move
    c = sim.contacts()
    dynamic = _box_on("dynamic")
    dynamic.simulate(0.1)
    d = dynamic.contacts()
    on_base = d.body_a != -1
    assert len(c) == 4 and on_base.sum() == 4 and set(c.body_a.tolist()) == {0} and set(c.body_b.tolist()) == {1}

    def corners(points):
        return points[np.lexsort(points[:, :2].T)]

    np.testing.assert_allclose(corners(c.point), corners(d.point[on_base]), atol=1e-4)
    np.testing.assert_allclose(c.normal, [[0.0, 0.0, 1.0]] * 4, atol=1e-12)
    assert c.normal_impulse.sum() == pytest.approx(G * sim.model.host.body_mass[1] * sim.dt, rel=1e-3)


def test_a_ball_bounces_on_a_tilted_static_box_to_e_squared_of_its_height():
    """A ramp: a static 40 x 40 x 1 m box turned 20 degrees about y. A ball dropped 1 m above it (along its
    normal) bounces to e^2 of the previous height along the normal, within 1%, as on a ground plane."""
    theta, e = math.radians(20.0), 0.8
    n = np.array([-math.sin(theta), 0.0, math.cos(theta)])
    b = wi.SceneBuilder()
    ramp = wi.Shape("box", size=(40.0, 40.0, 1.0))
    b.add_static_body((0.0, 0.0, 0.0), quat_from_axis_angle([0, 1, 0], -theta), shape=ramp, restitution=e, name="ramp")
    ball = wi.Shape("sphere", radius=0.1)
    b.add_body(*ball.mass_properties(1000.0), n * 1.6, shape=ball, restitution=e, name="ball")
    sim = wi.Simulator(b.finalize(), dt=1.0 / 240.0)
    apex, v_prev = [1.0], 0.0
    for _ in range(int(3.0 * 240)):
        sim.step()
        height, v = np.dot(n, sim.positions()[1]) - 0.6, np.dot(n, sim.linear_velocities()[1])
        if v_prev > 0.0 >= v:
            apex.append(height)
        v_prev = v
    assert len(apex) >= 4
    np.testing.assert_allclose(np.array(apex[1:4]) / np.array(apex[0:3]), e * e, rtol=0.01)


def test_contacts_report_the_resting_load():
    sim = _stack(2)
    sim.simulate(0.5)
    c = sim.contacts()
    ground = c.body_a == -1
    assert ground.sum() == 4 and (~ground).sum() == 4
    np.testing.assert_allclose(c.normal[ground], [[0.0, 0.0, 1.0]] * 4, atol=1e-9)
    assert np.all(np.abs(c.depth) <= sim.tolerance)
    m = sim.model.host.body_mass
    # Over a step the ground carries both boxes' weight, the lower box's top the upper one's.
    assert c.normal_impulse[ground].sum() == pytest.approx(G * m.sum() * sim.dt, rel=1e-3)
    assert c.normal_impulse[~ground].sum() == pytest.approx(G * m[1] * sim.dt, rel=1e-3)


def test_jointed_bodies_do_not_collide_and_scenes_without_colliders_have_no_contact_stage():
    b = wi.SceneBuilder()
    box = wi.Shape("box", size=(0.2, 0.2, 0.2))
    m, inertia = box.mass_properties(500.0)
    b0 = b.add_body(m, inertia, (0, 0, 1), shape=box, name="a")
    b1 = b.add_body(m, inertia, (0.1, 0, 1), shape=box, name="b")  # overlapping, welded
    b.add_joint_fixed(b0, b1, (0.05, 0, 1))
    assert b.finalize().colliders.filter_pairs.tolist() == [[0, 1]]
    sim = wi.Simulator(b.finalize(), dt=0.01)
    sim.simulate(0.1)
    assert len(sim.contacts()) == 0
    assert wi.Simulator(scenes.binary_tree(7).finalize(), dt=0.01).contact_stage is None


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"shape": wi.Shape("sphere", radius=0.0)}, "body 'bad': collision shape sphere has zero size"),
        ({"shape": wi.Shape("box", size=(0.1, 0.0, 0.1))}, "body 'bad': collision shape box has zero size"),
        ({"friction": -0.1}, "body 'bad': friction must be a finite number >= 0"),
        ({"restitution": 1.5}, r"body 'bad': restitution must be in \[0, 1\]"),
    ],
)
def test_bad_collision_input_names_the_body(kwargs, message):
    b = wi.SceneBuilder()
    with pytest.raises(wi.SceneError, match=message):
        b.add_body(1.0, [0.1, 0.1, 0.1], (0, 0, 0), name="bad", **kwargs)


def test_bad_ground_is_refused():
    with pytest.raises(wi.SceneError, match=r"ground 0: restitution must be in \[0, 1\]"):
        wi.SceneBuilder().add_ground(restitution=-0.2)
    with pytest.raises(wi.SceneError, match="ground 0 normal is a zero vector"):
        wi.SceneBuilder().add_ground(normal=(0, 0, 0))


def test_usd_round_trip_keeps_colliders_materials_grounds_and_filters(tmp_path):
    from pxr import Usd, UsdPhysics

    from warpimpulse import usd

    b = scenes.box_stack(3)
    b.bodies[1].friction, b.bodies[2].restitution = 0.25, 0.5
    b.add_ground(height=-1.0, normal=(0.0, 0.1, 1.0), friction=0.7)
    b.filter_collision(0, 2)
    path = tmp_path / "stack.usda"
    usd.save_scene(b, path)
    stage = Usd.Stage.Open(str(path))
    colliders = sorted(str(p.GetPath()) for p in stage.Traverse() if p.HasAPI(UsdPhysics.CollisionAPI))
    assert colliders == ["/World/Ground0", "/World/Ground1", "/World/box0/geom", "/World/box1/geom", "/World/box2/geom"]
    back = usd.load_stage(path).builder
    assert [body.shape.size for body in back.bodies] == [(0.2, 0.2, 0.2)] * 3
    assert [round(body.friction, 6) for body in back.bodies] == [0.5, 0.25, 0.5]
    assert [body.restitution for body in back.bodies] == [0.0, 0.0, 0.5]
    assert back.collision_filters == {(0, 2)}
    assert len(back.grounds) == 2
    np.testing.assert_allclose(
        back.grounds[1].normal, np.array([0.0, 0.1, 1.0]) / np.linalg.norm([0, 0.1, 1]), atol=1e-6
    )
    assert back.grounds[1].height == pytest.approx(-1.0, abs=1e-6)
    assert back.grounds[1].friction == pytest.approx(0.7, rel=1e-6)
    # The model's colliders survive a recording without the builder (usd.scene.builder_from_model).
    from warpimpulse.usd.scene import builder_from_model

    again = builder_from_model(b.finalize())
    assert again.finalize().colliders.filter_pairs.tolist() == [[0, 2]]
    assert len(again.grounds) == 2 and again.bodies[2].restitution == 0.5


def test_usd_bad_material_names_the_prim(tmp_path):
    from warpimpulse import usd

    path = tmp_path / "ball.usda"
    b = _ball_builder()
    usd.save_scene(b, path)
    text = path.read_text().replace("physics:restitution = 0.5", "physics:restitution = 1.5")
    path.write_text(text)
    with pytest.raises(
        wi.SceneError, match=r"/World/PhysicsMaterials/material0: physics:restitution must be in \[0, 1\]"
    ):
        usd.load_stage(path)


def _ball_builder() -> wi.SceneBuilder:
    b = wi.SceneBuilder()
    s = wi.Shape("sphere", radius=0.1)
    m, inertia = s.mass_properties(1000.0)
    b.add_body(m, inertia, (0, 0, 1), shape=s, restitution=0.5, name="ball")
    return b


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"contact_solver": "lcp"}, "unknown contact_solver 'lcp'"),
        ({"broad_phase": "grid"}, "unknown broad_phase 'grid'"),
        ({"contact_margin": -1.0}, "contact_margin must be positive"),
        ({"contact_sweeps": 0}, "contact_sweeps must be an integer >= 1"),
    ],
)
def test_bad_contact_options_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        wi.Simulator(scenes.box_stack(1).finalize(), dt=0.01, **wi.StepOptions.fold(kwargs))


def test_all_pairs_broad_phase_finds_the_same_contacts_as_the_bvh():
    found = []
    for broad in ("bvh", "all_pairs"):
        sim = wi.Simulator(
            scenes.pile(60, seed=3).finalize(), dt=1.0 / 60.0, tolerance=1e-4, options=wi.StepOptions(broad_phase=broad)
        )
        sim.simulate(1.0)
        c = sim.contacts()
        found.append(sorted(zip(c.body_a.tolist(), c.body_b.tolist())))
    assert found[0] == found[1] and len(found[0]) > 60


def test_a_cart_driven_through_its_wheels_rolls_without_slipping():
    """Joints and contacts in one loop: a box on four hinged cylinder wheels, a torque on each wheel; friction
    at the ground turns it into forward motion."""
    b = wi.SceneBuilder()
    box = wi.Shape("box", size=(0.6, 0.3, 0.1))
    chassis = b.add_body(*box.mass_properties(500.0), (0.0, 0.0, 0.15), shape=box, name="chassis")
    wheel = wi.Shape("cylinder", radius=0.1, length=0.05)
    for i, (x, y) in enumerate([(0.25, 0.2), (0.25, -0.2), (-0.25, 0.2), (-0.25, -0.2)]):
        w = b.add_body(*wheel.mass_properties(500.0), (x, y, 0.1), quat_from_axis_angle([1, 0, 0], -math.pi / 2),
                       shape=wheel, friction=1.0, name=f"wheel{i}")  # fmt: skip
        b.add_joint_revolute(chassis, w, (x, y, 0.1), (0.0, 1.0, 0.0), name=f"axle{i}")
        b.add_force(w, torque=(0.0, 0.5, 0.0))
    b.add_ground(friction=1.0)
    sim = wi.Simulator(b.finalize(), dt=1.0 / 60.0)
    for stats in sim.simulate(1.0):
        assert stats.max_joint_error <= sim.tolerance and stats.max_penetration <= sim.tolerance
    v, w = sim.linear_velocities(), sim.angular_velocities()
    assert sim.positions()[0, 0] > 0.5 and v[0, 0] > 1.0
    np.testing.assert_allclose(w[1:, 1] * 0.1, v[1:, 0], rtol=1e-2)  # v = w r at every wheel
    assert abs(sim.positions()[0, 1]) < 1e-4  # straight


def test_composed_steps_fall_back_to_order_two_near_contacts():
    b = _ball_builder()  # a ball 1 m up, falling onto the ground
    b.add_ground()
    sim = wi.Simulator(b.finalize(), dt=1.0 / 60.0, order=4)
    stats = sim.simulate(1.0)
    high = [s for s, k in zip(stats, range(len(stats))) if k < 10]  # 0.9 m above the ground: no contact ahead
    assert all(s.order == 4 and s.fallback == "" for s in high)
    near = [s for s in stats if s.contacts]
    assert near and all(s.order == 2 and s.fallback == "contacts" for s in near)
    assert sim.positions()[0, 2] >= 0.1 - sim.tolerance  # resting on the ground


def _car_on_ground(steering: float, seconds: float, tolerance: float = 1e-6) -> wi.Simulator:
    sim = wi.Simulator(scenes.car(steering=steering, ground=True).finalize(), dt=1.0 / 60.0, tolerance=tolerance)
    for stats in sim.simulate(seconds):
        assert stats.converged and stats.max_penetration <= sim.tolerance
    return sim


def _yaw(sim: wi.Simulator) -> float:
    r = rotations(sim.orientations()[0])
    return math.atan2(r[1, 0], r[0, 0])


def test_the_car_drives_straight_on_the_ground():
    """The paper's car with its wheel servos at 5 rad/s on wheels of 0.3 m: it drives at 1.5 m/s along x."""
    sim = _car_on_ground(0.0, 1.0)
    v = sim.linear_velocities()[0]
    assert v[0] == pytest.approx(scenes.CAR_WHEEL_SPEED * 0.3, rel=0.03)
    assert abs(v[1]) < 1e-4 * v[0] and abs(_yaw(sim)) < 1e-4 and sim.positions()[0, 0] > 1.0


def test_the_car_turns_left_when_it_steers():
    """Steered 0.3 rad to the left (at 1e-4 m: at 1e-6 m the joints and contacts, alternating, took 100
    iterations and more a step while it turned)."""
    sim = _car_on_ground(scenes.CAR_STEERING, 2.0, tolerance=1e-4)
    assert _yaw(sim) > math.radians(10.0) and sim.positions()[0, 1] > 0.5


WALK_SPEED = 1.0  # rad/s, the cranks' speed of the walking test


def walker_stride() -> float:
    """m per radian of crank: the x range a foot sweeps relative to the body while it is lowest (crank angles
    180 to 360 degrees), over that half turn."""
    swept = [scenes.walker_leg_points(a)[3][0] for a in (math.pi, 2.0 * math.pi)]
    return abs(swept[1] - swept[0]) / math.pi


def test_the_walking_machine_walks_on_the_ground():
    """Stood on its six feet (two tripods), its cranks at 1 rad/s, the walker moves its body along -x by at least
    80% of what its feet sweep in 4 s (it slips or stumbles by more otherwise), straight (1 cm sideways) and level
    (1 degree), every step converged: joints and contacts within the tolerance (1e-6), no NaN."""
    sim = wi.Simulator(scenes.walking_machine(crank_speed=WALK_SPEED, ground=True).finalize(), dt=1.0 / 60.0)
    x0 = sim.positions()[0].copy()
    for stats in sim.simulate(4.0):
        assert stats.converged and stats.max_joint_error <= sim.tolerance and stats.max_penetration <= sim.tolerance
        r = rotations(sim.orientations()[0])
        assert r[2, 2] > math.cos(math.radians(1.0))  # level
    moved = x0 - sim.positions()[0]
    assert np.all(np.isfinite(sim.positions()))
    assert moved[0] >= 0.8 * walker_stride() * WALK_SPEED * 4.0 and abs(moved[1]) < 0.01


def test_batched_worlds_refuse_contacts():
    with pytest.raises(wi.SceneError, match="batched worlds do not take contacts yet"):
        scenes.box_stack(2).replicate(2)
    with pytest.raises(wi.SceneError, match="ground 0: a replicated scene takes no additions"):
        scenes.binary_tree(3).replicate(2).add_ground()


def test_paper_contact_solver_holds_a_stack_to_the_tolerance():
    """The "paper" solver (one sweep a prediction) closes pushing contacts to touching: with the pgs solver's
    half-tolerance slop it ran out of iterations on 59 of 60 steps of this stack (9 of 60 at 0)."""
    sim = wi.Simulator(
        scenes.box_stack(10).finalize(),
        1.0 / 60.0,
        tolerance=1e-4,
        contact_solver="paper",
        on_max_iterations="warn",
        options=wi.StepOptions(max_substep_depth=0),
    )
    assert sim.contact_stage.position_slop == 0.0
    short = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(60):
            stats = sim.step()
            short += not stats.converged
    assert short <= 15, f"{short} of 60 steps short of the tolerance"


@pytest.mark.parametrize("count", [1, 2, 7, 64, 300])
def test_the_cpu_sort_of_contacts_is_the_radix_sorts_order(count):
    """`contacts.sort_pairs` sorts with numpy on a CPU (Warp's CPU radix sort takes ~80 us whatever the count): the
    same stable order as the radix sort, ties (contacts at one height) in their first order, negative keys first,
    and nothing past `count` moved."""
    import warp as wp

    from warpimpulse.contacts import sort_pairs

    rng = np.random.default_rng(count)
    keys = rng.integers(-5, 6, 2 * count).astype(np.int32)  # few distinct keys: many ties
    values = np.arange(2 * count, dtype=np.int32)
    ours = [wp.array(keys, dtype=wp.int32, device="cpu"), wp.array(values, dtype=wp.int32, device="cpu")]
    radix = [wp.array(keys, dtype=wp.int32, device="cpu"), wp.array(values, dtype=wp.int32, device="cpu")]
    sort_pairs(*ours, count)
    wp.utils.radix_sort_pairs(*radix, count)
    assert np.array_equal(ours[0].numpy()[:count], radix[0].numpy()[:count])
    assert np.array_equal(ours[1].numpy()[:count], radix[1].numpy()[:count])
    assert np.array_equal(ours[0].numpy()[count:], keys[count:])
    assert np.array_equal(ours[1].numpy()[count:], values[count:])
