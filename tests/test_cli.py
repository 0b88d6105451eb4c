"""CLI and scene files: every user mistake ends in one clear line on stderr and a non-zero exit status, never
a traceback; the checks run before any simulation work. A good run is quiet (no Warp banner, module loads or
CUDA-driver warning unless --verbose), writes into out/ by default and says when it overwrites a file;
`preview` draws a written run."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run

from warpimpulse.cli import main

SCENES = Path(__file__).parents[1] / "scenes"


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
    argv = ["simulate", str(tmp_path / "redundant.usda"), "--out", str(tmp_path / "out.usda"), "--duration", "0.2"]
    code, lines = run(argv, capsys)  # runs, and says so: redundancy is information, not an error
    assert code == 0 and lines == ["warpimpulse: 5 constraint rows of loop-closing joints are redundant (regularised)"]


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


def run_command(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """The CLI in a child process, as from a shell: what it prints from a fresh start, Warp's included."""
    return subprocess.run([sys.executable, "-m", "warpimpulse.cli", *argv], capture_output=True, text=True,
                          cwd=cwd, timeout=300)  # fmt: skip


def test_a_run_is_quiet_and_writes_into_out(tmp_path):
    argv = ["simulate", "--scene", "chain", "--duration", "0.1"]
    proc = run_command(argv, tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""  # no banner, no CUDA-driver warning on the CPU, no overwrite notice
    assert proc.stdout.startswith(f"wrote {Path('out', 'chain.usdc')}: 4 frames") and proc.stdout.count("\n") == 1
    assert (tmp_path / "out" / "chain.usdc").is_file()

    proc = run_command([*argv, "--verbose"], tmp_path)  # asked: Warp's messages; and the file is replaced
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.splitlines()[-1] == f"warpimpulse: overwriting {Path('out', 'chain.usdc')}"
    assert "Module warpimpulse.kernels.rigid" in proc.stdout and "initialized" in proc.stdout


def test_the_python_api_is_quiet(tmp_path):
    for verbose in (False, True):
        code = (
            f"import warpimpulse as wi\nwi.Simulator(wi.scenes.chain(2).finalize(), 1 / 60, verbose={verbose}).step()"
        )
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=300)
        assert proc.returncode == 0 and proc.stderr == "", proc.stderr  # no CUDA-driver warning on the CPU
        assert proc.stdout.startswith("Module warpimpulse.kernels") if verbose else proc.stdout == "", proc.stdout


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> dict[str, Path]:
    """A 3-link chain, 0.3 s at 30 fps (10 frames), as body prims and as a PointInstancer."""
    import warpimpulse as wi

    folder = tmp_path_factory.mktemp("preview")
    files = {}
    for name, instancer in (("prims", False), ("instancer", True)):
        sim = wi.Simulator(wi.scenes.chain(3).finalize("cpu"), 1.0 / 30.0)
        files[name] = Path(wi.usd.record(sim, folder / f"{name}.usdc", 0.3, 30.0, instancer=instancer).path)
    return files


def test_preview_reads_the_bodies_and_joints(recorded):
    from warpimpulse import preview, usd

    anim, pairs, anchors = preview.read(recorded["prims"])
    np.testing.assert_array_equal(anim.positions, usd.read_animation(recorded["prims"]).positions)
    assert anim.positions.shape == (10, 3, 3)
    assert pairs.tolist() == [[-1, 0], [0, 1], [1, 2]]  # the world, then link to link
    np.testing.assert_allclose(anchors[0], [0.0, 0.0, 0.0], atol=1e-12)
    anim, pairs, _ = preview.read(recorded["instancer"])
    assert anim.positions.shape == (10, 3, 3) and len(pairs) == 0  # an instancer holds no joints


def test_preview_draws_png_and_gif(recorded, tmp_path, capsys):
    pytest.importorskip("matplotlib")
    from PIL import Image

    png, gif = tmp_path / "chain.png", tmp_path / "chain.gif"
    assert main(["preview", str(recorded["prims"]), "-o", str(png)]) == 0
    assert capsys.readouterr().out.startswith(f"wrote {png}: 3 bodies at 4 of 10 frames")
    pixels = np.asarray(Image.open(png).convert("L"))
    assert pixels.shape[1] > 3 * pixels.shape[0] and (pixels < 128).mean() > 0.001  # 4 panels, something drawn
    assert main(["preview", str(recorded["instancer"]), "-o", str(gif), "--gif-frames", "5"]) == 0
    assert Image.open(gif).n_frames == 5
    assert main(["preview", str(recorded["prims"]), "-o", str(png), "--frames", "2"]) == 0
    assert capsys.readouterr().err == f"warpimpulse: overwriting {png}\n"
    assert_one_line_error(
        ["preview", str(recorded["prims"]), "-o", str(tmp_path / "x.jpg")], "must end in .png", capsys
    )
    assert_one_line_error(["preview", str(tmp_path / "missing.usdc")], "no such file", capsys)


def test_preview_without_matplotlib_says_what_to_install(recorded):
    code = (
        "import sys\n"
        "sys.modules['matplotlib'] = None  # as if it were not installed\n"
        "from warpimpulse.cli import main\n"
        f"sys.exit(main(['preview', {str(recorded['prims'])!r}]))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and 'pip install "warpimpulse[preview]"' in proc.stderr, proc.stderr


@pytest.mark.parametrize("order", [2, 4, 6])
def test_order_is_recorded(order, tmp_path, capsys):
    from pxr import Sdf

    from warpimpulse import composition

    out = tmp_path / "x.usda"
    argv = ["simulate", "--scene", "chain", "--duration", "0.1", "--out", str(out), "--order", str(order)]
    code, _ = run(argv, capsys)
    assert code == 0
    data = Sdf.Layer.FindOrOpen(str(out)).customLayerData
    assert data["warpimpulse:order"] == order
    assert data["warpimpulse:composition"] == composition.DEFAULT[order]
    assert data["warpimpulse:tolerance"] == composition.default_tolerance(1 / 30, order)


@pytest.mark.parametrize("option", ["carry", "defer_velocities"])
@pytest.mark.parametrize(("flag", "taken"), [("auto", True), ("on", True), ("off", False)])
def test_correction_flags_are_taken_and_recorded(option, flag, taken, tmp_path, capsys):
    """`--carry` and `--defer-velocities` set `Simulator(carry=...)` and `Simulator(defer_velocities=...)` (auto: on
    with the cholesky solver on the chain) and the file records what ran (customLayerData warpimpulse:carry,
    warpimpulse:defer_velocities); asked for where it cannot run, one line and exit 2."""
    from pxr import Sdf

    out = tmp_path / "x.usda"
    cli = "--" + option.replace("_", "-")
    code, _ = run(["simulate", "--scene", "chain", "--duration", "0.1", "--out", str(out), cli, flag], capsys)
    assert code == 0
    assert Sdf.Layer.FindOrOpen(str(out)).customLayerData[f"warpimpulse:{option}"] is taken
    code, lines = run(["simulate", "--scene", "chain", "--duration", "0.1", "--out", str(out), cli, "on",
                       "--solver", "cg"], capsys)  # fmt: skip
    assert code == 2 and any(f"{option} needs" in line and "'cg'" in line for line in lines), lines


@pytest.mark.fused
@pytest.mark.parametrize(("flag", "order", "taken"), [("auto", 2, False), ("auto", 4, True), ("on", 2, True),
                                                    ("off", 4, False)])  # fmt: skip
def test_reuse_factor_flag_is_taken_and_recorded(flag, order, taken, tmp_path, capsys):
    """`--reuse-factor` sets `StepOptions(reuse_factor=...)` (auto: at order 4 and 6) and the file records what ran
    (customLayerData warpimpulse:reuse_factor); asked for where it cannot run, one line and exit 2."""
    from pxr import Sdf

    out = tmp_path / "x.usda"
    args = ["simulate", "--scene", "chain", "--duration", "0.1", "--out", str(out), "--order", str(order)]
    code, _ = run([*args, "--reuse-factor", flag], capsys)
    assert code == 0
    assert Sdf.Layer.FindOrOpen(str(out)).customLayerData["warpimpulse:reuse_factor"] is taken
    if flag == "on":
        code, lines = run([*args, "--reuse-factor", "on", "--solver", "cg"], capsys)
        assert code == 2 and any("reuse_factor needs" in line and "'cg'" in line for line in lines), lines


def test_split_forces_flag_is_taken_and_recorded(tmp_path, capsys):
    """`--split-forces` sets `StepOptions(split_forces=...)` and the file records what ran (customLayerData
    warpimpulse:split_forces); asked for on a scene without force elements, one line and exit 2."""
    from pxr import Sdf

    out = tmp_path / "x.usda"
    args = ["simulate", "--scene", "chain", "--duration", "0.1", "--out", str(out)]
    for flag in ("auto", "off"):
        code, _ = run([*args, "--split-forces", flag], capsys)
        assert code == 0 and Sdf.Layer.FindOrOpen(str(out)).customLayerData["warpimpulse:split_forces"] is False
    code, lines = run([*args, "--split-forces", "on"], capsys)
    assert code == 2 and any("split_forces needs" in line and "no force elements" in line for line in lines), lines


@pytest.mark.parametrize(("flag", "taken"), [("auto", False), ("on", True), ("off", False)])
def test_newton_flag_is_taken_and_recorded(flag, taken, tmp_path, capsys):
    """`--newton` sets `Simulator(newton=...)` (auto: off for a chain of a few bodies) and the file records what
    ran (customLayerData warpimpulse:newton)."""
    from pxr import Sdf

    out = tmp_path / "x.usda"
    code, _ = run(["simulate", "--scene", "chain", "--duration", "0.1", "--out", str(out), "--newton", flag], capsys)
    assert code == 0
    assert Sdf.Layer.FindOrOpen(str(out)).customLayerData["warpimpulse:newton"] is taken
