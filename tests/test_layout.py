"""The package's layout: no import cycles (imports inside functions included), the simulator never imports the
harness (warpimpulse.bench) except where the CLI dispatches to it, and `warpimpulse bench` without the bench
extra says what to install."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# Source folder -> package name (kernels/ is packaged as warpimpulse.kernels).
PACKAGES = {ROOT / "warpimpulse": "warpimpulse", ROOT / "kernels": "warpimpulse.kernels"}
HARNESS = "warpimpulse.bench"
# The one way into the harness from outside it: the CLI's bench/stress command, imported inside the function.
DISPATCH = ("warpimpulse.cli", "warpimpulse.bench.cli")


def module_files(packages: dict[Path, str]) -> dict[str, Path]:
    """Module name -> file, for every .py under each source folder (a package's __init__ is the package)."""
    modules = {}
    for folder, package in packages.items():
        for path in sorted(folder.rglob("*.py")):
            parts = [package, *path.relative_to(folder).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join(parts)] = path
    return modules


def import_edges(modules: dict[str, Path]) -> dict[tuple[str, str], bool]:
    """(importer, imported) -> True when some import of it runs at module level (False: only inside a function).

    Only imports of modules in `modules` count. `from p import name` is an edge to p.name when that is a
    module, else to p. Parent packages that Python initialises on the way are not edges.
    """
    edges: dict[tuple[str, str], bool] = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]

        def add(target: str, module_level: bool, name=name) -> None:
            if target in modules and target != name:
                edges[(name, target)] = edges.get((name, target), False) or module_level

        def visit(node: ast.AST, module_level: bool, package=package, add=add) -> None:
            for child in ast.iter_child_nodes(node):
                if isinstance(child, ast.Import):
                    for alias in child.names:
                        add(alias.name, module_level)
                elif isinstance(child, ast.ImportFrom):
                    if child.level:
                        base = package.rsplit(".", child.level - 1)[0] if child.level > 1 else package
                        base = f"{base}.{child.module}" if child.module else base
                    else:
                        base = child.module
                    for alias in child.names:
                        add(f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base, module_level)
                inner = module_level and not isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
                visit(child, inner)

        visit(ast.parse(path.read_text(), str(path)), True)
    return edges


def cyclic_groups(edges) -> list[list[str]]:
    """The modules that import each other in a ring, directly or through others: every strongly connected
    group of more than one module, sorted."""
    graph: dict[str, set[str]] = {}
    for a, b in edges:
        graph.setdefault(a, set()).add(b)

    def reachable(start: str) -> set[str]:
        seen, todo = set(), [start]
        while todo:
            for nxt in graph.get(todo.pop(), ()):
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
        return seen

    reach = {node: reachable(node) for node in graph}
    groups = {tuple(sorted(m for m in reach[n] if n in reach.get(m, ()))) for n in graph if n in reach[n]}
    return sorted(list(g) for g in groups)


def in_harness(module: str) -> bool:
    return module == HARNESS or module.startswith(HARNESS + ".")


def test_the_checker_sees_imports_inside_functions(tmp_path):
    """The cycles this layout removed were hidden behind imports inside functions: the checker must see them."""
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from .sub import b\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "b.py").write_text("def f():\n    from .. import a\n    return a\n")
    edges = import_edges(module_files({pkg: "pkg"}))
    assert edges == {("pkg.a", "pkg.sub.b"): True, ("pkg.sub.b", "pkg.a"): False}
    assert cyclic_groups(edges) == [["pkg.a", "pkg.sub.b"]]
    assert cyclic_groups({("pkg.a", "pkg.sub.b"): True}) == []


def test_no_import_cycles():
    modules = module_files(PACKAGES)
    assert {"warpimpulse.cli", "warpimpulse.bench.cli", "warpimpulse.kernels"} <= modules.keys()
    edges = import_edges(modules)
    assert len(edges) > 20
    assert cyclic_groups(edges) == []


def test_the_core_never_imports_the_harness():
    edges = import_edges(module_files(PACKAGES))
    inward = {edge: module_level for edge, module_level in edges.items() if in_harness(edge[1])}
    outside = {edge: module_level for edge, module_level in inward.items() if not in_harness(edge[0])}
    assert outside == {DISPATCH: False}, f"imports of the harness from outside it: {sorted(outside)}"


def test_bench_without_the_extra_says_what_to_install():
    """mujoco made unimportable: one line naming it and the extra, exit status 2, no traceback."""
    code = (
        "import sys; sys.modules['mujoco'] = None\n"
        "from warpimpulse.cli import main\n"
        "raise SystemExit(main(['bench', '--quick', '--no-progress']))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "mujoco" in lines[0] and "pip install 'warpimpulse[bench]'" in lines[0]
    assert proc.stdout == ""


def test_bench_cannot_edit_the_readme(capsys):
    """Only `python -m warpimpulse.bench.report --readme` (make bench) regenerates README.md's block."""
    from warpimpulse.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(["bench", "--readme", "README.md"])
    assert exit_.value.code == 2
    assert "unrecognized arguments: --readme" in capsys.readouterr().err
