"""Linear tetrahedral meshes: validation, volumes, element quality and boundary.

A :class:`TetMesh` is the static geometry the FEM of SPEC §2 runs on. It owns
no device memory: the assembly kernels upload what they need. Everything here is
vectorised NumPy, run once at set-up.

Conventions
-----------
* ``points``: rest positions [m], shape ``(N, 3)``, float64.
* ``tets``: node indices, shape ``(M, 4)``, int32, positively oriented:
  ``det[p1 - p0, p2 - p0, p3 - p0] > 0``.
* Faces of tet ``(a, b, c, d)`` are numbered by the node they are opposite to and
  are wound so their right-hand normal points out of the tet (see ``_FACE_NODES``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .._validate import MAX_COORDINATE as SHARED_MAX_COORDINATE

__all__ = [
    "MAX_COORDINATE",
    "MIN_EDGE_LENGTH",
    "TET_EDGE_NODES",
    "TetMesh",
    "TetQuality",
    "tet_signed_volumes",
    "tet_dihedral_angles",
]

MAX_COORDINATE = SHARED_MAX_COORDINATE
"""Largest accepted node coordinate magnitude [m] (:data:`warpface._validate.MAX_COORDINATE`): the
BVHs of embedding and meshing are float32."""

MIN_EDGE_LENGTH = 1.0e-9
"""Shortest accepted longest edge of a tet [m]: smaller tets underflow volumes and float32 bounds."""

# Local node triples of the four faces, face k opposite node k, wound outward for a
# positively oriented tet.
_FACE_NODES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)

# The six edges (local node pairs) and, for each, the two faces that meet there
# (the faces opposite the two nodes *not* on the edge).
TET_EDGE_NODES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)
_EDGE_FACES = np.array([[2, 3], [1, 3], [1, 2], [0, 3], [0, 2], [0, 1]], dtype=np.int64)

# A tet whose volume is below this fraction of (longest edge)^3 / (6 sqrt 2) -- the
# volume of the regular tet with that edge -- is treated as degenerate.
_DEGENERATE_RELATIVE_VOLUME = 1.0e-9


def tet_signed_volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed tet volumes [m^3], shape (M,), float64; positive for positive orientation."""
    p = np.asarray(points, dtype=np.float64)[np.asarray(tets)]
    e1 = p[:, 1] - p[:, 0]
    e2 = p[:, 2] - p[:, 0]
    e3 = p[:, 3] - p[:, 0]
    return np.einsum("ij,ij->i", np.cross(e1, e2), e3) / 6.0


def _longest_edges(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Longest edge length per tet [m], shape (M,)."""
    p = points[tets]
    d = p[:, TET_EDGE_NODES[:, 0]] - p[:, TET_EDGE_NODES[:, 1]]
    return np.sqrt(np.max(np.einsum("ijk,ijk->ij", d, d), axis=1))


def tet_dihedral_angles(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Interior dihedral angles [rad] at the six edges of each tet, shape (M, 6), float64.

    The angle at an edge is pi minus the angle between the outward normals of the two
    faces meeting there. Degenerate faces give NaN; callers reject such tets first.
    """
    p = np.asarray(points, dtype=np.float64)[np.asarray(tets)]
    # Outward face normals (sign-corrected for orientation so inverted tets still give
    # interior angles of the shape itself).
    fa = p[:, _FACE_NODES[:, 0]]
    fb = p[:, _FACE_NODES[:, 1]]
    fc = p[:, _FACE_NODES[:, 2]]
    normals = np.cross(fb - fa, fc - fa)
    orientation = np.sign(tet_signed_volumes(points, tets))[:, None, None]
    normals = normals * np.where(orientation == 0.0, 1.0, orientation)
    with np.errstate(invalid="ignore", divide="ignore"):
        normals /= np.linalg.norm(normals, axis=2, keepdims=True)
        n1 = normals[:, _EDGE_FACES[:, 0]]
        n2 = normals[:, _EDGE_FACES[:, 1]]
        cos_between = np.clip(np.einsum("ijk,ijk->ij", n1, n2), -1.0, 1.0)
    return np.pi - np.arccos(cos_between)


@dataclass(frozen=True)
class TetQuality:
    """Element quality summary of a tet mesh."""

    min_dihedral_deg: float
    """Smallest interior dihedral angle over the mesh [degrees] (regular tet: 70.53)."""
    max_dihedral_deg: float
    """Largest interior dihedral angle over the mesh [degrees] (regular tet: 70.53)."""
    inverted_count: int
    """Number of tets with non-positive signed volume (always 0 for a validated mesh)."""
    min_volume: float
    """Smallest tet volume [m^3]."""
    max_volume: float
    """Largest tet volume [m^3]."""
    per_tet_min_dihedral_deg: np.ndarray
    """Smallest dihedral angle of each tet [degrees], shape (M,), float64."""

    def __str__(self) -> str:
        return (
            f"dihedral angles {self.min_dihedral_deg:.2f}..{self.max_dihedral_deg:.2f} deg, "
            f"{self.inverted_count} inverted, volumes {self.min_volume:.3e}..{self.max_volume:.3e} m^3"
        )


class TetMesh:
    """Validated linear tetrahedral mesh.

    Args:
        points: Rest node positions [m], shape (N, 3), finite.
        tets: Node indices of each tet, shape (M, 4), integers in ``[0, N)``, four distinct
            nodes per tet, positively oriented, non-degenerate; every node must belong to at
            least one tet (an orphan node has no stiffness or mass and makes the system singular).

    Raises:
        ValueError: naming the offending tet or node when any of the above fails. Use
            :meth:`TetMesh.repaired` to flip negatively oriented tets and drop orphan nodes.
    """

    def __init__(self, points, tets):
        try:
            points = np.array(points, dtype=np.float64, copy=True)
        except (TypeError, ValueError):
            raise TypeError(f"TetMesh points must be numbers of shape (N, 3), got {type(points).__name__}") from None
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"TetMesh points must have shape (N, 3), got {points.shape}")
        if points.shape[0] < 4:
            raise ValueError(f"TetMesh needs at least 4 points, got {points.shape[0]}")
        bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
        if bad.size:
            raise ValueError(f"TetMesh point {bad[0]} is not finite: {points[bad[0]].tolist()}")
        far = np.flatnonzero(np.abs(points).max(axis=1) > MAX_COORDINATE)
        if far.size:
            raise ValueError(
                f"TetMesh point {far[0]} lies beyond {MAX_COORDINATE:g} m from the origin: {points[far[0]].tolist()}"
            )

        tets_in = np.asarray(tets)
        if tets_in.dtype == object or tets_in.dtype.kind in "USV":
            raise ValueError(f"TetMesh tets must hold integer node indices, got dtype {tets_in.dtype}")
        if tets_in.ndim != 2 or tets_in.shape[1] != 4:
            raise ValueError(f"TetMesh tets must have shape (M, 4), got {tets_in.shape}")
        if tets_in.shape[0] == 0:
            raise ValueError("TetMesh needs at least one tet")
        if not np.issubdtype(tets_in.dtype, np.integer):
            if not np.issubdtype(tets_in.dtype, np.floating) or not np.all(tets_in == np.round(tets_in)):
                raise ValueError(f"TetMesh tets must hold integer node indices, got dtype {tets_in.dtype}")
        tets_i64 = tets_in.astype(np.int64)
        n = points.shape[0]
        out_of_range = np.flatnonzero(((tets_i64 < 0) | (tets_i64 >= n)).any(axis=1))
        if out_of_range.size:
            t = out_of_range[0]
            raise ValueError(f"TetMesh tet {t} has node index out of range [0, {n}): {tets_i64[t].tolist()}")
        s = np.sort(tets_i64, axis=1)
        repeated = np.flatnonzero((s[:, 1:] == s[:, :-1]).any(axis=1))
        if repeated.size:
            t = repeated[0]
            raise ValueError(f"TetMesh tet {t} repeats a node: {tets_i64[t].tolist()}")

        volumes = tet_signed_volumes(points, tets_i64)
        longest = _longest_edges(points, tets_i64)
        tiny = np.flatnonzero(longest < MIN_EDGE_LENGTH)
        if tiny.size:
            t = tiny[0]
            raise ValueError(
                f"TetMesh tet {t} is smaller than {MIN_EDGE_LENGTH:g} m (longest edge {longest[t]:.3e} m); "
                "points are in metres"
            )
        scale = longest**3 / (6.0 * np.sqrt(2.0))
        degenerate = np.flatnonzero(np.abs(volumes) <= _DEGENERATE_RELATIVE_VOLUME * scale)
        if degenerate.size:
            t = degenerate[0]
            raise ValueError(
                f"TetMesh tet {t} is degenerate (volume {volumes[t]:.3e} m^3 for longest edge "
                f"{np.cbrt(scale[t] * 6.0 * np.sqrt(2.0)):.3e} m); {degenerate.size} degenerate tets in all"
            )
        inverted = np.flatnonzero(volumes < 0.0)
        if inverted.size:
            t = inverted[0]
            raise ValueError(
                f"TetMesh tet {t} is inverted (signed volume {volumes[t]:.3e} m^3); {inverted.size} inverted "
                "tets in all. Use TetMesh.repaired(points, tets) to flip negatively oriented tets."
            )
        referenced = np.zeros(n, dtype=bool)
        referenced[tets_i64.ravel()] = True
        orphans = np.flatnonzero(~referenced)
        if orphans.size:
            raise ValueError(
                f"TetMesh node {orphans[0]} belongs to no tet ({orphans.size} such nodes); "
                "use TetMesh.repaired(points, tets) to drop them"
            )

        points.setflags(write=False)
        tets_i32 = np.ascontiguousarray(tets_i64, dtype=np.int32)
        tets_i32.setflags(write=False)
        volumes.setflags(write=False)
        self._points = points
        self._tets = tets_i32
        self._volumes = volumes

    # ------------------------------------------------------------------ construction helpers
    @classmethod
    def repaired(cls, points, tets) -> tuple[TetMesh, np.ndarray]:
        """Build a mesh after flipping negatively oriented tets and dropping orphan nodes.

        Degenerate (zero-volume) tets are still rejected: there is no sound way to repair them.

        Returns:
            ``(mesh, node_map)`` where ``node_map[old] = new`` index, or -1 for a dropped
            node; shape (N_in,), int64.
        """
        try:
            points = np.asarray(points, dtype=np.float64)
            tets = np.asarray(tets)
        except (TypeError, ValueError):
            raise ValueError("TetMesh points and tets must be regular numeric arrays") from None
        if tets.dtype.kind not in "iuf" or (
            tets.dtype.kind == "f" and not np.all(np.isfinite(tets) & (tets == np.round(tets)))
        ):
            raise ValueError(f"TetMesh tets must hold integer node indices, got dtype {tets.dtype}")
        tets = np.clip(tets, -1, 2**62).astype(np.int64) if tets.dtype.kind == "f" else tets.astype(np.int64)
        if tets.ndim != 2 or tets.shape[1] != 4:
            raise ValueError(f"TetMesh tets must have shape (M, 4), got {tets.shape}")
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"TetMesh points must have shape (N, 3), got {points.shape}")
        n = points.shape[0]
        if tets.size and (tets.min() < 0 or tets.max() >= n):
            t = np.flatnonzero(((tets < 0) | (tets >= n)).any(axis=1))[0]
            raise ValueError(f"TetMesh tet {t} has node index out of range [0, {n}): {tets[t].tolist()}")
        flip = tet_signed_volumes(points, tets) < 0.0
        tets[flip] = tets[flip][:, [0, 1, 3, 2]]
        used = np.zeros(n, dtype=bool)
        used[tets.ravel()] = True
        node_map = np.full(n, -1, dtype=np.int64)
        node_map[used] = np.arange(int(used.sum()))
        return cls(points[used], node_map[tets]), node_map

    # ------------------------------------------------------------------ basic data
    @property
    def points(self) -> np.ndarray:
        """Rest node positions [m], shape (N, 3), float64, read-only."""
        return self._points

    @property
    def tets(self) -> np.ndarray:
        """Node indices per tet, shape (M, 4), int32, positively oriented, read-only."""
        return self._tets

    @property
    def node_count(self) -> int:
        """Number of nodes N."""
        return self._points.shape[0]

    @property
    def tet_count(self) -> int:
        """Number of tets M."""
        return self._tets.shape[0]

    @property
    def volumes(self) -> np.ndarray:
        """Tet volumes [m^3], shape (M,), float64, all positive, read-only."""
        return self._volumes

    @property
    def total_volume(self) -> float:
        """Sum of tet volumes [m^3]."""
        return float(self._volumes.sum())

    @cached_property
    def nodal_volumes(self) -> np.ndarray:
        """Lumped volume per node (a quarter of each incident tet) [m^3], shape (N,), float64."""
        v = np.zeros(self.node_count)
        np.add.at(v, self._tets.ravel(), np.repeat(self._volumes / 4.0, 4))
        v.setflags(write=False)
        return v

    # ------------------------------------------------------------------ boundary
    @cached_property
    def boundary_faces(self) -> np.ndarray:
        """Faces on the mesh boundary, shape (F, 3), int32, wound so normals point outward."""
        faces = self._tets[:, _FACE_NODES].reshape(-1, 3)
        key = np.sort(faces, axis=1)
        _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        result = np.ascontiguousarray(faces[counts[inverse.ravel()] == 1], dtype=np.int32)
        result.setflags(write=False)
        return result

    @cached_property
    def surface_nodes(self) -> np.ndarray:
        """Sorted indices of the nodes on the boundary, shape (S,), int32."""
        result = np.unique(self.boundary_faces).astype(np.int32)
        result.setflags(write=False)
        return result

    @cached_property
    def interior_nodes(self) -> np.ndarray:
        """Sorted indices of the nodes not on the boundary, shape (N - S,), int32."""
        mask = np.ones(self.node_count, dtype=bool)
        mask[self.surface_nodes] = False
        result = np.flatnonzero(mask).astype(np.int32)
        result.setflags(write=False)
        return result

    @cached_property
    def edges(self) -> np.ndarray:
        """Unique undirected edges, shape (E, 2), int32, each row sorted ascending."""
        e = np.sort(self._tets[:, TET_EDGE_NODES].reshape(-1, 2), axis=1)
        result = np.unique(e, axis=0).astype(np.int32)
        result.setflags(write=False)
        return result

    # ------------------------------------------------------------------ quality
    def quality(self) -> TetQuality:
        """Dihedral-angle and volume statistics of the mesh."""
        angles = np.degrees(tet_dihedral_angles(self._points, self._tets))
        per_tet_min = angles.min(axis=1)
        return TetQuality(
            min_dihedral_deg=float(per_tet_min.min()),
            max_dihedral_deg=float(angles.max()),
            inverted_count=int(np.count_nonzero(self._volumes <= 0.0)),
            min_volume=float(self._volumes.min()),
            max_volume=float(self._volumes.max()),
            per_tet_min_dihedral_deg=per_tet_min,
        )

    def __repr__(self) -> str:
        return f"TetMesh(nodes={self.node_count}, tets={self.tet_count}, volume={self.total_volume:.4e} m^3)"
