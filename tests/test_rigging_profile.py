"""The mid-line profile match (docs/RIG.md §9, step 5a): the plane cut against a height field's exact values, the
dynamic time warping against a known warp of the heights, and a closed loop on the whole ICT head whose nose and mouth
were moved up or down by a known amount (ground truth carried along)."""

from __future__ import annotations

import numpy as np
import pytest

from warpface.data import ict_landmark_indices, shared_data_path
from warpface.mesh import load_obj
from warpface.rigging import find_landmarks, profile
from warpface.rigging.template import template


def _height_field(depth, xs, ys, behind: float | None = None):
    """The surface z = depth(y) + 0.3 x over the grid ``xs`` × ``ys`` (triangulated), and with ``behind`` a second
    sheet that far behind it: (points (V, 3), triangles (T, 3))."""
    grid_x, grid_y = np.meshgrid(xs, ys, indexing="ij")
    sheets, triangles = [], []
    for back in [0.0] + ([behind] if behind is not None else []):
        start = sum(len(sheet) for sheet in sheets)
        sheets.append(
            np.column_stack([grid_x.ravel(), grid_y.ravel(), depth(grid_y.ravel()) + 0.3 * grid_x.ravel() - back])
        )
        index = start + np.arange(grid_x.size).reshape(grid_x.shape)
        a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
        triangles += [np.stack([a, b, c], 1), np.stack([a, c, d], 1)]
    return np.vstack(sheets), np.vstack(triangles)


def test_the_cut_gives_the_frontmost_depth_at_every_height():
    """At the grid's own heights the cut of a height field linear in x is exact; a sheet behind is never taken;
    heights past the surface are NaN."""
    ys = np.linspace(-1.0, 1.0, 41)
    xs = np.array([-0.25, -0.07, 0.11, 0.3])  # no vertex on the plane

    def depth(y):
        return 0.2 * np.sin(3.0 * y) + 0.1 * y**2

    points, triangles = _height_field(depth, xs, ys, behind=0.5)
    heights = np.concatenate([ys[3:-3], [1.5, -1.5]])
    found = profile.midline_profile(points, triangles, heights)
    np.testing.assert_allclose(found[:-2], depth(ys[3:-3]), atol=1e-12)
    assert np.isnan(found[-2:]).all()


def test_the_warping_recovers_a_known_shift_of_the_heights():
    """Skin profile = the template's with its middle moved up by 0.2 (heights stretched below, squeezed above): the
    matched heights are the warp's within two steps where the profile has features."""
    step = profile.STEP
    heights = np.arange(-1.8, 1.4, step)

    def depth(y):
        return 0.3 * np.exp(-(((y + 0.75) / 0.12) ** 2)) - 0.15 * np.exp(-(((y + 1.1) / 0.1) ** 2)) + 0.05 * y

    def warp(y):  # template height → skin height: 0 at the ends, +0.2 in the middle
        return y + np.interp(y, [-1.8, -0.9, -0.2, 1.4], [0.0, 0.2, 0.2, 0.0])

    reach = int(round(profile.REACH / step))
    skin_heights = heights[0] + step * np.arange(-reach, len(heights) + reach)
    skin_depth = depth(np.interp(skin_heights, warp(heights), heights))  # the skin's height → the template's
    matched, cost = profile.profile_heights(depth(heights), skin_depth, reach)
    matched = skin_heights[0] + matched * step
    features = (heights > -1.3) & (heights < -0.6)
    assert np.abs(matched - warp(heights))[features].max() <= 2 * step + 1e-9
    assert np.all(np.diff(matched) >= 0.0) and cost < profile.MATCH_COST


@pytest.fixture(scope="module")
def ict_head():
    path = shared_data_path("ict_facekit", "original", "generic_neutral_mesh.obj")
    if path is None:
        pytest.skip("ICT-FaceKit not found in ../shared/data")
    return load_obj(path)


def test_the_ict_head_s_profile_leaves_the_template_as_it_is(ict_head):
    """The head the template was calibrated on: its profile's shifts are under the least one taken."""
    from warpface.rigging.detect import register

    points, triangles = ict_head
    registration = register(points, triangles, nonrigid=False)
    knots = profile.knot_shifts(template(), registration.skin.points, registration.surface.skin_faces)
    assert knots is not None and np.abs(knots[1]).max() < profile.LEAST_SHIFT
    assert profile.profiled(template(), registration.skin.points, registration.surface.skin_faces) is template()


@pytest.mark.slow
def test_a_head_whose_nose_and_mouth_sit_lower_is_found_where_they_are(ict_head):
    """A broad warp that moves the nose and the mouth ~1.3 cm down against the eyes (benchmarks.rigging.broad_warp,
    seed 728; ground truth carried along): the template as it is leaves its nose 14 mm off; moved to the profile's
    heights first, the nose and the mouth are found within 3 mm."""
    from benchmarks.rigging import broad_warp

    points, triangles = ict_head
    truth = ict_landmark_indices()
    warped = broad_warp(points, 728)
    found = find_landmarks(warped, triangles, label="broad warp 728")
    error = np.linalg.norm(warped[found.indices] - warped[truth], axis=1) * 10.0
    assert error[27:36].mean() < 3.0 and error[48:].mean() < 3.0, (error[27:36].mean(), error[48:].mean())


@pytest.mark.slow
def test_a_shifted_start_that_leaves_no_face_s_layout_is_found_again_from_the_template_as_it_is(ict_head, monkeypatch):
    """Broad warp 731: the profile moves the mouth 1.1 cm down and the fit from there puts the nose base where a
    mouth would be (no face's layout, step 7); the landmarks are found again without the shift, as before it."""
    from benchmarks.rigging import broad_warp
    from warpface.rigging import detect

    calls = []
    register = detect.register

    def spied(*args, **kwargs):
        calls.append(kwargs.get("profile_match", True))
        return register(*args, **kwargs)

    monkeypatch.setattr(detect, "register", spied)
    points, triangles = ict_head
    truth = ict_landmark_indices()
    warped = broad_warp(points, 731)
    stages = []
    found = find_landmarks(warped, triangles, label="broad warp 731", progress=stages.append)
    error = np.linalg.norm(warped[found.indices] - warped[truth], axis=1) * 10.0
    assert calls == [True, False]
    assert stages.count("orientation") == 1 and stages.count("proportions") == 2  # the second keeps the orientation
    assert stages.count("landmarks") == 2
    assert error.mean() < 3.0 and error.max() < 10.0, (error.mean(), error.max())


def test_a_profile_out_of_reach_gives_no_match():
    """A skin profile shorter than the template's and offset past the reach: no path, an infinite cost, NaN heights."""
    template_depth = np.linspace(0.0, 1.0, 50)
    matched, cost = profile.profile_heights(template_depth, np.zeros(5), offset=10_000)
    assert np.isinf(cost) and np.isnan(matched).all()
