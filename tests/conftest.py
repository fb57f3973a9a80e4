"""Shared test fixtures: CPU Warp, seeded RNG, a small rig (procedural meshes live in ``helpers.py``)."""

from __future__ import annotations

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")

import numpy as np
import pytest
import warp as wp

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
