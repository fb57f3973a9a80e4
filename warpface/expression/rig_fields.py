"""A rig's rig-time fields, computed once per rig and shared by the expression model and the solver.

The fields are what SPEC §1 and docs/RIG.md §14 evaluate before any frame: each muscle's weight field with the
tissue's response and the fold guards (:func:`~warpface.expression.tissue.skin_muscle_weights`), the wrinkle profiles
(:func:`~warpface.expression.wrinkles.skin_wrinkle_shapes`) and the guarded lifts
(:func:`~warpface.expression.lift_guard.guarded_lifts`). The expression model and the solver's operators read the
same ones; each used to compute them, which on a whole head is ~20 s apiece (a ``fit`` or ``track`` of a user's own
head paid it twice).

They are known by a digest of everything they are computed from — the rest mesh's points, triangles and degenerate
triangles, the muscles, wrinkles, thickness and jaw, the face's size and the device's kind — so two rigs that hold the
same data share them, and a rig changed in any number is computed afresh. The last :data:`KEPT` are kept in the
process, and every rig's on disk (:mod:`~warpface.expression.fields_cache`: a later process reads them instead of
computing them again); their arrays are read-only, as both readers only copy them.
"""

from __future__ import annotations

import hashlib
import pickle
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from .._validate import as_device
from .fields_cache import read_fields, write_fields
from .lids import bulging_thickness
from .lift_guard import guarded_lifts
from .muscles import MuscleWeights
from .tissue import skin_muscle_weights
from .wrinkles import WrinkleShapes, skin_wrinkle_shapes

__all__ = ["RigFields", "rig_fields", "forget_rig_fields", "KEPT"]

KEPT = 2
"""How many rigs' fields the process keeps (a whole head's are ~25 MB)."""


@dataclass(frozen=True)
class RigFields:
    """The rig-time fields of one rig (read-only arrays)."""

    weights: MuscleWeights
    """The muscles' weight fields with the tissue's response and the fold guards."""
    shapes: WrinkleShapes
    """The wrinkle profiles before the lift guard (``shapes.shape``)."""
    bulging: np.ndarray
    """The bulge's ``h`` after the lift guard, (V,) [mesh units]."""
    faded: np.ndarray
    """The wrinkle profiles after the lift guard, one per entry of ``shapes``."""


_KEPT: OrderedDict[str, RigFields] = OrderedDict()
_LOCK = threading.Lock()


def rig_fields(mesh, muscles, wrinkles, thickness: np.ndarray, jaw, size: float, *, device=None) -> RigFields:
    """The rig-time fields of a rig's parts (as :class:`~warpface.ExpressionModel` validated them: ``muscles`` and
    ``wrinkles`` lists, ``thickness`` (V,) [mesh units], ``jaw`` or None, the face's ``size`` [mesh units]) with the
    weight kernels on ``device``; the same object for the same data while the process keeps it (:data:`KEPT`)."""
    device = as_device(device)
    muscles, wrinkles = list(muscles), list(wrinkles)
    thickness = np.asarray(thickness, dtype=np.float64)
    key = _digest(mesh, muscles, wrinkles, thickness, jaw, float(size), device)
    with _LOCK:
        fields = _KEPT.get(key)
        if fields is not None:
            _KEPT.move_to_end(key)
            return fields
    counts = (mesh.vertex_count, len(muscles), len(wrinkles))
    stored = read_fields(key, counts)
    if stored is not None:
        fields = _from_arrays(stored)
    else:
        fields = _computed(mesh, muscles, wrinkles, thickness, jaw, float(size), device)
        write_fields(key, _arrays(fields))
    with _LOCK:  # two threads computing the same rig at once both get correct fields; the later one is kept
        _KEPT[key] = fields
        _KEPT.move_to_end(key)
        while len(_KEPT) > KEPT:
            _KEPT.popitem(last=False)
    return fields


def forget_rig_fields() -> None:
    """Let go of the fields the process keeps (the next :func:`rig_fields` of any rig reads or computes them)."""
    with _LOCK:
        _KEPT.clear()


def _computed(mesh, muscles, wrinkles, thickness, jaw, size, device) -> RigFields:
    """The fields as the model and the solver computed them, each array made read-only (copied where the lift guard
    may hand back an input's own array)."""
    weights = skin_muscle_weights(mesh, muscles, thickness, device=device, size=size)
    shapes = skin_wrinkle_shapes(mesh, wrinkles, muscles, device=device)
    bulging = bulging_thickness(thickness, muscles)
    bulging, faded = guarded_lifts(mesh, bulging, muscles, weights, wrinkles, shapes, jaw, size)
    for array in (weights.offsets, weights.muscle, weights.weight, shapes.offsets, shapes.wrinkle, shapes.shape):
        array.flags.writeable = False
    bulging, faded = np.array(bulging), np.array(faded)
    bulging.flags.writeable = faded.flags.writeable = False
    return RigFields(weights, shapes, bulging, faded)


def _arrays(fields: RigFields) -> dict[str, np.ndarray]:
    """The fields as the named arrays of a cache file (:data:`~warpface.expression.fields_cache.ARRAY_NAMES`)."""
    weights, shapes = fields.weights, fields.shapes
    return {
        "offsets": weights.offsets,
        "muscle": weights.muscle,
        "weight": weights.weight,
        "shape_offsets": shapes.offsets,
        "wrinkle": shapes.wrinkle,
        "shape": shapes.shape,
        "bulging": fields.bulging,
        "faded": fields.faded,
    }


def _from_arrays(arrays: dict[str, np.ndarray]) -> RigFields:
    """:func:`_arrays` undone, each array read-only."""
    for array in arrays.values():
        array.flags.writeable = False
    return RigFields(
        MuscleWeights(arrays["offsets"], arrays["muscle"], arrays["weight"]),
        WrinkleShapes(arrays["shape_offsets"], arrays["wrinkle"], arrays["shape"]),
        arrays["bulging"],
        arrays["faded"],
    )


def _digest(mesh, muscles, wrinkles, thickness, jaw, size, device) -> str:
    """SHA-256 of the fields' inputs: the arrays' bytes (with their dtypes and shapes) and the pickled parts."""
    digest = hashlib.sha256()
    for array in (mesh.points, mesh.triangles, mesh.degenerate_triangles, thickness):
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype.str}{array.shape}".encode())
        digest.update(array.tobytes())
    kind = "cpu" if device.is_cpu else f"cuda sm_{device.arch}"
    digest.update(pickle.dumps((muscles, wrinkles, jaw, size, kind), protocol=5))
    return digest.hexdigest()
