"""Point-cache bakes: the expression model evaluated at a rig stage's time codes, streamed into a ``.usdc``.

:func:`bake` writes the skin's ``points`` and ``extent`` time samples (and normals, when the skin's asset
authors them; :mod:`warpface.usd.asset_io`) as ``over`` opinions into a cache layer of its own. Where
that layer goes: with ``shot``, into a small *shot stage* whose layer stack is ``[cache, stage]`` (the
stage's own layer, the rig's, and the referenced asset stay byte for byte as they were: what ``warpface
bake`` does); without, sublayered (strongest sublayer) under the stage's root layer, which is saved
(what ``animate`` does with the stage it wrote itself). A referenced asset is never edited. The rest
shape lives in the skin's ``warpFaceShape`` variant (see :mod:`warpface.usd.rig_io`) or in the
referenced asset, which every sublayer opinion overrides.

Frames are read, evaluated and written in chunks: the cache is a ``.usdc`` file saved after every
chunk (crate files grow by appending), so memory stays bounded by one chunk however long the bake.
The file is a temporary one beside the cache, renamed onto it only when the bake is complete:
interrupting a bake (Ctrl-C, crash, error) leaves the previous rig layer and cache exactly as they
were. :func:`check_bake` runs every check :func:`bake` makes without writing anything (``warpface
validate`` uses it).
"""

from __future__ import annotations

import itertools
import os
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import closing
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from .._files import atomic_path
from .._validate import as_count, expect_instance
from ..errors import RigError
from ._files import open_layer, open_stage, usd_error_message, writable_path
from .animation import CACHE_SUFFIX, MAX_FRAMES, as_time_codes, frame_times, read_animation
from .asset_io import NORMAL_PROPERTIES, SkinNormals, jaw_followers, shells_of, write_jaw_followers
from .cache_layers import (
    attach_cache,
    check_shot_path,
    default_shot_path,
    find_sublayer,
    same_file,
    sublayer_files,
    write_shot,
)
from .rig_io import SHAPE_VARIANT_SET, read_rig, rig_prims, stage_meters_per_unit
from .schema import ensure_schema
from .skin_followers import skin_followers, write_skin_followers

__all__ = [
    "bake",
    "check_bake",
    "write_point_cache",
    "check_cache_path",
    "default_cache_path",
    "default_shot_path",
    "existing_cache_path",
    "CACHE_SUFFIX",
]

MAX_REACH = 10.0
"""A bake refuses a frame whose skin leaves the rest shape's bounding box by more than this many times
the box's diagonal: controls that far outside the rig's scale are a mistake, not an expression."""


def default_cache_path(stage: Usd.Stage) -> Path | None:
    """``<rig layer stem>_anim.usdc`` beside the stage's root layer; ``None`` for an in-memory root."""
    expect_instance(stage, Usd.Stage, "stage")
    root = stage.GetRootLayer()
    if root.anonymous:
        return None
    root_file = Path(root.realPath)
    return root_file.with_name(root_file.stem + CACHE_SUFFIX)


def existing_cache_path(stage: Usd.Stage, skin_path) -> Path | None:
    """The strongest sublayer of the root layer that is a points cache of ``skin_path`` (what a bake
    wrote), or ``None``."""
    expect_instance(stage, Usd.Stage, "stage")
    root = stage.GetRootLayer()
    for resolved in sublayer_files(root):
        layer = Sdf.Layer.Find(resolved)
        if layer is not None and layer.realPath and _is_points_cache(layer, skin_path):
            return Path(layer.realPath)
    return None


def check_cache_path(stage: Usd.Stage, cache_path, skin_path) -> Path:
    """``cache_path`` as an absolute Path after checking a bake may write it.

    Raises:
        ValueError: unwritable; the stage's own root layer or one of the layers it uses (other than a
            points cache already sublayered under it); an existing file that is unreadable or holds
            anything but a warpface points cache.
    """
    cache_path = writable_path(cache_path, (".usdc", ".usda"))
    root = stage.GetRootLayer()
    if root.realPath and same_file(root.realPath, cache_path):
        raise ValueError(f"cache {cache_path}: is the stage itself; choose another cache file")
    direct = {os.path.realpath(p) for p in sublayer_files(root)}
    for layer in stage.GetUsedLayers():
        if layer.realPath and same_file(layer.realPath, cache_path):
            if os.path.realpath(cache_path) not in direct or not _is_points_cache(layer, skin_path):
                raise ValueError(
                    f"cache {cache_path}: is one of the stage's own layers (not a points cache); "
                    f"choose another cache file"
                )
            return cache_path
    if cache_path.exists():
        layer = open_layer(cache_path)
        if not _is_points_cache(layer, skin_path):
            raise ValueError(
                f"cache {cache_path}: exists and holds more than a points cache of {skin_path}; "
                f"remove it or choose another cache file"
            )
    return cache_path


def check_bake(
    stage_or_path,
    frames=None,
    *,
    cache_path=None,
    skin_path: str | None = None,
    model=None,
    device=None,
    max_frames: int | None = MAX_FRAMES,
    chunk_frames: int = 64,
    evaluate: bool = True,
):
    """Everything :func:`bake` checks before and while it writes, without writing.

    With ``evaluate``, the model is evaluated (not written) at the control time samples in range,
    where the controls take their extreme values, so controls giving non-finite positions are found.

    Returns:
        ``(stage, times, cache_path, model)``: the model is ``model`` or one built from the stage's rig.

    Raises:
        ValueError, RigError: as :func:`bake` would, naming the file, prim or time code.
    """
    ensure_schema()
    stage = open_stage(stage_or_path)
    prims = rig_prims(stage, skin_path)
    skin_path = prims.skin.GetPath()
    times = frame_times(stage, skin_path, max_frames=max_frames) if frames is None else as_time_codes(frames, "frames")
    if len(times) == 0:
        raise ValueError(
            f"nothing to bake: stage {stage.GetRootLayer().identifier} has no time range or time samples; pass frames"
        )
    if max_frames is not None and len(times) > max_frames:
        raise ValueError(
            f"frames: {len(times)} frames, more than the limit of {max_frames}; pass max_frames to allow it"
        )
    if cache_path is None:
        cache_path = default_cache_path(stage)
        if cache_path is None:
            raise ValueError("bake: the stage's root layer is in memory; pass cache_path")
    cache_path = check_cache_path(stage, cache_path, skin_path)
    root = stage.GetRootLayer()
    if not root.anonymous:
        writable_path(root.realPath)
    _check_not_masked(stage, skin_path, cache_path)
    stage_unit = stage_meters_per_unit(stage)
    if model is None:
        from ..expression.model import ExpressionModel

        model = ExpressionModel.from_rig(
            read_rig(stage, skin_path=str(skin_path), meters_per_unit=stage_unit), device=device
        )
    elif model.mesh.vertex_count != len(
        prims.skin.GetAttribute(UsdGeom.Tokens.points).Get(Usd.TimeCode.Default()) or ()
    ):
        raise ValueError(
            f"bake: the model has {model.mesh.vertex_count} vertices, the skin {skin_path} a different count"
        )
    if prims.muscle_names != list(model.muscle_names) or prims.wrinkle_names != list(model.wrinkle_names):
        raise ValueError("bake: model's muscles or wrinkles differ from the stage's rig")
    if evaluate:
        sampled = _control_sample_times(prims, times)
        for start in range(0, len(sampled), chunk_frames):
            _evaluate(stage, model, sampled[start : start + chunk_frames], skin_path, stage_unit)
    return stage, times, cache_path, model


def bake(
    stage_or_path,
    frames=None,
    *,
    cache_path=None,
    skin_path: str | None = None,
    model=None,
    device=None,
    progress: bool = True,
    chunk_frames: int = 64,
    max_frames: int | None = MAX_FRAMES,
    workers: int | None = None,
    shot=None,
) -> Path:
    """Evaluate the expression model at every time code and write the skin's points and extent as a cache.

    The cache layer (``.usdc``: raw float32, memory-mapped) is sublayered as the strongest sublayer of
    the rig (root) layer, and the rig layer's time range grows to cover ``frames``. Re-baking a range
    replaces the cached samples in ``[min(frames), max(frames)]`` and keeps the others. Files are
    written through a temporary file and a rename; on any interruption the previous files stay intact.

    Args:
        stage_or_path: the rig stage or its file. A file-backed root layer is saved (it gains the
            sublayer); an in-memory one is only edited and needs ``cache_path``.
        frames: time codes to bake, shape (F,); default :func:`~warpface.usd.frame_times` of the stage.
        cache_path: the cache file (``.usdc``, or ``.usda`` for inspection); default
            ``<rig layer stem>_anim.usdc`` beside the rig layer. Never the stage or one of its layers.
        skin_path: the rig's skin mesh (default: the only one).
        model: a prebuilt :class:`~warpface.ExpressionModel` of this rig in stage units (optional).
        device: Warp device for the model (default: Warp's preferred device).
        progress: show a progress bar.
        chunk_frames: frames read, evaluated and written per batch (bounds the memory used).
        max_frames: refuse more frames than this (``None``: no limit).
        workers: threads evaluating chunks of frames while this one reads controls and writes (default:
            one per CPU core on the CPU, where Warp's kernels run serially and release the GIL). A GPU
            model always runs in this thread. The cache is the same bits for any count.
        shot: a ``.usda``/``.usdc`` shot stage to write (replaced if it exists): its layer stack is the
            cache over the stage's saved root layer, with the stage's units, up axis, default prim, rates
            and a time range covering the cache. The stage's root layer is then not edited at all.

    Returns:
        The cache file path.

    Raises:
        ValueError: no frames, too many frames, unwritable paths, a cache that is the stage or one of
            its layers, controls that give non-finite positions, bad arguments.
        RigError: the rig on the stage is invalid, or the rig layer authors the skin's points
            directly (which would hide the cache).
    """
    chunk_frames = as_count(chunk_frames, "chunk_frames", minimum=1)
    shot_path = None if shot is None else writable_path(shot, (".usda", ".usdc", ".usd"))
    if workers is not None:
        workers = as_count(workers, "workers", minimum=1)
    stage, times, cache_path, model = check_bake(
        stage_or_path,
        frames,
        cache_path=cache_path,
        skin_path=skin_path,
        model=model,
        device=device,
        max_frames=max_frames,
        evaluate=False,
    )
    if shot_path is not None:
        check_shot_path(stage, shot_path, cache_path)
    skin = rig_prims(stage, skin_path).skin
    skin_path, model = skin.GetPath(), shells_of(stage, skin, model)  # extra shells move only rigidly
    stage_unit = stage_meters_per_unit(stage)
    chunks = [times[start : start + chunk_frames] for start in range(0, len(times), chunk_frames)]
    workers = _evaluation_workers(model) if workers is None or not model.device.is_cpu else int(workers)
    with closing(_evaluated_chunks(stage, model, chunks, skin_path, stage_unit, workers)) as evaluated:
        return _write_cache(stage, skin, cache_path, chunks, evaluated, progress, shot_path=shot_path, model=model)


def write_point_cache(
    stage_or_path, times, positions, *, cache_path=None, skin_path: str | None = None, progress: bool = False
) -> Path:
    """Write given skin positions as the time-sampled point cache :func:`bake` writes (same layer, sublayering
    and atomic files): for skins computed elsewhere, e.g. by a simulation (``warpface.newton.SkinRecorder``).

    Args:
        stage_or_path: the rig stage or its file (as :func:`bake`).
        times: time codes, shape (F,).
        positions: skin points per time code in the stage's units, shape (F, V, 3).
        cache_path: the cache file; default ``<rig layer stem>_anim.usdc`` beside the rig layer.
        skin_path: the rig's skin mesh (default: the only one).
        progress: show a progress bar.

    Returns:
        The cache file path.

    Raises:
        ValueError: no frames, positions of the wrong shape or not finite, unwritable or forbidden paths.
        RigError: the rig on the stage is invalid, or the rig layer authors the skin's points directly.
    """
    ensure_schema()
    stage = open_stage(stage_or_path)
    skin = rig_prims(stage, skin_path).skin
    times = as_time_codes(times, "times")
    count = len(skin.GetAttribute(UsdGeom.Tokens.points).Get(Usd.TimeCode.Default()) or ())
    points = np.asarray(positions, dtype=np.float32)
    if len(times) == 0 or points.shape != (len(times), count, 3):
        raise ValueError(
            f"positions must have shape ({len(times)}, {count}, 3) for {skin.GetPath()}, got {points.shape}"
        )
    if not np.isfinite(points).all():
        raise ValueError(f"positions: frame {int(np.argmin(np.isfinite(points).all(axis=(1, 2))))} is not finite")
    if cache_path is None:
        cache_path = default_cache_path(stage)
        if cache_path is None:
            raise ValueError("write_point_cache: the stage's root layer is in memory; pass cache_path")
    cache_path = check_cache_path(stage, cache_path, skin.GetPath())
    _check_not_masked(stage, skin.GetPath(), cache_path)
    step = 64
    chunks = [times[start : start + step] for start in range(0, len(times), step)]
    frames = ((points[s : s + step], _extents(points[s : s + step])) for s in range(0, len(times), step))
    return _write_cache(stage, skin, cache_path, chunks, frames, progress)


def _write_cache(
    stage: Usd.Stage,
    skin: Usd.Prim,
    cache_path: Path,
    chunks: list,
    frames,
    progress: bool,
    *,
    shot_path=None,
    model=None,
) -> Path:
    """Write ``frames`` (an iterable of ``(positions (F, V, 3), extents (F, 2, 3))`` float32, one per chunk of
    time codes) as the skin's point cache, sublayered under the root layer or under the shot stage
    ``shot_path``; with ``model``, the asset's other meshes follow its jaw. Returns the cache path."""
    skin_path = skin.GetPath()
    times = np.concatenate(chunks)
    points_path = skin_path.AppendProperty(UsdGeom.Tokens.points)
    extent_path = skin_path.AppendProperty(UsdGeom.Tokens.extent)
    low, high = float(times.min()), float(times.max())
    incremental = cache_path.suffix == ".usdc"

    from tqdm import tqdm

    with atomic_path(cache_path, cache_path.suffix, create=False) as temporary:
        cache = _new_cache_layer(temporary, cache_path, skin_path, stage)
        normals = SkinNormals.of(skin)  # the asset's normals, rewritten for each frame
        if normals is not None:
            normals.prepare(cache, skin_path, low, high)
        with Sdf.ChangeBlock():
            for path in (points_path, extent_path):
                for time in cache.ListTimeSamplesForPath(path):
                    if low <= time <= high:
                        cache.EraseTimeSample(path, time)
        skin_rest = UsdGeom.Mesh(skin).GetPointsAttr().Get(Usd.TimeCode.Default())
        riding = skin_followers(stage, len(skin_rest)) if skin_rest is not None else []  # lashes on the lids
        with tqdm(total=len(times), desc="bake", unit="frame", disable=not progress, leave=False) as bar:
            for chunk, (positions, bounds) in zip(chunks, frames):
                write_skin_followers(cache, riding, skin_rest, chunk, positions)
                with Sdf.ChangeBlock():
                    for offset, time in enumerate(chunk.tolist()):
                        cache.SetTimeSample(points_path, time, Vt.Vec3fArray.FromNumpy(positions[offset]))
                        cache.SetTimeSample(extent_path, time, Vt.Vec3fArray.FromNumpy(bounds[offset]))
                        if normals is not None:
                            normals.write(cache, time, positions[offset])
                if incremental:
                    _save(cache, cache_path)
                bar.update(len(chunk))
        followers = jaw_followers(stage) if model is not None and model.jaw is not None else []
        if followers:  # the asset's other meshes on the jaw: the controls are read again only for them
            unit = stage_meters_per_unit(stage)
            animation = read_animation(stage, times, skin_path=str(skin_path), meters_per_unit=unit)
            write_jaw_followers(cache, followers, model, times, animation.controls)
        samples = cache.ListTimeSamplesForPath(points_path)
        cache.startTimeCode, cache.endTimeCode = min(samples), max(samples)
        _save(cache, cache_path)
        del cache
    opened = Sdf.Layer.Find(str(cache_path))
    if opened is not None:
        opened.Reload(force=True)
    root = stage.GetRootLayer()
    if shot_path is not None:
        write_shot(root, cache_path, shot_path)
    else:
        attach_cache(root, None if root.anonymous else Path(root.realPath), cache_path, low, high)
    return cache_path


def _evaluated_chunks(stage: Usd.Stage, model, chunks: list[np.ndarray], skin_path, stage_unit: float, workers: int):
    """``(positions (F, V, 3) float32, extents (F, 2, 3) float32)`` of each chunk of time codes, in order.

    The controls are read here (USD, in this thread); with several ``workers`` the model runs in that
    many threads a few chunks ahead of the caller, who writes the previous chunks meanwhile (with one,
    everything runs in this thread: a GPU model is only ever used from its caller's thread). Each
    chunk's frames are evaluated exactly as one serial ``evaluate`` would (same kernels, frame by
    frame), so the bits do not depend on the thread count. An error is raised when its chunk's turn
    comes, so it is the first in time order.
    """
    if workers == 1:
        for chunk in chunks:
            animation = read_animation(stage, chunk, skin_path=str(skin_path), meters_per_unit=stage_unit)
            yield _evaluate_controls(model, animation, chunk, skin_path)
        return
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="warpface-bake") as pool:
        pending: deque[Future] = deque()
        upcoming = iter(chunks)
        try:
            for _ in chunks:
                for chunk in itertools.islice(upcoming, workers + 1 - len(pending)):
                    pending.append(_submit(pool, stage, model, chunk, skin_path, stage_unit))
                yield pending.popleft().result()
        finally:
            for future in pending:
                future.cancel()


def _submit(
    pool: ThreadPoolExecutor, stage: Usd.Stage, model, times: np.ndarray, skin_path, stage_unit: float
) -> Future:
    """The chunk's controls read now and its evaluation queued on ``pool`` (a read error waits in the future)."""
    try:
        animation = read_animation(stage, times, skin_path=str(skin_path), meters_per_unit=stage_unit)
    except Exception as exc:  # raised in order, when the chunk's turn comes
        failed: Future = Future()
        failed.set_exception(exc)
        return failed
    return pool.submit(_evaluate_controls, model, animation, times, skin_path)


def _evaluation_workers(model) -> int:
    """Threads evaluating chunks at once: the CPU cores this process may use (at most 8), or 1 on a GPU."""
    if not model.device.is_cpu:
        return 1
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cores, 8))


def _evaluate(stage: Usd.Stage, model, times: np.ndarray, skin_path, stage_unit: float) -> np.ndarray:
    """Skin positions (F, V, 3) float32 at ``times``; ValueError naming the first time that is not finite."""
    animation = read_animation(stage, times, skin_path=str(skin_path), meters_per_unit=stage_unit)
    return _evaluate_controls(model, animation, times, skin_path)[0]


def _evaluate_controls(model, animation, times: np.ndarray, skin_path) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_evaluate` with the controls already read: (positions (F, V, 3), extents (F, 2, 3)) float32.

    Frames whose controls repeat an earlier frame's bit for bit (held curves, a neutral stretch) are
    evaluated once and copied.
    """
    muscles_and_jaw = animation.controls
    controls = np.ascontiguousarray(np.concatenate([muscles_and_jaw, animation.wrinkle_depths], axis=1))
    _, first, copies = np.unique(
        controls.view(np.uint8).reshape(len(controls), -1), axis=0, return_index=True, return_inverse=True
    )
    try:
        if len(first) == len(controls):
            positions = model.evaluate(muscles_and_jaw, wrinkle_depths=animation.wrinkle_depths)
        else:
            positions = model.evaluate(muscles_and_jaw[first], wrinkle_depths=animation.wrinkle_depths[first])
            positions = positions[copies.reshape(-1)]
    except ValueError as exc:
        for row, time in enumerate(times.tolist()):  # name the first frame the model refuses
            try:
                model.evaluate(muscles_and_jaw[row : row + 1], wrinkle_depths=animation.wrinkle_depths[row : row + 1])
            except ValueError as frame_error:
                raise ValueError(f"{skin_path}: controls at time {time:g}: {frame_error}") from None
        raise ValueError(f"{skin_path}: controls at time codes {times[0]:g} … {times[-1]:g}: {exc}") from None
    bounds = _extents(positions)
    finite = np.isfinite(bounds).all(axis=(1, 2))  # min/max propagate NaN and reach ±inf
    if not finite.all():
        raise ValueError(
            f"{skin_path}: the controls at time {times[int(np.argmin(finite))]:g} give non-finite skin "
            f"positions (a contraction or depth far outside the rig's scale); nothing was written"
        )
    rest = np.asarray(model.mesh.points, dtype=np.float64)
    lo, hi = rest.min(axis=0), rest.max(axis=0)
    size = float(np.linalg.norm(hi - lo)) or 1.0
    reach = np.maximum(lo - bounds[:, 0], bounds[:, 1] - hi).max(axis=1)  # how far each frame leaves the rest box
    if (reach > MAX_REACH * size).any():
        frame = int(np.argmax(reach))
        raise ValueError(
            f"{skin_path}: the controls at time {times[frame]:g} move the skin {reach[frame]:.3g} stage units "
            f"outside its rest box, more than {MAX_REACH:g}× the face's size {size:.3g} (a contraction or "
            f"depth far outside the rig's scale); nothing was written"
        )
    return positions, bounds


def _control_sample_times(prims, times: np.ndarray) -> np.ndarray:
    """The control time samples within [min(times), max(times)], plus both ends: where the controls
    take their extreme values (USD interpolates linearly between samples)."""
    low, high = float(times.min()), float(times.max())
    samples = {low, high}
    for prim, name in [(p, "contraction") for p in prims.muscles] + [(p, "depth") for p in prims.wrinkles]:
        attribute = prim.GetAttribute(name)
        if attribute:
            samples.update(t for t in attribute.GetTimeSamplesInInterval(Gf.Interval(low, high)))
    return np.array(sorted(samples), dtype=np.float64)


def _save(layer: Sdf.Layer, target: Path) -> None:
    try:
        saved = layer.Save()
    except Exception as exc:  # Tf.ErrorException: full disk, permissions, ...
        raise OSError(f"cannot write {target}: {usd_error_message(exc)}") from None
    if not saved:
        raise OSError(f"cannot write {target}")


_EXTENT_LANES = 128
"""Vertices :func:`_extents` reduces side by side."""


def _extents(positions: np.ndarray) -> np.ndarray:
    """Per-frame bounding boxes, (F, V, 3) → (F, 2, 3) float32 (min row, max row); NaN propagates."""
    # Reducing axis 1 of (F, V, 3) walks rows of 3 floats; viewed as (F, V/128, 384) each step is one
    # vectorised min/max of 384 floats, and the 128 lanes are folded afterwards (the same result).
    frames, count = positions.shape[:2]
    body = count - count % _EXTENT_LANES
    rows = positions[:, :body].reshape(frames, body // _EXTENT_LANES, 3 * _EXTENT_LANES)
    low = rows.min(axis=1, initial=np.inf).reshape(frames, _EXTENT_LANES, 3).min(axis=1)
    high = rows.max(axis=1, initial=-np.inf).reshape(frames, _EXTENT_LANES, 3).max(axis=1)
    if body < count:
        low = np.minimum(low, positions[:, body:].min(axis=1))
        high = np.maximum(high, positions[:, body:].max(axis=1))
    return np.stack([low, high], axis=1).astype(np.float32, copy=False)


def _new_cache_layer(temporary: Path, cache_path: Path, skin_path: Sdf.Path, stage: Usd.Stage) -> Sdf.Layer:
    """A new layer in file ``temporary`` with the existing cache's content (if any) and the point and extent specs."""
    try:
        layer = Sdf.Layer.CreateNew(str(temporary))
    except Exception as exc:
        raise OSError(f"cannot write {cache_path}: {usd_error_message(exc)}") from None
    if cache_path.exists():
        layer.TransferContent(open_layer(cache_path))
    # A sublayer's time codes are scaled by the ratio of its rate to the root's: keep them equal.
    layer.timeCodesPerSecond = stage.GetTimeCodesPerSecond()
    layer.framesPerSecond = stage.GetFramesPerSecond()
    prim = Sdf.CreatePrimInLayer(layer, skin_path)
    for name, type_name in (
        (UsdGeom.Tokens.points, Sdf.ValueTypeNames.Point3fArray),
        (UsdGeom.Tokens.extent, Sdf.ValueTypeNames.Float3Array),
    ):
        if prim.attributes.get(name) is None:
            Sdf.AttributeSpec(prim, name, type_name)
    return layer


def _is_points_cache(layer: Sdf.Layer, skin_path) -> bool:
    """True when ``layer`` holds nothing but ``over`` prims and the skin's points/extent/normals, and points/extent
    of other meshes (the asset's meshes that follow the jaw): what bake writes."""
    skin_path = Sdf.Path(str(skin_path))
    allowed = {skin_path.AppendProperty(name) for name in (UsdGeom.Tokens.points, UsdGeom.Tokens.extent)}
    allowed |= {skin_path.AppendProperty(name) for name in NORMAL_PROPERTIES}
    foreign = []

    def visit(path: Sdf.Path) -> None:
        if path.IsPropertyPath():
            if path not in allowed and path.name not in (UsdGeom.Tokens.points, UsdGeom.Tokens.extent):
                foreign.append(path)
        elif path.IsPrimPath():
            spec = layer.GetPrimAtPath(path)
            if spec is None or spec.specifier != Sdf.SpecifierOver:
                foreign.append(path)

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return not foreign and not layer.subLayerPaths


def _check_not_masked(stage: Usd.Stage, skin_path: Sdf.Path, cache_path: Path) -> None:
    """Raise if a layer stronger than the cache authors the skin's points or extent (it would hide the cache)."""
    root = stage.GetRootLayer()
    if find_sublayer(root, cache_path) is None:
        stronger = [root]  # the cache will become the strongest sublayer
    else:
        stronger = []
        for layer in stage.GetLayerStack(includeSessionLayers=False):
            if layer.realPath and same_file(layer.realPath, cache_path):
                break
            stronger.append(layer)
    for layer in stronger:
        for name in (UsdGeom.Tokens.points, UsdGeom.Tokens.extent):
            spec = layer.GetAttributeAtPath(skin_path.AppendProperty(name))
            if spec is not None and (spec.HasDefaultValue() or layer.GetNumTimeSamplesForPath(spec.path)):
                raise RigError(
                    f"{spec.path}: authored directly in layer {layer.identifier}, which is stronger than the cache and "
                    f"would hide it; author the rest shape in the skin's '{SHAPE_VARIANT_SET}' variant (write_rig does)"
                )
