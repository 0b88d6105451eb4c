"""Issue 14, the command line: every user mistake is one line and exit 2; no wrong answer is silent."""

from __future__ import annotations

import os
import resource
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
import warp as wp
from cli_helpers import assert_one_line_error, run
from pxr import Sdf


def _layer_data(path) -> dict:
    return dict(Sdf.Layer.FindOrOpen(str(path)).customLayerData)


@pytest.mark.parametrize("device", ["tpu", "cuda:99"] + ([] if wp.get_cuda_device_count() else ["cuda"]))
def test_unavailable_device(device, tmp_path, capsys):
    out = tmp_path / "o.usdc"
    assert_one_line_error(["simulate", "--device", device, "--out", str(out)], f"device '{device}'", capsys)
    assert not out.exists()


@pytest.mark.skipif(wp.get_cuda_device_count() > 0, reason="this machine has a GPU")
def test_cuda_without_a_gpu_is_exactly_one_line(tmp_path):
    """In a fresh process, so that Warp's own CUDA messages (written to file descriptor 2) would show."""
    proc = subprocess.run([sys.executable, "-m", "warpimpulse.cli", "simulate", "--device", "cuda", "--out",
                           str(tmp_path / "o.usdc")], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 2 and proc.stderr.splitlines() == [
        "warpimpulse: error: device 'cuda' is not available (Warp finds no CUDA GPU or driver); this machine has: cpu"
    ], proc.stderr


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


# ------------------------------------------------------------------------------------------------ output paths
SCENES = Path(__file__).parents[1] / "scenes"


def _frames(path) -> int:
    return int(_layer_data(path)["warpimpulse:framesWritten"])


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/null, /dev/full")
def test_device_outputs_are_written_into_never_replaced(capsys):
    code, lines = run(["simulate", "--scene", "chain", "--duration", "0.1", "--out", "/dev/null"], capsys)
    assert code == 0 and not lines and stat.S_ISCHR(os.stat("/dev/null").st_mode)
    code, lines = run(["simulate", "--scene", "chain", "--duration", "0.1", "--out", "/dev/full"], capsys)
    assert code == 1 and lines == ["warpimpulse: error: /dev/full: could not write into it (No space left on device)"]
    assert stat.S_ISCHR(os.stat("/dev/full").st_mode)


@pytest.mark.parametrize("flatten", [False, True])
def test_the_input_scene_is_never_the_output(flatten, tmp_path, capsys):
    scene = tmp_path / "chain.usda"
    shutil.copy(SCENES / "chain.usda", scene)
    before = scene.read_bytes()
    (tmp_path / "link.usda").symlink_to(scene)
    os.link(scene, tmp_path / "hard.usda")
    for source, out in [(scene, scene), (scene, tmp_path / "link.usda"), (tmp_path / "link.usda", scene),
                        (scene, tmp_path / "hard.usda"), (scene, tmp_path / "sub" / ".." / "chain.usda")]:  # fmt: skip
        argv = ["simulate", str(source), "--duration", "0.1", "--out", str(out)] + (["--flatten"] if flatten else [])
        assert_one_line_error(argv, "is the input scene; the output would replace it", capsys)
    assert scene.read_bytes() == before and (tmp_path / "link.usda").is_symlink()


def test_the_writer_refuses_its_input_too(tmp_path):
    from warpimpulse import usd

    scene = usd.load_stage(SCENES / "chain.usda")
    with pytest.raises(ValueError, match="is the input scene"):
        usd.AnimationWriter(SCENES / "chain.usda", scene, 30)


def test_a_symbolic_link_output_is_written_through(tmp_path, capsys):
    target = tmp_path / "runs" / "chain.usdc"
    target.parent.mkdir()
    link = tmp_path / "latest.usdc"
    link.symlink_to(target)
    code, _ = run(["simulate", "--scene", "chain", "--duration", "0.1", "--out", str(link)], capsys)
    assert code == 0 and link.is_symlink() and _frames(target) == 4
    assert sorted(os.listdir(target.parent)) == ["chain.usdc"]


def test_a_stale_temporary_of_a_killed_run_is_removed(tmp_path, capsys):
    """SIGKILL during the write leaves `.<name>.<pid>.<random>.usdc`; the next run of that output removes it."""
    out = tmp_path / "o.usdc"
    pid = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    ).stdout.strip()  # fmt: skip  (a process that has ended)
    stale = tmp_path / f".o.usdc.{pid}.x1y2z3.usdc"
    stale.write_bytes(b"PXR-USDC partial")
    code, _ = run(["simulate", "--scene", "chain", "--duration", "0.1", "--out", str(out)], capsys)
    assert code == 0 and sorted(os.listdir(tmp_path)) == ["o.usdc"]


# ------------------------------------------------------------------------------------------------ faults in a run
def _start(argv: list[str], **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "warpimpulse.cli", *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kwargs)  # fmt: skip


@pytest.mark.parametrize("name", ["SIGTERM", "SIGHUP", "SIGINT"])
def test_stop_signals_keep_the_frames_and_say_so(name, tmp_path):
    """What `timeout`, `kill`, a batch scheduler or a closed terminal send ends the run like Ctrl-C: the
    frames done are saved, the message says how many, the exit status is 128 + the signal."""
    out = tmp_path / "o.usdc"
    proc = _start(["simulate", "--scene", "tree127", "--duration", "1000", "--out", str(out), "--progress"])
    deadline = time.monotonic() + 120
    progress = ""
    while "] 5/" not in progress and "] 6/" not in progress and time.monotonic() < deadline:  # frames under way
        progress += proc.stderr.read(1)
    signum = getattr(signal, name)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    lines = [line for line in err.replace("\r", "\n").splitlines() if line.startswith("warpimpulse")]
    assert proc.returncode == 128 + signum, err
    frames = _frames(out)
    assert lines == [f"warpimpulse: interrupted ({name}); {out} holds the {frames} frames done"], err
    assert frames >= 6 and _layer_data(out)["warpimpulse:stoppedEarly"] == f"interrupted ({name})"


def test_interrupts_during_the_final_write_finish_it(tmp_path, capsys, monkeypatch):
    """Ctrl-C twice while the file is being saved: the file is finished and holds every frame, the user is told
    the interrupts wait for it, and the closing message is true."""
    from warpimpulse.usd import writer

    real = writer.write_atomically

    def interrupted_twice(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)
        os.kill(os.getpid(), signal.SIGINT)
        return real(*args, **kwargs)

    monkeypatch.setattr(writer, "write_atomically", interrupted_twice)
    out = tmp_path / "o.usdc"
    code, lines = run(["simulate", "--scene", "chain", "--duration", "0.5", "--out", str(out)], capsys)
    assert code == 130
    assert lines == [f"warpimpulse: SIGINT while saving {out}: finishing the file first (further interrupts are "
                     "ignored until it is written)",
                     f"warpimpulse: interrupted (SIGINT); {out} holds the 16 frames done"]  # fmt: skip
    assert _frames(out) == 16


@pytest.mark.skipif(not hasattr(resource, "RLIMIT_FSIZE"), reason="no file size limit here")
def test_a_file_size_limit_is_one_line_and_keeps_the_previous_output(tmp_path, capsys):
    """The write fails (EFBIG, as a full disk fails with ENOSPC): one line naming the file and the reason,
    exit 1, the previous output byte for byte, no temporary left."""
    out = tmp_path / "o.usdc"
    assert run(["simulate", "--scene", "tree31", "--duration", "0.1", "--out", str(out)], capsys)[0] == 0  # warm
    previous = out.read_bytes()
    limit = len(previous) + 4096  # the longer run's file is ~46 kB

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    proc = _start(["simulate", "--scene", "tree31", "--duration", "1", "--out", str(out)], preexec_fn=cap)
    _, err = proc.communicate(timeout=300)
    lines = [line for line in err.splitlines() if line.startswith("warpimpulse") and "overwriting" not in line]
    assert proc.returncode == 1 and "Traceback" not in err, err
    assert len(lines) == 1 and lines[0].startswith(f"warpimpulse: error: {out}: could not write the file ("), err
    assert "File too large" in lines[0] and "previous file is unchanged" in lines[0] and "pxrInternal" not in err
    assert out.read_bytes() == previous and os.listdir(tmp_path) == ["o.usdc"]
