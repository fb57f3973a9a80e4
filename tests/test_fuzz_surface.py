"""Bad arguments to the public surface (meshes, rigs, assets, drivers, tracking, USD I/O, previews): each call
raises TypeError for a wrong type or ValueError for a wrong value — never a pxr/Boost, NumPy or OS error —
with a one-line message that names the argument, raised by warpface itself.

Every case swaps one argument of a valid call for a generated bad value; the valid call itself must succeed,
so a case cannot pass by failing for another reason.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from helpers import small_face_rig
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import warpface as wf

FUZZ = settings(
    max_examples=int(os.environ.get("WARPFACE_FUZZ_EXAMPLES", 25)),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
PACKAGE = str(Path(wf.__file__).parent)

WRONG_TYPES = [None, "abc", b"x", {}, {"a": 1}, object(), 1 + 1j, np.array(["a", "b"]), [None, "x"]]
"""Values of a type no argument below accepts (strings only where a name or path is not expected)."""
WRONG_VALUES = [np.nan, np.inf, -1.0, 0, 1e300, [[1.0, 2.0], [3.0]], np.zeros((2, 2, 2)), np.zeros((0, 3))]
bad_values = st.sampled_from(WRONG_TYPES + WRONG_VALUES)


def check_error(call, names, value=None):
    """Run ``call``; a clean result is fine, an error must be a warpface TypeError/ValueError naming one of
    ``names`` on one line (a bad file name may be named by itself: ``value``, when it is a string)."""
    if isinstance(value, bytes):
        value = value.decode(errors="replace")
    if isinstance(value, str) and value.strip():
        names = (*names, value[:20])
    try:
        with np.errstate(all="ignore"):
            call()
    except (TypeError, ValueError) as error:
        message = str(error)
        assert "\n" not in message.strip(), f"multi-line error: {message!r}"
        assert any(name in message for name in names), f"{type(error).__name__} does not name {names}: {message!r}"
        assert type(error).__module__ in ("builtins", "warpface.errors"), f"foreign {type(error)}: {message}"
        frame = error.__traceback__
        while frame.tb_next is not None:
            frame = frame.tb_next
        origin = frame.tb_frame.f_code.co_filename
        assert origin.startswith(PACKAGE), f"{type(error).__name__} raised in {origin}, not by warpface: {message}"
        return error
    return None


@pytest.fixture(scope="module")
def rig():
    return small_face_rig(8)


# ----------------------------------------------------------------- mesh, rig parts, geometry, assets, metrics
def _model_cases(rig):
    from warpface.assets import expression_contractions, preset_controls, rig_scale
    from warpface.geometry import TriangleMeshIndex, closest_points, triangle_areas
    from warpface.metrics import surface_error

    mesh = rig.mesh
    points, triangles = mesh.points, mesh.triangles
    obj = _obj_file(points, triangles)
    curve = [[0, 0], [1, 0], [2, 0], [3, 0]]
    planar = wf.PlanarProjection([0, 0, 0], [1, 0, 0], [0, 1, 0])
    muscle = ("m", [0, 0, 0], [1, 0, 0], 30.0, 0.5, 2.0)
    return {
        "FaceMesh.points": (lambda x: wf.FaceMesh(x, triangles), ("points",), points),
        "FaceMesh.triangles": (lambda x: wf.FaceMesh(points, x), ("triangles",), triangles),
        "FaceMesh.name": (lambda x: wf.FaceMesh(points, triangles, name=x), ("name",), "face"),
        "load_obj": (lambda x: wf.load_obj(x), ("path", "OBJ"), obj),
        "FaceRig.thickness": (lambda x: wf.FaceRig(mesh, rig.muscles, rig.wrinkles, x), ("thickness",), 0.003),
        "LinearMuscle.name": (lambda x: wf.LinearMuscle(x, *muscle[1:]), ("name",), "zyg"),
        "LinearMuscle.attachment": (lambda x: wf.LinearMuscle("m", x, *muscle[2:]), ("attachment",), [0, 1, 0]),
        "LinearMuscle.zone_angle": (lambda x: wf.LinearMuscle(*muscle[:3], x, 0.5, 2.0), ("zone_angle",), 40.0),
        "Wrinkle.control_points": (lambda x: wf.Wrinkle("w", x, planar, 1.0, 1.0), ("control_points",), curve),
        "Wrinkle.projection": (lambda x: wf.Wrinkle("w", curve, x, 1.0, 1.0), ("projection",), planar),
        "Wrinkle.width": (lambda x: wf.Wrinkle("w", curve, planar, 1.0, x), ("width",), 0.5),
        "PlanarProjection.origin": (lambda x: wf.PlanarProjection(x, [1, 0, 0], [0, 1, 0]), ("origin",), [0, 0, 1]),
        "closest_points.query": (lambda x: closest_points(x, points, triangles, device="cpu"), ("query",), points[:3]),
        "TriangleMeshIndex.triangles": (
            lambda x: TriangleMeshIndex(points, x, device="cpu"),
            ("triangles",),
            triangles,
        ),
        "triangle_areas": (lambda x: triangle_areas(x), ("corners",), points[triangles]),
        "rig_scale": (lambda x: rig_scale(x), ("rig",), _default_rig()),
        "preset_controls.rig": (lambda x: preset_controls("smile", x), ("rig",), _default_rig()),
        "expression_contractions.intensity": (
            lambda x: expression_contractions("smile", _default_rig(), intensity=x),
            ("intensity",),
            0.5,
        ),
        "surface_error.reference": (lambda x: surface_error(points, x), ("surface_error", "reference"), points),
    }


_RIG = []


def _obj_file(points, triangles) -> Path:
    import tempfile

    path = Path(tempfile.mkdtemp()) / "face.obj"
    lines = [f"v {x} {y} {z}" for x, y, z in points] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in triangles]
    path.write_text("\n".join(lines) + "\n")
    return path


def _default_rig():
    if not _RIG:
        from warpface.assets import default_rig

        _RIG.append(default_rig(device="cpu"))
    return _RIG[0]


@FUZZ
@given(data=st.data(), value=bad_values)
def test_model_and_content_arguments(rig, data, value):
    cases = _model_cases(rig)
    call, names, _ = cases[data.draw(st.sampled_from(sorted(cases)))]
    check_error(lambda: call(value), names, value)


# ----------------------------------------------------------------- drivers, tracking, previews
def _solver_cases(rig, tmp):
    from warpface import drivers, preview
    from warpface.tracking import KINECT_V1_INTRINSICS, RecordedLandmarks, landmark_vertices, place_fiducials
    from warpface.usd import read_driver

    curves = drivers.Curves(np.arange(3) / 30.0, ["jawOpen"], np.zeros((3, 1)), fps=30.0)
    take = drivers.write_live_link(tmp / "take.csv", curves)
    recording = tmp / "take.npz"
    np.savez(
        recording,
        timestamps=np.arange(2) / 30.0,
        points=np.zeros((2, 3, 3)),
        confidence=np.ones((2, 3), np.float32),
        names=np.array(["a", "b", "c"]),
    )
    mesh = rig.mesh
    return {
        "Curves.times": (
            lambda x: drivers.Curves(x, ["jawOpen"], np.zeros((3, 1)), fps=30.0),
            ("times", "curves"),
            [0, 1, 2],
        ),
        "Curves.values": (
            lambda x: drivers.Curves(np.arange(3.0), ["jawOpen"], x, fps=30.0),
            ("values", "curves"),
            np.ones((3, 1)),
        ),
        "resample.fps": (lambda x: drivers.resample(curves, x), ("fps",), 60.0),
        "clean.curves": (lambda x: drivers.clean(x), ("curves",), curves),
        "default_table.kind": (lambda x: drivers.default_table(x), ("kind",), "arkit"),
        "mapping_for_rig.rig": (lambda x: drivers.mapping_for_rig(x), ("rig",), _default_rig()),
        "Mapping.from_entries": (lambda x: drivers.Mapping.from_entries(x), ("entries",), [("jawOpen", "m", 1.0)]),
        "write_live_link.curves": (lambda x: drivers.write_live_link(tmp / "o.csv", x), ("curves",), curves),
        "read_driver.path": (lambda x: read_driver(x), ("path",), take),
        "read_driver.fps": (lambda x: read_driver(take, fps=x), ("fps",), 24.0),
        "project.points": (lambda x: KINECT_V1_INTRINSICS.project(x), ("points",), [[0.0, 0.0, 0.6]]),
        "landmark_vertices.names": (lambda x: landmark_vertices(x, 10), ("landmark", "names"), ["v0001"]),
        "place_fiducials.count": (
            lambda x: place_fiducials(mesh.points, mesh.triangles, x, device="cpu"),
            ("count",),
            4,
        ),
        "RecordedLandmarks.path": (lambda x: RecordedLandmarks(x), ("path",), recording),
        "heat_colors.cmap": (lambda x: preview.heat_colors(np.linspace(0, 1, 4), cmap=x), ("cmap",), "viridis"),
        "heat_colors.values": (lambda x: preview.heat_colors(x), ("values",), [0.0, 1.0]),
    }


@FUZZ
@given(data=st.data(), value=bad_values)
def test_driver_tracking_and_preview_arguments(rig, tmp_path_factory, data, value):
    cases = _solver_cases(rig, tmp_path_factory.mktemp("drv"))
    call, names, _ = cases[data.draw(st.sampled_from(sorted(cases)))]
    check_error(lambda: call(value), names, value)


# ----------------------------------------------------------------- USD I/O
def drivers_curves():
    from warpface.drivers import Curves

    return Curves(np.arange(3) / 30.0, ["jawOpen"], np.zeros((3, 1)), fps=30.0)


prim_paths = st.sampled_from([5, 2.5, None, b"/Face", ["/Face"], {"a": 1}, object(), "", "/", "rel/path", "not a path"])


def _usd_cases(rig, folder):
    from warpface import usd
    from warpface.usd.skel_io import read_skel_animation, write_skel_animation

    stage = usd.write_rig(folder / "rig.usda", rig)
    skin = str(usd.rig_prims(stage).skin.GetPath())
    contractions = np.zeros((1, len(rig.muscles)))
    curves = drivers_curves()
    skel = write_skel_animation(folder / "skel.usda", curves)
    return {
        "rig_prims.skin_path": (lambda x: usd.rig_prims(stage, x), ("skin_path",), skin),
        "read_rig.skin_path": (lambda x: usd.read_rig(stage, skin_path=x), ("skin_path",), skin),
        "read_rig.stage": (lambda x: usd.read_rig(x), ("stage", "path", "USD file"), stage),
        "frame_times.skin_path": (lambda x: usd.frame_times(stage, x), ("skin_path",), skin),
        "read_animation.skin_path": (lambda x: usd.read_animation(stage, skin_path=x), ("skin_path",), skin),
        "write_animation.skin_path": (
            lambda x: usd.write_animation(stage, [0.0], contractions=contractions, skin_path=x),
            ("skin_path",),
            skin,
        ),
        "write_animation.times": (
            lambda x: usd.write_animation(stage, x, contractions=contractions),
            ("times",),
            [3.0],
        ),
        "write_rig.root_path": (
            lambda x: usd.write_rig(folder / "o.usda", rig, root_path=x),
            ("root_path",),
            "/Other",
        ),
        "write_rig.rig": (lambda x: usd.write_rig(folder / "o.usda", x), ("rig",), rig),
        "read_skel_animation.prim_path": (
            lambda x: read_skel_animation(skel, prim_path=x),
            ("prim_path",),
            "/Animation",
        ),
        "stage_meters_per_unit": (lambda x: usd.stage_meters_per_unit(x), ("stage",), stage),
        "validate_stage": (lambda x: usd.validate_stage(x), ("stage", "path", "USD file"), stage),
        "open_stage": (lambda x: usd.open_stage(x), ("stage", "path", "USD file"), str(folder / "rig.usda")),
    }


@FUZZ
@given(data=st.data(), value=st.one_of(prim_paths, bad_values))
def test_usd_arguments(rig, tmp_path_factory, data, value):
    pytest.importorskip("pxr")
    cases = _usd_cases(rig, tmp_path_factory.mktemp("usd"))
    case = data.draw(st.sampled_from(sorted(cases)))
    call, names, _ = cases[case]
    if isinstance(value, str) and not case.endswith("path"):
        return  # a string is a file name there: covered by the path tests of test_fuzz_api
    check_error(lambda: call(value), names, value)


def test_a_wrong_type_is_a_type_error_and_a_wrong_value_a_value_error(rig, tmp_path):
    """The rule itself, on one argument of each kind."""
    pytest.importorskip("pxr")
    from warpface import usd

    stage = usd.write_rig(tmp_path / "rig.usda", rig)
    for wrong_type in (5, b"/Face", ["/Face"]):
        assert isinstance(check_error(lambda value=wrong_type: usd.rig_prims(stage, value), ("skin_path",)), TypeError)
    for wrong_value in ("/", "rel/path", "not a path"):
        error = check_error(lambda value=wrong_value: usd.rig_prims(stage, value), ("skin_path",))
        assert type(error) is ValueError
    assert isinstance(check_error(lambda: wf.FaceMesh("abc", [[0, 1, 2]]), ("points",)), TypeError)
    assert type(check_error(lambda: wf.FaceMesh([[0, 0, np.nan]] * 3, [[0, 1, 2]]), ("points",))) is ValueError
    assert isinstance(check_error(lambda: wf.FaceMesh(rig.mesh.points, rig.mesh.triangles > 3), ("tri",)), TypeError)


def test_every_case_accepts_its_valid_value(rig, tmp_path):
    """Each fuzzed call succeeds with a good value in the fuzzed slot: the errors above come from that slot."""
    cases = {**_model_cases(rig), **_solver_cases(rig, tmp_path)}
    try:
        import pxr  # noqa: F401

        folder = tmp_path / "usd"
        folder.mkdir()
        cases.update(_usd_cases(rig, folder))
    except ImportError:
        pass
    for name, (call, _, good) in sorted(cases.items()):
        try:
            call(good)
        except Exception as error:  # noqa: BLE001 — name the case that broke
            pytest.fail(f"{name}: the valid call raised {type(error).__name__}: {error}")
