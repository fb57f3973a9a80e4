"""The landmark-error diagnosis of benchmarks/rigging_diagnosis.py (docs/RIG.md §9, "Where the jaw line misses"):
its split of the jaw error along / across the contour and along the normal, its floor (the warp's tangential motion
beyond an affine map) and its edge length, each against a closed form."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.rigging_diagnosis import jaw_components, jaw_edge_length, non_affine_tangential, visible_part


def _contour():
    """17 points along a line on a surface tilted about it (normals (0, 1, 1)/√2): (points, normals, unit tangents,
    unit directions in the surface across the line)."""
    points = np.stack([np.linspace(-1.0, 1.0, 17), np.zeros(17), np.zeros(17)], axis=1)
    normal = np.array([0.0, 1.0, 1.0]) / np.sqrt(2.0)
    across = np.array([0.0, 1.0, -1.0]) / np.sqrt(2.0)
    return points, np.tile(normal, (17, 1)), np.tile([1.0, 0.0, 0.0], (17, 1)), np.tile(across, (17, 1))


@pytest.mark.parametrize(
    ("move", "expected"),
    [("tangent", (0.3, 0.0, 0.0)), ("across", (0.0, 0.3, 0.0)), ("normal", (0.0, 0.0, 0.3))],
)
def test_the_jaw_error_is_split_along_across_and_normal_to_the_contour(move, expected):
    truth, normals, tangent, across = _contour()
    shift = {"tangent": tangent, "across": across, "normal": normals}[move]
    parts = jaw_components(truth + 0.3 * shift, truth, normals)
    np.testing.assert_allclose([parts["along"], parts["across"], parts["normal"]], expected, atol=1e-9)


def test_the_components_add_up_to_the_error():
    truth, normals, _, _ = _contour()
    error = np.random.default_rng(3).normal(0.0, 0.1, (17, 3))
    parts = jaw_components(truth + error, truth, normals)
    total = sum(value**2 for value in parts.values())
    assert total == pytest.approx(np.mean(np.sum(error**2, axis=1)), rel=1e-9)


def test_an_affine_warp_has_no_floor_and_a_slide_on_a_plane_is_its_own_floor():
    rng = np.random.default_rng(5)
    rest = np.concatenate([rng.uniform(-1.0, 1.0, (200, 2)), np.zeros((200, 1))], axis=1)
    normals = np.tile([0.0, 0.0, 1.0], (200, 1))
    linear, shift = np.eye(3) + rng.normal(0.0, 0.1, (3, 3)), rng.normal(0.0, 1.0, 3)
    affine = rest @ linear.T + shift
    fit_on, at = np.arange(10, 200), np.arange(10)
    np.testing.assert_allclose(non_affine_tangential(rest, affine, normals, fit_on, at), 0.0, atol=1e-9)
    slid = rest.copy()
    slid[at] += [0.03, -0.04, 0.5]  # the fit never sees these: 0.05 in the plane, 0.5 along its normal
    np.testing.assert_allclose(non_affine_tangential(rest, slid, normals, fit_on, at), 0.05, atol=1e-9)


def test_the_edge_length_at_a_vertex_of_a_unit_grid_is_one_or_the_diagonal():
    points = np.array([(x, y, 0.0) for y in range(3) for x in range(3)], dtype=float)
    quads = [(y * 3 + x, y * 3 + x + 1, y * 3 + x + 4, y * 3 + x + 3) for y in range(2) for x in range(2)]
    triangles = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    # the centre vertex 4 has 4 unit edges and 2 diagonals; a corner (0) 2 unit edges and 1 diagonal
    assert jaw_edge_length(points, triangles, np.array([4])) == pytest.approx((4.0 + 2.0 * np.sqrt(2.0)) / 6.0)
    assert jaw_edge_length(points, triangles, np.array([0])) == pytest.approx((2.0 + np.sqrt(2.0)) / 3.0)


def test_the_visible_part_keeps_an_affine_warp_and_the_normal_motion_but_drops_the_slide():
    """On a plane grid: an affine warp is its own visible part; a bump along the normal stays; a slide within the
    plane beyond the affine map is dropped."""
    x, y = np.meshgrid(np.linspace(-1.0, 1.0, 21), np.linspace(-1.0, 1.0, 21))
    rest = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    index = np.arange(x.size).reshape(21, 21)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    triangles = np.concatenate([np.c_[a, b, d], np.c_[a, d, c]])
    fit_on = np.arange(0, x.size, 3)
    linear = np.array([[1.1, 0.2, 0.0], [-0.1, 0.9, 0.0], [0.0, 0.0, 1.0]])
    affine = rest @ linear.T + [0.3, -0.2, 0.1]
    np.testing.assert_allclose(visible_part(rest, affine, triangles, fit_on), affine, atol=1e-12)
    bump = np.exp(-8.0 * np.sum(rest[:, :2] ** 2, axis=1))
    lifted = rest + 0.1 * bump[:, None] * [0.0, 0.0, 1.0]
    slid = lifted + 0.1 * bump[:, None] * [1.0, 0.0, 0.0]
    visible = visible_part(rest, slid, triangles, fit_on)
    rows = np.concatenate([rest, np.ones((len(rest), 1))], axis=1)
    solution = np.linalg.lstsq(rows[fit_on], slid[fit_on], rcond=None)[0]
    mapped = rows @ solution  # the affine map fitted on fit_on: a plane again, of normal n
    normal = np.cross(solution[0], solution[1])
    normal /= np.linalg.norm(normal)
    kept = visible - mapped
    np.testing.assert_allclose(kept - np.outer(kept @ normal, normal), 0.0, atol=1e-12)  # nothing within the plane
    np.testing.assert_allclose((visible - slid) @ normal, 0.0, atol=1e-12)  # all of the motion along its normal
    assert np.abs(slid - mapped)[:, 0].max() > 0.05  # while the warp itself slid the sheet
