"""Issue 14, the command line: every user mistake is one line and exit 2; no wrong answer is silent."""

from __future__ import annotations

import pytest
import warp as wp
from pxr import Sdf
from test_cli import assert_one_line_error, run


def _layer_data(path) -> dict:
    return dict(Sdf.Layer.FindOrOpen(str(path)).customLayerData)


@pytest.mark.parametrize("device", ["tpu", "cuda:99"] + ([] if wp.get_cuda_device_count() else ["cuda"]))
def test_unavailable_device(device, tmp_path, capsys):
    out = tmp_path / "o.usdc"
    assert_one_line_error(["simulate", "--device", device, "--out", str(out)], f"device '{device}'", capsys)
    assert not out.exists()


@pytest.mark.parametrize("fps,duration", [("0.1", "1"), ("1", "0.4"), ("0.5", "0.9")])
def test_no_frame_in_the_duration_is_refused(fps, duration, tmp_path, capsys):
    out = tmp_path / "o.usdc"
    argv = ["simulate", "--scene", "tree31", "--fps", fps, "--duration", duration, "--out", str(out)]
    assert_one_line_error(argv, f"--fps {fps}: a frame lasts", capsys)
    assert not out.exists()


def test_energy_gain_of_whole_steps_is_recorded_and_warned(tmp_path, capsys):
    """h = 0.5 s whole steps on the 31-body tree gain about as much energy as the motion has: a warning naming
    the threshold, and the gain in the layer data. With substeps (the default) the same run holds, silently."""
    whole, split = tmp_path / "whole.usdc", tmp_path / "split.usdc"
    base = ["simulate", "--scene", "tree31", "--fps", "2", "--duration", "6"]
    code, lines = run([*base, "--whole-steps", "--out", str(whole)], capsys)
    assert code == 0 and len(lines) == 1, lines
    assert "warning: the energy grew by" in lines[0] and "above the 5% threshold" in lines[0], lines
    data = _layer_data(whole)
    assert data["warpimpulse:energyGain"] > 0.05 and data["warpimpulse:energyGainThreshold"] == 0.05
    code, lines = run([*base, "--out", str(split)], capsys)
    assert code == 0 and not lines, lines
    data = _layer_data(split)
    assert 0.0 <= data["warpimpulse:energyGain"] < 0.05 and abs(data["warpimpulse:energyDrift"]) < 0.05
