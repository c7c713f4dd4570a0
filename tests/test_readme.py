"""The README's library snippet runs as written, from the repository root; its lists follow the code's."""
from __future__ import annotations

import os
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_readme_snippet_runs_as_written(monkeypatch):
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks, "the README has no python snippet"
    monkeypatch.chdir(ROOT)  # its paths (reglib/examples/...) are relative to the clone
    namespace: dict = {}
    exec(compile(blocks[0], "README.md", "exec"), namespace)  # noqa: S102 - our own README
    res, m, r = namespace["res"], namespace["m"], namespace["r"]
    # what the snippet says of its values holds
    assert res.converged and res.inliers[100:].mean() > 0.95 and res.inliers[:100].mean() < 0.1
    assert namespace["same"].transform.to_dict() == res.transform.to_dict()
    assert namespace["flow"].shape == (*m.shape_a, 2) and namespace["warped"].shape[:2] == m.shape_a
    assert r.registered.shape == namespace["model"].shape and r.matrix is None
    model, rigid = namespace["model"], namespace["rigid"]
    assert rigid.matrix.shape == (3, 3)
    assert abs(model @ rigid.matrix[:2, :2].T + rigid.matrix[:2, 2] - rigid.registered).max() < 1e-9
    assert os.path.basename(namespace["a"]) == "cat_a.jpg"


def test_the_readme_lists_every_flow_format_where_it_lists_them():
    from reglib.outputs import FLOW_FORMATS

    text = (ROOT / "README.md").read_text()
    assert f"--flow-format {'|'.join(FLOW_FORMATS)}" in text
    row = next(line for line in text.splitlines() if line.startswith("| `POST /v1/flow`"))
    assert all(fmt in row for fmt in (*FLOW_FORMATS, "png"))


def test_data_md_names_every_data_folder_the_benchmarks_read_with_its_source():
    """Every first-level folder under ``--data`` that a benchmark script names has its section in
    benchmarks/DATA.md, with a public repository to fetch it from."""
    read = set()
    for script in (ROOT / "benchmarks").glob("*.py"):
        text = script.read_text()
        if '"--data"' in text:  # (the scripts without --data make their own folders)
            read |= set(re.findall(r'(?:data|root|args\.data\)?)\s*/\s*"([a-z0-9_]+)"', text))
    assert {"chui_rangarajan", "cpd_fish", "image_pairs", "multimodal", "pointsets3d"} <= read
    sections = re.split(r"^## ", (ROOT / "benchmarks" / "DATA.md").read_text(), flags=re.M)
    for folder in sorted(read):
        section = next((s for s in sections if s.startswith(f"`{folder}/`")), None)
        assert section is not None, f"benchmarks/DATA.md has no section for {folder}/"
        assert "https://github.com/" in section and "licence" in section.lower(), folder
