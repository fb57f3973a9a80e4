"""warpface as a Newton plug-in: the face's tissue in a Newton world (``pip install 'warpface[newton]'``).

:func:`add_face` puts a face (a :class:`~warpface.FaceRig` or a rig stage, with its tissue) into a
``newton.ModelBuilder``: tissue nodes as particles, tets with the tissue's material, namespaced custom attributes
(``warpface:*``: CONTROL for the muscle contractions and the jaw, MODEL for the rig's per-node, per-tet and
per-skin-vertex data), and returns a :class:`NewtonFace` handle. :class:`SolverFace` is a
``newton.solvers.SolverBase`` that advances the face: expression model -> driven displacements -> warpface's
Newmark-beta tissue FEM in the moving frame of the head body, with Newton's particle-shape soft contacts as
forces on the skin nodes; on CUDA (or with ``graph_capturable=True``) its step is kernel launches only, so
``wp.ScopedCapture`` can capture it (docs/NEWTON.md §5). :class:`SkinRecorder` records the render skin of a run
and writes it as a time-sampled point cache with warpface's bake writer. The loop and the moving-frame formula:
``docs/NEWTON.md``.

This package imports ``newton`` (not ``import warpface``): without it, importing ``warpface.newton`` raises an
ImportError that says how to install it.
"""

from __future__ import annotations

try:
    import newton  # noqa: F401
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError(
        "warpface.newton needs Newton (newton>=1.8): pip install 'warpface[newton]'", name="newton"
    ) from exc

from .face import NAMESPACE, NewtonFace, add_face, register_face_attributes
from .frame import HeadMotion, head_motion
from .recording import SkinRecorder
from .solver import SolverFace

__all__ = [
    "NAMESPACE",
    "HeadMotion",
    "NewtonFace",
    "SkinRecorder",
    "SolverFace",
    "add_face",
    "head_motion",
    "register_face_attributes",
]
