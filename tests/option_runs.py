"""A scene run with an option of the joint correction off and on (the Newton step, the carried right-hand side),
for the tests that measure what the option saves against the plain iteration."""

from __future__ import annotations

import warpimpulse as wi


def off_and_on(make, dt: float, steps: int, option: str, before: int = 0, **settings) -> dict:
    """{False: (sim, stats), True: (sim, stats)}: `steps` steps, one StepStats each, after `before` steps, of
    the scene `make()` builds, with `option` off and on (and `settings` for both)."""
    runs = {}
    for on in (False, True):
        sim = wi.Simulator(make().finalize("cpu"), dt, tolerance=1e-6, **wi.StepOptions.fold({option: on, **settings}))
        if before:
            sim.step(before)
        runs[on] = (sim, [sim.step() for _ in range(steps)])
    return runs


def assert_saves_iterations(runs: dict, option: str, most: float) -> None:
    """The option was taken (and not without it), the run with it took fewer than `most` of the plain run's
    joint iterations, and held every step to the tolerance (1e-6)."""
    (plain, plain_stats), (taken, taken_stats) = runs[False], runs[True]
    assert getattr(taken, option) and not getattr(plain, option)
    plain_its = sum(s.joint_iterations for s in plain_stats)
    taken_its = sum(s.joint_iterations for s in taken_stats)
    assert taken_its < most * plain_its, (taken_its, plain_its)
    for s in taken_stats:
        assert s.converged and s.max_joint_error <= 1e-6
