"""Energy drift of a run, so that a step too large for the motion is never a silent wrong answer.

A run with no active forces and no damping conserves E = kinetic + gravitational potential energy. The
impulse method is second order in the rotation per step: at a step far too large (h = 0.5 s with whole
steps on a whipping tree) it gains energy, with every joint still held to tolerance. `EnergyWatch` samples E
at each output frame and reports the gain against the largest kinetic energy seen, the same measure as the
stress suite (`stress.py`): gain = (E - E_ref) / E_scale.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .simulator import Simulator

# A gain above this fraction of the energy scale is reported as a warning (the stress suite's hold criterion).
GAIN_WARNING = 0.05


class EnergyWatch:
    """Samples E at chosen instants (the CLI: every frame written) and keeps the worst gain.

    The reference E_ref is the first sample taken while no force acts; a force (the builder's, before its
    `until`, or `set_external_forces`) does work, so while one acts the reference is dropped and taken again
    after it stops. E_scale is the largest kinetic energy seen since the reference, floored at 1e-6 of the
    energy that would lift the bodies by 1 m or move them at 1 m/s (a scene at rest has no kinetic scale,
    only round-off; static bodies have no mass to count, and a scene of them no energy to gain)."""

    def __init__(self, sim: Simulator, threshold: float = GAIN_WARNING) -> None:
        self.sim = sim
        h = sim.model.host  # 1e-6 of lifting the bodies by 1 m, or of moving them at 1 m/s (J)
        self.floor = max(1e-6 * float(h.body_mass.sum()) * (float(np.linalg.norm(h.gravity)) + 1.0), 1e-300)
        self.threshold = threshold
        self.reference: float | None = None
        self.scale = 0.0
        self.worst = 0.0  # J, the largest E - E_ref sampled
        self.last = 0.0  # J, E - E_ref at the last sample

    def sample(self) -> None:
        if self.sim.forces_active():
            self.reference = None
            return
        e = self.sim.energy()
        if self.reference is None:
            self.reference, self.scale, self.worst, self.last = e, 0.0, 0.0, 0.0
        self.scale = max(self.scale, self.sim.kinetic_energy(), self.floor)
        self.last = e - self.reference
        self.worst = max(self.worst, self.last)

    def follow(self, record: dict) -> Callable[[int], None]:
        """A per-frame callback (`run.record_frames(on_frame=...)`): sample, and keep the gain so far in
        `record` (a writer's settings, which go into the layer data, even of a partial file)."""

        def on_frame(_: int) -> None:
            self.sample()
            record.update(self.record())

        return on_frame

    @property
    def gain(self) -> float | None:
        """The worst (E - E_ref) / E_scale sampled, or None before any force-free sample."""
        return None if self.reference is None else self.worst / self.scale

    @property
    def drift(self) -> float | None:
        """(E - E_ref) / E_scale at the last sample, or None."""
        return None if self.reference is None else self.last / self.scale

    def record(self) -> dict[str, float]:
        """Layer-data entries: the gain and drift as fractions of E_scale, and the scale in J."""
        if self.reference is None or not math.isfinite(self.worst):
            return {}
        return {"energyGain": self.gain, "energyDrift": self.drift, "energyScale": self.scale,
                "energyGainThreshold": self.threshold}  # fmt: skip

    def warning(self) -> str | None:
        """A sentence when the gain is past the threshold."""
        gain = self.gain
        if gain is None or gain <= self.threshold:
            return None
        return (
            f"the energy grew by {gain:.1%} of the largest kinetic energy ({self.scale:.3g} J), above the "
            f"{self.threshold:.0%} threshold: the step is too large for this motion (the joints held, the "
            "trajectory did not); use smaller steps (a smaller --dt, or substeps: drop --whole-steps)"
        )
