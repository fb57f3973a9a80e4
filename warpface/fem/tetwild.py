"""fTetWild (pytetwild) in a child process, with validation of its tets and retries.

fTetWild writes debug files into the working directory and aborts the whole process on some
inputs, so it runs in a child process in a scratch folder. It is not deterministic, not even with
one thread (measured: 1,796 and 1,809 nodes from two single-thread runs on the same shell) and
pytetwild offers no seed: node counts and element quality vary a little from run to run.
"""

from __future__ import annotations

import time

import numpy as np

from .tetmesh import TetMesh, tet_signed_volumes

__all__ = ["TETWILD_ATTEMPTS", "tetrahedralize", "tetrahedralize_validated", "validated_tets"]

_TETWILD_SCRIPT = """
import json, sys
import numpy as np
import pytetwild
data = np.load("shell.npz")
nodes, tets = pytetwild.tetrahedralize(data["points"], data["triangles"], **json.loads(sys.argv[1]))
np.savez("tets.npz", nodes=nodes, tets=tets)
"""


TETWILD_ATTEMPTS = 3
"""fTetWild runs before :func:`mesh_tissue` gives up on tets that fail validation.

fTetWild is not deterministic: about one run in 40 on a small test patch leaves a few zero-volume
(degenerate) tets, and a second run of the same shell does not."""


def tetrahedralize_validated(shell, *, on_wait=None, **options) -> tuple[TetMesh, int]:
    """fTetWild on the shell until its tets pass :func:`validated_tets`; returns the mesh and the runs taken.

    ``on_wait(seconds)``, when given, is called about twice a second while fTetWild runs, with the
    seconds since the first run started."""
    start = time.perf_counter()
    tick = None if on_wait is None else (lambda: on_wait(time.perf_counter() - start))
    for run in range(1, TETWILD_ATTEMPTS + 1):
        nodes, tets = tetrahedralize(shell.points, shell.triangles, on_wait=tick, **options)
        try:
            return validated_tets(
                np.asarray(nodes, dtype=np.float64), np.asarray(tets, dtype=np.int64), shell.volume
            ), run
        except ValueError as exc:
            if run == TETWILD_ATTEMPTS:
                raise ValueError(f"{exc} (after {TETWILD_ATTEMPTS} fTetWild runs)") from None
    raise AssertionError("unreachable")


def tetrahedralize(points: np.ndarray, triangles: np.ndarray, *, timeout: float | None, on_wait=None, **options):
    """fTetWild (pytetwild) in a child process, in a scratch folder.

    fTetWild writes debug files (``__tracked_surface.stl`` ...) into the working directory and
    aborts the whole process on some inputs; a child process in a temporary folder keeps both away
    from the caller, and turns a crash or a hang into an exception. ``options`` go to
    ``pytetwild.tetrahedralize``; ``on_wait()`` is called about twice a second while it runs.
    Returns ``(nodes, tets)``.
    """
    import importlib.util
    import json
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    if importlib.util.find_spec("pytetwild") is None:
        raise RuntimeError("tetrahedralising needs pytetwild (pip install pytetwild)")
    with tempfile.TemporaryDirectory(prefix="warpface-tetwild-") as scratch:
        folder = Path(scratch)
        np.savez(
            folder / "shell.npz",
            points=np.ascontiguousarray(points, dtype=np.float64),
            triangles=np.ascontiguousarray(triangles, dtype=np.int32),
        )
        child = subprocess.Popen(
            [sys.executable, "-c", _TETWILD_SCRIPT, json.dumps(options)],
            cwd=folder,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        deadline = None if timeout is None else time.monotonic() + float(timeout)
        try:
            while True:
                try:
                    stdout, stderr = child.communicate(timeout=0.5)
                    break
                except subprocess.TimeoutExpired:
                    if deadline is not None and time.monotonic() > deadline:
                        raise RuntimeError(f"fTetWild did not finish within {timeout} s") from None
                    if on_wait is not None:
                        on_wait()
        finally:
            if child.poll() is None:  # timeout, Ctrl-C or a failing callback: never leave fTetWild running
                child.kill()
                child.communicate()
        if child.returncode != 0 or not (folder / "tets.npz").is_file():
            tail = (stderr or stdout).strip().splitlines()[-5:]
            raise RuntimeError(f"fTetWild failed (exit status {child.returncode}): " + " | ".join(tail))
        result = np.load(folder / "tets.npz")
        return result["nodes"], result["tets"]


def validated_tets(
    nodes: np.ndarray, tets: np.ndarray, shell_volume: float, *, volume_tolerance: float = 0.05
) -> TetMesh:
    """Orient fTetWild's tets positively and reject inverted, degenerate or missing ones."""
    if len(tets) == 0:
        raise ValueError("fTetWild returned no tets: the shell is too thin for the edge length, or not closed")
    volumes = tet_signed_volumes(nodes, tets)
    negative = volumes < 0.0
    # fTetWild orients all its tets one way; which way depends on its ordering convention
    if negative.sum() * 2 > len(tets):
        tets = tets[:, [0, 1, 3, 2]]
        volumes = -volumes
        negative = volumes < 0.0
    if negative.any():
        t = int(np.flatnonzero(negative)[0])
        raise ValueError(
            f"fTetWild returned {int(negative.sum())} inverted tets (opposite orientation to the rest); "
            f"first: tet {t} {tets[t].tolist()} with signed volume {volumes[t]:.3e} m^3"
        )
    # drops orphan nodes; degenerate tets raise ValueError from TetMesh naming the tet
    try:
        mesh, _ = TetMesh.repaired(nodes, tets)
    except ValueError as exc:
        raise ValueError(f"fTetWild result rejected: {exc}") from None
    error = abs(mesh.total_volume - shell_volume) / shell_volume
    if error > volume_tolerance:
        raise ValueError(
            f"fTetWild's tets fill {mesh.total_volume:.4e} m^3 but the shell encloses {shell_volume:.4e} m^3 "
            f"({100 * error:.1f} % off): the shell was not filled correctly"
        )
    return mesh
