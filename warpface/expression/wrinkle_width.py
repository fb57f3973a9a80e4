"""Wrinkles no narrower than the mesh can draw (docs/RIG.md §14): a furrow's width ``k_w`` raised to
:data:`WRINKLE_EDGES` local edge lengths, its depth lowered in the same ratio.

A furrow ``S(d) = k_d (d/k_w − 1) e^{−d/k_w}`` (SPEC §1.4) is a groove ``2 k_w`` wide. Where the edges along its path
are longer than ``k_w / 2`` the groove falls on one row of vertices: the rest of the profile is its flank's far tail,
so the mesh shows a one-vertex cut (a sign island: one vertex down between vertices up). Per wrinkle, with ``ē`` the
mean length of the edges at the vertices nearest its curve (the :data:`_NEAREST` nearest, and every vertex within
``k_w``), the model uses

``k_w' = max(k_w, WRINKLE_EDGES · ē)``,  ``k_d' = k_d · k_w / k_w'``

— the furrow low-passed to the mesh's resolution: its cross-section ``∫ S dd`` (∝ ``k_d k_w``) is kept, its peak is
spread over the rows of vertices that can carry it. A wrinkle at least that wide is unchanged.
"""

from __future__ import annotations

import numpy as np

from ..geometry.triangles import triangle_edges
from .wrinkles import Wrinkle, bezier_distances, project_points

__all__ = ["WRINKLE_EDGES", "drawable_widths", "vertex_edge_lengths"]

WRINKLE_EDGES = 3.0
"""The narrowest furrow, ``k_w``, in local edge lengths: its groove (``d < k_w`` on either side) spans six edges. Two
left the built-in face's forehead furrows at "thinking" as rows of lumps (docs/images/wrinkles_builtin.png)."""
_NEAREST = 12
"""At least this many vertices nearest a wrinkle's curve set its local edge length."""


def vertex_edge_lengths(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Mean length of the edges at each vertex (V,) [mesh units] (0 at a vertex on no triangle)."""
    edges = triangle_edges(triangles)[0]
    lengths = np.linalg.norm(points[edges[:, 0]] - points[edges[:, 1]], axis=1)
    total = np.bincount(edges.ravel(), np.repeat(lengths, 2), minlength=len(points))
    count = np.bincount(edges.ravel(), minlength=len(points))
    return total / np.maximum(count, 1)


def drawable_widths(points: np.ndarray, triangles: np.ndarray, wrinkles, *, device=None) -> list[tuple[float, float]]:
    """Per wrinkle, ``(k_w', k_w / k_w')`` of the module docstring: the width the mesh can draw [mesh units] and the
    factor on its profile (the depth's ratio), from the rest ``points`` (V, 3) and ``triangles`` (T, 3)."""
    edge = vertex_edge_lengths(points, triangles)
    out = []
    for wrinkle in wrinkles:
        if not isinstance(wrinkle, Wrinkle):
            raise TypeError(f"wrinkles: expected Wrinkle objects, got {type(wrinkle).__name__}")
        distance = bezier_distances(
            project_points(wrinkle.projection, points, device=device), wrinkle.control_points, device=device
        )
        nearest = np.argsort(distance)[: min(_NEAREST, len(distance))]
        near = np.union1d(nearest, np.flatnonzero(distance <= wrinkle.width))
        width = max(wrinkle.width, WRINKLE_EDGES * float(edge[near].mean()) if len(near) else 0.0)
        out.append((width, wrinkle.width / width))
    return out
