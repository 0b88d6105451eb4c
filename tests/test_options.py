"""`StepOptions`: the performance switches in one object, the old keyword spelling still accepted for a release
with a DeprecationWarning naming the new one, and the constructor keeping what a user decides."""

from __future__ import annotations

import inspect
import warnings

import numpy as np
import pytest

import warpimpulse as wi
from warpimpulse import scenes


def test_the_constructor_keeps_what_a_user_decides():
    params = [p for p in inspect.signature(wi.Simulator.__init__).parameters.values() if p.kind != p.VAR_KEYWORD]
    assert len(params) - 1 <= 14  # less self
    assert "options" in {p.name for p in params}
    assert not {"schedule", "newton", "carry", "defer_velocities", "specialize", "scheme"} & {p.name for p in params}


def test_old_spelling_runs_the_same_steps_with_a_deprecation_warning():
    model = scenes.chain(4).finalize()
    new = wi.Simulator(model, 1 / 60, options=wi.StepOptions(carry=False, max_rotation=None))
    with pytest.warns(DeprecationWarning, match=r"Simulator\(carry=False, max_rotation=None\) is deprecated.*"
                      r"options=warpimpulse.StepOptions\(carry=False, max_rotation=None\)"):  # fmt: skip
        old = wi.Simulator(model, 1 / 60, carry=False, max_rotation=None)
    assert old.options == new.options and not old.carry
    new.step(5)
    old.step(5)
    assert np.array_equal(new.positions(), old.positions())


def test_wrappers_take_the_old_spelling_too():
    model = scenes.chain(3).finalize()
    with pytest.warns(DeprecationWarning, match="carry=False"):
        split = wi.ThreadedSimulator(model, 1 / 60, threads=1, carry=False)
    assert not split.parts[0].carry


def test_unknown_keywords_and_wrong_options_are_refused():
    model = scenes.chain(2).finalize()
    with pytest.raises(TypeError, match="unexpected keyword argument 'sheme'"):
        wi.Simulator(model, 1 / 60, sheme="yoshida3")
    with pytest.raises(TypeError, match="options must be a warpimpulse.StepOptions, got dict"):
        wi.Simulator(model, 1 / 60, options={"carry": False})


def test_fold_moves_switches_into_options():
    folded = wi.StepOptions.fold({"tolerance": 1e-6, "carry": False, "options": wi.StepOptions(newton=True)})
    assert folded == {"tolerance": 1e-6, "options": wi.StepOptions(newton=True, carry=False)}
    assert wi.StepOptions.fold({"order": 4}) == {"order": 4}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        wi.Simulator(scenes.chain(2).finalize(), 1 / 60, **wi.StepOptions.fold({"carry": False}))
