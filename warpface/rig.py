"""``FaceRig``: everything that defines a face's expressions, validated, as plain arrays and records."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import RigError
from .expression.controls import check_rig_parts
from .expression.jaw import JAW_CONTROL_NAMES, Jaw
from .expression.muscles import Muscle
from .expression.wrinkles import Wrinkle
from .mesh import FaceMesh

__all__ = ["FaceRig"]


@dataclass(eq=False)
class FaceRig:
    """A face rig: rest mesh, muscles, wrinkles, per-vertex thickness and optional landmarks.

    Args:
        mesh: rest surface.
        muscles: linear and sphincter muscles (contraction order).
        wrinkles: wrinkle furrows (depth order).
        thickness: subcutaneous thickness [mesh units], scalar or shape (V,); stored as (V,) float64.
        landmarks: optional vertex indices of named landmarks, shape (L,) int (e.g. the 68 iBUG points).
        name: rig name (used for prim names and messages).
        jaw: optional :class:`~warpface.expression.Jaw` (hinge and per-vertex weights, SPEC §6.2).

    Raises:
        RigError: (a ``ValueError``) mesh not a FaceMesh, wrong item types, duplicate names, wrong
            thickness — the same errors :class:`~warpface.ExpressionModel` raises — or landmark
            indices out of range.
    """

    mesh: FaceMesh
    muscles: list[Muscle] = field(default_factory=list)
    wrinkles: list[Wrinkle] = field(default_factory=list)
    thickness: np.ndarray | float = 0.0
    landmarks: np.ndarray | None = None
    name: str = "Face"
    jaw: Jaw | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise RigError(f"rig name: expected a non-empty string, got {self.name!r}")
        self.muscles, self.wrinkles, self.thickness = check_rig_parts(
            self.mesh, self.muscles, self.wrinkles, self.thickness, owner=f"rig {self.name!r}"
        )
        if self.landmarks is not None:
            try:
                landmarks = np.asarray(self.landmarks)
            except (TypeError, ValueError):  # ragged nesting
                landmarks = np.asarray(0.5)
            if landmarks.ndim != 1 or not np.issubdtype(landmarks.dtype, np.integer):
                raise RigError(f"rig {self.name!r}: landmarks must be a 1-D integer array of vertex indices")
            bad = np.flatnonzero((landmarks < 0) | (landmarks >= self.mesh.vertex_count))
            if len(bad):
                raise RigError(f"rig {self.name!r}: landmark {int(bad[0])} index {int(landmarks[bad[0]])} out of range")
            self.landmarks = landmarks.astype(np.int64)
        if self.jaw is not None:
            if not isinstance(self.jaw, Jaw):
                raise RigError(f"rig {self.name!r}: jaw must be a Jaw, got {type(self.jaw).__name__}")
            try:
                self.jaw.check_vertex_count(self.mesh.vertex_count)
            except ValueError as exc:
                raise RigError(f"rig {self.name!r}: {exc}") from None

    @property
    def muscle_names(self) -> list[str]:
        return [m.name for m in self.muscles]

    @property
    def control_names(self) -> list[str]:
        """Muscle names, then the jaw's controls when the rig has a jaw (the model's control order)."""
        return self.muscle_names + (list(JAW_CONTROL_NAMES) if self.jaw is not None else [])

    @property
    def wrinkle_names(self) -> list[str]:
        return [w.name for w in self.wrinkles]

    def model(self, *, device=None):
        """An :class:`~warpface.ExpressionModel` for this rig on ``device``."""
        from .expression.model import ExpressionModel

        return ExpressionModel.from_rig(self, device=device)
