"""Every bad input listed for the expression model gives a ValueError that names the item."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import grid_surface

import warpface as wf

PLANAR = wf.PlanarProjection([0, 0, 0], [1, 0, 0], [0, 1, 0])
CURVE = [[0, 0], [1, 0], [2, 0], [3, 0]]


@pytest.mark.parametrize(
    "build, message",
    [
        (lambda: wf.LinearMuscle("zyg", [0, 0, np.inf], [1, 0, 0], 30, 1, 2), "zyg.*attachment.*non-finite"),
        (lambda: wf.LinearMuscle("zyg", [0, 0, 0], [1, 0, 0], 30, 2, 2), "zyg.*falloff_start"),
        (lambda: wf.LinearMuscle("zyg", [0, 0, 0], [1, 0, 0], 30, 3, 2), "zyg.*falloff_start"),
        (lambda: wf.LinearMuscle("zyg", [0, 0, 0], [1, 0, 0], 30, -1, 2), "zyg.*falloff_start"),
        (lambda: wf.LinearMuscle("zyg", [0, 0, 0], [1, 0, 0], 0, 1, 2), "zyg.*zone_angle"),
        (lambda: wf.LinearMuscle("zyg", [0, 0, 0], [1, 0, 0], 180, 1, 2), "zyg.*zone_angle"),
        (lambda: wf.LinearMuscle("zyg", [0, 0, 0], [1, 0, 0], np.nan, 1, 2), "zyg.*zone_angle"),
        (lambda: wf.LinearMuscle("zyg", [1, 2, 3], [1, 2, 3], 30, 1, 2), "zyg.*zero-length"),
        (lambda: wf.SphincterMuscle("oris", [0, 0, 0], [1, 0, 0], [0, 1, 0], (1, 0)), "oris.*semi_axes"),
        (lambda: wf.SphincterMuscle("oris", [0, 0, 0], [1, 0, 0], [0, 1, 0], (-1, 1)), "oris.*semi_axes"),
        (lambda: wf.SphincterMuscle("oris", [0, 0, 0], [0, 0, 0], [0, 1, 0], (1, 1)), "oris.*axis_x.*zero-length"),
        (lambda: wf.SphincterMuscle("oris", [0, 0, 0], [1, 0, 0], [2, 0, 0], (1, 1)), "oris.*parallel"),
        (lambda: wf.Wrinkle("brow", CURVE[:3], PLANAR, 1, 1), r"brow.*control_points.*\(4, 2\)"),
        (lambda: wf.Wrinkle("brow", [[0, 0, 0]] * 4, PLANAR, 1, 1), r"brow.*control_points.*\(4, 2\)"),
        (lambda: wf.Wrinkle("brow", CURVE, PLANAR, 1, 0), "brow.*width"),
        (lambda: wf.Wrinkle("brow", CURVE, PLANAR, 1, -2), "brow.*width"),
        (lambda: wf.Wrinkle("brow", CURVE, PLANAR, np.nan, 1), "brow.*depth"),
        (lambda: wf.Wrinkle("brow", CURVE, PLANAR, 1, 1, kr=1.5), "brow.*kr"),
        (lambda: wf.PlanarProjection([0, 0, 0], [1, 0, 0], [3, 0, 0]), "parallel"),
        (lambda: wf.CylindricalProjection([0, 0, 0], [0, 1, 0], [0, 2, 0], 1), "reference"),
        (lambda: wf.CylindricalProjection([0, 0, 0], [0, 1, 0], [0, 0, 1], 0), "radius"),
    ],
)
def test_bad_parameters(build, message):
    with pytest.raises(ValueError, match=message):
        build()


@pytest.fixture
def small_model():
    points, triangles = grid_surface(6)
    muscle = wf.LinearMuscle("zyg", [0, -2, -0.5], [0, 0, 0], 40, 0.5, 2.5)
    return wf.FaceMesh(points, triangles), muscle


def test_unknown_muscle_name(small_model):
    mesh, muscle = small_model
    model = wf.ExpressionModel(mesh, [muscle], [], 0.1, device="cpu")
    with pytest.raises(ValueError, match="unknown muscle name 'zygo'"):
        model.evaluate({"zygo": 1.0})
    with pytest.raises(ValueError, match="zyg.*non-finite"):
        model.evaluate({"zyg": np.nan})
    with pytest.raises(ValueError, match="expected 1 values"):
        model.evaluate([1.0, 2.0])
    with pytest.raises(ValueError, match=r"shape \(frames, 1\)"):
        model.evaluate(np.zeros((3, 2)))


@pytest.mark.parametrize(
    "thickness, message", [(np.ones(5), "one value per vertex"), (-1.0, "negative"), (np.nan, "non-finite")]
)
def test_bad_thickness(small_model, thickness, message):
    mesh, muscle = small_model
    with pytest.raises(ValueError, match=f"thickness.*{message}"):
        wf.ExpressionModel(mesh, [muscle], [], thickness, device="cpu")


def test_duplicate_names(small_model):
    mesh, muscle = small_model
    with pytest.raises(ValueError, match="duplicate muscle name 'zyg'"):
        wf.ExpressionModel(mesh, [muscle, muscle], [], 0.1, device="cpu")


def test_extreme_compression_stays_finite(small_model):
    mesh, _ = small_model
    crush = wf.SphincterMuscle("crush", [0, 0, 0], [1, 0, 0], [0, 1, 0], (5.0, 5.0))
    model = wf.ExpressionModel(mesh, [crush], [wf.Wrinkle("w", CURVE, PLANAR, 0.1, 0.2)], 0.1, device="cpu")
    for k in (1.0, 1.25, 50.0):  # K = 1.25 collapses the centre exactly, larger values invert it
        assert np.all(np.isfinite(model.evaluate({"crush": k})))
