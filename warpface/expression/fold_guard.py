"""Rig-time guards against folded skin: a muscle's response, or a jaw weight, eased where it would fold a triangle.

Both act on rig-time data only (per-vertex fields and weights computed once per rig), so the frame kernels
and the solver's Jacobian are unchanged (docs/RIG.md §14):

- :func:`unfolded_response`: the skin's answer to a pull (sliding, bunching, thickening: docs/RIG.md §2–3)
  blended back toward the muscle's own zone field, per vertex, where it would turn a triangle over that
  the zone field alone keeps: ``w' = w₀ + g·(w − w₀)``, ``g ∈ [0, 1]``.
- :func:`unfolded_weights`: a scalar blend weight (the jaw's, SPEC §6.2) diffused over the mesh's edges
  around the triangles a reference motion would fold; :func:`equalized_weights` then makes it equal on the corners
  of each triangle still folded, and :func:`equalized_field` does the same with a muscle's field
  (:func:`ladder_equalized`: on a ladder of contractions up to its reference one).

A triangle *folds* under a displacement ``d`` when its deformed area vector keeps less than
:data:`FOLD_MARGIN` of its rest one along the rest normal: ``n₀·n(x + d) < m·|n₀|²`` (``m = 0`` is the flip).
"""

from __future__ import annotations

import hashlib

import numpy as np
from scipy.sparse import coo_matrix

from ..geometry.triangles import triangle_edges, vertex_triangles

__all__ = [
    "area_vectors",
    "FOLD_MARGIN",
    "FOLD_TRAVEL",
    "FACE_SPAN",
    "face_size",
    "equalized_field",
    "equalized_weights",
    "fold_blend",
    "ladder_equalized",
    "folded_triangles",
    "unfolded_response",
    "unfolded_weights",
    "corner_columns",
    "touching_triangles",
    "vertex_graph",
]

FOLD_MARGIN = 0.1
"""A triangle folds when its area along the rest normal falls below this fraction of the rest area."""
FOLD_TRAVEL = 0.05
"""The response is checked at the contraction that moves the field's farthest vertex by this fraction of the
face's size (:func:`face_size`; 14 mm on the built-in face; a full ARKit smile moves the cheek 11–12 mm)."""
FACE_SPAN = 6.0
"""The most eye-centre distances :func:`face_size` counts: a face mesh spans 4.6 (the built-in face) to 5.8 (the
ICT face region) along its bounding box's diagonal; a whole head, a bust or shoulders more (the ICT whole head 7.3,
the Lee Perry-Smith scan 10.4), which must not widen the tissue's reach on the same face (docs/RIG.md §14)."""


def face_size(points: np.ndarray, landmarks=None) -> float:
    """The length the tissue's fractions (:data:`FOLD_TRAVEL`, ``tissue.FASCIA_RADIUS``) refer to [mesh units]: the
    bounding-box diagonal of ``points`` (V, 3), at most :data:`FACE_SPAN` eye-centre distances when ``landmarks``
    (the 68 iBUG vertex indices) are given."""
    points = np.asarray(points, dtype=np.float64)
    diagonal = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0))) if len(points) else 0.0
    if landmarks is None or len(landmarks) != 68:
        return diagonal
    marks = points[np.asarray(landmarks, dtype=np.int64)]
    eyes = float(np.linalg.norm(marks[36:42].mean(axis=0) - marks[42:48].mean(axis=0)))
    return min(diagonal, FACE_SPAN * eyes) if eyes > 0.0 else diagonal


_GUARD_ROUNDS = 30
"""Most rounds of :func:`unfolded_response` (each eases the vertices of the triangles still folded)."""
_STALL_ROUNDS = 10
""":func:`unfolded_weights` stops when this many rounds have not lowered the count of folded triangles."""
_EQUAL_ROUNDS = 200
"""Most rounds of :func:`equalized_weights` (81 on the ICT face's jaw, 27 on the Lee Perry-Smith scan's)."""
LADDER_STEPS = 4
""":func:`ladder_equalized` checks a field at its reference contraction times 1/8, 1/4, 1/2 and 1."""
_EQUAL_STALL_ROUNDS = 40
""":func:`equalized_weights` stops when this many rounds have not lowered the count (an averaging round may raise it
for a while before the next lowers it)."""


def area_vectors(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Twice the area vectors (T, 3): ``(p₁ − p₀) × (p₂ − p₀)``, written out (the same products and differences as
    ``np.cross``, whose axis handling costs more than the arithmetic on the guards' small triangle sets)."""
    first, second, third = points[triangles[:, 0]], points[triangles[:, 1]], points[triangles[:, 2]]
    u, v = second - first, third - first
    return np.stack(
        [
            u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1],
            u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2],
            u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0],
        ],
        axis=1,
    )


def folded_triangles(points: np.ndarray, triangles: np.ndarray, moved: np.ndarray, margin: float = FOLD_MARGIN):
    """Per triangle, whether ``moved`` folds it against ``points`` (module docstring), shape (T,) bool; triangles of
    zero rest area never fold."""
    rest = area_vectors(points, triangles)
    area = np.einsum("ti,ti->t", rest, rest)
    along = np.einsum("ti,ti->t", area_vectors(moved, triangles), rest)
    return (area > 0.0) & (along < margin * area)


_TOPOLOGY: dict = {}
"""The last mesh's :func:`_topology`: a rig's guards ask for it once per muscle (the edge sort cost 0.1 s each)."""


def _topology(triangles: np.ndarray, count: int) -> tuple:
    """(edge adjacency CSR, degree per vertex ≥ 1, vertex → triangle offsets (V + 1,), triangle ids (3T,)) of a
    mesh; read-only (the last mesh's is reused)."""
    triangles = np.ascontiguousarray(triangles)
    key = (int(count), triangles.shape, triangles.dtype.str, hashlib.sha1(triangles.tobytes()).hexdigest())
    cached = _TOPOLOGY.get(key)
    if cached is None:  # a thread that clears the cache meanwhile costs the other one nothing but a rebuild
        edges = triangle_edges(triangles)[0]
        rows, columns = edges.ravel(), edges[:, ::-1].ravel()
        graph = coo_matrix((np.ones(len(rows)), (rows, columns)), shape=(count, count)).tocsr()
        cached = (graph, np.maximum(np.asarray(graph.sum(axis=1)).ravel(), 1.0), *vertex_triangles(triangles, count))
        _TOPOLOGY.clear()
        _TOPOLOGY[key] = cached
    return cached


def vertex_graph(triangles: np.ndarray, count: int):
    """(adjacency CSR over the mesh's edges, degree per vertex ≥ 1); read-only (the last mesh's is reused)."""
    return _topology(triangles, count)[:2]


def _triangles_of(vertices: np.ndarray, offsets: np.ndarray, triangle_ids: np.ndarray, marks: np.ndarray) -> np.ndarray:
    """The triangles with a corner among ``vertices`` (indices), sorted and unique (:func:`_topology`'s tables;
    ``marks``: an all-False (T,) bool scratch, :func:`_distinct`)."""
    starts, lengths = offsets[vertices], offsets[vertices + 1] - offsets[vertices]
    within = np.arange(int(lengths.sum())) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    return _distinct(triangle_ids[np.repeat(starts, lengths) + within], marks)


def _distinct(ids: np.ndarray, marks: np.ndarray) -> np.ndarray:
    """``np.unique(ids)`` of non-negative indices below ``len(marks)``, by marking them in ``marks``, an all-False bool
    scratch left all False again: one pass over the scratch instead of a sort, 2–4× faster at the guards' 100–5,000
    ids of a 30k-vertex head, the same sorted ids."""
    marks[ids] = True
    distinct = np.flatnonzero(marks)
    marks[distinct] = False
    return distinct


def _distinct_with_inverse(ids: np.ndarray, marks: np.ndarray, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(ids, return_inverse=True)`` (the inverse in ``ids``'s shape) through :func:`_distinct`; ``slots``:
    an int scratch as long as ``marks``."""
    distinct = _distinct(ids.ravel(), marks)
    slots[distinct] = np.arange(len(distinct))
    return distinct, slots[ids]


def unfolded_response(
    points: np.ndarray, triangles: np.ndarray, zone: np.ndarray, response: np.ndarray, travel: float
) -> np.ndarray:
    """``response`` (V, 3) eased toward ``zone`` (V, 3) where, at the contraction ``K = travel / max|response|``,
    it folds a triangle that ``zone`` does not: ``zone + g·(response − zone)`` with ``g`` from :func:`fold_blend`."""
    peak = float(np.linalg.norm(response, axis=1).max()) if len(response) else 0.0
    if peak <= 0.0 or travel <= 0.0:
        return response
    blend = fold_blend(points, triangles, zone, response, travel / peak)
    return zone + blend[:, None] * (response - zone)


def fold_blend(
    points: np.ndarray, triangles: np.ndarray, zone: np.ndarray, response: np.ndarray, contraction: float
) -> np.ndarray:
    """Per vertex, the blend ``g ∈ [0, 1]`` (V,) that keeps ``x + K·(zone + g·(response − zone))`` from folding the
    triangles ``x + K·zone`` keeps, at ``K = contraction``.

    Each round sets ``g`` to 0 on the vertices of the triangles still folded and their first ring, then smooths it
    once over the edges (``g ← min(g, mean of the neighbours + ½)``), so the response fades out over a ring
    instead of stopping at one edge; at most :data:`_GUARD_ROUNDS` rounds.
    """
    # a triangle whose corners neither field moves stays where it is: only the others can fold
    moving = _any_per_row(zone != 0.0) | _any_per_row(response != 0.0)
    near = triangles[touching_triangles(moving, corner_columns(triangles))]
    kept = ~folded_triangles(points, near, points + contraction * zone)
    graph, degree = vertex_graph(triangles, len(points))
    blend = np.ones(len(points))
    field = response
    for _ in range(_GUARD_ROUNDS):
        folded = kept & folded_triangles(points, near, points + contraction * field)
        if not folded.any():
            break
        eased = np.zeros(len(points), dtype=bool)
        eased[near[folded].ravel()] = True
        eased |= graph @ eased > 0
        blend[eased] = 0.0
        blend = np.minimum(blend, (graph @ blend) / degree + 0.5)
        field = zone + blend[:, None] * (response - zone)
    return blend


def unfolded_weights(
    points: np.ndarray,
    triangles: np.ndarray,
    weights: np.ndarray,
    motion: np.ndarray,
    *,
    free: np.ndarray | None = None,
    rounds: int = 100,
) -> np.ndarray:
    """Blend weights ``w`` (V,) of a motion ``x + w·motion`` ((V, 3) at a reference amplitude) diffused where that
    motion folds triangles: each round, the vertices of the folded triangles and their three rings take four steps of
    ``w ← ½w + ½·mean of the neighbours``, until none folds, ``rounds`` are done, or the count of folded triangles
    has not fallen for :data:`_STALL_ROUNDS` rounds (a fold the motion itself makes, at a mouth corner where the
    lips' weights meet). Only the ``free`` vertices (V,) bool (default: all) change. Returns values in [0, 1]."""
    graph, degree = vertex_graph(triangles, len(points))
    weights = np.asarray(weights, dtype=np.float64).copy()
    best, since, columns = len(triangles) + 1, 0, corner_columns(triangles)
    for _ in range(rounds):
        # a triangle whose corners all weigh 0 stays where it is: only the others can fold
        moving = np.flatnonzero(touching_triangles(weights != 0.0, columns))
        folded = np.zeros(len(triangles), dtype=bool)
        folded[moving] = folded_triangles(points, triangles[moving], points + weights[:, None] * motion)
        count = int(folded.sum())
        best, since = (count, 0) if count < best else (best, since + 1)
        if count == 0 or since > _STALL_ROUNDS:
            break
        region = np.zeros(len(points), dtype=bool)
        region[triangles[folded].ravel()] = True
        for _ring in range(3):
            region |= graph @ region > 0
        if free is not None:
            region &= free
        for _step in range(4):
            weights = np.where(region, 0.5 * weights + 0.5 * (graph @ weights) / degree, weights)
    return np.clip(weights, 0.0, 1.0)


def equalized_weights(
    points: np.ndarray,
    triangles: np.ndarray,
    weights: np.ndarray,
    motions: np.ndarray,
    *,
    free: np.ndarray | None = None,
    rounds: int = _EQUAL_ROUNDS,
    stall: int = _EQUAL_STALL_ROUNDS,
) -> np.ndarray:
    """Blend weights ``w`` (V,) of rigid displacements ``motions`` ((V, 3), or (M, V, 3) for several) made equal on
    the corners of every triangle that some ``x + w·motion`` folds (margin :data:`FOLD_MARGIN`): each round, every
    ``free`` vertex (V,) bool (default: all) of a folded triangle takes the mean, over the folded triangles it
    belongs to, of their corners' mean weight; until none folds, ``rounds`` are done, or the count of folded
    triangles has not fallen for ``stall`` rounds (a fold whose corners are not free); returns the weights of the
    round that folded fewest.

    Why it ends the folds the diffusion leaves (docs/RIG.md §14): with one weight ``w ∈ [0, 1]`` on its corners a
    triangle moves by the affine map ``(1 − w) I + w R`` (plus a translation) of a rigid motion ``R`` turning by
    less than a right angle, whose cofactor keeps every normal on its side, so it cannot fold; the folds sit on
    slivers at the mouth corners, where a weight change too small for the edge diffusion to notice spans the
    sliver's short side. Each round only averages existing weights, so the values stay in the input's range."""
    weights = np.asarray(weights, dtype=np.float64)
    motions = np.asarray(motions, dtype=np.float64)
    motions = motions[None] if motions.ndim == 2 else motions

    def moved(values: np.ndarray, motion: np.ndarray, at: np.ndarray) -> np.ndarray:
        return points[at] + values[at, None] * motion[at]

    return _equalized(points, triangles, weights, motions, moved, free, rounds, stall=stall)


def equalized_field(
    points: np.ndarray,
    triangles: np.ndarray,
    field: np.ndarray,
    contraction,
    *,
    margin: float = FOLD_MARGIN,
    free: np.ndarray | None = None,
    each: bool = False,
    rounds: int = _EQUAL_ROUNDS,
) -> np.ndarray:
    """A muscle's field ``w`` (V, 3) made equal on the corners of every triangle that ``x + K·w`` folds at
    ``K = contraction`` (a number, or a sequence of them that are all checked; ``margin``), as
    :func:`equalized_weights` does with weights: a triangle whose corners share one displacement only moves, so it
    cannot fold, at any ``K``. Only the ``free`` vertices change: (V,) bool, or (V, 3·n) per column of ``field``
    (default all). Several fields that act together, side by side as (V, 3·n), are checked by their sum (and, with
    ``each``, also each alone) and made equal on the same corners. Returns the shape of ``field``."""
    field = np.asarray(field, dtype=np.float64)
    scales = [float(k) for k in np.atleast_1d(np.asarray(contraction, dtype=np.float64))]
    parts = field.shape[1] // 3 if field.ndim == 2 else 1
    groups = [slice(None)] + ([slice(3 * i, 3 * i + 3) for i in range(parts)] if each and parts > 1 else [])
    motions = [(k, group) for k in scales for group in groups]

    def moved(values: np.ndarray, motion, at: np.ndarray) -> np.ndarray:
        scale, group = motion
        return points[at] + scale * values[at][:, group].reshape(len(at), -1, 3).sum(axis=1)

    return _equalized(points, triangles, field, motions, moved, free, rounds, margin)


def ladder_equalized(points: np.ndarray, triangles: np.ndarray, field: np.ndarray, contraction: float) -> np.ndarray:
    """:func:`equalized_field` of a muscle's field (V, 3) climbing to its reference contraction: at
    ``K = contraction · 2⁻ʲ``, ``j`` = :data:`LADDER_STEPS` − 1 … 0, each step also checking every step below it,
    taken while every step so far ends without a fold (the last one tried is taken when it leaves the steps below it
    unfolded). Where the reference contraction is more than the skin can carry without folding (a whole head's
    bounding box sets it: 34 mm on the Lee Perry-Smith scan), the field keeps the equal corners of the largest
    contraction that could be cleared, instead of the best of a stalled search at the top (docs/RIG.md §14)."""
    done: list[float] = []
    for step in range(LADDER_STEPS - 1, -1, -1):
        scales = [*done, contraction * 0.5**step]
        trial = equalized_field(points, triangles, field, scales)
        moving = _any_per_row(trial != 0.0)
        touched = triangles[touching_triangles(moving, corner_columns(triangles))]  # no other triangle moves
        left = [folded_triangles(points, touched, points + k * trial).any() for k in scales]
        if any(left[:-1]):
            break
        field, done = trial, scales
        if left[-1]:
            break
    return field


def _any_per_row(mask: np.ndarray) -> np.ndarray:
    """``mask.any(axis=1)`` of a (N, k) bool array, column by column (NumPy's row-wise reduce is slow for small k)."""
    rows = mask[:, 0].copy()
    for column in range(1, mask.shape[1]):
        rows |= mask[:, column]
    return rows


def corner_columns(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The triangles' (T, 3) three corner columns, each (T,) contiguous: what :func:`touching_triangles` reads."""
    return tuple(np.ascontiguousarray(triangles[:, k]) for k in range(3))


def touching_triangles(vertices: np.ndarray, columns: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """Per triangle (T,) bool: some corner is set in ``vertices`` (V,) bool; ``columns``: :func:`corner_columns`."""
    return vertices[columns[0]] | vertices[columns[1]] | vertices[columns[2]]


def _equalized(
    points, triangles, values, motions, moved, free, rounds, margin=FOLD_MARGIN, stall=_EQUAL_STALL_ROUNDS
) -> np.ndarray:
    """The rounds of :func:`equalized_weights` over per-vertex ``values`` (V,) or (V, k); ``moved(values, motion, at)``
    gives the moved points (len(at), 3) of the vertices ``at`` for each of ``motions``."""
    values = values.copy()
    count = len(points)
    # rest area vectors of the triangles asked about so far: a muscle's field touches a small part of a face
    rest, known = np.zeros((len(triangles), 3)), np.zeros(len(triangles), dtype=bool)
    # scratch of the distinct-index sets below (np.unique's results without its sort)
    vertex_marks, vertex_slots = np.zeros(count, dtype=bool), np.empty(count, dtype=np.intp)
    triangle_marks = np.zeros(len(triangles), dtype=bool)

    def folds(subset: np.ndarray) -> np.ndarray:
        """Whether some motion folds each triangle of ``subset`` (indices) at the current values."""
        if len(subset) == 0:
            return np.zeros(0, dtype=bool)
        missing = subset[~known[subset]]
        rest[missing], known[missing] = area_vectors(points, triangles[missing]), True
        before = rest[subset]
        area = np.einsum("ti,ti->t", before, before)
        corners, local = _distinct_with_inverse(triangles[subset], vertex_marks, vertex_slots)
        out = np.zeros(len(subset), dtype=bool)
        for motion in motions:
            turned = area_vectors(moved(values, motion, corners), local)
            out |= (area > 0.0) & (np.einsum("ti,ti->t", turned, before) < margin * area)
        return out

    # a triangle whose corners no field moves stays where it is under every motion: only the others can fold
    support = _any_per_row(values.reshape(count, -1) != 0.0)
    folded = np.zeros(len(triangles), dtype=bool)
    touched = np.flatnonzero(touching_triangles(support, corner_columns(triangles)))
    folded[touched] = folds(touched)
    offsets, triangle_ids = _topology(triangles, count)[2:]
    folded_count = int(folded.sum())
    best, since, kept = folded_count, 0, values.copy()
    for _ in range(rounds):
        if folded_count == 0 or since > stall:
            break
        corners = triangles[np.flatnonzero(folded)]
        means = np.repeat(values[corners].mean(axis=1), 3, axis=0)
        # per corner vertex, in the order the corners come (so the sums add up as they would over all vertices)
        hit, slot = _distinct_with_inverse(corners.ravel(), vertex_marks, vertex_slots)
        hits = np.bincount(slot)
        if values.ndim == 1:
            total = np.bincount(slot, means)
        else:
            total = np.stack([np.bincount(slot, means[:, k]) for k in range(values.shape[1])], axis=1)
        shape = (-1,) + (1,) * (values.ndim - 1)
        update = np.ones((len(hit),) + (1,) * (values.ndim - 1), dtype=bool)
        if free is not None:
            update = update & (free[hit] if free.ndim == values.ndim else free[hit].reshape(shape))
        values[hit] = np.where(update, total / hits.reshape(shape), values[hit])
        moved_vertices = hit[_any_per_row(update.reshape(len(hit), -1))]
        near = _triangles_of(moved_vertices, offsets, triangle_ids, triangle_marks)  # only these can have changed
        now = folds(near)
        folded_count += int(now.sum()) - int(folded[near].sum())
        folded[near] = now
        if folded_count < best:
            best, since, kept = folded_count, 0, values.copy()
        else:
            since += 1
    return kept
