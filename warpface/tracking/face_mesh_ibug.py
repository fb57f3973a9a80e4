"""The 68 iBUG points from MediaPipe's 468-point face mesh: a fixed barycentric map, and how it was derived.

**Method** (:func:`derive_ibug_map`, re-run by ``tests/test_face_detector.py`` on the shared data):

1. MediaPipe's canonical face model (``canonical_face_model.obj``, 468 v, cm) is registered onto the
   ICT-FaceKit neutral face, whose 68 iBUG vertices are known (``landmarks_multipie68.txt``), by an
   affine map fitted (least squares) to 8 points both models name: the outer and inner eye corners
   (mesh 33, 133, 362, 263 ↔ iBUG 36, 39, 42, 45), the nose tip (1 ↔ 30), the mouth corners
   (61, 291 ↔ 48, 54) and the chin (152 ↔ 8);
2. a Gaussian radial-basis warp (σ = 2 cm) then moves those 8 and 6 more named points — the nose
   bridge between the eyes (168 ↔ 27), the nose base (2 ↔ 33), the outer lip centres (0, 17 ↔ 51, 57)
   and inner lip centres (13, 14 ↔ 62, 66) — exactly onto their iBUG points, bending the rest smoothly;
3. each of the 68 ICT landmarks takes the closest point on the warped canonical mesh: a triangle of
   mesh points and barycentric weights (:data:`IBUG_TRIANGLES`, :data:`IBUG_WEIGHTS`).

The map is then applied to detected meshes (:func:`ibug_from_mesh`): a weighted sum of three mesh points per
iBUG point. iBUG numbering is the subject's (iBUG 36 is the subject's right eye's outer corner, at the
image's left in a frontal photo), as MediaPipe's (mesh 33 is that corner).
"""

from __future__ import annotations

import numpy as np

__all__ = ["IBUG_NAMES", "IBUG_ANCHORS", "IBUG_TRIANGLES", "IBUG_WEIGHTS", "ibug_from_mesh", "derive_ibug_map"]

IBUG_NAMES = tuple(f"ibug{i:02d}" for i in range(68))
"""Landmark names of the 68 iBUG points, in iBUG order."""
IBUG_ANCHORS = {36: 33, 39: 133, 42: 362, 45: 263, 30: 1, 48: 61, 54: 291, 8: 152}
"""iBUG point → the face-mesh point at the same place, used for the affine registration."""
_WARP_ANCHORS = {**IBUG_ANCHORS, 27: 168, 33: 2, 51: 0, 57: 17, 62: 13, 66: 14}
_WARP_SIGMA_CM = 2.0


def derive_ibug_map(canonical_points, canonical_triangles, ict_landmarks, *, device="cpu"):
    """The barycentric map mesh → iBUG from a canonical face mesh and a face with known iBUG points.

    Args:
        canonical_points: the 468 canonical face-mesh points [cm], shape (468, 3).
        canonical_triangles: its triangles, shape (T, 3).
        ict_landmarks: the 68 iBUG points of another neutral face [cm], shape (68, 3), same axes
            (+y up, +z toward the viewer).

    Returns:
        ``(triangles (68, 3) int64 mesh-point indices, weights (68, 3) float64 summing to 1, distance (68,) [cm])``:
        the distance is how far each iBUG point lies from the warped canonical surface.
    """
    from ..geometry.mesh_index import closest_points

    source = np.asarray(canonical_points, dtype=np.float64)
    target = np.asarray(ict_landmarks, dtype=np.float64)
    first = np.array([source[v] for v in IBUG_ANCHORS.values()])
    homogeneous = np.c_[first, np.ones(len(first))]
    affine, *_ = np.linalg.lstsq(homogeneous, target[list(IBUG_ANCHORS)], rcond=None)
    moved = np.c_[source, np.ones(len(source))] @ affine
    anchors = moved[list(_WARP_ANCHORS.values())]
    offsets = target[list(_WARP_ANCHORS)] - anchors

    def kernel(a, b):
        return np.exp(-((np.linalg.norm(a[:, None] - b[None], axis=2) / _WARP_SIGMA_CM) ** 2))

    weights = np.linalg.solve(kernel(anchors, anchors), offsets)
    warped = moved + kernel(moved, anchors) @ weights
    tri, bary, dist = closest_points(target, warped, canonical_triangles, device=device)
    triangles = np.asarray(canonical_triangles, dtype=np.int64)[tri]
    bary = np.asarray(bary, dtype=np.float64)
    return triangles, bary / bary.sum(axis=1, keepdims=True), np.asarray(dist, dtype=np.float64)


def ibug_from_mesh(points) -> np.ndarray:
    """The 68 iBUG points of a face mesh: ``points`` (468, D) → (68, D), the same units."""
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[0] != 468:
        raise ValueError(f"points: expected the 468 face-mesh points (468, D), got {points.shape}")
    return np.einsum("lk,lkd->ld", IBUG_WEIGHTS, points[IBUG_TRIANGLES])


# Derived by derive_ibug_map on canonical_face_model.obj and the ICT-FaceKit neutral (see the module
# docstring); tests/test_face_detector.py re-derives it from the shared data and compares.
# fmt: off
IBUG_TRIANGLES = np.array([
    [127, 34, 162], [234, 227, 127], [93, 137, 234], [132, 58, 177], [138, 215, 172], [136, 150, 135],
    [170, 169, 149], [148, 171, 176], [175, 152, 396], [377, 400, 396], [395, 378, 394], [365, 364, 379],
    [367, 397, 435], [361, 401, 288], [323, 454, 366], [454, 356, 447], [356, 389, 264], [71, 70, 68],
    [68, 63, 104], [104, 105, 69], [107, 108, 66], [9, 151, 107], [9, 336, 151], [336, 296, 337],
    [296, 334, 299], [298, 333, 293], [301, 298, 300], [168, 417, 8], [197, 6, 196], [5, 195, 51],
    [1, 19, 274], [97, 98, 167], [99, 97, 242], [2, 164, 326], [328, 462, 326], [326, 393, 327],
    [246, 33, 7], [29, 30, 160], [27, 159, 28], [173, 155, 133], [22, 153, 23], [24, 144, 110],
    [382, 398, 362], [257, 258, 386], [259, 387, 260], [263, 466, 249], [254, 339, 373], [252, 253, 380],
    [61, 146, 76], [40, 39, 92], [37, 167, 39], [267, 0, 302], [267, 269, 393], [270, 322, 269],
    [291, 306, 375], [405, 406, 321], [405, 314, 406], [17, 18, 314], [181, 182, 84], [181, 91, 182],
    [183, 62, 191], [81, 82, 41], [12, 13, 268], [311, 271, 312], [407, 415, 292], [311, 271, 312],
    [15, 316, 14], [81, 82, 41],
], dtype=np.int64)
IBUG_WEIGHTS = np.array([
    [0.3306, 0.0000, 0.6694], [0.2965, 0.2601, 0.4434], [0.3177, 0.5533, 0.1290], [0.0944, 0.1629, 0.7427],
    [0.4639, 0.2157, 0.3204], [0.3918, 0.4246, 0.1836], [0.0832, 0.1178, 0.7990], [0.3278, 0.3891, 0.2831],
    [0.0000, 1.0000, 0.0000], [0.3278, 0.2832, 0.3890], [0.0832, 0.7991, 0.1177], [0.3918, 0.1835, 0.4247],
    [0.4640, 0.3205, 0.2155], [0.0943, 0.7427, 0.1630], [0.3178, 0.1288, 0.5534], [0.2966, 0.4432, 0.2602],
    [0.3306, 0.6694, 0.0000], [0.1594, 0.5617, 0.2789], [0.0366, 0.5977, 0.3657], [0.0000, 0.6919, 0.3081],
    [0.1073, 0.2287, 0.6640], [0.0407, 0.1285, 0.8308], [0.0408, 0.8308, 0.1284], [0.1074, 0.6639, 0.2287],
    [0.0000, 0.6919, 0.3081], [0.0365, 0.3657, 0.5978], [0.1594, 0.2788, 0.5618], [1.0000, 0.0000, 0.0000],
    [0.5437, 0.2955, 0.1608], [0.2939, 0.4234, 0.2827], [1.0000, 0.0000, 0.0000], [0.0276, 0.8513, 0.1211],
    [0.1423, 0.8222, 0.0355], [1.0000, 0.0000, 0.0000], [0.1422, 0.0355, 0.8223], [0.0276, 0.1211, 0.8513],
    [0.0000, 1.0000, 0.0000], [0.7604, 0.2300, 0.0096], [0.2044, 0.0000, 0.7956], [0.0000, 0.0000, 1.0000],
    [0.2000, 0.7708, 0.0292], [0.4871, 0.4314, 0.0815], [0.0000, 0.0000, 1.0000], [0.2039, 0.7961, 0.0000],
    [0.7603, 0.0099, 0.2298], [1.0000, 0.0000, 0.0000], [0.4876, 0.0813, 0.4311], [0.2017, 0.0290, 0.7693],
    [1.0000, 0.0000, 0.0000], [0.2924, 0.6009, 0.1067], [0.8506, 0.1393, 0.0101], [0.0000, 1.0000, 0.0000],
    [0.8505, 0.0101, 0.1394], [0.2924, 0.1068, 0.6008], [1.0000, 0.0000, 0.0000], [0.2075, 0.1222, 0.6703],
    [0.2695, 0.6257, 0.1048], [1.0000, 0.0000, 0.0000], [0.2695, 0.1048, 0.6257], [0.2075, 0.6703, 0.1222],
    [0.0170, 0.7834, 0.1996], [0.4260, 0.1906, 0.3834], [0.0000, 1.0000, 0.0000], [0.4259, 0.3835, 0.1906],
    [0.0169, 0.1996, 0.7835], [0.8245, 0.1603, 0.0152], [0.0000, 0.0000, 1.0000], [0.8245, 0.0153, 0.1602],
])
# fmt: on
