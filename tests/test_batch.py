"""``warpface batch``: a manifest of real and hand-written takes on the local engine — each good take baked exactly as
``animate`` bakes it, the corrupt one failed alone, report, contact sheet and shoot stage; resume, --force; bad
manifests refused before any work."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from helpers import live_link_csv

from warpface.cli import main
from warpface.data import shared_data_path

OPENFACE = shared_data_path("auplayer_openface_au", "19_3_au.txt")
MEDIAPIPE = shared_data_path("mediapipe", "face_blendshapes_out.prototxt")
needs_data = pytest.mark.skipif(
    OPENFACE is None or MEDIAPIPE is None, reason="../shared/data (OpenFace, MediaPipe) is not present"
)


def write_manifest(folder, rows, rig, name="takes.csv"):
    """A CSV manifest of ``(id, input, kind, options)`` rows, every take on the rig stage ``rig``."""
    path = folder / name
    path.write_text("id,input,kind,rig,options\n" + "".join(f"{i},{f},{k},{rig},{o}\n" for i, f, k, o in rows))
    return path


@pytest.fixture(scope="module")
def shoot(tmp_path_factory, classic_rig_stage):
    """A manifest of a hand-written Live Link take, a real OpenFace recording, real MediaPipe scores and a corrupt
    file on the classic rig, run once by ``warpface batch`` on the local engine."""
    if OPENFACE is None or MEDIAPIPE is None:
        pytest.skip("../shared/data (OpenFace, MediaPipe) is not present")
    folder = tmp_path_factory.mktemp("shoot")
    live_link_csv(folder / "smile.csv", 9, {"mouthSmileLeft": 0.9, "browInnerUp": 0.6})
    (folder / "corrupt.csv").write_bytes(b"Timecode,BlendshapeCount,BrowInnerUp\n\x00\xff\x10garbage,,\n")
    manifest = write_manifest(
        folder,
        [
            ("smile", "smile.csv", "animate", "--no-video"),
            ("openface", str(OPENFACE), "animate", "--no-video"),
            ("mediapipe", str(MEDIAPIPE), "animate", "--no-video"),
            ("corrupt", "corrupt.csv", "animate", "--no-video"),
        ],
        classic_rig_stage,
    )
    out = folder / "out"
    code = main(["--quiet", "--device", "cpu", "batch", str(manifest), "--out", str(out), "--jobs", "2"])
    return {"folder": folder, "manifest": manifest, "out": out, "code": code, "rig": classic_rig_stage}


def report_of(out):
    return {entry["id"]: entry for entry in json.loads((out / "report.json").read_text())["takes"]}


def skin_points(stage_path, time):
    from pxr import Usd

    from warpface import usd

    stage = Usd.Stage.Open(str(stage_path))
    return np.asarray(usd.rig_prims(stage).skin.GetAttribute("points").Get(Usd.TimeCode(time)), dtype=np.float64)


def test_good_takes_are_done_and_the_corrupt_one_fails_alone(shoot):
    out = shoot["out"]
    assert shoot["code"] == 1  # a take failed
    takes = report_of(out)
    assert [takes[i]["status"] for i in ("smile", "openface", "mediapipe", "corrupt")] == ["done"] * 3 + ["failed"]
    error = takes["corrupt"]["error"]
    assert "corrupt.csv" in error and "\n" not in error and takes["corrupt"]["stage"] is None
    assert not (out / "corrupt").exists()
    assert takes["openface"]["frames"] == 301 and takes["mediapipe"]["frames"] == 1 and takes["smile"]["frames"] == 9
    for take_id in ("smile", "openface", "mediapipe"):
        stage = out / take_id / f"{take_id}.usda"
        assert takes[take_id]["stage"] == str(stage) and stage.is_file()
        assert (out / take_id / f"{take_id}_anim.usdc").is_file() and (out / take_id / "thumb.png").is_file()
        assert json.loads((out / take_id / "take.json").read_text())["digest"] == takes[take_id]["digest"]
    assert sorted(p.name for p in out.iterdir()) == [
        "mediapipe",
        "openface",
        "report.json",
        "report.png",
        "shoot.usda",
        "smile",
    ]  # nothing partial, nothing hidden left behind
    document = json.loads((out / "report.json").read_text())
    assert document["finished"] and document["counts"] == {"done": 3, "skipped": 0, "failed": 1}


def test_a_batch_take_is_baked_exactly_as_animate_bakes_it(shoot, tmp_path):
    from warpface.commands.animate import animate

    smile = shoot["folder"] / "smile.csv"
    animate(smile, tmp_path / "direct.usda", rig=shoot["rig"], video=False, device="cpu", progress=False)
    for time in range(9):
        np.testing.assert_array_equal(
            skin_points(shoot["out"] / "smile" / "smile.usda", time), skin_points(tmp_path / "direct.usda", time)
        )


def test_the_picture_is_taken_at_the_most_active_moment(shoot):
    """The recorded moment is where the skin is furthest from rest, found here over every frame independently."""
    from pxr import Usd

    from warpface import usd

    entry = report_of(shoot["out"])["openface"]
    stage = Usd.Stage.Open(str(shoot["out"] / "openface" / "openface.usda"))
    rest = usd.read_rig(stage).mesh.points
    points = usd.rig_prims(stage).skin.GetAttribute("points")
    distance = np.array([np.abs(np.asarray(points.Get(t), dtype=np.float64) - rest).max() for t in range(301)])
    best = int(np.argmax(distance))
    assert distance[int(entry["moment"])] >= distance[best] * 0.95  # at most a sampling step from the peak
    assert distance[int(entry["moment"])] > 2 * np.median(distance)  # a moment of real motion


def test_shoot_stage_opens_and_every_variant_plays(shoot):
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(shoot["out"] / "shoot.usda"))
    character = stage.GetPrimAtPath("/Shoot/Character")
    variants = character.GetVariantSet("take")
    assert sorted(variants.GetVariantNames()) == ["mediapipe", "openface", "smile"]
    frames = {"smile": 9, "openface": 301, "mediapipe": 1}
    moved = {}
    for name in variants.GetVariantNames():
        assert variants.SetVariantSelection(name)
        skin = next(p for p in Usd.PrimRange(character) if p.IsA(UsdGeom.Mesh))
        samples = UsdGeom.Mesh(skin).GetPointsAttr().GetTimeSamples()
        assert len(samples) == frames[name]
        points = [np.asarray(UsdGeom.Mesh(skin).GetPointsAttr().Get(t)) for t in samples]
        moved[name] = max(np.abs(p - points[0]).max() for p in points)
        take = stage.GetPrimAtPath(f"/Shoot/Takes/{name}")
        assert take.GetCustomData()["frames"] == frames[name] and take.GetCustomData()["status"] == "done"
    assert moved["smile"] > 1e-3 and moved["openface"] > 1e-4  # metres: the takes play, not a still face
    rate = stage.GetTimeCodesPerSecond()
    seconds = []
    for name in frames:  # each take's own length in seconds, from its own stage
        own = Usd.Stage.Open(str(shoot["out"] / name / f"{name}.usda"))
        seconds.append(own.GetEndTimeCode() / own.GetTimeCodesPerSecond())
    assert stage.GetEndTimeCode() == pytest.approx(max(seconds) * rate)


def test_contact_sheet_has_a_tile_per_take_with_its_picture(shoot):
    import cv2

    sheet = cv2.imread(str(shoot["out"] / "report.png"))
    assert sheet is not None and sheet.shape[1] == 4 * 240  # four takes side by side
    tiles = [sheet[:270, 240 * k : 240 * (k + 1)] for k in range(4)]
    assert all(t.std() > 10 for t in tiles[:3])  # a rendered face
    thumb = cv2.imread(str(shoot["out"] / "smile" / "thumb.png"))
    y, x = (270 - thumb.shape[0]) // 2, (240 - thumb.shape[1]) // 2
    np.testing.assert_array_equal(tiles[0][y : y + thumb.shape[0], x : x + thumb.shape[1]], thumb)


def test_a_second_run_skips_complete_takes_and_redoes_changed_ones(shoot, tmp_path, capsys):
    out = tmp_path / "out"
    shutil.copytree(shoot["out"], out)
    before = {i: (out / i / f"{i}_anim.usdc").stat().st_mtime_ns for i in ("smile", "openface", "mediapipe")}
    manifest = write_manifest(
        shoot["folder"],
        [
            ("smile", "smile.csv", "animate", "--no-video"),
            ("openface", str(OPENFACE), "animate", "--no-video"),
            ("mediapipe", str(MEDIAPIPE), "animate", "--no-video --gain browDownLeft=0.5"),
        ],
        shoot["rig"],
        name="rerun.csv",
    )
    assert main(["--quiet", "--device", "cpu", "batch", str(manifest), "--out", str(out)]) == 0
    takes = report_of(out)
    assert [takes[i]["status"] for i in ("smile", "openface", "mediapipe")] == ["skipped", "skipped", "done"]
    assert (out / "smile" / "smile_anim.usdc").stat().st_mtime_ns == before["smile"]
    assert (out / "mediapipe" / "mediapipe_anim.usdc").stat().st_mtime_ns != before["mediapipe"]
    assert "0 failed" in capsys.readouterr().out
    assert main(["--quiet", "--device", "cpu", "batch", str(manifest), "--out", str(out), "--jobs", "1"]) == 0
    assert {e["status"] for e in report_of(out).values()} == {"skipped"}
    single = write_manifest(
        shoot["folder"], [("smile", "smile.csv", "animate", "--no-video")], shoot["rig"], name="one.csv"
    )
    assert main(["--quiet", "--device", "cpu", "batch", str(single), "--out", str(out), "--force"]) == 0
    assert report_of(out)["smile"]["status"] == "done"
    assert (out / "smile" / "smile_anim.usdc").stat().st_mtime_ns != before["smile"]
    np.testing.assert_array_equal(
        skin_points(out / "smile" / "smile.usda", 4), skin_points(shoot["out"] / "smile" / "smile.usda", 4)
    )
