"""Display shapes and their mass properties (uniform density, axis along local z)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SHAPE_KINDS = ("capsule", "box", "sphere", "cylinder")


@dataclass(frozen=True)
class Shape:
    """A solid for display and for mass helpers.

    capsule / cylinder: `radius`, `length` (cylinder part, along local z).
    sphere: `radius`. box: `size` (full edge lengths x, y, z).
    """

    kind: str
    radius: float = 0.0
    length: float = 0.0
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)
    color: tuple[float, float, float] = (0.8, 0.5, 0.2)

    def __post_init__(self) -> None:
        if self.kind not in SHAPE_KINDS:
            raise ValueError(f"unknown shape kind {self.kind!r}; expected one of {SHAPE_KINDS}")
        values = (self.radius, self.length, *self.size)
        if not all(math.isfinite(v) and v >= 0.0 for v in values):
            raise ValueError(f"shape {self.kind} has a negative or non-finite size: {values}")

    def volume(self) -> float:
        r, l = self.radius, self.length
        if self.kind == "sphere":
            return 4.0 / 3.0 * math.pi * r**3
        if self.kind == "cylinder":
            return math.pi * r * r * l
        if self.kind == "capsule":
            return math.pi * r * r * l + 4.0 / 3.0 * math.pi * r**3
        return float(np.prod(self.size))

    def inertia(self, mass: float) -> np.ndarray:
        """Body-frame inertia tensor about the centre of mass for a solid of this mass."""
        r, l = self.radius, self.length
        if self.kind == "sphere":
            return np.eye(3) * (0.4 * mass * r * r)
        if self.kind == "box":
            x, y, z = self.size
            return np.diag([y * y + z * z, x * x + z * z, x * x + y * y]) * (mass / 12.0)
        if self.kind == "cylinder":
            ixx = mass * (3.0 * r * r + l * l) / 12.0
            return np.diag([ixx, ixx, 0.5 * mass * r * r])
        # Capsule: a cylinder plus two hemispheres, split by volume (parallel-axis theorem).
        v_cyl = math.pi * r * r * l
        v_sph = 4.0 / 3.0 * math.pi * r**3
        m_cyl = mass * v_cyl / (v_cyl + v_sph)
        m_hemi = 0.5 * (mass - m_cyl)
        izz = 0.5 * m_cyl * r * r + 2.0 * (0.4 * m_hemi * r * r)
        ixx_cyl = m_cyl * (3.0 * r * r + l * l) / 12.0
        # Hemisphere about its own centroid (3r/8 from the flat face), shifted to the capsule centre.
        d = 0.5 * l + 3.0 * r / 8.0
        ixx_hemi = 0.4 * m_hemi * r * r - m_hemi * (3.0 * r / 8.0) ** 2 + m_hemi * d * d
        ixx = ixx_cyl + 2.0 * ixx_hemi
        return np.diag([ixx, ixx, izz])

    def mass_properties(self, density: float) -> tuple[float, np.ndarray]:
        mass = density * self.volume()
        return mass, self.inertia(mass)
