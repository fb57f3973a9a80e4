"""The default rig's jaw (SPEC §6.2): a hinge between the temporomandibular joints and smooth skin weights.

Everything is placed from the 68 iBUG landmarks in the :class:`~warpface.assets.frame.FaceFrame`
(inter-ocular units), so the same construction fits any landmark-rigged face.

**Hinge.** The pivot lies on the midline between the ear-level jaw points (iBUG 0 and 16), 0.15 units
below and 0.20 behind them — the condyles sit just in front of and below the tragus, inside the head;
the axis is the frame's x axis (positive angles open the mouth), protrusion is the frame's z axis.

**Weights** ``w ∈ [0, 1]`` (docs/RIG.md §4). A *jaw line* in the face plane runs along the lips' contact
line (inner-lip landmarks 60–67) between the mouth corners and from each corner out to the jaw outline
at iBUG 4/12 (the mandible's body: the lower cheek follows it; the cheek above the line only partly,
through the ramp — a line up to iBUG 2/14 moved the whole lower cheek rigidly and cost 7 points of
jawOpen reach, docs/RIG.md). With ``φ`` the
height below that line, ``w = smoothstep((φ + a)/(a + b))`` (cubic, C¹): near the mouth ``a = b`` is
small, so the lips part along the contact line; beside it the ramp widens (``a`` = 0.30, ``b`` = 0.30)
over the cheeks. Where the mesh has a mouth opening, its rim is split at the corners into an upper and
a lower arc (a closed mouth's slit, :func:`slit_faces`, gives the lips' facing surfaces instead); with geodesic
distances ``d_u``, ``d_l`` to them, ``φ`` gains
``ε·(d_u − d_l)/(d_u + d_l + c)`` near the mouth, so each lip follows its own side of the opening
(the lower lip the jaw, the upper lip not) and the term fades to 0 at the corners, where both
distances agree. Last, below that line (and up to 0.10 above it) the weights diffuse over the mesh's edges
by ~0.05 units (:data:`_DIFFUSION`), so no triangle spans a change the chin's travel would fold it over.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from ..expression.fold_guard import equalized_weights, folded_triangles, unfolded_weights
from ..expression.jaw import Jaw
from ..geometry.ramps import smooth_ramp
from ..mesh import FaceMesh
from .frame import FaceFrame

__all__ = ["default_jaw", "jaw_weights", "lip_sided", "mouth_rim_arcs", "slit_faces", "SLIT_GAP"]

_ABOVE_RAMP = 0.30
"""Reach of the weight ramp above the jaw line [inter-ocular units]: upper lip and cheeks follow partly."""
_BELOW_RAMP = (0.12, 0.30)
"""Reach of the ramp below the jaw line at the mouth and beside it [inter-ocular units]."""
_NECK_RAMP = (0.02, 0.28)
"""Below the mandible's lower border (iBUG 4–12) the weight falls from 1 to 0 between these depths."""
_LIP_OFFSET = 0.20
"""ε: how far the lip-side term moves a lip off the contact line [inter-ocular units]."""
_CORNER_SOFTENING = 0.25
"""Added to ``d_u + d_l`` [inter-ocular units]: near a mouth corner, where both distances are small,
the lip-side term fades smoothly instead of flipping between neighbouring vertices."""
_LIP_REACH = (0.25, 0.55)
"""Geodesic distance from the mouth rim over which the lip-side term fades out [inter-ocular units]."""


_SLIT_BAND = 0.12
"""A closed mouth's slit is looked for within this height of the landmarks' contact line [inter-ocular units]."""
SLIT_GAP = 0.04
"""Facing lip surfaces closer than this [inter-ocular units] form the slit (2.5 mm at a 63 mm eye distance)."""
_SLIT_DETOUR = 3.0
"""Facing lip surfaces form a slit where the path over the surface is at least this many times their distance."""
_SLIT_FACING = 0.3
"""A lip surface faces down (up) where its unit normal's up component is below −0.3 (above 0.3)."""

_DIFFUSION = 0.05
"""Spread of the weights' final diffusion over the mesh [inter-ocular units]: the weight must not change by
more than the mesh can carry where the chin moves ~25 mm (a 2 mm triangle spanning 0.9 → 1 folded over in
jawOpen: 68 of the built-in face's 70 flipped triangles of all ARKit/FACS channels, 4 after)."""
_DIFFUSION_ABOVE = 0.10
"""The diffusion reaches this far above the jaw line [inter-ocular units]; higher, the upper lip and cheeks keep
their weights (diffusing everywhere lifted the upper lip's to 0.37)."""
_MAX_DIFFUSION_STEPS = 400
_FOLD_ANGLE = 0.35
"""The opening [rad] no triangle may fold at (the default mappings' full ``jawOpen``): docs/RIG.md §14."""
_GUARD_ABOVE = 0.12
"""The fold guard may change weights up to this far above the jaw line [inter-ocular units]: the mouth corners,
where the lips' weights meet, but not the upper lip's middle."""

_FOLD_SLIDE = 0.08
"""The protrusion and lateral slide [inter-ocular units] no triangle may fold at (the default mappings' full
``jawForward``, ``jawLeft``, ``jawRight``): docs/RIG.md §14."""

_HELD_LIPS = 0.5
"""The lips' facing vertices within this many of the mouth's half-widths from its centre keep the diffused weights
through the longer equalizing rounds: the lip seal's pairs lie there (its full turn,
:data:`~warpface.assets.lips.CORNER_BAND`), and the seal closes the lips against the jaw only while each lip's weight
there is one value (docs/RIG.md §14)."""
_LONG_ROUNDS = 2000
"""Most of the longer equalizing rounds, where the first stall; they do not stop for a stall: on whole heads the
count of folded triangles rises for hundreds of rounds while the equal weights spread, before it falls (a posed,
warped ICT head: 506 folded after 100 rounds, 68 after 400, 18 after 1,500; docs/RIG.md §14)."""

_PIVOT_OFFSET = (0.35, -0.65)
"""Hinge pivot relative to the ear-level jaw points (iBUG 0/16 midpoint), (up, out) [inter-ocular units]."""


def _jaw_line(local_landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Knots (x, y) of the jaw line, sorted by x, and the mouth half-width [inter-ocular units]."""
    L = local_landmarks[:, :2]
    contact = [L[60], 0.5 * (L[61] + L[67]), 0.5 * (L[62] + L[66]), 0.5 * (L[63] + L[65]), L[64]]
    knots = np.array([L[4], *contact, L[12]])
    far = np.array([[knots[0, 0] - 1.0, knots[0, 1]], [knots[-1, 0] + 1.0, knots[-1, 1]]])
    knots = np.concatenate([far[:1], knots, far[1:]])
    order = np.argsort(knots[:, 0])
    return knots[order, 0], knots[order, 1], 0.5 * abs(L[64, 0] - L[60, 0])


def mouth_rim_arcs(mesh: FaceMesh, local: np.ndarray, landmarks: np.ndarray):
    """The mouth opening's rim split at the corners into its (upper, lower) arcs of vertices, or None without one
    (``local``: the mesh's points in the face frame; ``landmarks``: the 68 iBUG vertex indices).

    Only the lips' own shell is searched: a whole head's mouth socket, gums or teeth are other shells whose rims
    lie in front of the mouth too (on the ICT head the socket's rim was taken for the lips', and the lips lost
    their slit, §12)."""
    local_landmarks = local[landmarks]
    open_edges = mesh.open_edges
    open_edges = open_edges[mesh.shells[open_edges[:, 0]] == mesh.shells[landmarks[60]]]
    centre = local_landmarks[60:68, :2].mean(axis=0)
    half_width = 0.5 * abs(local_landmarks[64, 0] - local_landmarks[60, 0])
    near = np.linalg.norm(local[open_edges, :2] - centre, axis=2).max(axis=1) < 1.3 * half_width
    rim_edges = open_edges[near]
    if len(rim_edges) < 6:
        return None
    rim = np.unique(rim_edges)
    corners = [rim[np.argmin(np.linalg.norm(local[rim, :2] - local_landmarks[i, :2], axis=1))] for i in (60, 64)]
    # Walk the rim from one corner to the other both ways round: the two arcs.
    neighbours: dict[int, list[int]] = {int(v): [] for v in rim}
    for a, b in rim_edges:
        neighbours[int(a)].append(int(b))
        neighbours[int(b)].append(int(a))
    arcs = []
    for first in neighbours[int(corners[0])][:2]:
        arc, previous, current = [int(corners[0])], int(corners[0]), first
        while current != int(corners[1]) and current not in arc and len(arc) <= len(rim):
            arc.append(current)
            following = [n for n in neighbours[current] if n != previous]
            if not following:
                break
            previous, current = current, following[0]
        arc.append(current)
        arcs.append(np.array(arc[1:-1]))
    if len(arcs) != 2 or min(len(a) for a in arcs) == 0:
        return None
    return tuple(sorted(arcs, key=lambda arc: -local[arc, 1].mean()))


def _edge_graph(mesh: FaceMesh, local: np.ndarray):
    """The mesh's edges as a sparse graph weighted by their length [inter-ocular units]; an edge of two triangles
    weighs twice its length (the duplicates add up; :data:`_CORNER_SOFTENING` and :data:`_LIP_REACH` were set so)."""
    edges = np.sort(mesh.triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    lengths = np.linalg.norm(local[edges[:, 0]] - local[edges[:, 1]], axis=1)
    return coo_matrix((lengths, (edges[:, 0], edges[:, 1])), shape=(mesh.vertex_count,) * 2).tocsr()


def slit_faces(mesh: FaceMesh, local: np.ndarray, landmarks: np.ndarray, up: np.ndarray):
    """A closed mouth's slit (docs/RIG.md §12): the lips' facing surfaces as (upper, lower) vertex arrays, or None.
    Used where the mesh has no mouth opening (a scan whose lips touch and whose surface turns into the mouth).

    Within :data:`_SLIT_BAND` of the landmarks' contact line and the mouth's width, a vertex is on its lip's side
    when it is nearer over the surface to that lip's outer landmarks (iBUG 49–53, 55–59) than to the other's; the
    upper lip's faces are those that face down (``n·up < −`` :data:`_SLIT_FACING`, ``up`` the face's unit up
    axis), the lower lip's those that face up. It is a slit when at least three faces have a face of the other lip
    within :data:`SLIT_GAP` that is at least :data:`_SLIT_DETOUR` times as far over the surface (the path runs
    round a corner); lips whose surfaces join along the contact line have none (None)."""
    local_landmarks = local[landmarks]
    knot_x, knot_y, half_width = _jaw_line(local_landmarks)
    below = np.interp(local[:, 0], knot_x, knot_y) - local[:, 1]
    band = (np.abs(local[:, 0] - local_landmarks[60:68, 0].mean()) < half_width) & (np.abs(below) < _SLIT_BAND)
    facing = np.asarray(mesh.vertex_normals(), dtype=np.float64) @ np.asarray(up, dtype=np.float64)
    graph = _edge_graph(mesh, local)
    to_upper = dijkstra(graph, directed=False, indices=landmarks[49:54], min_only=True)
    to_lower = dijkstra(graph, directed=False, indices=landmarks[55:60], min_only=True)
    upper = np.flatnonzero(band & (facing < -_SLIT_FACING) & (to_upper < to_lower))
    lower = np.flatnonzero(band & (facing > _SLIT_FACING) & (to_lower < to_upper))
    if len(upper) == 0 or len(lower) == 0:
        return None
    distance, nearest = cKDTree(local[lower]).query(local[upper])
    # the surface path between the two is at least the difference of their distances to the upper lip's landmarks
    detour = np.abs(to_upper[lower[nearest]] - to_upper[upper])
    if np.count_nonzero((distance < SLIT_GAP) & (detour > _SLIT_DETOUR * distance)) < 3:
        return None
    return upper, lower


def _lip_arcs(mesh: FaceMesh, local: np.ndarray, landmarks: np.ndarray, frame: FaceFrame):
    """The lips' facing vertices as (upper, lower) arrays: the mouth opening's rim arcs, or a closed mouth's slit
    faces; None with neither."""
    arcs = mouth_rim_arcs(mesh, local, landmarks)
    return arcs if arcs is not None else slit_faces(mesh, local, landmarks, frame.axes[1])


def _mouth_rim_side(mesh: FaceMesh, local: np.ndarray, arcs):
    """``(d_u − d_l)/(d_u + d_l + c)`` and the distance to the rim [inter-ocular units] from the lips' ``arcs``
    (:func:`_lip_arcs`), or None without them."""
    if arcs is None:
        return None
    upper, lower = arcs
    graph = _edge_graph(mesh, local)
    d_upper = dijkstra(graph, directed=False, indices=upper, min_only=True)
    d_lower = dijkstra(graph, directed=False, indices=lower, min_only=True)
    finite = np.isfinite(d_upper) & np.isfinite(d_lower) & (d_upper + d_lower > 0.0)
    side = np.zeros(mesh.vertex_count)
    side[finite] = (d_upper[finite] - d_lower[finite]) / (d_upper[finite] + d_lower[finite] + _CORNER_SOFTENING)
    reach = np.where(finite, np.minimum(d_upper, d_lower), np.inf)
    return side, reach


def lip_sided(mesh: FaceMesh, frame: FaceFrame, local: np.ndarray, landmarks: np.ndarray, below: np.ndarray):
    """``below`` (V,), a height below the lips' contact line [inter-ocular units], plus the lip-side term
    ``ε·(d_u − d_l)/(d_u + d_l + c)`` faded with the distance from the mouth's rim or slit (module docstring), so
    each lip lies on its own side of the line; unchanged without a mouth opening or slit. ``local``: the mesh's
    points in ``frame``; ``landmarks``: the 68 iBUG vertex indices."""
    return _sided_by(mesh, local, below, _lip_arcs(mesh, local, landmarks, frame))


def _sided_by(mesh: FaceMesh, local: np.ndarray, below: np.ndarray, arcs) -> np.ndarray:
    """:func:`lip_sided` from the lips' facing vertices ``arcs`` (:func:`_lip_arcs`; None: ``below`` unchanged)."""
    rim = _mouth_rim_side(mesh, local, arcs)
    if rim is None:
        return below
    side, reach = rim
    fade = 1.0 - smooth_ramp(_LIP_REACH[0], _LIP_REACH[1], reach)
    return below + _LIP_OFFSET * side * fade


def jaw_weights(mesh: FaceMesh, frame: FaceFrame, landmarks: np.ndarray) -> np.ndarray:
    """Per-vertex jaw weights of the default rig, shape (V,), in [0, 1] (module docstring)."""
    local = frame.to_local(mesh.points)
    local_landmarks = local[landmarks]
    knot_x, knot_y, half_width = _jaw_line(local_landmarks)
    below = np.interp(local[:, 0], knot_x, knot_y) - local[:, 1]
    mouth_x = local_landmarks[60:68, 0].mean()
    lateral = smooth_ramp(0.0, 1.0, (np.abs(local[:, 0] - mouth_x) - 0.55 * half_width) / (0.75 * half_width))
    above_ramp = _ABOVE_RAMP
    below_ramp = _BELOW_RAMP[0] + lateral * (_BELOW_RAMP[1] - _BELOW_RAMP[0])
    arcs = _lip_arcs(mesh, local, landmarks, frame)
    below = _sided_by(mesh, local, below, arcs)
    border = local_landmarks[4:13, :2]
    border = np.concatenate([[border[0] - (1.0, 0.0)], border, [border[-1] + (1.0, 0.0)]])
    under = np.interp(local[:, 0], border[:, 0], border[:, 1]) - local[:, 1]
    neck = 1.0 - smooth_ramp(_NECK_RAMP[0], _NECK_RAMP[1], under)
    weights = smooth_ramp(-above_ramp, below_ramp, below) * neck
    free = below > -_DIFFUSION_ABOVE
    weights = _diffused(mesh, weights, _DIFFUSION * frame.scale, free=free)
    # The weights diffuse further where the reference opening would still fold the skin (docs/RIG.md §14).
    pivot = _pivot(frame, local_landmarks)
    motion = (mesh.points - pivot) @ _rotation(frame.axes[0], _FOLD_ANGLE).T + pivot - mesh.points
    weights = unfolded_weights(mesh.points, mesh.triangles, weights, motion, free=below > -_GUARD_ABOVE)
    # What the diffusion leaves folded (slivers in the mouth corners) gets one weight on its corners, at the full
    # opening and the full slides; anywhere, as the triangles it touches are tiny (docs/RIG.md §14).
    slide = _FOLD_SLIDE * frame.scale
    slides = [motion] + [np.broadcast_to(d, motion.shape) for d in (slide * frame.axes[2], slide * frame.axes[0])]
    slides.append(-slides[-1])
    motions = np.stack(slides)
    equal = equalized_weights(mesh.points, mesh.triangles, weights, motions)
    folds = _fold_count(mesh, equal, motions)
    if folds == 0:
        return equal
    # Stalled rounds (a whole head, where the mouth socket and the neck join the mouth's corners and the jaw's
    # border) run on, longer, with the lips the seal reads held (docs/RIG.md §14); the fewer folds are kept.
    free = ~_held_lips(local, arcs, mouth_x, half_width)
    longer = equalized_weights(
        mesh.points, mesh.triangles, weights, motions, free=free, rounds=_LONG_ROUNDS, stall=_LONG_ROUNDS
    )
    return longer if _fold_count(mesh, longer, motions) < folds else equal


def _fold_count(mesh: FaceMesh, weights: np.ndarray, motions: np.ndarray) -> int:
    """How many triangles some ``x + w·motion`` of ``motions`` (M, V, 3) folds (margin as the equalizing rounds)."""
    folded = np.zeros(len(mesh.triangles), dtype=bool)
    for motion in motions:
        folded |= folded_triangles(mesh.points, mesh.triangles, mesh.points + weights[:, None] * motion)
    return int(folded.sum())


def _held_lips(local: np.ndarray, arcs, mouth_x: float, half_width: float) -> np.ndarray:
    """(V,) bool: the lips' facing vertices (``arcs``, :func:`_lip_arcs`) within :data:`_HELD_LIPS` half-widths
    (``half_width``) of the mouth's centre ``mouth_x`` [inter-ocular units], where the lip seal takes its pairs
    (docs/RIG.md §12, §14)."""
    held = np.zeros(len(local), dtype=bool)
    if arcs is None:
        return held
    facing = np.concatenate(arcs)
    held[facing[np.abs(local[facing, 0] - mouth_x) < _HELD_LIPS * half_width]] = True
    return held


def _pivot(frame: FaceFrame, local_landmarks: np.ndarray) -> np.ndarray:
    """The hinge's pivot in mesh coordinates (module docstring)."""
    ears = 0.5 * (local_landmarks[0] + local_landmarks[16])
    return frame.to_world([0.0, ears[1] + _PIVOT_OFFSET[0], ears[2] + _PIVOT_OFFSET[1]])


def _diffused(mesh: FaceMesh, values: np.ndarray, length: float, free: np.ndarray) -> np.ndarray:
    """``values`` diffused over the mesh's edges (steps of ``v ← ½v + ½·mean of the neighbours`` at the ``free``
    vertices; the others keep their value) to a spread of about ``length`` [mesh units]: as many steps as the
    mesh's mean edge needs, so the result does not depend on the resolution; edges follow the surface, so the
    lips stay apart across the mouth's opening."""
    edges = mesh.edges
    edge = float(np.linalg.norm(mesh.points[edges[:, 0]] - mesh.points[edges[:, 1]], axis=1).mean())
    steps = min(int(np.ceil(2.0 * (length / edge) ** 2)), _MAX_DIFFUSION_STEPS) if edge > 0.0 else 0
    count = mesh.vertex_count
    graph = coo_matrix((np.ones(2 * len(edges)), (edges.ravel(), edges[:, ::-1].ravel())), shape=(count, count))
    graph = graph.tocsr()
    degree = np.maximum(np.asarray(graph.sum(axis=1)).ravel(), 1.0)
    for _ in range(steps):
        values = np.where(free, 0.5 * values + 0.5 * (graph @ values) / degree, values)
    return np.clip(values, 0.0, 1.0)


def default_jaw(mesh: FaceMesh, frame: FaceFrame, landmarks: np.ndarray) -> Jaw:
    """The default rig's :class:`~warpface.expression.Jaw` on a face (module docstring)."""
    pivot = _pivot(frame, frame.to_local(mesh.points[landmarks]))
    weights = jaw_weights(mesh, frame, landmarks)
    return Jaw(pivot=pivot, axis=frame.axes[0], forward=frame.axes[2], weights=weights)


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """The 3 × 3 rotation by ``angle`` [rad] about the unit ``axis`` (Rodrigues)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)
