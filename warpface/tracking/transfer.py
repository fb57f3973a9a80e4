"""Sparse → dense motion transfer (SPEC §3 steps 3–4) with a smooth blend, and the tracking adapter.

Geometric transfer (Kato eq. 4.15): a dense vertex ``p`` attached to sparse triangle ``m`` with
barycentric coordinates ``a_j`` moves by ``d(p) = Σ_j a_j d_j`` — like its sparse triangle.

Kato applied it inside a "moving region" and let the FEM decide elsewhere, with a hard switch at
the boundary; where the sparse and dense contours disagreed (the jaw) the transfer extrapolated the
sparse mesh's border triangles, and the seam showed. Here every dense vertex gets a **blend weight**
``w ∈ [0, 1]`` that falls smoothly (C¹ smoothstep) to 0

* with the distance *beyond the sparse mesh's contour* — the in-plane part ("overhang") of the
  offset from the vertex to its closest sparse point, 0 for a vertex that projects inside a sparse
  triangle — over ``cover_falloff`` metres, and
* optionally with the distance from a user-given driven region (e.g. the area the tracker
  covers well) over ``region_falloff`` metres,

and the dense displacement is ``u = w · s · Σ_j a_j d_j + (1 − w) · u_other`` where ``u_other`` is
what drives the rest (zero, or the FEM's solution) and ``s`` maps sparse to dense units. Vertices
with ``w = 1`` are fully driven (Dirichlet conditions for the FEM); the blend band between is
where the two solutions meet without a seam.

:class:`TrackingAdapter` holds the correspondence and weights (computed once) and maps each
:class:`~warpface.tracking.sources.LandmarkFrame` to dense points: camera → model frame, optional
head-motion removal, hold of missing landmarks, transfer kernel. ``track(source)`` is a generator of
``(frame, dense_points)`` for writers (USD time samples) and simulators.
"""

from __future__ import annotations

from typing import Iterable, Iterator, Sequence

import numpy as np
import warp as wp

from .._validate import as_bounded, as_device, as_finite_array, as_points, as_positive, as_triangles
from ..geometry import smoothstep
from .alignment import rigid_fit, similarity_fit
from .correspondence import Correspondence, FaceNormalization, compute_correspondence
from .frames import LandmarkFrame
from .streams import validate_landmark_names

__all__ = [
    "TrackingAdapter",
    "blend_weights",
    "transfer_displacements",
]


# --------------------------------------------------------------------------------------------
# Kernels
# --------------------------------------------------------------------------------------------


@wp.kernel
def _transfer_kernel(
    sparse_displacement: wp.array(dtype=wp.vec3),
    corners: wp.array(dtype=wp.vec3i),
    weighted_barycentric: wp.array(dtype=wp.vec3),
    weight: wp.array(dtype=float),
    scale: float,
    rest: wp.array(dtype=wp.vec3),
    other: wp.array(dtype=wp.vec3),
    use_other: int,
    out_displacement: wp.array(dtype=wp.vec3),
    out_points: wp.array(dtype=wp.vec3),
):
    """u = s Σ_j (w a_j) d_j + (1 − w) u_other per dense vertex (eq. 4.15 with the blend).

    ``corners`` are the sparse vertices of each dense vertex's triangle and ``weighted_barycentric``
    its barycentric coordinates times its blend weight w, both gathered once per correspondence
    (half the loads of looking up the triangle every frame); ``weight`` is read only with ``other``.
    """
    v = wp.tid()
    c = corners[v]
    a = weighted_barycentric[v]
    u = scale * (a[0] * sparse_displacement[c[0]] + a[1] * sparse_displacement[c[1]] + a[2] * sparse_displacement[c[2]])
    if use_other != 0:
        u = u + (1.0 - weight[v]) * other[v]
    out_displacement[v] = u
    out_points[v] = rest[v] + u


def _transfer_coefficients(
    sparse_triangles: np.ndarray, correspondence: Correspondence, weights: np.ndarray, device
) -> tuple[wp.array, wp.array]:
    """Per dense vertex: its triangle's sparse vertex indices (vec3i) and ``w · barycentric`` (vec3)."""
    corners = np.ascontiguousarray(sparse_triangles[correspondence.triangle], dtype=np.int32)
    weighted = (correspondence.barycentric * weights[:, None]).astype(np.float32)
    return wp.array(corners, dtype=wp.vec3i, device=device), wp.array(weighted, dtype=wp.vec3, device=device)


@wp.kernel
def _distance_to_set_kernel(
    grid: wp.uint64,
    set_points: wp.array(dtype=wp.vec3),
    queries: wp.array(dtype=wp.vec3),
    radius: float,
    out_distance: wp.array(dtype=float),
):
    """Distance from each query to the nearest set point, capped at ``radius``."""
    i = wp.tid()
    p = queries[i]
    best = radius
    query = wp.hash_grid_query(grid, p, radius)
    j = int(0)
    while wp.hash_grid_query_next(query, j):
        best = wp.min(best, wp.length(p - set_points[j]))
    out_distance[i] = best


@wp.kernel
def _blend_weights_kernel(
    overhang: wp.array(dtype=float),
    region_distance: wp.array(dtype=float),
    cover_start: float,
    cover_end: float,
    region_falloff: float,
    out_weight: wp.array(dtype=float),
):
    """w = (1 − smoothstep over the overhang) · (1 − smoothstep over the distance to the region)."""
    v = wp.tid()
    w_cover = 1.0 - smoothstep(cover_start, cover_end, overhang[v])
    w_region = float(1.0)
    if region_falloff > 0.0:
        w_region = 1.0 - smoothstep(0.0, region_falloff, region_distance[v])
    elif region_distance[v] > 0.0:
        w_region = 0.0
    out_weight[v] = w_cover * w_region


# --------------------------------------------------------------------------------------------
# Functions
# --------------------------------------------------------------------------------------------


def blend_weights(
    dense_points,
    correspondence: Correspondence,
    *,
    region=None,
    region_falloff: float = 0.01,
    cover_falloff: tuple[float, float] = (0.0, 0.015),
    device=None,
) -> np.ndarray:
    """Smooth per-vertex weights of the directly driven motion, shape (V,), float32 in [0, 1].

    Args:
        dense_points: dense rest points [m], shape (V, 3).
        correspondence: from :func:`~warpface.tracking.correspondence.compute_correspondence`.
        region: optional driven region — a boolean mask (V,) or vertex indices; all vertices when
            ``None``.
        region_falloff: width [m] of the fade outside ``region`` (Euclidean distance to its nearest
            vertex); 0 makes the region edge hard.
        cover_falloff: ``(start, end)`` [m] of the fade with the overhang beyond the sparse contour.

    Raises:
        ValueError: bad shapes, an empty region, or a falloff with end ≤ start.
    """
    points = as_points(dense_points, "dense_points")
    count = points.shape[0]
    if not isinstance(correspondence, Correspondence):
        raise TypeError(f"correspondence: expected a Correspondence, got {type(correspondence).__name__}")
    correspondence = correspondence.checked(vertex_count=count)
    start, end = (float(x) for x in as_finite_array(cover_falloff, "cover_falloff", shape=(2,), max_abs=1e6))
    if not (end > start >= 0.0):
        raise ValueError(f"cover_falloff must satisfy 0 ≤ start < end, got {cover_falloff}")
    region_falloff = as_positive(region_falloff, "region_falloff", allow_zero=True)
    device = as_device(device)
    distance = wp.zeros(count, dtype=float, device=device)
    if region is not None:
        mask = np.zeros(count, dtype=bool)
        region = np.asarray(region)
        if region.dtype == bool:
            if region.shape != (count,):
                raise ValueError(f"region: boolean mask must have shape ({count},), got {region.shape}")
            mask = region.copy()
        else:
            if not np.issubdtype(region.dtype, np.integer):
                raise ValueError(f"region: expected a boolean mask or integer vertex indices, got dtype {region.dtype}")
            idx = region.astype(np.int64).reshape(-1)
            if idx.size and (idx.min() < 0 or idx.max() >= count):
                raise ValueError(f"region: vertex index out of range [0, {count})")
            mask[idx] = True
        if not mask.any():
            raise ValueError("region: no vertex selected")
        center = points.mean(axis=0)
        set_points = wp.array((points[mask] - center).astype(np.float32), dtype=wp.vec3, device=device)
        queries = wp.array((points - center).astype(np.float32), dtype=wp.vec3, device=device)
        radius = max(float(region_falloff), 1e-6)
        grid = wp.HashGrid(64, 64, 64, device=device)
        grid.build(set_points, radius)
        wp.launch(
            _distance_to_set_kernel,
            dim=count,
            inputs=[grid.id, set_points, queries, radius],
            outputs=[distance],
            device=device,
        )
        # Region vertices are at distance 0 exactly (float rounding aside).
        host = distance.numpy()
        host[mask] = 0.0
        distance = wp.array(host, dtype=float, device=device)
    weight = wp.empty(count, dtype=float, device=device)
    wp.launch(
        _blend_weights_kernel,
        dim=count,
        inputs=[
            wp.array(correspondence.overhang.astype(np.float32), dtype=float, device=device),
            distance,
            start,
            end,
            float(region_falloff),
        ],
        outputs=[weight],
        device=device,
    )
    return weight.numpy().copy()


def transfer_displacements(
    sparse_displacement,
    sparse_triangles,
    correspondence: Correspondence,
    weights=None,
    *,
    scale: float = 1.0,
    device=None,
) -> np.ndarray:
    """Dense displacements ``w · scale · Σ_j a_j d_j``, shape (V, 3), float32 (one-off helper).

    For per-frame use, :class:`TrackingAdapter` keeps everything on the device instead.

    Raises:
        ValueError: bad shapes, non-finite values, a correspondence that refers to a sparse
            triangle that is not there, or a result too large for float32 (naming the item).
    """
    disp = as_points(sparse_displacement, "sparse_displacement")
    tri = as_triangles(sparse_triangles, disp.shape[0], "sparse_triangles")
    if not isinstance(correspondence, Correspondence):
        raise TypeError(f"correspondence: expected a Correspondence, got {type(correspondence).__name__}")
    correspondence = correspondence.checked(triangle_count=tri.shape[0])
    count = correspondence.triangle.shape[0]
    if weights is None:
        w = np.ones(count, np.float32)
    else:
        w = as_finite_array(weights, "weights", max_abs=1e6).reshape(-1).astype(np.float32)
        if w.shape != (count,):
            raise ValueError(f"weights: expected shape ({count},), got {w.shape}")
    scale = float(as_finite_array(scale, "scale", shape=(), max_abs=1e6))
    device = as_device(device)
    out_u = wp.empty(count, dtype=wp.vec3, device=device)
    out_p = wp.empty(count, dtype=wp.vec3, device=device)
    zeros = wp.zeros(count, dtype=wp.vec3, device=device)
    wp.launch(
        _transfer_kernel,
        dim=count,
        inputs=[
            wp.array(disp.astype(np.float32), dtype=wp.vec3, device=device),
            *_transfer_coefficients(tri, correspondence, w, device),
            wp.array(w, dtype=float, device=device),
            float(scale),
            zeros,
            zeros,
            0,
        ],
        outputs=[out_u, out_p],
        device=device,
    )
    result = out_u.numpy().copy()
    if not np.all(np.isfinite(result)):
        raise ValueError(
            "transfer_displacements: the dense displacements overflow float32; "
            "sparse_displacement, weights or scale are too large"
        )
    return result


# --------------------------------------------------------------------------------------------
# The adapter
# --------------------------------------------------------------------------------------------


class TrackingAdapter:
    """Maps landmark frames to dense face points, frame after frame.

    Built once from the sparse tracking mesh (at rest, model frame) and the dense face (at rest,
    model frame); then :meth:`track_frame` turns each :class:`LandmarkFrame` (camera frame) into dense
    points, and :meth:`track` does so for a whole source as a generator.

    Per frame:

    1. **Select** the source's landmarks in sparse-vertex order (by name, see ``landmark_names``).
    2. **Reference**: the first frame in which a landmark is measured defines its rest position
       (start the capture from a neutral face). ``camera_to_model`` — a similarity, 4×4 — maps
       camera-frame motion into the model frame; when not given it is fitted on the first frame
       with ≥ 4 measured landmarks (camera landmarks → sparse rest points, Umeyama).
    3. **Stabilise** (optional): a rigid fit of the frame's stable landmarks onto their reference
       positions removes head motion, so only expression moves the face.
    4. **Displace**: ``d_j = s R (p_j − p_j^ref)`` in the model frame; a landmark missing in this
       frame (NaN or confidence ≤ ``min_confidence``) keeps its last displacement (0 until first
       seen) — nothing NaN reaches the kernel.
    5. **Transfer** on the device: ``u = w · k · Σ a_j d_j + (1 − w) u_other``, points = rest + u,
       where ``k`` = dense face width / sparse face width when normalisations are given, else 1.

    Args:
        sparse_points: sparse rest points [m], shape (N, 3), model frame.
        sparse_triangles: sparse triangles, shape (T, 3).
        dense_points: dense rest points [m], shape (V, 3), model frame.
        landmark_names: name of each sparse vertex (N); the source's frames are matched by name.
            ``None`` matches by position (the source must then have exactly N landmarks).
        sparse_normalization, dense_normalization: :class:`FaceNormalization` of each model for
            the correspondence (SPEC eq. 5.1–5.4); both or neither.
        region, region_falloff, cover_falloff: blend weights, see :func:`blend_weights`.
        camera_to_model: 4×4 similarity from the camera frame to the sparse model frame; fitted on
            the first usable frame when ``None``.
        stabilize: ``False``; ``True`` (all landmarks vote); or the indices/names of stable
            landmarks (forehead, nose bridge) for the head-motion fit.
        min_confidence: landmarks at or below this confidence count as missing.
        device: Warp device.

    Raises:
        ValueError: bad shapes, names not unique, or invalid options.
    """

    def __init__(
        self,
        sparse_points,
        sparse_triangles,
        dense_points,
        *,
        landmark_names: Sequence[str] | None = None,
        sparse_normalization: FaceNormalization | None = None,
        dense_normalization: FaceNormalization | None = None,
        region=None,
        region_falloff: float = 0.01,
        cover_falloff: tuple[float, float] = (0.0, 0.015),
        camera_to_model: np.ndarray | None = None,
        stabilize: bool | Sequence[int] | Sequence[str] = False,
        min_confidence: float = 0.0,
        device=None,
    ):
        self.device = as_device(device)
        self.sparse_rest = as_points(sparse_points, "sparse_points")
        """Sparse rest points [m], shape (N, 3), model frame."""
        self.sparse_triangles = as_triangles(sparse_triangles, self.sparse_rest.shape[0], "sparse_triangles")
        self.dense_rest = as_points(dense_points, "dense_points")
        """Dense rest points [m], shape (V, 3), model frame."""
        n = self.sparse_rest.shape[0]
        self.landmark_names: tuple[str, ...] | None = (
            None if landmark_names is None else validate_landmark_names(landmark_names, n, "landmark_names")
        )
        self.correspondence = compute_correspondence(
            self.dense_rest,
            self.sparse_rest,
            self.sparse_triangles,
            sparse_normalization=sparse_normalization,
            dense_normalization=dense_normalization,
            device=self.device,
        )
        """Per dense vertex: sparse triangle, barycentric coordinates, distance, overhang."""
        self.weights = blend_weights(
            self.dense_rest,
            self.correspondence,
            region=region,
            region_falloff=region_falloff,
            cover_falloff=cover_falloff,
            device=self.device,
        )
        """Blend weight of the directly driven motion per dense vertex, shape (V,), float32."""
        self.scale = dense_normalization.width / sparse_normalization.width if sparse_normalization is not None else 1.0
        """Sparse → dense displacement scale (dense face width / sparse face width)."""
        if camera_to_model is not None:
            camera_to_model = as_finite_array(camera_to_model, "camera_to_model", shape=(4, 4), max_abs=1e6)
        self.camera_to_model = camera_to_model
        """Camera → sparse model similarity, 4×4 (set on the first usable frame if not given)."""
        self._stable_spec = stabilize
        self.min_confidence = as_bounded(min_confidence, "min_confidence", 0.0, 1.0)

        count = self.dense_rest.shape[0]
        dev = self.device
        self._corners, self._weighted_bary = _transfer_coefficients(
            self.sparse_triangles, self.correspondence, self.weights, dev
        )
        self._weights = wp.array(self.weights, dtype=float, device=dev)
        self._rest = wp.array(self.dense_rest.astype(np.float32), dtype=wp.vec3, device=dev)
        self._sparse_disp = wp.zeros(n, dtype=wp.vec3, device=dev)
        self._sparse_view = (
            self._sparse_disp.numpy() if self._sparse_disp.device.is_cpu else None
        )  # zero-copy on the CPU
        self._other = wp.zeros(count, dtype=wp.vec3, device=dev)
        self.displacements = wp.zeros(count, dtype=wp.vec3, device=dev)
        """Dense displacements of the last frame [m], shape (V,), vec3, on the device."""
        self.points = wp.zeros(count, dtype=wp.vec3, device=dev)
        """Dense points of the last frame [m], shape (V,), vec3, on the device."""
        self._record_transfer()
        self.reset()

    def _record_transfer(self) -> None:
        """Record the transfer launch, without and with ``other``: packing its ten arguments anew
        every frame costs a fifth of the kernel itself on the CPU."""
        self._recorded_scale = float(self.scale)
        self._transfer_launches = tuple(
            wp.launch(
                _transfer_kernel,
                dim=self.dense_rest.shape[0],
                inputs=[
                    self._sparse_disp,
                    self._corners,
                    self._weighted_bary,
                    self._weights,
                    self._recorded_scale,
                    self._rest,
                    self._other,
                    flag,
                ],
                outputs=[self.displacements, self.points],
                device=self.device,
                record_cmd=True,
            )
            for flag in (0, 1)
        )

    # -- state -----------------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget the reference frame, held landmarks and (if it was fitted) the camera transform."""
        n = self.sparse_rest.shape[0]
        self._reference = np.full((n, 3), np.nan)  # camera frame (after stabilisation)
        self.sparse_displacement = np.zeros((n, 3))
        """Sparse displacements of the last frame [m], shape (N, 3), model frame."""
        self._selection: np.ndarray | None = None
        self._stable: np.ndarray | None = None
        self._source_names: tuple[str, ...] | None = None
        self.frames_processed = 0
        if getattr(self, "_fitted_camera", False):
            self.camera_to_model = None
        self._fitted_camera = False

    def driven_vertices(self, threshold: float = 0.999) -> np.ndarray:
        """Indices of dense vertices whose weight ≥ ``threshold`` (fully driven: Dirichlet for the FEM)."""
        return np.flatnonzero(self.weights >= threshold)

    def bind(self, source_names: Sequence[str]) -> None:
        """Match a source's landmark names to the sparse vertices.

        Extra source landmarks are ignored.

        Raises:
            ValueError: a sparse vertex has no landmark of its name in the source (names listed),
                or (without names) the counts differ.
        """
        names = tuple(str(x) for x in source_names)
        n = self.sparse_rest.shape[0]
        if self.landmark_names is None:
            if len(names) != n:
                raise ValueError(
                    f"the source has {len(names)} landmarks but the sparse mesh has {n} vertices "
                    "(give landmark_names to match by name)"
                )
            self._selection = np.arange(n)
        else:
            where = {name: i for i, name in enumerate(names)}
            missing = [name for name in self.landmark_names if name not in where]
            if missing:
                shown = ", ".join(repr(m) for m in missing[:5]) + (" …" if len(missing) > 5 else "")
                raise ValueError(f"the source lacks {len(missing)} of the sparse mesh's landmarks: {shown}")
            self._selection = np.array([where[name] for name in self.landmark_names])
        self._source_names = names
        spec = self._stable_spec
        if spec is False or spec is None:
            self._stable = None
        elif spec is True:
            self._stable = np.arange(n)
        else:
            if isinstance(spec, (str, bytes)) or not hasattr(spec, "__iter__"):
                raise ValueError(f"stabilize: expected True, False, or sparse vertex indices or names, got {spec!r}")
            items = list(spec)
            if items and isinstance(items[0], str):
                if self.landmark_names is None:
                    raise ValueError("stabilize: names need landmark_names")
                lookup = {name: i for i, name in enumerate(self.landmark_names)}
                unknown = [s for s in items if s not in lookup]
                if unknown:
                    raise ValueError(f"stabilize: unknown landmark names {unknown[:5]}")
                items = [lookup[s] for s in items]
            if not all(isinstance(i, (int, np.integer)) and not isinstance(i, bool) for i in items):
                raise TypeError("stabilize: expected True, or sparse vertex indices or names")
            stable = np.asarray(items, dtype=np.int64)
            if stable.size < 3 or stable.min() < 0 or stable.max() >= n:
                raise ValueError("stabilize: need ≥ 3 valid sparse vertex indices")
            self._stable = stable

    # -- per frame -------------------------------------------------------------------------------

    def _select(self, frame: LandmarkFrame) -> tuple[np.ndarray, np.ndarray]:
        if self._selection is None:
            if self.landmark_names is not None:
                raise ValueError("landmark names are set: call bind(source.landmark_names) or use track(source)")
            self.bind([str(i) for i in range(frame.landmark_count)])
        expected = len(self._source_names)
        if frame.landmark_count != expected:
            raise ValueError(
                f"frame {frame.index} has {frame.landmark_count} landmarks, the source was bound with {expected}"
            )
        pts = frame.points[self._selection]
        valid = np.all(np.isfinite(pts), axis=1) & (frame.confidence[self._selection] > self.min_confidence)
        return pts, valid

    def update_sparse(self, frame: LandmarkFrame) -> np.ndarray:
        """Steps 1–4 for one frame: the sparse displacements [m], shape (N, 3), model frame."""
        pts, valid = self._select(frame)
        if self.camera_to_model is None:
            if valid.sum() < 4:
                return self.sparse_displacement  # nothing to anchor the model frame yet: hold
            s, rot, t, _ = similarity_fit(pts[valid], self.sparse_rest[valid])
            self.camera_to_model = np.eye(4)
            self.camera_to_model[:3, :3] = s * rot
            self.camera_to_model[:3, 3] = t
            self._fitted_camera = True
        if self._stable is not None:
            ref_ok = np.all(np.isfinite(self._reference), axis=1)
            use = np.zeros_like(valid)
            use[self._stable] = True
            use &= valid & ref_ok
            if use.sum() >= 3:
                rot, t = rigid_fit(pts[use], self._reference[use])
                pts = pts @ rot.T + t
        new = valid & ~np.all(np.isfinite(self._reference), axis=1)
        self._reference[new] = pts[new]
        linear = self.camera_to_model[:3, :3]
        moved = (pts[valid] - self._reference[valid]) @ linear.T
        self.sparse_displacement = self.sparse_displacement.copy()
        self.sparse_displacement[valid] = moved
        return self.sparse_displacement

    def track_frame(self, frame: LandmarkFrame, *, other=None, copy: bool = True) -> np.ndarray:
        """Dense points [m] for one frame, shape (V, 3), float32, model frame.

        Args:
            frame: the landmarks.
            other: displacement [m] of the not-directly-driven part (V, 3) — e.g. the FEM's last
                solution — blended in with weight ``1 − w``; zero when ``None``.
            copy: return a copy (``False`` returns a view of the device buffer on CPU devices,
                overwritten by the next step).
        """
        disp = self.update_sparse(frame)
        if self._sparse_view is not None:
            self._sparse_view[:] = disp  # into the device buffer (float32), no temporary array
        else:
            self._sparse_disp.assign(disp.astype(np.float32))
        use_other = 0
        if other is not None:
            other = np.asarray(other, dtype=np.float32)
            if other.shape != (self.dense_rest.shape[0], 3) or not np.all(np.isfinite(other)):
                raise ValueError(f"other: expected finite shape ({self.dense_rest.shape[0]}, 3), got {other.shape}")
            self._other.assign(other)
            use_other = 1
        if float(self.scale) != self._recorded_scale:  # ``scale`` was changed by the caller
            self._record_transfer()
        self._transfer_launches[use_other].launch()
        self.frames_processed += 1
        out = self.points.numpy()
        if not np.all(np.isfinite(out)):
            raise ValueError(
                f"frame {frame.index}: the dense points overflow float32 (landmarks too far from the reference)"
            )
        return out.copy() if copy else out

    def track(
        self, source, *, frames: Iterable[LandmarkFrame] | None = None
    ) -> Iterator[tuple[LandmarkFrame, np.ndarray]]:
        """Yield ``(frame, dense_points (V, 3) float32)`` for every frame of ``source``.

        Binds the source's ``landmark_names`` first (ValueError if they do not cover the sparse
        mesh). ``frames`` overrides ``source.frames()`` (e.g. a :func:`fill_missing` stream).
        """
        self.bind(source.landmark_names)
        for frame in source.frames() if frames is None else frames:
            yield frame, self.track_frame(frame)
