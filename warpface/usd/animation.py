"""Animation on a rig stage: contractions, wrinkle depths and the jaw's controls as time samples, and the
frames they play at.

Controls live on the rig prims (``contraction`` on muscles, ``depth`` on wrinkles, ``jawOpen`` [rad],
``jawForward`` and ``jawLeft`` [lengths] on the jaw), authored in the stage's edit target. Baking them
into a point cache is :mod:`warpface.usd.baking`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np
from pxr import Sdf, Usd

from .._validate import as_finite_array, as_positive, expect_instance
from ..errors import RigError
from ._files import open_stage
from .jaw_io import JAW_CONTROL_ATTRIBUTES, jaw_prim
from .rig_io import ItemPlacements, RigPrims, rig_prims, stage_meters_per_unit
from .schema import ensure_schema

__all__ = [
    "Animation",
    "write_animation",
    "read_animation",
    "frame_times",
    "frame_range",
    "as_time_codes",
    "cover_time_range",
    "DEFAULT_FPS",
    "MAX_FRAMES",
    "CACHE_SUFFIX",
]

DEFAULT_FPS = 30.0
"""``timeCodesPerSecond`` / ``framesPerSecond`` given to an animated stage that has none."""

CACHE_SUFFIX = "_anim.usdc"
"""Default bake cache file: ``<rig layer stem>_anim.usdc`` beside the rig layer (see :mod:`warpface.usd.baking`)."""

MAX_FRAMES = 100_000
"""Most frames :func:`frame_times`, :func:`frame_range` and :func:`~warpface.usd.bake` accept unless told otherwise
(``max_frames``; ``warpface bake --max-frames``): 55 minutes at 30 fps, 13 GB of points for the
built-in face. A larger count is almost always a typo in a time range or a step."""

_LINEAR = "WarpFaceLinearMuscle"


@dataclass(frozen=True)
class Animation:
    """Rig controls sampled at time codes."""

    times: np.ndarray
    """Time codes, shape (F,), float64 (frames; seconds = time / timeCodesPerSecond)."""
    contractions: np.ndarray
    """Muscle contractions in muscle order, shape (F, M), float64 (linear: length units; sphincter: 1)."""
    wrinkle_depths: np.ndarray
    """Wrinkle depths ``k_d`` in wrinkle order [length units], shape (F, W), float64."""
    muscle_names: list[str]
    wrinkle_names: list[str]
    jaw: np.ndarray | None = None
    """The jaw's controls ``jaw_open`` [rad], ``jaw_forward``, ``jaw_left`` [length units], shape (F, 3),
    float64; ``None`` when the rig has no jaw."""

    @property
    def control_names(self) -> list[str]:
        """The muscles, then the jaw's controls when the rig has a jaw (the expression model's control order)."""
        return self.muscle_names + (list(JAW_CONTROL_ATTRIBUTES) if self.jaw is not None else [])

    @property
    def controls(self) -> np.ndarray:
        """Contractions, then the jaw's controls: shape (F, M) or (F, M + 3), in :attr:`control_names` order."""
        return self.contractions if self.jaw is None else np.concatenate([self.contractions, self.jaw], axis=1)


# ---------------------------------------------------------------------------------------------- controls


def _length_scales(
    stage: Usd.Stage, prims: RigPrims, jaw: Usd.Prim | None, meters_per_unit: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Factors turning stored control values into values in ``meters_per_unit`` units, per muscle, wrinkle and
    jaw control.

    Linear-muscle contractions, wrinkle depths and the jaw's slides are lengths in their prim's local
    space; sphincter contractions and the jaw's opening angle are dimensionless.
    """
    to_units = stage_meters_per_unit(stage) / as_positive(meters_per_unit, "meters_per_unit")
    placements = ItemPlacements(stage, prims.skin)
    muscle = np.array([placements.of(p).scale * to_units if p.GetTypeName() == _LINEAR else 1.0 for p in prims.muscles])
    wrinkle = np.array([placements.of(p).scale * to_units for p in prims.wrinkles])
    slide = placements.of(jaw).scale * to_units if jaw is not None else 1.0
    return muscle, wrinkle, np.array([1.0, slide, slide])


def _control_table(values, names: list[str], frame_count: int, label: str, kind: str) -> tuple[list[int], np.ndarray]:
    """(columns, values (F, len(columns))) from an (F, N) array or a mapping name → (F,) values."""
    if isinstance(values, Mapping):
        index = {name: i for i, name in enumerate(names)}
        columns, rows = [], []
        for name, series in values.items():
            if name not in index:
                raise ValueError(f"{label}: unknown {kind} name {name!r} (known: {', '.join(names) or 'none'})")
            columns.append(index[name])
            rows.append(as_finite_array(series, f"{label}[{name!r}]", shape=(frame_count,)))
        return columns, np.stack(rows, axis=1) if rows else np.zeros((frame_count, 0))
    table = as_finite_array(values, label, shape=(frame_count, len(names)))
    return list(range(len(names))), table


def as_time_codes(times, label: str = "times") -> np.ndarray:
    """``times`` as distinct finite time codes, shape (F,), float64; ValueError naming ``label`` otherwise."""
    times = as_finite_array(times, label, shape=(None,))
    if len(times) == 0:
        raise ValueError(f"{label}: no time codes given")
    if len(np.unique(times)) != len(times):
        raise ValueError(f"{label}: time codes repeat")
    return times


def write_animation(
    stage: Usd.Stage,
    times,
    *,
    contractions=None,
    wrinkle_depths=None,
    jaw=None,
    skin_path: str | None = None,
    fps: float | None = None,
    meters_per_unit: float = 1.0,
) -> None:
    """Author contractions, wrinkle depths and the jaw's controls as time samples on the rig prims.

    Existing samples of an animated attribute between ``min(times)`` and ``max(times)`` are replaced;
    samples outside that range are kept. The stage's ``startTimeCode``/``endTimeCode`` grow to cover
    ``times``; ``timeCodesPerSecond`` and ``framesPerSecond`` are set to ``fps`` (or to 30 when the
    stage has none).

    Args:
        stage: the rig stage; samples go to its edit target, time metadata to its root layer. Not saved.
        times: time codes, shape (F,).
        contractions: shape (F, M) in muscle order, or ``{muscle name: (F,) values}``.
        wrinkle_depths: shape (F, W) in wrinkle order, or ``{wrinkle name: (F,) values}``.
        jaw: the jaw's controls, shape (F, 3) (``jaw_open`` [rad], ``jaw_forward``, ``jaw_left``), or
            ``{control name: (F,) values}``; the rig must have a jaw.
        skin_path: the rig's skin mesh (default: the only one).
        fps: frames per second.
        meters_per_unit: length unit of the given values in metres (as returned by ``read_rig``).

    Raises:
        ValueError: wrong shapes, unknown names, non-finite values, repeated times, jaw controls for a rig
            without a jaw.
        RigError: the stage's rig is invalid.
    """
    expect_instance(stage, Usd.Stage, "stage")
    ensure_schema()
    times = as_time_codes(times)
    prims = rig_prims(stage, skin_path)
    jaw_controls = jaw_prim(stage, prims.skin)
    muscle_scale, wrinkle_scale, jaw_scale = _length_scales(stage, prims, jaw_controls, meters_per_unit)
    series = []
    if contractions is not None:
        columns, table = _control_table(contractions, prims.muscle_names, len(times), "contractions", "muscle")
        series += [(prims.muscles[c], "contraction", table[:, k] / muscle_scale[c]) for k, c in enumerate(columns)]
    if wrinkle_depths is not None:
        columns, table = _control_table(wrinkle_depths, prims.wrinkle_names, len(times), "wrinkle_depths", "wrinkle")
        series += [(prims.wrinkles[c], "depth", table[:, k] / wrinkle_scale[c]) for k, c in enumerate(columns)]
    if jaw is not None:
        if jaw_controls is None:
            raise ValueError(f"jaw: rig {prims.skin.GetPath()} has no jaw to animate")
        names = list(JAW_CONTROL_ATTRIBUTES)
        columns, table = _control_table(jaw, names, len(times), "jaw", "jaw control")
        series += [
            (jaw_controls, JAW_CONTROL_ATTRIBUTES[names[c]], table[:, k] / jaw_scale[c]) for k, c in enumerate(columns)
        ]

    layer = stage.GetEditTarget().GetLayer()
    paths = []
    for prim, name, _ in series:  # specs first: never create specs inside a change block
        paths.append(stage.GetEditTarget().MapToSpecPath(prim.GetPath().AppendProperty(name)))
        if layer.GetAttributeAtPath(paths[-1]) is None:
            prim.CreateAttribute(name, Sdf.ValueTypeNames.Double, custom=False)
    low, high = float(times.min()), float(times.max())
    with Sdf.ChangeBlock():
        for path, (_, _, values) in zip(paths, series):
            for time in layer.ListTimeSamplesForPath(path):
                if low <= time <= high:
                    layer.EraseTimeSample(path, time)
            for time, value in zip(times.tolist(), values.tolist()):
                layer.SetTimeSample(path, time, value)
    cover_time_range(stage.GetRootLayer(), low, high, fps)


def cover_time_range(layer: Sdf.Layer, low: float, high: float, fps: float | None) -> None:
    """Grow the layer's start/end time codes to cover [low, high]; author both rates."""
    if fps is not None:
        fps = as_positive(fps, "fps")
        layer.timeCodesPerSecond = fps
        layer.framesPerSecond = fps
    else:
        rate = (
            layer.timeCodesPerSecond
            if layer.HasTimeCodesPerSecond()
            else (layer.framesPerSecond if layer.HasFramesPerSecond() else DEFAULT_FPS)
        )
        if not layer.HasTimeCodesPerSecond():
            layer.timeCodesPerSecond = rate
        if not layer.HasFramesPerSecond():
            layer.framesPerSecond = layer.timeCodesPerSecond
    if layer.HasStartTimeCode() and layer.HasEndTimeCode():
        low, high = min(low, layer.startTimeCode), max(high, layer.endTimeCode)
    layer.startTimeCode = low
    layer.endTimeCode = high


def frame_range(
    start: float, end: float, step: float = 1.0, *, max_frames: int | None = MAX_FRAMES, label: str = "time range"
) -> np.ndarray:
    """Time codes ``start, start + step, …`` up to ``end`` (included), shape (F,), float64.

    Raises:
        ValueError: a non-finite bound or step, ``end < start``, ``step ≤ 0``, or more than
            ``max_frames`` frames (``None``: no limit) — checked before anything is allocated.
    """
    start, end, step = (
        as_finite_array(value, f"{label}: {name}", shape=()).item()
        for value, name in ((start, "start"), (end, "end"), (step, "step"))
    )
    if step <= 0:
        raise ValueError(f"{label}: step must be > 0, got {step:g}")
    if end < start:
        raise ValueError(f"{label}: end {end:g} is before start {start:g}")
    count = math.floor((end - start) / step + 1e-9) + 1
    _check_frame_count(count, max_frames, f"{label} [{start:g}, {end:g}] step {step:g}")
    times = start + step * np.arange(count, dtype=np.float64)
    if len(np.unique(times)) != count:
        raise ValueError(f"{label}: step {step:g} is too small to separate time codes near {end:g}")
    return times


def _check_frame_count(count: int, max_frames: int | None, what: str) -> None:
    if max_frames is not None and count > max_frames:
        raise ValueError(
            f"{what} has {count:.4g} frames, more than the limit of {max_frames}; "
            f"pass max_frames (warpface bake --max-frames) to allow it"
        )


def frame_times(stage: Usd.Stage, skin_path: str | None = None, *, max_frames: int | None = MAX_FRAMES) -> np.ndarray:
    """The time codes an animation plays at, shape (F,), float64.

    Whole frames from ``startTimeCode`` to ``endTimeCode`` when the stage authors them; otherwise the
    union of the contraction and depth time samples; empty when nothing is animated.

    Raises:
        RigError: the stage's time range is not finite or ends before it starts.
        ValueError: more than ``max_frames`` frames (``None``: no limit).
    """
    expect_instance(stage, Usd.Stage, "stage")
    if stage.HasAuthoredTimeCodeRange():
        start, end = stage.GetStartTimeCode(), stage.GetEndTimeCode()
        if not (math.isfinite(start) and math.isfinite(end)) or end < start:
            raise RigError(f"stage {stage.GetRootLayer().identifier}: invalid time range [{start}, {end}]")
        first, last = math.ceil(start), math.floor(end)
        _check_frame_count(
            max(last - first + 1, 0),
            max_frames,
            f"stage {stage.GetRootLayer().identifier}: time range [{start:g}, {end:g}]",
        )
        return np.arange(first, last + 1, dtype=np.float64)
    prims = rig_prims(stage, skin_path)
    samples = set()
    jaw = jaw_prim(stage, prims.skin)
    jaw_controls = [(jaw, name) for name in JAW_CONTROL_ATTRIBUTES.values()] if jaw is not None else []
    for prim, name in (
        [(p, "contraction") for p in prims.muscles] + [(p, "depth") for p in prims.wrinkles] + jaw_controls
    ):
        samples.update(prim.GetAttribute(name).GetTimeSamples())
    return np.array(sorted(samples), dtype=np.float64)


def read_animation(
    stage_or_path, times=None, *, skin_path: str | None = None, meters_per_unit: float = 1.0
) -> Animation:
    """Sample contractions, wrinkle depths and the jaw's controls at time codes (USD value resolution: held or
    interpolated).

    Args:
        stage_or_path: the rig stage or its file.
        times: time codes, shape (F,); default :func:`frame_times`.
        skin_path: the rig's skin mesh (default: the only one).
        meters_per_unit: length unit of the returned values in metres (default SI).

    Raises:
        RigError: a value is missing or non-finite (named by attribute path and time).
    """
    ensure_schema()
    stage = open_stage(stage_or_path)
    prims = rig_prims(stage, skin_path)
    times = frame_times(stage, skin_path) if times is None else as_finite_array(times, "times", shape=(None,))
    jaw = jaw_prim(stage, prims.skin)
    muscle_scale, wrinkle_scale, jaw_scale = _length_scales(stage, prims, jaw, meters_per_unit)
    contractions = _sample(prims.muscles, "contraction", times) * muscle_scale
    depths = _sample(prims.wrinkles, "depth", times) * wrinkle_scale
    if jaw is not None:
        jaw = (
            np.stack([_sample([jaw], name, times)[:, 0] for name in JAW_CONTROL_ATTRIBUTES.values()], axis=1)
            * jaw_scale
        )
    return Animation(
        times=times,
        contractions=contractions,
        wrinkle_depths=depths,
        muscle_names=prims.muscle_names,
        wrinkle_names=prims.wrinkle_names,
        jaw=jaw,
    )


def _sample(prims, name: str, times: np.ndarray) -> np.ndarray:
    table = np.empty((len(times), len(prims)), dtype=np.float64)
    for column, prim in enumerate(prims):
        attr = prim.GetAttribute(name)
        if not attr:
            raise RigError(f"{prim.GetPath()}.{name}: attribute is missing")
        query = Usd.AttributeQuery(attr)
        # An attribute without time samples (or clips) has one value at every time: read it once.
        sampled = times.tolist() if query.ValueMightBeTimeVarying() else times[:1].tolist()
        for row, time in enumerate(sampled):
            value = query.Get(time)
            if value is None or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise RigError(f"{attr.GetPath()}: bad value {value!r} at time {time}")
            table[row, column] = value
        table[len(sampled) :, column] = table[0, column] if len(sampled) else 0.0
    return table
