"""Joint-type specialization: a scene compiles the constraint kernels for its own constraint kinds only, and
they compute exactly what the kernels compiled for all six kinds compute."""

from __future__ import annotations

import numpy as np
import pytest
from numpy_checks import sim_state
from rigs import DT, JOINTS, TOL, Rig
from warpimpulse.kernels import constraints

import warpimpulse
from warpimpulse import scenes
from warpimpulse.joints import JOINT_TYPES
from warpimpulse.launch import record
from warpimpulse.types import ConstraintKind

# Custom joints of one basic constraint each, beside the seven catalogue joints.
CASES = [(joint, None) for joint in JOINTS] + [
    ("cylindrical", ("line",)),
    ("planar", ("plane",)),
    ("revolute", ("axis",)),
]


@pytest.mark.parametrize(("joint", "kinds"), CASES)
def test_specialized_matches_all_kinds(joint, kinds):
    """Bit-identical states after 60 steps of a kicked child on a dynamic parent (every constraint corrects)."""
    builder = Rig(joint, seed=11, parent_dynamic=True, kinds=kinds).b
    sims = [
        warpimpulse.Simulator(builder.finalize(), DT, tolerance=TOL, options=warpimpulse.StepOptions(specialize=s))
        for s in (True, False)
    ]
    for _ in range(60):
        stats = [sim.step() for sim in sims]
        assert stats[0] == stats[1]
    for a, b in zip(*(sim_state(sim) for sim in sims)):
        np.testing.assert_array_equal(a, b)
    assert sims[1].kernels.kinds == tuple(sorted(constraints.ALL_KINDS))


@pytest.mark.parametrize(("joint", "kinds"), CASES)
def test_compiled_kinds_are_the_scene_kinds(joint, kinds):
    sim = Rig(joint, seed=1, kinds=kinds).sim
    expected = [ConstraintKind.parse(k) for k in kinds] if kinds else JOINT_TYPES[joint]
    assert sim.kernels.kinds == tuple(sorted(expected))


@pytest.mark.parametrize(
    ("builder", "expected"),
    [(scenes.binary_tree(7), (ConstraintKind.POINT,)), (scenes.chain(3), (ConstraintKind.POINT, ConstraintKind.AXIS))],
)
def test_scene_kinds(builder, expected):
    assert warpimpulse.Simulator(builder.finalize(), DT).kernels.kinds == expected


def test_absent_kinds_have_no_code():
    """Kernels for points only, run on a hinge (point + axis): the axis constraint's outputs stay as they were."""
    sim = warpimpulse.Simulator(scenes.chain(2).finalize(), DT)
    m, f = sim.model, sim.frames
    is_point = m.constraint_kind.numpy() == ConstraintKind.POINT
    sim.errors.fill_(-1.0)
    points_only = constraints.specialized(frozenset({ConstraintKind.POINT}))
    record(points_only.position_errors, m.constraint_count, m.device, (m, f, sim), sim.state, inv_h=1.0 / DT).launch()
    errors = sim.errors.numpy()
    assert np.all(errors[is_point] >= 0.0) and np.all(errors[~is_point] == -1.0)
