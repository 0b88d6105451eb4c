"""Checks on the raw state and the raw system matrix, with numpy only (tests/reference.py):

- |q| - 1 of the orientation quaternions as the engine stores them (no conversion that normalises);
- the energy of a 3D jointed system without gravity, from a numpy energy function (not `sim.energy()`);
- K against J M^-1 J^T built in numpy from the bodies and the constraints, and the solver's lambda against a
  dense numpy solve of that K, in both formulations of the Cholesky solver ("constraint": K itself; "body":
  the augmented body-joint matrix).
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy_checks import Internals
from reference import numpy_energy, numpy_k
from rigs import ball_chain, floating_body

import warpimpulse as wi
from warpimpulse import JOINT_TYPES, scenes


def test_quaternions_stay_unit_in_the_raw_state():
    """A body spinning at 12 rad/s, 0.2 rad a step: RK4 alone would change |q| by ~1e-8 a step."""
    b = wi.SceneBuilder(gravity=(0.0, 0.0, 0.0))
    b.add_body(1.0, (1.0, 2.0, 2.5), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), angular_velocity=(7.0, 9.0, -3.0))
    sim = wi.Simulator(b.finalize(), 1.0 / 60.0, options=wi.StepOptions(max_rotation=None))
    tree = wi.Simulator(scenes.binary_tree(31).finalize(), 1.0 / 60.0)
    worst = 0.0
    for _ in range(120):
        sim.step()
        tree.step()
        for q in (sim.orientations(), tree.orientations()):
            worst = max(worst, float(np.abs(np.linalg.norm(q, axis=1) - 1.0).max()))
    print(f"\nmax ||q| - 1| over 2 s: {worst:.1e}")
    assert worst < 1e-13


def spinning_chain():
    """The 3-link ball chain of test_rotation3d without gravity, every link spinning."""
    return ball_chain(
        [(1.0, 0.0, -0.2), (0.2, 1.0, 0.3), (-0.5, 0.4, -1.0)], [1.0, 0.8, 0.6], [1.0, 0.7, 0.5],
        [(0.3, 0.2, 1.0), (-1.0, 0.5, 0.2), (1.0, -0.5, 0.0)], gravity=(0.0, 0.0, 0.0),
    )  # fmt: skip


# Measured over 2 s at tolerance 1e-8: relative drift 3.3e-5 (chain, h = 1/200) and 5.3e-8 (floating body of every
# joint type, h = 1/100).
DRIFT = {"ball_chain": 1e-4, "every_joint": 1e-6}


@pytest.mark.parametrize("scene", sorted(DRIFT))
def test_energy_of_a_3d_jointed_system_without_gravity(scene):
    if scene == "ball_chain":
        builder, _ = spinning_chain()
        rate = 200
    else:
        builder = floating_body(seed=3, consistent=True)
        rate = 100
    sim = wi.Simulator(builder.finalize(), 1.0 / rate, tolerance=1e-8)

    def energy() -> float:
        return numpy_energy(builder, sim.positions(), sim.orientations(), sim.linear_velocities(),
                            sim.angular_velocities())  # fmt: skip

    e0 = energy()
    x0 = sim.positions()
    drift = 0.0
    for _ in range(2 * rate):
        sim.step()
        drift = max(drift, abs(energy() - e0) / e0)
    moved = float(np.abs(sim.positions() - x0).max())
    print(f"\n{scene}: energy {e0:.4f} J, max relative drift {drift:.2e} over 2 s; moved {moved:.2f} m")
    assert moved > 0.3
    assert drift < DRIFT[scene]


def all_kinds_chain() -> wi.SceneBuilder:
    """A chain through every joint type, so every basic constraint kind is in K."""
    return scenes.chain(len(JOINT_TYPES), sorted(JOINT_TYPES))


K_SCENES = {
    "tree31": lambda: scenes.binary_tree(31),
    "star15": lambda: scenes.star(15),
    "every_kind_chain": all_kinds_chain,
    "floating_every_joint": lambda: floating_body(seed=2, consistent=False),
}


@pytest.mark.parametrize("formulation", ["constraint", "body"])
@pytest.mark.parametrize("name", sorted(K_SCENES))
def test_system_matrix_is_j_inverse_mass_jt(name, formulation):
    builder = K_SCENES[name]()
    kinds = {int(c.kind) for c in builder.constraints}
    if name == "every_kind_chain":
        assert kinds == set(range(6))
    sim = wi.Simulator(builder.finalize(), 1.0 / 60.0, options=wi.StepOptions(formulation=formulation))
    sim.simulate(0.2)  # away from the symmetric start
    engine = Internals(sim)
    assert engine.formulation() == formulation
    k = numpy_k(builder, sim.positions(), sim.orientations(), engine.rows())
    scale = np.abs(k).max()
    assembled = engine.assembled_k()
    np.testing.assert_allclose(assembled, k, rtol=0, atol=1e-12 * scale)
    n = len(builder.constraints)
    rhs = np.random.default_rng(7).normal(size=(n, 3))
    expected = np.linalg.solve(k, rhs.ravel()).reshape(n, 3)
    np.testing.assert_allclose(engine.solve(rhs), expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    # Where two constraints share a body, K couples them: without its off-diagonal blocks lambda would differ.
    blocks = np.zeros_like(k)
    for i in range(n):
        blocks[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = k[3 * i : 3 * i + 3, 3 * i : 3 * i + 3]
    uncoupled = np.linalg.solve(blocks, rhs.ravel()).reshape(n, 3)
    assert np.abs(uncoupled - expected).max() > 0.1 * np.abs(expected).max()
