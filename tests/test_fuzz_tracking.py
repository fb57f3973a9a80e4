"""Property-based tests of the tracking public API: random valid, boundary and invalid inputs.

Every call either returns a finite result with valid indices, or raises ValueError / TypeError /
:class:`warpface.RigError` with a one-line message naming the item — never another exception, a
crash, NaN/inf or an index out of range.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import grid_surface
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from warpface.errors import RigError
from warpface.tracking import (
    KINECT_V1_INTRINSICS,
    CameraIntrinsics,
    Correspondence,
    DotTracker,
    FaceNormalization,
    LandmarkFrame,
    RecordedLandmarks,
    TrackingAdapter,
    backproject,
    compute_correspondence,
    landmark_vertices,
    vertex_landmark_names,
)
from warpface.tracking.alignment import rigid_fit, similarity_fit
from warpface.tracking.correspondence import triangulate_landmarks
from warpface.tracking.detect import detect_blobs
from warpface.tracking.streams import checked_frames, fill_missing
from warpface.tracking.transfer import blend_weights, transfer_displacements

FUZZ = settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow]
)
ALLOWED = (ValueError, TypeError, RigError)

special_floats = st.sampled_from(
    [
        0.0,
        -0.0,
        1.0,
        -1.0,
        0.5,
        3.0,
        1e-300,
        -1e-300,
        1e38,
        1e39,
        1e300,
        -1e300,
        float("nan"),
        float("inf"),
        float("-inf"),
    ]
)
numbers = st.one_of(
    special_floats, st.floats(allow_nan=True, allow_infinity=True), st.integers(min_value=-(2**70), max_value=2**70)
)
scalars = st.one_of(numbers, st.booleans(), st.none(), st.just("text"), st.just([1.0, 2.0]), st.just({}))


def arrays_of(shape_options, elements=numbers):
    """Lists with a shape from ``shape_options`` (sometimes ragged or of strings)."""

    @st.composite
    def build(draw):
        shape = draw(st.sampled_from(shape_options))
        size = int(np.prod(shape)) if shape else 1
        values = draw(st.lists(elements, min_size=size, max_size=size))
        if draw(st.integers(0, 9)) == 0:
            return [[1.0, 2.0], [3.0]]  # ragged
        return np.array(values, dtype=object).reshape(shape).tolist() if shape else values[0]

    return build()


def check_error(error: Exception, *names: str) -> None:
    """One line, naming one of ``names``."""
    message = str(error)
    assert isinstance(error, ALLOWED), f"{type(error).__name__}: {message}"
    assert "\n" not in message.strip(), message
    assert any(name in message for name in names), f"message does not name {names}: {message}"


def assert_finite(*arrays) -> None:
    for array in arrays:
        array = np.asarray(array)
        if np.issubdtype(array.dtype, np.floating):
            assert np.all(np.isfinite(array)), "non-finite result"


@pytest.fixture(scope="module")
def sparse_setup():
    rest, triangles = grid_surface(6, seed=2)
    sparse = rest[[0, 5, 14, 21, 30, 35]]
    sparse_triangles = triangulate_landmarks(sparse)
    dense, dense_triangles = grid_surface(10, seed=3)
    corr = compute_correspondence(dense, sparse, sparse_triangles, device="cpu")
    return sparse, sparse_triangles, dense, corr


@FUZZ
@given(
    kind=st.sampled_from(["int", "float", "shape", "object"]),
    where=st.integers(0, 99),
    special=special_floats,
    values=st.lists(st.one_of(st.integers(-3, 40), st.integers(-(2**40), 2**40)), min_size=100, max_size=100),
)
def test_transfer_displacements_with_bad_correspondence_indices(sparse_setup, kind, where, special, values):
    sparse, sparse_triangles, dense, corr = sparse_setup
    triangle = np.array(values, dtype=np.int64)
    if kind == "float":
        triangle = triangle.astype(np.float64)
        triangle[where] = special
    elif kind == "shape":
        triangle = triangle.reshape(10, 10)
    elif kind == "object":
        triangle = triangle.astype(str)
    try:
        bad = Correspondence(triangle, corr.barycentric, corr.distance, corr.overhang)
        result = transfer_displacements(np.ones((len(sparse), 3)) * 1e-3, sparse_triangles, bad, device="cpu")
    except ALLOWED as error:
        check_error(error, "correspondence")
        return
    assert result.shape == (len(dense), 3)
    assert_finite(result)


@FUZZ
@given(displacement=st.one_of(special_floats, st.floats(-1e40, 1e40)), weight=numbers, scale=numbers)
def test_transfer_displacements_scalars(sparse_setup, displacement, weight, scale):
    sparse, sparse_triangles, dense, corr = sparse_setup
    try:
        result = transfer_displacements(
            np.full((len(sparse), 3), displacement),
            sparse_triangles,
            corr,
            np.full(len(dense), weight, dtype=object),
            scale=scale,
            device="cpu",
        )
    except ALLOWED as error:
        check_error(error, "sparse_displacement", "weights", "scale", "transfer_displacements")
        return
    assert_finite(result)


@FUZZ
@given(
    points=st.one_of(
        arrays_of([(3, 3), (4, 3), (6, 3), (2, 3), (5, 2)], st.one_of(special_floats, st.integers(-3, 3))),
        st.lists(st.tuples(st.integers(-3, 3), st.just(0), st.integers(-3, 3)), min_size=3, max_size=8),  # x-z plane
        st.lists(st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)), min_size=3, max_size=12),
    ),
    max_edge=st.one_of(st.none(), numbers),
)
def test_triangulate_landmarks(points, max_edge):
    try:
        triangles = triangulate_landmarks(points, max_edge=max_edge)
    except ALLOWED as error:
        check_error(error, "points", "max_edge", "triangulate_landmarks")
        return
    count = len(np.asarray(points))
    assert triangles.dtype == np.int32 and triangles.ndim == 2 and triangles.shape[1] == 3
    assert triangles.min() >= 0 and triangles.max() < count


@FUZZ
@given(
    key=st.sampled_from(
        ["window", "min_valid", "outlier_floor", "max_slope", "noise_floor", "iterations", "min_inlier_fraction"]
    ),
    value=scalars,
    pixels=arrays_of([(2, 2), (1, 2), (0, 2), (2, 3)], st.one_of(special_floats, st.floats(-10, 700))),
)
def test_backproject(key, value, pixels):
    depth = np.full((KINECT_V1_INTRINSICS.height, KINECT_V1_INTRINSICS.width), 0.6, dtype=np.float32)
    try:
        points, inliers = backproject(pixels, depth, KINECT_V1_INTRINSICS, device="cpu", **{key: value})
    except ALLOWED as error:
        check_error(error, key, "pixels")
        return
    valid = inliers > 0
    assert np.all(np.isfinite(points[valid])) and np.all(np.isnan(points[~valid]))


@FUZZ
@given(depth_value=st.one_of(special_floats, st.floats(-1, 1e40)))
def test_backproject_depth_values(depth_value):
    depth = np.full((48, 64), depth_value)
    intrinsics = CameraIntrinsics(50.0, 50.0, 31.5, 23.5, 64, 48)
    points, inliers = backproject([[30.0, 20.0]], depth, intrinsics, device="cpu")
    assert np.all(np.isfinite(points[inliers > 0]))


@FUZZ
@given(key=st.sampled_from(["fx", "fy", "cx", "cy", "width", "height"]), value=scalars)
def test_camera_intrinsics_from_dict(key, value):
    data = KINECT_V1_INTRINSICS.to_dict() | {key: value}
    try:
        intrinsics = CameraIntrinsics.from_dict(data)
    except ALLOWED as error:
        check_error(error, key)
        return
    assert intrinsics.width >= 1 and intrinsics.height >= 1
    assert_finite(intrinsics.matrix)


@FUZZ
@given(
    key=st.sampled_from(
        [
            "threshold",
            "min_area",
            "max_area",
            "min_axis_ratio",
            "max_diameter",
            "gate_px",
            "outlier_px",
            "neighbours",
            "velocity_damping",
            "area_change",
            "color",
            "names",
        ]
    ),
    value=scalars,
)
def test_dot_tracker_options(key, value):
    image = np.full((60, 80, 3), 200, dtype=np.uint8)
    image[28:33, 38:43] = 20
    try:
        tracker = DotTracker([[40.0, 30.0], [10.0, 10.0]], **{key: value})
        pixels, confidence = tracker.detect(image)
    except ALLOWED as error:
        check_error(error, key)
        return
    found = confidence > 0
    assert np.all(np.isfinite(pixels[found])) and np.all(np.isfinite(confidence))


@FUZZ
@given(
    key=st.sampled_from(["threshold", "min_area", "max_area", "min_axis_ratio", "max_diameter", "color"]), value=scalars
)
def test_detect_blobs_options(key, value):
    image = np.full((40, 40, 3), 220, dtype=np.uint8)
    image[18:23, 18:23] = 10
    try:
        blobs = detect_blobs(image, **{key: value})
    except ALLOWED as error:
        check_error(error, key)
        return
    assert_finite(blobs.centers, blobs.contrast, blobs.axis_ratio)


@FUZZ
@given(detections=arrays_of([(2, 2), (3, 2), (1, 3), (0, 2)], st.one_of(special_floats, st.floats(-50, 100))))
def test_dot_tracker_update(detections):
    tracker = DotTracker([[40.0, 30.0], [10.0, 10.0], [60.0, 50.0]])
    try:
        pixels, confidence = tracker.update(detections)
    except ALLOWED as error:
        check_error(error, "detections")
        return
    assert np.all(np.isfinite(pixels[confidence > 0]))
    assert np.all(np.isfinite(tracker.position))


@FUZZ
@given(
    key=st.sampled_from(["timestamps", "points", "confidence", "names", "fps"]),
    value=st.one_of(
        st.just(np.float64(1.0)),
        st.just(np.zeros((2, 2, 2))),
        st.just(np.array(["a", "b"])),
        st.just(np.array([np.nan, 1.0])),
        st.just(np.array([1e300, -1e300])),
        st.just(np.zeros(0)),
        st.just(np.array([[1, 2]])),
        st.just(np.array([True, False])),
    ),
)
def test_recorded_landmarks_with_bad_arrays(tmp_path_factory, key, value):
    arrays = {
        "timestamps": np.array([0.0, 0.1]),
        "points": np.zeros((2, 2, 3)),
        "confidence": np.ones((2, 2)),
        "names": np.array(["a", "b"]),
        "fps": np.float64(10.0),
    }
    arrays[key] = value
    path = tmp_path_factory.mktemp("npz") / "rec.npz"
    np.savez(path, **arrays)
    try:
        recording = RecordedLandmarks(path)
        frames = list(recording.frames())
    except ALLOWED as error:
        check_error(error, str(path))
        return
    for frame in frames:
        assert np.all(np.isfinite(frame.points[~frame.missing])) and np.all(np.isfinite(frame.confidence))
    assert recording.fps is None or np.isfinite(recording.fps)


@FUZZ
@given(
    timestamp=scalars, points=arrays_of([(2, 3), (1, 3), (2, 2)]), confidence=arrays_of([(2,), (1,), ()]), index=scalars
)
def test_landmark_frame(timestamp, points, confidence, index):
    try:
        frame = LandmarkFrame(timestamp, points, confidence, index)
    except ALLOWED as error:
        check_error(error, "frame")
        return
    assert np.all(np.isfinite(frame.points[~frame.missing]))
    assert np.all((frame.confidence >= 0) & (frame.confidence <= 1))


@FUZZ
@given(
    source=arrays_of([(4, 3), (3, 3), (2, 3), (4, 2)], st.one_of(special_floats, st.floats(-2, 2))),
    weights=st.one_of(st.none(), arrays_of([(4,), (3,)])),
)
def test_alignment(source, weights):
    target = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    for fit in (similarity_fit, rigid_fit):
        try:
            result = fit(source, target[: len(np.asarray(source, dtype=object))], weights)
        except ALLOWED as error:
            check_error(error, "source", "target", "weights")
            continue
        assert_finite(*[np.asarray(r, dtype=np.float64) for r in result])


@FUZZ
@given(
    key=st.sampled_from(["region_falloff", "cover_falloff", "region"]),
    value=st.one_of(
        scalars, st.just((0.0, 0.0)), st.just((1e300, 1e301)), st.just([-1, 3]), st.just([0.5]), st.just([])
    ),
)
def test_blend_weights_options(sparse_setup, key, value):
    sparse, sparse_triangles, dense, corr = sparse_setup
    try:
        weights = blend_weights(dense, corr, device="cpu", **{key: value})
    except ALLOWED as error:
        check_error(error, key)
        return
    assert weights.shape == (len(dense),) and np.all((weights >= 0) & (weights <= 1))


@FUZZ
@given(
    key=st.sampled_from(["min_confidence", "camera_to_model", "stabilize", "landmark_names", "cover_falloff"]),
    value=st.one_of(
        scalars,
        st.just(np.full((4, 4), np.inf)),
        st.just([0.5, 1.5, 2.5]),
        st.just([0, 1, 99]),
        st.just(["a"] * 6),
        st.just(np.eye(4)),
    ),
)
def test_tracking_adapter_options(sparse_setup, key, value):
    sparse, sparse_triangles, dense, _ = sparse_setup
    try:
        adapter = TrackingAdapter(sparse, sparse_triangles, dense, device="cpu", **{key: value})
        adapter.bind([str(i) for i in range(len(sparse))] if adapter.landmark_names is None else adapter.landmark_names)
        points = adapter.track_frame(LandmarkFrame(0.0, sparse, np.ones(len(sparse)), 0))
    except ALLOWED as error:
        check_error(error, key)
        return
    assert_finite(points)


@FUZZ
@given(offset=st.one_of(special_floats, st.floats(-1e7, 1e7)))
def test_tracking_adapter_frames(sparse_setup, offset):
    sparse, sparse_triangles, dense, _ = sparse_setup
    adapter = TrackingAdapter(sparse, sparse_triangles, dense, camera_to_model=np.eye(4), device="cpu")
    adapter.track_frame(LandmarkFrame(0.0, sparse, np.ones(len(sparse)), 0))
    try:
        points = adapter.track_frame(LandmarkFrame(1.0, sparse + offset, np.ones(len(sparse)), 1))
    except ALLOWED as error:
        check_error(error, "frame")
        return
    assert_finite(points)


@FUZZ
@given(key=st.sampled_from(["landmark_count", "timestamp_policy", "max_lookahead", "mode"]), value=scalars)
def test_stream_options(key, value):
    frames = [LandmarkFrame(t, np.zeros((2, 3)), np.ones(2), i) for i, t in enumerate([0.0, 0.1, 0.1, 0.2])]
    try:
        if key in ("landmark_count", "timestamp_policy"):
            out = list(checked_frames(frames, **{key: value}))
        else:
            out = list(fill_missing(frames, **{key: value}))
    except ALLOWED as error:
        check_error(error, key, "timestamp", "frame")
        return
    assert all(np.all(np.isfinite(f.points)) for f in out)


@FUZZ
@given(vertices=arrays_of([(2,), (0,), ()], st.one_of(special_floats, st.integers(-3, 10**12))))
def test_vertex_landmark_names_round_trip(vertices):
    try:
        names = vertex_landmark_names(vertices)
        indices = landmark_vertices(names, 10**13)
    except ALLOWED as error:
        check_error(error, "vertices", "landmark")
        return
    np.testing.assert_array_equal(indices, np.asarray(vertices).ravel())


@FUZZ
@given(eye_y=scalars, front_z=st.one_of(st.none(), scalars))
def test_face_normalization(eye_y, front_z):
    points = np.array([[0.0, 0, 0], [1, 1, 0.2], [0.5, 2, 0.1]])
    try:
        norm = FaceNormalization.measure(points, eye_y, front_z=front_z)
        normalized = norm.normalize(points)
    except ALLOWED as error:
        check_error(error, "eye_y", "front_z")
        return
    assert_finite(normalized)


def test_the_reported_crashes_are_clear_errors(sparse_setup, tmp_path):
    """Each input of the new-user trial (issue 9) that crashed now names what is wrong."""
    sparse, sparse_triangles, dense, corr = sparse_setup
    displacement = np.zeros((len(sparse), 3))
    for triangle, name in (
        ([-1], "correspondence.triangle"),
        ([2**40], "correspondence.triangle"),
        ([np.nan], "correspondence.triangle"),
        ([len(sparse_triangles)], "correspondence.triangle"),
    ):
        with pytest.raises(ValueError, match=name):
            transfer_displacements(
                displacement,
                sparse_triangles,
                Correspondence(np.array(triangle * len(dense)), corr.barycentric, corr.distance, corr.overhang),
                device="cpu",
            )
    with pytest.raises(ValueError, match="collinear"):
        triangulate_landmarks([[0, 0, 0], [1, 0, 5], [2, 0, 1], [3, 0, 2]])  # coplanar (x-z plane)
    with pytest.raises(ValueError, match="collinear"):
        triangulate_landmarks([[0, 0, 0], [1, 1, 1], [2, 2, 2]])
    depth = np.full((KINECT_V1_INTRINSICS.height, KINECT_V1_INTRINSICS.width), 0.6)
    with pytest.raises(TypeError, match="window"):
        backproject([[320.0, 240.0]], depth, KINECT_V1_INTRINSICS, window=float("nan"), device="cpu")
    np.savez(
        tmp_path / "rec.npz",
        timestamps=np.float64(0.0),
        points=np.zeros((1, 2, 3)),
        confidence=np.ones((1, 2)),
        names=np.array(["a", "b"]),
    )
    with pytest.raises(ValueError, match="timestamps"):
        RecordedLandmarks(tmp_path / "rec.npz")
    with pytest.raises(ValueError, match="width"):
        CameraIntrinsics.from_dict(KINECT_V1_INTRINSICS.to_dict() | {"width": float("inf")})
    with pytest.raises(TypeError, match="neighbours"):
        DotTracker([[1.0, 1.0]], neighbours=float("inf"))
    with pytest.raises(ValueError, match="max_diameter"):
        DotTracker([[1.0, 1.0]], max_diameter=int(1e9))


@FUZZ
@given(
    timestamp=scalars,
    landmarks=arrays_of([(2, 3), (3, 3)]),
    confidence=arrays_of([(2,), (3,)]),
    dense_value=st.one_of(special_floats, st.floats(-1e40, 1e40)),
)
def test_tracking_stage_writer_frames(tmp_path_factory, timestamp, landmarks, confidence, dense_value):
    from warpface.usd.tracking_io import TrackingStageWriter, read_tracking

    rest, triangles = grid_surface(3)
    path = tmp_path_factory.mktemp("cap") / "cap.usda"
    with TrackingStageWriter(path, ["a", "b"], 30.0, dense_rest=rest, triangles=triangles) as writer:
        try:
            writer.add(timestamp, landmarks, confidence, np.full(rest.shape, dense_value))
        except ALLOWED as error:
            check_error(error, "frame at t=")
            return
    back = read_tracking(path)
    assert len(back["times"]) == 1
    assert_finite(back["landmarks"], back["confidence"], back["dense"])
