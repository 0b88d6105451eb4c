"""The world inverse inertia J~^-1 = R J^-1 R^T is kept as its upper triangle (`kernels/inertia.py`), and a body
built on its principal axes forms it from its inverse inertia's diagonal: checked against numpy's R J^-1 R^T for
diagonal, non-diagonal and static bodies, the principal path against the general one bit for bit, and the K
that the engine assembles from the packed inertias of bodies with full inertia tensors against a dense numpy K
built from the bodies (tests/reference.py)."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from numpy_checks import Internals, rotations
from reference import numpy_k
from rigs import Rig
from warpimpulse.kernels import inertia, rigid

from warpimpulse.model import principal_axes

F64, VEC3, QUAT, MAT33 = wp.float64, wp.vec3d, wp.quatd, wp.mat33d


@wp.kernel
def unpacked(
    packed: wp.array(dtype=inertia.sym33d),
    u: wp.array(dtype=VEC3),
    matrix_out: wp.array(dtype=MAT33),
    product_out: wp.array(dtype=VEC3),
):
    b = wp.tid()
    matrix_out[b] = inertia.symmetric_matrix(packed[b])
    product_out[b] = inertia.symmetric_times(packed[b], u[b])


@wp.kernel
def full_product(inv_inertia: wp.array(dtype=MAT33), q: wp.array(dtype=QUAT), out: wp.array(dtype=MAT33)):
    """R J^-1 R^T as one 3x3, Warp's matrix products (what the frames pass stored before it kept 6 numbers)."""
    b = wp.tid()
    r = wp.quat_to_matrix(q[b])
    out[b] = r * inv_inertia[b] * wp.transpose(r)


def bodies(n: int, seed: int):
    """Random bodies a third each diagonal (principal axes), non-diagonal and static (zero inverse), random
    orientations; the Model's arrays of them (`Model.set_masses`: `rigid.principal_terms`)."""
    rng = np.random.default_rng(seed)
    inertia_ = np.zeros((n, 3, 3))
    inertia_[:, range(3), range(3)] = rng.uniform(0.1, 2.0, (n, 3))
    kind = np.arange(n) % 3
    for b in np.flatnonzero(kind == 1):
        r = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        inertia_[b] = r @ inertia_[b] @ r.T
    inv = np.linalg.inv(inertia_)
    inv[kind == 2] = 0.0
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    arrays = [wp.array(inertia_, dtype=MAT33), wp.array(inv, dtype=MAT33)]
    moments = wp.array(principal_axes(inertia_, kind != 2)[0], dtype=VEC3)
    principal, euler, inv_principal = wp.zeros(n, dtype=wp.int32), wp.zeros(n, dtype=VEC3), wp.zeros(n, dtype=VEC3)
    launch = dict(inputs=[*arrays, moments], outputs=[principal, euler, inv_principal], device="cpu")
    wp.launch(rigid.principal_terms, n, **launch)
    assert np.all(principal.numpy()[kind == 1] == rigid.TURNED)  # by its full inverse: R J^-1 R^T
    return kind, inv, q, principal, inv_principal, arrays[1]


def world_inverse(principal, inv_principal, inv_inertia, q) -> np.ndarray:
    out = wp.zeros(len(q), dtype=inertia.sym33d)
    wp.launch(
        inertia.world_inverse_inertia, len(q), inputs=[principal, inv_principal, inv_inertia, wp.array(q, dtype=QUAT)],
        outputs=[out], device="cpu",
    )  # fmt: skip
    return out.numpy()


def test_packed_world_inverse_inertia_is_r_j_inverse_r_t():
    """Upper triangle, its mirror and S u against numpy at 1e-14 of the matrix's largest entry, for the three
    kinds of body; the DIAGONAL flag is set for the diagonal ones and the static ones (diagonal zeros) only."""
    kind, inv, q, principal, inv_principal, inv_inertia = bodies(60, 3)
    assert np.array_equal(principal.numpy() == rigid.DIAGONAL, kind != 1)
    packed = world_inverse(principal, inv_principal, inv_inertia, q)
    r = rotations(q)
    ref = r @ inv @ np.swapaxes(r, 1, 2)
    u = np.random.default_rng(4).normal(size=(len(q), 3))
    matrix, product = wp.zeros(len(q), dtype=MAT33), wp.zeros(len(q), dtype=VEC3)
    wp.launch(
        unpacked, len(q), inputs=[wp.array(packed, dtype=inertia.sym33d), wp.array(u, dtype=VEC3)],
        outputs=[matrix, product], device="cpu",
    )  # fmt: skip
    scale = np.maximum(np.abs(ref).max(axis=(1, 2)), 1e-300)
    upper = ref[:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]
    assert (np.abs(packed - upper).max(axis=1) <= 1e-14 * scale).all()
    assert (np.abs(matrix.numpy() - ref).max(axis=(1, 2)) <= 1e-14 * scale).all()
    assert (np.abs(product.numpy() - np.einsum("nij,nj->ni", ref, u)).max(axis=1) <= 1e-14 * scale * 3.0).all()
    assert not packed[kind == 2].any()
    assert np.abs(packed[kind == 1][:, [1, 2, 4]]).min() > 1e-6  # the non-diagonal bodies' products of inertia


def test_packed_triangle_holds_the_full_products_bits():
    """R diag(d) from the diagonal alone is the matrix product's R J^-1 bit for bit (its terms with the zeros
    add nothing), so a diagonal body's J~^-1 is the same read either way; and either way the stored triangle is
    that of the full product R J^-1 R^T, bit for bit."""
    kind, inv, q, principal, inv_principal, inv_inertia = bodies(60, 5)
    packed = world_inverse(principal, inv_principal, inv_inertia, q)
    general = wp.zeros_like(principal)
    assert np.array_equal(packed, world_inverse(general, inv_principal, inv_inertia, q))
    full = wp.zeros(len(q), dtype=MAT33)
    wp.launch(full_product, len(q), inputs=[inv_inertia, wp.array(q, dtype=QUAT)], outputs=[full], device="cpu")
    assert np.array_equal(packed, full.numpy()[:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]])


@pytest.mark.parametrize("joint", ["ball", "revolute", "universal"])
def test_k_of_full_inertia_bodies_matches_dense_numpy(joint):
    """Two bodies with full inertia tensors on a joint, moved off their start: the K the engine assembles from
    the packed J~^-1 (CG's slots) and the Cholesky solution (its columns) against K = J M^-1 J^T in numpy."""
    rig = Rig(joint, seed=7, parent_dynamic=True)
    sim = rig.sim
    sim.step(5)
    k = numpy_k(rig.b, sim.positions(), sim.orientations(), Internals(sim).rows())
    assembled = Internals(sim).assembled_k()
    assert np.abs(assembled - k).max() <= 1e-13 * np.abs(k).max()
    rhs = np.random.default_rng(2).normal(size=(sim.model.constraint_count, 3))
    ref = np.linalg.solve(k, rhs.ravel()).reshape(-1, 3)
    assert np.abs(Internals(sim).solve(rhs) - ref).max() <= 1e-10 * np.abs(ref).max()
