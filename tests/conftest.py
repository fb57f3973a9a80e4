"""Shared test fixtures: CPU Warp, seeded RNG, small procedural meshes."""

from __future__ import annotations

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")

import numpy as np
import pytest
import warp as wp

wp.config.quiet = True
wp.init()


def grid_surface(n: int = 24, size: float = 2.0, height: float = 0.3, seed: int | None = 0):
    """A wavy height-field patch: points (n·n, 3) float64, triangles (2(n−1)², 3) int.

    With ``seed`` a little random jitter is added so normals and areas are all different.
    """
    xs = np.linspace(-size / 2, size / 2, n)
    x, y = np.meshgrid(xs, xs)
    z = height * np.sin(1.7 * x) * np.cos(1.3 * y)
    points = np.c_[x.ravel(), y.ravel(), z.ravel()]
    if seed is not None:
        rng = np.random.default_rng(seed)
        points += rng.uniform(-0.15, 0.15, points.shape) * (size / n)
    index = np.arange(n * n).reshape(n, n)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    triangles = np.r_[np.c_[a, b, d], np.c_[a, d, c]]
    return points, triangles


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def cpu():
    return wp.get_device("cpu")
