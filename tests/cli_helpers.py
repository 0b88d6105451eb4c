"""Running the command line in-process: its exit status and stderr lines, and the one-line error check."""

from __future__ import annotations

from warpimpulse.cli import main


def run(argv: list[str], capsys) -> tuple[int, list[str]]:
    """Exit status and the lines on stderr."""
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse exits by itself
        code = exc.code
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return code, [line for line in err.splitlines() if line.strip()]


def assert_one_line_error(argv: list[str], message: str, capsys, code: int = 2) -> None:
    got, lines = run(argv, capsys)
    assert got == code, (got, lines)
    assert len(lines) == 1 and "error: " in lines[0] and message in lines[0], lines
