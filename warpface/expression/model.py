"""``ExpressionModel``: the rig's data for the expression pipeline of SPEC §1 on one Warp device."""

from __future__ import annotations

from typing import Sequence

import numpy as np
import warp as wp

from .._validate import MAX_COORDINATE, as_device
from ..mesh import FaceMesh
from .controls import check_rig_parts, contraction_limits, control_vector, frame_controls
from .evaluator import ExpressionEvaluator, ExpressionStages
from .fold_guard import face_size
from .jaw import JAW_CONTROL_NAMES, Jaw
from .kernels import MuscleEntry, WrinkleEntry
from .muscles import Muscle
from .plans import PLANS, tiled_rig
from .rig_fields import rig_fields
from .tiling import mesh_tiles
from .wrinkles import Wrinkle

__all__ = ["ExpressionModel", "ExpressionStages"]


class ExpressionModel:
    """Jaw → muscles → stretch → bulge → wrinkles, per vertex, from the rest mesh every frame (never cumulative).

    The model is the rig's data on one device: everything that depends only on the rig (muscle weight fields,
    wrinkle profiles, the tiles of the tiled plan) is evaluated once here in float64 and stored as Warp arrays
    that never change. Evaluation state (work buffers, recorded launches, CUDA graphs, pinned readbacks) lives in
    an :class:`~warpface.expression.evaluator.ExpressionEvaluator`: :meth:`evaluate` uses the model's own, and
    :meth:`evaluator` makes another (e.g. one per CUDA stream).

    One call evaluates one frame or a batch, chosen by the controls' shape, and returns NumPy or writes into a
    caller's device array (a ``wp.array`` or any DLPack tensor, e.g. torch) without a host sync::

        points = model.evaluate({"zygomatic_major_L": 0.01})         # (V, 3) float32
        frames = model.evaluate(controls)                             # controls (F, C) → (F, V, 3)
        model.evaluate(torch_controls, out=torch_points)             # float32 (F, C) on the device; no sync

    Synchronise (``wp.synchronize_device``) or share the stream before reading a device result on the host. On
    the CPU several threads may evaluate at once (each thread has its own work buffers; Warp's CPU kernels release
    the GIL).

    Controls are always the rig's full control vector (:attr:`control_names`: the muscles, then the jaw's
    :data:`~warpface.expression.JAW_CONTROL_NAMES` when there is a jaw), named or positional. Host values are
    checked (names, types, finite, within range; ``ValueError`` naming the item); device-resident values are used
    as they are (checking them would need a host sync).

    Args:
        mesh: the rest surface.
        muscles: linear and sphincter muscles; their order is the contraction order.
        wrinkles: wrinkle furrows; their order is the depth order.
        thickness: subcutaneous thickness ``h`` [mesh units]: a scalar or shape (V,), in [0, 1e6].
        device: Warp device (default: Warp's preferred device).
        jaw: optional :class:`~warpface.expression.Jaw`, applied before the muscles (SPEC §6.2).
        plan: ``"staged"`` (five kernels, every intermediate stored; the CPU default) or ``"tiled"`` (one kernel
            over vertex tiles in shared memory; the CUDA default, which falls back to staged for a mesh a tile
            cannot hold). Both give the same bits on the same device (:mod:`~warpface.expression.plans`).
        size: the face's size [mesh units], which the tissue's rig-time lengths are fractions of
            (:func:`~warpface.expression.fold_guard.face_size`; default: the mesh's bounding-box diagonal;
            :meth:`from_rig` measures it with the rig's landmarks).

    Raises:
        RigError: (a ``ValueError``) mesh not a FaceMesh, wrong item types, duplicate muscle or
            wrinkle names, wrong thickness — the same errors :class:`~warpface.FaceRig` raises.
    """

    def __init__(
        self,
        mesh: FaceMesh,
        muscles: Sequence[Muscle] = (),
        wrinkles: Sequence[Wrinkle] = (),
        thickness: float | np.ndarray = 0.0,
        *,
        device=None,
        jaw: Jaw | None = None,
        plan: str | None = None,
        size: float | None = None,
    ):
        self.muscles, self.wrinkles, self.thickness = check_rig_parts(
            mesh, muscles, wrinkles, thickness, owner="expression model"
        )
        self.mesh = mesh
        self.muscle_names = [m.name for m in self.muscles]
        self.wrinkle_names = [w.name for w in self.wrinkles]
        if jaw is not None:
            if not isinstance(jaw, Jaw):
                raise TypeError(f"jaw: expected a Jaw, got {type(jaw).__name__}")
            jaw.check_vertex_count(mesh.vertex_count)
            if set(JAW_CONTROL_NAMES) & set(self.muscle_names):
                raise ValueError(f"muscle names must not repeat the jaw's controls {', '.join(JAW_CONTROL_NAMES)}")
        self.jaw = jaw
        self.size = face_size(mesh.points) if size is None else float(size)
        """The face's size [mesh units] the rig-time fields were built with."""
        self.control_names = self.muscle_names + (list(JAW_CONTROL_NAMES) if jaw is not None else [])
        """Muscle names, then the jaw's controls when there is a jaw: the order of a control vector."""
        jaw_limits = np.full(len(self.control_names) - len(self.muscles), MAX_COORDINATE)
        self._contraction_limits = np.concatenate([contraction_limits(self.muscles), jaw_limits])
        self._depth_limits = np.full(len(self.wrinkles), MAX_COORDINATE)
        self.device = as_device(device)
        if plan is not None and (not isinstance(plan, str) or plan not in PLANS):
            raise ValueError(f"plan: expected one of {', '.join(map(repr, PLANS))} or None, got {plan!r}")
        self._mesh_buffers = mesh.device_buffers(device=self.device)
        self._upload_rig(mesh)
        tiles = None
        if (plan or ("staged" if self.device.is_cpu else "tiled")) == "tiled":
            # by default, a mesh that cannot be tiled runs the staged plan
            tiles = mesh_tiles(mesh, self._mesh_buffers, device=self.device, required=plan == "tiled")
        self.plan = "staged" if tiles is None else "tiled"
        """The evaluation plan: ``"staged"`` or ``"tiled"``."""
        self._tiled_rig = None if tiles is None else tiled_rig(self, tiles)
        self.block_dim = 256 if self.device.is_cuda else 1
        """Threads per block of every launch (the tiled plan's blocks are its third launch dimension)."""
        self._evaluator = ExpressionEvaluator(self)

    def _upload_rig(self, mesh: FaceMesh) -> None:
        """The rig-time fields (muscle weights with the tissue's response, wrinkle profiles) as device arrays."""
        device = self.device
        fields = rig_fields(mesh, self.muscles, self.wrinkles, self.thickness, self.jaw, self.size, device=device)
        weights, shapes, bulging, faded = fields.weights, fields.shapes, fields.bulging, fields.faded
        self.muscle_entry_count = int(len(weights.muscle))
        self.wrinkle_entry_count = int(len(shapes.wrinkle))
        self._muscle_offsets = wp.array(weights.offsets, dtype=wp.int32, device=device)
        self._muscle_entries = _entry_array(
            MuscleEntry, device, muscle=weights.muscle, weight=weights.weight.reshape(-1, 3)
        )
        self._wrinkle_offsets = wp.array(shapes.offsets, dtype=wp.int32, device=device)
        wrinkle_kr = np.array([w.kr for w in self.wrinkles], dtype=np.float32)
        self._wrinkle_entries = _entry_array(
            WrinkleEntry, device, wrinkle=shapes.wrinkle, shape=faded, kr=wrinkle_kr[shapes.wrinkle]
        )
        counted = np.bincount(mesh.triangles[~mesh.degenerate_triangles].ravel(), minlength=mesh.vertex_count)
        self._counts = wp.array(counted.astype(np.float32), dtype=wp.float32, device=device)
        self._thickness = wp.array(bulging.astype(np.float32), dtype=wp.float32, device=device)
        self.default_depths = np.array([w.depth for w in self.wrinkles], dtype=np.float64)
        if self.jaw is not None:
            self._jaw_weight = wp.array(self.jaw.weights.astype(np.float32), dtype=wp.float32, device=device)

    @classmethod
    def from_rig(cls, rig, *, device=None, plan: str | None = None) -> "ExpressionModel":
        """Build from a :class:`warpface.FaceRig` (mesh, muscles, wrinkles, thickness, jaw; its landmarks bound the
        face's size, :func:`~warpface.expression.fold_guard.face_size`)."""
        if not all(
            hasattr(rig, field) for field in ("mesh", "muscles", "wrinkles", "thickness")
        ):  # warpface.rig imports this module
            raise TypeError(f"rig: expected a FaceRig, got {type(rig).__name__}")
        jaw = getattr(rig, "jaw", None)
        size = face_size(rig.mesh.points, getattr(rig, "landmarks", None))
        return cls(rig.mesh, rig.muscles, rig.wrinkles, rig.thickness, device=device, jaw=jaw, plan=plan, size=size)

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, controls=None, out=None, *, wrinkle_depths=None, progress: bool = False, frames_per_launch=None):
        """Deformed positions of one frame or a batch; see :meth:`ExpressionEvaluator.evaluate
        <warpface.expression.evaluator.ExpressionEvaluator.evaluate>` (the model's own evaluator runs it)."""
        return self._evaluator.evaluate(
            controls, out, wrinkle_depths=wrinkle_depths, progress=progress, frames_per_launch=frames_per_launch
        )

    def stages(self, controls=None, *, wrinkle_depths=None) -> ExpressionStages:
        """One frame's intermediate results (x1, r, x2, x3) from the staged plan, for inspection."""
        return self._evaluator.stages(controls, wrinkle_depths=wrinkle_depths)

    def evaluator(self) -> ExpressionEvaluator:
        """A new evaluator of this model with its own work buffers, graphs and readbacks."""
        return ExpressionEvaluator(self)

    # ------------------------------------------------------------------ controls
    def control_vector(self, controls) -> np.ndarray:
        """One frame's controls in :attr:`control_names` order, shape (C,), float64.

        ``controls``: a mapping ``{muscle or jaw control name: value}`` (absent ones are 0), the full control
        vector (C numbers), or ``None`` (all 0). Non-numbers raise TypeError; unknown names, a wrong length,
        non-finite values and values beyond ±1e6 (linear muscles and jaw, lengths and radians) or ±1e3
        (sphincters) raise ValueError; both name the control.
        """
        kind = "muscle" if self.jaw is None else "control"
        zeros = np.zeros(len(self.control_names))
        limits = self._contraction_limits
        return control_vector(controls, self.control_names, zeros, limits, "contraction", kind, argument="controls")

    def depth_vector(self, depths) -> np.ndarray:
        """Wrinkle depths ``k_d`` in wrinkle order, shape (W,); ``None`` or absent names keep each wrinkle's own depth.

        Depths are lengths: beyond ±1e6 they are rejected like other bad values (ValueError naming the wrinkle).
        """
        return control_vector(
            depths, self.wrinkle_names, self.default_depths, self._depth_limits, "wrinkle depth", "wrinkle"
        )

    def host_frames(self, controls, wrinkle_depths) -> tuple[np.ndarray, np.ndarray]:
        """Validated (F, C) controls and (F, W) depths (the defaults for ``None`` depths) from host values."""
        values = frame_controls(
            controls, self.control_vector, len(self.control_names), "controls", self._contraction_limits
        )
        if wrinkle_depths is None:
            return values, np.tile(self.default_depths, (len(values), 1))
        depths = self.host_depths(wrinkle_depths)
        if len(depths) != len(values):
            raise ValueError(f"wrinkle_depths: {len(depths)} frames, controls have {len(values)}")
        return values, depths

    def host_depths(self, wrinkle_depths) -> np.ndarray:
        """Validated (F, W) wrinkle depths from host values."""
        return frame_controls(
            wrinkle_depths, self.depth_vector, len(self.wrinkles), "wrinkle_depths", self._depth_limits
        )


def _entry_array(struct, device, **fields: np.ndarray) -> wp.array:
    """A Warp array of ``struct`` entries from per-field numpy columns (one unused zero entry if empty)."""
    count = len(next(iter(fields.values())))
    packed = np.zeros(max(count, 1), dtype=struct.numpy_dtype())
    for name, values in fields.items():
        packed[name][:count] = values
    return wp.array(packed, dtype=struct, device=device)
