"""Every ```python block of README.md runs as written (on the built-in face, CPU, in a scratch folder)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCKS = re.findall(r"^```python\n(.*?)^```", README.read_text(), flags=re.S | re.M)


def test_the_readme_has_python_snippets():
    assert len(BLOCKS) >= 3


@pytest.mark.parametrize("index", range(len(BLOCKS)), ids=lambda i: f"block{i}")
def test_readme_snippet_runs(index, tmp_path, monkeypatch):
    import warp as wp

    monkeypatch.chdir(tmp_path)  # snippets write files (face.usda, ...) into the working folder
    previous = wp.get_preferred_device()
    wp.set_device("cpu")  # device=None in the snippets means Warp's preferred device: the CPU here
    try:
        exec(compile(BLOCKS[index], f"README.md python block {index}", "exec"), {"__name__": f"readme_{index}"})
    finally:
        wp.set_device(previous)
