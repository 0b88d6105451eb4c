"""Which joint dampers the prediction takes implicitly (`kernels/forces.py`, `implicit_damper`).

A damper of gain c on a coordinate whose two bodies answer a unit impulse with a rate change k (the two-body
response, `damper_coordinate`) makes the explicit RK4 prediction a decay of rate c k: stable only while
h c k < 2.785, RK4's limit on the negative real axis. Real robots break that: URDF `<dynamics damping>` on a
light wrist (tiago: 2 I / c = 8e-6 s) wants a step 125 times below 1 ms. Such a damper leaves RK4 and acts as
an implicit impulse on the prediction instead, stable at any step. The choice is per drive and per step size:
at h c k above `STIFF` (2, where RK4's damping of a step, 1/3, is no better than implicit Euler's 1 / (1 + 2),
and 28 % below the limit) the damper goes implicit; below, it keeps RK4's fourth order.

The damping terms taken: a joint spring's damping and a position motor's kd, a velocity motor's kp (damping
towards its target rate), on drives without a force cap (a capped output is one clamped sum of all its terms).
A drive on a chain of joints through light bodies (`SceneBuilder.chain_joints`, the MJCF loader's bodies of
several joints) acts on the chain's ends, and so does its damper, k included (`forces.damper_frame`): left in
RK4, such dampers halved the dm_control humanoids' steps 4-32 times at their own step size."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import warp as wp

from .kernels import forces as force_kernels
from .launch import record
from .model import Model

STIFF = 2.0  # h c k above which a damper is integrated implicitly
STIFF_SPRING = 2.0  # h omega (omega^2 = s k) above which a spring goes with it

POSITION, VELOCITY = 0, 1  # `types.DRIVE_MODES` indices


def pick(model: Model, dt: float, keep_order: bool = False) -> SimpleNamespace:
    """The dampers that go implicit at steps of dt, measured at the model's initial state: `drive` (their drive
    indices), `gain` (c, N m s/rad or N s/m), `spring` (a position drive's kp, N m/rad or N/m, taken with its
    damper), `names` (their drives' names) and `drive_gains`, the drives' gains for the explicit prediction (the
    implicit terms zeroed; the model's own array where none is). A drive goes implicit where its damper is stiff
    (h c k > STIFF) or its spring is (h omega > STIFF_SPRING, omega^2 = s k: RK4 holds an undamped oscillator to
    h omega < 2.83 and is far off the circle well before; the dm_control dog's tail vertebrae, 1e-8 kg m^2 on
    springs of 0.04 N m/rad, have h omega = 9 at its own step and went to NaN in RK4).

    With `keep_order` (order 4 or 6 asked, and the steps take it: a scene with rows takes them at order 2) none
    goes implicit: an implicit damper is first order and would hold
    every step at order 2 (the gymnasium ant at h = 1/240 parts from MuJoCo by 0.05 m in 0.25 s that way, 1e-6
    m at order 4), so the stiff ones stay in RK4, listed in `kept`, the largest `stiffness` of theirs (1/s), and
    the simulator splits each step into substeps in which none is stiff (`Simulator._depth_of`): the composed
    step of Suzuki's coefficients damps within 1.5% of exp(-h c k) there, and is unstable from h c k ~ 5.5."""
    d, h = model.device, model.host
    zero = wp.zeros(0, dtype=wp.float64, device=d)
    none = SimpleNamespace(drive=wp.zeros(0, dtype=wp.int32, device=d), gain=zero, spring=zero, names=(),
                           drive_gains=model.drive_gains, kept=(), stiffness=0.0)  # fmt: skip
    if model.drive_count == 0 or model.element_count == 0:
        return none
    k = wp.zeros(model.drive_count, dtype=wp.float64, device=d)
    record(force_kernels.damper_rates, model.drive_count, d, (model,), model.state(), damper_k_out=k).launch()
    gains = model.drive_gains.numpy()  # the model's: velocity mode's kd, effort and stiff motors' gains are 0
    term = np.where(h.drive_mode == POSITION, 2, 0)  # kd in position mode, kp in velocity mode
    c = np.where(h.drive_mode <= VELOCITY, gains[np.arange(len(gains)), term], 0.0)
    s = np.where(h.drive_mode == POSITION, gains[:, 0], 0.0)  # a position drive's kp: a spring
    k = k.numpy()
    # 1/s: a step of h is stiff for the drive where h times this is over 1 (its damper's h c k over STIFF, or its
    # spring's h omega over STIFF_SPRING)
    stiffness = np.maximum(c * k / STIFF, np.sqrt(np.maximum(s * k, 0.0)) / STIFF_SPRING)
    stiff = (dt * stiffness > 1.0) & np.isinf(h.drive_max_force) & ~h.drive_stiff
    chosen = np.flatnonzero(stiff)
    if not len(chosen):
        return none
    if keep_order:
        none.kept = tuple(model.drive_name[i] for i in chosen)
        none.stiffness = float(np.max(stiffness[chosen]))
        return none
    explicit = gains.copy()
    explicit[chosen, term[chosen]] = 0.0
    springs = chosen[h.drive_mode[chosen] == POSITION]
    explicit[springs, 0] = 0.0
    return SimpleNamespace(
        drive=wp.array(chosen.astype(np.int32), dtype=wp.int32, device=d),
        gain=wp.array(c[chosen], dtype=wp.float64, device=d),
        spring=wp.array(s[chosen], dtype=wp.float64, device=d),
        names=tuple(model.drive_name[i] for i in chosen),
        drive_gains=wp.array(explicit, dtype=wp.vec3d, device=d),
        kept=(),
        stiffness=0.0,
    )
