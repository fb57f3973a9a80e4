"""Face detection and the 468-point face mesh on RGB images, on the CPU (MediaPipe's networks, see
:mod:`~warpface.tracking.face_models`).

Two stages, the pre/post-processing written here from the networks' published input/output layout:

1. **Detection** (BlazeFace, an SSD): the image is letterboxed into the network's square input (values
   in [−1, 1]); each anchor (a grid cell centre; 128×128 short range: 16×16 cells × 2 at stride 8 and
   8×8 × 6 at stride 16 = 896; 192×192 full range: 48×48 × 1 at stride 4 = 2304) regresses a box centre
   offset, a box size and 6 keypoints (subject's right eye, left eye, nose tip, mouth centre, right and
   left tragion), all in input pixels relative to the anchor centre; the score is the logistic of the
   classifier. Overlapping boxes (IoU > 0.3) are merged by a score-weighted mean (weighted NMS).
2. **Face mesh**: a square region around the face (1.5 × the box's longer side), turned so that the
   line from the subject's right eye to the left eye is horizontal, is resampled to 192×192 (values in
   [0, 1]); the network returns 468 points (x, y in crop pixels, z relative depth in the same scale) and
   a face-presence logit. Points are taken back through the crop's similarity into image pixels.

For video, :class:`FaceMeshDetector` runs detection only when the face is lost; otherwise it crops the next
frame where the face was found, moved by the similarity that takes that frame's stable mesh points (eyes, nose,
forehead) to the previous frame's: unlike a box around all points, this crop does not change with the
expression, and the mesh (which shifts with its crop by up to ~1 px) gives the same landmarks for the same face.

Pixel convention: OpenCV's (pixel centres at integer coordinates), as in :mod:`warpface.tracking.detect`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .face_models import load_interpreter, model_path

__all__ = ["FaceBox", "FaceMesh468", "FaceMeshDetector", "ssd_anchors", "MESH_POINT_COUNT"]

MESH_POINT_COUNT = 468
"""Points of the face mesh."""
_DETECTOR_LAYOUT = {128: ((8, 2), (16, 6)), 192: ((4, 1),)}
"""Input size → (stride, anchors per cell) per feature map of the SSD."""
_MESH_SIZE = 192
_ROI_SCALE = 1.5
_SETTLE_PASSES, _SETTLED_PX = 6, 0.3
_STABLE = [33, 133, 362, 263, 168, 6, 197, 195, 5, 4, 1, 10, 151, 9]
"""Mesh points an expression hardly moves (eye corners, nose bridge and tip, mid-forehead): they carry the crop."""
_EYE_OUTER = (33, 263)  # mesh points: the subject's right and left outer eye corners


def ssd_anchors(input_size: int) -> np.ndarray:
    """Anchor centres of the detector with square input ``input_size`` [input pixels], shape (A, 2), in the
    network's output order (feature map, row, column, anchor)."""
    centres = []
    for stride, per_cell in _DETECTOR_LAYOUT[input_size]:
        cells = input_size // stride
        yy, xx = np.meshgrid(np.arange(cells), np.arange(cells), indexing="ij")
        grid = np.stack([(xx + 0.5) * stride, (yy + 0.5) * stride], axis=-1).reshape(-1, 1, 2)
        centres.append(np.repeat(grid, per_cell, axis=1).reshape(-1, 2))
    return np.concatenate(centres).astype(np.float64)


@dataclass(frozen=True)
class FaceBox:
    """One detected face [image pixels, OpenCV convention]."""

    center: np.ndarray
    """Box centre (x, y), shape (2,)."""
    size: np.ndarray
    """Box width and height, shape (2,)."""
    keypoints: np.ndarray
    """The six keypoints (right eye, left eye, nose tip, mouth, right tragion, left tragion), shape (6, 2)."""
    score: float
    """Detection confidence in (0, 1)."""

    @property
    def area(self) -> float:
        return float(self.size[0] * self.size[1])


@dataclass(frozen=True)
class FaceMesh468:
    """The face mesh of one face."""

    points: np.ndarray
    """468 points, shape (468, 3): x, y [image pixels, OpenCV convention], z relative depth [pixels, toward
    the camera negative]."""
    presence: float
    """Face-presence confidence of the mesh network in (0, 1)."""


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.clip(x, -80.0, 80.0)))


def _square_crop(image: np.ndarray, center, size: float, angle: float, out: int, value_range) -> tuple:
    """The square of side ``size`` [px] centred at ``center``, its x axis at ``angle`` [rad, image y down],
    resampled to ``out``×``out`` float32 in ``value_range``; also the 2×3 map crop pixel → image pixel."""
    import cv2

    c, s = math.cos(angle), math.sin(angle)
    scale = size / out
    # crop pixel centre i (continuous i + 0.5) → image continuous → OpenCV pixel (− 0.5)
    to_image = np.array([[c * scale, -s * scale, 0.0], [s * scale, c * scale, 0.0]])
    half = 0.5 * out
    to_image[:, 2] = np.asarray(center, dtype=np.float64) - to_image[:, :2] @ np.array([half - 0.5, half - 0.5])
    crop = cv2.warpAffine(
        image,
        to_image,
        (out, out),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=(0, 0, 0),
    )
    low, high = value_range
    tensor = crop.astype(np.float32) * np.float32((high - low) / 255.0) + np.float32(low)
    return tensor, to_image


class FaceMeshDetector:
    """Face detection + the 468-point face mesh, frame by frame (see the module docstring).

    Args:
        model_dir: folder with the model files (default: :func:`~warpface.tracking.face_models.model_folder`).
        mesh_model: path of a face-mesh ``.tflite`` file to use instead (same 192×192 → 468×3 layout).
        min_score: lowest detection score kept.
        min_presence: lowest face-presence score of the mesh network for a frame to count as a face.
        face: which face to follow when there are several: 0 = the largest, 1 = the next largest, ...
        track: crop each frame around the previous frame's mesh (video); ``False`` detects every frame.
        threads: interpreter threads.

    Raises:
        FileNotFoundError: a model file is missing; ImportError: ``ai-edge-litert`` is not installed.
    """

    def __init__(
        self,
        *,
        model_dir=None,
        mesh_model=None,
        min_score: float = 0.5,
        min_presence: float = 0.5,
        face: int = 0,
        track: bool = True,
        threads: int = 1,
    ):
        from .._validate import as_bounded, as_count

        self.min_score = as_bounded(min_score, "min_score", 0.0, 1.0)
        self.min_presence = as_bounded(min_presence, "min_presence", 0.0, 1.0)
        self.face = as_count(face, "face")
        self.track = bool(track)
        self._paths = {
            "detector": model_path("detector", model_dir=model_dir),
            "detector_full": model_path("detector_full", model_dir=model_dir),
            "mesh": model_path("mesh", model_dir=model_dir, path=mesh_model),
        }
        self._threads = threads
        self._nets: dict = {}
        self._net("mesh")  # a bad mesh model fails here, before any frame
        self._previous: FaceMesh468 | None = None
        self._anchor = None
        self.detections_run = 0
        """How many frames needed the face detector (the others were tracked from the previous mesh)."""

    def _net(self, role: str):
        if role not in self._nets:
            net = load_interpreter(self._paths[role], threads=self._threads)
            inputs, outputs = net.get_input_details(), net.get_output_details()
            if role == "mesh":
                shape = tuple(inputs[0]["shape"])
                sizes = sorted(int(np.prod(o["shape"])) for o in outputs)
                if shape != (1, _MESH_SIZE, _MESH_SIZE, 3) or MESH_POINT_COUNT * 3 not in sizes:
                    raise ValueError(
                        f"face model {self._paths[role]}: expected a 1×192×192×3 → 468×3 face mesh, got input {shape}"
                    )
            self._nets[role] = (net, inputs, outputs)
        return self._nets[role]

    def reset(self) -> None:
        """Forget the previous frame's face (a cut in the video)."""
        self._previous = None

    # -- detection --------------------------------------------------------------------------

    def detect_faces(self, rgb: np.ndarray, *, role: str = "detector") -> list[FaceBox]:
        """Faces in ``rgb`` (H, W, 3) uint8, largest first."""
        import cv2

        net, inputs, outputs = self._net(role)
        size = int(inputs[0]["shape"][1])
        height, width = rgb.shape[:2]
        scale = size / max(height, width)  # letterbox: the longer side fills the input
        new_w, new_h = max(1, round(width * scale)), max(1, round(height * scale))
        pad_x, pad_y = (size - new_w) // 2, (size - new_h) // 2
        small = cv2.resize(rgb, (new_w, new_h), interpolation=cv2.INTER_AREA)
        tensor = np.zeros((size, size, 3), dtype=np.float32)
        tensor[pad_y : pad_y + new_h, pad_x : pad_x + new_w] = small.astype(np.float32) / 127.5 - 1.0
        net.set_tensor(inputs[0]["index"], tensor[None])
        net.invoke()
        raw = {int(np.prod(o["shape"][2:])): net.get_tensor(o["index"])[0] for o in outputs}
        boxes, scores = raw[16], _sigmoid(raw[1][:, 0])
        keep = np.flatnonzero(scores >= self.min_score)
        if keep.size == 0:
            return []
        anchors = ssd_anchors(size)[keep]
        regress = boxes[keep].astype(np.float64)
        centre = anchors + regress[:, 0:2]
        extent = regress[:, 2:4]
        keypoints = anchors[:, None, :] + regress[:, 4:16].reshape(-1, 6, 2)
        merged = _weighted_nms(centre, extent, keypoints, scores[keep])
        offset = np.array([pad_x, pad_y], dtype=np.float64)
        faces = [
            FaceBox(
                center=(c - offset) / scale - 0.5,
                size=e / scale,
                keypoints=(k - offset) / scale - 0.5,
                score=float(sc),
            )
            for c, e, k, sc in merged
        ]
        return sorted(faces, key=lambda f: -f.area)

    # -- face mesh --------------------------------------------------------------------------

    def mesh_in_box(self, rgb: np.ndarray, center, size: float, angle: float) -> FaceMesh468:
        """The face mesh in the square of side ``size`` [px] at ``center``, turned by ``angle`` [rad]."""
        net, inputs, outputs = self._net("mesh")
        tensor, to_image = _square_crop(rgb, center, size, angle, _MESH_SIZE, (0.0, 1.0))
        net.set_tensor(inputs[0]["index"], tensor[None])
        net.invoke()
        values = {int(np.prod(o["shape"])): net.get_tensor(o["index"]).reshape(-1) for o in outputs}
        crop = values[MESH_POINT_COUNT * 3].astype(np.float64).reshape(-1, 3)
        presence = float(_sigmoid(np.asarray(values[1][0])))
        points = np.empty_like(crop)
        # network x, y are continuous crop coordinates: pixel centre i sits at i + 0.5
        points[:, :2] = (crop[:, :2] - 0.5) @ to_image[:, :2].T + to_image[:, 2]
        points[:, 2] = crop[:, 2] * (size / _MESH_SIZE)
        return FaceMesh468(points, presence)

    def _mesh_from_box(self, rgb, box: FaceBox) -> FaceMesh468:
        eye_r, eye_l = box.keypoints[0], box.keypoints[1]
        angle = math.atan2(eye_l[1] - eye_r[1], eye_l[0] - eye_r[0])
        return self.mesh_in_box(rgb, box.center, _ROI_SCALE * float(max(box.size)), angle)

    @staticmethod
    def _box_of(points: np.ndarray) -> tuple:
        """The crop (centre (2,), side, angle) around a mesh: its box in the eye-aligned frame, × 1.5."""
        xy = points[:, :2]
        eye_r, eye_l = xy[_EYE_OUTER[0]], xy[_EYE_OUTER[1]]
        angle = math.atan2(eye_l[1] - eye_r[1], eye_l[0] - eye_r[0])
        c, s = math.cos(-angle), math.sin(-angle)
        turned = xy @ np.array([[c, s], [-s, c]])  # into the face-aligned frame
        low, high = turned.min(axis=0), turned.max(axis=0)
        middle = 0.5 * (low + high) @ np.array([[c, -s], [s, c]])
        return middle, _ROI_SCALE * float(max(high - low)), angle

    def _mesh_from_previous(self, rgb, previous: FaceMesh468) -> FaceMesh468:
        return self.mesh_in_box(rgb, *self._box_of(previous.points))

    def _mesh_from_anchor(self, rgb, previous: FaceMesh468) -> FaceMesh468:
        """The crop of the frame where the face was found, moved by the 2-D similarity that takes that frame's
        stable points (eyes, nose, forehead) onto the previous frame's: an expression (a smile widening the
        face's box) does not move the crop, so the same face gives the same landmarks before and after it."""
        reference, (centre, size, angle) = self._anchor
        now = previous.points[_STABLE, :2]
        ref_mean, now_mean = reference.mean(axis=0), now.mean(axis=0)
        a, b = reference - ref_mean, now - now_mean
        ref_c, now_c = a[:, 0] + 1j * a[:, 1], b[:, 0] + 1j * b[:, 1]
        z = np.vdot(ref_c, now_c) / np.vdot(ref_c, ref_c).real  # now ≈ z · reference (complex similarity)
        offset = (centre[0] - ref_mean[0]) + 1j * (centre[1] - ref_mean[1])
        moved = z * offset
        return self.mesh_in_box(
            rgb, now_mean + np.array([moved.real, moved.imag]), size * abs(z), angle + float(np.angle(z))
        )

    def __call__(self, rgb: np.ndarray) -> FaceMesh468 | None:
        """The face mesh of the followed face in ``rgb`` (H, W, 3) uint8 RGB, or ``None`` when there is none."""
        rgb = _checked_image(rgb)
        if self.track and self._previous is not None:
            mesh = self._mesh_from_anchor(rgb, self._previous)
            if mesh.presence >= self.min_presence:
                self._previous = mesh
                return mesh
        self._previous = None
        self.detections_run += 1
        faces = self.detect_faces(rgb) or self.detect_faces(rgb, role="detector_full")
        if len(faces) <= self.face:
            return None
        mesh = self._mesh_from_box(rgb, faces[self.face])
        if mesh.presence < self.min_presence:
            return None
        # The detector's box is coarser than the mesh's own crop, and the mesh shifts with its crop: re-crop around
        # the mesh until it settles (measured: ~2 px on the first pass, < 0.3 px after four), so a face found by
        # detection and the same face tracked from the frame before give the same landmarks.
        for _ in range(_SETTLE_PASSES):
            settled = self._mesh_from_previous(rgb, mesh)
            if settled.presence < self.min_presence:
                break
            shift = float(np.abs(settled.points[:, :2] - mesh.points[:, :2]).max())
            mesh = settled
            if shift < _SETTLED_PX:
                break
        self._previous = mesh if self.track else None
        self._anchor = (mesh.points[_STABLE, :2].copy(), self._box_of(mesh.points))
        return mesh


def _checked_image(rgb) -> np.ndarray:
    if not isinstance(rgb, np.ndarray):
        raise TypeError(f"rgb: expected a numpy array (H, W, 3) uint8, got {type(rgb).__name__}")
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8 or min(rgb.shape[:2]) < 16:
        raise ValueError(f"rgb: expected an (H, W, 3) uint8 image at least 16 px wide, got {rgb.shape} {rgb.dtype}")
    return np.ascontiguousarray(rgb)


def _weighted_nms(centre, extent, keypoints, scores, iou: float = 0.3) -> list:
    """Score-weighted merge of overlapping boxes: ``[(centre, extent, keypoints, score)]``, best first."""
    order = np.argsort(-scores)
    low, high = centre - 0.5 * extent, centre + 0.5 * extent
    area = np.prod(np.maximum(extent, 0.0), axis=1)
    merged = []
    remaining = order
    while remaining.size:
        best = remaining[0]
        inter = np.prod(
            np.clip(np.minimum(high[remaining], high[best]) - np.maximum(low[remaining], low[best]), 0.0, None),
            axis=1,
        )
        overlap = inter / np.maximum(area[remaining] + area[best] - inter, 1e-12)
        group = remaining[overlap > iou]
        w = scores[group] / scores[group].sum()
        merged.append(
            (
                w @ centre[group],
                w @ extent[group],
                np.einsum("g,gkd->kd", w, keypoints[group]),
                float(scores[best]),
            )
        )
        remaining = remaining[overlap <= iou]
    return merged
