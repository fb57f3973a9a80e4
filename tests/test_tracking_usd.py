"""Tracked captures on USD: exact round trips, incremental flushing, nothing lost on failure."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import DisappearingCamera, grid_surface

from warpface.cli import main
from warpface.pipelines.capture import record
from warpface.tracking import adapter_for_face, landmark_vertices, vertex_landmark_names
from warpface.usd.tracking_io import TrackingStageWriter, read_tracking


def test_round_trip_is_exact_across_chunks(tmp_path, rng):
    rest, triangles = grid_surface(8)
    landmarks = rng.normal(size=(10, 3, 3))
    dense = (rest + rng.normal(size=(10, *rest.shape)) * 1e-3).astype(np.float32)
    with TrackingStageWriter(
        tmp_path / "cap.usda", ["a", "b", "c"], 24.0, dense_rest=rest, triangles=triangles, chunk_frames=4
    ) as writer:
        for i in range(10):
            writer.add(0.5 + i / 24.0, landmarks[i], np.full(3, 0.9), dense[i])
    assert sorted(p.name for p in (tmp_path / "cap_track").iterdir()) == [
        "chunk_0000.usdc",
        "chunk_0001.usdc",
        "chunk_0002.usdc",
        "static.usdc",
    ]
    back = read_tracking(tmp_path / "cap.usda")
    np.testing.assert_allclose(back["times"], np.arange(10), atol=1e-9)
    assert back["fps"] == 24.0 and back["names"] == ["a", "b", "c"]
    np.testing.assert_array_equal(back["landmarks"], landmarks.astype(np.float32))
    np.testing.assert_array_equal(back["dense"], dense)
    np.testing.assert_array_equal(back["rest"], rest.astype(np.float32))
    np.testing.assert_array_equal(back["confidence"], np.full((10, 3), 0.9, dtype=np.float32))


def test_missing_landmarks_hold_their_last_position_with_zero_confidence(tmp_path):
    with TrackingStageWriter(tmp_path / "cap.usda", ["a", "b"], 30.0) as writer:
        writer.add(0.0, np.array([[1.0, 2, 3], [4, 5, 6]]), np.ones(2))
        writer.add(1 / 30, np.array([[1.5, 2, 3], [np.nan, np.nan, np.nan]]), np.ones(2))
    back = read_tracking(tmp_path / "cap.usda")
    np.testing.assert_array_equal(back["landmarks"][1], [[1.5, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(back["confidence"][1], [1.0, 0.0])
    assert np.all(np.isfinite(back["landmarks"]))


def test_bad_frames_are_refused(tmp_path):
    rest, triangles = grid_surface(4)
    writer = TrackingStageWriter(tmp_path / "cap.usda", ["a"], 30.0, dense_rest=rest, triangles=triangles)
    writer.add(1.0, np.zeros((1, 3)), np.ones(1), rest)
    with pytest.raises(ValueError, match="time must increase"):
        writer.add(1.0, np.zeros((1, 3)), np.ones(1), rest)
    with pytest.raises(ValueError, match="expected 1 landmarks"):
        writer.add(2.0, np.zeros((2, 3)), np.ones(2), rest)
    bad = rest.copy()
    bad[0] = np.nan
    with pytest.raises(ValueError, match="not finite"):
        writer.add(3.0, np.zeros((1, 3)), np.ones(1), bad)
    with pytest.raises(ValueError, match="fps"):
        TrackingStageWriter(tmp_path / "other.usda", ["a"], 0.0)


def test_a_camera_that_disappears_keeps_every_frame_received(tmp_path):
    rest, triangles = grid_surface(12, seed=1)
    rest = rest * 0.05
    vertices = np.array([13, 17, 20, 50, 55, 60, 90, 95, 100, 130, 133])
    source = DisappearingCamera(rest, vertices, 7)
    adapter = adapter_for_face(rest, source.landmark_names, camera_to_model=np.eye(4), device="cpu")
    writer = TrackingStageWriter(
        tmp_path / "cap.usda", source.landmark_names, 30.0, dense_rest=rest, triangles=triangles, chunk_frames=5
    )
    with pytest.raises(ConnectionError):
        record(source, adapter, writer, progress=False)
    back = read_tracking(tmp_path / "cap.usda")
    assert len(back["times"]) == 7
    np.testing.assert_allclose(back["landmarks"][6], rest[vertices] + [0, 0.006, 0], atol=1e-7)
    moved = back["dense"][6] - rest
    assert np.abs(moved[:, 1]).max() == pytest.approx(0.006, rel=1e-4)  # the driven face follows


def test_landmark_names_map_to_vertices():
    assert vertex_landmark_names([3, 12345]) == ["v00003", "v12345"]
    np.testing.assert_array_equal(landmark_vertices(["v00003", "v12"], 20), [3, 12])
    with pytest.raises(ValueError, match="dense-vertex name"):
        landmark_vertices(["nose"], 20)
    with pytest.raises(ValueError, match="outside the face"):
        landmark_vertices(["v00021"], 20)


def test_track_command_on_the_synthetic_camera(tmp_path, capsys):
    stage = tmp_path / "new" / "folder" / "capture.usda"  # track creates the folders it needs
    assert main(["--device", "cpu", "--quiet", "track", "synthetic", "--stage", str(stage), "--frames", "4"]) == 0
    back = read_tracking(stage)
    assert len(back["times"]) == 4 and back["dense"].shape[1] == back["rest"].shape[0]
    assert sorted(p.name for p in (stage.parent / "capture_track").iterdir()) == ["chunk_0000.usdc", "static.usdc"]
    assert "4 frames" in capsys.readouterr().out
    assert main(["track", str(tmp_path / "nothing.txt"), "--stage", str(stage)]) == 2


def test_a_failing_track_command_leaves_nothing_behind(tmp_path, monkeypatch):
    import warpface.fem.volume

    def failing_meshing(*args, **kwargs):
        raise ValueError("tissue shell intersects itself")

    monkeypatch.setattr(warpface.fem.volume, "tissue_from_surface", failing_meshing)
    out = tmp_path / "out"
    assert main(["--device", "cpu", "--quiet", "track", "synthetic", "--stage", str(out / "cap.usda"), "--fem"]) == 2
    assert not out.exists()
    assert main(["--quiet", "track", str(tmp_path / "missing.npz"), "--stage", str(out / "cap.usda")]) == 2
    assert list(tmp_path.iterdir()) == []


def test_track_help_names_the_files_it_writes(capsys):
    with pytest.raises(SystemExit):
        main(["track", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "<stage>_track/" in text and "_track.usdc" not in text


def test_a_new_capture_replaces_a_longer_one_at_the_same_path(tmp_path):
    for frames in (7, 2):
        with TrackingStageWriter(tmp_path / "cap.usda", ["a"], 30.0, chunk_frames=2) as writer:
            for i in range(frames):
                writer.add(i / 30.0, np.full((1, 3), float(frames)), np.ones(1))
    back = read_tracking(tmp_path / "cap.usda")
    assert len(back["times"]) == 2 and np.all(back["landmarks"] == 2.0)
    assert sorted(p.name for p in (tmp_path / "cap_track").iterdir()) == ["chunk_0000.usdc", "static.usdc"]


def test_a_reused_buffer_is_copied_when_queued_and_extents_are_exact(tmp_path, rng):
    """``track_frame(copy=False)`` hands the writer the same buffer every frame: each queued frame
    must keep its own values, and the extent must be its exact bounds."""
    from pxr import Usd, UsdGeom

    from warpface.usd.tracking_io import vec3f_array

    rest, triangles = grid_surface(6)
    buffer = np.empty(rest.shape, dtype=np.float32)
    written = []
    with TrackingStageWriter(
        tmp_path / "cap.usda", ["a"], 30.0, dense_rest=rest, triangles=triangles, chunk_frames=3
    ) as writer:
        for i in range(5):
            buffer[:] = rest + rng.normal(size=rest.shape) * 1e-2
            written.append(buffer.copy())
            writer.add(i / 30.0, np.zeros((1, 3)), np.ones(1), buffer)
    back = read_tracking(tmp_path / "cap.usda")
    np.testing.assert_array_equal(back["dense"], np.stack(written))
    stage = Usd.Stage.Open(str(tmp_path / "cap.usda"))
    face = UsdGeom.Mesh(stage.GetPrimAtPath("/Capture/Face"))
    for i, points in enumerate(written):
        np.testing.assert_array_equal(np.asarray(face.GetExtentAttr().Get(float(i))), [points.min(0), points.max(0)])
    points = rng.normal(size=(7, 3)).astype(np.float32)
    copied = vec3f_array(points)
    points[:] = 0.0  # the Vt array owns its copy
    assert np.asarray(copied).any() and np.asarray(vec3f_array(np.zeros((0, 3), np.float32))).shape == (0, 3)
    with pytest.raises(ValueError, match="float32"):
        vec3f_array(np.zeros((4, 3)))
