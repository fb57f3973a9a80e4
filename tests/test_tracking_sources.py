"""Landmark and RGB-D sources: exact round trips, timestamp policy, missing-landmark filling,
MediaPipe reader on real detector output, live cameras against fake SDK devices."""

import json
import re
import sys
import types

import numpy as np
import pytest

from warpface.data import shared_data_path
from warpface.tracking import (
    CameraDisconnected,
    CameraIntrinsics,
    CameraUnavailable,
    LandmarkFrame,
    MediaPipeLandmarks,
    OrbbecCamera,
    RealSenseCamera,
    RecordedLandmarks,
    RGBDFolder,
    RGBDFrame,
)
from warpface.tracking.alignment import similarity_fit
from warpface.tracking.mediapipe import parse_landmark_list
from warpface.tracking.streams import checked_frames, fill_missing


def make_frames(count=5, n=4, seed=0):
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(count):
        pts = rng.normal(size=(n, 3))
        conf = rng.uniform(0.2, 1.0, n)
        if i == 2:
            pts[1] = np.nan
        frames.append(LandmarkFrame(0.1 + i / 30.0, pts, conf, i))
    return frames


def test_landmark_frame_marks_nan_rows_missing():
    f = LandmarkFrame(0.0, [[0, 0, 1], [np.nan, 0, 1]], [0.9, 0.8], 0)
    assert f.points.dtype == np.float64 and f.confidence.dtype == np.float32
    assert f.missing.tolist() == [False, True] and f.confidence[1] == 0.0
    with pytest.raises(ValueError, match="confidences"):
        LandmarkFrame(0.0, np.zeros((2, 3)), [1.0], 3)
    with pytest.raises(ValueError, match="timestamp"):
        LandmarkFrame(float("nan"), np.zeros((2, 3)), [1.0, 1.0], 3)


def test_recorded_landmarks_round_trip_is_exact(tmp_path):
    frames = make_frames()
    names = ["a", "b", "c", "d"]
    path = RecordedLandmarks.write(tmp_path / "rec.npz", frames, names, fps=30.0)
    with RecordedLandmarks(path) as src:
        assert src.landmark_names == tuple(names) and src.fps == 30.0 and len(src) == 5
        back = list(src.frames())
    for a, b in zip(frames, back):
        assert a.timestamp == b.timestamp and a.index == b.index
        np.testing.assert_array_equal(a.points, b.points)  # NaN rows included
        np.testing.assert_array_equal(a.confidence, b.confidence)


def test_recorded_write_keeps_frames_received_before_a_failure(tmp_path):
    frames = make_frames()

    def dying_camera():
        yield from frames[:3]
        raise RuntimeError("unplugged")

    with pytest.raises(RuntimeError, match="unplugged"):
        RecordedLandmarks.write(tmp_path / "cut.npz", dying_camera(), ["a", "b", "c", "d"])
    back = list(RecordedLandmarks(tmp_path / "cut.npz").frames())
    assert [f.index for f in back] == [0, 1, 2]


def test_timestamp_policy_and_landmark_count(tmp_path):
    frames = make_frames()
    dup = frames[:3] + [LandmarkFrame(frames[2].timestamp, frames[3].points, frames[3].confidence, 3)]
    with pytest.raises(ValueError, match="duplicate timestamp at frame 3"):
        list(checked_frames(dup))
    back = frames[:3] + [LandmarkFrame(0.0, frames[3].points, frames[3].confidence, 3), frames[4]]
    with pytest.raises(ValueError, match="decreasing timestamp at frame 3"):
        list(checked_frames(back))
    assert [f.index for f in checked_frames(back, timestamp_policy="drop")] == [0, 1, 2, 4]
    grown = frames[:2] + [LandmarkFrame(1.0, np.zeros((5, 3)), np.ones(5), 2)]
    with pytest.raises(ValueError, match="frame 2 has landmark count \\(5,\\), but the stream started with \\(4,\\)"):
        list(checked_frames(grown))
    with pytest.raises(ValueError, match="timestamp_policy"):
        list(checked_frames(frames, timestamp_policy="sort"))
    # A file that goes back in time is rejected on read.
    np.savez(
        tmp_path / "bad.npz",
        timestamps=np.array([0.0, 0.1, 0.05]),
        points=np.zeros((3, 2, 3)),
        confidence=np.ones((3, 2), np.float32),
        names=np.array(["a", "b"]),
    )
    with pytest.raises(ValueError, match="decreasing timestamp at frame 2"):
        list(RecordedLandmarks(tmp_path / "bad.npz").frames())
    np.savez(tmp_path / "noname.npz", timestamps=np.zeros(1), points=np.zeros((1, 2, 3)), confidence=np.ones((1, 2)))
    with pytest.raises(ValueError, match="missing array 'names'"):
        RecordedLandmarks(tmp_path / "noname.npz")


def linear_track(count=8, n=3):
    t = np.arange(count) / 10.0
    base = np.arange(n * 3, dtype=float).reshape(n, 3)
    vel = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, -1.0]])[:n]
    return t, base, vel


def test_fill_missing_interpolates_and_holds():
    t, base, vel = linear_track()
    gaps = {(0, 1), (3, 0), (4, 0), (5, 2), (7, 2)}  # landmark 1 missing at the start, 2 at the end
    frames = []
    for i, ti in enumerate(t):
        pts = base + vel * ti
        conf = np.ones(3)
        for fi, j in gaps:
            if fi == i:
                pts[j] = np.nan
        frames.append(LandmarkFrame(ti, pts, conf, i))
    interp = list(fill_missing(frames, mode="interpolate"))
    held = list(fill_missing(frames, mode="hold"))
    assert [f.index for f in interp] == list(range(8)) == [f.index for f in held]
    for f in interp + held:
        assert np.all(np.isfinite(f.points))
    truth = [base + vel * ti for ti in t]
    # Interior gap (landmark 0, frames 3–4): exactly on the straight line.
    np.testing.assert_allclose(interp[3].points[0], truth[3][0], atol=1e-12)
    np.testing.assert_allclose(interp[4].points[0], truth[4][0], atol=1e-12)
    np.testing.assert_allclose(interp[5].points[2], truth[5][2], atol=1e-12)
    # Hold repeats the last measurement.
    np.testing.assert_allclose(held[4].points[0], truth[2][0])
    # Leading gap: the first measurement; trailing gap: the last one.
    np.testing.assert_allclose(interp[0].points[1], truth[1][1])
    np.testing.assert_allclose(held[0].points[1], truth[1][1])
    np.testing.assert_allclose(interp[7].points[2], truth[6][2])
    # Filled landmarks keep confidence 0, measured ones keep theirs.
    assert interp[3].confidence[0] == 0.0 and interp[3].confidence[1] == 1.0
    never = [LandmarkFrame(i, [[0, 0, 0], [np.nan] * 3], [1, 0], i) for i in range(3)]
    with pytest.raises(ValueError, match="landmark 1 was never measured"):
        list(fill_missing(never))


def rgbd_frames(count=3, size=(48, 64), seed=1):
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(count):
        color = rng.integers(0, 256, size=size + (3,), dtype=np.uint8)
        depth = rng.integers(0, 65536, size=size, dtype=np.uint16)
        depth[::7, ::5] = 0
        frames.append(RGBDFrame(i * 0.04, color, depth, 1e-4, i))
    return frames


def test_rgbd_folder_round_trip_is_exact(tmp_path):
    intr = CameraIntrinsics(60.0, 61.0, 31.5, 23.5, 64, 48)
    frames = rgbd_frames()
    RGBDFolder.write(tmp_path / "rec", frames, intr, fps=25.0, fiducials={"names": ["x"]})
    with RGBDFolder(tmp_path / "rec") as folder:
        assert folder.intrinsics == intr and folder.depth_scale == 1e-4 and folder.fps == 25.0
        assert folder.fiducials == {"names": ["x"]}
        back = list(folder.frames())
    assert len(back) == 3
    for a, b in zip(frames, back):
        assert a.timestamp == b.timestamp
        np.testing.assert_array_equal(a.color, b.color)
        np.testing.assert_array_equal(a.depth, b.depth)
        assert b.depth.dtype == np.uint16


def test_rgbd_folder_bad_input(tmp_path):
    intr = CameraIntrinsics(60.0, 61.0, 31.5, 23.5, 64, 48)
    RGBDFolder.write(tmp_path / "rec", rgbd_frames(2), intr)
    meta = json.loads((tmp_path / "rec" / "meta.json").read_text())
    del meta["intrinsics"]
    (tmp_path / "rec" / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="intrinsics missing"):
        RGBDFolder(tmp_path / "rec")
    meta["intrinsics"] = {"fx": 60.0, "fy": 61.0, "cx": 31.5, "width": 64, "height": 48}
    (tmp_path / "rec" / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="missing cy"):
        RGBDFolder(tmp_path / "rec")
    meta["intrinsics"]["cy"] = 23.5
    (tmp_path / "rec" / "meta.json").write_text(json.dumps(meta))
    (tmp_path / "rec" / "depth" / "000001.png").unlink()
    with pytest.raises(ValueError, match="000001.png: missing or unreadable"):
        list(RGBDFolder(tmp_path / "rec").frames())
    with pytest.raises(ValueError, match="no meta.json"):
        RGBDFolder(tmp_path)
    wrong = CameraIntrinsics(60.0, 61.0, 31.5, 23.5, 32, 48)
    with pytest.raises(ValueError, match="intrinsics say 32×48"):
        RGBDFolder.write(tmp_path / "other", rgbd_frames(1), wrong)


# ------------------------------------------------------------------------------------------------
# MediaPipe
# ------------------------------------------------------------------------------------------------


def mediapipe_file(name):
    path = shared_data_path("mediapipe", name)
    if path is None:
        pytest.skip("shared data mediapipe/ not available")
    return path


def test_mediapipe_reconstruction_agrees_with_mediapipe_geometry():
    landmarks = mediapipe_file("face_blendshapes_in_landmarks.prototxt")
    source = MediaPipeLandmarks(landmarks)
    assert len(source.landmark_names) == 478
    frame = next(source.frames())
    assert frame.points.shape == (478, 3) and np.all(np.isfinite(frame.points))
    # MediaPipe's own metric face geometry for the same portrait: mesh in canonical space + pose.
    text = mediapipe_file("portrait_expected_face_geometry.pbtxt").read_text()
    mesh = np.array([float(v) for v in re.findall(r"vertex_buffer:\s*(\S+)", text)]).reshape(-1, 5)[:, :3]
    pose = np.array([float(v) for v in re.findall(r"packed_data:\s*(\S+)", text)]).reshape(4, 4).T  # column-major
    gl = (np.c_[mesh, np.ones(len(mesh))] @ pose.T)[:, :3] * 0.01  # cm → m, OpenGL camera axes
    expected = gl * np.array([1.0, -1.0, -1.0])  # → OpenCV camera axes
    scale, _, _, rms = similarity_fit(frame.points[:468], expected)
    assert rms < 0.005  # shape within 5 mm RMS
    assert abs(scale - 1.0) < 0.1  # metric size within 10 %
    assert np.linalg.norm(frame.points[:468].mean(0) - expected.mean(0)) < 0.06  # placed within 6 cm


def test_mediapipe_reader_bad_input(tmp_path):
    xy_only = mediapipe_file("portrait_expected_face_landmarks.pbtxt")
    assert parse_landmark_list(xy_only.read_text()).shape == (478, 3)
    with pytest.raises(ValueError, match="has no z"):
        MediaPipeLandmarks(xy_only)
    (tmp_path / "few.pbtxt").write_text("landmark { x: 0.5 y: 0.5 z: 0.0 }\n" * 10)
    with pytest.raises(ValueError, match="478 vertices, but the landmark files have 10"):
        MediaPipeLandmarks(tmp_path / "few.pbtxt", model_path=mediapipe_file("face_model_with_iris.obj"))
    (tmp_path / "none.pbtxt").write_text("nothing here")
    with pytest.raises(ValueError, match="no 'landmark"):
        MediaPipeLandmarks(tmp_path / "none.pbtxt")


# ------------------------------------------------------------------------------------------------
# Live cameras, against fake SDK modules that follow the real APIs
# ------------------------------------------------------------------------------------------------


class FakeRealSense:
    """Just enough of pyrealsense2: context, pipeline/config/profile, align, frames."""

    def __init__(self, frames, devices=1, fail_after=None):
        mod = types.ModuleType("pyrealsense2")
        mod.stream = types.SimpleNamespace(depth="depth", color="color")
        mod.format = types.SimpleNamespace(z16="z16", rgb8="rgb8")
        mod.camera_info = types.SimpleNamespace(serial_number="serial")
        self.started = self.stopped = 0
        outer = self

        class Device:
            def get_info(self, what):
                return "1234"

            def first_depth_sensor(self):
                return types.SimpleNamespace(get_depth_scale=lambda: 0.001)

        class Context:
            def query_devices(self):
                return [Device() for _ in range(devices)]

        class Config:
            def __init__(self):
                self.streams = []

            def enable_stream(self, *args):
                self.streams.append(args)

            def enable_device(self, serial):
                pass

        class Profile:
            def get_device(self):
                return Device()

            def get_stream(self, kind):
                intr = types.SimpleNamespace(fx=600.0, fy=601.0, ppx=320.2, ppy=239.7, width=640, height=480)
                return types.SimpleNamespace(
                    as_video_stream_profile=lambda: types.SimpleNamespace(get_intrinsics=lambda: intr)
                )

        class Frame:
            def __init__(self, data):
                self.data = data

            def get_data(self):
                return self.data

            def __bool__(self):
                return True

        class FrameSet:
            def __init__(self, stamp, color, depth):
                self.stamp, self.color, self.depth = stamp, color, depth

            def get_timestamp(self):
                return self.stamp

            def get_depth_frame(self):
                return Frame(self.depth)

            def get_color_frame(self):
                return Frame(self.color)

        class Pipeline:
            def __init__(self):
                self.k = 0

            def start(self, config):
                outer.started += 1
                outer.config = config
                return Profile()

            def wait_for_frames(self, timeout_ms):
                if fail_after is not None and self.k >= fail_after or self.k >= len(frames):
                    raise RuntimeError("Frame didn't arrive within 5000")
                stamp, color, depth = frames[self.k]
                self.k += 1
                return FrameSet(stamp, color, depth)

            def stop(self):
                outer.stopped += 1

        class Align:
            def __init__(self, to):
                assert to == "color"

            def process(self, frameset):
                return frameset

        mod.context, mod.pipeline, mod.config, mod.align = Context, Pipeline, Config, Align
        self.module = mod


def camera_frames(stamps_ms, h=480, w=640):
    rng = np.random.default_rng(0)
    return [
        (s, rng.integers(0, 256, (h, w, 3), dtype=np.uint8), rng.integers(0, 4000, (h, w), dtype=np.uint16))
        for s in stamps_ms
    ]


def test_realsense_camera_with_fake_device(monkeypatch):
    data = camera_frames([1000.0, 1033.3, 1033.3, 1066.7])  # one duplicate delivery
    fake = FakeRealSense(data, fail_after=4)
    monkeypatch.setitem(sys.modules, "pyrealsense2", fake.module)
    received = []
    with RealSenseCamera(width=640, height=480, fps=30) as cam:
        assert cam.intrinsics == CameraIntrinsics(600.0, 601.0, 320.2, 239.7, 640, 480)
        assert cam.depth_scale == 0.001
        assert ("depth", 640, 480, "z16", 30) in fake.config.streams
        with pytest.raises(CameraDisconnected, match="after 3 frames"):
            for frame in cam.frames():
                received.append(frame)
    assert fake.stopped == 1
    np.testing.assert_allclose([f.timestamp for f in received], [1.0, 1.0333, 1.0667], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(received[2].depth, data[3][2])
    np.testing.assert_array_equal(received[0].color, data[0][1])
    assert cam.dropped_frames == 1


def test_realsense_camera_missing_sdk_or_device(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # import fails
    with pytest.raises(CameraUnavailable, match=r"pip install 'warpface\[realsense\]'"):
        RealSenseCamera()
    monkeypatch.setitem(sys.modules, "pyrealsense2", FakeRealSense([], devices=0).module)
    with pytest.raises(CameraUnavailable, match="no RealSense device attached"):
        RealSenseCamera()


class FakeOrbbec:
    """Just enough of pyorbbecsdk (v2): Context, Pipeline, Config, profiles, AlignFilter, frames."""

    def __init__(self, frames, devices=1, empty_after=None):
        mod = types.ModuleType("pyorbbecsdk")
        mod.OBSensorType = types.SimpleNamespace(DEPTH_SENSOR="depth", COLOR_SENSOR="color")
        mod.OBFormat = types.SimpleNamespace(Y16="Y16", RGB="RGB")
        mod.OBStreamType = types.SimpleNamespace(COLOR_STREAM="color_stream")
        outer = self
        self.stopped = 0

        class Context:
            def query_devices(self):
                return types.SimpleNamespace(get_count=lambda: devices)

        class ProfileList:
            def __init__(self, kind):
                self.kind = kind

            def get_video_stream_profile(self, w, h, fmt, fps):
                return (self.kind, w, h, fmt, fps)

        class Config:
            def __init__(self):
                self.streams = []

            def enable_stream(self, profile):
                self.streams.append(profile)

        class VideoFrame:
            def __init__(self, data, h, w, stamp, scale=None):
                self.data, self.h, self.w, self.stamp, self.scale = data, h, w, stamp, scale

            def get_data(self):
                return self.data.tobytes()

            def get_height(self):
                return self.h

            def get_width(self):
                return self.w

            def get_timestamp_us(self):
                return int(self.stamp * 1000)

            def get_depth_scale(self):
                return self.scale

        class FrameSet:
            def __init__(self, stamp, color, depth):
                h, w = depth.shape
                self.d = VideoFrame(depth, h, w, stamp, 1.0)
                self.c = VideoFrame(color, h, w, stamp)

            def as_frame_set(self):
                return self

            def get_depth_frame(self):
                return self.d

            def get_color_frame(self):
                return self.c

        class Pipeline:
            def __init__(self):
                self.k = 0

            def get_stream_profile_list(self, kind):
                return ProfileList(kind)

            def start(self, config):
                outer.config = config

            def get_camera_param(self):
                intr = types.SimpleNamespace(fx=500.0, fy=500.0, cx=319.0, cy=241.0, width=640, height=480)
                return types.SimpleNamespace(rgb_intrinsic=intr)

            def wait_for_frames(self, timeout_ms):
                if (empty_after is not None and self.k >= empty_after) or self.k >= len(frames):
                    return None
                stamp, color, depth = frames[self.k]
                self.k += 1
                return FrameSet(stamp, color, depth)

            def stop(self):
                outer.stopped += 1

        class AlignFilter:
            def __init__(self, align_to_stream):
                assert align_to_stream == "color_stream"

            def process(self, frames):
                return frames

        mod.Context, mod.Pipeline, mod.Config, mod.AlignFilter = Context, Pipeline, Config, AlignFilter
        self.module = mod


def test_orbbec_camera_with_fake_device(monkeypatch):
    data = camera_frames([500.0, 533.0, 566.0])
    fake = FakeOrbbec(data)
    monkeypatch.setitem(sys.modules, "pyorbbecsdk", fake.module)
    cam = OrbbecCamera(max_empty_waits=2)
    assert cam.intrinsics == CameraIntrinsics(500.0, 500.0, 319.0, 241.0, 640, 480)
    assert ("depth", 640, 480, "Y16", 30) in fake.config.streams
    assert ("color", 640, 480, "RGB", 30) in fake.config.streams
    received = []
    with pytest.raises(CameraDisconnected, match="after 3 frames"):
        for frame in cam.frames():
            received.append(frame)
    cam.close()
    cam.close()
    assert fake.stopped == 1 and len(received) == 3
    assert received[1].timestamp == pytest.approx(0.533) and received[1].depth_scale == pytest.approx(0.001)
    np.testing.assert_array_equal(received[2].color, data[2][1])
    np.testing.assert_array_equal(received[2].depth, data[2][2])
    monkeypatch.setitem(sys.modules, "pyorbbecsdk", FakeOrbbec([], devices=0).module)
    with pytest.raises(CameraUnavailable, match="no Orbbec device attached"):
        OrbbecCamera()
    monkeypatch.setitem(sys.modules, "pyorbbecsdk", None)
    with pytest.raises(CameraUnavailable, match="orbbec"):
        OrbbecCamera()
