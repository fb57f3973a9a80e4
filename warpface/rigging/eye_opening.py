"""The eyes placed by the geometry of an open eye: the lid margin, where the skin drops into the socket.

A head modelled with its eyes open has a skin that turns in at the lid margin and lines the socket behind the
eyeball (or stops there, a hole). Seen from the front, the lids' surface ends at the margin and what lies behind it
is far deeper: the margin is the outline of the *socket*, the part of the eye's surroundings whose frontmost
front-facing skin lies more than :data:`DEPTH` behind the carried eye. The ICT annotation's lid points lie on that
outline (within 0.8 mm on the ICT head and on every warp of it measured), while the registration can leave a warped
head's eye several millimetres off it (development head 618: 6.5 mm mean), because the lid surface and the socket's
are one smooth sheet along which the template slides freely. The carried eye points are moved onto the outline,
and each brow by its eye's mean shift (:func:`eye_openings`, docs/RIG.md §9 step 6c). A scan without an opening (one
surface over the eye) has no socket: nothing changes.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from .nonrigid import SkinTarget

__all__ = [
    "BROWS",
    "CELL",
    "DEPTH",
    "CORNER_OFFSETS",
    "EYES",
    "SocketOutline",
    "front_depth",
    "socket_outline",
    "eye_openings",
]

CELL = 0.01
"""Side of the front view's depth-buffer cells [inter-ocular units, ~0.6 mm]."""
WINDOW = (0.4, 0.3)
"""Half-width and half-height of the front view around the carried eye's centre [inter-ocular units]."""
DEPTH = 0.15
"""Skin this far or farther behind the carried eye points' mean depth is the socket's [inter-ocular units, ~9 mm;
the ICT lids lie 0.0–0.27 d deep in the template frame, their socket's lining −0.15 to −0.28 d or open]."""
MAX_EDGE = 0.06
"""An eye whose window's skin triangles have a median edge longer than this [inter-ocular units, ~3.8 mm] is too
coarse to show its margin (the ICT head: 0.034 d; decimated to 6 mm cells, 0.1 d, where the step moved an eye
point of smooth warp 1 from 11.1 to 12.1 mm)."""
MIN_CELLS = 20
"""A socket of fewer cells (~7 mm²) is no eye opening."""
AREA_RATIO = (0.3, 3.0)
"""The socket's area over the carried eye ring's must lie in this range."""
MAX_MOVE = 0.3
"""An eye point the outline would move farther than this [inter-ocular units] leaves that eye as it was."""
CORNER_WEIGHT = 4.0
"""Weight of the two corners against each lid point in the fit of the eye ring's affine map."""
ROUNDS = 5
"""Rounds of matching the lid points to their nearest outline points."""
CORNER_OFFSETS = ((-0.039, 0.011), (1.158, -0.013))
"""Outer and inner corner in the socket's own frame: origin its outer extreme, first axis to its inner extreme
(length 1), second axis up. Calibrated on the ICT neutral, mirror-averaged: the socket tapers before the inner
corner (the caruncle's fold), so the annotated inner corner lies 0.16 of the eye's width beyond it."""
EYES = ((36, 37, 38, 39, 40, 41), (42, 43, 44, 45, 46, 47))
"""The eye rings in iBUG order: the subject's right eye (−x in the template frame), then the left."""
CORNERS = ((36, 39), (45, 42))
"""Outer, inner corner of each eye."""
BROWS = (np.arange(17, 22), np.arange(22, 27))
"""The brow above each eye (iBUG 17–21 over the right, 22–26 over the left): it moves with its eye ring's mean
shift. Where the registration slid an eye it slid the brow with it: on 37 training and development heads the carried
brows' error correlates with their eye's shift (0.70 across the face, 0.48 up; least-squares gain 0.95)."""


class SocketOutline:
    """One eye's socket seen from the front (template frame x, y): its outline and its cells' centres."""

    def __init__(self, outline: np.ndarray, cells: np.ndarray, right_eye: bool):
        self.outline = outline
        """Closed outline (N, 2), in the order :func:`cv2.findContours` walks it."""
        self.cells = cells
        """Centres of the socket's cells (M, 2)."""
        centre = cells.mean(axis=0)
        axis = np.linalg.svd(cells - centre, full_matrices=False)[2][0]
        if (axis[0] < 0.0) == right_eye:  # from the outer toward the inner corner: +x for the right eye
            axis = -axis
        along = (outline - centre) @ axis
        self.outer, self.inner = outline[np.argmin(along)], outline[np.argmax(along)]
        self.width = float(np.linalg.norm(self.inner - self.outer))
        self.across = (self.inner - self.outer) / max(self.width, 1e-12)
        self.up = np.array([-self.across[1], self.across[0]]) * (1.0 if right_eye else -1.0)

    def corners(self) -> tuple[np.ndarray, np.ndarray]:
        """The outer and inner corners where the ICT annotation puts them (:data:`CORNER_OFFSETS`), (2,) each."""
        return tuple(self.outer + self.width * (along * self.across + up * self.up) for along, up in CORNER_OFFSETS)

    def nearest(self, points: np.ndarray) -> np.ndarray:
        """The outline point nearest each of ``points`` (N, 2)."""
        distance = np.linalg.norm(points[:, None, :] - self.outline[None, :, :], axis=2)
        return self.outline[np.argmin(distance, axis=1)]


def front_depth(
    points: np.ndarray, triangles: np.ndarray, low: np.ndarray, shape: tuple[int, int], nearest: float
) -> np.ndarray:
    """Depth buffer (shape) of the front-facing triangles seen along −z: each cell's frontmost z over the cell
    centre ``low + (i + ½) CELL``, −inf where none; triangles wholly behind ``nearest`` are skipped."""
    a, b, c = (points[triangles[:, k]] for k in range(3))
    lower, upper = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
    high = low + np.asarray(shape) * CELL
    facing = np.cross(b - a, c - a)[:, 2] > 0.0
    inside = np.all(upper[:, :2] >= low, axis=1) & np.all(lower[:, :2] <= high, axis=1) & (upper[:, 2] > nearest)
    kept = facing & inside
    first, edge_1, edge_2 = a[kept], b[kept] - a[kept], c[kept] - a[kept]
    area = edge_1[:, 0] * edge_2[:, 1] - edge_1[:, 1] * edge_2[:, 0]
    start = np.clip(np.floor((lower[kept, :2] - low) / CELL).astype(int), 0, shape)
    stop = np.clip(np.ceil((upper[kept, :2] - low) / CELL).astype(int), 0, shape)
    size = np.where((np.abs(area) >= 1e-14)[:, None], np.maximum(stop - start, 0), 0)
    # every cell of every triangle's bounding box at once: its triangle, and its place in the box (row-major)
    cells = size[:, 0] * size[:, 1]
    triangle = np.repeat(np.arange(len(cells)), cells)
    place = np.arange(len(triangle)) - np.repeat(np.cumsum(cells) - cells, cells)
    row = start[triangle, 0] + place // size[triangle, 1]
    column = start[triangle, 1] + place % size[triangle, 1]
    x = low[0] + (row + 0.5) * CELL - first[triangle, 0]
    y = low[1] + (column + 0.5) * CELL - first[triangle, 1]
    e_1, e_2 = edge_1[triangle], edge_2[triangle]
    u = (x * e_2[:, 1] - y * e_2[:, 0]) / area[triangle]
    v = (e_1[:, 0] * y - e_1[:, 1] * x) / area[triangle]
    z = first[triangle, 2] + u * e_1[:, 2] + v * e_2[:, 2]
    covered = (u >= 0.0) & (v >= 0.0) & (u + v <= 1.0)
    depth = np.full(shape, -np.inf)
    np.maximum.at(depth, (row[covered], column[covered]), z[covered])
    return depth


def socket_outline(skin: SkinTarget, triangles: np.ndarray, ring: np.ndarray, right_eye: bool) -> SocketOutline | None:
    """The socket behind one carried eye ring (6, 3), or None when the skin shows no opening there (or is too
    coarse there to show one, :data:`MAX_EDGE`).

    Args:
        skin: the skin in the template frame (z out of the face).
        triangles: the skin's triangles (T, 3), indices into ``skin.points``.
        ring: the carried eye points in iBUG order.
        right_eye: the subject's right eye (iBUG 36–41).
    """
    centre = ring.mean(axis=0)
    near = triangles[np.all(np.abs(skin.points[triangles, :2] - centre[:2]) <= WINDOW, axis=(1, 2))]
    if len(near) == 0:
        return None
    edges = np.linalg.norm(skin.points[near] - skin.points[near[:, [1, 2, 0]]], axis=2)
    if np.median(edges) > MAX_EDGE:
        return None
    low = centre[:2] - np.asarray(WINDOW)
    shape = tuple(int(n) for n in np.ceil(2.0 * np.asarray(WINDOW) / CELL))
    depth = front_depth(skin.points, triangles, low, shape, centre[2] - 1.0)
    labels, count = ndimage.label(depth < centre[2] - DEPTH)
    best, best_distance = 0, np.inf
    for label, found in enumerate(ndimage.find_objects(labels), start=1):
        touches_edge = found[0].start == 0 or found[1].start == 0
        touches_edge |= found[0].stop == shape[0] or found[1].stop == shape[1]
        cells = np.argwhere(labels == label)
        if touches_edge or len(cells) < MIN_CELLS:
            continue
        distance = np.linalg.norm(low + (cells.mean(axis=0) + 0.5) * CELL - centre[:2])
        if distance < best_distance:
            best, best_distance = label, distance
    if best == 0:
        return None
    mask = (labels == best).astype(np.uint8)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    outline = low + (max(contours, key=len)[:, 0, ::-1] + 0.5) * CELL  # OpenCV gives (column, row) = (y, x)
    cells = low + (np.argwhere(mask) + 0.5) * CELL
    x, y = ring[:, 0], ring[:, 1]
    ring_area = 0.5 * abs(x @ np.roll(y, -1) - y @ np.roll(x, -1))  # the shoelace formula
    if not AREA_RATIO[0] <= len(cells) * CELL**2 / max(ring_area, 1e-12) <= AREA_RATIO[1]:
        return None
    return SocketOutline(outline, cells, right_eye)


def _fit_ring(ring: np.ndarray, socket: SocketOutline, corners: tuple[int, int]) -> np.ndarray:
    """The carried ring (6, 2) moved onto the socket's outline: an affine map taking its corners to the
    socket's (weighted :data:`CORNER_WEIGHT`) and its lid points to their nearest outline points, matched anew
    :data:`ROUNDS` times from the similarity the corners alone give; then each lid point on its nearest
    outline point, each corner on its socket corner."""
    corner_rows = list(corners)
    targets = np.array(socket.corners())
    points = ring[:, 0] + 1j * ring[:, 1]  # the plane as complex numbers: a similarity is z ↦ a z + b
    start, end = points[corner_rows]
    if abs(end - start) < 1e-9:  # a ring with its corners together has no direction to turn
        return ring
    goals = targets[:, 0] + 1j * targets[:, 1]
    placed = (points - start) * (goals[1] - goals[0]) / (end - start) + goals[0]
    moved = np.stack([placed.real, placed.imag], axis=1)
    lids = np.setdiff1d(np.arange(len(ring)), corner_rows)
    root_weights = np.ones((len(ring), 1))
    root_weights[corner_rows] = np.sqrt(CORNER_WEIGHT)
    homogeneous = np.concatenate([ring, np.ones((len(ring), 1))], axis=1)
    for _ in range(ROUNDS):
        goal = moved.copy()
        goal[corner_rows] = targets
        goal[lids] = socket.nearest(moved[lids])
        solution = np.linalg.lstsq(homogeneous * root_weights, goal * root_weights, rcond=None)[0]
        moved = homogeneous @ solution
    moved[lids] = socket.nearest(moved[lids])
    moved[corner_rows] = targets
    return moved


def eye_openings(skin: SkinTarget, triangles: np.ndarray, marks: np.ndarray) -> np.ndarray:
    """The carried landmarks (68, 3) with each eye's ring (iBUG 36–41, 42–47) moved in the front view (x, y) onto
    its socket's outline where the skin shows one, and the brow above it (:data:`BROWS`) by the ring's mean shift;
    depth is left to the snap onto the skin (:func:`~warpface.rigging.detect.snap_to_skin`).

    Args:
        skin: the skin in the template frame.
        triangles: the skin's triangles, indices into ``skin.points``.
        marks: the carried landmark points in that frame.
    """
    moved = marks.copy()
    for ring, (outer, inner), brow, right_eye in zip(EYES, CORNERS, BROWS, (True, False)):
        indices = np.asarray(ring)
        socket = socket_outline(skin, triangles, marks[indices], right_eye)
        if socket is None:
            continue
        corners = (ring.index(outer), ring.index(inner))
        placed = _fit_ring(marks[indices, :2], socket, corners)
        if not np.max(np.linalg.norm(placed - marks[indices, :2], axis=1)) <= MAX_MOVE:  # too far, or not finite
            continue
        moved[indices, :2] = placed
        moved[brow, :2] += np.mean(placed - marks[indices, :2], axis=0)
    return moved
