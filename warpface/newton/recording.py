"""Record the render skin of a Newton run and write it as a time-sampled USD point cache.

The skin of each recorded frame is the rig's rest skin moved by the tissue's displacement at its embedding
(``skin = S + Σ w_k d_{node k}``, :class:`~warpface.fem.Embedding`), in the head frame, or in the world
(``p + R skin``) with ``frame="world"``. :meth:`SkinRecorder.write` hands the frames to warpface's bake
writer (:func:`warpface.usd.write_point_cache`), which writes them like a bake: one cache layer sublayered under
the rig layer, written through a temporary file and a rename.
"""

from __future__ import annotations

import numpy as np

from .frame import head_motion

__all__ = ["SkinRecorder"]


class SkinRecorder:
    """Collects skin frames of a :class:`~warpface.newton.SolverFace` run.

    Args:
        solver: The face's solver.
        frame: ``"head"`` (default: the deformation alone, in the rig's frame) or ``"world"`` (with the head's
            rigid motion).
    """

    def __init__(self, solver, *, frame: str = "head"):
        if frame not in ("head", "world"):
            raise ValueError(f"SkinRecorder: frame must be 'head' or 'world', got {frame!r}")
        self.solver = solver
        self.frame = frame
        self.times: list[float] = []
        """Time codes of the recorded frames."""
        self.frames: list[np.ndarray] = []
        """Skin positions [m] per frame, each (V, 3) float32."""

    def skin(self, state=None) -> np.ndarray:
        """The skin now [m], shape (V, 3), float64: head frame, or world with ``state``'s head pose."""
        solver = self.solver
        rest = np.asarray(solver.face.rig.mesh.points, dtype=np.float64)
        if solver.simulation is None:
            skin = rest.copy()
        else:
            skin = rest + solver.face.embedding.apply(solver.simulation.d, device="cpu")
        if self.frame == "world" and state is not None:
            motion = head_motion(solver.model, state, state, solver.face.head_body, 1.0)
            skin = motion.position + skin @ motion.rotation.T
        return skin

    def record(self, time_code: float, state=None) -> None:
        """Store the skin at ``time_code`` (``state`` gives the head pose for ``frame="world"``)."""
        self.times.append(float(time_code))
        self.frames.append(self.skin(state).astype(np.float32))

    def write(self, stage_or_path, *, cache_path=None, skin_path: str | None = None):
        """Write the recorded frames as the rig stage's skin point cache (stage units converted from metres);
        returns the cache path. ValueError when nothing was recorded."""
        if not self.frames:
            raise ValueError("SkinRecorder.write: no frame was recorded")
        from ..usd import open_stage, write_point_cache
        from ..usd.rig_io import stage_meters_per_unit

        stage = open_stage(stage_or_path)
        positions = np.stack(self.frames) / stage_meters_per_unit(stage)
        return write_point_cache(stage, self.times, positions, cache_path=cache_path, skin_path=skin_path)
