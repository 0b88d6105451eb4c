"""The engine against stored MuJoCo trajectories (tests/data/reference_trajectories.npz), without MuJoCo.

benchmarks/make_reference.py wrote them: MuJoCo RK4 at h = 1/3000 in reduced coordinates, on the paper's tree
(127 bodies, ball joints, driven by its start torque for the first second) and on a 3D chain of ball,
universal and revolute joints with its tip pushed for half a second. Probe bodies' centres of mass and
orientations at a few times. The engine runs the same scenes at two step sizes, tolerance 1e-8; it must
be near the reference and converge to it at second order.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from reference import matrices, order

import warpimpulse as wi
from warpimpulse import scenes

DATA = Path(__file__).parent / "data" / "reference_trajectories.npz"
MAKE = {"tree127": lambda: scenes.binary_tree(127), "bent_chain": scenes.bent_chain}
# Step rates (1/h) of the runs, and the bound on the COM error at the finer one. Measured (max over the probes and
# times): 4.0e-5 m (tree, h = 1/240), 1.3e-3 m (chain, h = 1/480; it whips, so it needs the smaller steps to be
# in the second-order regime).
RATES = {"tree127": (120, 240), "bent_chain": (240, 480)}
BOUNDS = {"tree127": 1e-4, "bent_chain": 3e-3}


@pytest.fixture(scope="module")
def stored():
    with np.load(DATA) as data:
        return {key: data[key] for key in data.files}


def errors(stored, name: str, rate: int) -> tuple[np.ndarray, np.ndarray]:
    """Max COM distance (m) and max |R - R_ref| over the probes, at each stored time."""
    builder = MAKE[name]()
    probes, times = stored[f"{name}_probes"], stored[f"{name}_times"]
    # The scene is still the one the reference was made of.
    np.testing.assert_allclose([builder.bodies[b].position for b in probes], stored[f"{name}_start"], atol=1e-12)
    sim = wi.Simulator(builder.finalize(), 1.0 / rate, tolerance=1e-8)
    marks = {int(round(t * rate)): k for k, t in enumerate(times)}
    x_err, r_err = np.zeros(len(times)), np.zeros(len(times))
    for step in range(1, max(marks) + 1):
        sim.step()
        if step in marks:
            k = marks[step]
            x_err[k] = np.linalg.norm(sim.positions()[probes] - stored[f"{name}_x"][k], axis=1).max()
            r_err[k] = np.abs(matrices(sim.orientations()[probes]) - matrices(stored[f"{name}_q"][k])).max()
    return x_err, r_err


@pytest.mark.parametrize("name", sorted(MAKE))
def test_matches_stored_mujoco_trajectory(stored, name):
    assert float(stored[f"{name}_self_check"]) < 1e-6  # the reference's own error (h = 1/6000 against 1/3000)
    coarse, fine = RATES[name]
    x1, r1 = errors(stored, name, coarse)
    x2, r2 = errors(stored, name, fine)
    p_x, p_r = order(x1.max(), x2.max()), order(r1.max(), r2.max())
    print(f"\n{name}: COM error {x1.max():.2e} / {x2.max():.2e} m, R error {r1.max():.2e} / {r2.max():.2e} "
          f"at h = 1/{coarse}, 1/{fine}; observed order {p_x:.2f} (COM), {p_r:.2f} (R)")  # fmt: skip
    assert x2.max() < BOUNDS[name]
    assert 1.7 < p_x < 2.3 and 1.7 < p_r < 2.3
