"""68 iBUG landmarks on any head mesh: the built-in face registered onto the skin, its landmarks carried over.

Pipeline (docs/RIG.md, "Automatic landmarks"): split shells and keep the skin
(:class:`~warpface.rigging.surface.HeadSurface`); find the symmetry plane, up, front and scale with a
similarity fit of the template (:mod:`~warpface.rigging.align`; on a low-poly skin with its edges' midpoints too,
points past a face-only mesh's outline charged little); move the template's nose and mouth to the heights the
skin's mid-line profile gives (:mod:`~warpface.rigging.profile`); deform the template onto the skin
with non-rigid ICP (:mod:`~warpface.rigging.nonrigid`), four times: each time after the first from the head's
proportions as the previous fit's feature landmarks give them (:func:`affine_from_features`, :data:`PASSES`);
move the mouth onto the ends of a closed mouth's lip contact where it has one (:mod:`~warpface.rigging.lip_contact`)
and the eyes onto the outline of an open eye's socket, the brows with them (:mod:`~warpface.rigging.eye_opening`);
give every template landmark the nearest skin vertex that faces the same way (an eye landmark carried off the skin:
the one across its normal, :func:`snap_to_skin`); refuse landmarks not laid out as a face's
(:func:`~warpface.landmarks.check_layout`; after a start moved to the profile, once the template as it is has
given none either). The unit follows from the fitted eye distance
(:mod:`~warpface.rigging.units`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..errors import RigError
from ..landmarks import check_layout
from .align import Affine, Similarity, fit_affine, fit_similarity
from .eye_opening import eye_openings
from .lip_contact import mouth_contact
from .nonrigid import NonRigidFit, SkinTarget, fit_nonrigid
from .profile import profiled
from .surface import HeadSurface
from .template import Template, template
from .units import infer_units, parse_axis, parse_units

__all__ = [
    "LandmarkFit",
    "Registration",
    "find_landmarks",
    "register",
    "snap_to_skin",
    "affine_from_features",
    "CONFIDENCE_DISTANCE",
]

CONFIDENCE_DISTANCE = 0.05
"""Distance from a carried-over landmark to its skin vertex at which confidence falls to 1/e
[inter-ocular units, ~3 mm]."""
MAX_RESIDUAL = 0.12
"""A similarity fit leaving the template farther than this from the skin [inter-ocular units] finds no face."""
MAX_ASYMMETRY = 0.08
"""A skin whose best mirror plane leaves more than this (relative to its size) is not a face."""
SNAP_CANDIDATES = 32
"""Nearest skin vertices considered for a landmark (:func:`snap_to_skin`)."""
OFF_SKIN = 0.03
"""A carried point farther than this from every skin vertex [inter-ocular units] is off the skin."""
SNAPPED_ACROSS = np.arange(36, 48)
"""The eye landmarks (iBUG 36–47): snapped to the vertex nearest the line along their normal (docs/RIG.md §9)."""


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
    """The head's up direction in mesh coordinates (unit vector)."""
    front: np.ndarray
    """The direction the head looks in mesh coordinates (unit vector)."""
    left: np.ndarray
    """Toward the subject's left in mesh coordinates (unit vector)."""
    eye_distance: float
    """Fitted inter-ocular distance [mesh units]."""
    residual: float
    """Mean distance of the registered template to the skin [inter-ocular units]."""
    shells: int
    """Connected shells in the mesh (the skin and e.g. eyes, teeth)."""
    inside_out: bool
    """The skin's faces are wound so that their normals point into the head."""
    seconds: float


def snap_to_skin(
    points: np.ndarray, normals: np.ndarray, skin: SkinTarget, across: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Each point's skin vertex among its :data:`SNAP_CANDIDATES` nearest that face the point's normal: the nearest
    one, or where ``across`` (N,) bool is set, the one nearest to the line through the point along its normal.
    Returns (skin indices, distances to the points).

    A carried lid point sits a few mm behind the lid's thin margin; the nearest vertex in space can then be on the
    cheek below, while the one across from the point along its normal is the lid's (docs/RIG.md §9, step 6)."""
    count = min(SNAP_CANDIDATES, len(skin.points))
    distance, index = skin.tree.query(points, k=count)
    distance, index = distance.reshape(len(points), count), index.reshape(len(points), count)
    facing = np.einsum("ij,ikj->ik", normals, skin.normals[index]) > 0.0
    offsets = skin.points[index] - points[:, None, :]
    along = np.einsum("ikj,ij->ik", offsets, normals)
    off_line = np.linalg.norm(offsets - along[..., None] * normals[:, None, :], axis=2)
    marked = np.zeros(len(points), bool) if across is None else np.asarray(across, bool)
    use_line = marked & (distance[:, 0] > OFF_SKIN)  # a new array: the caller's ``across`` is left as given
    score = np.where(facing, np.where(use_line[:, None], off_line, distance), np.inf)
    first = np.where(facing.any(axis=1), np.argmin(score, axis=1), 0)
    rows = np.arange(len(points))
    return index[rows, first], distance[rows, first]


@dataclass(frozen=True)
class Registration:
    """The template registered onto a head's skin: what :func:`find_landmarks` reads its landmarks from."""

    surface: HeadSurface
    similarity: Similarity
    """Template frame → mesh coordinates."""
    skin: SkinTarget
    """The skin in the template's frame."""
    deformed: NonRigidFit | None
    """The non-rigid fit (None for the rigid baseline)."""
    symmetry_residual: float
    affine: Affine
    """Template frame → the similarity's frame: the head's proportions (the skin is held in its inverse)."""
    shaped: Template | None = None
    """The template the non-rigid fit deformed: the built-in one with its nose and mouth moved to the heights the
    skin's profile gives (:func:`~warpface.rigging.profile.profiled`); None for the rigid baseline."""

    def to_local(self, points: np.ndarray) -> np.ndarray:
        """Mesh coordinates (N, 3) → the frame the skin and the deformed template are held in."""
        return self.affine.inverse(self.similarity.inverse(points))

    def landmark_points(self) -> tuple[np.ndarray, np.ndarray]:
        """The carried-over landmark points and normals in the template frame, (68, 3) each."""
        model = template() if self.shaped is None else self.shaped
        if self.deformed is None:
            return model.landmark_points, model.normals[model.landmark_vertices]
        points = self.deformed.move(model.landmark_points, model.landmark_nodes)
        return points, self.deformed.normals[model.landmark_vertices]


def register(
    points,
    triangles,
    *,
    up=None,
    front=None,
    nonrigid: bool = True,
    label: str = "mesh",
    model: Template | None = None,
    profile_match: bool = True,
    progress: Callable[[str], None] | None = None,
    oriented: Registration | None = None,
) -> Registration:
    """Register the built-in face onto the skin of a head mesh (see :func:`find_landmarks` for the arguments;
    ``model`` replaces the template, e.g. with other landmark points while they are calibrated; ``profile_match``
    False starts the non-rigid fit from the template as it is, not moved to the skin's profile; ``oriented``, an
    earlier registration of the same mesh and template, lends its skin surface and similarity fit, which nothing
    after them changes).

    Raises:
        ValueError: no surface (empty, a point cloud), or no face-like part.
    """
    up_hint, front_hint = parse_axis(up, "up"), parse_axis(front, "front")
    if up_hint is not None and front_hint is not None and abs(up_hint @ front_hint) > 0.5:
        raise ValueError(f"up/front: {up!r} and {front!r} are not perpendicular")
    step = progress if progress is not None else _silent
    model = template() if model is None else model
    if oriented is not None:
        surface, fit, plane_residual = oriented.surface, oriented.similarity, oriented.symmetry_residual
    else:
        step("orientation")
        surface, fit, plane_residual = _oriented(points, triangles, model, up_hint, front_hint, label)
    skin_points = surface.points[surface.skin_vertices]
    step("proportions")
    similar = fit.inverse(skin_points)
    similar_normals = surface.skin_normals @ fit.rotation
    affine = fit_affine(model, similar, similar_normals)
    skin = _held(affine, similar, similar_normals, surface.skin_boundary)
    deformed, shaped = None, None
    if nonrigid:
        shaped = profiled(model, skin.points, surface.skin_faces) if profile_match else model
        step(f"non-rigid fit 1 of {PASSES + 1}")
        deformed, final = fit_nonrigid(shaped, skin, rounds=EARLY_ROUNDS), False
        for read in range(PASSES):
            refined = affine_from_features(shaped, affine, deformed)
            if refined is None:
                break
            affine, skin = refined, _held(refined, similar, similar_normals, surface.skin_boundary)
            final = read == PASSES - 1
            step(f"non-rigid fit {read + 2} of {PASSES + 1}")
            deformed = fit_nonrigid(shaped, skin, rounds=None if final else EARLY_ROUNDS)
        if not final:  # a re-read was refused: the last fit is made again in full
            step(f"non-rigid fit {PASSES + 1} of {PASSES + 1}")
            deformed = fit_nonrigid(shaped, skin)
    return Registration(surface, fit, skin, deformed, plane_residual, affine, shaped)


def _oriented(points, triangles, model: Template, up_hint, front_hint, label: str):
    """The head's skin surface, the template's similarity fit to it and the skin's mirror residual (steps 1–3).

    Raises:
        ValueError: no surface (empty, a point cloud), or no face-like part.
    """
    surface = HeadSurface(points, triangles, label)
    samples, sample_normals, on_edge = surface.skin_samples  # the skin's vertices, and midpoints on a low-poly skin
    fit, plane_residual = fit_similarity(
        model, samples, sample_normals, on_edge, up_hint=up_hint, front_hint=front_hint
    )
    if fit.residual > MAX_RESIDUAL or plane_residual > MAX_ASYMMETRY:
        raise ValueError(
            f"{label}: no face-like part found (a face template fits its largest part only to "
            f"{fit.residual:.2f} eye distances; mirror symmetry {plane_residual:.2f}); pass a head or face mesh, "
            "or --up/--front if it is one"
        )
    return surface, fit, plane_residual


def _held(affine: Affine, points: np.ndarray, normals: np.ndarray, boundary: np.ndarray) -> SkinTarget:
    """The skin (similarity frame) held in the inverse of ``affine``: the frame the non-rigid fit works in."""
    local = affine.inverse(points)
    return SkinTarget(local, affine.inverse_normals(normals), boundary, cKDTree(local))


FEATURES = slice(27, 68)
"""Nose, eyes and mouth (iBUG 27–67): the landmarks the first non-rigid fit places best (≈ 1 mm), whose
positions give the head's proportions for the next fit."""
PASSES = 3
"""Times the proportions are read anew from the feature landmarks, each followed by a fresh non-rigid fit: every
re-read moves the map only part of the way toward the head's proportions (on the ICT head made 8 % wider the
width ratio went 1.114, 1.106, 1.097 for 1.08; on one 10 % flatter the depth ratio 0.958, 0.941, 0.933 for 0.9)."""
EARLY_ROUNDS = 1
"""Correspondence rounds per stiffness stage of the fits whose only use is the next re-read (the last fit has
:data:`~warpface.rigging.nonrigid.ROUNDS`)."""
REFIT_LIMIT = 1.25
"""A feature-based affine map whose stretch against the first one (a singular value of their ratio) lies
outside [1/1.25, 1.25] is not trusted: the re-reads stop there."""
REGISTRATION_STEPS = 2 + PASSES + 1
"""Stages :func:`register` reports to its ``progress`` callback: orientation, proportions and each non-rigid fit."""


def _silent(_stage: str) -> None:
    """No progress reported."""


def affine_from_features(model, affine: Affine, deformed: NonRigidFit) -> Affine | None:
    """The affine map (template frame → similarity frame) taking the template's feature landmark points to
    where the non-rigid fit carried them (docs/RIG.md §9, step 5c), or None when it is implausible."""
    carried = affine.apply(deformed.move(model.landmark_points[FEATURES], model.landmark_nodes[FEATURES]))
    rows = np.concatenate([model.landmark_points[FEATURES], np.ones((len(carried), 1))], axis=1)
    solution = np.linalg.lstsq(rows, carried, rcond=None)[0]
    refined = Affine(solution[:3].T, solution[3])
    stretch = np.linalg.svd(refined.linear @ np.linalg.inv(affine.linear), compute_uv=False)
    if not (np.all(np.isfinite(stretch)) and stretch.min() >= 1.0 / REFIT_LIMIT and stretch.max() <= REFIT_LIMIT):
        return None
    if np.linalg.det(refined.linear) * np.linalg.det(affine.linear) <= 0.0:
        return None
    return refined


def find_landmarks(
    points,
    triangles,
    *,
    up=None,
    front=None,
    units: str | None = None,
    nonrigid: bool = True,
    label: str = "mesh",
    progress: Callable[[str], None] | None = None,
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
        progress: called with the name of each stage as it starts (:data:`REGISTRATION_STEPS` of the registration,
            then ``"landmarks"``; a second registration from the unmoved template (step 5a's fallback) reports
            its stages from ``"proportions"`` on), e.g. to drive a progress bar.

    Raises:
        ValueError: no surface (empty, a point cloud), a size no unit explains, or no face-like part.
    """
    started = time.perf_counter()
    given_unit = parse_units(units) if units is not None else None
    step = progress if progress is not None else _silent
    registration = register(points, triangles, up=up, front=front, nonrigid=nonrigid, label=label, progress=progress)
    fit, surface, model = registration.similarity, registration.surface, template()
    if given_unit is None:
        unit_name, meters_per_unit = infer_units(fit.scale, label)
    else:
        unit_name, meters_per_unit = units.strip().lower(), given_unit
    step("landmarks")
    indices, confidence, residual = _snapped(registration)
    facing = fit.rotation @ model.forward
    laid_out = _laid_out(surface.points[indices], facing)
    if not laid_out and registration.shaped is not None and registration.shaped is not model:
        # the profile's heights misled the fit (docs/RIG.md §9, step 5a): the template as it is, as before
        registration = register(
            points,
            triangles,
            up=up,
            front=front,
            label=label,
            profile_match=False,
            progress=progress,
            oriented=registration,
        )
        step("landmarks")
        indices, confidence, residual = _snapped(registration)
        laid_out = _laid_out(surface.points[indices], facing)
    if not laid_out:  # a surface the template fits without being a face (a tube) gives landmarks out of their order
        raise ValueError(
            f"{label}: no face-like part found (the template fitted to its largest part gives landmarks that are "
            "not laid out as a face's); pass a head or face mesh, or --up/--front if it is one"
        )
    return LandmarkFit(
        indices=indices,
        confidence=confidence,
        units=unit_name,
        meters_per_unit=meters_per_unit,
        up=fit.rotation @ model.vertical,
        front=facing,
        left=fit.rotation @ np.array([1.0, 0.0, 0.0]),
        eye_distance=float(fit.scale),
        residual=residual,
        shells=surface.shell_count,
        inside_out=surface.inside_out,
        seconds=time.perf_counter() - started,
    )


def _snapped(registration: Registration) -> tuple[np.ndarray, np.ndarray, float]:
    """The registration's landmarks as skin vertices: (mesh vertex indices (68,), confidence (68,), the fit's mean
    match distance [inter-ocular units])."""
    skin, surface = registration.skin, registration.surface
    marks, mark_normals = registration.landmark_points()
    contact = mouth_contact(skin, marks)
    taken: dict[int, int] = {}
    if contact is not None:
        marks, taken = contact.move(marks)
    marks = eye_openings(skin, surface.skin_faces, marks)
    index, distance = snap_to_skin(marks, mark_normals, skin, across=np.isin(np.arange(68), SNAPPED_ACROSS))
    for corner, end in taken.items():
        index[corner], distance[corner] = end, np.linalg.norm(skin.points[end] - marks[corner])
    confidence = np.exp(-((distance / CONFIDENCE_DISTANCE) ** 2))
    if registration.deformed is not None:
        deformed = registration.deformed
        residual = float(np.mean(skin.tree.query(deformed.points)[0][deformed.weights > 0]))
    else:
        residual = registration.similarity.residual
    return surface.skin_vertices[index].astype(np.int64), confidence, residual


def _laid_out(points: np.ndarray, front: np.ndarray) -> bool:
    """Whether landmark points (68, 3) pass :func:`~warpface.landmarks.check_layout`."""
    try:
        check_layout(points, front)
    except RigError:
        return False
    return True
