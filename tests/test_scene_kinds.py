

def test_the_readme_block_is_the_committed_json_written_up(kinds) -> None:
    """README.md's scene-kinds block is generated from benchmarks/results/scene_kinds.json, never typed."""
    import json

    results = json.loads((ROOT / "benchmarks/results/scene_kinds.json").read_text())
    text = (ROOT / "README.md").read_text()
    block = text[text.index(kinds.BEGIN) + len(kinds.BEGIN) : text.index(kinds.END)]
    assert block.strip() == kinds.readme_block(results).strip()
