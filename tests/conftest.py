"""Shared test fixtures: CPU Warp, seeded RNG, small procedural meshes."""

from __future__ import annotations

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")

import numpy as np
import pytest
import warp as wp

wp.config.quiet = True
wp.config.log_level = wp.LOG_WARNING
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


def small_face_rig(n: int = 16, *, name: str = "Face"):
    """A small procedural :class:`warpface.FaceRig` on a :func:`grid_surface` patch (for USD I/O tests).

    Points are rounded to float32 (USD stores mesh points as point3f) so round trips can be exact.
    Two linear muscles, one sphincter, a planar and a cylindrical wrinkle, a varying thickness,
    four landmarks; one name is not a valid USD identifier.
    """
    from warpface import (CylindricalProjection, FaceMesh, FaceRig, LinearMuscle, PlanarProjection,
                          SphincterMuscle, Wrinkle)

    points, triangles = grid_surface(n, size=0.2, height=0.02, seed=3)
    points = points.astype(np.float32).astype(np.float64)
    muscles = [
        LinearMuscle("zygomaticus major L", attachment=[0.09, 0.08, -0.03], insertion=[0.02, -0.02, 0.01],
                     zone_angle_deg=35.0, falloff_start=0.05, falloff_finish=0.14),
        LinearMuscle("frontalis_R", attachment=[-0.05, 0.12, -0.02], insertion=[-0.04, 0.03, 0.01],
                     zone_angle_deg=28.5, falloff_start=0.04, falloff_finish=0.11),
        SphincterMuscle("orbicularis_oris", center=[0.0, -0.03, 0.0], axis_x=[1.0, 0.0, 0.1], axis_y=[0.0, 1.0, 0.0],
                        semi_axes=(0.05, 0.03)),
    ]
    wrinkles = [
        Wrinkle("forehead_1", control_points=[[-0.06, 0.05], [-0.02, 0.06], [0.02, 0.06], [0.06, 0.05]],
                projection=PlanarProjection([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
                depth=0.002, width=0.004, kr=0.0),
        Wrinkle("crow_L", control_points=[[0.01, -0.02], [0.015, -0.01], [0.02, 0.0], [0.022, 0.015]],
                projection=CylindricalProjection([0.0, 0.0, -0.1], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], 0.1),
                depth=0.0015, width=0.003, kr=0.25),
    ]
    thickness = 0.004 + 0.003 * (points[:, 0] - points[:, 0].min()) / np.ptp(points[:, 0])
    mesh = FaceMesh(points, triangles, name="skin mesh")
    return FaceRig(mesh=mesh, muscles=muscles, wrinkles=wrinkles, thickness=thickness,
                   landmarks=np.array([0, 5, n * n - 1, n + 3]), name=name)


@pytest.fixture
def small_rig():
    """A fresh :func:`small_face_rig`."""
    return small_face_rig()
