"""Output files that no fault loses, and USD's errors in one line.

- `write_atomically`: a temporary file in the target's folder, renamed over the target, so that a failed or
  interrupted write leaves the previous file whole. Through a symbolic link it writes the link's target
  (the link stays a link); a device, FIFO or socket (/dev/null, /dev/full) is written straight into, never
  replaced by a regular file. Temporaries carry the writer's process id: one left by a killed process
  (SIGKILL, power loss) is removed by the next write of the same file.
- `interrupts_deferred`: Ctrl-C, SIGTERM and SIGHUP while a file is being saved are noted (one line on
  stderr says so) and raised once the file is whole, so that a second Ctrl-C cannot lose it.
- `signals_interrupt`: SIGTERM and SIGHUP (sent by `timeout`, `kill`, batch schedulers, containers and a
  closed terminal) raise `Interrupted`, a KeyboardInterrupt, so that they end a run like Ctrl-C does.
- `usd_message`: the description in a `pxr.Tf.ErrorException`, without USD's C++ function names;
  `fd2_captured` and `usd_warnings`: what USD's C++ code writes to stderr, caught and made one line each.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import stat
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator

STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


class WriteError(OSError):
    """An output file could not be written; the message names it and the reason. The previous file, if
    any, is unchanged."""


class Interrupted(KeyboardInterrupt):
    """A stop signal (SIGINT, SIGTERM or SIGHUP) received during a run; `signum` says which."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextlib.contextmanager
def signals_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM and SIGHUP raise `Interrupted` (as SIGINT raises KeyboardInterrupt)."""
    if not _main_thread():  # Python delivers signals to the main thread only
        yield
        return

    def handler(signum, _frame):
        raise Interrupted(signum)

    previous = {s: signal.signal(s, handler) for s in STOP_SIGNALS if s != signal.SIGINT}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


@contextlib.contextmanager
def interrupts_deferred(what: str) -> Iterator[None]:
    """Within the block, stop signals are noted, not acted on; after it, the first one is raised as
    `Interrupted`. `what` ("saving out.usdc") goes into the line that tells the user."""
    if not _main_thread():
        yield
        return
    received: list[int] = []

    def handler(signum, _frame):
        if not received:
            print(f"\nwarpimpulse: {signal.Signals(signum).name} while {what}: finishing the file first "
                  "(further interrupts are ignored until it is written)", file=sys.stderr, flush=True)  # fmt: skip
        received.append(signum)

    previous = {s: signal.signal(s, handler) for s in STOP_SIGNALS}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
    if received:
        raise Interrupted(received[0])


def usd_message(exc: BaseException) -> str:
    """The first description in a USD error ("Error in 'pxrInternal_...::Fn' at line N in file F : 'text'"),
    without the C++ parts; parse errors keep their file:line:column and lose the grammar's template names."""
    text = str(exc)
    found = re.findall(r" : '(.*?)'\s*(?:\n|$)", text, flags=re.S)
    message = next((m for m in found if m.strip()), text.strip().splitlines()[-1] if text.strip() else "")
    message = re.sub(r"parse error matching .*?(?= at '| in <|$)", "parse error", message)
    message = re.sub(r"pxrInternal_v\w+?::", "", message)
    return " ".join(message.split())


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether two paths name one file, through symbolic links and hard links."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def _stale_temporaries(folder: str, name: str, suffix: str) -> Iterator[str]:
    """Temporaries of `name` in `folder` left by processes that no longer run."""
    pattern = re.compile(rf"^\.{re.escape(name)}\.(\d+)\.\w+{re.escape(suffix)}$")
    try:
        entries = os.listdir(folder)
    except OSError:
        return
    for entry in entries:
        match = pattern.match(entry)
        if match is None:
            continue
        pid = int(match.group(1))
        if pid == os.getpid():
            continue
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            yield os.path.join(folder, entry)
        except PermissionError:  # alive, another user's
            pass


def write_atomically(path: str | os.PathLike, export: Callable[[str], None], suffix: str, mode: int = 0o644) -> None:
    """Write the file at `path` by calling `export(temporary_path)` (which must write a file there, named
    with `suffix`, e.g. ".usdc"), then renaming it over the target. Raises WriteError naming `path`."""
    path = os.fspath(path)
    target = os.path.realpath(path)  # through symbolic links: the link stays, its target gets the file
    try:
        info = os.stat(target)
    except FileNotFoundError:
        info = None
    except OSError as err:
        raise WriteError(f"{path}: cannot write it ({err.strerror or err})") from None
    if info is not None and not stat.S_ISREG(info.st_mode):
        _write_into(path, target, export, suffix)
        return
    folder, name = os.path.split(target)
    for stale in _stale_temporaries(folder, name, suffix):
        with contextlib.suppress(OSError):
            os.unlink(stale)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{name}.{os.getpid()}.", suffix=suffix, dir=folder)
    except OSError as err:
        raise WriteError(f"{path}: cannot write in {folder} ({err.strerror or err})") from None
    os.close(fd)
    try:
        _export(path, tmp, export)
        os.chmod(tmp, mode)  # mkstemp makes it 0600
        os.replace(tmp, target)
    except OSError as err:
        raise WriteError(f"{path}: could not write the file ({err.strerror or err}); any previous file is "
                         "unchanged") from None  # fmt: skip
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)


def _write_into(path: str, target: str, export: Callable[[str], None], suffix: str) -> None:
    """A device, FIFO or socket: export to a private temporary file, then copy its bytes into the node."""
    with tempfile.TemporaryDirectory(prefix="warpimpulse-") as folder:
        tmp = os.path.join(folder, "out" + suffix)
        try:
            _export(path, tmp, export)
            with open(tmp, "rb") as src, open(target, "wb") as dst:
                shutil.copyfileobj(src, dst)
        except OSError as err:
            raise WriteError(f"{path}: could not write into it ({err.strerror or err})") from None


def _export(path: str, tmp: str, export: Callable[[str], None]) -> None:
    """Run `export`, turning USD's errors (a Tf.ErrorException, or False from Export) into OSError."""
    try:
        ok = export(tmp)
    except OSError:
        raise
    except Exception as err:  # pxr.Tf.ErrorException: its text can be megabytes, one line of it says why
        if type(err).__name__ != "ErrorException":
            raise
        raise OSError(usd_message(err)) from None
    if ok is False:
        raise OSError(f"USD could not export {path}")


@contextlib.contextmanager
def fd2_captured() -> Iterator[list[bytes]]:
    """Within the block, what is written to file descriptor 2 (USD's C++ warnings) is caught; the list
    yielded holds it afterwards."""
    caught: list[bytes] = []
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with tempfile.TemporaryFile() as sink:
            os.dup2(sink.fileno(), 2)
            try:
                yield caught
            finally:
                sys.stderr.flush()
                os.dup2(saved, 2)
                sink.seek(0)
                caught.append(sink.read())
    finally:
        os.close(saved)


def usd_warnings(caught: list[bytes]) -> list[str]:
    """USD's warnings ("Warning: in Fn at line N of file.cpp -- text (context)") as their text, one each."""
    text = b"".join(caught).decode(errors="replace")
    out = []
    for line in text.splitlines():
        line = re.sub(r"^Warning: (in \S+ at line \d+ of \S+ -- )?", "", line.strip())
        line = re.sub(r" \((instantiating stage on stage|in stage) @[^)]*\)$", "", line)
        if line:
            out.append(re.sub(r"\s*\[python[\d.]*\]$", "", line))
    return out
