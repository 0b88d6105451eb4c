"""Shapes: display, mass properties (uniform density, axis along local z) and collision (`kernels/collide.py`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SHAPE_KINDS = ("capsule", "box", "sphere", "cylinder")
SHAPE_CODES = {"sphere": 0, "capsule": 1, "box": 2, "cylinder": 3}
"""The kernels' codes for the collision shapes (`kernels/collide.py`); -1 is a body that does not collide."""


@dataclass(frozen=True)
class Shape:
    """A solid for display, for mass helpers and for collision, in the body frame centred on the body's origin.

    capsule / cylinder: `radius`, `length` (cylinder part, along local z).
    sphere: `radius`. box: `size` (full edge lengths x, y, z).
    collide: the body collides with this shape (False: display and mass only).
    """

    kind: str
    radius: float = 0.0
    length: float = 0.0
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)
    color: tuple[float, float, float] = (0.8, 0.5, 0.2)
    collide: bool = True

    def __post_init__(self) -> None:
        if self.kind not in SHAPE_KINDS:
            raise ValueError(f"unknown shape kind {self.kind!r}; expected one of {SHAPE_KINDS}")
        values = (self.radius, self.length, *self.size)
        if not all(math.isfinite(v) and v >= 0.0 for v in values):
            raise ValueError(f"shape {self.kind} has a negative or non-finite size: {values}")

    def zero_size(self) -> bool:
        """A collision shape of no extent: a sphere, capsule or cylinder of zero radius, a cylinder of zero length,
        a box with a zero edge."""
        if self.kind == "box":
            return min(self.size) <= 0.0
        return self.radius <= 0.0 or (self.kind == "cylinder" and self.length <= 0.0)

    def collision_size(self) -> tuple[float, float, float]:
        """What the narrow phase reads (m): (radius, half length, 0) for spheres, capsules and cylinders, half
        the edges for a box."""
        if self.kind == "box":
            return tuple(0.5 * v for v in self.size)
        return (self.radius, 0.5 * self.length, 0.0)

    def bounding_radius(self) -> float:
        """The radius of a sphere about the body's origin that holds the shape (m), for the broad phase."""
        if self.kind == "box":
            return 0.5 * math.sqrt(sum(v * v for v in self.size))
        if self.kind == "cylinder":
            return math.hypot(self.radius, 0.5 * self.length)
        return self.radius + 0.5 * self.length

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


def parallel_axis(mass: float, inertia: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """A body's inertia tensor about its centre of mass (kg m^2, world axes) moved to a point `offset` (m) away."""
    return inertia + mass * (float(offset @ offset) * np.eye(3) - np.outer(offset, offset))


PIECE_SHARES = (0.5, 0.25, 0.1, 0.03, 0.01)
"""The shares of a body's mass its collision pieces take (`collision_pieces`), tried in turn."""


def collision_pieces(
    mass: float, com: np.ndarray, inertia: np.ndarray, shapes: list[tuple[Shape, np.ndarray, np.ndarray]]
):
    """A body's collision shapes as pieces of its mass, to be welded to what remains of it: a body carries one
    shape, centred on its centre of mass (`kernels/collide.py`), so a foot sphere at the end of a shank, or a
    link's second shape, becomes a body of its own. The whole keeps its mass, centre and inertia exactly: each
    piece is a solid of its shape with a share of the mass by volume (half, or less until what remains has a
    physical inertia: positive moments that meet the triangle inequality), the rest stays on the body.

    Args:
        mass, com, inertia: the body's mass (kg), centre of mass (m, world) and inertia about it (world axes).
        shapes: each piece's (shape, centre (m, world), orientation (3x3, world from shape)).

    Returns:
        (the remainder's mass, centre, inertia about that centre, [(each piece's mass, inertia about its centre,
        world axes)]), or None when no share leaves a physical remainder (the caller says so).
    """
    volumes = np.array([shape.volume() for shape, _, _ in shapes])
    weights = volumes / volumes.sum() if volumes.sum() > 0.0 else np.full(len(shapes), 1.0 / len(shapes))
    for share in PIECE_SHARES:
        masses = share * mass * weights
        pieces = [(float(m), rot @ shape.inertia(float(m)) @ rot.T) for m, (shape, _, rot) in zip(masses, shapes)]
        rest = mass - float(masses.sum())
        centre = (mass * com - sum(m * c for m, (_, c, _) in zip(masses, shapes))) / rest
        # The whole's inertia about its centre, less the pieces' about it, moved to the remainder's centre.
        about = inertia - sum(parallel_axis(m, i, c - com) for (m, i), (_, c, _) in zip(pieces, shapes))
        about = 0.5 * (about + about.T) - rest * (float((centre - com) @ (centre - com)) * np.eye(3)
                                                  - np.outer(centre - com, centre - com))  # fmt: skip
        moments = np.linalg.eigvalsh(about)
        if moments[0] > 1e-9 * moments[-1] and moments[0] + moments[1] >= moments[2] * (1.0 + 1e-9):
            return rest, centre, about, pieces
    return None


@dataclass
class Colliders:
    """A scene's collision geometry on the host (`SceneBuilder.finalize` fills it, `contacts.ContactStage` puts it
    on the device). n bodies, p planes, f filtered pairs.

    shape_kind: (n,) `SHAPE_CODES`, -1 for a body without a colliding shape.
    shape_size: (n, 3) `Shape.collision_size()` (m). bound: (n,) `Shape.bounding_radius()` (m).
    friction, restitution: (n,) Coulomb coefficient and Newton's coefficient of each body.
    plane_normal (p, 3) unit, world; plane_offset (p,): the plane is {x : normal . x = offset} (m), solid below.
    plane_friction, plane_restitution: (p,).
    filter_pairs: (f, 2) bodies that never collide with each other (jointed pairs and user filters), a < b.
    """

    shape_kind: np.ndarray
    shape_size: np.ndarray
    bound: np.ndarray
    friction: np.ndarray
    restitution: np.ndarray
    plane_normal: np.ndarray
    plane_offset: np.ndarray
    plane_friction: np.ndarray
    plane_restitution: np.ndarray
    filter_pairs: np.ndarray

    @property
    def plane_count(self) -> int:
        return len(self.plane_offset)

    @property
    def collider_count(self) -> int:
        return int(np.count_nonzero(self.shape_kind >= 0))
