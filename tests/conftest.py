"""Shared test fixtures: CPU Warp, seeded RNG, a small rig (procedural meshes live in ``helpers.py``)."""

from __future__ import annotations

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
# Every test computes its rigs' fields (and never reads or fills the user's cache folder); the cache's own tests
# point it at a temporary folder.
os.environ["WARPFACE_CACHE"] = "off"

import numpy as np
import pytest
import warp as wp
from hypothesis import settings

# Property tests draw the same examples on every run (a fixed seed), so a suite that passed once passes
# again: one randomly drawn, very slow example once held a whole run. HYPOTHESIS_PROFILE=explore draws anew.
settings.register_profile("warpface", derandomize=True, deadline=None, print_blob=True)
settings.register_profile("explore", deadline=None, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "warpface"))

wp.config.quiet = True
wp.config.log_level = wp.LOG_WARNING
wp.init()

from helpers import small_face_rig  # noqa: E402  (after Warp is configured)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def cpu():
    return wp.get_device("cpu")


@pytest.fixture
def small_rig():
    """A fresh :func:`small_face_rig`."""
    return small_face_rig()


@pytest.fixture(scope="session")
def lee_perry_smith():
    """The Lee Perry-Smith scan (closed mouth, eyes closed over by skin) and the 68 landmarks found on it:
    ``(mesh, landmark indices, mm per mesh unit)``; skipped without ``../shared/data``."""
    import warpface as wf
    from warpface.data import shared_data_path
    from warpface.rigging import find_landmarks

    path = shared_data_path("lee_perry_smith", "LeePerrySmith.obj")
    if path is None:
        pytest.skip("Lee Perry-Smith scan not found in ../shared/data (set WARPFACE_SHARED_DATA)")
    mesh = wf.FaceMesh.from_obj(path)
    found = find_landmarks(mesh.points, mesh.triangles, label="Lee Perry-Smith")
    return mesh, found.indices, 1000.0 * found.meters_per_unit


@pytest.fixture(scope="session")
def classic_rig_stage(tmp_path_factory):
    """A rig stage of the built-in face with the classic anatomy (23 muscles, no jaw): its expression model builds
    in a fraction of a second where the full rig's takes seconds, for end-to-end runs whose point is not the
    anatomy. It has no frame rate of its own, so a take keeps its driver's rate, as on the built-in rig."""
    from pxr import Sdf

    from warpface import usd
    from warpface.assets import default_rig

    path = tmp_path_factory.mktemp("classic_rig") / "classic.usda"
    usd.write_rig(path, default_rig(device="cpu", anatomy="classic"))
    layer = Sdf.Layer.FindOrOpen(str(path))
    layer.ClearTimeCodesPerSecond()
    layer.ClearFramesPerSecond()
    layer.Save()
    return path
