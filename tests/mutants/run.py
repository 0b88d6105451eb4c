"""`make mutants`: break the engine on purpose, one curated mutation at a time, and see whether the tests notice.

    python tests/mutants/run.py [--only NAME ...] [--timeout SECONDS] [--list] [--keep]

Each mutation in tests/mutants/mutations.toml replaces one exact snippet of source (it must occur exactly once,
or the run stops before doing anything, naming the stale entry) in a temporary copy of the repository, then
runs the fast suite there (`pytest -x -q -m "not slow"`, the physics reference tests first so a broken engine
fails early) with that copy first on the import path. A mutation is killed when the suite fails, survives
when it passes. The entries marked `control = true` change dead text only: they must survive, or the run
itself is broken (a kill would not mean what it says). The report lists every mutation, the test that
killed it, the survivors and the kill rate; the exit status is 1 when a mutation survived or a control was
killed. Not part of `make test` (minutes per mutation); not collected by pytest (no test_ prefix).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    sys.exit("make mutants needs Python 3.11 or later (tomllib)")

ROOT = Path(__file__).resolve().parents[2]
LIST = Path(__file__).with_name("mutations.toml")
# Run first, so that a broken engine fails within seconds; the rest of the suite follows in a second run.
FIRST = [
    "tests/test_loads.py",
    "tests/test_rotation3d.py",
    "tests/test_raw_state.py",
    "tests/test_reference_trajectory.py",
    "tests/test_constraint_hold.py",
]
# test_package builds a wheel of the copy and installs it into a fresh environment, which the PYTHONPATH that
# points at the copy confuses (the wheel's module is not found); no mutation touches packaging.
SKIP = ["tests/test_package.py"]
OPTIONS = ["-x", "-q", "-m", "not slow", "-p", "no:cacheprovider"]
STAGES = [[*OPTIONS, *FIRST], [*OPTIONS, *(f"--ignore={f}" for f in FIRST + SKIP), "tests"]]


@dataclass
class Mutation:
    name: str
    file: str
    find: str
    replace: str
    breaks: str
    control: bool = False


def load(path: Path = LIST) -> list[Mutation]:
    """The mutations, each checked against the source: its file exists and its snippet occurs exactly once."""
    with open(path, "rb") as f:
        entries = tomllib.load(f)["mutation"]
    out, problems, names = [], [], set()
    for entry in entries:
        m = Mutation(**entry)
        if m.name in names:
            problems.append(f"{m.name}: a mutation of that name is listed twice")
        names.add(m.name)
        source = ROOT / m.file
        if not source.is_file():
            problems.append(f"{m.name}: {m.file} does not exist")
            continue
        count = source.read_text().count(m.find)
        if count != 1:
            problems.append(f"{m.name}: its snippet occurs {count} times in {m.file} (must be exactly once):\n{m.find}")
        if m.find == m.replace:
            problems.append(f"{m.name}: the replacement equals the snippet")
        out.append(m)
    if problems:
        sys.exit(f"{path.relative_to(ROOT)} is stale; fix these entries:\n" + "\n".join(problems))
    return out


def copy_repository(dest: Path) -> None:
    """The working tree as git sees it (tracked and untracked, not ignored files), and the import layout the
    editable install maps (warpimpulse.kernels is kernels/), so the copy imports nothing from ROOT."""
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=ROOT, check=True,
                           capture_output=True).stdout.decode().split("\0")  # fmt: skip
    for name in filter(None, files):
        src = ROOT / name
        if src.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)
    (dest / "warpimpulse" / "kernels").symlink_to(Path("..") / "kernels", target_is_directory=True)


def environment(copy: Path) -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=str(copy), PYTHONDONTWRITEBYTECODE="1")
    env.pop("PYTEST_ADDOPTS", None)
    return env


def check_imports(copy: Path) -> None:
    """Fail loudly when the copy's Python would import the package from anywhere but the copy."""
    code = "import warpimpulse, warpimpulse.kernels.rigid as r; print(warpimpulse.__file__); print(r.__file__)"
    out = subprocess.run([sys.executable, "-c", code], cwd=copy, env=environment(copy), capture_output=True,
                         text=True, check=True).stdout.split()  # fmt: skip
    for path in out:
        if not Path(path).resolve().is_relative_to(copy.resolve()):
            sys.exit(f"the copy imports {path}, outside {copy}: mutants would run against the unmutated source")


def run_suite(copy: Path, timeout: float) -> tuple[str, str, float]:
    """(status, first failing test or reason, seconds): status killed, survived or timeout. The suite is the
    fast one, in two runs (FIRST, then the rest) that stop at the first failure."""
    start = time.perf_counter()
    for stage in STAGES:
        left = timeout - (time.perf_counter() - start)
        try:
            proc = subprocess.run([sys.executable, "-m", "pytest", *stage], cwd=copy, env=environment(copy),
                                  capture_output=True, text=True, timeout=max(left, 1.0))  # fmt: skip
        except subprocess.TimeoutExpired:
            return "timeout", f"the suite ran past {timeout:.0f} s", time.perf_counter() - start
        if proc.returncode != 0:
            failed = re.findall(r"^(?:FAILED|ERROR) (\S+)", proc.stdout, flags=re.M)
            tail = (proc.stdout + proc.stderr).strip()[-300:]
            why = failed[0] if failed else f"pytest exit {proc.returncode}: {tail}"
            return "killed", why, time.perf_counter() - start
    return "survived", "", time.perf_counter() - start


def run_matrix(copy: Path, files: list[str], timeout: float) -> tuple[str, str, float]:
    """Which tests of `files` fail (all of them, not the first): the map from mutation to the tests that see it."""
    start = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-m", "pytest", *OPTIONS[1:], *files], cwd=copy,
                              env=environment(copy), capture_output=True, text=True, timeout=timeout)  # fmt: skip
    except subprocess.TimeoutExpired:
        return "timeout", f"ran past {timeout:.0f} s", time.perf_counter() - start
    failed = re.findall(r"^(?:FAILED|ERROR) (\S+)", proc.stdout, flags=re.M)
    status = "survived" if proc.returncode == 0 else "killed"
    return status, " ".join(f.split("/")[-1] for f in failed), time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", metavar="NAME", help="run these mutations only")
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds per mutation (default 900)")
    parser.add_argument("--list", action="store_true", help="check and list the mutations, run nothing")
    parser.add_argument("--keep", action="store_true", help="keep the temporary copy (its path is printed)")
    parser.add_argument(
        "--matrix", nargs="+", metavar="TEST_FILE",
        help="instead of the suite, run these test files to the end and list every failing test",
    )  # fmt: skip
    args = parser.parse_args(argv)
    mutations = load()
    if args.only:
        unknown = set(args.only) - {m.name for m in mutations}
        if unknown:
            sys.exit(f"unknown mutations: {sorted(unknown)}")
        mutations = [m for m in mutations if m.name in args.only]
    if args.list:
        for m in mutations:
            print(f"{m.name:32} {m.file:28} {'(control) ' if m.control else ''}{m.breaks}")
        return 0

    tmp = Path(tempfile.mkdtemp(prefix="warpimpulse-mutants-"))
    copy = tmp / "repo"
    copy.mkdir()
    copy_repository(copy)
    check_imports(copy)
    print(f"{len(mutations)} mutations, each against the fast suite in {copy}", flush=True)
    results = []
    try:
        for k, m in enumerate(mutations, 1):
            target = copy / m.file
            original = target.read_text()
            target.write_text(original.replace(m.find, m.replace, 1))
            try:
                if args.matrix:
                    status, why, seconds = run_matrix(copy, args.matrix, args.timeout)
                else:
                    status, why, seconds = run_suite(copy, args.timeout)
            finally:
                target.write_text(original)
            results.append((m, status, why))
            label = "survived (control, as it must)" if m.control and status == "survived" else status
            print(f"[{k}/{len(mutations)}] {m.name}: {label} in {seconds:.0f} s  {why}", flush=True)
    finally:
        if args.keep:
            print(f"copy kept at {copy}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)

    real = [(m, s, w) for m, s, w in results if not m.control]
    survivors = [m for m, s, _ in real if s == "survived"]
    broken_controls = [m for m, s, _ in results if m.control and s != "survived"]
    killed = len(real) - len(survivors)
    print(f"\nkilled {killed} of {len(real)} mutations ({100.0 * killed / max(len(real), 1):.0f}%)")
    for m in survivors:
        print(f"SURVIVED {m.name} ({m.file}): {m.breaks}")
    for m in broken_controls:
        print(f"CONTROL KILLED {m.name}: dead text changed and the suite failed; the runner or the suite is flaky")
    return 1 if survivors or broken_controls else 0


if __name__ == "__main__":
    raise SystemExit(main())
