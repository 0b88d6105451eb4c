"""The benchmark scripts the tests import by path (benchmarks/ is no package)."""

import importlib.util
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parent.parent


def benchmark(name: str) -> Iterator[ModuleType]:
    """benchmarks/<name>.py imported as module `name`, registered in sys.modules while it is in use (its
    dataclasses look their module up there): a fixture's body, `yield from benchmark(name)`."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    yield module
    del sys.modules[name]
