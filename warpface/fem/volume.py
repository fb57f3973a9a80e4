"""Tissue volume from a face surface: thicken, close into a watertight shell, tetrahedralise.

The render surface of a face is an open triangle mesh (boundary loops at the rim, the eyes and the
mouth) whose triangles are wound so their normals point out of the tissue, toward the viewer. The
soft tissue under it is modelled as a shell of per-vertex thickness ``h`` [m]:

1. **Coarsen** (optional). The FEM needs far fewer nodes than the render surface has vertices
   (Kato's face had 6,434 nodes, SPEC §2.1), and fTetWild keeps every input vertex, so the surface
   is first decimated to the target resolution (VTK quadric decimation through PyVista, which
   pytetwild imports anyway, boundaries held in place), and the nearly flat "ear" triangles that
   leaves along the boundary are dropped. Thickness is carried over by closest-point lookup on the
   input surface (a Warp kernel over ``wp.Mesh``).
2. **Offset.** Each vertex moves inward by ``h`` along its offset direction: the area-weighted
   vertex normal, Laplacian-smoothed only as often as needed for no inner triangle to flip. An
   inward offset folds over itself where ``h`` exceeds the local radius of a convex feature (nose
   tip, lip margins); smoothing the directions is the usual remedy, and when it cannot avoid the
   fold — or tilts the directions so far that the shell crosses itself — the thickness is wrong for
   that geometry and a ``ValueError`` says where. Surfaces with cavities (nostrils) or margins that
   curl into the head are thickened through a proxy (:func:`warpface.fem.proxy.tissue_proxy`),
   the mesher thins the thickness locally where the offset still folds or crosses itself
   (``thin_defects``, on by default: the lips and lids of the built-in face need it), and
   ``fair_folds`` lets it also relax the coarsened surface there.
3. **Close.** The inner surface (winding reversed, normals out of the tissue) is stitched to the
   outer one along every boundary loop by side quads split into two triangles. The shell is
   checked watertight (every edge used by exactly two triangles, once in each direction) and free
   of self-intersections (a Warp kernel over a BVH of triangle bounds, exact double-precision
   triangle–triangle tests).
4. **Tetrahedralise** with fTetWild (pytetwild), then orient the tets positively, reject inverted
   or degenerate ones, and compare the tet volume with the shell's enclosed volume.

Units are those of the input (metres in warpface). Everything except the Warp kernels is set-up
NumPy run once; pytetwild and PyVista are imported lazily.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field

import numpy as np

from ..geometry.mesh_index import closest_points
from ..geometry.surface_checks import as_surface, boundary_loops, check_surface, find_self_intersections
from ..geometry.triangles import triangle_areas, triangle_corners
from .shell import ShellSurface, fair_locally, offset_shell, shell_defects, thickness_per_vertex
from .tetmesh import TetMesh, TetQuality
from .tetwild import tetrahedralize_validated

__all__ = ["MESHING_STAGES", "MeshingReport", "TissueMeshing", "mesh_tissue", "tissue_from_surface"]

_SQRT3 = float(np.sqrt(3.0))

# fTetWild stops optimising once the worst element's conformal AMIPS energy is below this (its
# default, 10, costs several more passes over the whole bounding box for little FEM benefit: the
# passes it saves remove only the last few slivers, which the quality report still shows).
_STOP_ENERGY = 100.0

# Node count of fTetWild's output per vertex of the input shell, measured on the built-in face
# (1.3 with the default envelope); used to turn ``target_nodes`` into a surface resolution.
_TETWILD_NODE_FACTOR = 1.3


@dataclass(frozen=True)
class MeshingReport:
    """What :func:`mesh_tissue` did and the quality of the result."""

    input_vertices: int
    """Vertices of the input surface."""
    surface_vertices: int
    """Vertices of the (decimated) outer surface given thickness."""
    boundary_loops: int
    """Boundary loops of the input surface (rim, eyes, mouth ...)."""
    input_intersections: int
    """Pairs of crossing triangles in the input surface (0 unless ``input_intersections="ignore"``)."""
    shell_triangles: int
    """Triangles of the closed shell handed to fTetWild."""
    smoothing_iterations: int
    """Laplacian passes the offset directions needed (0: plain vertex normals)."""
    thickness_range: tuple[float, float]
    """Smallest and largest thickness used [m]."""
    edge_length: float
    """Target tet edge length given to fTetWild [m]."""
    node_count: int
    """Nodes of the tet mesh."""
    tet_count: int
    """Tets of the tet mesh."""
    quality: TetQuality
    """Dihedral angles and volumes of the tets (inverted count 0: inverted tets are rejected)."""
    shell_volume: float
    """Volume enclosed by the shell [m^3]."""
    tet_volume: float
    """Total volume of the tets [m^3]."""
    timings: dict = field(default_factory=dict)
    """Seconds per stage: "decimate", "shell", "tetrahedralize", "validate", "total"."""
    fairing_rounds: int = 0
    """Rounds of local fairing the coarsened surface needed for a clean shell (``fair_folds``)."""
    thinning_rounds: int = 0
    """Rounds of thickness clamping the shell needed (``thin_defects``)."""
    tetwild_runs: int = 1
    """fTetWild runs it took to get tets that pass validation (see ``TETWILD_ATTEMPTS``)."""

    @property
    def volume_error(self) -> float:
        """Relative difference of the tet volume from the shell volume."""
        return abs(self.tet_volume - self.shell_volume) / self.shell_volume

    @property
    def sliver_fraction(self) -> float:
        """Fraction of tets whose smallest dihedral angle is below 10 degrees."""
        return float(np.mean(self.quality.per_tet_min_dihedral_deg < 10.0))

    def __str__(self) -> str:
        q = self.quality
        t = ", ".join(f"{k} {v:.2f} s" for k, v in self.timings.items())
        return (
            f"{self.node_count} nodes, {self.tet_count} tets from a {self.surface_vertices}-vertex surface "
            f"({self.input_vertices} input, {self.boundary_loops} boundary loops"
            + (f", {self.input_intersections} crossing triangle pairs" if self.input_intersections else "")
            + f"), edge {self.edge_length * 1e3:.2f} mm, "
            + (f"{self.thinning_rounds} thickness clamping rounds, " if self.thinning_rounds else "")
            + (f"{self.fairing_rounds} local fairing rounds, " if self.fairing_rounds else "")
            + (f"{self.tetwild_runs} fTetWild runs, " if self.tetwild_runs > 1 else "")
            + f"thickness {self.thickness_range[0] * 1e3:.2f}..{self.thickness_range[1] * 1e3:.2f} mm; "
            f"dihedral {q.min_dihedral_deg:.2f}..{q.max_dihedral_deg:.2f} deg, {100 * self.sliver_fraction:.2f} % "
            f"below 10 deg, {q.inverted_count} inverted; volume {self.tet_volume:.4e} m^3 "
            f"({100 * self.volume_error:.2f} % from the shell); {t}"
        )


@dataclass(frozen=True)
class TissueMeshing:
    """Result of :func:`mesh_tissue`: the tet mesh, the shell it fills, and the report."""

    tetmesh: TetMesh
    """The validated, positively oriented tet mesh."""
    shell: ShellSurface
    """The closed shell that was tetrahedralised."""
    report: MeshingReport
    """Sizes, quality and timings."""


def _surface_area(points: np.ndarray, triangles: np.ndarray) -> float:
    return float(triangle_areas(triangle_corners(points, triangles)).sum())


def _edge_length_for(area: float, mean_thickness: float, target_nodes: int) -> float:
    """Tet edge length [m] expected to give ``target_nodes`` nodes for a shell of this area and thickness.

    A surface of area A meshed with equilateral triangles of edge L has ``2A / (sqrt(3) L^2)``
    vertices; the shell has that many on each side plus ``h / L - 1`` interior layers when
    ``h > L``; fTetWild adds about ``_TETWILD_NODE_FACTOR - 1`` more.
    """
    length = np.sqrt(2.0 * area * 2.0 / (_SQRT3 * target_nodes))
    for _ in range(20):  # fixed point: the layer count depends on L
        layers = 2.0 + max(0.0, mean_thickness / length - 1.0)
        length = np.sqrt(2.0 * area * layers * _TETWILD_NODE_FACTOR / (_SQRT3 * target_nodes))
    return float(length)


def _decimate(points: np.ndarray, triangles: np.ndarray, target_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Quadric decimation (VTK through PyVista) of an open surface, boundaries kept in place."""
    import pyvista as pv

    cells = np.hstack([np.full((len(triangles), 1), 3, dtype=np.int64), triangles]).ravel()
    poly = pv.PolyData(points, cells)
    # an open surface has about twice as many triangles as vertices
    reduction = 1.0 - min(1.0, 2.0 * target_vertices / len(triangles))
    reduced = poly.decimate(reduction, volume_preservation=True, boundary_constraints=True, boundary_weight=10.0)
    out_points = np.asarray(reduced.points, dtype=np.float64)
    out_triangles = np.asarray(reduced.faces).reshape(-1, 4)[:, 1:].astype(np.int64)
    used = np.zeros(len(out_points), dtype=bool)
    used[out_triangles.ravel()] = True
    remap = np.cumsum(used) - 1
    return out_points[used], remap[out_triangles]


def _sample_at_closest_points(
    points: np.ndarray, triangles: np.ndarray, values: np.ndarray, queries: np.ndarray, device
) -> np.ndarray:
    """A per-vertex field (V,) of a triangle surface, interpolated at the surface point closest to each
    query (Q, 3), by :func:`warpface.geometry.mesh_index.closest_points`."""
    triangle, barycentric, _ = closest_points(queries, points, triangles, device=device)
    corners = np.asarray(triangles)[triangle]
    return np.sum(barycentric.astype(np.float64) * np.asarray(values, dtype=np.float64)[corners], axis=1)


def _remove_ears(points: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop boundary "ears": triangles whose middle vertex belongs to no other triangle.

    Decimation with fixed boundaries leaves many of them along the rim, each nearly flat (three
    consecutive boundary vertices); their offset flips at the slightest turn of the directions.
    """
    while True:
        valence = np.bincount(triangles.ravel(), minlength=len(points))
        ear = (valence[triangles] == 1).any(axis=1)
        lonely = (valence[triangles] == 1).sum(axis=1) > 1  # an isolated triangle is not an ear
        ear &= ~lonely
        if not ear.any():
            break
        triangles = triangles[~ear]
    used = np.zeros(len(points), dtype=bool)
    used[triangles.ravel()] = True
    remap = np.cumsum(used) - 1
    return points[used], remap[triangles]


def mesh_tissue(
    surface,
    thickness,
    *,
    target_nodes: int | None = 6400,
    edge_length: float | None = None,
    decimate: bool = True,
    envelope: float = 1.5e-3,
    optimize_passes: int = 2,
    threads: int = 0,
    max_smoothing: int = 200,
    input_intersections: str = "error",
    thin_defects: int = 6,
    fair_folds: int = 0,
    timeout: float | None = 600.0,
    progress=None,
    device=None,
) -> TissueMeshing:
    """Tetrahedralise the tissue under a face surface; see the module docstring for the steps.

    Args:
        surface: :class:`~warpface.FaceMesh` or ``(points (V, 3), triangles (T, 3))`` [m], an
            oriented open manifold whose normals point out of the tissue.
        thickness: Tissue thickness [m] under each vertex: a scalar, shape (V,), or an object with
            ``sample(points, device) -> (V,)`` such as :class:`~warpface.ThicknessMap`; all > 0.
        target_nodes: Approximate node count of the result (Kato: 6,434); sets the tet edge length
            and the decimation. Ignored when ``edge_length`` is given.
        edge_length: Target tet edge length [m] (fTetWild's ideal edge length).
        decimate: Coarsen the surface to the edge length first (strongly recommended for a dense
            render surface: fTetWild keeps every input vertex and its run time grows with them).
        envelope: fTetWild's envelope (how far its boundary may stray from the shell), relative to
            the shell's bounding-box diagonal.
        optimize_passes: Most fTetWild optimisation passes (split, collapse, swap, smooth over its
            whole bounding-box mesh, the bulk of the meshing time). It stops as soon as no element's
            AMIPS energy exceeds 100, which on faces takes one pass.
        threads: fTetWild threads (0: all cores). Meshing is NOT reproducible: fTetWild has no seed
            and gives slightly different meshes from run to run even with one thread (the built-in
            face at 1,500 target nodes gave 1,796 to 1,851 nodes over four runs). Save a mesh you
            need again (:func:`warpface.usd.write_tissue_mesh`) instead of re-meshing.
        max_smoothing: See :func:`offset_shell`.
        input_intersections: What a self-intersecting input surface does: ``"error"`` (raise) or
            ``"ignore"`` (count it in the report and go on: scanned and artist faces often fold a
            little, e.g. ICT-FaceKit's alar creases cross the cheek). The shell that is
            tetrahedralised is always checked.
        thin_defects: Most rounds of thickness clamping where the offset shell folds or crosses
            itself (a thickness beyond the local radius of curvature, or beyond the gap between the
            lips or lids): each round thins the thickness at the defect by 15 % and smooths it within
            two edge rings; the outer surface is not moved, so the tissue still fits the skin. 6
            rounds keep at least 38 % of the input thickness there. 0 refuses such a shell.
        fair_folds: Rounds of local fairing tried after ``thin_defects``: like a thinning round, but
            the coarsened surface is smoothed too (it moves away from the skin by up to a fraction
            of an edge; needed for surfaces that fold, e.g. scanned faces).
        timeout: Seconds fTetWild may take before it is stopped (``None``: no limit).
        progress: Report progress: ``True`` shows a tqdm bar (when tqdm is installed), ``False``
            nothing, ``None`` (default) a bar only when stderr is a terminal; or a callable
            ``progress(stage, seconds)`` called as each stage ("decimate", "offset shell",
            "tetrahedralize", "validate") starts and about twice a second during fTetWild, with
            the seconds spent in that stage so far.
        device: Warp device for the geometric kernels; ``None`` uses Warp's preferred device.

    Returns:
        :class:`TissueMeshing` with the tet mesh, the shell and a :class:`MeshingReport`.

    Raises:
        ValueError: bad surface or thickness (see :func:`check_surface`, :func:`offset_shell`), a
            self-intersecting input surface, or a fTetWild result with inverted or degenerate tets
            or a volume far from the shell's (naming what failed).
        RuntimeError: fTetWild crashed or ran past ``timeout``.
    """
    start = time.perf_counter()
    with contextlib.closing(_progress_reporter(progress)) as report_stage:
        points, triangles = as_surface(surface)
        boundary = check_surface(points, triangles, closed=False, name="face surface")
        if len(boundary) == 0:
            raise ValueError("face surface has no boundary loop: it is already closed, not a skin surface to thicken")
        loop_count = len(boundary_loops(boundary))
        h_fine = thickness_per_vertex(thickness, points, device=device)
        if input_intersections not in ("error", "ignore"):
            raise ValueError(f"input_intersections must be 'error' or 'ignore', got {input_intersections!r}")
        crossings, pairs = find_self_intersections(points, triangles, device=device)
        if crossings and input_intersections == "error":
            i, j = (int(x) for x in pairs[0])
            raise ValueError(
                f"face surface intersects itself: {crossings} pairs of triangles cross, first {i} and {j} near "
                f"{np.round(points[triangles[i]].mean(axis=0), 5).tolist()} m (input_intersections='ignore' "
                "meshes it anyway when the coarsened shell is clean)"
            )

        area = _surface_area(points, triangles)
        if edge_length is None:
            if target_nodes is None or int(target_nodes) < 8:
                raise ValueError(
                    f"target_nodes must be an integer >= 8 when edge_length is not given, got {target_nodes}"
                )
            edge_length = _edge_length_for(area, float(np.mean(h_fine)), int(target_nodes))
        edge_length = float(edge_length)
        if not (np.isfinite(edge_length) and edge_length > 0.0):
            raise ValueError(f"edge_length must be finite and > 0 [m], got {edge_length}")
        if not 0.0 < envelope < 0.1:
            raise ValueError(f"envelope must be in (0, 0.1) (relative to the bounding-box diagonal), got {envelope}")
        if int(optimize_passes) < 0:
            raise ValueError(f"optimize_passes must be >= 0, got {optimize_passes}")
        for option, rounds in (("thin_defects", thin_defects), ("fair_folds", fair_folds)):
            if isinstance(rounds, bool) or not isinstance(rounds, (int, np.integer)):
                raise TypeError(f"{option} must be an integer >= 0, got {type(rounds).__name__}")
            if rounds < 0:
                raise ValueError(f"{option} must be an integer >= 0, got {rounds!r}")

        t0 = time.perf_counter()
        report_stage("decimate", 0.0)
        surface_vertices = int(2.0 * area / (_SQRT3 * edge_length**2))
        if decimate and surface_vertices < 0.8 * len(points):
            coarse_points, coarse_triangles = _remove_ears(*_decimate(points, triangles, surface_vertices))
            coarse_boundary = check_surface(coarse_points, coarse_triangles, closed=False, name="decimated surface")
            coarse_loops = len(boundary_loops(coarse_boundary))
            if coarse_loops != loop_count:
                raise ValueError(
                    f"decimation to {len(coarse_points)} vertices changed the surface's boundary loops from "
                    f"{loop_count} to {coarse_loops}; ask for more nodes (target_nodes / edge_length) or decimate=False"
                )
            h = (
                _sample_at_closest_points(points, triangles, h_fine, coarse_points, device)
                if np.ptp(h_fine) > 0.0
                else (np.full(len(coarse_points), float(h_fine[0])))
            )
        else:
            coarse_points, coarse_triangles, h = points, triangles, h_fine
        t1 = time.perf_counter()
        report_stage("offset shell", 0.0)
        thinning_rounds = fairing_rounds = 0
        while True:
            try:
                shell = offset_shell(coarse_points, coarse_triangles, h, max_smoothing=max_smoothing, device=device)
                break
            except ValueError:
                thinning = thinning_rounds < int(thin_defects)
                defects = (
                    shell_defects(coarse_points, coarse_triangles, h, max_smoothing=max_smoothing, device=device)
                    if (thinning or fairing_rounds < int(fair_folds))
                    else np.zeros(0, dtype=np.int64)
                )
                if len(defects) == 0:
                    raise
                coarse_points, h = fair_locally(coarse_points, coarse_triangles, h, defects, move_surface=not thinning)
                if thinning:
                    thinning_rounds += 1
                else:
                    fairing_rounds += 1
        t2 = time.perf_counter()

        report_stage("tetrahedralize", 0.0)
        tetmesh, tetwild_runs = tetrahedralize_validated(
            shell,
            on_wait=lambda seconds: report_stage("tetrahedralize", seconds),
            edge_length_abs=edge_length,
            epsilon=float(envelope),
            optimize=int(optimize_passes) > 0,
            num_opt_iter=max(int(optimize_passes), 1),
            stop_energy=_STOP_ENERGY,
            simplify=False,  # the shell is already at the target resolution; fTetWild's own pass is slow
            num_threads=int(threads),
            quiet=True,
            timeout=timeout,
        )
        t3 = time.perf_counter()
        report_stage("validate", 0.0)
        quality = tetmesh.quality()
        t4 = time.perf_counter()
        report = MeshingReport(
            input_vertices=len(points),
            surface_vertices=len(coarse_points),
            boundary_loops=loop_count,
            input_intersections=int(crossings),
            shell_triangles=len(shell.triangles),
            smoothing_iterations=shell.smoothing_iterations,
            thickness_range=(float(h.min()), float(h.max())),
            edge_length=edge_length,
            node_count=tetmesh.node_count,
            tet_count=tetmesh.tet_count,
            quality=quality,
            shell_volume=shell.volume,
            tet_volume=tetmesh.total_volume,
            timings={
                "decimate": t1 - t0,
                "shell": t2 - t1,
                "tetrahedralize": t3 - t2,
                "validate": t4 - t3,
                "total": t4 - start,
            },
            fairing_rounds=fairing_rounds,
            thinning_rounds=thinning_rounds,
            tetwild_runs=tetwild_runs,
        )
        return TissueMeshing(tetmesh=tetmesh, shell=shell, report=report)


MESHING_STAGES = ("decimate", "offset shell", "tetrahedralize", "validate")
"""The stages :func:`mesh_tissue` reports to its ``progress`` callback, in order."""


class _StageReporter:
    """Forwards stage reports to a callable, or shows them on a tqdm bar of :data:`MESHING_STAGES`."""

    def __init__(self, callback=None, bar=None):
        self._callback, self._bar, self._stage = callback, bar, None

    def __call__(self, stage: str, seconds: float) -> None:
        if self._callback is not None:
            self._callback(stage, seconds)
        if self._bar is not None:
            if stage != self._stage:
                if self._stage is not None:
                    self._bar.update(1)
                self._stage = stage
            self._bar.set_postfix_str(f"{stage} {seconds:.0f} s")

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


def _progress_reporter(progress) -> _StageReporter:
    if callable(progress):
        return _StageReporter(callback=progress)
    if progress is not None and not isinstance(progress, (bool, np.bool_)):
        raise TypeError(
            f"progress must be True, False, None or a callable(stage, seconds), got {type(progress).__name__}"
        )
    if progress is None:
        import sys

        progress = bool(getattr(sys.stderr, "isatty", lambda: False)())
    if not progress:
        return _StageReporter()
    try:
        from tqdm.auto import tqdm
    except ImportError:
        return _StageReporter()
    return _StageReporter(bar=tqdm(total=len(MESHING_STAGES), unit="stage", desc="tissue meshing", leave=False))


def tissue_from_surface(surface, thickness, *, target_nodes: int | None = 6400, **options) -> TetMesh:
    """Tet mesh of the tissue under a face surface (see :func:`mesh_tissue` for the arguments).

    Returns:
        A validated, positively oriented :class:`~warpface.fem.TetMesh` [m]. Call
        :func:`mesh_tissue` instead to also get the :class:`MeshingReport` (quality, timings).
    """
    return mesh_tissue(surface, thickness, target_nodes=target_nodes, **options).tetmesh
