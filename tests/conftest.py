"""Test session set-up: Warp quiet. Shared checks live in numpy_checks.py (independent numpy references of the
engine's state), reference.py (reduced-coordinate and free-body references), rigs.py (random joint rigs) and
cli_helpers.py (running the command line); tests import those, never each other."""

import os
import signal

import pytest
import warp as wp
from hypothesis import settings

import warpimpulse as wi

wp.config.quiet = True
# Warp 1.19 no longer reads `config.quiet`; its start-up and module-load messages are info-level logs.
wp.config.log_level = getattr(wp, "LOG_WARNING", 30)


# A suite started in the background inherits SIGINT ignored (a shell does that to its background jobs), and so would
# the runs its interrupt tests start: give them SIGINT as a terminal does.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

# `make test` draws no new cases: every Hypothesis test runs the same examples on every machine (derandomized,
# no example database), so CI cannot fail by chance. `make fuzz` explores with fresh seeds and keeps what fails.
settings.register_profile("deterministic", derandomize=True, database=None)
settings.register_profile("fuzz", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "deterministic"))


def pytest_addoption(parser):
    parser.addoption(
        "--schedule",
        default="auto",
        choices=("auto", "fused", "parallel"),
        help="the schedule a Simulator built with StepOptions(schedule='auto') runs (the whole suite on the "
        "parallel schedule, what a GPU runs)",
    )


def pytest_collection_modifyitems(config, items):
    """Under --schedule parallel (`make test`'s second pass), skip the tests of the fused schedule itself and the
    tests that step no simulator (`schedule_free`: the CUDA compilation, the wheel), which the first pass ran."""
    if config.getoption("--schedule") == "parallel":
        reasons = {"fused": "a test of the fused schedule itself", "schedule_free": "steps no simulator: run once"}
        for item in items:
            for marker, reason in reasons.items():
                if marker in item.keywords:
                    item.add_marker(pytest.mark.skip(reason=reason))
                    break


@pytest.fixture(autouse=True)
def _default_schedule(request, monkeypatch):
    """With --schedule, every Simulator the tests build without naming a schedule runs that one."""
    chosen = request.config.getoption("--schedule")
    if chosen == "auto":
        return
    init = wi.Simulator.__init__

    def built_with(self, *args, options: wi.StepOptions | None = None, **settings):
        options = options or wi.StepOptions()
        if isinstance(options, wi.StepOptions) and options.schedule == "auto":  # else the Simulator refuses it
            options = options.replace(schedule=chosen)
        init(self, *args, options=options, **settings)

    monkeypatch.setattr(wi.Simulator, "__init__", built_with)
