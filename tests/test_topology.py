"""The symbolic analysis (warpimpulse/topology.py, numpy throughout) against a dense numeric factorization: on
trees, stars, chains, rings, graphs with several loops and floating islands, the factor pattern is exactly the
set of blocks a dense Cholesky of a random matrix with the scene's coupling fills, in the elimination order."""

from __future__ import annotations

import numpy as np
import pytest

import warpimpulse as wi
from warpimpulse import scenes, topology


def _ring(links: int) -> wi.SceneBuilder:
    b = scenes.chain(links, joint="ball")
    b.add_joint_ball(0, links - 1, b.bodies[links - 1].position, name="close")
    return b


def _tree_with_loops() -> wi.SceneBuilder:
    b = scenes.binary_tree(31)
    b.add_joint_ball(7, 20, b.bodies[20].position, name="across")
    b.add_joint_ball(None, 12, b.bodies[12].position, name="to_world")
    b.add_joint_ball(3, 30, b.bodies[30].position, name="far")
    return b


def _islands() -> wi.SceneBuilder:
    b = wi.SceneBuilder()
    for i in range(6):
        b.add_body(1.0, [1.0, 1.0, 1.0], (i, 0.0, 0.0))
    b.add_joint_ball(1, 2, (1.5, 0.0, 0.0))
    b.add_joint_ball(4, 5, (4.5, 0.0, 0.0))
    b.add_joint_ball(3, 4, (3.5, 0.0, 0.0))
    return b


SCENES = {
    "tree31": lambda: scenes.binary_tree(31),
    "star15": lambda: scenes.star(15),
    "chain9_mixed": lambda: scenes.chain(9, joint=["ball", "universal", "revolute"]),
    "ring12": lambda: _ring(12),
    "tree31_loops": _tree_with_loops,
    "islands": _islands,
}


def _blocks(pattern: topology.Pattern, unknowns: int, coupled: np.ndarray) -> tuple[set, set]:
    """(the pattern's lower blocks, the lower blocks a dense factorization fills), in elimination positions."""
    n = len(pattern.perm)
    rng = np.random.default_rng(1)
    a = np.zeros((n, n))
    pos = np.full(unknowns, -1)
    pos[pattern.perm] = np.arange(n)
    i, j = pos[coupled[:, 0]], pos[coupled[:, 1]]
    keep = (i >= 0) & (j >= 0)
    a[i[keep], j[keep]] = rng.uniform(0.1, 1.0, keep.sum())
    a = a + a.T
    a += np.diag(np.abs(a).sum(axis=1) + 1.0)  # diagonally dominant: SPD; random entries cancel by no chance
    filled = np.linalg.cholesky(a) != 0.0  # a structural zero stays an exact zero
    dense = {(r, c) for r, c in zip(*np.nonzero(filled))}
    col = np.repeat(np.arange(n), np.diff(pattern.col_start))
    return set(zip(pattern.col_row.tolist(), col.tolist())), dense


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("level_order", [False, True])
def test_factor_pattern_is_the_dense_fill(scene, level_order):
    graph = SCENES[scene]().finalize().graph
    top = topology.analyze(graph, level_order=level_order)
    u, v = topology._coupling(graph)
    pattern, dense = _blocks(top.pattern("constraint"), graph.constraint_count, np.stack([u, v], axis=1))
    assert pattern == dense
    # The body-joint matrix: a body's two parts and each constraint on it.
    nb = graph.body_count
    body, constraint = topology._body_constraints(graph)
    pairs = np.concatenate([np.stack([body, 2 * nb + constraint], 1), np.stack([nb + body, 2 * nb + constraint], 1)])
    pattern, dense = _blocks(top.pattern("body"), 2 * nb + graph.constraint_count, pairs)
    assert pattern == dense


@pytest.mark.parametrize("scene", SCENES)
def test_spanning_tree_depths_and_loops(scene):
    """The tree joints form a spanning forest: a grounded one holds a body at depth 0, any other joins bodies one
    level apart, and every body not at depth 0 hangs from exactly one; the loops are the joints left over."""
    graph = SCENES[scene]().finalize().graph
    depth, loops = topology._spanning_tree(graph)
    tree = np.setdiff1d(np.arange(graph.joint_count), loops)
    parent, child = graph.joint_parent[tree], graph.joint_child[tree]
    grounded = parent == -1
    assert np.all(depth[child[grounded]] == 0)
    assert np.all(np.abs(depth[child[~grounded]] - depth[parent[~grounded]]) == 1)
    deeper = np.where(depth[child] > np.where(grounded, -1, depth[np.maximum(parent, 0)]), child, parent)
    hung = deeper[depth[deeper] > 0]
    assert sorted(hung.tolist()) == np.flatnonzero(depth > 0).tolist()
    assert len(loops) == {"ring12": 1, "tree31_loops": 3}.get(scene, 0)
