"""The double pendulum against an independent reference in reduced coordinates.

The reference: two uniform rods on parallel hinges (y axis), angles theta1, theta2 from the downward vertical,
centres of mass at c1, c2 from their hinges, the second hinge L1 from the first. Lagrange's equations, M t'' = f:

    M = [m1 c1^2 + I1 + m2 L1^2     m2 L1 c2 cos(t1 - t2)]
        [m2 L1 c2 cos(t1 - t2)      m2 c2^2 + I2         ]
    f = [-m2 L1 c2 sin(t1 - t2) t2'^2 - (m1 c1 + m2 L1) g sin t1]
        [ m2 L1 c2 sin(t1 - t2) t1'^2 - m2 c2 g sin t2           ]

with I1, I2 the rods' moments about the hinge axis through their centres of mass, taken from the builder,
integrated by scipy's DOP853 at rtol 1e-12.

Convergence, measured (h = 1/250, 1/500, 1/1000, 1/2000; 2 s from both rods horizontal; tolerance 1e-6):
max COM error 4.0e-4, 9.8e-5, 2.5e-5, 6.2e-6 m: the method is second order in h here (ratio 4.0 per halving),
so the test asserts 4e-5 m at h = 1/1000 and an observed order between 1.8 and 2.2.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

import warpimpulse
from warpimpulse import scenes

DURATION = 2.0
ANGLES = (math.pi / 2, math.pi / 2)


class Reference:
    def __init__(self, builder: warpimpulse.SceneBuilder) -> None:
        b0, b1 = builder.bodies
        h0, h1 = builder.joints
        np.testing.assert_allclose(h0.axis, [0, 1, 0])
        np.testing.assert_allclose(h1.axis, [0, 1, 0])
        self.pivot = h0.anchor
        self.m1, self.m2 = b0.mass, b1.mass
        self.l1 = float(np.linalg.norm(h1.anchor - h0.anchor))
        self.c1 = float(np.linalg.norm(b0.position - h0.anchor))
        self.c2 = float(np.linalg.norm(b1.position - h1.anchor))
        self.i1, self.i2 = (self._hinge_moment(b) for b in (b0, b1))
        self.g = -float(builder.gravity[2])
        assert np.allclose(builder.gravity[:2], 0.0)

    @staticmethod
    def _hinge_moment(body) -> float:
        r = Rotation.from_quat(body.orientation).as_matrix()
        return float((r @ body.inertia @ r.T)[1, 1])

    def rhs(self, t, y):
        t1, t2, w1, w2 = y
        m1, m2, l1, c1, c2, g = self.m1, self.m2, self.l1, self.c1, self.c2, self.g
        c, s = math.cos(t1 - t2), math.sin(t1 - t2)
        m12 = m2 * l1 * c2 * c
        mass = np.array([[m1 * c1 * c1 + self.i1 + m2 * l1 * l1, m12], [m12, m2 * c2 * c2 + self.i2]])
        force = np.array(
            [
                -m2 * l1 * c2 * s * w2 * w2 - (m1 * c1 + m2 * l1) * g * math.sin(t1),
                m2 * l1 * c2 * s * w1 * w1 - m2 * c2 * g * math.sin(t2),
            ]
        )
        a1, a2 = np.linalg.solve(mass, force)
        return [w1, w2, a1, a2]

    def energy(self, y) -> np.ndarray:
        t1, t2, w1, w2 = y
        m1, m2, l1, c1, c2, g = self.m1, self.m2, self.l1, self.c1, self.c2, self.g
        kinetic = 0.5 * (m1 * c1 * c1 + self.i1 + m2 * l1 * l1) * w1**2 + 0.5 * (m2 * c2 * c2 + self.i2) * w2**2
        kinetic += m2 * l1 * c2 * np.cos(t1 - t2) * w1 * w2
        potential = -g * ((m1 * c1 + m2 * l1) * np.cos(t1) + m2 * c2 * np.cos(t2))
        return kinetic + potential

    def solve(self, angles, times):
        y0 = [angles[0], angles[1], 0.0, 0.0]
        sol = solve_ivp(self.rhs, (0.0, times[-1]), y0, method="DOP853", rtol=1e-12, atol=1e-12, t_eval=times)
        assert sol.success
        return sol.y

    def coms(self, y) -> np.ndarray:
        """(T, 2, 3) centre-of-mass positions of the two rods."""
        t1, t2 = y[0], y[1]
        u1 = np.stack([np.sin(t1), np.zeros_like(t1), -np.cos(t1)], axis=-1)
        u2 = np.stack([np.sin(t2), np.zeros_like(t2), -np.cos(t2)], axis=-1)
        return self.pivot + np.stack([self.c1 * u1, self.l1 * u1 + self.c2 * u2], axis=1)


@pytest.fixture(scope="module")
def errors():
    """Max COM distance from the reference over 2 s, at two step sizes."""
    builder = scenes.double_pendulum(angles=ANGLES)
    ref = Reference(builder)
    out = {}
    for steps_per_second in (500, 1000):
        h = 1.0 / steps_per_second
        n = int(round(DURATION / h))
        times = np.arange(n + 1) * h
        y = ref.solve(ANGLES, times)
        # The reference itself: energy is conserved, and it starts where the builder's bodies are.
        e = ref.energy(y)
        assert np.abs(e - e[0]).max() < 1e-9 * max(1.0, abs(e[0]))
        expected = ref.coms(y)
        np.testing.assert_allclose(expected[0], [b.position for b in builder.bodies], atol=1e-12)
        sim = warpimpulse.Simulator(builder.finalize(), h, tolerance=1e-6)
        worst = 0.0
        for k in range(1, n + 1):
            sim.step()
            worst = max(worst, float(np.linalg.norm(sim.positions() - expected[k], axis=1).max()))
        out[steps_per_second] = worst
    return out


def test_matches_reduced_coordinates(errors):
    print(f"\nmax COM error over {DURATION} s: h=1/500 {errors[500]:.3e} m, h=1/1000 {errors[1000]:.3e} m")
    assert errors[1000] < 4e-5


def test_convergence_order(errors):
    order = math.log2(errors[500] / errors[1000])
    print(f"\nobserved order {order:.3f}")
    assert 1.8 < order < 2.2
