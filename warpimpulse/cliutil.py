"""What every command line of the package shares (`warpimpulse.cli` and the harness's commands): a usage
mistake reported in one line with exit status 2, and an output path checked before any work."""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from .builder import SceneError

EXIT_USAGE = 2


class ArgumentParser(argparse.ArgumentParser):
    """Reports a usage mistake in one line (the full usage is one `--help` away), exit status 2."""

    def error(self, message: str):
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def check_writable(path: Path, create_parent: bool = False) -> None:
    """Refuse an output path that cannot be written, before any work: a long run must not fail at the end."""
    if path.is_dir():
        raise SceneError(f"{path}: is a directory; give a file name")
    target = Path(os.path.realpath(path))  # a symbolic link is written through: its target's folder counts
    if target.exists() and not target.is_file():  # a device or FIFO (/dev/null) is written into, not replaced
        if not os.access(target, os.W_OK):
            raise SceneError(f"{path}: cannot write into it (permission denied)")
        return
    parent = target.parent if path.is_symlink() else path.parent
    if create_parent:
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise SceneError(f"{path}: cannot create the directory {parent} ({err.strerror or err})") from None
    if not parent.is_dir():
        raise SceneError(f"{path}: the directory {parent} does not exist")
    try:  # os.access is not enough: root passes it, and some file systems refuse new files anyway
        with tempfile.TemporaryFile(dir=parent):
            pass
    except OSError as err:
        raise SceneError(f"{path}: cannot write in {parent} ({err.strerror or err})") from None
