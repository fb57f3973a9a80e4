"""The face's mid-line profile: at which heights the head's nose and mouth lie, against the template's.

Both surfaces are in the template's frame (x across, y up, z front, inter-ocular units) after the similarity and
affine fits, so their mirror planes are x = 0. Each is cut by that plane; the frontmost depth at every height is the
profile, ``z(y)``. The template's profile is matched to the skin's by dynamic time warping on the profile's slope angle
and depth: a monotone map from the template's heights to the skin's. The template's nose and mouth are moved to the
heights it gives them, and the non-rigid fit starts from there (docs/RIG.md §9, step 5a).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..geometry.ramps import smooth_ramp
from .surface import vertex_normals
from .template import Template

__all__ = ["midline_profile", "profile_heights", "knot_shifts", "profiled", "STEP"]

STEP = 0.02
"""Height step of the profiles [inter-ocular units]."""
REACH = 0.8
"""Farthest a template height may be matched from itself [inter-ocular units]."""
SMOOTHING = 2.0
"""Gaussian width of the profiles' smoothing before their slope is taken [steps]."""
DEPTH_WEIGHT = 4.0
"""Weight of the depth difference (squared, per inter-ocular unit²) against the slope angle's (squared, rad²)."""
SLANT = 0.05
"""Cost of a non-diagonal warping step (a stretch or a squeeze of the height), per step."""


def midline_profile(points: np.ndarray, triangles: np.ndarray, heights: np.ndarray) -> np.ndarray:
    """Frontmost depth ``z`` of the surface's cut by the plane x = 0 at each of ``heights`` (H,): NaN where the cut
    does not reach. ``points`` (V, 3), ``triangles`` (T, 3)."""
    x = points[triangles, 0]
    crossing = (x.min(axis=1) < 0.0) & (x.max(axis=1) > 0.0)
    corners, x = points[triangles[crossing]], x[crossing]
    ends = []
    for a, b in ((0, 1), (1, 2), (2, 0)):  # the two edges whose ends lie on either side hold the cut's ends
        cut = (x[:, a] < 0.0) != (x[:, b] < 0.0)
        t = np.where(cut, x[:, a] / np.where(cut, x[:, a] - x[:, b], 1.0), 0.0)
        ends.append((cut, corners[:, a] + t[:, None] * (corners[:, b] - corners[:, a])))
    # per triangle, the first two of its cut edges (a vertex exactly on the plane can make a third)
    first = np.where(ends[0][0][:, None], ends[0][1], np.where(ends[1][0][:, None], ends[1][1], ends[2][1]))
    second = np.where(
        (ends[0][0] & ends[1][0])[:, None], ends[1][1], np.where(ends[2][0][:, None], ends[2][1], ends[1][1])
    )
    depth = np.full(len(heights), np.nan)
    low, high = np.minimum(first[:, 1], second[:, 1]), np.maximum(first[:, 1], second[:, 1])
    for start in range(0, len(first), 512):
        part = slice(start, start + 512)
        span = high[part, None] - low[part, None]
        inside = (heights[None] >= low[part, None]) & (heights[None] <= high[part, None])
        t = np.where(
            span > 0.0,
            (heights[None] - first[part, 1, None])
            / np.where(span > 0.0, second[part, 1, None] - first[part, 1, None], 1.0),
            0.0,
        )
        z = first[part, 2, None] + t * (second[part, 2, None] - first[part, 2, None])
        z = np.where(inside, z, -np.inf).max(axis=0)
        depth = np.where(np.isfinite(z), np.fmax(depth, z), depth)
    return depth


def _slope_angles(depth: np.ndarray) -> np.ndarray:
    """The profile's slope angle ``atan(dz/dy)`` per height, after a Gaussian smoothing of ``SMOOTHING`` steps."""
    radius = int(np.ceil(3 * SMOOTHING))
    kernel = np.exp(-0.5 * (np.arange(-radius, radius + 1) / SMOOTHING) ** 2)
    padded = np.pad(depth, radius, mode="edge")
    smooth = np.convolve(padded, kernel / kernel.sum(), mode="valid")
    return np.arctan(np.gradient(smooth, STEP))


def profile_heights(template_depth: np.ndarray, skin_depth: np.ndarray, offset: int) -> tuple[np.ndarray, float]:
    """For each template height (index ``i`` of ``template_depth``, (N,)), the skin height index it matches in
    ``skin_depth`` (M,), where skin index ``i + offset`` is the same height: a monotone dynamic-time-warping path of
    steps (1, 1), (1, 2) and (2, 1), within :data:`REACH`, free to start and end anywhere in it. Both profiles are
    complete (no NaN). Returns (N,) fractional skin indices and the path's mean cost per template height (NaN
    indices and an infinite cost when no path stays within reach)."""
    n, m = len(template_depth), len(skin_depth)
    cost = (_slope_angles(template_depth)[:, None] - _slope_angles(skin_depth)[None]) ** 2
    cost += DEPTH_WEIGHT * (template_depth[:, None] - skin_depth[None]) ** 2
    reach = int(round(REACH / STEP))
    rows, columns = np.arange(n)[:, None], np.arange(m)[None]
    cost[np.abs(columns - rows - offset) > reach] = np.inf
    total = np.full((n, m), np.inf)
    move = np.zeros((n, m), dtype=np.int8)
    total[0] = cost[0]
    for i in range(1, n):
        options = np.full((3, m), np.inf)
        options[0, 1:] = total[i - 1, :-1]  # (1, 1)
        options[1, 2:] = total[i - 1, :-2] + cost[i, 1:-1] + SLANT  # (1, 2): through the skin height between
        if i >= 2:
            options[2, 1:] = total[i - 2, :-1] + cost[i - 1, 1:] + SLANT  # (2, 1): through the template height between
        move[i] = np.argmin(options, axis=0)
        total[i] = cost[i] + options[move[i], np.arange(m)]
    matched = np.empty(n)
    j = int(np.argmin(total[-1]))
    if not np.isfinite(total[-1, j]):
        return np.full(n, np.nan), np.inf
    cost = float(total[-1, j] / n)
    i = n - 1
    while i > 0:
        matched[i] = j
        kind = move[i, j]
        if kind == 0:
            i, j = i - 1, j - 1
        elif kind == 1:
            i, j = i - 1, j - 2
        else:
            matched[i - 1] = j - 0.5
            i, j = i - 2, j - 1
    matched[0] = j
    return matched, cost


KNOTS = (30, 33, 51, 57)
"""iBUG landmarks whose heights the profile match moves: the nose tip and base and the lips' outer middles."""
PINNED = (27, 8)
"""iBUG landmarks whose heights stay: the nasion (the eyes, which the affine fit placed) and the chin's bottom (the
template's profile ends there, so its match is loose)."""
LEAST_SHIFT = 0.07
"""A profile whose knots all move less than this [inter-ocular units] (~4.5 mm) leaves the template as it is: the
non-rigid fit finds such shifts itself, and the heads it was tuned on keep their landmarks."""
MOST_SHIFT = 0.4
"""A knot moved farther than this [inter-ocular units] (~2.5 cm) is no face's proportion: the template stays."""
MATCH_COST = 0.2
"""A match costing more than this per height (slope angle² + depth term) is no face's profile (faces: 0.03–0.14, an
open tube 0.29): the template stays."""
LATERAL = (0.5, 1.0)
"""The shift is whole within this distance of the mid-plane [inter-ocular units] (the nose and the mouth) and fades
to none at the second (the cheeks and the jaw line keep their heights), smoothstep between."""


def knot_shifts(model: Template, skin_points: np.ndarray, skin_faces: np.ndarray):
    """(heights (6,), shifts (6,)) of the template's pinned and knot landmarks, ascending heights; None when a
    profile is missing, the match is poor (:data:`MATCH_COST`), a shift implausible (:data:`MOST_SHIFT`) or the
    match would reorder them."""
    top, bottom = model.points[:, 1].max(), model.points[:, 1].min()
    heights = np.arange(bottom, top, STEP)
    template_depth = midline_profile(model.points, model.triangles, heights)
    known = np.flatnonzero(np.isfinite(template_depth))
    if len(known) < 10:
        return None
    heights = heights[known[0] : known[-1] + 1]
    template_depth = template_depth[known[0] : known[-1] + 1]
    known = np.isfinite(template_depth)
    template_depth = np.interp(heights, heights[known], template_depth[known])  # the mouth's slit
    reach = int(round(REACH / STEP))
    skin_heights = heights[0] + STEP * np.arange(-reach, len(heights) + reach)
    skin_depth = midline_profile(skin_points, skin_faces, skin_heights)
    good = np.isfinite(skin_depth)
    if good.sum() < 0.5 * len(skin_depth):
        return None
    skin_depth = np.interp(skin_heights, skin_heights[good], skin_depth[good])
    matched, cost = profile_heights(template_depth, skin_depth, reach)
    if cost > MATCH_COST:
        return None
    shift = skin_heights[0] + matched * STEP - heights
    marks = np.array(PINNED[:1] + KNOTS + PINNED[1:])
    at = model.landmark_points[marks, 1]
    moved = np.array([np.median(shift[np.abs(heights - y) <= 2.5 * STEP]) for y in at])
    moved[[0, -1]] = 0.0
    order = np.argsort(at)
    if np.any(np.diff((at + moved)[order]) <= 0.0) or np.abs(moved).max() > MOST_SHIFT:
        return None
    return at[order], moved[order]


def profiled(model: Template, skin_points: np.ndarray, skin_faces: np.ndarray) -> Template:
    """The template with its heights moved by :func:`knot_shifts` (piecewise linear in the height between the knots,
    none above the nasion or below the chin), or ``model`` itself."""
    knots = knot_shifts(model, skin_points, skin_faces)
    if knots is None or np.abs(knots[1]).max() < LEAST_SHIFT:
        return model
    heights, shifts = knots

    def moved(points):
        out = points.copy()
        whole = 1.0 - smooth_ramp(LATERAL[0], LATERAL[1], np.abs(points[:, 0]))
        out[:, 1] += whole * np.interp(points[:, 1], heights, shifts, left=0.0, right=0.0)
        return out

    points = moved(model.points)
    normals = vertex_normals(points, model.triangles)
    return replace(model, points=points, normals=normals, landmark_points=moved(model.landmark_points))
