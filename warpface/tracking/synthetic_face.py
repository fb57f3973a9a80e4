"""Facial features painted on a :class:`~warpface.tracking.synthetic.SyntheticRGBDCamera`'s texture, so that a
markerless face detector sees a face: brows, lips and nostrils drawn from the face's 68 iBUG points at rest.

The features live in the texture (a front projection of the first frame), so they move with the skin: lips
stretch in a smile, brows rise — the ground truth of a markerless closed loop.
"""

from __future__ import annotations

import numpy as np

__all__ = ["paint_face_features", "BROW_RGB", "LIP_RGB"]

BROW_RGB = (70, 45, 30)
"""Brow colour (0–255)."""
LIP_RGB = (170, 75, 75)
"""Lip colour (0–255)."""


def paint_face_features(camera, ibug_points, *, brow_width: float = 0.005) -> np.ndarray:
    """Paint brows (a ``brow_width`` [m] wide stroke through iBUG 17–21 and 22–26), the lips (the outer lip
    polygon 48–59) and nostrils (iBUG 31–35 region) into ``camera.texture``, before its first render.

    Args:
        camera: a :class:`~warpface.tracking.synthetic.SyntheticRGBDCamera` (not yet rendered).
        ibug_points: the 68 iBUG points at rest [m], shape (68, 3), in the camera's model frame.

    Returns:
        The painted texture (also set on the camera).
    """
    import cv2

    points = np.asarray(ibug_points, dtype=np.float64)
    if points.shape != (68, 3):
        raise ValueError(f"ibug_points: expected (68, 3), got {points.shape}")
    if camera._renderer is not None:
        raise ValueError("camera: paint the features before the first render")
    texture = np.ascontiguousarray(camera.texture.copy())
    size = texture.shape[0]
    per_metre = size / camera._uv_extent

    def texel(indices) -> np.ndarray:
        uv = (points[list(indices), :2] - camera._uv_origin) / camera._uv_extent
        return np.stack([uv[:, 0] * size - 0.5, (1.0 - uv[:, 1]) * size - 0.5], axis=1)

    shift = 4  # sub-texel precision of cv2's drawing

    def fixed(xy):
        return np.round(xy * (1 << shift)).astype(np.int32)

    for brow in (range(17, 22), range(22, 27)):
        cv2.polylines(
            texture,
            [fixed(texel(brow))],
            False,
            BROW_RGB,
            thickness=max(1, int(round(brow_width * per_metre))),
            lineType=cv2.LINE_AA,
            shift=shift,
        )
    cv2.fillPoly(texture, [fixed(texel(range(48, 60)))], LIP_RGB, lineType=cv2.LINE_AA, shift=shift)
    nostril_size = 0.003 * per_metre
    for side, toward in ((32, 31), (34, 35)):
        centre = 0.5 * (texel([side])[0] + texel([toward])[0]) + np.array([0.0, -0.2 * nostril_size])
        axes = (int(round(nostril_size)), int(round(0.55 * nostril_size)))
        cv2.ellipse(texture, tuple(int(round(c)) for c in centre), axes, 0, 0, 360, (60, 30, 25), -1, cv2.LINE_AA)
    camera.texture = texture
    return texture
