"""weld_seams: a surface split along a seam is one piece again; folds, small pieces and soups are left apart."""

from __future__ import annotations

import numpy as np
import pytest

from warpface.geometry.triangles import SEAM_MIN_SHARE, vertex_shells, weld_seams


def _sheet(columns: int = 8, rows: int = 6, height=lambda x, y: 0.0 * x):
    """A grid sheet z = height(x, y) over [0, columns] × [0, rows]: (points (V, 3), triangles (T, 3))."""
    x, y = np.meshgrid(np.arange(columns + 1.0), np.arange(rows + 1.0), indexing="xy")
    points = np.c_[x.ravel(), y.ravel(), height(x, y).ravel()]
    index = np.arange(points.shape[0]).reshape(rows + 1, columns + 1)
    a, b, c, d = index[:-1, :-1], index[:-1, 1:], index[1:, :-1], index[1:, 1:]
    triangles = np.concatenate([np.c_[a.ravel(), b.ravel(), d.ravel()], np.c_[a.ravel(), d.ravel(), c.ravel()]])
    return points, triangles


def _split(points, triangles, faces):
    """The ``faces`` (boolean per triangle) given their own copies of the vertices they share with the others."""
    shared = np.intersect1d(np.unique(triangles[faces]), np.unique(triangles[~faces]))
    copy = np.full(len(points), -1)
    copy[shared] = len(points) + np.arange(len(shared))
    split = triangles.copy()
    moved = split[faces]
    on_seam = np.isin(moved, shared)
    moved[on_seam] = copy[moved[on_seam]]
    split[faces] = moved
    return np.vstack([points, points[shared]]), split, shared


def test_a_sheet_split_along_a_curved_seam_is_joined_back_exactly():
    points, triangles = _sheet(height=lambda x, y: 0.3 * np.sin(x) * np.cos(0.5 * y))
    centroid = points[triangles].mean(axis=1)
    faces = centroid[:, 0] < 3.0 + 0.5 * np.sin(centroid[:, 1])  # a wavy UV seam
    split_points, split, shared = _split(points, triangles, faces)
    assert len(np.unique(vertex_shells(split, len(split_points))[np.unique(split)])) == 2
    joined = weld_seams(split_points, split)
    np.testing.assert_array_equal(joined, triangles)  # each copy goes back to its original (the lowest index)
    assert len(shared) > 5


def test_lips_modelled_touching_stay_apart():
    """Two sheets sharing the row y = 0 as copies: folded onto each other (facing apart, like lips modelled
    touching) they stay two pieces; laid out as one flat sheet they are welded into one."""
    upper, triangles = _sheet(rows=3)  # y in [0, 3], faces toward +z
    flipped = triangles[:, [0, 2, 1]] + len(upper)
    folded = np.vstack([upper, upper * [1.0, 1.0, 0.0] - [0.0, 0.0, 1e-3] * upper[:, [1, 1, 1]]])  # under it, → −z
    both = np.vstack([triangles, flipped])
    np.testing.assert_array_equal(weld_seams(folded, both), both)
    laid_out = np.vstack([upper, upper * [1.0, -1.0, 1.0]])  # mirrored below y = 0: the flip turns it back to +z
    joined = weld_seams(laid_out, both)
    assert len(np.unique(vertex_shells(joined, len(laid_out))[np.unique(joined)])) == 1


def test_a_small_piece_joins_the_skin_but_small_pieces_that_meet_only_each_other_stay_apart():
    """A 1 % corner split off a large sheet (a lip cut off by a hard edge) is welded back; a small strip split in
    two away from it (lashes, an eye film: each piece well under :data:`SEAM_MIN_SHARE`) is not; a soup is left."""
    points, triangles = _sheet(columns=20, rows=20)
    centroid = points[triangles].mean(axis=1)
    corner = (centroid[:, 0] < 2.0) & (centroid[:, 1] < 2.0)
    assert corner.mean() < SEAM_MIN_SHARE
    split_points, split, _ = _split(points, triangles, corner)
    np.testing.assert_array_equal(weld_seams(split_points, split), triangles)
    strip_points, strip = _sheet(columns=4, rows=1)
    strip_points = strip_points * 0.5 + [0.0, 0.0, 5.0]  # away from the sheet, 0.5 % of the area in all
    halves = strip_points[strip].mean(axis=1)[:, 0] < 1.0
    strip_points, strip, _ = _split(strip_points, strip, halves)
    both_points = np.vstack([points, strip_points])
    both = np.vstack([triangles, strip + len(points)])
    np.testing.assert_array_equal(weld_seams(both_points, both), both)
    soup_points = points[triangles].reshape(-1, 3)
    soup = np.arange(len(soup_points)).reshape(-1, 3)
    np.testing.assert_array_equal(weld_seams(soup_points, soup), soup)  # refused downstream as a soup


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_welding_swaps_vertices_only_for_their_coincident_copies(seed):
    rng = np.random.default_rng(seed)
    points, triangles = _sheet(columns=12, rows=10, height=lambda x, y: rng.normal(0.0, 0.05, x.shape))
    centroid = points[triangles].mean(axis=1)
    amplitude, phase = rng.uniform(0.5, 2.0), rng.uniform(0.0, 2.0 * np.pi)
    faces = centroid[:, 0] < 6.0 + amplitude * np.sin(centroid[:, 1] + phase)  # a seam of random course
    split_points, split, _ = _split(points, triangles, faces)
    joined = weld_seams(split_points, split)
    assert joined.shape == split.shape  # no triangle of a flat seam degenerates
    # every corner is the same point as before: welding only swaps a vertex for a coincident copy
    np.testing.assert_array_equal(split_points[joined], split_points[split])
    np.testing.assert_array_equal(joined, triangles)


def test_a_copy_left_out_of_the_triangles_neither_dilutes_its_neighbours_means_nor_misses_its_own():
    """The tissue stage's neighbourhood means (normals, stretch) count only vertices on triangles: a seam's copy,
    unused by the welded triangles, takes its twin's mean and leaves every other vertex's mean as it was."""
    from warpface.expression.tissue import neighbourhood_averager

    rng = np.random.default_rng(4)
    points = rng.uniform(-1.0, 1.0, (300, 3))
    values = rng.normal(0.0, 1.0, (300, 2))
    plain = neighbourhood_averager(points, 0.5)(values)
    with_copies = np.vstack([points, points[:20]])
    copied_values = np.vstack([values, np.zeros((20, 2))])  # a copy has no value of its own (no normal, no stretch)
    counted = np.arange(320) < 300
    means = neighbourhood_averager(with_copies, 0.5, counted)(copied_values)
    np.testing.assert_allclose(means[:300], plain, atol=1e-12)
    np.testing.assert_allclose(means[300:], plain[:20], atol=1e-12)
    np.testing.assert_array_equal(neighbourhood_averager(points, 0.5, np.ones(300, bool))(values), plain)


def test_a_chain_of_small_pieces_off_the_skin_joins_it_piece_by_piece():
    points, triangles = _sheet(columns=20, rows=20)
    centroid = points[triangles].mean(axis=1)
    near = (centroid[:, 0] < 2.0) & (centroid[:, 1] < 4.0)  # two small islands: one on the sheet …
    far = near & (centroid[:, 1] < 2.0)  # … and one that meets only the first
    split_points, split, _ = _split(points, triangles, near)
    split_points, split, _ = _split(split_points, split, far)
    assert len(np.unique(vertex_shells(split, len(split_points))[np.unique(split)])) == 3
    np.testing.assert_array_equal(weld_seams(split_points, split), triangles)
