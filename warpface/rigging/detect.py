"""68 iBUG landmarks on any head mesh: the built-in face registered onto the skin, its landmarks carried over.

Pipeline (docs/RIG.md, "Automatic landmarks"): split shells and keep the skin
(:class:`~warpface.rigging.surface.HeadSurface`); find the symmetry plane, up, front and scale with a
similarity fit of the template (:mod:`~warpface.rigging.align`); deform the template onto the skin
with non-rigid ICP (:mod:`~warpface.rigging.nonrigid`); give every template landmark the nearest
skin vertex that faces the same way. The unit follows from the fitted eye distance
(:mod:`~warpface.rigging.units`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .align import fit_similarity
from .nonrigid import SkinTarget, fit_nonrigid
from .surface import HeadSurface
from .template import template
from .units import infer_units, parse_axis, parse_units

__all__ = ["LandmarkFit", "find_landmarks", "CONFIDENCE_DISTANCE"]

CONFIDENCE_DISTANCE = 0.05
"""Distance from a carried-over landmark to its skin vertex at which confidence falls to 1/e
[inter-ocular units, ~3 mm]."""
SNAP_CANDIDATES = 12
"""Nearest skin vertices considered for a landmark; the nearest one facing the template's way wins."""


@dataclass(frozen=True)
class LandmarkFit:
    """68 landmarks found on a head mesh, and what was learnt about the mesh on the way."""

    indices: np.ndarray
    """iBUG-order vertex indices into the input's vertices, (68,) int64."""
    confidence: np.ndarray
    """Per landmark, 0 … 1: how closely the registered template met the skin there."""
    units: str
    """The mesh's length unit (``"m"``, ``"cm"`` or ``"mm"``), inferred or given."""
    meters_per_unit: float
    up: np.ndarray
    """The face's up direction in mesh coordinates (unit vector)."""
    front: np.ndarray
    """The direction the face looks in mesh coordinates (unit vector)."""
    left: np.ndarray
    """Toward the subject's left in mesh coordinates (unit vector)."""
    eye_distance: float
    """Fitted inter-ocular distance [mesh units]."""
    residual: float
    """Mean distance of the registered template to the skin [inter-ocular units]."""
    shells: int
    """Connected shells in the mesh (the skin and e.g. eyes, teeth)."""
    seconds: float


def _snap(points: np.ndarray, normals: np.ndarray, skin: SkinTarget) -> tuple[np.ndarray, np.ndarray]:
    """Nearest skin vertex to each point among those facing the point's normal: (skin positions, distances)."""
    count = min(SNAP_CANDIDATES, len(skin.points))
    distance, index = skin.tree.query(points, k=count)
    distance, index = distance.reshape(len(points), count), index.reshape(len(points), count)
    facing = np.einsum("ij,ikj->ik", normals, skin.normals[index]) > 0.0
    first = np.where(facing.any(axis=1), np.argmax(facing, axis=1), 0)
    rows = np.arange(len(points))
    return index[rows, first], distance[rows, first]


def find_landmarks(
    points,
    triangles,
    *,
    up=None,
    front=None,
    units: str | None = None,
    nonrigid: bool = True,
    label: str = "mesh",
) -> LandmarkFit:
    """Find the 68 iBUG landmarks of the face on a head mesh.

    Args:
        points: vertices (V, 3), any unit and orientation.
        triangles: (T, 3) vertex indices (polygons fan-triangulated, see
            :func:`~warpface.rigging.surface.polygons_to_triangles`); extra shells are allowed.
        up, front: optional hints: ``"y"``, ``"+z"``, ``"-x"`` … or 3-vectors in mesh coordinates.
        units: ``"m"``, ``"cm"`` or ``"mm"``; inferred from the face's size when omitted.
        nonrigid: False stops after the similarity fit (the rigid baseline of benchmarks/rigging.py).
        label: names the mesh in errors.

    Raises:
        ValueError: no surface (empty, a point cloud), a size no unit explains, or no face-like part.
    """
    started = time.perf_counter()
    up_hint, front_hint = parse_axis(up, "up"), parse_axis(front, "front")
    if up_hint is not None and front_hint is not None and abs(up_hint @ front_hint) > 0.5:
        raise ValueError(f"up/front: {up!r} and {front!r} are not perpendicular")
    given_unit = parse_units(units) if units is not None else None
    surface = HeadSurface(points, triangles, label)
    skin_points = surface.points[surface.skin_vertices]
    if len(skin_points) < 100:
        raise ValueError(
            f"{label}: the largest connected part has only {len(skin_points)} vertices; a face needs a few thousand"
        )
    model = template()
    fit, plane_residual = fit_similarity(
        model, skin_points, surface.skin_normals, up_hint=up_hint, front_hint=front_hint
    )
    if fit.residual > 0.12 or plane_residual > 0.08:
        raise ValueError(
            f"{label}: no face-like part found (the template of a face fits the largest part only to "
            f"{fit.residual:.2f} eye distances, symmetry {plane_residual:.2f}); pass a head or face mesh, "
            "or --up/--front if it is one"
        )
    if given_unit is None:
        unit_name, meters_per_unit = infer_units(fit.scale, label)
    else:
        unit_name, meters_per_unit = units.strip().lower(), given_unit
    local = fit.inverse(skin_points)
    skin = SkinTarget(local, surface.skin_normals @ fit.rotation, surface.skin_boundary, cKDTree(local))
    if nonrigid:
        deformed = fit_nonrigid(model, skin)
        marks, mark_normals = deformed.points[model.landmarks], deformed.normals[model.landmarks]
        residual = float(np.mean(skin.tree.query(deformed.points)[0][deformed.weights > 0]))
    else:
        marks, mark_normals = model.points[model.landmarks], model.normals[model.landmarks]
        residual = fit.residual
    index, distance = _snap(marks, mark_normals, skin)
    confidence = np.exp(-((distance / CONFIDENCE_DISTANCE) ** 2))
    axes = fit.rotation.T  # rows: template x, y, z in mesh coordinates
    return LandmarkFit(
        indices=surface.skin_vertices[index].astype(np.int64),
        confidence=confidence,
        units=unit_name,
        meters_per_unit=meters_per_unit,
        up=axes[1].copy(),
        front=axes[2].copy(),
        left=axes[0].copy(),
        eye_distance=float(fit.scale),
        residual=residual,
        shells=surface.shell_count,
        seconds=time.perf_counter() - started,
    )
