"""Generated blocks of the README and docs: tables and figures written from a benchmark's JSON between markers.

A block is the text between `<!-- NAME:begin -->` and `<!-- NAME:end -->` of a Markdown file; only it is
replaced, so the prose around it stays the author's and every figure in it comes from the JSON."""

from __future__ import annotations

from pathlib import Path

from ..files import write_atomically


def markers(name: str) -> tuple[str, str]:
    """The begin and end markers of block `name`."""
    return f"<!-- {name}:begin -->", f"<!-- {name}:end -->"


def write_block(path: str | Path, name: str, text: str) -> None:
    """Replace the text of block `name` in `path` with `text` (written atomically). A file without both markers
    is a ValueError naming the file and the block: a block is placed by hand, once, where the prose wants it."""
    path = Path(path)
    begin, end = markers(name)
    old = path.read_text()
    start, stop = old.find(begin), old.find(end)
    if start < 0 or stop < start:
        raise ValueError(f"{path} has no {begin} ... {end} block to regenerate")
    new = old[: start + len(begin)] + "\n" + text.strip("\n") + "\n" + old[stop:]
    write_atomically(path, lambda tmp: Path(tmp).write_text(new), path.suffix)
