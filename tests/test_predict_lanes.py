"""The CPU predicts bodies LANES at a time (`rigid.predict_group`): each lane must give the scalar path's values
bit for bit, whatever the mix of bodies (static, torqued, fast spin, diagonal inertias with inertias turned off
their axes: those groups go one body at a time), bodies of diagonal or of turned inertia (`rigid.TURNED`,
predicted in their principal frames) and a count that is not a multiple of LANES. The fused schedule predicts in
lanes too, so tests/test_schedules.py checks the same through whole steps; this checks the prediction alone, on
bodies no scene has, and the rotations the lanes use against Warp's own."""

from __future__ import annotations

import numpy as np
import warp as wp
from warpimpulse.kernels import rigid

from warpimpulse.model import principal_axes

F64, VEC3, QUAT, MAT33 = wp.float64, wp.vec3d, wp.quatd, wp.mat33d


def bodies(n: int, seed: int, mixed: bool, turned: bool = False) -> tuple[list, list]:
    """Random bodies: diagonal inertia (with `turned`, every inertia turned off its axes), no torque, one RK4 step
    each (all fit a lane), or with `mixed` about a fifth of them static, torqued, non-diagonal or spinning fast
    enough for substeps."""
    rng = np.random.default_rng(seed)
    moments = rng.uniform(0.1, 2.0, (n, 3))
    inertia = np.zeros((n, 3, 3))
    inertia[:, range(3), range(3)] = moments
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    w = rng.normal(size=(n, 3)) * 3.0  # rad/s: |w| h well under MAX_SUBSTEP_ROTATION at h = 1/60
    inv_mass, torque = np.ones(n), np.zeros((n, 3))
    if mixed:
        kind = rng.integers(0, 8, n)
        inv_mass[kind == 1] = 0.0
        torque[kind == 2] = rng.normal(size=((kind == 2).sum(), 3))
        r = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        inertia[kind == 3] = r @ inertia[kind == 3] @ r.T
        w[kind == 4] *= 40.0
    if turned:
        r = np.linalg.qr(rng.normal(size=(n, 3, 3)))[0]
        inertia = r @ inertia @ r.transpose(0, 2, 1)
    inv_inertia = np.linalg.inv(inertia)
    model = [wp.array(inv_mass, dtype=F64), wp.array(inertia, dtype=MAT33), wp.array(inv_inertia, dtype=MAT33)]
    principal, euler = wp.zeros(n, dtype=wp.int32), wp.zeros(n, dtype=VEC3)  # as `Model.set_masses` makes them
    inv_principal = wp.zeros(n, dtype=VEC3)
    moments, axes = principal_axes(inertia, inv_mass > 0.0)
    inputs = [*model[1:], wp.array(moments, dtype=VEC3)]
    wp.launch(rigid.principal_terms, n, inputs=inputs, outputs=[principal, euler, inv_principal], device="cpu")
    model += [principal, euler, wp.array(axes, dtype=QUAT)]
    state = [
        wp.array(rng.normal(size=(n, 3)), dtype=VEC3),
        wp.array(q, dtype=QUAT),
        wp.array(rng.normal(size=(n, 3)), dtype=VEC3),
        wp.array(w, dtype=VEC3),
        wp.array(rng.normal(size=(n, 3)), dtype=VEC3),  # force, N
        wp.array(torque, dtype=VEC3),
    ]
    return model, state


def predicted(model: list, state: list, group_size: int, h: float) -> list[np.ndarray]:
    n = model[0].shape[0]
    out = [wp.zeros(n, dtype=t) for t in (VEC3, QUAT, VEC3, VEC3)]
    gravity = VEC3(0.0, 0.0, -9.81)
    wp.launch(
        rigid.predict, -(-n // group_size), inputs=[*model, gravity, F64(h), group_size, *state, *out], device="cpu"
    )
    return [a.numpy() for a in out]


def test_lanes_predict_the_scalar_values_bit_for_bit():
    cases = ((1, False, False, 0), (10, False, False, 1), (64, False, False, 2), (1001, True, False, 3))
    cases += ((10, False, True, 4), (1001, True, True, 5))
    for n, mixed, turned, seed in cases:
        model, state = bodies(n, seed, mixed, turned)
        if turned:
            assert np.all(model[3].numpy()[model[0].numpy() > 0.0] == rigid.TURNED)
        for h in (1.0 / 60.0, -1.0 / 240.0):
            alone = predicted(model, state, 1, h)
            together = predicted(model, state, rigid.LANES, h)
            for name, a, b in zip(("x", "q", "v", "w"), alone, together):
                assert np.array_equal(a, b), f"{n} bodies, h = {h}: {name} in lanes differs from alone"
            assert np.all(np.isfinite(together[1]))


def test_turned_bodies_predict_the_body_frame_motion():
    """A TURNED body without torque is predicted in its principal frame (`rigid.predict_turned`): RK4 is the same
    in any frame fixed in the body, so the prediction is the body frame's (the GENERAL path, J^-1 (w x J w)) to
    round-off, fast-spinning bodies (substeps) included; a torqued one takes the GENERAL path itself."""
    model, state = bodies(1001, 7, True, True)
    general = [*model[:3], wp.zeros_like(model[3]), *model[4:]]  # every body by its full inertia matrices
    for h in (1.0 / 60.0, -1.0 / 240.0):
        turned, plain = predicted(model, state, rigid.LANES, h), predicted(general, state, 1, h)
        for name, a, b in zip(("x", "q", "v", "w"), turned, plain):
            scale = max(1.0, float(np.abs(b).max()))
            assert np.abs(a - b).max() < 1e-12 * scale, f"h = {h}: {name} of the principal frame differs"


@wp.kernel
def _rotations(
    q: wp.array(dtype=QUAT),
    v: wp.array(dtype=VEC3),
    ours: wp.array2d(dtype=VEC3),
    warps: wp.array2d(dtype=VEC3),
):
    i = wp.tid()
    ours[i, 0] = rigid.rotate(q[i], v[i])
    ours[i, 1] = rigid.rotate_inv(q[i], v[i])
    warps[i, 0] = wp.quat_rotate(q[i], v[i])
    warps[i, 1] = wp.quat_rotate_inv(q[i], v[i])


def test_rotations_are_warps_bit_for_bit():
    """`rigid.rotate` / `rotate_inv` (written once for a body and for lanes) do Warp's operations in its order."""
    rng = np.random.default_rng(5)
    n = 10_000
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    ours, warps = (wp.zeros((n, 2), dtype=VEC3) for _ in range(2))
    inputs = [wp.array(q, dtype=QUAT), wp.array(rng.normal(size=(n, 3)) * 10.0, dtype=VEC3), ours, warps]
    wp.launch(_rotations, n, inputs=inputs, device="cpu")
    assert np.array_equal(ours.numpy(), warps.numpy())
