"""Rigs and their expression models kept between takes of one process (``warpface batch``'s workers).

Building a rig's :class:`~warpface.ExpressionModel` evaluates every muscle's weight field with the tissue's
response, seconds for the built-in face; a worker that animates many takes of one rig builds it once here. A rig
is known by its stage file's resolved path, size and modification time (the built-in rig by name), and a model
by its rig and its Warp device, so a rig file changed between takes is read and built afresh. A model from the
cache is the same object a fresh build gives, bit for bit: the model is the rig's data only, never changed by
evaluation, and every frame is evaluated from the rest mesh.
"""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path

__all__ = ["RigModels", "load_rig", "RIG_SUFFIXES"]

RIG_SUFFIXES = (".usda", ".usdc", ".usd", ".usdz")
"""The extensions of a rig stage."""


def load_rig(rig_path):
    """(FaceRig in stage units, the rig's stage or None, meters per unit, the stage's rate or None) of the rig
    stage at ``rig_path``; None: the built-in face's rig.

    Raises:
        ValueError: not a USD stage, or a stage that does not hold a valid rig.
    """
    from ..usd import open_stage, read_rig, stage_meters_per_unit

    if rig_path is None:
        from ..assets import default_rig

        return default_rig(), None, 1.0, None
    if Path(rig_path).suffix.lower() not in RIG_SUFFIXES:
        raise ValueError(f"--rig {rig_path}: expected a USD rig stage (.usda, .usdc, .usd)")
    stage = open_stage(rig_path)
    units = stage_meters_per_unit(stage)
    rate = stage.GetTimeCodesPerSecond() if stage.GetRootLayer().HasTimeCodesPerSecond() else None
    return read_rig(stage, meters_per_unit=units), stage, units, rate


class RigModels:
    """The rigs (:func:`load_rig`) and expression models of the last ``capacity`` rig files used.

    Not shared between threads: one per worker process, used by one take at a time.
    """

    def __init__(self, capacity: int = 2):
        from .._validate import as_count

        self.capacity = as_count(capacity, "capacity", minimum=1)
        self._entries: OrderedDict[tuple, dict] = OrderedDict()
        self.builds = 0
        """How many expression models were built (a model taken from the cache is not counted)."""

    def load(self, rig_path):
        """:func:`load_rig` of ``rig_path``, read once per rig file (until the file changes)."""
        key = _rig_key(rig_path)
        entry = self._entries.get(key)
        if entry is None:
            for stale in [k for k in self._entries if k[:2] == key[:2]]:  # the same file before it changed
                del self._entries[stale]
            if rig_path is not None and Path(rig_path).suffix.lower() in RIG_SUFFIXES:
                _reload_if_open(rig_path)
            entry = {"rig": load_rig(rig_path), "models": {}}
            self._entries[key] = entry
            while len(self._entries) > self.capacity:
                self._entries.popitem(last=False)
        self._entries.move_to_end(key)
        return entry["rig"]

    def model(self, rig, *, device=None):
        """The expression model of ``rig`` (a FaceRig that :meth:`load` gave) on ``device`` (default: Warp's
        preferred device), built once per rig and device; a rig that :meth:`load` did not give (or gave before
        it was dropped) gets a model built for this call."""
        from .._validate import as_device

        alias = as_device(device).alias
        models = next((e["models"] for e in self._entries.values() if e["rig"][0] is rig), {})
        if alias not in models:
            models[alias] = rig.model(device=alias)
            self.builds += 1
        return models[alias]


def _rig_key(rig_path) -> tuple:
    """What identifies a rig: the built-in one, or a stage file by resolved path, size and modification time."""
    if rig_path is None:
        return ("built-in",)
    path = Path(rig_path)
    try:
        stat = path.stat()
    except OSError:  # let load_rig report a missing file the usual way
        return ("file", str(path.absolute()), None, None)
    return ("file", str(path.resolve()), stat.st_size, stat.st_mtime_ns)


def _reload_if_open(rig_path) -> None:
    """Read the rig file's root layer again if this process has it open (USD would hand back the layer it holds,
    as it was when first read, for a file another process has changed since)."""
    from pxr import Sdf

    layer = Sdf.Layer.Find(str(rig_path))
    if layer is not None:
        layer.Reload(force=True)
