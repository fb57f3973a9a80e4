"""The face mesh's other points on a rig: which of the 468 points land on the rig's skin, and on which vertex.

The 68 iBUG points map onto any rig through its 68 landmark vertices; the rest of the mesh is matched on one
neutral frame of the subject (:func:`dense_mesh_vertices`):

1. the network's 468 points of that frame, ``(x, y)`` pixels and its relative depth ``z`` (same scale), become a
   3-D face ``(x, −y, −z)`` (right-handed, +y up, +z toward the camera);
2. a similarity (Umeyama) takes its iBUG points (:func:`~warpface.tracking.face_mesh_ibug.ibug_from_mesh`) onto
   the rig's landmarks — the jaw line's excepted, which are the face's outline, not fixed skin points;
3. each moved mesh point takes the nearest vertex of its closest point on the rig's surface, when that point is
   within ``max_distance`` × the rig's inter-ocular distance and not at the surface's rim (a mesh point beyond
   the rig's skin: the rig "does not have it"); a vertex claimed twice goes to the nearer point, and the rig's
   own landmark vertices stay with their iBUG points.
"""

from __future__ import annotations

import numpy as np

from .face_mesh_ibug import ibug_from_mesh

__all__ = ["dense_mesh_vertices", "DENSE_MAX_DISTANCE"]

DENSE_MAX_DISTANCE = 0.04
"""Largest distance of a registered mesh point from the rig's skin, × the rig's inter-ocular distance."""
_OUTLINE = [i for i in range(17) if i != 8]


def dense_mesh_vertices(mesh_points, surface, ibug_vertices, *, max_distance=DENSE_MAX_DISTANCE):
    """Rig vertices for the face mesh's points (see the module docstring).

    Args:
        mesh_points: one neutral frame's 468 mesh points, (468, 3): x, y [px], z relative depth [px].
        surface: the rig's skin at rest, a :class:`warpface.FaceMesh` (e.g. ``rig.mesh``).
        ibug_vertices: the rig's 68 iBUG landmark vertices, (68,).
        max_distance: see :data:`DENSE_MAX_DISTANCE`.

    Returns:
        ``{mesh point index: rig vertex}`` for the points the rig's skin has, none of them on a landmark vertex.
    """
    from ..geometry.mesh_index import closest_points
    from .alignment import similarity_fit

    mesh = np.asarray(mesh_points, dtype=np.float64)
    if mesh.shape != (468, 3) or not np.all(np.isfinite(mesh)):
        raise ValueError(f"mesh_points: expected 468 finite points (468, 3), got {mesh.shape}")
    rest = np.asarray(surface.points, dtype=np.float64)
    tris = np.asarray(surface.triangles, dtype=np.int64)
    marks = np.asarray(ibug_vertices, dtype=np.int64)
    face = mesh * np.array([1.0, -1.0, -1.0])
    inner = np.setdiff1d(np.arange(68), _OUTLINE)
    scale, rotation, translation, _ = similarity_fit(ibug_from_mesh(face)[inner], rest[marks[inner]])
    moved = scale * face @ rotation.T + translation
    triangle, barycentric, distance = closest_points(moved, rest, tris, device="cpu")
    reach = max_distance * float(np.linalg.norm(rest[marks[36]] - rest[marks[45]]))
    rim = surface.boundary_vertices
    corners = tris[triangle]
    nearest = corners[np.arange(len(corners)), np.argmax(barycentric, axis=1)]
    keep = (distance <= reach) & ~np.isin(corners, rim).any(axis=1) & ~np.isin(nearest, marks)
    chosen: dict[int, tuple[float, int]] = {}
    for point in np.flatnonzero(keep):
        vertex = int(nearest[point])
        if vertex not in chosen or distance[point] < chosen[vertex][0]:
            chosen[vertex] = (float(distance[point]), int(point))
    return {point: vertex for vertex, (_, point) in sorted(chosen.items(), key=lambda item: item[1][1])}
