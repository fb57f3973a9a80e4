"""Property-based tests of the model layer's public calls (issue 9): random valid, boundary and
invalid inputs give a finite result or a ValueError/TypeError/RigError whose message names the item —
never another exception, never NaN/inf, never an invalid index."""

import os

import numpy as np
import pytest
from helpers import grid_surface, small_face_rig
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import warpface as wf
from warpface.errors import RigError
from warpface.geometry import closest_points

DEVICE = "cpu"
FUZZ = settings(
    max_examples=int(os.environ.get("WARPFACE_FUZZ_EXAMPLES", 40)),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)

# Numbers a user might pass: ordinary, boundary (0, ±tiny, ±huge), float32-overflowing, non-finite.
numbers = st.one_of(
    st.floats(-10.0, 10.0),
    st.sampled_from(
        [0.0, -0.0, 1e-300, 1e-30, -1e-30, 1e3, -1e3, 1e6, -1e6, 1e7, 1e20, 1e39, -1e39, 1e300, np.inf, -np.inf, np.nan]
    ),
    st.integers(-5, 5),
)
# Anything: numbers plus wrong types.
anything = st.one_of(numbers, st.sampled_from([None, "1", b"x", {}, [], [1, 2], {"a": 1}, True, object()]))
vectors = st.one_of(st.lists(numbers, min_size=3, max_size=3), st.lists(numbers, min_size=0, max_size=5), anything)


def outcome(call, *names):
    """Run ``call``; return its result, or None after checking a clean error naming one of ``names``."""
    try:
        return call()
    except (ValueError, TypeError) as exc:  # RigError is a ValueError
        message = str(exc)
        assert "\n" not in message.strip(), f"multi-line error: {message!r}"
        assert any(name in message for name in names), f"error does not name {names}: {message!r}"
        return None


def finite(*arrays):
    for array in arrays:
        assert np.all(np.isfinite(np.asarray(array, dtype=np.float64))), "NaN/inf returned"


@pytest.fixture(scope="module")
def rig():
    return small_face_rig(8)


@pytest.fixture(scope="module")
def model(rig):
    return rig.model(device=DEVICE)


@FUZZ
@given(
    scale=numbers,
    shift=numbers,
    triangles=st.one_of(
        st.just([[0, 1, 2]]),
        st.lists(
            st.lists(st.one_of(st.integers(-3, 5), st.sampled_from([2**40, -(2**40)])), min_size=3, max_size=3),
            min_size=0,
            max_size=3,
        ),
        st.just(np.array([[0.0, 1.0, np.nan]])),
        st.just([[0, 1]]),
        anything,
    ),
)
def test_face_mesh_and_vertex_normals(scale, shift, triangles):
    def build():
        with np.errstate(all="ignore"):
            points = np.asarray(np.eye(3), dtype=np.float64) * scale + shift
        return wf.FaceMesh(points, triangles, name="fuzzmesh")

    mesh = outcome(build, "fuzzmesh")
    if mesh is not None:
        normals = mesh.vertex_normals(device=DEVICE)
        finite(normals)
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
        finite(mesh.rest_areas)


@FUZZ
@given(scale=numbers, points=st.one_of(st.just("same"), vectors))
def test_vertex_normals_of_deformed_points(scale, points):
    p, t = grid_surface(4)
    mesh = wf.FaceMesh(p, t, name="grid")
    with np.errstate(all="ignore"):
        values = p * scale if isinstance(points, str) and points == "same" else points
    normals = outcome(lambda: mesh.vertex_normals(values, device=DEVICE), "grid: points")
    if normals is not None:
        finite(normals)


@FUZZ
@given(attachment=vectors, insertion=vectors, zone=numbers, start=numbers, finish=numbers)
def test_linear_muscle(attachment, insertion, zone, start, finish):
    outcome(lambda: wf.LinearMuscle("zyg", attachment, insertion, zone, start, finish), "zyg")


@FUZZ
@given(
    center=vectors,
    ax=vectors,
    ay=vectors,
    semi=st.one_of(st.tuples(numbers, numbers), anything),
    name=st.one_of(st.just("oris"), anything),
)
def test_sphincter_muscle(center, ax, ay, semi, name):
    outcome(lambda: wf.SphincterMuscle(name, center, ax, ay, semi), "sphincter muscle")


@FUZZ
@given(
    origin=vectors,
    u=vectors,
    v=vectors,
    radius=numbers,
    depth=numbers,
    width=numbers,
    kr=numbers,
    control=st.one_of(st.lists(st.tuples(numbers, numbers), min_size=4, max_size=4), anything),
)
def test_projections_and_wrinkle(origin, u, v, radius, depth, width, kr, control):
    planar = outcome(lambda: wf.PlanarProjection(origin, u, v), "planar projection")
    cylinder = outcome(lambda: wf.CylindricalProjection(origin, u, v, radius), "cylindrical projection")
    for projection in (planar, cylinder):
        if projection is not None:
            wrinkle = outcome(lambda p=projection: wf.Wrinkle("brow", control, p, depth, width, kr), "brow")
            uv = wf.expression.project_points(projection, grid_surface(3)[0], device=DEVICE)
            finite(uv)
            if wrinkle is not None:
                assert wrinkle.width > 0 and 0 <= wrinkle.kr <= 1


@FUZZ
@given(
    shape=st.sampled_from([(4, 4), (0, 3), (1, 2, 3), (3, 3, 3), (2,), (1, 1)]),
    fill=numbers,
    blur=numbers,
    black=numbers,
    white=numbers,
    points=st.one_of(st.sampled_from(["grid", "empty", "bad"]), vectors),
)
def test_thickness_map(shape, fill, blur, black, white, points):
    planar = wf.PlanarProjection([0, 0, 0], [1, 0, 0], [0, 1, 0])
    image = np.full(shape, fill, dtype=np.float64) if np.isfinite(fill) else np.full(shape, fill)
    tmap = outcome(lambda: wf.ThicknessMap(image, planar, (-1, 1), (-1, 1), black, white, blur), "thickness map")
    if tmap is None:
        return
    values = (
        {"grid": grid_surface(3)[0], "empty": np.zeros((0, 3)), "bad": np.zeros((1, 2, 3))}.get(points, points)
        if isinstance(points, str)
        else points
    )
    sampled = outcome(lambda: tmap.sample(values, device=DEVICE), "thickness map: points")
    if sampled is not None:
        finite(sampled)


@FUZZ
@given(
    thickness=st.one_of(numbers, anything, st.just(np.full(64, 1e39)), st.just(np.full(64, 0.003))),
    landmarks=st.one_of(
        st.none(), st.just(np.array([0, 63])), st.just(np.array([0, 64])), st.just([[1, 2], [3]]), anything
    ),
    muscles=st.sampled_from(["ok", "dup", "wrong"]),
)
def test_face_rig_and_model_raise_the_same_errors(rig, thickness, landmarks, muscles):
    parts = {"ok": rig.muscles, "dup": rig.muscles + rig.muscles[:1], "wrong": rig.muscles + ["zyg"]}[muscles]
    rig_error = model_error = None
    try:
        wf.FaceRig(rig.mesh, parts, rig.wrinkles, thickness, landmarks=None, name="fz")
    except (ValueError, TypeError) as exc:
        rig_error = exc
    try:
        wf.ExpressionModel(rig.mesh, parts, rig.wrinkles, thickness, device=DEVICE)
    except (ValueError, TypeError) as exc:
        model_error = exc
    assert type(rig_error) is type(model_error), (rig_error, model_error)
    if isinstance(rig_error, TypeError):  # a wrong type is a TypeError naming the item, after the owner's name
        assert rig_error.args[0].split(": ", 1)[1] == model_error.args[0].split(": ", 1)[1]
    elif rig_error is not None:
        assert isinstance(rig_error, RigError)
        assert rig_error.args[0].split(": ", 1)[1] == model_error.args[0].split(": ", 1)[1]
    outcome(lambda: wf.FaceRig(rig.mesh, rig.muscles, rig.wrinkles, 0.003, landmarks=landmarks, name="fz"), "fz")


control_values = st.one_of(numbers, st.sampled_from([None, "1", {}, [], [1.0], True, object()]))
control_names = st.one_of(
    st.sampled_from(["zygomaticus major L", "frontalis_R", "orbicularis_oris", "forehead_1", "crow_L", "nope"]),
    st.integers(),
    st.none(),
)


@FUZZ
@given(
    contractions=st.one_of(
        st.dictionaries(control_names, control_values, max_size=4), st.lists(numbers, min_size=0, max_size=4), anything
    ),
    depths=st.one_of(
        st.none(), st.dictionaries(control_names, control_values, max_size=3), st.lists(numbers, max_size=3)
    ),
)
def test_evaluate(model, contractions, depths):
    points = outcome(
        lambda: model.evaluate(contractions, wrinkle_depths=depths),
        "contraction",
        "controls",
        "wrinkle depth",
        "wrinkle_depths",
    )
    if points is not None:
        assert points.shape[-2:] == (model.mesh.vertex_count, 3) and points.ndim in (2, 3)  # a frame or a batch
        finite(points)
        if points.ndim == 2:
            stages = model.stages(contractions, wrinkle_depths=depths)
            finite(stages.muscle, stages.stretch, stages.bulge, stages.final)


@FUZZ
@given(
    frames=st.integers(0, 3),
    fill=numbers,
    kind=st.sampled_from(["array", "mappings", "ragged", "flat", "bad"]),
    per_launch=st.one_of(st.none(), st.integers(-1, 3), st.sampled_from([1.5, "2", True])),
)
def test_evaluate_batch(model, frames, fill, kind, per_launch):
    width = len(model.muscles)
    values = {
        "array": np.full((frames, width), fill),
        "mappings": [{"frontalis_R": fill}] * frames,
        "ragged": [[fill] * width, [fill]],
        "flat": [fill] * width,
        "bad": "smile",
    }[kind]
    result = outcome(
        lambda: model.evaluate(values, frames_per_launch=per_launch), "contraction", "controls", "frames_per_launch"
    )
    if result is not None:
        assert result.shape == (
            (model.mesh.vertex_count, 3) if kind == "flat" else (frames, model.mesh.vertex_count, 3)
        )
        finite(result)


@FUZZ
@given(
    query=st.one_of(st.lists(st.tuples(numbers, numbers, numbers), min_size=0, max_size=4), anything),
    scale=numbers,
    triangles=st.one_of(
        st.just([[0, 1, 2], [1, 2, 3]]),
        st.just([[0, 1, 9]]),
        st.just([[0, 1, -1]]),
        st.just(np.array([[0, 1, 2.0]])),
        anything,
    ),
)
def test_closest_points(query, scale, triangles):
    with np.errstate(all="ignore"):
        vertices = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.2]]) * scale
    result = outcome(
        lambda: closest_points(query, vertices, triangles, device=DEVICE), "query", "vertices", "triangles"
    )
    if result is not None:
        tri, bary, dist = result
        assert np.all((tri >= 0) & (tri < len(np.asarray(triangles))))
        finite(bary, dist)


# The cases reported in issue 9, each pinned down.
def _tmap(**kwargs):
    args = dict(
        image=np.full((4, 4), 0.5),
        projection=wf.PlanarProjection([0, 0, 0], [1, 0, 0], [0, 1, 0]),
        u_range=(-1, 1),
        v_range=(-1, 1),
    )
    args.update(kwargs)
    return wf.ThicknessMap(**args)


@pytest.mark.parametrize(
    "call, message",
    [
        (
            lambda r, m: wf.FaceMesh(np.eye(3) * 1e20, [[0, 1, 2]]).vertex_normals(device=DEVICE),
            r"points.*outside ±1e\+06",
        ),
        (lambda r, m: wf.FaceMesh(np.eye(3) * 1e-30, [[0, 1, 2]]), "zero-area"),
        (lambda r, m: m.evaluate({"frontalis_R": {}}), "contraction for muscle 'frontalis_R': expected a number"),
        (lambda r, m: m.evaluate({"frontalis_R": 1e39}), r"contraction for muscle 'frontalis_R'.*outside"),
        (
            lambda r, m: m.evaluate({"orbicularis_oris": 2e3}),
            r"contraction for muscle 'orbicularis_oris'.*outside ±1000",
        ),
        (lambda r, m: m.evaluate(wrinkle_depths={"crow_L": 1e39}), r"wrinkle depth for wrinkle 'crow_L'.*outside"),
        (
            lambda r, m: wf.Wrinkle("brow", r.wrinkles[0].control_points, r.wrinkles[0].projection, 1e39, 1.0),
            "wrinkle 'brow': depth",
        ),
        (lambda r, m: wf.ExpressionModel(r.mesh, thickness=1e39, device=DEVICE), "thickness.*above"),
        (lambda r, m: wf.FaceRig(r.mesh, thickness=1e39), "thickness.*above"),
        (lambda r, m: _tmap().sample(np.zeros((1, 2, 3)), device=DEVICE), "thickness map: points"),
        (lambda r, m: _tmap(blur_sigma=1e300), "blur_sigma"),
        (lambda r, m: _tmap(white=1e39), "white"),
        (lambda r, m: closest_points([[1e16, 0, 0]], np.eye(3), [[0, 1, 2]], device=DEVICE), "query"),
    ],
)
def test_issue_9_cases_raise_one_clear_line(rig, model, call, message):
    with pytest.raises((TypeError, ValueError), match=message):
        call(rig, model)


def test_issue_9_empty_thickness_sample_is_empty():
    assert _tmap().sample(np.zeros((0, 3)), device=DEVICE).shape == (0,)


obj_lines = st.one_of(
    st.builds(lambda a, b, c: f"v {a} {b} {c}", numbers, numbers, numbers),
    st.builds(
        lambda a, b, c: f"f {a} {b} {c}",
        *(st.one_of(st.integers(-6, 6), st.sampled_from(["x", "1/2/3", "", "2.5"])),) * 3,
    ),
    st.sampled_from(["v 1 2", "f 1 2", "# comment", "vt 0 0", "", "v nan 0 0", "f 1//1 2//2 3//3"]),
)


@FUZZ
@given(lines=st.lists(obj_lines, max_size=10))
def test_obj_files(tmp_path_factory, lines):
    path = tmp_path_factory.mktemp("obj") / "fuzz.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n" + "\n".join(lines) + "\nf 1 2 3\n")
    mesh = outcome(lambda: wf.FaceMesh.from_obj(path), "fuzz")
    if mesh is not None:
        finite(mesh.vertex_normals(device=DEVICE))
