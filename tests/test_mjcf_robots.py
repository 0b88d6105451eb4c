"""benchmarks/mjcf_robots.py, the probe of every gymnasium and dm_control MJCF model: run on two small models for
a short time, its JSON holds a row per variant and run, and its table is made from that JSON (failures and
refusals listed under it). Nothing here times anything; the figures are the script's, not asserted."""

import json

import pytest
from scripts import benchmark

pytest.importorskip("mujoco")
pytest.importorskip("gymnasium")
pytest.importorskip("dm_control")


@pytest.fixture(scope="module")
def probe():
    yield from benchmark("mjcf_robots")


def test_the_table_is_made_from_the_json(probe, tmp_path) -> None:
    out, table = tmp_path / "r.json", tmp_path / "r.md"
    assert probe.main(["--models", "g/swimmer", "d/lqr", "--duration", "0.1", "--json", str(out),
                       "--markdown", str(table)]) == 0  # fmt: skip
    results = json.loads(out.read_text())
    swimmer, lqr = results["models"]
    for variant in ("shipped", "bare"):
        runs = swimmer["variants"][variant]["runs"]
        assert [(r["order"], r["h"] / swimmer["variants"][variant]["timestep"]) for r in runs] == [
            (2, 1.0), (4, 1.0), (2, 2.0), (4, 2.0)]  # fmt: skip
        assert all(r["failed"] is None and r["solves"] >= 0.0 for r in runs)
        assert lqr["variants"][variant]["load"] == "refused"  # a template with no bodies
    text = table.read_text()
    assert text == probe.markdown(results)
    assert "| g/swimmer | shipped |" in text and "d/lqr (shipped): refused: the scene has no bodies" in text


def test_an_unknown_model_is_one_line_and_exit_2(probe, capsys) -> None:
    assert probe.main(["--models", "g/nothing"]) == 2
    assert "unknown model 'g/nothing'" in capsys.readouterr().err
