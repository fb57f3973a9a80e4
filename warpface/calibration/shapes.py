"""Example shapes for a calibration: read, named and checked against the rig (docs/RIG.md §13)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..drivers.channels import ARKIT_CHANNELS
from ..mesh import FaceMesh, load_obj
from ..rig import FaceRig

__all__ = ["ExampleShape", "arkit_name", "check_shapes", "read_shapes"]

NAME_STYLES = ("file", "arkit")
"""How example names are read from file stems: as they are, or as ARKit names (checked)."""

_ARKIT = {name.lower(): name for name in ARKIT_CHANNELS}


@dataclass(frozen=True)
class ExampleShape:
    """One example: its ``name``, the ``points`` (V, 3) in the rig's units and the file it came from."""

    name: str
    points: np.ndarray
    source: str = ""


def arkit_name(stem: str) -> str | None:
    """The ARKit spelling of a file stem (``browDownLeft``, ``BrowDownLeft`` or ICT's ``browDown_L``), or None."""
    text = stem.strip()
    for suffix, side in (("_L", "Left"), ("_R", "Right")):
        if text.endswith(suffix):
            base = text[: -len(suffix)]
            sided = _ARKIT.get((base + side).lower())
            # ICT splits some of ARKit's unsided channels per side (browInnerUp_L, cheekPuff_R)
            return (
                sided if sided is not None else (None if base.lower() not in _ARKIT else _ARKIT[base.lower()] + suffix)
            )
    return _ARKIT.get(text.lower())


def _files(sources) -> list[Path]:
    """OBJ files of the sources (folders are listed, sorted; ``neutral.obj`` in a folder is skipped)."""
    if isinstance(sources, (str, Path)):
        sources = [sources]
    files: list[Path] = []
    for source in sources:
        path = Path(source)
        if path.is_dir():
            files.extend(p for p in sorted(path.glob("*.obj")) if p.stem.lower() != "neutral")
        elif path.is_file():
            files.append(path)
        else:
            raise ValueError(f"{path}: no such file or folder")
    if not files:
        raise ValueError(f"shapes: no example shapes (.obj) in {', '.join(str(s) for s in sources) or 'nothing'}")
    return files


def read_shapes(sources, rig: FaceRig, *, names: str = "file", scale: float = 1.0) -> list[ExampleShape]:
    """Example shapes from OBJ files or folders of them, in the rig's units (coordinates × ``scale``).

    Raises:
        ValueError: no shapes; a file that does not exist or cannot be read; another vertex count or other
            triangles than the rig; non-finite coordinates; ``names="arkit"`` and a stem that is no ARKit name;
            two shapes of one name. The message names the file.
    """
    if names not in NAME_STYLES:
        raise ValueError(f"names: expected one of {', '.join(NAME_STYLES)}, got {names!r}")
    if not (isinstance(scale, (int, float)) and np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale: expected a positive number, got {scale!r}")
    shapes = []
    for path in _files(sources):
        name = path.stem
        if names == "arkit":
            name = arkit_name(path.stem)
            if name is None:
                raise ValueError(f"{path}: {path.stem!r} is not an ARKit blendshape name")
        try:
            points, triangles = load_obj(path)
        except (OSError, ValueError) as error:
            raise ValueError(f"{path}: cannot read the shape ({error})") from None
        if len(points) == rig.mesh.vertex_count and not np.array_equal(triangles, rig.mesh.triangles):
            raise ValueError(f"{path}: same vertex count as the rig but other triangles (topology differs)")
        shapes.append(ExampleShape(name, points * float(scale), str(path)))
    return check_shapes(shapes, rig)


def check_shapes(shapes, rig: FaceRig) -> list[ExampleShape]:
    """``shapes`` (ExampleShapes, or ``{name: points}``) checked against ``rig``: ValueError naming the shape."""
    if not isinstance(rig, FaceRig):
        raise TypeError(f"rig: expected a warpface.FaceRig, got {type(rig).__name__}")
    if isinstance(shapes, dict):
        shapes = [ExampleShape(str(name), points) for name, points in shapes.items()]
    shapes = list(shapes)
    if not shapes:
        raise ValueError("shapes: no example shapes given")
    seen = set()
    out = []
    for shape in shapes:
        if not isinstance(shape, ExampleShape):
            raise TypeError(f"shapes: expected ExampleShape items or a dict of arrays, got {type(shape).__name__}")
        label = shape.source or shape.name
        points = np.asarray(shape.points, dtype=np.float64) if not isinstance(shape.points, FaceMesh) else None
        if points is None or points.ndim != 2 or points.shape[1:] != (3,):
            raise ValueError(f"{label}: expected points of shape (V, 3)")
        if len(points) != rig.mesh.vertex_count:
            raise ValueError(f"{label}: {len(points)} vertices, the rig has {rig.mesh.vertex_count} (topology differs)")
        if not np.all(np.isfinite(points)):
            raise ValueError(f"{label}: non-finite (NaN or inf) coordinates")
        if shape.name in seen:
            raise ValueError(f"{label}: a second example named {shape.name!r}")
        seen.add(shape.name)
        out.append(ExampleShape(shape.name, points, shape.source))
    return out
