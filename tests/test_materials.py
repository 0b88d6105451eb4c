"""How a contact combines the materials of its two sides, against analytic bounces and slides: the friction is
the geometric mean of the two coefficients, the restitution the larger (docs/contacts.md), for a body on the
ground, a body on another (static) body, and both read from USD materials (`reader._material`: the dynamic
friction).

Each scene gives the two sides different materials, once one way round and once the other, so that a rule
that reads one side only, or the wrong one, fails one of the two: a ball dropped from h rebounds to e^2 h, and
a box launched at v0 slides v0^2 / (2 mu g) before it stops."""

from __future__ import annotations

import math

import numpy as np
import pytest

import warpimpulse as wi

G = 9.81
DT = 1.0 / 240.0
DROP = 0.2  # m, the ball's fall to its first bounce
V0 = 1.0  # m/s, the box's launch speed along x
BALL = wi.Shape("sphere", radius=0.1)
BOX = wi.Shape("box", size=(0.2, 0.2, 0.1))

# (the moving bodies' friction and restitution, the surface's): the combined friction sqrt(0.8 * 0.2) = 0.4 and
# restitution max(0.8, 0.2) = 0.8 either way round; a one-sided rule gives 0.8 or 0.2 instead.
CASES = {"body high, surface low": ((0.8, 0.8), (0.2, 0.2)), "body low, surface high": ((0.2, 0.2), (0.8, 0.8))}
MU, E = math.sqrt(0.8 * 0.2), 0.8


def _scene(body: tuple[float, float], surface: tuple[float, float], ground: bool) -> wi.SceneBuilder:
    """A ball above the surface at x = 0 and a box on it at x = 2 moving at V0 along x; the surface is the ground
    plane z = 0, or a static box whose top is z = 0 (a contact between two bodies)."""
    friction, restitution = body
    b = wi.SceneBuilder()
    m, inertia = BALL.mass_properties(1000.0)
    b.add_body(m, inertia, (0.0, 0.0, BALL.radius + DROP), shape=BALL, friction=friction, restitution=restitution,
               name="ball")  # fmt: skip
    m, inertia = BOX.mass_properties(1000.0)
    b.add_body(m, inertia, (2.0, 0.0, 0.5 * BOX.size[2]), linear_velocity=(V0, 0.0, 0.0), shape=BOX,
               friction=friction, restitution=restitution, name="box")  # fmt: skip
    if ground:
        b.add_ground(friction=surface[0], restitution=surface[1])
    else:
        slab = wi.Shape("box", size=(8.0, 2.0, 0.5))
        b.add_static_body((1.5, 0.0, -0.25), shape=slab, friction=surface[0], restitution=surface[1], name="slab")
    return b


def _bounce_and_slide(builder: wi.SceneBuilder) -> tuple[float, float]:
    """The ball's first rebound height over its drop (e^2), and the box's travel until it stops (m)."""
    sim = wi.Simulator(builder.finalize(), DT)
    names = [b.name.rsplit("/", 1)[-1] for b in builder.bodies]  # USD names them by prim path
    ball, box = names.index("ball"), names.index("box")
    x0 = sim.positions()[box, 0]
    apex, bounced, v_prev = None, False, 0.0
    for _ in range(int(0.45 / DT)):
        sim.step()
        z, v = sim.positions()[ball, 2] - BALL.radius, sim.linear_velocities()[ball, 2]
        bounced = bounced or v > 0.0
        if bounced and apex is None and v_prev > 0.0 >= v:
            apex = z + 0.5 * v_prev * v_prev / G  # the top between the two steps (free flight)
        v_prev = v
    assert apex is not None, "the ball did not rebounce within 0.45 s"
    assert abs(sim.linear_velocities()[box, 0]) < 1e-3, "the box still slides"
    return apex / DROP, float(sim.positions()[box, 0] - x0)


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("surface", ["ground", "static body"])
def test_contact_combines_both_materials(case, surface):
    """e^2 of the drop and v0^2 / (2 mu g) of travel with mu = sqrt(mu_a mu_b), e = max(e_a, e_b)."""
    body, other = CASES[case]
    rebound, travel = _bounce_and_slide(_scene(body, other, ground=surface == "ground"))
    assert rebound == pytest.approx(E * E, rel=0.02)
    assert travel == pytest.approx(V0 * V0 / (2.0 * MU * G), rel=0.03)


def test_usd_materials_combine_the_same_way(tmp_path):
    """The same scene through USD: each side's PhysicsMaterialAPI material (bound to the bodies' colliders and
    the ground plane), its dynamic friction the Coulomb coefficient; the static friction, set far off here, is
    not read."""
    from warpimpulse import usd

    body, other = CASES["body low, surface high"]
    path = tmp_path / "materials.usda"
    usd.save_scene(_scene(body, other, ground=True), path)
    text = path.read_text()
    assert text.count("physics:staticFriction") == 2
    path.write_text(text.replace("float physics:staticFriction = 0.2", "float physics:staticFriction = 1.5")
                    .replace("float physics:staticFriction = 0.8", "float physics:staticFriction = 0.01"))  # fmt: skip
    builder = usd.load_stage(path).builder
    rebound, travel = _bounce_and_slide(builder)
    assert rebound == pytest.approx(E * E, rel=0.02)
    assert travel == pytest.approx(V0 * V0 / (2.0 * MU * G), rel=0.03)
    np.testing.assert_allclose([g.friction for g in builder.grounds], [0.8])
