"""A stream read ahead in a background thread: same items in the same order, errors where they
happened, an early stop closes the upstream in its own thread, and a prefetched capture writes the
same stage as a plain one."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from helpers import DisappearingCamera, grid_surface
from hypothesis import given, settings
from hypothesis import strategies as st

from warpface.pipelines.capture import record
from warpface.tracking import PrefetchedSource, adapter_for_face, prefetch
from warpface.usd.tracking_io import TrackingStageWriter, read_tracking


@settings(max_examples=25, deadline=None)
@given(items=st.lists(st.integers(), max_size=40), depth=st.integers(1, 5))
def test_items_arrive_in_order_and_unchanged(items, depth):
    assert list(prefetch(iter(items), depth=depth)) == items


def test_the_producer_runs_in_another_thread_and_ahead_of_the_consumer():
    produced = []
    started = threading.Event()

    def numbers():
        for i in range(10):
            produced.append((i, threading.get_ident()))
            started.set()
            yield i

    stream = prefetch(numbers(), depth=3)
    assert next(stream) == 0
    started.wait(5)
    for _ in range(100):  # the producer fills the queue: the first four items are made (one handed out + three held)
        if len(produced) >= 4:
            break
        threading.Event().wait(0.01)
    assert len(produced) >= 4 and {ident for _, ident in produced} == {produced[0][1]} != {threading.get_ident()}
    assert list(stream) == list(range(1, 10))


def test_an_error_is_raised_where_it_happened():
    def failing():
        yield 1
        yield 2
        raise ConnectionError("camera gone")

    stream = prefetch(failing())
    assert next(stream) == 1 and next(stream) == 2
    with pytest.raises(ConnectionError, match="camera gone"):
        next(stream)


def test_an_early_stop_closes_the_upstream_in_the_producer_thread():
    closed = []

    def endless():
        try:
            i = 0
            while True:
                yield i
                i += 1
        finally:
            closed.append(threading.get_ident())

    stream = prefetch(endless(), depth=2)
    assert [next(stream) for _ in range(5)] == [0, 1, 2, 3, 4]
    stream.close()
    assert len(closed) == 1 and closed[0] != threading.get_ident()


@pytest.mark.parametrize(
    "depth, error", [(0, ValueError), (-1, ValueError), (1.5, TypeError), (True, TypeError), ("2", TypeError)]
)
def test_a_bad_depth_is_refused(depth, error):
    with pytest.raises(error, match="depth"):
        prefetch([1, 2], depth=depth)
    with pytest.raises(error, match="depth"):
        PrefetchedSource(DisappearingCamera(np.zeros((3, 3)), np.arange(3), 1), depth=depth)


def test_a_source_without_frames_is_refused():
    with pytest.raises(TypeError, match="frames"):
        PrefetchedSource(object())


def test_a_prefetched_capture_writes_the_same_stage(tmp_path):
    rest, triangles = grid_surface(12, seed=1)
    rest = rest * 0.05
    vertices = np.array([13, 17, 20, 50, 55, 60, 90, 95, 100, 130, 133])
    stages = []
    for prefetch_depth in (0, 2):
        source = DisappearingCamera(rest, vertices, 12)
        wrapped = PrefetchedSource(source)
        assert wrapped.landmark_names == source.landmark_names and wrapped.fps == source.fps  # attributes forwarded
        adapter = adapter_for_face(rest, source.landmark_names, camera_to_model=np.eye(4), device="cpu")
        path = tmp_path / f"cap{prefetch_depth}.usda"
        writer = TrackingStageWriter(
            path, source.landmark_names, 30.0, dense_rest=rest, triangles=triangles, chunk_frames=5
        )
        with pytest.raises(ConnectionError):  # the camera disappears after 12 frames: all 12 are kept
            record(source, adapter, writer, progress=False, prefetch=prefetch_depth)
        stages.append(read_tracking(path))
    plain, prefetched = stages
    assert len(prefetched["times"]) == 12
    for key in ("times", "landmarks", "confidence", "dense"):
        np.testing.assert_array_equal(prefetched[key], plain[key])


def test_a_prefetched_capture_stops_after_max_frames(tmp_path):
    rest, triangles = grid_surface(12, seed=1)
    rest = rest * 0.05
    vertices = np.array([13, 17, 20, 50, 55, 60, 90, 95, 100, 130, 133])
    source = DisappearingCamera(rest, vertices, 1000)
    adapter = adapter_for_face(rest, source.landmark_names, camera_to_model=np.eye(4), device="cpu")
    writer = TrackingStageWriter(
        tmp_path / "cap.usda", source.landmark_names, 30.0, dense_rest=rest, triangles=triangles, chunk_frames=5
    )
    stats = record(source, adapter, writer, progress=False, prefetch=3, max_frames=8)
    assert stats.frames == 8 and len(read_tracking(tmp_path / "cap.usda")["times"]) == 8
    with pytest.raises(ValueError, match="prefetch"):
        record(source, adapter, writer, progress=False, prefetch=-1)


def test_the_synthetic_rgbd_capture_prefetched_matches_the_plain_one(tmp_path):
    """The real source side in the background thread: rendering (pyrender), dot detection (OpenCV)
    and back-projection (Warp kernel); the stage must be bitwise the same as without prefetching."""
    pytest.importorskip("pyrender")
    pytest.importorskip("cv2")
    from warpface.pipelines.capture import synthetic_capture

    stages = []
    for prefetch_depth in (0, 2):
        capture = synthetic_capture(seconds=0.2, device="cpu")
        rest = capture.truth[0]
        adapter = adapter_for_face(rest, capture.source.landmark_names, device="cpu")
        path = tmp_path / f"cap{prefetch_depth}.usda"
        writer = TrackingStageWriter(
            path, capture.source.landmark_names, 30.0, dense_rest=rest, triangles=capture.triangles
        )
        try:
            stats = record(capture.source, adapter, writer, progress=False, prefetch=prefetch_depth)
        finally:
            capture.camera.close()
        assert stats.frames == len(capture.truth)  # every frame of the expression
        stages.append(read_tracking(path))
    for key in ("times", "landmarks", "confidence", "dense"):
        np.testing.assert_array_equal(stages[1][key], stages[0][key])
