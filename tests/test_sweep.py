"""`warpimpulse sweep`: points as batched worlds on a process pool (or Ray), one table, failures recorded, and a
stopped sweep resumed with only the missing points computed."""

from __future__ import annotations

import csv
import json

import pytest

from warpimpulse import sweep
from warpimpulse.cli import main

GRID = {"mass_scale": [1.0, 2.0], "spin": [0.0, 1.0], "force": [0.0, 1e13], "duration": [0.05]}


def without_timing(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in row.items() if k not in sweep.TIMING} for row in rows]


@pytest.fixture(scope="module")
def pool_sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("pool")
    return out, sweep.run(sweep.make_points(GRID), out, workers=2, backend="pool")


def test_pool_sweep_records_every_point_and_failures(pool_sweep):
    out, result = pool_sweep
    assert result.backend == "pool" and result.computed == list(range(8))
    rows = result.rows
    assert [r["point"] for r in rows] == list(range(8))
    assert [r["outcome"] for r in rows] == ["ok", "stopped"] * 4  # the huge force fails; the rest go on
    for r in rows:
        if r["outcome"] == "ok":
            assert r["steps"] == 3 and r["joint_iterations"] > 0 and r["max_joint_error"] <= 1e-6
            assert r["energy_drift"] is not None and r["error"] == ""
        else:
            assert r["error"].startswith("step 1 ") and "world" not in r["error"] and r["energy_drift"] is None
    with (out / "sweep.csv").open() as f:
        table = list(csv.DictReader(f))
    assert len(table) == 8 and list(table[0]) == list(sweep.COLUMNS)
    assert json.loads((out / "sweep.json").read_text()) == rows


def test_points_alone_give_the_same_rows_as_in_a_chunk(pool_sweep):
    """A point's row does not depend on its chunk: each world of a batch runs as it would alone."""
    _, result = pool_sweep
    points = sweep.make_points(GRID)
    alone = [row for p in points[:4] for row in sweep.run_chunk([p])]
    assert without_timing(alone) == without_timing(result.rows[:4])


def test_resumed_sweep_computes_only_the_missing_points(pool_sweep, tmp_path):
    out, first = pool_sweep
    lines = (out / "points.jsonl").read_text().splitlines()
    (tmp_path / "points.jsonl").write_text("\n".join(lines[:5]) + '\n{"cut short')  # a stop mid-line
    done = {json.loads(line)["point"] for line in lines[:5]}
    again = sweep.run(sweep.make_points(GRID), tmp_path, workers=2, backend="pool")
    assert again.computed == sorted(set(range(8)) - done)
    assert without_timing(again.rows) == without_timing(first.rows)
    assert sweep.run(sweep.make_points(GRID), tmp_path, workers=2, backend="pool").computed == []


@pytest.mark.slow
def test_ray_sweep_gives_the_pool_table(pool_sweep, tmp_path):
    ray = pytest.importorskip("ray")
    try:
        result = sweep.run(sweep.make_points(GRID), tmp_path, workers=2, backend="ray")
    finally:
        ray.shutdown()
    assert result.backend == "ray" and result.computed == list(range(8))
    assert without_timing(result.rows) == without_timing(pool_sweep[1].rows)


def test_points_grid_random_and_config(tmp_path):
    grid = sweep.make_points({"dt": [0.01, 0.02], "spin": [0.0, 1.0, 2.0]})
    assert len(grid) == 6 and grid[1].params["spin"] == 1.0 and grid[0].params["scene"] == "tree31"
    config = tmp_path / "s.toml"
    config.write_text('[params]\nscene = ["chain"]\n[random]\nsamples = 5\nseed = 3\n[random.ranges]\nspin = [0, 2]\n')
    c = sweep.load_config(config)
    a = sweep.make_points(c["params"], c["samples"], c["seed"], c["ranges"])
    b = sweep.make_points(c["params"], c["samples"], c["seed"], c["ranges"])
    assert [p.params for p in a] == [p.params for p in b] and len(a) == 5
    assert all(0.0 <= p.params["spin"] < 2.0 and p.params["scene"] == "chain" for p in a)
    chunks = sweep.make_chunks(grid, workers=2)
    assert sorted(p.index for c in chunks for p in c) == list(range(6))
    assert all(len({p.params["dt"] for p in c}) == 1 for c in chunks)  # a chunk shares its simulator


@pytest.mark.parametrize(
    "args, message",
    [
        (["--param", "gravity=1"], "unknown parameter 'gravity'"),
        (["--param", "dt=-1"], "parameter dt: must be positive"),
        (["--param", "scene=moon"], "unknown scene 'moon'"),
        (["--param", "dt"], "expected name=value1,value2"),
        ([], "nothing to sweep"),
    ],
)
def test_cli_refuses_bad_input_in_one_line(args, message, tmp_path, capsys):
    assert main(["sweep", *args, "-o", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def test_cli_without_ray_says_it_runs_on_the_pool(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sweep, "ray_available", lambda: False)
    assert main(["sweep", "--param", "duration=0.02", "--workers", "1", "--no-plot", "-o", str(tmp_path)]) == 0
    captured = capsys.readouterr()
    assert "Ray is not installed" in captured.err and "process pool" in captured.err
    assert "swept 1 points (1 computed on pool, 0 done before): 1 ok" in captured.out
    assert main(["sweep", "--param", "duration=0.02", "--address", "h:1", "-o", str(tmp_path)]) == 2
