"""files.py (issue 14): atomic writes through links and into devices, stale temporaries, deferred interrupts,
stop signals, USD's errors in one line."""

from __future__ import annotations

import os
import signal
import stat
from pathlib import Path

import pytest
from pxr import Sdf, Tf, Usd

from warpimpulse.files import (
    Interrupted,
    WriteError,
    interrupts_deferred,
    same_file,
    signals_interrupt,
    usd_message,
    write_atomically,
)


def _export_text(text: str):
    def export(tmp: str) -> None:
        Path(tmp).write_text(text)

    return export


def test_replaces_a_regular_file_and_leaves_no_temporary(tmp_path):
    out = tmp_path / "out.usda"
    out.write_text("old")
    write_atomically(out, _export_text("new"), ".usda")
    assert out.read_text() == "new" and os.listdir(tmp_path) == ["out.usda"]
    assert stat.S_IMODE(out.stat().st_mode) == 0o644


def test_writes_through_a_symbolic_link(tmp_path):
    real = tmp_path / "data" / "real.usda"
    real.parent.mkdir()
    real.write_text("old")
    link = tmp_path / "link.usda"
    link.symlink_to(real)
    write_atomically(link, _export_text("new"), ".usda")
    assert link.is_symlink() and real.read_text() == "new"
    assert sorted(os.listdir(real.parent)) == ["real.usda"]


@pytest.mark.skipif(not os.path.exists("/dev/null"), reason="no /dev/null")
def test_a_device_is_written_into_not_replaced():
    write_atomically("/dev/null", _export_text("frames"), ".usda")
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full")
def test_a_full_device_is_one_error():
    with pytest.raises(WriteError, match=r"^/dev/full: could not write into it \(No space left on device\)$"):
        write_atomically("/dev/full", _export_text("frames" * 1000), ".usda")
    assert stat.S_ISCHR(os.stat("/dev/full").st_mode)


def _dead_pid() -> int:
    for pid in range(4_000_000, 3_000_000, -1):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return pid
        except PermissionError:
            continue
    pytest.skip("no free process id")


def test_stale_temporaries_of_a_killed_writer_are_removed(tmp_path):
    out = tmp_path / "out.usdc"
    dead, alive = _dead_pid(), os.getppid()
    stale = tmp_path / f".out.usdc.{dead}.k3j_x9.usdc"
    running = tmp_path / f".out.usdc.{alive}.a8b7c6.usdc"  # another process writing now: kept
    other = tmp_path / f".other.usdc.{dead}.k3j_x9.usdc"  # another file's: not ours to clean
    for p in (stale, running, other):
        p.write_text("partial")
    write_atomically(out, _export_text("whole"), ".usdc")
    assert sorted(os.listdir(tmp_path)) == sorted([out.name, running.name, other.name])


def test_a_usd_error_is_one_line_and_keeps_the_previous_file(tmp_path):
    out = tmp_path / "out.usda"
    out.write_text("previous")

    def export(tmp: str) -> None:
        Path(tmp).write_text("partial")
        Tf.RaiseRuntimeError("Error occurred writing file: File too large")

    with pytest.raises(WriteError) as err:
        write_atomically(out, export, ".usda")
    message = str(err.value)
    assert message.startswith(f"{out}: could not write the file (") and "File too large" in message
    assert "pxrInternal" not in message and "\n" not in message
    assert out.read_text() == "previous" and os.listdir(tmp_path) == ["out.usda"]


def test_usd_messages_lose_the_cpp_parts(tmp_path):
    bad = tmp_path / "bad.usda"
    bad.write_text('#usda 1.0\ndef Xform "W" (\n    prepend apiSchemas = []\n)\n{\n}\n')
    with pytest.raises(Tf.ErrorException) as err:
        Sdf.Layer.FindOrOpen(str(bad))
    assert usd_message(err.value) == f"{bad}:3:27: parse error at ']' in </W>"
    text = tmp_path / "text.usda"
    text.write_text("hello")
    with pytest.raises(Tf.ErrorException) as err:
        Usd.Stage.Open(str(text))
    assert usd_message(err.value) == f"<{text}> is not a valid usda layer"


def test_interrupts_while_saving_are_deferred_and_said(capsys):
    done = []
    with pytest.raises(Interrupted) as err:
        with interrupts_deferred("saving out.usdc"):
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGINT)  # a second Ctrl-C: ignored as well
            done.append("saved")
    assert done == ["saved"] and err.value.name == "SIGINT"
    lines = [line for line in capsys.readouterr().err.splitlines() if line]
    assert lines == ["warpimpulse: SIGINT while saving out.usdc: finishing the file first (further interrupts are "
                     "ignored until it is written)"]  # fmt: skip
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


@pytest.mark.parametrize("name", ["SIGTERM", "SIGHUP"])
def test_stop_signals_interrupt_like_ctrl_c(name):
    signum = getattr(signal, name)
    before = signal.getsignal(signum)
    with pytest.raises(Interrupted) as err:
        with signals_interrupt():
            os.kill(os.getpid(), signum)
    assert isinstance(err.value, KeyboardInterrupt) and err.value.name == name
    assert signal.getsignal(signum) == before


def test_same_file_through_links(tmp_path):
    real = tmp_path / "scene.usda"
    real.write_text("x")
    (tmp_path / "link.usda").symlink_to(real)
    os.link(real, tmp_path / "hard.usda")
    assert same_file(tmp_path / "link.usda", real) and same_file(tmp_path / "hard.usda", real)
    assert same_file(tmp_path / "sub" / ".." / "scene.usda", real)
    assert not same_file(tmp_path / "absent.usda", real)
