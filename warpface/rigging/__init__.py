"""Rigging a head of one's own: 68 iBUG landmarks found on any head mesh, read from files, and checked.

    >>> from warpface.rigging import find_landmarks
    >>> found = find_landmarks(points, triangles)          # any unit, up axis, facing; extra shells allowed
    >>> rig = default_rig(FaceMesh(points, triangles), found.indices)

The method (template registration of the built-in face: symmetry plane, similarity ICP, non-rigid
ICP) is stated in docs/RIG.md, "Automatic landmarks".
"""

from .detect import LandmarkFit, find_landmarks
from .landmark_files import landmarks_from_values, read_landmark_file
from .layout import check_layout
from .picture import rig_picture
from .surface import HeadSurface, polygons_to_triangles
from .units import UNITS, infer_units

__all__ = [
    "find_landmarks",
    "LandmarkFit",
    "read_landmark_file",
    "landmarks_from_values",
    "check_layout",
    "rig_picture",
    "HeadSurface",
    "polygons_to_triangles",
    "UNITS",
    "infer_units",
]
