"""A plain ``pip install`` of the built wheel, in a fresh venv, renders the demo pictures.

pyrender pins PyOpenGL 3.1.0, which cannot use OSMesa; warpface must pick EGL by itself. This test
builds the wheel, installs it with nothing but ``pip install <wheel>`` (dependencies from PyPI,
through pip's own download cache) and runs ``warpface demo``. It takes a few minutes the first
time on a machine and ~2 minutes with a warm pip cache; it is skipped when PyPI cannot be reached.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _pypi_reachable() -> bool:
    try:
        socket.create_connection(("pypi.org", 443), timeout=5).close()
    except OSError:
        return False
    return True


@pytest.mark.wheel
@pytest.mark.slow
@pytest.mark.skipif(not _pypi_reachable(), reason="PyPI is not reachable: cannot install the wheel's dependencies")
def test_plain_pip_install_of_the_wheel_renders_the_demo(tmp_path):
    import cv2

    environment = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYOPENGL_PLATFORM", "VIRTUAL_ENV")}
    run = lambda *args, **kw: subprocess.run(args, capture_output=True, text=True, env=environment, **kw)  # noqa: E731
    built = run(
        sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path / "dist"), str(ROOT), timeout=600
    )
    assert built.returncode == 0, built.stderr[-2000:]
    wheel = next((tmp_path / "dist").glob("warpface-*.whl"))
    venv = tmp_path / "venv"
    base_python = getattr(sys, "_base_executable", sys.executable)
    assert run(base_python, "-m", "venv", str(venv), timeout=300).returncode == 0
    python = venv / "bin" / "python"
    installed = run(str(python), "-m", "pip", "install", "-q", str(wheel), timeout=1200)
    assert installed.returncode == 0, installed.stderr[-2000:]
    opengl = run(str(python), "-c", "import OpenGL; print(OpenGL.__version__)", timeout=120)
    print("PyOpenGL in the fresh venv:", opengl.stdout.strip())
    out = tmp_path / "demo"
    demo = run(
        str(venv / "bin" / "warpface"),
        "--device",
        "cpu",
        "--quiet",
        "demo",
        "--out",
        str(out),
        "--seconds",
        "0.2",
        "--no-video",
        cwd=str(tmp_path),
        timeout=900,
    )
    assert demo.returncode == 0, demo.stderr[-2000:]
    assert demo.stderr == "", demo.stderr  # no Warp banner, no GL warnings
    image = cv2.imread(str(out / "expressions.png"))
    assert image is not None and image.shape[0] > 100
    assert np.asarray(image, dtype=float).std() > 10  # faces, not an empty frame
