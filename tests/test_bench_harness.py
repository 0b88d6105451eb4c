"""The benchmark harness's own logic: scaling budgets, isolation of slow points, the scaling report."""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path

import pytest

from warpimpulse.bench import harness, report


def _row(n: int, setup: float, step: float) -> dict:
    return {"bodies": n, "setup_s": setup, "time_per_step": step}


def test_cheap_sizes_are_always_tried() -> None:
    """Fixed overheads say nothing about growth: below half a second nothing is projected."""
    done = [_row(10, 0.2, 1e-4)]
    assert harness.over_budget(done, "chain", "mujoco", 100_000, 80, 1.0) is None


def test_a_costly_size_is_projected_with_the_measured_growth() -> None:
    done = [_row(1000, 1.0, 0.01), _row(4000, 4.0, 0.04)]  # linear
    assert harness.over_budget(done, "tree", "warpimpulse", 16000, 80, 60.0) is None  # 16 + 12.8 s
    why = harness.over_budget(done, "tree", "warpimpulse", 64000, 80, 60.0)  # 64 + 51 s
    assert why is not None and why.startswith("projected 115 s") and "n^1.0" in why


def test_mujoco_chains_are_projected_cubic_before_two_sizes_are_measured() -> None:
    why = harness.over_budget([_row(1000, 3.0, 0.001)], "chain", "mujoco", 3000, 80, 60.0)
    assert why is not None and "setup ~n^3.0" in why


def test_a_size_after_one_past_the_budget_is_skipped() -> None:
    done = [{"bodies": 100, "over_budget": True}]
    assert "already ran past" in harness.over_budget(done, "tree", "warpimpulse", 200, 80, 60.0)


def test_a_point_past_its_budget_is_stopped_and_reported() -> None:
    start = time.perf_counter()
    result = harness.isolated(partial(time.sleep, 60), 2.0)
    assert result["over_budget"] and "budget of 2 s" in result["skipped"]
    assert time.perf_counter() - start < 30.0


@pytest.mark.slow
def test_scaling_end_to_end(tmp_path) -> None:
    pytest.importorskip("mujoco")
    pytest.importorskip("matplotlib")
    rows = harness.scaling([15], [3], steps=2, repeats=1, budget_s=60.0, progress=False)
    assert len(rows) == 6 and all(r["time_per_step"] > 0.0 and r["setup_s"] > 0.0 for r in rows)
    ours = [r for r in rows if r["engine"] == "warpimpulse"]
    assert all(r["joint_iterations_mean"] >= 1.0 for r in ours)
    results = {"scaling": {"budget_s": 60.0, "steps": 2, "repeats": 1, "rows": rows}}
    assert "| tree | 15 | warpimpulse | auto |" in report.markdown(results)
    assert [p.name for p in report.plots(results, tmp_path)] == ["scaling.png"]


def test_paper_tables_render_from_their_json() -> None:
    """RESULTS.md carries the paper's tables, rendered from paper_tables.py's JSON like everything else."""
    row = {"steps": 90, "median_ms": 1.0, "mean_ms": 1.0, "joint_iterations": 2.0, "velocity_iterations": 1.0}
    rows = [row | {"scene": "tree127", "solver": s, "tolerance": t} for s in ("iterative", "cholesky")
            for t in (1e-2, 1e-4, 1e-6)]  # fmt: skip
    tables = {
        "machine": {"processor": "x86_64", "python": "3.11", "warp": "1.19"}, "dt": 1 / 30, "rows": rows,
        "star": [row | {"scene": "star127", "solver": s, "tolerance": 1e-4} for s in ("iterative", "cholesky")],
        "paper": {"with_sle": {"127": [18.78, 18.95, 20.09]}, "without_sle": {"127": [6.25, 87.05, 228.57]},
                  "table1": {"iterative": {"ms": 228.57, "jc": 518.15, "vc": 745.54},
                             "cholesky": {"ms": 20.09, "jc": 2, "vc": 1}}},
    }  # fmt: skip
    text = "\n".join(report.paper_markdown(tables))
    assert "| time per step (ms) | 228.57 | 1.000 | 20.09 | 1.000 |" in text
    assert "| tree 127 | 18.78 / 1.000 (2.0) | 18.95 / 1.000 (2.0) | 20.09 / 1.000 (2.0) |" in text
    assert "1.0x; the paper reports almost 80x" in text


def test_the_readme_block_is_the_committed_json_written_up() -> None:
    """docs/results.md's results block is generated (make bench), never typed: it equals the write-up of the JSON."""
    root = Path(__file__).resolve().parents[1]
    results = report.load([root / "benchmarks/results" / f"{name}.json"
                           for name in ("paper_tables", "run_vs_error", "scaling")])  # fmt: skip
    text = (root / "docs/results.md").read_text()
    begin, end = text.index(report.README_BEGIN) + len(report.README_BEGIN), text.index(report.README_END)
    assert text[begin:end].strip() == report.readme_block(results, "../benchmarks/results").strip()
    assert (root / "benchmarks/results/RESULTS.md").read_text() == report.markdown(results)
