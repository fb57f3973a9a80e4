"""Reader for MediaPipe Face Landmarker output (text-format ``NormalizedLandmarkList``).

MediaPipe gives 478 landmarks per face (468 mesh points + 10 iris points) as normalised image
coordinates: ``x`` and ``y`` in [0, 1] of the image width and height, ``z`` a relative depth with
the head centre at 0, smaller = nearer, "roughly the same scale as x". Landmark ``i`` is vertex
``i`` of MediaPipe's canonical face model (``canonical_face_model.obj``, 468 vertices;
``face_model_with_iris.obj``, 478), which makes that model the sparse tracking mesh.

Metric reconstruction (per frame): the landmarks, scaled to pixel units ``(x W, y H, z W)``, are
fitted to the canonical model (metres, turned into camera orientation) with a similarity
transform; its scale ``k`` [px/m] gives the head's depth under weak perspective, ``Z̄ = f / k``,
each landmark's depth is ``Z̄`` plus its relative depth ``z W / k``, and X, Y follow from the
pinhole model. Absolute distance therefore assumes the subject's face is the canonical model's
size (an average adult; a 10 % larger face reads 10 % nearer), while shape and motion are
measured. When the image size is unknown its aspect ratio is estimated as the one that makes the
landmarks fit the canonical model best.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from .alignment import similarity_fit
from .frames import LandmarkFrame, SourceBase
from .intrinsics import CameraIntrinsics
from .streams import checked_frames

__all__ = ["MediaPipeLandmarks", "parse_landmark_list", "MEDIAPIPE_VERTICAL_FOV_DEG"]

MEDIAPIPE_VERTICAL_FOV_DEG = 63.0
"""MediaPipe's default perspective camera (face geometry pipeline): vertical field of view [deg]."""

_BLOCK = re.compile(r"\blandmark\s*\{([^{}]*)\}")
_FIELD = re.compile(r"\b(x|y|z|visibility|presence)\s*:\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|nan|inf|-inf)")


def parse_landmark_list(text: str, *, where: str = "landmarks") -> np.ndarray:
    """``x, y, z`` of every ``landmark { ... }`` block, shape (L, 3), float64 (NaN where z is absent).

    Raises:
        ValueError: no blocks, or a block without ``x`` or ``y`` (naming its index).
    """
    blocks = _BLOCK.findall(text)
    if not blocks:
        raise ValueError(f"{where}: no 'landmark {{ x: y: z: }}' blocks found")
    out = np.full((len(blocks), 3), np.nan)
    for i, body in enumerate(blocks):
        fields = dict(_FIELD.findall(body))
        if "x" not in fields or "y" not in fields:
            raise ValueError(f"{where}: landmark {i} lacks x or y")
        out[i, 0] = float(fields["x"])
        out[i, 1] = float(fields["y"])
        if "z" in fields:
            out[i, 2] = float(fields["z"])
    return out


def _default_model_path(count: int) -> Path | None:
    from ..data import shared_data_path

    name = "face_model_with_iris.obj" if count == 478 else "canonical_face_model.obj"
    return shared_data_path("mediapipe", name)


class MediaPipeLandmarks(SourceBase):
    """MediaPipe landmark files as a landmark stream (one file = one frame).

    Args:
        paths: one ``.pbtxt``/``.prototxt`` file, a list of them (frame order), or a folder (its
            ``*.pbtxt``/``*.prototxt`` files sorted by name).
        fps: frame rate of the sequence [1/s]; frame ``i`` is at ``i / fps`` seconds.
        image_size: ``(W, H)`` [px] of the images the landmarks came from; ``None`` estimates
            the aspect ratio from the landmarks (see module docstring) with ``H = 480``.
        intrinsics: camera intrinsics; default a pinhole with MediaPipe's 63° vertical field of
            view centred in the image.
        model_path: the canonical model OBJ (centimetres, +y up, +z toward the viewer); default
            the matching file in ``shared/data/mediapipe``.

    Raises:
        ValueError: unreadable files, landmarks without ``z``, a count other than the model's
            vertex count, or no model found.
    """

    def __init__(
        self,
        paths: str | Path | Sequence[str | Path],
        *,
        fps: float = 30.0,
        image_size: tuple[int, int] | None = None,
        intrinsics: CameraIntrinsics | None = None,
        model_path: str | Path | None = None,
    ):
        if isinstance(paths, (str, Path)) and Path(paths).is_dir():
            folder = Path(paths)
            files = sorted(p for p in folder.iterdir() if p.suffix in (".pbtxt", ".prototxt"))
            if not files:
                raise ValueError(f"{folder}: no .pbtxt/.prototxt files")
        elif isinstance(paths, (str, Path)):
            files = [Path(paths)]
        else:
            files = [Path(p) for p in paths]
        if not files:
            raise ValueError("paths: no landmark files given")
        if not (math.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be > 0, got {fps}")
        self.files = files
        self.fps = float(fps)
        self._normalized = []
        for path in files:
            if not path.is_file():
                raise ValueError(f"{path}: no such landmark file")
            lm = parse_landmark_list(path.read_text(encoding="utf-8", errors="replace"), where=str(path))
            if np.isnan(lm[:, 2]).any():
                raise ValueError(
                    f"{path}: landmark {int(np.flatnonzero(np.isnan(lm[:, 2]))[0])} has no z; "
                    "metric reconstruction needs x, y and z"
                )
            if self._normalized and lm.shape[0] != self._normalized[0].shape[0]:
                raise ValueError(f"{path}: {lm.shape[0]} landmarks, but {files[0]} has {self._normalized[0].shape[0]}")
            self._normalized.append(lm)
        count = self._normalized[0].shape[0]
        model = Path(model_path) if model_path is not None else _default_model_path(count)
        if model is None or not model.is_file():
            raise ValueError(f"canonical face model not found ({model}); pass model_path")
        from ..mesh import load_obj

        vertices, triangles = load_obj(model)
        if vertices.shape[0] != count:
            raise ValueError(f"{model}: {vertices.shape[0]} vertices, but the landmark files have {count} landmarks")
        self.model_points = vertices * 0.01
        """Canonical model [m], shape (N, 3), model frame (+y up, +z toward the viewer)."""
        self.model_triangles = triangles.astype(np.int32)
        """Canonical model triangles, shape (T, 3), int32."""
        self.landmark_names = tuple(f"mp_{i:03d}" for i in range(count))

        if image_size is None:
            aspect = self._estimate_aspect(self._normalized[0])
            height = 480
            image_size = (int(round(height / aspect)), height)
        self.image_size = (int(image_size[0]), int(image_size[1]))
        """``(W, H)`` [px] used to scale the normalised coordinates."""
        if intrinsics is None:
            w, h = self.image_size
            f = 0.5 * h / math.tan(math.radians(0.5 * MEDIAPIPE_VERTICAL_FOV_DEG))
            intrinsics = CameraIntrinsics(f, f, 0.5 * w - 0.5, 0.5 * h - 0.5, w, h)
        self.intrinsics = intrinsics

    @property
    def _camera_model(self) -> np.ndarray:
        """Canonical model in camera orientation (x right, y down, z forward) [m]."""
        return self.model_points * np.array([1.0, -1.0, -1.0])

    def _estimate_aspect(self, normalized: np.ndarray) -> float:
        """Image aspect H / W that lets the landmarks fit the canonical model best (golden section)."""
        model = self._camera_model

        def residual(aspect: float) -> float:
            pts = normalized * np.array([1.0, aspect, 1.0])  # units of W
            s, _, _, rms = similarity_fit(model, pts)
            return rms / s  # in metres, comparable across aspects

        lo, hi = math.log(0.4), math.log(2.5)
        g = (math.sqrt(5.0) - 1.0) / 2.0
        a, b = hi - g * (hi - lo), lo + g * (hi - lo)
        fa, fb = residual(math.exp(a)), residual(math.exp(b))
        for _ in range(40):
            if fa < fb:
                hi, b, fb = b, a, fa
                a = hi - g * (hi - lo)
                fa = residual(math.exp(a))
            else:
                lo, a, fa = a, b, fb
                b = lo + g * (hi - lo)
                fb = residual(math.exp(b))
        return math.exp(0.5 * (lo + hi))

    def metric_points(self, normalized: np.ndarray) -> np.ndarray:
        """Camera-frame landmark positions [m], shape (N, 3), from normalised landmarks (N, 3)."""
        w, h = self.image_size
        pix = normalized * np.array([w, h, w], dtype=np.float64)
        k, _, t, _ = similarity_fit(self._camera_model, pix)
        intr = self.intrinsics
        f = 0.5 * (intr.fx + intr.fy)
        z = f / k + (pix[:, 2] - t[2]) / k
        x = (pix[:, 0] - intr.cx) * z / intr.fx
        y = (pix[:, 1] - intr.cy) * z / intr.fy
        return np.stack([x, y, z], axis=1)

    def __len__(self) -> int:
        return len(self.files)

    def frames(self) -> Iterator[LandmarkFrame]:
        """One frame per file at ``i / fps`` seconds; confidence 1 (MediaPipe leaves presence unset)."""
        raw = (
            LandmarkFrame(i / self.fps, self.metric_points(lm), np.ones(lm.shape[0], np.float32), i)
            for i, lm in enumerate(self._normalized)
        )
        yield from checked_frames(raw, where="MediaPipe landmarks")

    def sparse_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """The sparse tracking mesh: canonical model points [m] (model frame) and triangles."""
        return self.model_points.copy(), self.model_triangles.copy()
