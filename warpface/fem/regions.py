"""Material regions from facial landmarks, and Kato's heterogeneous models 1–3 (SPEC §2.1).

A region is the set of tets whose centroid lies within a radius of one of its landmark positions;
where regions compete, a tet belongs to the region of the nearest landmark (a Voronoi split
truncated at the radius), so neighbouring regions never overlap and the assignment does not
depend on the order regions are listed in.

Kato's tables 6.4–6.5 name six regions: cheek, cphs (L), cphs (R), cheilion, cphi and alare.
Five are small areas around landmarks (:data:`KATO_REGION_LANDMARKS`, landmark names from
:mod:`warpface.landmarks`); the thesis gives every tet a value, and the cheek is the region without a
landmark of its own, so here the cheek values apply to all remaining tissue (the project's choice).
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

import numpy as np

from .._validate import MAX_COORDINATE, as_finite_array, expect_instance
from ..landmarks import kato_landmarks
from .material import TissueMaterial
from .presets import KATO_MODELS, KATO_REGIONS, KATO_UNIFORM
from .tetmesh import TetMesh

__all__ = [
    "KATO_MODELS",
    "KATO_REGIONS",
    "KATO_REGION_LANDMARKS",
    "kato_material_model",
    "kato_regions",
    "landmark_regions",
    "tet_centroids",
]

KATO_REGION_LANDMARKS = MappingProxyType(
    {
        "cphs_L": ("cphs_L",),
        "cphs_R": ("cphs_R",),
        "cheilion": ("ch_L", "ch_R"),
        "cphi": ("cphi_L", "cphi_R"),
        "alare": ("al_L", "al_R"),
    }
)
"""Landmarks (names of :data:`warpface.landmarks.KATO_LANDMARKS`) each landmark region is centred on."""


def tet_centroids(tetmesh: TetMesh) -> np.ndarray:
    """Tet centroids [m], shape (M, 3), float64."""
    return tetmesh.points[tetmesh.tets].mean(axis=1)


def _positions(name: str, value) -> np.ndarray:
    p = as_finite_array(value, f"region {name!r}: landmark positions", max_abs=MAX_COORDINATE)
    if p.ndim == 1:
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
        raise ValueError(f"region {name!r}: landmark positions must have shape (3,) or (K, 3), got {np.shape(value)}")
    if not np.isfinite(p).all():
        raise ValueError(f"region {name!r}: landmark positions must be finite, got {p.tolist()}")
    return p


def landmark_regions(tetmesh: TetMesh, centres: Mapping[str, object], radius) -> dict[str, np.ndarray]:
    """Tets near landmarks, one disjoint mask per region.

    Args:
        tetmesh: The tissue mesh.
        centres: Region name -> landmark position(s) [m], shape (3,) or (K, 3).
        radius: Reach of every region [m] (scalar), or region name -> radius.

    Returns:
        Region name -> boolean mask over tets, shape (M,). A tet is in the region of the landmark
        nearest its centroid when that landmark is within its region's radius; masks are disjoint
        and may be empty.

    Raises:
        ValueError: no regions, malformed positions, or a radius that is missing or not > 0.
    """
    expect_instance(tetmesh, TetMesh, "tetmesh")
    if not isinstance(centres, Mapping):
        raise TypeError(
            f"landmark_regions: centres must be a {{region name: position(s)}} mapping, got {type(centres).__name__}"
        )
    if not centres:
        raise ValueError("landmark_regions: no regions given")
    names = list(centres)
    radii = {}
    for name in names:
        r = radius.get(name) if isinstance(radius, Mapping) else radius
        if r is None:
            raise ValueError(f"landmark_regions: no radius for region {name!r}")
        r = float(as_finite_array(r, f"landmark_regions: radius of region {name!r}", shape=()))
        if not (np.isfinite(r) and r > 0.0):
            raise ValueError(f"landmark_regions: radius of region {name!r} must be finite and > 0 [m], got {r}")
        radii[name] = r
    points = [_positions(name, centres[name]) for name in names]
    owner = np.concatenate([np.full(len(p), i) for i, p in enumerate(points)])
    all_points = np.concatenate(points)
    c = tet_centroids(tetmesh)
    distance = np.linalg.norm(c[:, None, :] - all_points[None, :, :], axis=2)  # (M, landmarks)
    nearest = np.argmin(distance, axis=1)
    region = owner[nearest]
    reach = np.array([radii[n] for n in names])[region]
    within = distance[np.arange(len(c)), nearest] <= reach
    return {name: within & (region == i) for i, name in enumerate(names)}


def kato_regions(tetmesh: TetMesh, landmarks, *, radius=0.01) -> dict[str, np.ndarray]:
    """Kato's six regions as disjoint boolean masks over tets (see the module docstring).

    Args:
        tetmesh: The tissue mesh.
        landmarks: Landmark name -> position (3,) [m] with at least the names in
            :data:`KATO_REGION_LANDMARKS` (as from :func:`warpface.landmarks.kato_landmarks`), or the
            68 iBUG positions, shape (68, 3).
        radius: Reach of each landmark region [m], scalar or region name -> radius (default 10 mm).

    Returns:
        Region name (all of :data:`KATO_REGIONS`) -> mask of shape (M,); "cheek" holds every tet in
        no landmark region.
    """
    expect_instance(tetmesh, TetMesh, "tetmesh")
    if not isinstance(landmarks, Mapping):
        landmarks = kato_landmarks(landmarks)
    centres = {}
    for region, names in KATO_REGION_LANDMARKS.items():
        missing = [n for n in names if n not in landmarks]
        if missing:
            raise ValueError(
                f"kato_regions: landmark(s) {missing} for region {region!r} missing; have {sorted(landmarks)}"
            )
        centres[region] = np.stack([_positions(region, landmarks[n])[0] for n in names])
    masks = landmark_regions(tetmesh, centres, radius)
    taken = np.zeros(tetmesh.tet_count, dtype=bool)
    for mask in masks.values():
        taken |= mask
    return {"cheek": ~taken, **masks}


def kato_material_model(
    tetmesh: TetMesh,
    landmarks,
    model: int = 1,
    *,
    radius=0.01,
    nu: float = KATO_UNIFORM["nu"],
    rho: float = KATO_UNIFORM["rho"],
    damping: str = "stokes",
) -> TissueMaterial:
    """Per-tet material of Kato's heterogeneous model 1, 2 or 3 (SPEC §2.1, tables 6.4–6.5).

    Args:
        tetmesh: The tissue mesh.
        landmarks: As for :func:`kato_regions`.
        model: 1 (healthy), 2 (stiffer right cphs: a scar) or 3 (softer right cphs).
        radius: Reach of each landmark region [m] (see :func:`kato_regions`).
        nu: Poisson's ratio everywhere (thesis: 0.495).
        rho: Density everywhere [kg/m^3] (thesis: 1100).
        damping: Viscous law of :class:`~warpface.fem.TissueMaterial` ("stokes" or "thesis").

    Returns:
        A :class:`~warpface.fem.TissueMaterial` with per-tet E and eta (shape (M,)).

    Raises:
        ValueError: unknown model, missing landmarks, or invalid material values.
    """
    expect_instance(tetmesh, TetMesh, "tetmesh")
    if model not in KATO_MODELS:
        raise ValueError(f"kato_material_model: model must be one of {sorted(KATO_MODELS)}, got {model!r}")
    table = KATO_MODELS[model]
    regions = kato_regions(tetmesh, landmarks, radius=radius)
    base = TissueMaterial(table["E"]["cheek"], nu, table["eta"]["cheek"], rho, damping=damping)
    overrides = {r: {"E": table["E"][r], "eta": table["eta"][r]} for r in KATO_REGIONS if r != "cheek"}
    return TissueMaterial.from_regions(tetmesh.tet_count, base, regions, overrides)
