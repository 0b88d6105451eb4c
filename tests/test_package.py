"""The wheel maps kernels/ to warpimpulse.kernels and never installs a top-level `kernels` package;
`import warpimpulse` gives the submodules a newcomer reaches for without importing them (or pxr) up front."""

import os
import site
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.schedule_free


def test_wheel_installs_and_imports(tmp_path):
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path), str(ROOT)],
        check=True,
    )
    wheel = next(tmp_path.glob("warpimpulse-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    assert "warpimpulse/kernels/cholesky.py" in names
    assert {"warpimpulse/bench/harness.py", "warpimpulse/bench/peers/mujoco.py"} <= set(names)
    assert "warpimpulse/usd/writer.py" in names
    assert not any(n.startswith("kernels/") for n in names)

    env_dir = tmp_path / "venv"
    venv.EnvBuilder(system_site_packages=True, with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "-q", "--no-deps", str(wheel)], check=True
    )
    code = (
        "import warpimpulse, warpimpulse.kernels.cholesky as c, importlib.util as u;"
        f"assert warpimpulse.__file__.startswith({str(env_dir)!r}), warpimpulse.__file__;"
        "assert u.find_spec('kernels') is None; print('ok')"
    )
    # Dependencies come from this interpreter's site-packages (as a plain path, so its editable install of
    # warpimpulse is not seen); warpimpulse itself must come from the wheel.
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(site.getsitepackages())}
    out = subprocess.run([str(python), "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


def test_submodules_without_a_second_import():
    code = (
        "import sys, warpimpulse as wi\n"
        "assert 'pxr' not in sys.modules and 'warpimpulse.usd' not in sys.modules, 'imported too early'\n"
        "assert len(wi.scenes.chain(2).bodies) == 2\n"
        "assert callable(wi.usd.record) and callable(wi.run.record_frames)\n"
        "assert 'pxr' not in sys.modules, 'wi.usd imported pxr before it was used'\n"
        "assert {'scenes', 'usd', 'run'} <= set(dir(wi))\n"
        "try:\n    wi.nonexistent\nexcept AttributeError as e:\n    print('ok', e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("ok module 'warpimpulse' has no attribute 'nonexistent'"), out.stdout
