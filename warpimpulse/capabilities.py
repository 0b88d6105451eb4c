"""What each schedule takes: one table of scene features against schedules, read where a schedule is chosen or a
scene is refused, and rendered into docs/capabilities.md (`make docs`).

The schedules (`StepOptions.schedule` and the drivers of `Simulator`):
- fused: whole steps, many a launch, as one kernel on a CPU (`kernels/step.py`);
- parallel: each stage a launch (a GPU's schedule; on a CPU where the fused step lacks a feature);
- threads: the fused step of one tree cut into parts run on threads (`split.py`, `ThreadedSimulator`);
- worlds: copies of a scene stepped together as batched worlds (`SceneBuilder.replicate`, `worlds.py`).

A cell says whether the schedule takes the feature ("yes"), takes the step on another schedule or at another
order and says so ("falls back", the note saying to what and why), or refuses the scene at construction with
one line naming the feature and the schedule ("no").
"""

from __future__ import annotations

from dataclasses import dataclass

SCHEDULE_NAMES = ("fused", "parallel", "threads", "worlds")

# Scene features, in the order a schedule's gaps are reported: (key, what a user reads).
FEATURES = (
    ("cg", "the CG solver"),
    ("iterative", "the iterative solver"),
    ("worlds", "batched worlds"),
    ("contacts", "contacts"),
    ("split_formulation", "the split formulation"),
    ("forces_without_joints", "force elements without joints"),
    ("rows_without_joints", "distance constraints without joints"),
    ("newton", "the first iteration's Newton step"),
    ("orders", "orders 4 and 6"),
    ("forces", "force elements (springs, joint springs, motors)"),
    ("rows", "joint limits, stiff motors or distance constraints"),
    ("loops", "kinematic loops"),
)
FEATURE_TEXT = dict(FEATURES)


@dataclass(frozen=True)
class Cell:
    """How a schedule takes a feature: "yes", "falls back" (the note says to what and why) or "no"."""

    support: str
    note: str = ""


YES = Cell("yes")

# The features the fused step lacks: the step runs on the parallel schedule instead, saying why.
_GAPS_FUSED = {
    "cg": Cell("falls back", "the CG solver runs its iterations from the host"),
    "worlds": Cell("falls back", "batched worlds step each world's convergence from the host (`worlds.py`)"),
    "contacts": Cell("falls back", "contacts are a stage the fused step does not have yet"),
    "split_formulation": Cell("falls back", "the split systems iterate their velocity correction from the host"),
    "forces_without_joints": Cell(
        "falls back", "force elements without joints: the fused step predicts them with the direct solver only"
    ),
    "rows_without_joints": Cell(
        "falls back", "distance constraints without joints: the fused step solves rows with the direct solver only"
    ),
}

# Only the cells that are not "yes".
_GAPS: dict[tuple[str, str], Cell] = {
    **{(feature, "fused"): c for feature, c in _GAPS_FUSED.items()},
    # threads: the split step needs the fused schedule and one system it can cut
    **{
        (feature, "threads"): Cell("falls back", f"the fused schedule does not run: {_GAPS_FUSED[feature].note}")
        for feature in _GAPS_FUSED
        if feature != "worlds"  # `ThreadedSimulator` shares batched worlds among threads as whole worlds
    },
    **{
        (feature, "threads"): Cell("falls back", why)
        for feature, why in (
            ("iterative", "the split step cuts the cholesky solver's factor"),
            ("newton", "the first iteration's Newton step (newton=True) runs on one thread"),
            ("orders", "orders 4 and 6 compose base steps; the split step takes order 2"),
            ("forces", "force elements couple the bodies' predictions; the split step predicts each part alone"),
            ("rows", "joint limits, stiff motors or distance constraints: their rows are one system over the model"),
            ("loops", "a joint that closes a loop joins the parts"),
        )
    },
    # worlds: every launch covers all worlds, each converging on its own, at order 2 with the cholesky solver
    **{
        (feature, "worlds"): Cell("no", why)
        for feature, why in (
            ("cg", "each world converges on its own through the cholesky solver's factor"),
            ("iterative", "each world converges on its own through the cholesky solver's factor"),
            ("contacts", "contacts are not batched yet"),
            ("forces_without_joints", "a world needs joints"),
            ("rows_without_joints", "a world needs joints"),
            ("orders", "batched worlds are stepped at order 2"),
            ("rows", "the rows are one dense system over the whole model (`kernels/limits.py`)"),
        )
    },
}


# Features with which a composed step (order 4 or 6) is taken at order 2, on every schedule, and said so
# (`StepStats.fallback`, the command line, the output's layer data).
ORDER_FALLBACKS = {
    "rows": "a step with joint limits, stiff motors or distance constraints is taken at order 2: a row's push-only "
    "impulse is not reversible, and a composed step runs substeps backwards",
    "contacts": "a step with contacts is taken at order 2: contacts push only, and a composed step runs substeps "
    "backwards",
}


def scene_features(model, solver: str, order: int, split_formulation: bool, newton: bool) -> set[str]:
    """The keys of `FEATURES` a simulator of `model` has, with the `solver` it runs ("cholesky", "cg" or
    "iterative"), its `order`, whether its factor is of the split formulation and whether it takes the Newton
    step."""
    joints = model.constraint_count > 0
    topology = getattr(model, "topology", None)
    present = {
        "cg": solver == "cg",
        "iterative": solver == "iterative",
        "worlds": model.world_count > 1,
        "contacts": model.colliders is not None,
        "split_formulation": split_formulation,
        "forces_without_joints": model.element_count > 0 and not joints,
        "rows_without_joints": model.limit_count > 0 and not joints,
        "newton": newton,
        "orders": order > 2,
        "forces": model.element_count > 0,
        "rows": model.limit_count > 0,
        "loops": bool(topology is not None and topology.loop_joints),
    }
    return {feature for feature, on in present.items() if on}


def cell(feature: str, schedule: str) -> Cell:
    """The table's cell of a feature (a key of `FEATURES`) and a schedule (`SCHEDULE_NAMES`)."""
    if feature not in FEATURE_TEXT or schedule not in SCHEDULE_NAMES:
        raise KeyError(f"no cell ({feature!r}, {schedule!r})")
    return _GAPS.get((feature, schedule), YES)


def first_gap(schedule: str, features: set[str], support: str) -> tuple[str, Cell] | None:
    """The first feature (in `FEATURES` order) of `features` that `schedule` takes as `support` ("falls back" or
    "no"), with its cell; None where there is none."""
    for feature, _ in FEATURES:
        if feature in features and (c := cell(feature, schedule)).support == support:
            return feature, c
    return None


def refuse(schedule: str, features: set[str], detail: str = "") -> None:
    """Raise one ValueError naming the first feature `schedule` does not take, and why; `detail` is added."""
    gap = first_gap(schedule, features, "no")
    if gap is not None:
        feature, c = gap
        raise ValueError(
            f"the {schedule} schedule does not take {FEATURE_TEXT[feature]}: {c.note}"
            + (f" ({detail})" if detail else "")
        )


def markdown() -> str:
    """The table as markdown: features down, schedules across, notes under it."""
    lines = [
        "# What each schedule takes",
        "",
        "Generated from `warpimpulse/capabilities.py` by `make docs`; `tests/test_capabilities.py` keeps this file",
        "equal to the table. *yes*: the schedule takes the feature; *falls back*: it runs, on the schedule the note",
        "names, and says so (`Simulator.schedule_note`, `split_note`); *no*: the scene is refused at construction",
        "with one line naming the feature and the schedule.",
        "",
        "| feature | " + " | ".join(SCHEDULE_NAMES) + " |",
        "|---|" + "---|" * len(SCHEDULE_NAMES),
    ]
    notes: list[str] = []
    for feature, text in FEATURES:
        row = []
        for schedule in SCHEDULE_NAMES:
            c = cell(feature, schedule)
            if c.support == "yes":
                row.append("yes")
            else:
                notes.append(f"{c.support} ({schedule}, {text}): {c.note}")
                row.append(f"{c.support} [{len(notes)}]")
        lines.append(f"| {text} | " + " | ".join(row) + " |")
    lines += ["", *(f"{i}. {n}" for i, n in enumerate(notes, 1)), "", "## Orders 4 and 6", ""]
    lines += [f"- {FEATURE_TEXT[feature]}: {why}." for feature, why in ORDER_FALLBACKS.items()]
    lines.append("")
    return "\n".join(lines)
