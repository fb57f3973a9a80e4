"""Validation at the boundary, written once: points, triangles, per-vertex arrays, scalars, vectors.

Every public constructor and call checks its inputs with these helpers, so the same fault gives the
same error and a one-line message naming the argument: TypeError for a wrong type (a string, None, a
dict or a non-numeric array where numbers belong; a float array where indices belong), ValueError for a
wrong value (shape, range, non-finite numbers, a ragged nesting of sequences). Ranges are chosen so
that nothing valid can overflow the float32 kernels (see :data:`MAX_COORDINATE`).
"""

from __future__ import annotations

import numbers
import os
from pathlib import Path

import numpy as np

__all__ = [
    "MAX_COORDINATE",
    "MAX_VERTICES",
    "as_finite_array",
    "as_points",
    "as_triangles",
    "as_per_vertex",
    "as_vec3",
    "as_positive",
    "as_bounded",
    "as_count",
    "as_indices",
    "unit_vector",
    "orthogonal_unit_vector",
    "as_device",
    "as_path",
    "expect_instance",
    "expect_iterable",
    "shape_of",
]

MAX_COORDINATE = 1.0e6
"""Largest accepted |coordinate|, length or thickness [mesh units]. The per-frame kernels run in
float32 and square edge cross products (≈ length⁴), which overflow float32 (3.4e38) near 1e9; 1e6
leaves room for deformation, and covers faces in metres, millimetres or micrometres."""


MAX_VERTICES = 1 << 26
"""Largest vertex count a per-vertex array is made for (67 M; a face mesh has tens of thousands)."""


def as_finite_array(
    value, name: str, *, shape: tuple | None = None, dtype=np.float64, max_abs: float | None = None
) -> np.ndarray:
    """``value`` as an array of ``dtype``, naming ``name`` in every error.

    TypeError when ``value`` is not numbers (None, text, a dict, strings or objects inside); ValueError on
    a ragged nesting, a bad shape or non-finite values. ``shape`` may contain ``None`` for a free
    dimension. With ``max_abs``, values of larger magnitude are rejected too.
    """
    if isinstance(value, (str, bytes, dict)) or value is None:
        raise TypeError(f"{name}: expected numbers, got {type(value).__name__}")
    try:
        array = np.asarray(value, dtype=dtype)
    except OverflowError:
        raise ValueError(f"{name}: a number is too large for {np.dtype(dtype).name}") from None
    except (TypeError, ValueError):
        kind = _kind(value)
        error = ValueError if "unequal or nested" in kind else TypeError
        raise error(f"{name}: expected a number or a regular array of numbers, got {kind}") from None
    if shape is not None:
        if array.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, array.shape)):
            expected = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
            raise ValueError(f"{name}: expected shape {expected}, got {array.shape}")
    if np.issubdtype(array.dtype, np.floating):
        if not np.all(np.isfinite(array)):
            bad = np.argwhere(~np.isfinite(array))
            raise ValueError(f"{name}: non-finite value at index {tuple(int(i) for i in bad[0])}")
        if max_abs is not None and array.size and float(np.abs(array).max()) > max_abs:
            bad = np.unravel_index(int(np.argmax(np.abs(array))), array.shape)
            raise ValueError(
                f"{name}: value {array[bad]:.6g} at index {tuple(int(i) for i in bad)} is outside ±{max_abs:g}"
            )
    return array


def as_points(value, name: str, *, max_abs: float = MAX_COORDINATE, min_count: int = 0) -> np.ndarray:
    """Finite points, shape (N, 3), float64, every coordinate within ±``max_abs``; N ≥ ``min_count``."""
    points = as_finite_array(value, name, shape=(None, 3), max_abs=max_abs)
    if len(points) < min_count:
        raise ValueError(f"{name}: need at least {min_count} point(s), got {len(points)}")
    return points


def as_triangles(
    value, vertex_count: int, name: str, *, integral_floats: bool = False, allow_empty: bool = False
) -> np.ndarray:
    """Triangle vertex indices, shape (T, 3) with T ≥ 1, int32, each in [0, vertex_count).

    Index arrays must have an integer dtype; with ``integral_floats``, float arrays whose values are
    whole numbers (as some loaders produce) are accepted too.
    """
    if isinstance(value, (str, bytes, dict)) or value is None:
        raise TypeError(f"{name}: expected an integer array of shape (T, 3), got {type(value).__name__}")
    try:
        triangles = np.asarray(value)
    except (TypeError, ValueError):  # ragged nesting
        raise ValueError(f"{name}: expected a regular integer array of shape (T, 3), got {_kind(value)}") from None
    if triangles.ndim != 2 or triangles.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (T, 3), got {triangles.shape}")
    if len(triangles) == 0 and not allow_empty:
        raise ValueError(f"{name}: no triangles")
    if triangles.dtype == np.bool_ or not (
        np.issubdtype(triangles.dtype, np.integer) or np.issubdtype(triangles.dtype, np.floating)
    ):
        raise TypeError(f"{name}: expected integer vertex indices, got dtype {triangles.dtype}")
    if np.issubdtype(triangles.dtype, np.floating):
        if not integral_floats:
            raise TypeError(f"{name}: expected integer vertex indices, got dtype {triangles.dtype}")
        if not np.all(np.isfinite(triangles)) or np.any(triangles != np.round(triangles)):
            raise ValueError(f"{name}: triangle indices must be whole numbers")
        triangles = np.clip(triangles, -1, vertex_count)  # out-of-range stays out of range, fits int64
    triangles = triangles.astype(np.int64)
    bad = np.flatnonzero(np.any((triangles < 0) | (triangles >= vertex_count), axis=1))
    if len(bad):
        t = int(bad[0])
        raise ValueError(
            f"{name}: triangle {t} {triangles[t].tolist()} has a vertex index out of range [0, {vertex_count}) "
            f"({len(bad)} such triangles)"
        )
    return triangles.astype(np.int32)


def as_per_vertex(
    value,
    vertex_count: int,
    name: str,
    *,
    minimum: float | None = None,
    maximum: float | None = None,
    broadcast: bool = True,
) -> np.ndarray:
    """One finite float64 per vertex, shape (V,); a scalar is broadcast (with ``broadcast``).

    Values below ``minimum`` or above ``maximum`` are rejected naming the first offending vertex.
    """
    values = as_finite_array(value, name)
    if values.ndim == 0 and broadcast:
        values = np.full(vertex_count, float(values))
    if values.shape != (vertex_count,):
        raise ValueError(f"{name}: expected one value per vertex ({vertex_count},), got shape {values.shape}")
    if minimum is not None and np.any(values < minimum):
        v = int(np.flatnonzero(values < minimum)[0])
        what = "negative value" if minimum == 0.0 else f"value below {minimum:g}:"
        raise ValueError(f"{name}: {what} {values[v]:.6g} at vertex {v}")
    if maximum is not None and np.any(values > maximum):
        v = int(np.flatnonzero(values > maximum)[0])
        raise ValueError(f"{name}: value {values[v]:.6g} at vertex {v} is above the largest accepted {maximum:g}")
    return values


def as_vec3(value, name: str, *, max_abs: float = MAX_COORDINATE) -> np.ndarray:
    """A finite 3-vector, float64, shape (3,), within ±``max_abs``."""
    return as_finite_array(value, name, shape=(3,), max_abs=max_abs)


def as_positive(value, name: str, *, allow_zero: bool = False, maximum: float = MAX_COORDINATE) -> float:
    """A finite scalar that is > 0 (or ≥ 0 with ``allow_zero``) and ≤ ``maximum``."""
    number = float(as_finite_array(value, name, shape=()))
    if number < 0.0 or (number == 0.0 and not allow_zero):
        raise ValueError(f"{name}: must be {'≥' if allow_zero else '>'} 0, got {number}")
    if number > maximum:
        raise ValueError(f"{name}: {number:.6g} is above the largest accepted value {maximum:g}")
    return number


def as_bounded(value, name: str, lower: float, upper: float) -> float:
    """A finite scalar in the closed range [``lower``, ``upper``]."""
    number = float(as_finite_array(value, name, shape=()))
    if not lower <= number <= upper:
        raise ValueError(f"{name}: {number:.6g} is outside [{lower:g}, {upper:g}]")
    return number


def as_count(value, name: str, *, minimum: int = 0, maximum: int | None = None) -> int:
    """A Python/NumPy integer (not bool) in [``minimum``, ``maximum``]."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name}: expected an integer, got {type(value).__name__}")
    count = int(value)
    if count < minimum or (maximum is not None and count > maximum):
        upper = "∞" if maximum is None else str(maximum)
        raise ValueError(f"{name}: {count} is outside [{minimum}, {upper}]")
    return count


def as_indices(value, count: int, name: str) -> np.ndarray:
    """A 1-D array of indices into ``count`` items, int64, each in [0, ``count``); integer dtype (or whole
    floats), never bool. TypeError/ValueError naming ``name`` otherwise."""
    if isinstance(value, (str, bytes, dict)) or value is None:
        raise TypeError(f"{name}: expected an integer index array, got {type(value).__name__}")
    try:
        indices = np.asarray(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a flat integer index array, got {_kind(value)}") from None
    if indices.ndim != 1:
        raise ValueError(f"{name}: expected a flat (N,) index array, got shape {indices.shape}")
    if indices.size and (
        indices.dtype == np.bool_
        or not (np.issubdtype(indices.dtype, np.integer) or np.issubdtype(indices.dtype, np.floating))
    ):
        raise TypeError(f"{name}: expected integer indices, got dtype {indices.dtype}")
    if np.issubdtype(indices.dtype, np.floating):
        if not np.all(np.isfinite(indices)) or np.any(indices != np.round(indices)):
            raise ValueError(f"{name}: indices must be whole numbers")
        indices = np.clip(indices, -1, count)
    indices = indices.astype(np.int64)
    bad = np.flatnonzero((indices < 0) | (indices >= count))
    if len(bad):
        raise ValueError(f"{name}: index {int(indices[bad[0]])} at position {int(bad[0])} is out of range [0, {count})")
    return indices


def unit_vector(value, name: str) -> np.ndarray:
    """``value`` normalised to unit length; raises ValueError if it has zero length.

    A vector whose length already rounds to 1 is returned unchanged: dividing it by that length can
    flip its last bit, and validated records (muscles, projections) must survive re-validation exactly
    (e.g. a USD round trip). Any finite magnitude is accepted (huge vectors are pre-scaled).
    """
    vector = as_finite_array(value, name, shape=(3,))
    scale = float(np.abs(vector).max())
    if scale > 1e150:  # |v|² would overflow float64
        vector = vector / scale
    length = float(np.linalg.norm(vector))
    if length <= 1e-12 * max(1.0, float(np.abs(vector).max())):
        raise ValueError(f"{name}: zero-length vector")
    if abs(length - 1.0) <= 2.0 * np.finfo(np.float64).eps:
        return vector
    return vector / length


def orthogonal_unit_vector(value, axis: np.ndarray, name: str) -> np.ndarray:
    """``value`` with its component along the unit vector ``axis`` removed, normalised (Gram–Schmidt).

    A vector already orthogonal to ``axis`` to within 1e-12 (relative) is only normalised, so that
    re-validating a validated frame is exact. Raises ValueError if ``value`` is parallel to ``axis``.
    """
    vector = as_finite_array(value, name, shape=(3,))
    scale = float(np.abs(vector).max())
    if scale > 1e150:
        vector = vector / scale
    along = float(np.dot(vector, axis))
    if abs(along) > 1e-12 * float(np.linalg.norm(vector)):
        vector = vector - along * axis
    return unit_vector(vector, name)


def as_device(device, name: str = "device"):
    """The Warp device ``device`` names: ``None`` (Warp's preferred device), a ``warp.Device``, or a
    name such as ``"cpu"``, ``"cuda"`` or ``"cuda:1"``. TypeError/ValueError naming ``name`` otherwise
    (Warp itself raises RuntimeError for ``"cuda"`` on a machine without CUDA)."""
    import warp as wp

    if device is None or isinstance(device, wp.Device):
        return wp.get_device(device)
    if not isinstance(device, str):
        raise TypeError(
            f"{name}: expected a Warp device or a name such as 'cpu' or 'cuda:0', got {type(device).__name__}"
        )
    try:
        return wp.get_device(device)
    except (ValueError, RuntimeError) as exc:
        raise ValueError(
            f"{name}: {device[:40]!r} is not a device of this machine (use 'cpu', 'cuda' or 'cuda:N'; {_short(exc)})"
        ) from None


def as_path(value, name: str) -> Path:
    """``value`` as a :class:`~pathlib.Path`: a ``str``/``bytes``/``os.PathLike`` that the operating system
    can take (not empty, no NUL byte, no component over 255 bytes). TypeError/ValueError naming ``name``
    otherwise, so a bad path never surfaces as an OSError from deep inside a reader or writer."""
    if not isinstance(value, (str, bytes, os.PathLike)):
        raise TypeError(f"{name}: expected a file path, got {type(value).__name__}")
    text = os.fsdecode(os.fspath(value))
    if not text.strip():
        raise ValueError(f"{name}: empty file path")
    if "\x00" in text:
        raise ValueError(f"{name}: file path contains a NUL byte")
    path = Path(text)
    if any(len(os.fsencode(part)) > 255 for part in path.parts):
        raise ValueError(f"{name}: a component of the file path is longer than 255 bytes")
    return path


def expect_instance(value, types, name: str):
    """``value`` unchanged when it is an instance of ``types`` (a class or tuple of classes), else a
    TypeError naming ``name``, the expected class and what was given."""
    if not isinstance(value, types):
        expected = " or ".join(t.__name__ for t in (types if isinstance(types, tuple) else (types,)))
        raise TypeError(f"{name}: expected a {expected}, got {type(value).__name__}")
    return value


def expect_iterable(value, name: str, *, item_types=None, sized: bool = False):
    """``value`` when it is an iterable (a sized collection with ``sized``), not a string or bytes, else
    a TypeError naming ``name``. With ``item_types`` the items are checked lazily: the returned
    generator raises TypeError at the first item of another type."""
    from collections.abc import Iterable, Sized

    if (
        isinstance(value, (str, bytes, dict))
        or not isinstance(value, Iterable)
        or (sized and not isinstance(value, Sized))
        or (isinstance(value, np.ndarray) and value.ndim == 0)
    ):
        raise TypeError(f"{name}: expected {'a list' if sized else 'an iterable'} of items, got {type(value).__name__}")
    if item_types is None:
        return value

    def checked():
        for position, item in enumerate(value):
            expect_instance(item, item_types, f"{name}[{position}]")
            yield item

    return checked()


def shape_of(value) -> tuple | None:
    """NumPy's shape of ``value``, or None for a ragged nesting NumPy cannot make an array of."""
    try:
        return np.shape(value)
    except (TypeError, ValueError):
        return None


def _kind(value) -> str:
    """What ``value`` is, for a message: its type, and for containers the first element's type
    that is not a number (``list containing dict``)."""
    kind = type(value).__name__
    if isinstance(value, (list, tuple)):
        for item in value:
            if not isinstance(item, (numbers.Number, np.generic)):
                if isinstance(item, (list, tuple, np.ndarray)):
                    return f"{kind} of unequal or nested sequences"
                return f"{kind} containing {type(item).__name__}"
    if isinstance(value, np.ndarray):
        return f"array of dtype {value.dtype}"
    return kind


def _short(exc: Exception) -> str:
    return str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
