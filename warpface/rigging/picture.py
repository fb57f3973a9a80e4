"""The rig preview picture: the face from the front and from the side, landmarks numbered, muscles as lines.

Drawn with matplotlib in the face's own landmark frame (x to the subject's left, y up, z out of the
face), so the picture is upright and frontal whatever the mesh's orientation.
"""

from __future__ import annotations

import io

import numpy as np

from ..assets.rig import face_frame
from ..expression.muscles import LinearMuscle
from ..rig import FaceRig

__all__ = ["rig_picture"]

MAX_DOTS = 12000
"""Skin vertices drawn as the face's grey shading (a random subset of larger meshes)."""


def rig_picture(rig: FaceRig, *, title: str = "", dpi: int = 110) -> bytes:
    """PNG bytes of the front and side views of ``rig`` (skin points, numbered landmarks, muscles)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    frame = face_frame(rig.mesh, rig.landmarks)
    skin_vertices = np.unique(rig.mesh.triangles)
    local = frame.to_local(rig.mesh.points[skin_vertices])
    near = np.linalg.norm(local[:, :2], axis=1) < 3.0
    local = local[near]
    if len(local) > MAX_DOTS:
        local = local[np.random.default_rng(0).choice(len(local), MAX_DOTS, replace=False)]
    marks = frame.to_local(rig.mesh.points[rig.landmarks])
    figure = Figure(figsize=(11, 6))
    views = (("front", 0, 1), ("side (face looks right)", 2, 1))
    for column, (name, u, v) in enumerate(views):
        axes = figure.add_subplot(1, 2, column + 1)
        order = np.argsort(local[:, 2 if u != 2 else 0])
        axes.scatter(local[order, u], local[order, v], s=1.0, c=local[order, 2 if u != 2 else 0], cmap="Greys_r")
        for muscle in rig.muscles:
            if isinstance(muscle, LinearMuscle):
                ends = frame.to_local(np.stack([muscle.attachment, muscle.insertion]))
                axes.plot(ends[:, u], ends[:, v], color="tab:red", linewidth=1.2)
                axes.plot(ends[1, u], ends[1, v], "o", color="tab:red", markersize=2.5)
            else:
                centre = frame.to_local(muscle.center[None])[0]
                axes.plot(centre[u], centre[v], "s", color="tab:orange", markersize=4)
        axes.scatter(marks[:, u], marks[:, v], s=9, color="tab:blue", zorder=3)
        for index, point in enumerate(marks):
            axes.annotate(
                str(index), (point[u], point[v]), fontsize=5.5, color="navy", xytext=(2, 2), textcoords="offset points"
            )
        axes.set_aspect("equal")
        axes.set_title(name)
        axes.set_xticks([])
        axes.set_yticks([])
    figure.suptitle(title or f"{rig.name}: {len(rig.muscles)} muscles, 68 landmarks")
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    return buffer.getvalue()
