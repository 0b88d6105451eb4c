"""The run-time-against-error comparison's rules (warpimpulse.bench.pareto), on synthetic fronts."""

import math

import pytest

from warpimpulse.bench.pareto import FLOOR_MARGIN, compare, cost_at, front, ratio_text


def pts(*pairs):
    return [{"error": e, "cost": c} for e, c in pairs]


def test_front_keeps_only_undominated_points() -> None:
    got = front(pts((1e-2, 1.0), (1e-3, 4.0), (5e-3, 5.0), (1e-4, 16.0), (1e-3, 3.0)))
    assert [(p["error"], p["cost"]) for p in got] == [(1e-4, 16.0), (1e-3, 3.0), (1e-2, 1.0)]


def test_cost_is_interpolated_log_log_between_the_bracketing_points() -> None:
    # cost = error^-1/2 along the front: exact under log-log interpolation.
    ours = pts((1e-2, 10.0), (1e-4, 100.0))
    got = cost_at(ours, 1e-3)
    assert got["reached"] and not got["bound"]
    assert got["cost"] == pytest.approx(10.0 * math.sqrt(10.0))
    assert got["grid"]["error"] == 1e-4  # the cheapest measured point that reaches the level


def test_a_level_the_peer_never_reached_is_not_a_win() -> None:
    ours = pts((1e-2, 1.0), (1e-4, 10.0), (1e-6, 100.0))
    mujoco = pts((1e-2, 0.5), (1e-3, 2.0))  # its finest step stops at 1e-3 m
    cell = compare(ours, mujoco, 1e-4)
    assert cell["status"] == "not reached by MuJoCo" and cell["ratio"] is None
    assert ratio_text(cell) == "not reached by MuJoCo"
    loss = compare(ours, mujoco, 1e-2)
    assert loss["status"] == "compared" and loss["ratio"] == pytest.approx(0.5)  # MuJoCo is cheaper there


def test_we_never_reached_and_neither_reached() -> None:
    ours, mujoco = pts((1e-3, 1.0)), pts((1e-5, 1.0))
    assert compare(ours, mujoco, 1e-4)["status"] == "not reached by warpimpulse"
    assert compare(ours, mujoco, 1e-6)["status"] == "reached by neither"


def test_a_cost_below_the_coarsest_point_is_an_upper_bound() -> None:
    ours = pts((2e-2, 1.0), (1e-4, 10.0))
    mujoco = pts((1e-3, 2.0), (1e-5, 20.0))  # even its coarsest step is below 1e-2
    cell = compare(ours, mujoco, 1e-2)
    assert cell["theirs"]["bound"] and cell["ratio_bound"] == "<="
    assert ratio_text(cell).startswith("<= ")


def test_levels_near_the_reference_floor_are_not_compared() -> None:
    ours, mujoco = pts((1e-2, 1.0), (1e-9, 10.0)), pts((1e-2, 1.0), (1e-9, 10.0))
    floor = 2e-6
    assert compare(ours, mujoco, FLOOR_MARGIN * floor / 2, floor)["status"] == "below the reference floor"
    # Errors below the floor are clamped to it: a point at 1e-9 m counts as 2e-6 m.
    assert front(ours, floor)[0]["error"] == floor and front(ours, floor)[0]["measured_error"] == 1e-9


def test_failed_configurations_are_ignored() -> None:
    got = front([{"error": None, "cost": 1.0}, {"error": 1e-3, "cost": None}, {"error": 1e-3, "cost": 2.0}])
    assert len(got) == 1


def test_the_report_counts_no_win_where_mujoco_never_reached_our_error() -> None:
    from warpimpulse.bench import report

    def run(engine, variant, rate, error, seconds):
        return {"scene": "tree127", "engine": engine, "variant": variant, "rate": rate, "tolerance": 1e-6,
                "order": 2, "failed": None, "trajectory_error": error, "time_per_step": seconds}  # fmt: skip

    runs = [
        run("warpimpulse", "auto", 60, 1e-3, 2e-4),  # MuJoCo at 1/60 is as accurate: a ratio
        run("warpimpulse", "auto", 120, 1e-6, 3e-4),  # more accurate than any MuJoCo run: no ratio, no win
        run("warpimpulse", "auto", 240, 1e-12, 6e-4),  # under the floor: not compared
        run("mujoco", "RK4", 60, 1e-4, 5e-4),
        run("mujoco", "RK4", 30, 2e-3, 3e-4) | {"failed": "MuJoCo diverged (bad qacc) before t = 5 s"},
    ]
    text = "\n".join(report.bar_markdown(runs, floor=1e-11))
    assert "we are faster in 1 and slower in 0; MuJoCo never reached the error of 1" in text
    assert "1 are under 10x the reference's floor" in text
    assert report.excluded(runs, "tree127") == ["mujoco RK4 1/30 (MuJoCo diverged (bad qacc) before t = 5 s)"]
    cells = report.level_cells(runs, "tree127", 1e-11)
    assert [c["status"] for c in cells] == ["compared", "compared", "compared", "not reached by MuJoCo"]
