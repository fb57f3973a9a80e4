"""Physical interpolation (SPEC §3 step 4): the tissue FEM decides where tracking does not reach.

The directly driven region of a :class:`TrackingAdapter` (blend weight ≈ 1) becomes Dirichlet
conditions on the tissue's tet nodes; the tissue's bone side stays fixed; a
:class:`~warpface.fem.TissueSimulation` advances between camera frames; the embedding carries the
node displacements to the surface; the two motions are blended with the adapter's smooth weights:
``u = w·u_tracked + (1 − w)·u_fem``.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..fem.kernels_integrator import interpolate_control
from ..fem.state import TissueControl

__all__ = ["TissueDrive", "bone_side_nodes"]


def bone_side_nodes(tetmesh, surface_points: np.ndarray, thickness: float) -> np.ndarray:
    """Boundary nodes of the tissue lying deeper than half the ``thickness`` [m] below the skin:
    the side attached to the skull. Returns node indices (K,), int64."""
    from scipy.spatial import cKDTree

    boundary = np.unique(tetmesh.boundary_faces)
    depth, _ = cKDTree(np.asarray(surface_points)).query(tetmesh.points[boundary])
    return boundary[depth > 0.5 * thickness].astype(np.int64)


class TissueDrive:
    """Drive a tissue simulation with tracked surface motion, one camera frame at a time.

    Args:
        adapter: the :class:`~warpface.tracking.TrackingAdapter` whose dense face is the skin.
        tetmesh: the tissue under that skin (:func:`warpface.fem.tissue_from_surface`).
        material: a :class:`~warpface.fem.TissueMaterial`.
        fps: camera frame rate [1/s].
        dt: FEM time step [s]; each frame advances ``round(1 / (fps·dt))`` Newmark steps with the
            driven displacements interpolated linearly across them.
        fixed: tet nodes held still (default: :func:`bone_side_nodes` with ``thickness``).
        thickness: tissue thickness [m] used to find the bone side when ``fixed`` is not given.
        formulation: FEM formulation (``"anp"`` does not lock at ν ≈ 0.5).
        device: Warp device.

    Calling the drive with ``(frame, dense_points)`` from :meth:`TrackingAdapter.track` returns the
    blended dense points (V, 3), float32.
    """

    def __init__(
        self,
        adapter,
        tetmesh,
        material,
        *,
        fps: float,
        dt: float = 1e-3,
        fixed=None,
        thickness: float | None = None,
        formulation: str = "anp",
        device=None,
    ):
        from ..fem import TissueSimulation
        from ..fem.embedding import embed_points

        self.adapter = adapter
        self.embedding = embed_points(tetmesh, adapter.dense_rest, device=device)
        driven_vertices = adapter.driven_vertices()
        if len(driven_vertices) == 0:
            raise ValueError("the tracking adapter drives no vertex directly; nothing to drive the tissue with")
        nodes = self.embedding.nodes_for(driven_vertices)
        self.driven_nodes, first = np.unique(nodes, return_index=True)
        self._driven_vertex = driven_vertices[first]  # the skin vertex whose motion each driven node takes
        if fixed is None:
            if thickness is None:
                raise ValueError("give the fixed nodes or the tissue thickness (to find the bone side)")
            fixed = bone_side_nodes(tetmesh, adapter.dense_rest, thickness)
        self.fixed_nodes = np.setdiff1d(np.asarray(fixed, dtype=np.int64), self.driven_nodes)
        self.substeps = max(1, int(round(1.0 / (float(fps) * float(dt)))))
        self.simulation = TissueSimulation(
            tetmesh,
            material,
            dt,
            fixed=self.fixed_nodes,
            driven=self.driven_nodes,
            formulation=formulation,
            device=device,
        )
        self.device = device
        self._weights = adapter.weights.astype(np.float32)[:, None]
        # The tissue's state stays on its device: per frame one upload of the driven targets, the
        # sub-step controls interpolated by a kernel, one download of the embedded skin.
        sim = self.simulation
        self.control = TissueControl(len(self.driven_nodes), device=sim.state.device)
        """Driven displacements of the current sub-step (device)."""
        self._previous = TissueControl(len(self.driven_nodes), device=sim.state.device)
        self._target = TissueControl(len(self.driven_nodes), device=sim.state.device)

    def __call__(self, frame, dense_points: np.ndarray) -> np.ndarray:
        rest = self.adapter.dense_rest
        tracked = np.asarray(dense_points, dtype=np.float64) - rest
        sim = self.simulation
        count = len(self.driven_nodes)
        target = self._target.driven
        target.assign(np.pad(tracked[self._driven_vertex], ((0, target.shape[0] - count), (0, 0))))
        for k in range(1, self.substeps + 1):
            wp.launch(
                interpolate_control,
                dim=target.shape[0],
                inputs=[self._previous.driven, target, wp.float64(k / self.substeps)],
                outputs=[self.control.driven],
                device=target.device,
            )
            sim.step(self.control)
        wp.copy(self._previous.driven, target)
        skin = self.embedding.apply(sim.state.d).numpy()  # waits for the steps
        sim.synchronize()  # raises if a CG step failed to converge
        return (rest + self._weights * tracked + (1.0 - self._weights) * skin).astype(np.float32)
