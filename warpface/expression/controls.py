"""Boundary checks of the expression model: rig parts, per-frame controls, output arrays.

Shared by :class:`~warpface.ExpressionModel` and :class:`~warpface.FaceRig`, so both raise the same
error for the same fault, with a message naming the item: a ``TypeError`` for a wrong type, a
:class:`~warpface.RigError` (a ``ValueError``) or ``ValueError`` for a wrong value.
"""

from __future__ import annotations

import numbers
from typing import Mapping, Sequence

import numpy as np
import warp as wp

from .._validate import MAX_COORDINATE, as_finite_array
from ..errors import RigError
from ..mesh import FaceMesh
from .lids import LidMuscle
from .muscles import MUSCLE_TYPES, SphincterMuscle
from .thickness import validate_thickness
from .wrinkles import Wrinkle

__all__ = [
    "MAX_SPHINCTER_CONTRACTION",
    "check_rig_parts",
    "contraction_limits",
    "control_vector",
    "frame_controls",
    "is_device_array",
    "as_device_array",
]

MAX_SPHINCTER_CONTRACTION = 1.0e3
"""Largest accepted |K| of a sphincter (dimensionless; K = 1 pulls the ring onto its centre).
Linear muscles' K is a length, bounded by :data:`~warpface._validate.MAX_COORDINATE` like every
length: together these keep a frame inside float32's range."""


def check_rig_parts(mesh, muscles, wrinkles, thickness, *, owner: str):
    """Validate a rig's parts; returns ``(muscles list, wrinkles list, thickness (V,) float64)``.

    Raises:
        TypeError: ``mesh`` not a FaceMesh; a muscle or wrinkle of the wrong type.
        RigError: duplicate names; a bad thickness. The message starts with ``owner`` and names the item.
    """
    if not isinstance(mesh, FaceMesh):
        raise TypeError(f"{owner}: mesh must be a FaceMesh, got {type(mesh).__name__}")
    parts = []
    for kind, items, types in (("muscle", muscles, MUSCLE_TYPES), ("wrinkle", wrinkles, (Wrinkle,))):
        if isinstance(items, (str, bytes, Mapping)) or not isinstance(items, (Sequence, np.ndarray, tuple, list)):
            expected = " or ".join(t.__name__ for t in types)
            raise TypeError(f"{owner}: {kind}s must be a sequence of {expected}, got {type(items).__name__}")
        items = list(items)
        names = set()
        for index, item in enumerate(items):
            if not isinstance(item, types):
                expected = " or ".join(t.__name__ for t in types)
                raise TypeError(f"{owner}: {kind} {index} has wrong type {type(item).__name__} (expected {expected})")
            if item.name in names:
                raise RigError(f"{owner}: duplicate {kind} name {item.name!r}")
            if isinstance(item, LidMuscle):
                try:
                    item.check_vertex_count(mesh.vertex_count)
                except ValueError as exc:
                    raise RigError(f"{owner}: {exc}") from None
            names.add(item.name)
        parts.append(items)
    try:
        values = validate_thickness(thickness, mesh.vertex_count)
    except ValueError as exc:
        raise RigError(f"{owner}: {exc}") from None
    return parts[0], parts[1], values


def contraction_limits(muscles) -> np.ndarray:
    """Largest accepted |K| per muscle, shape (M,): a length bound for linear muscles, dimensionless for sphincters."""
    dimensionless = (SphincterMuscle, LidMuscle)
    return np.array([MAX_SPHINCTER_CONTRACTION if isinstance(m, dimensionless) else MAX_COORDINATE for m in muscles])


def control_vector(
    values,
    names: list[str],
    default: np.ndarray,
    limits: np.ndarray,
    label: str,
    kind: str,
    *,
    argument: str | None = None,
) -> np.ndarray:
    """One frame's controls in rig order, shape (N,), float64.

    ``values``: ``None`` (``default``), a mapping ``{name: number}`` (absent names keep ``default``),
    or a sequence/array of N numbers. Names must be known strings, numbers finite and within ±``limits``.
    Errors about one item name it (``"{label} for {kind} 'name'"``), errors about the whole value name
    ``argument`` (default ``"{label}s"``).
    """
    whole = argument or f"{label}s"
    vector = np.array(default, dtype=np.float64)
    if values is None:
        return vector
    if isinstance(values, Mapping):
        index = {name: i for i, name in enumerate(names)}
        for name, value in values.items():
            if not isinstance(name, str) or name not in index:
                raise ValueError(f"{whole}: unknown {kind} name {name!r} (known: {', '.join(names) or 'none'})")
            if isinstance(value, bool) or not isinstance(value, (numbers.Real, np.ndarray)):
                raise TypeError(f"{label} for {kind} {name!r}: expected a number, got {type(value).__name__}")
            number = float(as_finite_array(value, f"{label} for {kind} {name!r}", shape=()))
            vector[index[name]] = _within(number, limits[index[name]], f"{label} for {kind} {name!r}")
        return vector
    if isinstance(values, (str, bytes)):
        raise TypeError(f"{whole}: expected a mapping or {len(names)} numbers, got a string")
    try:
        array = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise TypeError(
            f"{whole}: expected {len(names)} numbers in {kind} order, got {type(values).__name__}"
        ) from None
    if array.shape != (len(names),):
        raise ValueError(f"{whole}: expected {len(names)} values in {kind} order, got shape {array.shape}")
    inside = np.abs(array) <= limits  # False for NaN too: one test on the fast path
    if not inside.all():
        bad = int(np.flatnonzero(~inside)[0])
        item = f"{label} for {kind} {names[bad]!r}"
        if not np.isfinite(array[bad]):
            raise ValueError(f"{item}: non-finite value {array[bad]}")
        _within(float(array[bad]), limits[bad], item)
    return array


def _within(number: float, limit: float, name: str) -> float:
    if abs(number) > limit:
        raise ValueError(f"{name}: {number:.6g} is outside ±{limit:g}")
    return number


def frame_controls(values, to_vector, width: int, label: str, limits: np.ndarray | None = None) -> np.ndarray:
    """Many frames' controls, shape (F, width): an (F, width) array or a sequence of F per-frame values.

    An array within ±``limits`` is checked as a whole; anything else goes through ``to_vector`` frame
    by frame (which raises the error naming the frame's bad item).
    """
    if isinstance(values, (str, bytes, Mapping)) or values is None:
        raise ValueError(
            f"{label}: expected an array (frames, {width}) or a sequence of mappings, got {type(values).__name__}"
        )
    if isinstance(values, np.ndarray) or (
        isinstance(values, Sequence) and len(values) and not isinstance(values[0], Mapping)
    ):
        array = as_finite_array(values, label)
        if array.ndim != 2 or array.shape[1] != width:
            raise ValueError(f"{label}: expected shape (frames, {width}), got {array.shape}")
        if limits is not None and not np.any(np.abs(array) > limits):
            return array
        return np.stack([to_vector(row) for row in array]) if len(array) else array
    if isinstance(values, Sequence):
        return np.stack([to_vector(row) for row in values]) if len(values) else np.zeros((0, width))
    raise ValueError(
        f"{label}: expected an array (frames, {width}) or a sequence of mappings, got {type(values).__name__}"
    )


def is_device_array(value) -> bool:
    """Whether ``value`` is a Warp array or a foreign array exchanged zero-copy (DLPack: torch, JAX, …)."""
    return isinstance(value, wp.array) or (hasattr(value, "__dlpack__") and not isinstance(value, np.ndarray))


def as_device_array(value, name: str, *, device, shape: tuple, dtype) -> wp.array:
    """``value`` (a Warp array or a DLPack tensor) as a flat, contiguous Warp array of ``dtype`` on ``device``.

    ``shape`` is the expected shape in elements of ``dtype``; a float32 array whose last axis is 3 is
    accepted for ``wp.vec3`` (viewed, not copied). Nothing is copied and nothing is synchronised.
    """
    array = value
    if not isinstance(array, wp.array):
        try:
            array = wp.from_dlpack(value)
        except Exception as exc:  # noqa: BLE001 - any exporter failure is a wrong argument here
            raise TypeError(f"{name}: not a Warp array or a DLPack tensor ({exc})") from None
    if array.device != device:
        raise ValueError(f"{name}: array is on {array.device}, the model on {device}")
    if not array.is_contiguous:
        raise ValueError(f"{name}: array must be contiguous")
    if dtype == wp.vec3 and array.dtype == wp.float32 and array.ndim >= 2 and array.shape[-1] == 3:
        array = array.view(wp.vec3)
    if array.dtype != dtype:
        raise TypeError(f"{name}: expected dtype {wp.types.type_repr(dtype)}, got {wp.types.type_repr(array.dtype)}")
    if tuple(array.shape) != tuple(shape):
        raise ValueError(f"{name}: expected shape {tuple(shape)}, got {tuple(array.shape)}")
    return array.flatten() if array.ndim > 1 else array
