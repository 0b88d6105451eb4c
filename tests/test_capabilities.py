"""The capability table (`warpimpulse/capabilities.py`): the docs render it, and what it says is what the
simulator does: a "no" cell refuses at construction with one line naming the feature and the schedule, a
"falls back" cell runs on the schedule its note names and says so."""

from __future__ import annotations

from pathlib import Path

import pytest
from rigs import welded_hinge

import warpimpulse as wi
from warpimpulse import capabilities, scenes

DOCS = Path(__file__).resolve().parent.parent / "docs" / "capabilities.md"


def test_the_docs_show_the_table():
    assert DOCS.read_text() == capabilities.markdown(), "docs/capabilities.md is stale: run `make docs`"


def _limited_chain() -> wi.SceneBuilder:
    builder = scenes.chain(3)
    builder.add_joint_limit(1, -0.5, 0.5)
    return builder


@pytest.mark.parametrize(
    ("make", "settings", "feature"),
    [
        (lambda: scenes.chain(3), {"solver": "cg"}, "cg"),
        (lambda: scenes.chain(3), {"solver": "iterative"}, "iterative"),
        (lambda: scenes.chain(3), {"order": 4}, "orders"),
        (_limited_chain, {}, "rows"),
    ],
)
def test_what_batched_worlds_do_not_take_is_refused_naming_it(make, settings, feature):
    builder = make()
    if feature == "rows":  # replicate refuses rows itself, naming them; the Simulator's check is the same table
        with pytest.raises(wi.SceneError, match="limits"):
            builder.replicate(2)
        return
    model = builder.replicate(2).finalize()
    text = capabilities.FEATURE_TEXT[feature]
    with pytest.raises(ValueError, match=rf"^the worlds schedule does not take {text}: .* \(2 worlds\)$"):
        wi.Simulator(model, 1 / 60, **settings)


@pytest.mark.fused
@pytest.mark.parametrize(
    ("make", "settings", "feature"),
    [
        (lambda: scenes.chain(3), {"solver": "cg"}, "cg"),
        (lambda: scenes.box_stack(1), {}, "contacts"),
        (lambda: scenes.chain(3).replicate(2), {}, "worlds"),
        (welded_hinge, {"options": wi.StepOptions(formulation="split")}, "split_formulation"),
    ],
)
def test_what_the_fused_step_lacks_runs_on_the_parallel_schedule_and_says_why(make, settings, feature):
    sim = wi.Simulator(make().finalize(), 1 / 60, **settings)
    assert feature in sim.features
    assert sim.schedule == "parallel" and sim.schedule_note == capabilities.cell(feature, "fused").note


def test_every_cell_is_yes_falls_back_or_no_with_a_reason():
    for feature, _ in capabilities.FEATURES:
        for schedule in capabilities.SCHEDULE_NAMES:
            c = capabilities.cell(feature, schedule)
            assert c.support in ("yes", "falls back", "no")
            assert (c.support == "yes") == (c.note == "")
