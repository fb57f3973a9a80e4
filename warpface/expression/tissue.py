"""How the skin answers a muscle's pull: sliding on its tangent plane and bunching out of the face.

Both are rig-time, per-vertex and linear in the contraction (docs/RIG.md §2–3), so a muscle's field
stays ``d = K · w'(P)`` and the solver's Jacobian of the muscle stage is still exactly ``W``:

- **sliding** ``s ∈ [0, 1]``: ``w_s = (1 − s)·w + s·|w|·t̂`` with ``t̂`` the unit direction of the pull's
  tangential part ``w − (w·N) N`` and ``N`` the rest unit vertex normal averaged over
  :data:`FASCIA_RADIUS` (the fascia's normal): the skin glides along the surface toward the
  attachment by the full pull instead of sinking toward the bone beneath it. Skin glides
  over the fascia instead of sinking toward a bone attachment beneath it.
- **bunching** ``β ≥ 0``: ``w' = w_s − β · h · ρ(w_s) · N`` where ``ρ(w)`` is the first-order relative
  area change of the skin around a vertex under the field: ``Σ_t δA_t / Σ_t A_t`` over the incident
  triangles, ``δA_t = Σ_i ∂A_t/∂p_i · w_i`` with ``∂A/∂p_i = ½ n̂ × (p_{i+2} − p_{i+1})`` (the
  area-weighted form of §1.2's ``dr/dK``: a sliver triangle cannot dominate it). Compressed tissue
  (``ρ < 0``) moves out along ``N``, stretched tissue thins. ``ρ`` is averaged over
  :data:`FASCIA_RADIUS` and the height saturates at :data:`BUNCHING_CAP` times the muscle's
  largest pull (``c·tanh(b/c)``, still per unit K). It is the linearised §1.3 bulge
  ``(1/r − 1)·h ≈ −ρ·K·h`` of the muscle belly and fat pads, which the thin-sheet bulge under-states.
- **thickening** ``τ ≥ 0``: ``w' += τ · |w| · N``: a shortening muscle belly thickens (its volume is
  conserved), lifting the skin over it in proportion to the pull there.

Where the response would fold a triangle that the zone field alone keeps, it fades back to the zone field
(:func:`~warpface.expression.fold_guard.unfolded_response`, docs/RIG.md §14).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import warp as wp
from scipy.sparse import coo_matrix
from scipy.spatial import cKDTree

from .fold_guard import (
    FOLD_TRAVEL,
    corner_columns,
    equalized_field,
    face_size,
    ladder_equalized,
    touching_triangles,
    unfolded_response,
)
from .formulas import bunching_pull, sliding_pull, thickening_pull
from .muscles import Muscle, MuscleWeights

__all__ = [
    "tissue_response",
    "skin_muscle_weights",
    "unfolded_fields",
    "has_tissue_model",
    "stretch_rate",
    "neighbourhood_mean",
    "neighbourhood_averager",
    "FASCIA_RADIUS",
    "BUNCHING_CAP",
]

FASCIA_RADIUS = 0.03
"""Radius of the neighbourhood averages below, as a fraction of the face's size
(:func:`~warpface.expression.fold_guard.face_size`; 6 mm on a 20 cm face). Skin slides over the fascia beneath
it, whose surface is smoother than the skin's own curls (a lip rolling into the mouth, a lid margin); and the
area change of a sliver triangle at a mouth or eye corner must not raise a spike. Neighbourhoods are Euclidean,
so they reach across the lips' slit and the lid opening."""
BUNCHING_CAP = 0.5
_HINGE_FREE = 0.5
""":func:`unfolded_fields` changes a hinge's field only where it turns by at most half its largest angle (a taper
``1 − |θ|/max|θ| ≥`` this): the corners of the opening, not the margins that meet."""
"""Bunching saturates smoothly (``c·tanh(b/c)``) at this fraction of the muscle's largest pull."""


def neighbourhood_mean(points: np.ndarray, values: np.ndarray, radius: float) -> np.ndarray:
    """Gaussian-weighted mean (σ = radius/2) of per-vertex ``values`` (V, ...) over the points within ``radius``."""
    return neighbourhood_averager(points, radius)(values)


def neighbourhood_averager(points: np.ndarray, radius: float, counted: np.ndarray | None = None):
    """:func:`neighbourhood_mean` over ``points`` as a function of the values alone: the neighbour search
    and the weights are done once, for a rig's many averages (the same results, bit for bit).

    ``counted`` (V,) bool: the vertices whose values enter the means (default all). A vertex on no triangle — the
    copy of a vertex split along a seam, which the rig's welded triangles leave out — has no normal and no
    stretch of its own: left out, it gets the mean of its neighbours (its twin's) instead of diluting theirs."""
    tree = cKDTree(points)
    pairs = tree.query_pairs(radius, output_type="ndarray")
    sigma2 = (0.5 * radius) ** 2
    weight = np.exp(-np.sum((points[pairs[:, 0]] - points[pairs[:, 1]]) ** 2, axis=1) / (2.0 * sigma2))
    count = len(points)
    itself = np.ones(count)
    forward, backward = weight, weight
    if counted is not None and not np.all(counted):
        counted = np.asarray(counted, dtype=bool)
        forward, backward = weight * counted[pairs[:, 1]], weight * counted[pairs[:, 0]]
        itself = counted.astype(np.float64)
    matrix = coo_matrix(
        (
            np.concatenate([forward, backward, itself]),
            (
                np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(count)]),
                np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(count)]),
            ),
        ),
        shape=(count, count),
    ).tocsr()
    total = np.asarray(matrix.sum(axis=1)).ravel()[:, None]

    def mean(values: np.ndarray) -> np.ndarray:
        summed = matrix @ values.reshape(count, -1)
        return np.divide(summed, total, out=np.zeros_like(summed), where=total > 0.0).reshape(values.shape)

    return mean


def stretch_rate(points: np.ndarray, triangles: np.ndarray, field: np.ndarray) -> np.ndarray:
    """First-order relative area change around each vertex under displacements ``field`` (module docstring).

    Args:
        points: rest positions, shape (V, 3), float64.
        triangles: shape (T, 3), int.
        field: displacement per unit control, shape (V, 3) or (M, V, 3).

    Returns:
        ``Σ_t δA_t / Σ_t A_t`` per vertex, shape (V,) or (M, V); 0 where a vertex has no
        non-degenerate triangle.
    """
    field = np.asarray(field, dtype=np.float64)
    batched = field.ndim == 3
    fields = field if batched else field[None]
    corners = points[triangles]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    double_area = np.linalg.norm(normal, axis=1)
    counted = double_area > 1e-30 * max(1.0, float(np.abs(points).max()) ** 2)
    unit = np.zeros_like(normal)
    unit[counted] = normal[counted] / double_area[counted, None]
    change = np.zeros((len(fields), len(triangles)))
    for i in range(3):
        # ∂A/∂p_i = ½ n̂ × (p_{i+2} − p_{i+1}).
        gradient = 0.5 * np.cross(unit, corners[:, (i + 2) % 3] - corners[:, (i + 1) % 3])
        change += np.einsum("tk,mtk->mt", gradient, fields[:, triangles[:, i]])
    kept = triangles[counted]
    area = np.zeros(len(points))
    for i in range(3):
        np.add.at(area, kept[:, i], 0.5 * double_area[counted])
    total = np.zeros((len(fields), len(points)))
    for m in range(len(fields)):
        for i in range(3):
            total[m] += np.bincount(kept[:, i], weights=change[m, counted], minlength=len(points))
    result = np.divide(total, area, out=np.zeros_like(total), where=area > 0)
    return result if batched else result[0]


@wp.kernel
def _slide_and_thicken_kernel(
    field: wp.array(dtype=wp.vec3d),
    normals: wp.array(dtype=wp.vec3d),
    sliding: wp.float64,
    thickening: wp.float64,
    out: wp.array(dtype=wp.vec3d),
):
    i = wp.tid()
    w = field[i]
    pull = wp.length(w)
    if sliding > wp.float64(0.0):
        w = sliding_pull(w, normals[i], sliding)
    if thickening > wp.float64(0.0):
        w = thickening_pull(w, pull, normals[i], thickening)
    out[i] = w


@wp.kernel
def _bunch_kernel(
    field: wp.array(dtype=wp.vec3d),
    height: wp.array(dtype=wp.float64),
    cap: wp.float64,
    normals: wp.array(dtype=wp.vec3d),
    out: wp.array(dtype=wp.vec3d),
):
    i = wp.tid()
    out[i] = bunching_pull(field[i], height[i], cap, normals[i])


def _per_vertex(kernel, arrays: list, scalars: list, arrays_after: list = ()) -> np.ndarray:
    """``kernel`` over the vertices, float64 on the CPU (rig time): numpy (V, 3) / (V,) inputs in signature order."""
    wrap = {2: wp.vec3d, 1: wp.float64}
    device = "cpu"
    inputs = [wp.array(a, dtype=wrap[a.ndim], device=device) for a in arrays]
    inputs += [wp.float64(s) for s in scalars]
    inputs += [wp.array(a, dtype=wrap[a.ndim], device=device) for a in arrays_after]
    out = wp.empty(len(arrays[0]), dtype=wp.vec3d, device=device)
    wp.launch(kernel, dim=len(arrays[0]), inputs=inputs, outputs=[out], device=device)
    return out.numpy()


def tissue_response(
    points: np.ndarray,
    triangles: np.ndarray,
    normals: np.ndarray,
    thickness: np.ndarray,
    muscles: Sequence[Muscle],
    weights: MuscleWeights,
    *,
    size: float | None = None,
) -> MuscleWeights:
    """Muscle weights with each muscle's sliding and bunching applied (module docstring).

    Args:
        points: rest positions, shape (V, 3); triangles: shape (T, 3).
        normals: rest unit vertex normals, shape (V, 3).
        thickness: subcutaneous thickness h [mesh units], shape (V,).
        muscles: the muscles, in the column order of ``weights``.
        weights: the §1.1/§6.3 zone weights from :func:`~warpface.expression.muscle_weights`.
        size: the face's size [mesh units] (:func:`~warpface.expression.fold_guard.face_size`; default: the
            bounding-box diagonal of ``points``).

    Returns:
        New sparse weights (bunching reaches one ring of vertices beyond a zone).
    """
    points = np.asarray(points, dtype=np.float64)
    size = face_size(points) if size is None else float(size)
    radius, travel = FASCIA_RADIUS * size, FOLD_TRAVEL * size
    on_surface = np.bincount(np.asarray(triangles).ravel(), minlength=len(points)) > 0
    average = neighbourhood_averager(points, radius, on_surface)
    normals = average(np.asarray(normals, dtype=np.float64))
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.divide(normals, length, out=np.zeros_like(normals), where=length > 1e-12)
    vertex_count = len(points)
    row = np.repeat(np.arange(vertex_count), np.diff(weights.offsets))

    def responded(index: int, muscle: Muscle) -> np.ndarray:
        mine = weights.muscle == index
        field = np.zeros((vertex_count, 3))
        field[row[mine]] = weights.weight[mine]
        zone = field
        if muscle.sliding > 0.0 or muscle.thickening > 0.0:
            # Sliding removes the pull's normal part: the skin glides on the fascia. Carrying the full pull
            # along the surface instead folded the skin wherever the fascia turns steeply under a
            # pull (nose side, inner canthus, cheek sides; docs/RIG.md §2).
            field = _per_vertex(_slide_and_thicken_kernel, [field, normals], [muscle.sliding, muscle.thickening])
        if muscle.bunching > 0.0:
            height = -muscle.bunching * thickness * average(stretch_rate(points, triangles, field))
            cap = BUNCHING_CAP * float(np.linalg.norm(field, axis=1).max())
            if cap > 0.0:
                field = _per_vertex(_bunch_kernel, [field, height], [cap], [normals])
        return field if field is zone else unfolded_response(points, triangles, zone, field, travel)

    return MuscleWeights.from_fields(vertex_count, (responded(i, m) for i, m in enumerate(muscles)))


def skin_muscle_weights(
    mesh, muscles: Sequence[Muscle], thickness: np.ndarray, *, device=None, size: float | None = None
) -> MuscleWeights:
    """The weights the expression model applies: zone weights, each muscle's sliding and bunching, then the lips'
    seal (:mod:`~warpface.expression.seal`) when the muscles hold one.

    Args:
        mesh: the rest :class:`~warpface.FaceMesh`; muscles: in contraction order;
        thickness: h per vertex [mesh units], shape (V,); device: Warp device of the weight kernels;
        size: the face's size [mesh units] (:func:`~warpface.expression.fold_guard.face_size`; default: the mesh's
            bounding-box diagonal).
    """
    from .muscles import muscle_weights
    from .seal import sealed_weights

    weights = muscle_weights(mesh.points, list(muscles), device=device)
    if any(m.sliding > 0.0 or m.bunching > 0.0 or m.thickening > 0.0 for m in muscles):
        normals = mesh.vertex_normals(device=device)
        weights = tissue_response(
            mesh.points, mesh.triangles, normals, np.asarray(thickness, dtype=np.float64), muscles, weights, size=size
        )
    if has_tissue_model(muscles):  # a rig of the paper's §1.1 muscles alone evaluates SPEC §1 unchanged
        weights = unfolded_fields(mesh, list(muscles), weights, size=size)
    return sealed_weights(list(muscles), weights)


def has_tissue_model(muscles: Sequence[Muscle]) -> bool:
    """Whether a rig has more than the paper's model: a muscle with a skin response (§2–3 of docs/RIG.md) or a lid
    hinge / lip seal (§11–12). Only such rigs get the fold guards that change the muscles' fields and the lifts
    (docs/RIG.md §14); the others evaluate SPEC §1 as written."""
    from .lids import LidMuscle

    return any(m.sliding > 0.0 or m.bunching > 0.0 or m.thickening > 0.0 or isinstance(m, LidMuscle) for m in muscles)


def _pair_free(count: int, a, b) -> np.ndarray:
    """Where two hinges' fields may be made equal, per column of the pair (V, 6): the hinge that turns farther (an
    upper lid) wherever its own taper is at least :data:`_HINGE_FREE`, the other only where both tapers are. So the
    upper lid's motion may spread onto the lower margin at the corners of the eye, where the two lids' triangles meet,
    but no margin takes the lower lid's motion (docs/RIG.md §14)."""
    from .lids import hinge_taper

    taper_a, taper_b = hinge_taper(count, [a]), hinge_taper(count, [b])
    both = (taper_a >= _HINGE_FREE) & (taper_b >= _HINGE_FREE)
    lead_a = np.abs(a.angles).max(initial=0.0) >= np.abs(b.angles).max(initial=0.0)
    free_a = taper_a >= _HINGE_FREE if lead_a else both
    free_b = both if lead_a else taper_b >= _HINGE_FREE
    return np.repeat(np.stack([free_a, free_b], axis=1), 3, axis=1)


def unfolded_fields(
    mesh, muscles: Sequence[Muscle], weights: MuscleWeights, *, size: float | None = None
) -> MuscleWeights:
    """Each muscle's field made equal on the corners of the triangles it folds at its reference contraction
    (:func:`~warpface.expression.fold_guard.equalized_field`; docs/RIG.md §14): ``K = 1`` for a lid hinge or the
    lips' seal (their ``K`` ends at 1; only flips count), else on a ladder up to the ``K`` that moves the field's
    farthest vertex by :data:`~warpface.expression.fold_guard.FOLD_TRAVEL` of the face's ``size`` (default: the mesh's
    bounding-box diagonal)
    (:func:`~warpface.expression.fold_guard.ladder_equalized`); then every two hinges whose fields meet on a
    triangle, both at ``K = 1``, each alone and together, on the free vertices of :func:`_pair_free`."""
    from .lids import LidMuscle, hinge_taper

    points = np.asarray(mesh.points, dtype=np.float64)
    triangles = mesh.triangles[~mesh.degenerate_triangles]
    travel = FOLD_TRAVEL * (face_size(points) if size is None else float(size))
    row = np.repeat(np.arange(len(points)), np.diff(weights.offsets))
    fields, changed = [], False
    for index, muscle in enumerate(muscles):
        mine = weights.muscle == index
        field = np.zeros((len(points), 3))
        field[row[mine]] = weights.weight[mine]
        peak = float(np.linalg.norm(field, axis=1).max()) if len(field) else 0.0
        if peak > 0.0:
            if isinstance(muscle, LidMuscle):
                # A hinge squeezes a surface across the opening (a scan's closed eye) to a sliver by design, and
                # its margins must meet (§11): only its flips count, and the half that turns most keeps its field.
                free = hinge_taper(len(points), [muscle]) >= _HINGE_FREE
                equal = equalized_field(points, triangles, field, 1.0, margin=0.0, free=free)
            else:
                equal = ladder_equalized(points, triangles, field, travel / peak)
            changed |= not np.array_equal(equal, field)
            field = equal
        fields.append(field)
    # Two hinges of one eye close it together (a blink): a triangle between their fields can fold under both.
    hinges = [i for i, m in enumerate(muscles) if isinstance(m, LidMuscle)]
    columns = corner_columns(triangles)
    moving = {i: touching_triangles(np.any(fields[i] != 0.0, axis=1), columns) for i in hinges}
    for a, b in ((a, b) for a in hinges for b in hinges if a < b):
        if not np.any(moving[a] & moving[b]):
            continue
        free = _pair_free(len(points), muscles[a], muscles[b])
        pair = np.concatenate([fields[a], fields[b]], axis=1)
        equal = equalized_field(points, triangles, pair, 1.0, margin=0.0, free=free, each=True)
        if not np.array_equal(equal, pair):
            fields[a], fields[b], changed = equal[:, :3], equal[:, 3:], True
    return MuscleWeights.from_fields(len(points), fields) if changed else weights
