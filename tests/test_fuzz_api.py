"""Property-based tests across the public API: the classes of input a fuzz run found raising
from inside numpy, pathlib, Warp or pxr, or returning NaN, now meet warpface's own checks.

Each call returns a finite result, or raises ValueError / TypeError (RigError is a ValueError) whose
one-line message names the item — raised by warpface itself: the innermost traceback frame is in the
warpface package, not in a library it called.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from helpers import small_face_rig
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import warpface

FUZZ = settings(
    max_examples=int(os.environ.get("WARPFACE_FUZZ_EXAMPLES", 30)),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
PACKAGE = str(Path(warpface.__file__).parent)

numbers = st.one_of(
    st.floats(-10.0, 10.0),
    st.sampled_from([0.0, -0.0, 1e-300, 1e-30, 1e6, 1e7, 1e20, 1e39, -1e39, 1e300, -1e300, np.inf, -np.inf, np.nan]),
    st.integers(-3, 3),
    st.sampled_from([2**31, 2**63, -(2**63), 10**9]),
)
junk = st.sampled_from(
    [
        None,
        "abc",
        "",
        b"x",
        {},
        {"a": {}},
        [],
        [1, 2],
        [[1, 2], [3]],
        True,
        object(),
        1 + 1j,
        np.array(["a", "b"]),
        np.zeros((0, 3)),
        np.zeros((1, 2, 3)),
        np.array(1.0),
    ]
)
anything = st.one_of(numbers, junk)


def _walk_finite(value, depth=0) -> None:
    if depth > 3 or value is None or isinstance(value, (str, bytes, bool)):
        return
    if isinstance(value, (float, np.floating)):
        assert np.isfinite(value), "non-finite result"
    elif isinstance(value, np.ndarray) and value.dtype.kind in "fc":
        assert np.all(np.isfinite(value)), "non-finite result"
    elif isinstance(value, dict):
        for item in value.values():
            _walk_finite(item, depth + 1)
    elif isinstance(value, (list, tuple)):
        for item in value[:50]:
            _walk_finite(item, depth + 1)
    elif hasattr(value, "__dataclass_fields__"):
        for name in value.__dataclass_fields__:
            if not name.startswith("_"):
                _walk_finite(getattr(value, name), depth + 1)


def outcome(call, *names):
    """``call()``'s result, checked finite; or None after checking a clean, own error naming one of ``names``."""
    try:
        with np.errstate(all="ignore"):
            result = call()
    except (ValueError, TypeError) as error:
        message = str(error)
        assert "\n" not in message.strip(), f"multi-line error: {message!r}"
        assert any(name in message for name in names), f"error does not name {names}: {message!r}"
        frame = error.__traceback__
        while frame.tb_next is not None:
            frame = frame.tb_next
        origin = frame.tb_frame.f_code.co_filename
        assert origin.startswith(PACKAGE), f"{type(error).__name__} raised in {origin}, not by warpface: {message}"
        return None
    _walk_finite(result)
    return result


@pytest.fixture(scope="module")
def rig():
    return small_face_rig(8)


# ------------------------------------------------------------------ devices, paths, object types
devices = st.one_of(
    st.sampled_from(["cpu", None, "CPU", "cpux", "", "/", "cuda:77", "nonexistent", "\x00"]), junk, numbers
)


@FUZZ
@given(device=devices, which=st.sampled_from(["model", "normals", "closest", "tissue_state", "operators", "adapter"]))
def test_device_arguments_are_checked(rig, device, which):
    from warpface.fem import TissueState
    from warpface.geometry import closest_points
    from warpface.solve import RigOperators
    from warpface.tracking import adapter_for_face, vertex_landmark_names

    mesh = rig.mesh
    calls = {
        "model": lambda: rig.model(device=device),
        "normals": lambda: mesh.vertex_normals(device=device),
        "closest": lambda: closest_points(mesh.points[:3], mesh.points, mesh.triangles, device=device),
        "tissue_state": lambda: TissueState(4, device=device),
        "operators": lambda: RigOperators.from_rig(rig, device=device),
        "adapter": lambda: adapter_for_face(mesh.points, vertex_landmark_names([0, 9, 30, 60]), device=device),
    }
    result = outcome(calls[which], "device")
    if device is None or (isinstance(device, str) and device == "cpu"):
        assert result is not None


paths = st.one_of(
    junk, numbers, st.sampled_from(["x" * 300, "a\x00b", "", "/", ".", "missing/file.csv", "/proc/no/such"])
)


@FUZZ
@given(
    path=paths,
    which=st.sampled_from(
        [
            "read_driver",
            "read_live_link",
            "detect_format",
            "write_live_link",
            "load_obj",
            "open_stage",
            "recorded",
            "save_image",
        ]
    ),
)
def test_path_arguments_never_raise_os_errors(tmp_path_factory, path, which):
    from warpface import drivers, load_obj, preview, usd
    from warpface.drivers.csv_formats import read_live_link
    from warpface.tracking import RecordedLandmarks
    from warpface.usd import open_stage

    curves = drivers.Curves(np.arange(3) / 30.0, ["jawOpen"], np.zeros((3, 1)), fps=30.0)
    calls = {
        "read_driver": lambda: usd.read_driver(path),
        "read_live_link": lambda: read_live_link(path),
        "detect_format": lambda: drivers.detect_format(path),
        "write_live_link": lambda: drivers.write_live_link(path, curves),
        "load_obj": lambda: load_obj(path),
        "open_stage": lambda: open_stage(path),
        "recorded": lambda: RecordedLandmarks(path),
        "save_image": lambda: preview.save_image(path, np.zeros((4, 4, 3), np.uint8)),
    }
    cwd = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("paths"))  # relative paths land in a scratch folder
    try:
        outcome(calls[which], "path", "file", "folder", "format", str(path)[:20] if isinstance(path, str) else "path")
    finally:
        os.chdir(cwd)


@FUZZ
@given(
    value=anything,
    which=st.sampled_from(
        [
            "rig_scale",
            "preset",
            "timeline",
            "mapping_for_rig",
            "fit",
            "model_from_rig",
            "clean",
            "resample",
            "write_openface",
            "project_controls",
            "frame_times",
            "stage_meters_per_unit",
            "embed_points",
            "assemble",
            "jaw_points",
            "kinect_rng",
        ]
    ),
)
def test_wrong_object_types_are_type_errors(rig, value, which):
    from warpface import ExpressionModel, assets, drivers, fem, solve, usd
    from warpface.expression import jaw_points
    from warpface.tracking import KinectNoise

    calls = {
        "rig_scale": lambda: assets.rig_scale(value),
        "preset": lambda: assets.preset_controls("smile", value),
        "timeline": lambda: assets.expression_timeline("smile", value),
        "mapping_for_rig": lambda: drivers.mapping_for_rig(value),
        "fit": lambda: solve.fit(value, np.zeros((3, 3)), vertices=[0, 1, 2]),
        "model_from_rig": lambda: ExpressionModel.from_rig(value, device="cpu"),
        "clean": lambda: drivers.clean(value),
        "resample": lambda: drivers.resample(value, 30.0),
        "write_openface": lambda: drivers.write_openface("unused.csv", value),
        "project_controls": lambda: drivers.project_controls(value, np.zeros((1, 1))),
        "frame_times": lambda: usd.frame_times(value),
        "stage_meters_per_unit": lambda: usd.stage_meters_per_unit(value),
        "embed_points": lambda: fem.embed_points(value, np.zeros((1, 3))),
        "assemble": lambda: fem.assemble(value, fem.kato_uniform_material()),
        "jaw_points": lambda: jaw_points(value, rig.mesh.points, [0.1, 0.0, 0.0]),
        "kinect_rng": lambda: KinectNoise().apply(np.full((4, 4), 0.5), value),
    }
    with pytest.raises(TypeError) as caught:
        calls[which]()
    assert "expected a" in str(caught.value) and "\n" not in str(caught.value)


# ------------------------------------------------------------------ geometry, metrics, preview
@FUZZ
@given(
    scale=numbers,
    index=st.one_of(st.integers(-5, 70), st.sampled_from([2**40, -(2**40)])),
    kind=st.sampled_from(["int", "float", "bool", "junk"]),
)
def test_triangle_helpers(rig, scale, index, kind):
    from warpface.geometry import area_weighted_vertex_normals, triangle_areas, triangle_corners, triangle_normals

    points = rig.mesh.points * scale if isinstance(scale, (int, float)) else rig.mesh.points
    triangles = rig.mesh.triangles.astype(np.int64).copy()
    triangles[0, 0] = index
    triangles = {"int": triangles, "float": triangles.astype(float), "bool": triangles > 3, "junk": [[1, 2], [3]]}[kind]
    corners = outcome(lambda: triangle_corners(points, triangles), "points", "triangles")
    if corners is not None:
        assert np.all(index >= 0) and index < len(points)
        outcome(lambda: triangle_areas(corners), "corners")
        outcome(lambda: triangle_normals(corners), "corners")
    outcome(lambda: area_weighted_vertex_normals(points, triangles), "points", "triangles")


@FUZZ
@given(vertices=st.one_of(anything, st.lists(st.integers(-3, 80), max_size=4)), scale=numbers)
def test_surface_error_and_distances(rig, vertices, scale):
    from warpface.metrics import point_distances, surface_error

    points = rig.mesh.points
    other = points * scale if isinstance(scale, (int, float)) else points
    result = outcome(lambda: surface_error(points, other, vertices=vertices), "surface_error", "point_distances")
    if result is not None:
        assert 0 <= result.argmax < len(points)
    outcome(lambda: point_distances(points, other), "point_distances")


@FUZZ
@given(
    eye=st.one_of(anything, st.lists(numbers, min_size=3, max_size=3)),
    fov=anything,
    size=st.one_of(anything, st.tuples(numbers, numbers)),
    vmin=anything,
    cmap=st.sampled_from(["inferno", "nope", 3]),
)
def test_preview_arguments_without_rendering(rig, eye, fov, size, vmin, cmap):
    from warpface.preview import Camera, heat_colors, scale_label

    camera = outcome(lambda: Camera(eye, [0.0, 0.0, 0.0], yfov_deg=fov), "camera")
    if camera is not None:
        pose = camera.pose()
        assert np.all(np.isfinite(pose))
    outcome(lambda: Camera.framing(rig.mesh.points, yaw_deg=fov, aspect=fov), "yaw_deg", "aspect", "camera framing")
    colours = outcome(lambda: heat_colors(np.linspace(0, 1, 5), vmin=vmin, cmap=cmap), "vmin", "cmap")
    if colours is not None:
        assert colours.shape == (5, 3) and np.all((colours >= 0) & (colours <= 1))
    outcome(lambda: scale_label(vmin, fov), "value", "span")


# ------------------------------------------------------------------ assets, drivers
@FUZZ
@given(
    frames=anything,
    hold=anything,
    seconds=anything,
    intensity=anything,
    name=st.one_of(st.sampled_from(["smile", "nope"]), junk),
)
def test_expression_timelines(frames, hold, seconds, intensity, name):
    from warpface.assets import expression_envelope, expression_timeline

    envelope = outcome(lambda: expression_envelope(frames, hold), "expression envelope")
    if envelope is not None:
        assert envelope.shape == (frames,) and envelope[0] == 0.0
    outcome(
        lambda: expression_timeline(name, _default_rig(), seconds, 30.0, intensity=intensity),
        "expression",
        "seconds",
        "intensity",
    )


_RIG = []


def _default_rig():
    if not _RIG:
        from warpface.assets import default_rig

        _RIG.append(default_rig(device="cpu"))
    return _RIG[0]


entries = st.one_of(
    junk,
    st.lists(
        st.one_of(st.tuples(st.sampled_from(["jawOpen", 3]), st.sampled_from(["frontalis_R", None]), numbers), junk),
        max_size=3,
    ),
)


@FUZZ
@given(
    entries=entries,
    offsets=st.one_of(junk, st.dictionaries(st.sampled_from(["frontalis_R", "x"]), anything, max_size=2)),
    table=st.one_of(junk, st.dictionaries(st.sampled_from(["jawOpen", "nope"]), anything, max_size=2)),
    fps=anything,
)
def test_driver_mappings_and_cleanup(entries, offsets, table, fps):
    from warpface import drivers

    mapping = outcome(lambda: drivers.Mapping.from_entries(entries, offsets=offsets), "entries", "offsets", "mapping")
    curves = drivers.Curves(np.arange(4) / 30.0, ["jawOpen", "mouthSmileLeft"], np.full((4, 2), 0.25), fps=30.0)
    if mapping is not None and mapping.channels:
        mapped = outcome(lambda: mapping.apply(curves), "mapping")
        if mapped is not None:
            assert mapped.values.shape[0] == 4
        outcome(
            lambda: drivers.project_controls(mapping, np.zeros((2, len(mapping.controls))), ridge=fps),
            "ridge",
            "controls",
            "no non-zero weight",
        )
    outcome(
        lambda: drivers.clean(curves, neutral=table, gain=table, offset=table), "neutral", "gain", "offset", "curves"
    )
    resampled = outcome(lambda: drivers.resample(curves, fps), "fps")
    if resampled is not None:
        assert resampled.frame_count >= 1
    outcome(
        lambda: drivers.Curves(
            np.arange(2.0), [fps, "b"] if not isinstance(fps, str) else ["a", "b"], np.zeros((2, 2)), fps=fps
        ),
        "names",
        "frame rate",
        "curves",
    )


# ------------------------------------------------------------------ FEM sizes, tracking helpers, solver targets
@FUZZ
@given(count=anything, cells=st.one_of(anything, st.tuples(anything, st.just(2), st.just(2))), tets_scale=numbers)
def test_fem_sizes(count, cells, tets_scale):
    from warpface.fem import TetMesh, TissueControl, TissueState, box_tet_mesh, shell_tet_mesh

    state = outcome(lambda: TissueState(count, device="cpu"), "node_count")
    if state is not None:
        assert state.node_count == count
    outcome(lambda: TissueControl(count, device="cpu"), "driven_count")
    outcome(lambda: box_tet_mesh((0.01, 0.01, 0.01), cells), "box_tet_mesh")
    outcome(lambda: shell_tet_mesh(count, 2, 1), "shell_tet_mesh")
    box = box_tet_mesh((0.01, 0.01, 0.01), (1, 1, 1))
    with np.errstate(all="ignore"):
        tets = (
            box.tets.astype(np.float64) * tets_scale
            if isinstance(tets_scale, float)
            else box.tets.astype(object) * tets_scale
        )
    outcome(lambda: TetMesh.repaired(box.points, tets), "TetMesh")


@FUZZ
@given(
    points=st.one_of(anything, st.lists(st.lists(numbers, min_size=3, max_size=3), min_size=1, max_size=3)),
    depth=anything,
    noise=st.dictionaries(st.sampled_from(["sigma0", "z_ref", "dropout", "baseline_focal"]), anything, max_size=2),
    count=anything,
    spacing=anything,
    names=st.one_of(junk, st.lists(st.sampled_from(["v0001", "v9", "x", 3]), max_size=3)),
)
def test_tracking_helpers(rig, points, depth, noise, count, spacing, names):
    from warpface.tracking import KINECT_V1_INTRINSICS, KinectNoise, landmark_vertices, place_fiducials

    pixels = outcome(lambda: KINECT_V1_INTRINSICS.project(points), "points")
    if pixels is not None:
        assert pixels.shape[1] == 2
    outcome(lambda: KINECT_V1_INTRINSICS.unproject([[320.0, 240.0]], depth), "depth", "pixels")
    model = outcome(lambda: KinectNoise(**noise), "KinectNoise")
    if model is not None:
        outcome(lambda: model.apply(np.full((4, 4), 0.5), np.random.default_rng(0)), "depth")
    mesh = rig.mesh
    chosen = outcome(
        lambda: place_fiducials(mesh.points, mesh.triangles, count, spacing=spacing, device="cpu"),
        "count",
        "spacing",
        "no vertex",
    )
    if chosen is not None:
        assert np.all((chosen >= 0) & (chosen < mesh.vertex_count))
    indices = outcome(lambda: landmark_vertices(names, 10), "landmark", "vertex_count")
    if indices is not None:
        assert np.all((indices >= 0) & (indices < 10))


@FUZZ
@given(value=st.sampled_from([1e6 + 1.0, 1e20, 1e300, -1e300, 0.5]))
def test_solver_targets_within_range(rig, value):
    from warpface.solve import fit

    target = rig.mesh.points[:4].copy()
    target[1, 2] = value
    result = outcome(lambda: fit(rig, target, vertices=[0, 1, 2, 3], device="cpu", max_iterations=5), "target")
    assert (result is None) == (abs(value) > 1e6)
