"""Constraints with fewer than 3 rows (LINE, AXIS: 2; PLANE, ANGLE: 1) are padded to 3x3 blocks with a unit pivot,
so their blocks' padded rows and columns stay zero through the factor; the factor and the assembly skip them
(kernels/cholesky.py `times_transpose`, `cholesky_inverse`; kernels/assemble.py `leading_rows_times`,
`times_leading_transpose`; the shapes: `CholeskySolver._slot_shape`). Checked here: each skipping product gives
the full product's bits on blocks with those zeros, the 2x2 and 1x1 pivots numpy's Cholesky factor, the factor of
a scene with every kind has its zeros where the shapes say, and its solve numpy's dense solve of K built in numpy
(tests/reference.py) in both formulations."""

import numpy as np
import pytest
import warp as wp
from numpy_checks import Internals
from reference import numpy_k
from warpimpulse.kernels.assemble import leading_rows_times, times_leading_transpose
from warpimpulse.kernels.cholesky import cholesky_inverse, times_transpose

import warpimpulse as wi
from warpimpulse import scenes

MAT33 = wp.mat33d
MIXED = ["revolute", "prismatic", "cylindrical", "universal", "planar", "ball", "fixed"]
"""Joints whose constraints have every kind and dimension: POINT + AXIS, LINE + ROTATION, LINE + AXIS,
POINT + ANGLE, PLANE + AXIS, POINT, POINT + ROTATION."""


@wp.kernel
def _products(a: wp.array(dtype=MAT33), b: wp.array(dtype=MAT33), dims: wp.array(dtype=int),
              skipped: wp.array2d(dtype=MAT33), full: wp.array2d(dtype=MAT33)):  # fmt: skip
    i = wp.tid()
    n = dims[i]
    skipped[i, 0] = times_transpose(a[i], b[i], n)
    full[i, 0] = a[i] * wp.transpose(b[i])
    skipped[i, 1] = leading_rows_times(wp.transpose(a[i]), b[i], n)
    full[i, 1] = wp.transpose(a[i]) * b[i]
    skipped[i, 2] = times_leading_transpose(b[i], wp.transpose(a[i]), n)
    full[i, 2] = b[i] * a[i]


def test_skipped_products_keep_the_full_products_bits():
    """On blocks whose columns (or, transposed, rows) from `dims` on are zero, each skipping product is the full
    3x3 product bit for bit (zeros compared without their sign), over scales 1e-6 to 1e6."""
    rng = np.random.default_rng(7)
    n = 300
    dims = np.tile([1, 2, 3], n // 3)
    a = rng.normal(size=(n, 3, 3)) * 10.0 ** rng.uniform(-6, 6, (n, 1, 1))
    b = rng.normal(size=(n, 3, 3)) * 10.0 ** rng.uniform(-6, 6, (n, 1, 1))
    for i, d in enumerate(dims):
        a[i, :, d:] = 0.0
    skipped, full = wp.zeros((n, 3), dtype=MAT33), wp.zeros((n, 3), dtype=MAT33)
    wp.launch(_products, n, inputs=[wp.array(a, dtype=MAT33), wp.array(b, dtype=MAT33), wp.array(dims, dtype=int)],
              outputs=[skipped, full], device="cpu")  # fmt: skip
    skipped, full = skipped.numpy() + 0.0, full.numpy() + 0.0
    assert np.array_equal(skipped, full)
    assert np.abs(full[:, 0]).min() > 0.0  # a b^T has no zero entry: the skipped products are exactly 0
    for d in (1, 2):  # the rows (columns) the other two leave unformed are zero in the full products
        assert not full[dims == d][:, 1, d:, :].any() and not full[dims == d][:, 2, :, d:].any()


@wp.kernel
def _pivots(blocks: wp.array(dtype=MAT33), rows: wp.array(dtype=int), tiny: wp.array(dtype=wp.float64),
            inverse: wp.array(dtype=MAT33), bad: wp.array(dtype=int)):  # fmt: skip
    i = wp.tid()
    li, count = cholesky_inverse(blocks[i], rows[i], tiny[i], wp.float64(1.0))
    inverse[i] = li
    bad[i] = count


def _run_pivots(blocks, rows, tiny):
    inverse, bad = wp.zeros(len(blocks), dtype=MAT33), wp.zeros(len(blocks), dtype=int)
    inputs = [wp.array(blocks, dtype=MAT33), wp.array(rows, dtype=int), wp.array(tiny, dtype=wp.float64)]
    wp.launch(_pivots, len(blocks), inputs=inputs, outputs=[inverse, bad], device="cpu")
    return inverse.numpy(), bad.numpy()


def _padded(block: np.ndarray, rows: int) -> np.ndarray:
    """A pivot block of a constraint of `rows` rows: its leading block, then the unit padding."""
    out = np.eye(3)
    out[:rows, :rows] = block[:rows, :rows]
    return out


def test_small_pivots_match_numpy():
    """L^-1 of padded SPD pivot blocks (2 and 1 rows, condition numbers to 1e8) is numpy's, its padding the
    identity; a bad leading pivot is counted and replaced as the 3x3 path does."""
    rng = np.random.default_rng(12)
    blocks, rows = [], []
    for cond in np.logspace(0, 8, 30):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        a = 10.0 ** rng.uniform(-3, 3) * q @ np.diag([1.0, cond**-0.5, 1.0 / cond]) @ q.T
        for r in (1, 2):
            blocks.append(_padded(a, r))
            rows.append(r)
    blocks, rows = np.array(blocks), np.array(rows)
    inverse, bad = _run_pivots(blocks, rows, np.zeros(len(blocks)))
    assert not bad.any()
    for a, li in zip(blocks, inverse):
        ref = np.linalg.inv(np.linalg.cholesky(a))
        assert np.abs(li - ref).max() <= 1e-13 * np.linalg.cond(a) * np.abs(ref).max(), (a, li, ref)
    singular = np.array([_padded(np.diag([1.0, 0.0, 0.0]), 2), _padded(np.zeros((3, 3)), 1)])
    inverse, bad = _run_pivots(singular, np.array([2, 1]), np.full(2, 1e-9))
    assert bad.tolist() == [1, 1]
    assert np.allclose(inverse, np.eye(3))  # each bad pivot replaced by the fallback 1


@pytest.mark.parametrize("formulation", ["constraint", "body"])
def test_a_factor_of_every_kind_has_its_zeros_and_solves_k(formulation):
    """A chain of every joint (every constraint kind): each off-diagonal block of its factor is zero outside its
    shape (the structure the skipped products rely on), each diagonal block's padding is diagonal, and a solve with
    the factor is numpy's dense solve of K (built in numpy, not by the engine's kernels)."""
    builder = scenes.chain(14, MIXED)
    model = builder.finalize()
    sim = wi.Simulator(model, 1 / 120, options=wi.StepOptions(formulation=formulation))
    sim.simulate(0.2)  # away from the symmetric start
    solver = sim.linear
    assert solver.pattern.formulation == formulation
    shape = solver._slot_shape(model, solver.pattern)
    assert {tuple(s) for s in shape} >= {(1, 3), (3, 1), (2, 3), (3, 2)}
    values = solver.values.numpy()
    diagonal = np.zeros(len(values), dtype=bool)
    diagonal[solver.pattern.col_start[:-1]] = True
    for block, (r, c), diag in zip(values, shape, diagonal):
        if diag:
            assert np.array_equal(block[r:, :r], np.zeros((3 - r, r))) and np.allclose(block[r:, r:], np.eye(3 - r))
        else:
            assert not block[r:, :].any() and not block[:, c:].any()
    k = numpy_k(builder, sim.positions(), sim.orientations(), Internals(sim).rows())
    rhs = np.random.default_rng(1).normal(size=(model.constraint_count, 3))
    ref = np.linalg.solve(k, rhs.ravel()).reshape(-1, 3)
    assert np.abs(Internals(sim).solve(rhs) - ref).max() <= 1e-10 * np.abs(ref).max()
