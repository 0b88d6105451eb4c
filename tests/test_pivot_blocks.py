"""The factor's 3x3 pivot block (kernels/cholesky.py, `cholesky3_inverse`) against numpy: L^-1 of SPD blocks
with condition numbers up to 1e8, and the pivot checks (a pivot not above `tiny` counted and replaced by
`fallback` before the next is formed) on blocks whose first, second or third pivot is bad, against an
elimination in turn written here in numpy. Every block of every factor goes through this function; the solves
against a dense numpy solve are in tests/test_solvers.py."""

import numpy as np
import pytest
import warp as wp
from warpimpulse.kernels.cholesky import cholesky3_inverse

import warpimpulse as wi


@wp.kernel
def _pivots(blocks: wp.array(dtype=wp.mat33d), tiny: wp.array(dtype=wp.float64), fallback: wp.float64,
            inverse: wp.array(dtype=wp.mat33d), bad: wp.array(dtype=int)):  # fmt: skip
    i = wp.tid()
    li, count = cholesky3_inverse(blocks[i], tiny[i], fallback)
    inverse[i] = li
    bad[i] = count


def _run(blocks: np.ndarray, tiny: np.ndarray, fallback: float) -> tuple[np.ndarray, np.ndarray]:
    inverse = wp.zeros(len(blocks), dtype=wp.mat33d, device="cpu")
    bad = wp.zeros(len(blocks), dtype=int, device="cpu")
    wp.launch(
        _pivots,
        dim=len(blocks),
        inputs=[wp.array(blocks, dtype=wp.mat33d, device="cpu"), wp.array(tiny, dtype=wp.float64, device="cpu"),
                fallback, inverse, bad],
        device="cpu",
    )  # fmt: skip
    return inverse.numpy(), bad.numpy()


def _in_turn(a: np.ndarray, tiny: float, fallback: float) -> tuple[np.ndarray, int]:
    """L^-1 by eliminating in turn, each pivot not above tiny replaced by fallback (numpy, from the definition)."""
    a = np.tril(a) + np.tril(a, -1).T
    low, bad = np.zeros((3, 3)), 0
    for i in range(3):
        d = a[i, i] - low[i, :i] @ low[i, :i]
        if not d > tiny:
            bad, d = bad + 1, fallback
        low[i, i] = np.sqrt(d)
        for r in range(i + 1, 3):
            low[r, i] = (a[r, i] - low[r, :i] @ low[i, :i]) / low[i, i]
    return np.linalg.inv(low), bad


def test_spd_blocks_match_numpy():
    """L^-1 of random SPD blocks (condition numbers 1 to 1e8, scales 1e-6 to 1e6) is numpy's, and nothing is bad."""
    rng = np.random.default_rng(12)
    blocks = []
    for cond in np.logspace(0, 8, 40):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        scale = 10.0 ** rng.uniform(-6, 6)
        blocks.append(scale * q @ np.diag([1.0, cond**-0.5, 1.0 / cond]) @ q.T)
    blocks = np.array(blocks)
    inverse, bad = _run(blocks, np.zeros(len(blocks)), 1.0)
    assert not bad.any()
    for a, li in zip(blocks, inverse):
        ref = np.linalg.inv(np.linalg.cholesky(a))
        cond = np.linalg.cond(a)
        assert np.allclose(np.triu(li, 1), 0.0)
        assert np.abs(li - ref).max() <= 1e-13 * cond * np.abs(ref).max(), (a, li, ref)


@pytest.mark.parametrize(("which", "expected"), [(0, 1), (1, 1), (2, 1), ((1, 2), 1), ((0, 1, 2), 3)])
def test_bad_pivots_are_counted_and_replaced(which, expected):
    """A block whose pivots `which` are 0 (a redundant row; a zero block) counts its bad pivots, and each is
    replaced by `fallback` before the next pivot is formed, as eliminating in turn does (a replaced pivot changes
    the next: pivot 1 replaced makes pivot 2 of the `(1, 2)` blocks good; the zero block has all three bad)."""
    rng = np.random.default_rng(3)
    which = (which,) if isinstance(which, int) else which
    blocks, tiny = [], []
    for _ in range(10):
        low = np.tril(rng.normal(size=(3, 3)))
        for i in range(3):
            low[i, i] = 0.0 if i in which else 1.0 + abs(low[i, i])
        a = low @ low.T if len(which) < 3 else np.zeros((3, 3))  # its pivot i is low[i, i]^2: 0 for `which`
        blocks.append(a)
        tiny.append(1e-9 * np.abs(a).max())
    blocks, tiny = np.array(blocks), np.array(tiny)
    fallback = 2.5
    inverse, bad = _run(blocks, tiny, fallback)
    for a, t, li, count in zip(blocks, tiny, inverse, bad):
        ref, ref_bad = _in_turn(a, t, fallback)
        assert count == ref_bad == expected
        assert np.abs(li - ref).max() <= 1e-9 * np.abs(ref).max(), (a, li, ref)


@pytest.mark.parametrize("order", [2, 4])
def test_padded_pivots_are_not_the_scenes(order):
    """A body of 4e-16 kg on two slides from the world through a body of 4e-10 kg (the light body `load_mjcf`
    puts on gymnasium's pusher goal, whose slides it chains): a slide's two linear rows, padded to a 3x3 block
    with a unit pivot, form a block ~1e15 across, where the padded 1 fell below the tolerance relative to it and
    the simulator refused to build ("the system matrix is singular"). The padded pivot is no pivot of the scene:
    the simulator builds, and the bodies move as their slides let them: both along x at their common rate, the
    goal falling along y."""
    builder = wi.SceneBuilder(gravity=(0.0, -9.81, 0.0))
    light = builder.add_body(4e-16, (6e-19, 6e-19, 6e-19), (0.0, 0.0, 0.0), linear_velocity=(0.3, 0.0, 0.0))
    goal = builder.add_body(4e-10, (6e-13, 6e-13, 1e-12), (0.0, 0.0, 0.0), linear_velocity=(0.3, 0.0, 0.0))
    builder.add_joint_prismatic(None, light, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    builder.add_joint_prismatic(light, goal, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    sim = wi.Simulator(builder.finalize("cpu"), 0.01, tolerance=1e-9, order=order)
    stats = sim.step(50)
    assert stats.converged and stats.max_joint_error <= 1e-9
    x = sim.positions()
    assert x[1] == pytest.approx([0.15, -0.5 * 9.81 * 0.5**2, 0.0], abs=1e-9)  # slides along x, falls along y
    assert x[0][1] == pytest.approx(0.0, abs=1e-12)  # the light body keeps to its slide (x only)
