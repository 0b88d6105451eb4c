"""benchmarks/scene_kinds.py's models: each MJCF file is what its builder writes, loads in both engines as the
same bodies, and both engines move it alike over a few small steps. Nothing here times anything."""

from pathlib import Path

import numpy as np
import pytest
from scripts import benchmark

from warpimpulse.bench.blocks import markers

pytest.importorskip("mujoco")

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def kinds():
    yield from benchmark("scene_kinds")


def test_the_model_files_are_what_their_builders_write(kinds, tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(kinds, "MODELS", tmp_path)
    for path in kinds.write_models():
        assert path.read_text() == (ROOT / "benchmarks/models" / path.name).read_text(), path.name


@pytest.mark.parametrize(
    "name", ["double_pendulum_3d", "arm7", "chain30", "humanoid", "tree127", "reacher", "ant", "dm_humanoid"]
)
def test_a_scene_loads_in_both_engines_and_moves_alike(kinds, name) -> None:
    kind = next(k for k in kinds.KINDS if k.name == name)
    scene = kinds.load(kind)
    assert scene.mismatch < 1e-9
    m, ids = scene.mscene.model, scene.mscene.body_ids
    jointed = [b for b in range(1, m.nbody) if m.body_weldid[b] == b]  # the rest are welded into these
    assert sorted(ids[ids >= 0]) == jointed  # ids < 0: light bodies between two joints of one MuJoCo body
    rate, steps = 1000, 20
    ours, theirs = kinds.OursRun(scene, rate, 4, 1e-9), kinds.MujocoRun(scene, rate, "RK4")
    start = None
    for run in (ours, theirs):
        run.start()
        start = run.points() if start is None else start
        np.testing.assert_allclose(run.points(), start, atol=1e-12)  # the same tracked points at t = 0
        run.one_call(steps)
    moved = np.linalg.norm(theirs.points() - start, axis=1).max()
    gap = np.linalg.norm(ours.points() - theirs.points(), axis=1).max()
    assert moved > 1e-4 and gap < 1e-3 * moved, (moved, gap)


def test_the_readme_blocks_are_the_committed_json_written_up(kinds) -> None:
    """docs/results.md's scene-kinds block and README.md's summary of it are generated from
    benchmarks/results/scene_kinds.json, never typed."""
    import json

    results = json.loads((ROOT / "benchmarks/results/scene_kinds.json").read_text())
    for path, name, block in (
        (ROOT / "docs/results.md", kinds.BLOCK, kinds.readme_block(results)),
        (ROOT / "README.md", kinds.SUMMARY_BLOCK, kinds.summary_block(results)),
    ):
        begin, end = markers(name)
        text = path.read_text()
        assert text[text.index(begin) + len(begin) : text.index(end)].strip() == block.strip(), path
