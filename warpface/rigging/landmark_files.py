"""68 landmarks from a file: JSON vertex indices or points, menpo ``.ljson``, MeshLab/Wrap picked points ``.pp``.

Points become the nearest vertex of the mesh; a point far off the mesh (another unit, another mesh)
is refused. The order must be iBUG's: :mod:`~warpface.rigging.layout` checks it afterwards.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from .._files import read_text
from ..landmarks import IBUG_COUNT

__all__ = ["read_landmark_file", "landmarks_from_values", "FORMATS"]

FORMATS = (".json", ".ljson", ".pp")
MAX_OFFSET = 0.05
"""A landmark point farther than this × the mesh's bounding-box diagonal from every vertex is refused."""


def _from_json(data, label: str):
    if isinstance(data, dict):
        for key in ("landmarks", "indices", "points"):
            if key in data:
                return _from_json(data[key], label)
        if "groups" in data:  # menpo LJSON v2: {"groups": {name: {"landmarks": {"points": …}}}}
            groups = list(data["groups"].values())
            if groups:
                return _from_json(groups[0], label)
        raise ValueError(f"{label}: no 'landmarks', 'indices' or 'points' entry in the JSON object")
    return data


def _from_pp(text: str, label: str) -> list:
    try:
        root = ElementTree.fromstring(text)
    except ElementTree.ParseError as exc:
        raise ValueError(f"{label}: not a MeshLab picked-points file ({exc})") from None
    points = []
    for point in root.iter("point"):
        if point.get("active", "1") == "0":
            continue
        try:
            points.append([float(point.get(axis)) for axis in ("x", "y", "z")])
        except (TypeError, ValueError):
            raise ValueError(f"{label}: a <point> lacks numeric x, y, z attributes") from None
    return points


def landmarks_from_values(values, points: np.ndarray, label: str = "landmarks") -> np.ndarray:
    """68 vertex indices from 68 integer indices or 68 points (snapped to the nearest vertex of ``points``)."""
    try:
        array = np.asarray(values)
    except (TypeError, ValueError):
        raise ValueError(f"{label}: expected {IBUG_COUNT} vertex indices or {IBUG_COUNT} points") from None
    if array.ndim == 0:
        raise TypeError(f"{label}: expected {IBUG_COUNT} vertex indices or points, got {type(values).__name__}")
    if array.dtype.kind in "USb":
        kind = "true/false" if array.dtype.kind == "b" else "text"
        raise TypeError(f"{label}: landmarks must be numbers (vertex indices or x, y, z points), got {kind}")
    if array.dtype == object or len(array) != IBUG_COUNT:
        raise ValueError(f"{label}: expected {IBUG_COUNT} iBUG landmarks, got {len(array) if array.ndim else 0}")
    if array.ndim == 1:
        if not np.all(np.isfinite(array.astype(np.float64))) or np.any(array.astype(np.float64) % 1 != 0):
            raise ValueError(f"{label}: vertex indices must be whole numbers")
        indices = array.astype(np.int64)
        bad = np.flatnonzero((indices < 0) | (indices >= len(points)))
        if len(bad):
            raise ValueError(
                f"{label}: landmark {int(bad[0])} has vertex index {int(indices[bad[0]])}; the mesh has {len(points)}"
            )
        return _distinct(indices, label)
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"{label}: expected {IBUG_COUNT} indices or {IBUG_COUNT} × 3 points, got shape {array.shape}")
    marks = array.astype(np.float64)
    if not np.all(np.isfinite(marks)):
        raise ValueError(f"{label}: landmark points must be finite numbers")
    distance, index = cKDTree(points).query(marks)
    diagonal = float(np.linalg.norm(np.ptp(points, axis=0)))
    far = int(np.argmax(distance))
    if distance[far] > MAX_OFFSET * diagonal:
        raise ValueError(
            f"{label}: landmark {far} lies {distance[far]:.3g} units off the mesh (the mesh is {diagonal:.3g} across): "
            "points in another unit or for another mesh?"
        )
    return _distinct(index.astype(np.int64), label)


MAX_SHARING = 2
"""Landmarks that may name one vertex (two mouth corners on a coarse mesh); more is a mistake."""


def _distinct(indices: np.ndarray, label: str) -> np.ndarray:
    """``indices``, after refusing a vertex named by more than :data:`MAX_SHARING` landmarks."""
    vertices, counts = np.unique(indices, return_counts=True)
    if counts.max() > MAX_SHARING:
        vertex = int(vertices[np.argmax(counts)])
        shared = np.flatnonzero(indices == vertex)
        raise ValueError(
            f"{label}: {len(shared)} landmarks (iBUG {', '.join(map(str, shared[:5]))}"
            f"{', …' if len(shared) > 5 else ''}) name the same vertex {vertex}; give each landmark its own point"
        )
    return indices


def read_landmark_file(path, points: np.ndarray) -> np.ndarray:
    """The 68 vertex indices a landmark file gives for a mesh with vertices ``points`` (V, 3)."""
    path = Path(path)
    label = str(path)
    if path.suffix.lower() not in FORMATS:
        raise ValueError(f"{label}: landmark files must be {', '.join(FORMATS)}, got {path.suffix or 'no extension'}")
    if not path.is_file():
        raise ValueError(f"{label}: file not found")
    text = read_text(path)
    if not text.strip():
        raise ValueError(f"{label}: empty file")
    if path.suffix.lower() == ".pp":
        values = _from_pp(text, label)
    else:
        try:
            values = _from_json(json.loads(text), label)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{label}: not JSON ({exc.msg} at line {exc.lineno})") from None
    return landmarks_from_values(values, points, label)
