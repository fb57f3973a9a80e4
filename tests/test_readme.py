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


OWN_HEAD = re.search(r"^## Your own head\n.*?^```bash\n(.*?)^```", README.read_text(), flags=re.S | re.M)


@pytest.mark.slow  # rig → animate → preview end to end, ~40 s on the 2-core CI machine
def test_own_head_commands_run_on_a_head_in_centimetres(tmp_path, monkeypatch, capsys):
    """The README's three commands for one's own head, as written (comments dropped), on the built-in face
    exported in centimetres and a 1.3 s Live Link take."""
    import shlex

    import numpy as np

    from warpface.assets import default_face
    from warpface.cli import main
    from warpface.drivers import Curves, write_live_link

    assert OWN_HEAD is not None
    commands = [shlex.split(line.partition("#")[0]) for line in OWN_HEAD.group(1).splitlines() if line.strip()]
    assert [c[:2] for c in commands] == [["warpface", "rig"], ["warpface", "animate"], ["warpface", "preview"]]
    monkeypatch.chdir(tmp_path)
    face = default_face()
    Path("my_head.obj").write_text(
        "".join(f"v {x:.5f} {y:.5f} {z:.5f}\n" for x, y, z in 100.0 * face.points)
        + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in face.triangles)
    )
    times = np.arange(40) / 30.0
    write_live_link(Path("take.csv"), Curves(times, ["jawOpen"], 0.5 * np.sin(times)[:, None], fps=30.0))
    for command in commands:
        assert main(["--quiet", "--device", "cpu", *command[1:]]) == 0, command
    assert {p.name for p in Path("my_head").iterdir()} >= {"rig.usda", "rig.png", "anim.usda", "anim_anim.usdc"}
    assert Path("my_head/frame30.png").stat().st_size > 10_000
