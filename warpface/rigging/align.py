"""Where the face is and which way it looks: the bilateral symmetry plane, then a similarity fit of the template.

1. **Symmetry plane.** Each principal axis of the skin, and each of a net of directions over the half
   sphere, is a guess for the plane's normal. The points are reflected through the plane, the reflection
   is aligned rigidly onto the points, and the plane is read off the composed map, a few times over. The
   plane that maps the skin onto itself best wins.
2. **Up and front.** Both lie in that plane; they are searched over 12 turns in it, for either side
   of the plane as the subject's left (24 starts). Each start puts the template's nose tip on the
   skin point farthest along that front, and again on the next peak of the profile along it, and
   fits a similarity transform (scale, rotation, translation) by ICP. The three best are refined on all
   graph nodes; the one whose fit leaves the smallest capped distance wins.
   ``up`` and ``front`` hints drop the starts that disagree with them by more than 60°.
3. **Proportions.** A global affine map of the template onto the skin, fitted after the similarity
   (:func:`fit_affine`): a head wider, flatter or longer than the template is met by stretching the
   template as a whole before any local deformation, so the landmarks follow the head's proportions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .template import Template

__all__ = [
    "Similarity",
    "Affine",
    "symmetry_plane",
    "skin_symmetry_plane",
    "fit_similarity",
    "fit_affine",
    "umeyama",
    "umeyama_many",
]

TURNS = 12
"""Start angles of the up/front search in the symmetry plane."""
SCALE_STARTS = (1.0, 0.75)
"""Start scales per orientation, as fractions of the skin's width over the template's."""
REFINE_ROUNDS = 80
"""Rounds of each finalist's refinement, σ annealed slowly from 0.2 to 0.05 d: the fit slides slowly
along the face, and 30 rounds left it where its start put it (2.8 vs 0.1 mm mean on one turned ICT head)."""
FINALISTS = 3
"""Best coarse starts refined on every graph node before the winner is picked."""
HINT_COS = 0.5
"""A start is kept under an ``up``/``front`` hint when its axis is within 60° of it."""


@dataclass(frozen=True)
class Similarity:
    """``target = scale · rotation @ template + translation`` (template in inter-ocular units)."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    residual: float = float("inf")
    """Trimmed mean distance of the template to the skin after the fit [inter-ocular units]."""

    def apply(self, points: np.ndarray) -> np.ndarray:
        return self.scale * points @ self.rotation.T + self.translation

    def inverse(self, points: np.ndarray) -> np.ndarray:
        return (points - self.translation) @ self.rotation / self.scale


def umeyama(source: np.ndarray, target: np.ndarray, weights: np.ndarray, with_scale: bool = True):
    """Weighted least-squares similarity ``target ≈ s R source + t`` (Umeyama 1991): (s, R, t)."""
    scale, rotation, translation = umeyama_many(source, target[None], weights[None], with_scale)
    return float(scale[0]), rotation[0], translation[0]


def umeyama_many(source: np.ndarray, targets: np.ndarray, weights: np.ndarray, with_scale: bool = True):
    """:func:`umeyama` of one ``source`` (N, 3) onto each of ``targets`` (B, N, 3) with ``weights`` (B, N):
    scales (B,), rotations (B, 3, 3) and translations (B, 3)."""
    w = weights / weights.sum(axis=1, keepdims=True)
    mu_s, mu_t = w @ source, np.einsum("bn,bnk->bk", w, targets)
    a, b = source[None] - mu_s[:, None], targets - mu_t[:, None]
    cov = np.swapaxes(b * w[..., None], 1, 2) @ a
    u, sigma, vt = np.linalg.svd(cov)
    d = np.ones((len(targets), 3))
    d[np.linalg.det(u) * np.linalg.det(vt) < 0, 2] = -1.0
    rotation = (u * d[:, None, :]) @ vt
    variance = np.einsum("bn,bn->b", w, np.sum(a * a, axis=2))
    scale = (sigma * d).sum(axis=1) / variance if with_scale else np.ones(len(targets))
    return scale, rotation, mu_t - scale[:, None] * np.einsum("bij,bj->bi", rotation, mu_s)


PLANE_ROUNDS = 15
"""Reflect-and-ICP rounds of a symmetry plane's refinement."""
PLANE_NET = 64
"""Extra start normals spread over the half sphere: a head is near an ellipsoid, so reflections through planes
turned about its long axis fit its bulk (scalp, neck) almost as well as the true plane, and a start from a
principal axis can stop in such a plane. On 100 warped, posed whole ICT heads (benchmarks/rigging_orientation.py)
the principal axes left the plane up to 33° off (15 heads over 10°), and three were then fitted upside down; with
the net, at most 8°."""
PLANE_SCREEN = (500, 3, 2)
"""The net's screening: (subsample size, reflect-and-ICP rounds, screened planes refined in full). On the same 100
heads a screening of 1,000 points, 5 rounds and 4 refined planes gave the same angles (median 2.1°, worst 7.9°) in
0.75 s per head against 0.43 s; 32 starts left one plane 11.6° off."""


def _reflect(points: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    return points - 2.0 * ((points @ normal) - offset)[:, None] * normal


def _refine_plane(points: np.ndarray, tree: cKDTree, normal: np.ndarray, offset: float, rounds: int):
    """Reflect-and-ICP from the plane ``(normal, offset)``: (normal, offset) after ``rounds`` rounds."""
    for _ in range(rounds):
        reflected = _reflect(points, normal, offset)
        distance, index = tree.query(reflected)
        weights = (distance <= np.quantile(distance, 0.8)).astype(np.float64)
        _, rotation, translation = umeyama(reflected, points[index], weights, with_scale=False)
        linear = rotation @ (np.eye(3) - 2.0 * np.outer(normal, normal))
        values, vectors = np.linalg.eigh(0.5 * (linear + linear.T))
        new = vectors[:, 0] * np.sign(vectors[:, 0] @ normal or 1.0)
        shift = rotation @ (2.0 * offset * normal) + translation
        normal, offset = new / np.linalg.norm(new), 0.5 * float(shift @ new)
    return normal, offset


def _plane_residual(points: np.ndarray, tree: cKDTree, normal: np.ndarray, offset: float, size: float) -> float:
    """Mean of the 90 % nearest reflected distances, over the cloud's RMS size."""
    distance = np.sort(tree.query(_reflect(points, normal, offset))[0])
    return float(np.mean(distance[: int(0.9 * len(points))])) / size


def half_sphere(count: int) -> np.ndarray:
    """``count`` unit vectors spread evenly over the half sphere z > 0 (a Fibonacci spiral), (count, 3)."""
    k = np.arange(count) + 0.5
    z = k / count
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    ring = np.sqrt(1.0 - z * z)
    return np.stack([ring * np.cos(phi), ring * np.sin(phi), z], axis=1)


def symmetry_plane(points: np.ndarray, tree: cKDTree) -> tuple[np.ndarray, float, float]:
    """The best bilateral symmetry plane of ``points``: (unit normal, offset along it, residual / RMS size).

    Reflect-and-ICP: the reflection of the points is aligned rigidly onto the points; the composed map
    is a reflection again, through the refined plane. Starts: the three principal axes, and
    :data:`PLANE_NET` normals over the half sphere screened on a subsample, whose best few are refined too.
    """
    centre = points.mean(axis=0)
    size = float(np.sqrt(np.mean(np.sum((points - centre) ** 2, axis=1))))
    _, axes = np.linalg.eigh(np.cov((points - centre).T))
    refined = [_refine_plane(points, tree, axes[:, k], float(axes[:, k] @ centre), PLANE_ROUNDS) for k in range(3)]
    subsample_size, screen_rounds, kept = PLANE_SCREEN
    subsample = points[:: max(1, len(points) // subsample_size)]
    subsample_tree = cKDTree(subsample)
    screened = []
    for direction in half_sphere(PLANE_NET) @ axes.T:
        normal, offset = _refine_plane(subsample, subsample_tree, direction, float(direction @ centre), screen_rounds)
        screened.append((_plane_residual(subsample, subsample_tree, normal, offset, size), normal, offset))
    screened.sort(key=lambda plane: plane[0])
    refined += [_refine_plane(points, tree, normal, offset, PLANE_ROUNDS) for _, normal, offset in screened[:kept]]
    scored = [(normal, offset, _plane_residual(points, tree, normal, offset, size)) for normal, offset in refined]
    return min(scored, key=lambda plane: plane[2])


FACING = 0.3
"""A correspondence counts only where the template's and the skin's normals are within ~73°."""
MISS = 0.3
"""Distance charged to a template point with no plausible skin point [inter-ocular units]."""
BEYOND = 0.1
"""At most this is charged to a template point whose nearest skin point lies on the skin's open boundary [inter-ocular
units]: it hangs past where the mesh ends (a face cropped at the brows or behind the cheeks), which tells little
against the fit. Charged :data:`MISS`, a face cropped at the brows was fitted upside down: its chin and neck cover
more of the template than its missing forehead leaves uncovered. At 0 a fit slid off the mesh (ICT face 116 mm off)."""


def _icp(
    template: np.ndarray,
    template_normals: np.ndarray,
    skin: np.ndarray,
    skin_normals: np.ndarray,
    tree: cKDTree,
    starts: list[Similarity],
    iterations: int,
    sigma: tuple[float, float] = (0.3, 0.08),
    boundary: np.ndarray | None = None,
) -> list[Similarity]:
    """Similarity ICP from each of ``starts``, all at once, with Gaussian weights whose width shrinks from
    ``sigma[0]`` to ``sigma[1]``; the matched skin point slides to the foot of the template point on the skin's
    tangent plane; a start whose weights all but vanish stops where it is. The residual of each fit is the mean capped
    distance (:data:`MISS`; :data:`BEYOND` where the nearest skin point is on the skin's ``boundary``, (S,) bool)."""
    scale = np.array([fit.scale for fit in starts], dtype=np.float64)
    rotation = np.stack([fit.rotation for fit in starts]).astype(np.float64)
    translation = np.stack([fit.translation for fit in starts]).astype(np.float64)
    count = len(template)

    def moved(fits: np.ndarray) -> np.ndarray:
        return scale[fits, None, None] * (template @ np.swapaxes(rotation[fits], 1, 2)) + translation[fits, None]

    def matched(fits: np.ndarray):
        """Distance (F, N), skin index (F, N) and the facing cosine (F, N) of the fits' moved template points."""
        distance, index = tree.query(moved(fits).reshape(-1, 3), workers=-1)
        distance, index = distance.reshape(len(fits), count), index.reshape(len(fits), count)
        turned = template_normals @ np.swapaxes(rotation[fits], 1, 2)
        return distance, index, np.einsum("fnk,fnk->fn", turned, skin_normals[index])

    active = np.arange(len(starts))
    for width in np.geomspace(sigma[0], sigma[1], iterations):
        distance, index, facing = matched(active)
        weights = np.exp(-((distance / (width * scale[active, None])) ** 2)) * (facing > FACING)
        going = weights.sum(axis=1) >= 1e-3 * count
        active, distance, index, weights = active[going], distance[going], index[going], weights[going]
        if len(active) == 0:
            break
        points, normals = moved(active), skin_normals[index]
        foot = points - np.sum((points - skin[index]) * normals, axis=2)[..., None] * normals
        scale[active], rotation[active], translation[active] = umeyama_many(template, foot, weights)
    distance, index, facing = matched(np.arange(len(starts)))
    cost = np.where(facing > FACING, np.minimum(distance / scale[:, None], MISS), MISS)
    if boundary is not None:
        cost = np.where(boundary[index], np.minimum(cost, BEYOND), cost)
    residual = cost.mean(axis=1)
    return [Similarity(float(scale[i]), rotation[i], translation[i], float(residual[i])) for i in range(len(starts))]


def _starts(normal: np.ndarray, up_hint, front_hint):
    """(x, up, front) frames in the symmetry plane: TURNS angles × both sides."""
    seed = np.eye(3)[np.argmin(np.abs(normal))]
    u0 = seed - (seed @ normal) * normal
    u0 /= np.linalg.norm(u0)
    w0 = np.cross(normal, u0)
    frames = []
    for side in (1.0, -1.0):
        x = side * normal
        for theta in np.arange(TURNS) * (2.0 * np.pi / TURNS):
            up = np.cos(theta) * u0 + np.sin(theta) * w0
            front = np.cross(x, up)
            if up_hint is not None and up @ up_hint < HINT_COS:
                continue
            if front_hint is not None and front @ front_hint < HINT_COS:
                continue
            frames.append((x, up, front))
    return frames


TIP_STARTS = 2
"""Nose-tip guesses per start frame: the profile's most forward peaks (:func:`profile_peaks`)."""
TIP_SPACING = 0.3
"""Least distance between two nose-tip guesses along up, as a fraction of the skin's width."""


def profile_peaks(profile: np.ndarray, front: np.ndarray, up: np.ndarray, spacing: float) -> list[np.ndarray]:
    """Up to :data:`TIP_STARTS` points of the profile (the skin near the symmetry plane, (N, 3)) farthest along
    ``front``, each at least ``spacing`` along ``up`` from those taken before it.

    *Why more than one:* on a head tilted toward a start's front, or with a prominent chin, the chin (or the
    brow) is farther forward than the nose tip; a template put there by its nose stays there (a head whose
    chin was pulled forward 1 cm was fitted upside down, its correct start 8 cm off the nose).
    """
    forward, heights = profile @ front, profile @ up
    open_ = np.ones(len(profile), dtype=bool)
    peaks = []
    while len(peaks) < TIP_STARTS and open_.any():
        peak = int(np.flatnonzero(open_)[np.argmax(forward[open_])])
        peaks.append(profile[peak])
        open_ &= np.abs(heights - heights[peak]) >= spacing
    return peaks


PLANE_SAMPLE = 4000
"""Skin points the symmetry plane is fitted on (a random subset of a larger skin)."""


def skin_symmetry_plane(skin: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, float, float]:
    """:func:`symmetry_plane` of the skin points (N, 3), on :data:`PLANE_SAMPLE` of them drawn with ``rng``."""
    sample = skin if len(skin) <= PLANE_SAMPLE else skin[rng.choice(len(skin), PLANE_SAMPLE, replace=False)]
    return symmetry_plane(sample, cKDTree(sample))


def fit_similarity(
    model: Template,
    skin: np.ndarray,
    skin_normals: np.ndarray,
    skin_boundary: np.ndarray | None = None,
    *,
    up_hint: np.ndarray | None = None,
    front_hint: np.ndarray | None = None,
) -> tuple[Similarity, float]:
    """The template's similarity fit to the skin points (target units), searched from the symmetry plane;
    ``skin_boundary`` (S,) bool flags the points on the skin's open boundary (a face-only mesh's outline).

    Returns the fit and the symmetry plane's residual (relative to the skin's RMS size).
    """
    tree = cKDTree(skin)
    rng = np.random.default_rng(0)
    normal, _, plane_residual = skin_symmetry_plane(skin, rng)
    nodes, node_normals = model.points[model.nodes], model.normals[model.nodes]
    coarse = rng.choice(len(nodes), min(400, len(nodes)), replace=False)
    centre = skin.mean(axis=0)
    nose = model.points[model.landmarks[30]]
    template_width = float(np.ptp(model.points[:, 0]))
    starts = []
    for x, up, front in _starts(normal, up_hint, front_hint):
        rotation = np.stack([x, up, front], axis=1)  # template axes → target directions
        across = (skin - centre) @ x
        width = float(np.quantile(across, 0.98) - np.quantile(across, 0.02))
        profile = skin[np.abs(across) < 0.1 * width]
        for tip in profile_peaks(profile, front, up, TIP_SPACING * width):
            for factor in SCALE_STARTS:
                scale = factor * width / template_width
                starts.append(Similarity(scale, rotation, tip - scale * rotation @ nose))
    if not starts:
        raise ValueError("up/front: the hints given contradict each other (up and front must be perpendicular)")
    candidates = _icp(nodes[coarse], node_normals[coarse], skin, skin_normals, tree, starts, 20, boundary=skin_boundary)
    finalists = sorted(candidates, key=lambda fit: fit.residual)[:FINALISTS]
    refined = _icp(nodes, node_normals, skin, skin_normals, tree, finalists, REFINE_ROUNDS, (0.2, 0.05), skin_boundary)
    return min(refined, key=lambda fit: fit.residual), plane_residual


AFFINE_ROUNDS = 30
"""Rounds of the affine fit, σ annealed from :data:`AFFINE_SIGMA` [0] to [1]."""
AFFINE_SIGMA = (0.15, 0.05)
"""Gaussian match width of the affine fit [inter-ocular units], first and last round."""
AFFINE_PRIOR = 0.01
"""Pull of the affine fit's linear part toward the identity (the similarity), per unit of match weight: keeps the
fit from collapsing where only part of the template finds skin (0.0001 let one warped head's fit run away)."""


@dataclass(frozen=True)
class Affine:
    """``p ↦ linear @ p + shift`` in the similarity's (template) frame."""

    linear: np.ndarray
    shift: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        return points @ self.linear.T + self.shift

    def inverse(self, points: np.ndarray) -> np.ndarray:
        return np.linalg.solve(self.linear, (points - self.shift).T).T

    def inverse_normals(self, normals: np.ndarray) -> np.ndarray:
        """Unit normals of a surface mapped by :meth:`inverse` (normals transform by the transpose)."""
        mapped = normals @ self.linear
        return mapped / np.maximum(np.linalg.norm(mapped, axis=1, keepdims=True), 1e-300)


def fit_affine(model: Template, skin: np.ndarray, skin_normals: np.ndarray) -> Affine:
    """The global affine map of the template's graph nodes onto the skin (both in the template frame after the
    similarity fit): weighted least squares on the matches' tangent-plane feet, Gaussian weights of shrinking
    width, matches only where the mapped normals agree (cos > 0.5), the linear part pulled toward the identity
    by :data:`AFFINE_PRIOR`."""
    tree = cKDTree(skin)
    nodes, node_normals = model.points[model.nodes], model.normals[model.nodes]
    rows = np.concatenate([nodes, np.ones((len(nodes), 1))], axis=1)
    fit = Affine(np.eye(3), np.zeros(3))
    for width in np.geomspace(AFFINE_SIGMA[0], AFFINE_SIGMA[1], AFFINE_ROUNDS):
        moved = fit.apply(nodes)
        distance, index = tree.query(moved)
        normals = skin_normals[index]
        moved_normals = np.linalg.solve(fit.linear.T, node_normals.T).T
        moved_normals /= np.linalg.norm(moved_normals, axis=1, keepdims=True)
        weights = np.exp(-((distance / width) ** 2)) * (np.sum(moved_normals * normals, axis=1) > 0.5)
        if weights.sum() < 1e-3 * len(nodes):
            break
        foot = moved - np.sum((moved - skin[index]) * normals, axis=1)[:, None] * normals
        root, prior = np.sqrt(weights)[:, None], np.sqrt(AFFINE_PRIOR * weights.sum())
        system = np.concatenate([rows * root, prior * np.eye(4)[:3]])
        target = np.concatenate([foot * root, prior * np.eye(3)])
        solution = np.linalg.lstsq(system, target, rcond=None)[0]
        fit = Affine(solution[:3].T, solution[3])
    return fit
