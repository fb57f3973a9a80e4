"""Rig-time guards on the lifts along the normal: the bulge's ``h`` and the wrinkles' profiles, faded where a
control's full pull would make them fold skin.

The bulge (SPEC §1.3) lifts each vertex by ``(1/r − 1)·h`` along the deformed normal, the wrinkles (§1.4) by
``Σ k_d·s·C(r)``. Where a control squeezes the
skin hard (under the chin in jawOpen, ``r`` ≈ 0.25: lifts of 5–8 mm over 3 mm triangles on the ICT face) and the
surface is curved, neighbouring lifts differ by more than the triangles can carry and turn them over, though the
muscle stage folds none; the wrinkles do the same in the sharp inner corners of the eyes and mouth.
:func:`unfolded_thickness` replays each control's linear stage alone at a reference amplitude (docs/RIG.md §14)
and fades ``h`` there; :func:`unfolded_profiles` then fades the wrinkle profiles where the wrinkles fold what the
bulge keeps. The result is rig-time data (the ``h`` array the frame kernels and
the solver read), so the kernels and the solver's Jacobian are unchanged.
"""

from __future__ import annotations

import numpy as np

from .fold_guard import FOLD_TRAVEL, area_vectors, face_size, folded_triangles, vertex_graph

__all__ = [
    "JAW_FOLD_ANGLE",
    "bulge_points",
    "guarded_lifts",
    "reference_motions",
    "unfolded_profiles",
    "unfolded_thickness",
    "wrinkle_heights",
]

JAW_FOLD_ANGLE = 0.35
"""The jaw opening [rad] no triangle may fold at (the default mappings' full ``jawOpen``): docs/RIG.md §14."""
_ROUNDS = 30
"""Most rounds of :func:`unfolded_thickness`."""
_FADE_STEP = 0.25
"""Most rise of the fade per ring of edges away from a fold: ``h`` comes back over four rings, not in one step."""


def _stretch_and_normals(points: np.ndarray, triangles: np.ndarray, moved: np.ndarray):
    """SPEC §1.2 in float64: ``r`` (V,), the mean area ratio of the incident triangles (1 without any), and
    ``N`` (V, 3), the unit sum of their area vectors (0 where it vanishes)."""
    rest_area = np.linalg.norm(area_vectors(points, triangles), axis=1)
    area = area_vectors(moved, triangles)
    ratio = np.linalg.norm(area, axis=1) / rest_area
    corners = triangles.ravel()
    count = np.bincount(corners, minlength=len(points))
    total = np.bincount(corners, np.repeat(ratio, 3), minlength=len(points))
    r = np.where(count > 0, total / np.maximum(count, 1), 1.0)
    normal = np.stack([np.bincount(corners, np.repeat(area[:, k], 3), minlength=len(points)) for k in range(3)], 1)
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    return r, np.divide(normal, length, out=np.zeros_like(normal), where=length > 0.0)


def bulge_points(points: np.ndarray, triangles: np.ndarray, moved: np.ndarray, thickness: np.ndarray) -> np.ndarray:
    """SPEC §1.3 in float64 on the host: ``moved + (1/r − 1)·h·N(moved)`` (:func:`_stretch_and_normals`, ``r``
    floored at 1e-4 as the kernels do); ``points`` the rest (V, 3), ``triangles`` (T, 3) without degenerate ones,
    ``thickness`` (V,). Returns (V, 3)."""
    r, normal = _stretch_and_normals(points, triangles, moved)
    return moved + ((1.0 / np.maximum(r, 1.0e-4) - 1.0) * thickness)[:, None] * normal


def reference_motions(points: np.ndarray, fields, hinged, jaw=None, size: float | None = None) -> list[np.ndarray]:
    """Each control's linear-stage displacement (V, 3) at its reference amplitude: a muscle field ``fields[i]``
    (V, 3) at ``K = 1`` when ``hinged[i]`` (a lid hinge or lip seal, whose ``K`` ends at 1), else at the ``K``
    that moves its farthest vertex by :data:`FOLD_TRAVEL` of the face's ``size`` (as the response guard; default:
    the bounding-box diagonal);
    then the jaw (``Jaw``: pivot, axis, weights) opened by :data:`JAW_FOLD_ANGLE`."""
    travel = FOLD_TRAVEL * (face_size(points) if size is None else float(size))
    motions = []
    for field, hinge in zip(fields, hinged):
        peak = float(np.linalg.norm(field, axis=1).max()) if len(field) else 0.0
        if peak > 0.0:
            motions.append(field if hinge else field * (travel / peak))
    if jaw is not None:
        axis = np.asarray(jaw.axis, dtype=np.float64)
        k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
        turn = np.eye(3) + np.sin(JAW_FOLD_ANGLE) * k + (1.0 - np.cos(JAW_FOLD_ANGLE)) * (k @ k)
        offset = points - np.asarray(jaw.pivot, dtype=np.float64)
        motions.append(np.asarray(jaw.weights, dtype=np.float64)[:, None] * (offset @ turn.T - offset))
    return motions


def _faded(triangles: np.ndarray, count: int, motions, lifted, rounds: int) -> np.ndarray:
    """The fade ``g`` (V,) of :func:`unfolded_thickness` / :func:`unfolded_profiles`: ``lifted(i, g)`` gives the
    triangles (k, 3) that motion ``i`` folds at fade ``g`` and its stage before the lift keeps."""
    graph = vertex_graph(triangles, count)[0]
    fade = np.ones(count)
    everything = list(range(len(motions)))
    active = everything
    for round_ in range(rounds):
        folded, still = [], []
        for i in active if round_ < rounds - 1 else everything:
            hit = lifted(i, fade)
            if len(hit):
                folded.append(hit)
                still.append(i)
        if not folded:
            if active is everything:
                break
            active = everything  # a last check of every motion
            continue
        active = still
        fade[np.unique(np.concatenate(folded))] = 0.0
        fade = _limited_rise(graph, fade)
    return fade


def _supports(triangles: np.ndarray, count: int, moved) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per motion, (the triangles (C, 3) the stages need, a mask (C,) of those whose fold a lift can change).

    Only vertices within two rings of a moved vertex lift differently from rest (their stretch, or a neighbour's,
    changed); every triangle with a corner there is checked, and every triangle within three rings is needed to
    compute their stretch and normals exactly."""
    graph = vertex_graph(triangles, count)[0]
    out = []
    for motion in moved:
        ring = np.linalg.norm(motion, axis=1) > 0.0
        rings = [ring]
        for _ in range(3):
            rings.append(rings[-1] | (graph @ rings[-1].astype(np.float64) > 0.0))
        needed = triangles[rings[3][triangles].any(axis=1)]
        out.append((needed, rings[2][needed].any(axis=1)))
    return out


def unfolded_thickness(
    points: np.ndarray, triangles: np.ndarray, thickness: np.ndarray, motions, *, rounds: int = _ROUNDS
) -> np.ndarray:
    """``thickness`` (V,) times a fade ``g ∈ [0, 1]`` so that no ``motion`` of ``motions`` (each (V, 3), a linear
    stage's displacement) folds, after the bulge (:func:`bulge_points`), a triangle its linear stage keeps
    (margin :data:`~warpface.expression.fold_guard.FOLD_MARGIN`; ``triangles`` without degenerate ones).

    Each round sets ``g`` to 0 on the corners of the triangles still folded, then lets it rise by at most
    :data:`_FADE_STEP` per ring (``g ← min(g, min of the neighbours + step)``, repeated until it holds); the
    motions that folded nothing last round are not checked again until the last. ≤ ``rounds`` rounds."""
    points = np.asarray(points, dtype=np.float64)
    thickness = np.asarray(thickness, dtype=np.float64)
    motions = [np.asarray(m, dtype=np.float64) for m in motions]
    if not motions or not np.any(thickness > 0.0):
        return thickness
    supports = _supports(triangles, len(points), motions)
    moved = [points + m for m in motions]
    kept = [checked & ~folded_triangles(points, near, x) for (near, checked), x in zip(supports, moved)]

    def lifted(i: int, fade: np.ndarray) -> np.ndarray:
        near = supports[i][0]
        bulged = bulge_points(points, near, moved[i], fade * thickness)
        return near[kept[i] & folded_triangles(points, near, bulged)]

    return thickness * _faded(triangles, len(points), moved, lifted, rounds)


def wrinkle_heights(
    points: np.ndarray, triangles: np.ndarray, moved: np.ndarray, bulged: np.ndarray, offsets, wrinkle, shape, depth, kr
) -> tuple[np.ndarray, np.ndarray]:
    """(``Σ_k depth[wrinkle[k]]·shape[k]·C(r; kr[wrinkle[k]])`` per vertex (V,), ``N(bulged)`` (V, 3)): the wrinkles'
    heights (SPEC §1.4, C of eq. 5) at the stretch ``r`` of the muscle stage ``moved`` against ``points`` and the
    bulge's normals, as the frame kernels take them; profiles as vertex-major CSR."""
    r = _stretch_and_normals(points, triangles, moved)[0]
    normal = _stretch_and_normals(points, triangles, bulged)[1]
    vertex = np.repeat(np.arange(len(points)), np.diff(np.asarray(offsets)))
    rate = np.where(kr > 0.0, 1.0 - 1.0 / np.where(kr > 0.0, kr, 1.0), 0.0)
    k, x = np.asarray(kr)[wrinkle], r[vertex]
    factor = np.where(x <= 1.0, (k - 1.0) * x + 1.0, k * np.exp(rate[wrinkle] * (x - 1.0)))
    term = np.asarray(depth)[wrinkle] * np.asarray(shape, dtype=np.float64) * factor
    return np.bincount(vertex, term, minlength=len(points)), normal


def unfolded_profiles(
    points: np.ndarray, triangles: np.ndarray, thickness: np.ndarray, motions, profiles, *, rounds: int = _ROUNDS
) -> np.ndarray:
    """A fade ``g`` (V,) for every wrinkle profile at each vertex, so that no motion of ``motions`` (as in
    :func:`unfolded_thickness`, with the bulge of ``thickness``) folds, once the wrinkles lift it by ``g``
    times their :func:`wrinkle_heights` (``profiles``: its ``offsets, wrinkle, shape, depth, kr``), a
    triangle its bulge keeps."""
    points = np.asarray(points, dtype=np.float64)
    moved = [points + np.asarray(m, dtype=np.float64) for m in motions]
    supports = _supports(triangles, len(points), [x - points for x in moved])
    bulged = [bulge_points(points, near, x, thickness) for (near, _), x in zip(supports, moved)]
    kept = [checked & ~folded_triangles(points, near, x) for (near, checked), x in zip(supports, bulged)]
    lifts = [wrinkle_heights(points, near, x, b, *profiles) for (near, _), x, b in zip(supports, moved, bulged)]

    def lifted(i: int, fade: np.ndarray) -> np.ndarray:
        near = supports[i][0]
        height, normal = lifts[i]
        return near[kept[i] & folded_triangles(points, near, bulged[i] + (fade * height)[:, None] * normal)]

    return _faded(triangles, len(points), bulged, lifted, rounds)


def _limited_rise(graph, fade: np.ndarray) -> np.ndarray:
    """``fade`` lowered until no vertex exceeds its lowest neighbour by more than :data:`_FADE_STEP`."""
    indptr, indices = graph.indptr, graph.indices
    has = np.diff(indptr) > 0
    while True:
        lowest = np.full(len(fade), np.inf)
        lowest[has] = np.minimum.reduceat(fade[indices], indptr[:-1][has])
        limited = np.minimum(fade, lowest + _FADE_STEP)
        if np.array_equal(limited, fade):
            return fade
        fade = limited


def guarded_lifts(mesh, thickness: np.ndarray, muscles, weights, wrinkles, shapes, jaw=None, size: float | None = None):
    """(the bulge's ``h`` (V,), the wrinkle profiles ``shapes.shape`` faded) of a rig after
    :func:`unfolded_thickness` and :func:`unfolded_profiles`, from its mesh (a ``FaceMesh``), muscles, their skin
    weights (``tissue.skin_muscle_weights``: per-vertex entries ``offsets``, ``muscle``, ``weight``), wrinkles,
    their profiles (``wrinkles.skin_wrinkle_shapes``), optional jaw and the face's ``size``
    (:func:`~warpface.expression.fold_guard.face_size`): what the model and the solver both read.

    A rig of the paper's model alone (§1.1 muscles without a skin response, no hinges, no jaw) is left as SPEC §1
    has it: ``(thickness, shapes.shape)`` unchanged."""
    from .lids import LidMuscle
    from .tissue import has_tissue_model

    if jaw is None and not has_tissue_model(muscles):
        return np.asarray(thickness, dtype=np.float64), np.asarray(shapes.shape)
    points = np.asarray(mesh.points, dtype=np.float64)
    fields = np.zeros((len(muscles), len(points), 3))
    vertex = np.repeat(np.arange(len(points)), np.diff(np.asarray(weights.offsets)))
    fields[np.asarray(weights.muscle, dtype=np.int64), vertex] = np.asarray(weights.weight, np.float64).reshape(-1, 3)
    motions = reference_motions(points, fields, [isinstance(m, LidMuscle) for m in muscles], jaw, size)
    triangles = mesh.triangles[~mesh.degenerate_triangles]
    thickness = unfolded_thickness(points, triangles, thickness, motions)
    shape = np.asarray(shapes.shape, dtype=np.float64)
    if not len(shape):
        return thickness, shape
    depth = np.array([w.depth for w in wrinkles], dtype=np.float64)
    kr = np.array([w.kr for w in wrinkles], dtype=np.float64)
    wrinkle = np.asarray(shapes.wrinkle, dtype=np.int64)
    fade = unfolded_profiles(points, triangles, thickness, motions, (shapes.offsets, wrinkle, shape, depth, kr))
    return thickness, shape * fade[np.repeat(np.arange(len(points)), np.diff(np.asarray(shapes.offsets)))]
