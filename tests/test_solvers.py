"""Solver agreement: Cholesky, CG and a dense numpy solve of K = J M^-1 J^T built in numpy from the bodies
and constraints (tests/reference.py, not the engine's assembly kernel); the iterative baseline."""

import numpy as np
import pytest
import warp as wp
from numpy_checks import Internals
from reference import numpy_k

import warpimpulse as wi
from warpimpulse import scenes
from warpimpulse.solver import CGSolver, CholeskySolver


@pytest.mark.parametrize(
    "scene",
    [
        lambda: scenes.binary_tree(31),
        lambda: scenes.star(15),
        lambda: scenes.chain(6, "revolute"),
        lambda: scenes.chain(6, "universal"),
        lambda: scenes.chain(6, "prismatic"),
        lambda: scenes.chain(4, "planar"),
    ],
    ids=["tree31", "star15", "chain_revolute", "chain_universal", "chain_prismatic", "chain_planar"],
)
@pytest.mark.parametrize("formulation", ["constraint", "body"])
def test_cholesky_cg_and_dense_agree(scene, formulation):
    """Both matrices the Cholesky solver can factor (K, or the augmented body-joint matrix) give K's solution."""
    builder = scene()
    model = builder.finalize()
    sim = wi.Simulator(model, 1 / 60, options=wi.StepOptions(formulation=formulation))
    sim.simulate(0.2)  # move away from the symmetric start
    cg = CGSolver(model, sim.frames, tolerance=1e-15)
    cg.prepare()
    k = numpy_k(builder, sim.positions(), sim.orientations(), Internals(sim).rows())
    assert np.allclose(k, k.T, atol=1e-12 * np.abs(k).max()), "K must be symmetric"
    assert np.linalg.eigvalsh(k).min() > 0.0, "K must be positive definite"

    rng = np.random.default_rng(1)
    rhs_np = rng.normal(size=(model.constraint_count, 3))
    rhs = wp.array(rhs_np, dtype=wp.vec3d)
    chol, iterative = wp.zeros_like(rhs), wp.zeros_like(rhs)
    assert isinstance(sim.linear, CholeskySolver) and sim.linear.pattern.formulation == formulation
    sim.linear.solve(rhs, chol)
    cg.solve(rhs, iterative)
    ref = np.linalg.solve(k, rhs_np.ravel()).reshape(-1, 3)
    scale = np.abs(ref).max()
    assert np.abs(chol.numpy() - ref).max() <= 1e-10 * scale
    assert np.abs(iterative.numpy() - ref).max() <= 1e-10 * scale


def test_solvers_give_the_same_motion():
    """Cholesky and CG reach the same state; the paper's iterative method agrees to its tolerance. (The
    Cholesky solver without `carry` and `reuse_factor`, which CG does not take: with them the iterations start
    elsewhere and end elsewhere within the tolerance.)"""
    results = {}
    for solver in ("cholesky", "cg", "iterative"):
        carry = {"carry": False, "reuse_factor": False} if solver == "cholesky" else {}
        sim = wi.Simulator(
            scenes.binary_tree(15).finalize(), 1 / 30, tolerance=1e-8, solver=solver, **wi.StepOptions.fold(carry)
        )
        sim.simulate(0.5)
        results[solver] = sim.positions()
    assert np.abs(results["cholesky"] - results["cg"]).max() < 1e-9
    assert np.abs(results["cholesky"] - results["iterative"]).max() < 1e-5


def test_tree127_takes_few_iterations():
    """The paper's Table 1 reports 2 joint-correction iterations for the 127-body tree at h = 1/30, 1e-6."""
    sim = wi.Simulator(scenes.binary_tree(127).finalize(), 1 / 30, tolerance=1e-6)
    stats = sim.simulate(3.0)
    mean = np.mean([s.joint_iterations for s in stats])
    assert 1.5 <= mean <= 3.5, mean
    assert all(s.velocity_iterations <= 1 for s in stats)


@pytest.mark.parametrize("formulation", ["constraint", "body"])
def test_redundant_constraints_are_reported(formulation):
    """K's loop rows redundant with the tree are regularised and counted (tests/test_loops.py); the augmented
    matrix has no assembled diagonal to judge them by, so there they stay an error naming the joint."""
    b = wi.SceneBuilder()
    body = b.add_body(1.0, (0.1, 0.1, 0.1), (0.0, 0.0, -1.0))
    b.add_joint_fixed(None, body, (0.0, 0.0, 0.0), name="weld")
    b.add_joint_revolute(None, body, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), name="hinge")
    if formulation == "constraint":
        sim = wi.Simulator(b.finalize(), 1 / 60, options=wi.StepOptions(formulation=formulation))
        assert sim.redundant_rows == 5 and sim.step().converged
        return
    with pytest.raises(wi.SingularSystemError, match="singular at joint 'hinge'"):
        wi.Simulator(b.finalize(), 1 / 60, options=wi.StepOptions(formulation=formulation))


def test_a_loop_with_redundant_rows_solves_consistent_systems():
    """The planar four-bar's K is singular (3 of its loop rows repeat the tree's); the factor regularises those
    pivots (kernels/cholesky.py, `factor_column`). For a right-hand side K x that K can meet, the solve still
    meets it: K lambda = K x to 1e-10 of its size, against K built in numpy (tests/reference.py)."""
    builder = scenes.four_bar()
    sim = wi.Simulator(builder.finalize(), 1 / 60)
    sim.simulate(0.3)
    assert sim.redundant_rows == 3
    k = numpy_k(builder, sim.positions(), sim.orientations(), Internals(sim).rows())
    assert np.linalg.matrix_rank(k, tol=1e-10 * np.abs(k).max()) == len(k) - 3
    rhs = k @ np.random.default_rng(2).normal(size=len(k))
    impulse = Internals(sim).solve(rhs.reshape(-1, 3)).ravel()
    assert np.abs(k @ impulse - rhs).max() <= 1e-10 * np.abs(rhs).max()


def test_auto_formulation_keeps_stars_linear():
    """A star's K is dense (every joint shares the root): "auto" takes the augmented matrix, whose factor
    has a few block updates per joint, while a tree keeps K."""
    tree, star = scenes.binary_tree(127).finalize(), scenes.star(255).finalize()
    assert tree.topology.pattern("auto").formulation == "constraint"
    pattern = star.topology.pattern("auto")
    assert pattern.formulation == "body"
    assert pattern.updates < 20 * star.constraint_count
    assert star.topology.pattern("constraint").updates > 100 * pattern.updates


def test_a_long_chain_is_not_mistaken_for_singular():
    """The root pivot of a 10,000-link chain is ~1e-13 of its block (rotating the whole chain): ill-conditioned,
    not redundant. The redundant weld + hinge above has pivots of round-off or below; the tolerance sits between."""
    sim = wi.Simulator(scenes.chain(10_000).finalize(), 1 / 60, tolerance=1e-6)
    stats = sim.step()
    assert stats.converged and stats.max_joint_error <= 1e-6
