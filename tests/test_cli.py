"""Issue 5, CLI and scene files: every user mistake ends in one clear line on stderr and a non-zero exit
status, never a traceback; the checks run before any simulation work."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from warpimpulse.cli import main

SCENES = Path(__file__).parents[1] / "scenes"


def run(argv: list[str], capsys) -> tuple[int, list[str]]:
    """Exit status and the lines on stderr (Warp's own start-up notices left out)."""
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse exits by itself
        code = exc.code
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return code, [line for line in err.splitlines() if line.strip() and not line.startswith("Warp")]


def assert_one_line_error(argv: list[str], message: str, capsys, code: int = 2) -> None:
    got, lines = run(argv, capsys)
    assert got == code, (got, lines)
    assert len(lines) == 1 and "error: " in lines[0] and message in lines[0], lines


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--scene", "nope"], "argument --scene: invalid choice: 'nope'"),
        (["--dt", "-1"], "argument --dt: must be positive and finite, got -1"),
        (["--dt", "abc"], "argument --dt: expected a number, got 'abc'"),
        (["--fps", "0"], "argument --fps: must be positive"),
        (["--fps", "inf"], "argument --fps: must be positive and finite"),
        (["--duration", "nan"], "argument --duration: must be positive"),
        (["--duration", "inf"], "argument --duration: must be positive and finite"),
        (["--tolerance", "0"], "argument --tolerance: must be positive"),
        (["--velocity-tolerance=-1e-6"], "argument --velocity-tolerance: must be positive"),
        (["--max-iterations", "0"], "argument --max-iterations: must be positive"),
        (["--max-iterations", "1.5"], "argument --max-iterations: expected a number"),
        (["--solver", "lu"], "argument --solver: invalid choice: 'lu'"),
        (["--on-max-iterations", "ignore"], "argument --on-max-iterations: invalid choice"),
        (["--max-rotation", "0"], "argument --max-rotation: must be positive"),
        (["--bogus"], "unrecognized arguments: --bogus"),
    ],
)
def test_bad_flags(flags, message, capsys):
    assert_one_line_error(["simulate", *flags], message, capsys)


def test_bad_command(capsys):
    assert_one_line_error(["bogus"], "invalid choice: 'bogus'", capsys)
    assert_one_line_error([], "required: command", capsys)


@pytest.fixture
def not_usd(tmp_path) -> dict[str, Path]:
    (tmp_path / "text.usda").write_text("hello, not USD\n")
    (tmp_path / "noise.usdc").write_bytes(bytes(range(256)) * 4)
    (tmp_path / "empty.usda").write_text("#usda 1.0\n")
    return {p.stem: p for p in tmp_path.iterdir()}


def test_bad_scene_files(tmp_path, not_usd, capsys):
    out = ["--out", str(tmp_path / "out.usda")]
    assert_one_line_error(["simulate", str(tmp_path / "missing.usda"), *out], "missing.usda: no such file", capsys)
    assert_one_line_error(["simulate", str(tmp_path), *out], f"{tmp_path}: not a file", capsys)
    assert_one_line_error(["simulate", str(not_usd["text"]), *out], "not a USD file that can be opened", capsys)
    assert_one_line_error(["simulate", str(not_usd["noise"]), *out], "not a USD file that can be opened", capsys)
    assert_one_line_error(["simulate", str(not_usd["empty"]), *out], "no rigid bodies", capsys)
    assert_one_line_error(["simulate", str(not_usd["text"]), "--scene", "chain"], "not both", capsys)
    assert not (tmp_path / "out.usda").exists()


@pytest.mark.parametrize(
    "old, new, message",
    [
        ("float physics:mass = 7.592182", "float physics:mass = -1", "/World/link0: physics:mass must be positive"),
        ("float physics:mass = 7.592182", "float physics:mass = nan", "/World/link0: physics:mass must be positive"),
        ("float3 physics:diagonalInertia = (0.009359328, 0.59693533, 0.59693533)",
         "float3 physics:diagonalInertia = (0.1, 0.1, 5)", "'/World/link0': principal moments"),
        ("vector3f physics:velocity = (0, 0, 0)", "vector3f physics:velocity = (nan, 0, 0)",
         "/World/link0: physics:velocity is not finite"),
        ("point3f physics:localPos0 = (0, 0, 0)", "point3f physics:localPos0 = (inf, 0, 0)",
         "/World/Joints/j0: physics:localPos0 is not finite"),
        ("float physics:gravityMagnitude = 9.81", "float physics:gravityMagnitude = nan",
         "/World/PhysicsScene: physics:gravityMagnitude is not finite"),
        ("rel physics:body1 = </World/link1>", "rel physics:body1 = </World/nothere>",
         "/World/Joints/j1: physics:body1 targets /World/nothere, which does not exist"),
        ("rel physics:body0 = </World/link0>", "rel physics:body0 = </World/link1>",
         "joint '/World/Joints/j1': connects body '/World/link1' to itself"),
    ],
)  # fmt: skip
def test_bad_physics_in_a_scene_file(old, new, message, tmp_path, capsys):
    text = (SCENES / "chain.usda").read_text()
    assert old in text
    path = tmp_path / "bad.usda"
    path.write_text(text.replace(old, new, 1))
    assert_one_line_error(["simulate", str(path), "--out", str(tmp_path / "out.usda")], message, capsys)


def test_redundant_joints_in_a_scene_file(tmp_path, capsys):
    from warpimpulse import usd
    from warpimpulse.bench import stress

    usd.save_scene(stress.redundant_pair(), tmp_path / "redundant.usda")
    argv = ["simulate", str(tmp_path / "redundant.usda"), "--out", str(tmp_path / "out.usda")]
    assert_one_line_error(argv, "singular at joint '/World/Joints/hinge'", capsys)


def test_bad_output_paths(tmp_path, capsys):
    run_to = ["simulate", "--scene", "chain", "--duration", "0.1", "--out"]
    assert_one_line_error([*run_to, str(tmp_path / "no" / "dir" / "x.usda")], "the directory", capsys)
    assert not (tmp_path / "no").exists()
    assert_one_line_error([*run_to, str(tmp_path)], "is a directory", capsys)
    assert_one_line_error([*run_to, str(tmp_path / "x.txt")], "output must end in .usd, .usda or .usdc", capsys)
    assert_one_line_error([*run_to, str(tmp_path / "x.usda"), "--dt", "0.013"], "not a whole multiple", capsys)
    assert_one_line_error([*run_to, str(tmp_path / "x.usda"), "--device", "nodevice"], "nodevice", capsys)
    if Path("/proc/self").is_dir():  # not writable even for root
        assert_one_line_error([*run_to, "/proc/x.usda"], "cannot write in /proc", capsys)
    if hasattr(os, "geteuid") and os.geteuid() != 0:
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o555)
        assert_one_line_error([*run_to, str(locked / "x.usda")], "cannot write in", capsys)
    assert list(tmp_path.iterdir()) in ([], [tmp_path / "locked"])
    code, lines = run([*run_to, str(tmp_path / "ok.usda")], capsys)  # and a good run still goes through
    assert code == 0 and (tmp_path / "ok.usda").is_file()


def test_stress_and_bench_usage_errors(tmp_path, capsys):
    assert_one_line_error(["stress", "--bogus"], "unrecognized arguments: --bogus", capsys)
    assert run(["stress", "--case", "no-such-case"], capsys)[0] == 2
    if Path("/proc/self").is_dir():
        argv = ["stress", "--case", "redundant_fixed_hinge_cholesky", "--json", "/proc/x/stress.json"]
        assert_one_line_error(argv, "cannot create the directory /proc/x", capsys)
    assert run(["bench", "--bogus"], capsys)[0] == 2


def test_the_installed_command_prints_no_traceback(tmp_path):
    """The real entry point, in a child process: the error and the exit status reach the shell."""
    (tmp_path / "text.usda").write_text("hello\n")
    for argv, message in (
        (["simulate", "--duration", "inf"], "must be positive and finite"),
        (["simulate", str(tmp_path / "text.usda"), "--out", str(tmp_path / "o.usda")], "not a USD file"),
    ):
        proc = subprocess.run([sys.executable, "-m", "warpimpulse.cli", *argv], capture_output=True, text=True,
                              timeout=120)  # fmt: skip
        assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


@pytest.mark.parametrize(
    ("flags", "recorded"), [([], 0.5), (["--max-rotation", "0.25"], 0.25), (["--whole-steps"], 0.0)]
)
def test_substep_flags_are_recorded(flags, recorded, tmp_path, capsys):
    from pxr import Sdf

    out = tmp_path / "x.usda"
    code, _ = run(["simulate", "--scene", "chain", "--duration", "0.1", "--out", str(out), *flags], capsys)
    assert code == 0
    assert Sdf.Layer.FindOrOpen(str(out)).customLayerData["warpimpulse:max_rotation"] == recorded
