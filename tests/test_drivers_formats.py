"""Driver formats: round trips for every reader/writer pair, the real recordings, and bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from warpface.data import shared_data_path
from warpface.drivers import (
    ARKIT_CHANNELS,
    Curves,
    detect_format,
    write_live_link,
    write_mediapipe_jsonl,
    write_mediapipe_textproto,
    write_openface,
)
from warpface.drivers.channels import canonical_channel
from warpface.drivers.csv_formats import read_live_link
from warpface.drivers.mediapipe_format import read_mediapipe_jsonl, read_mediapipe_textproto
from warpface.usd import read_driver
from warpface.usd.skel_io import read_skel_animation, write_skel_animation


def arkit_curves(frames=40, fps=60.0, seed=0, names=ARKIT_CHANNELS):
    rng = np.random.default_rng(seed)
    return Curves(
        times=np.arange(frames) / fps,
        names=list(names),
        values=rng.uniform(0, 1, (frames, len(names))),
        source="random",
        fps=fps,
    )


def test_canonical_names():
    assert canonical_channel("BrowInnerUp") == "browInnerUp"
    assert canonical_channel(" MOUTHSMILELEFT ") == "mouthSmileLeft"
    assert canonical_channel("AU1") == canonical_channel("AU01_r") == canonical_channel("au_01") == "AU01"
    assert canonical_channel("HeadYaw") == "HeadYaw"
    assert len(ARKIT_CHANNELS) == len(set(ARKIT_CHANNELS)) == 52


def test_live_link_round_trip(tmp_path):
    curves = arkit_curves()
    path = write_live_link(tmp_path / "take.csv", curves, start_seconds=3723.5)
    header = path.read_text().splitlines()[0].split(",")
    assert header[:3] == ["Timecode", "BlendshapeCount", "BrowDownLeft"] and header[-1] == "RightEyeRoll"
    assert path.read_text().splitlines()[1].startswith("01:02:03:30.000,52,")
    back = read_driver(path)
    assert detect_format(path) == "livelink" and back.fps == 60.0
    assert back.names == list(ARKIT_CHANNELS)
    np.testing.assert_allclose(back.times, curves.times, atol=1e-3 / 60)
    np.testing.assert_allclose(back.values, curves.values, rtol=0, atol=1e-15)


def test_live_link_frame_rate_from_timecodes(tmp_path):
    for fps in (24.0, 30.0, 50.0):
        back = read_live_link(write_live_link(tmp_path / "t.csv", arkit_curves(frames=int(2 * fps), fps=fps), fps=fps))
        assert back.fps == fps
        np.testing.assert_allclose(np.diff(back.times), 1 / fps, atol=1e-9)


def test_openface_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    names = ["AU01", "AU02", "AU12", "AU26"]
    curves = Curves(times=np.cumsum(rng.uniform(0.03, 0.07, 30)), names=names, values=rng.uniform(0, 5, (30, 4)))
    path = write_openface(tmp_path / "of.csv", curves)
    assert detect_format(path) == "openface"
    back = read_driver(path)
    assert back.names == names
    np.testing.assert_array_equal(back.times, curves.times)
    np.testing.assert_array_equal(back.values, curves.values)


@pytest.mark.parametrize(
    "writer, reader, suffix",
    [
        (write_mediapipe_textproto, read_mediapipe_textproto, ".pbtxt"),
        (write_mediapipe_jsonl, read_mediapipe_jsonl, ".jsonl"),
    ],
)
def test_mediapipe_round_trips(tmp_path, writer, reader, suffix):
    curves = arkit_curves(frames=12, fps=30.0)
    path = writer(tmp_path / f"mp{suffix}", curves)
    for back in (reader(path), read_driver(path)):
        assert back.names == list(ARKIT_CHANNELS)
        np.testing.assert_allclose(back.times, curves.times, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(back.values, curves.values)


def test_mediapipe_single_frame_and_json_variants(tmp_path):
    single = write_mediapipe_textproto(tmp_path / "one.pbtxt", arkit_curves(frames=1))
    assert read_driver(single).frame_count == 1 and "classification_list" not in single.read_text()
    lines = [
        {
            "timestamp": 0.0,
            "face_blendshapes": [
                [{"category_name": "_neutral", "score": 0.1}, {"category_name": "jawOpen", "score": 0.4}]
            ],
        },
        {"timestamp": 0.5, "blendshapes": {"jawOpen": 0.7, "_neutral": 0.0}},
    ]
    path = tmp_path / "v.jsonl"
    path.write_text("\n".join(json.dumps(line) for line in lines))
    back = read_driver(path)
    assert back.names == ["jawOpen"]
    np.testing.assert_array_equal(back.values[:, 0], [0.4, 0.7])
    np.testing.assert_array_equal(back.times, [0.0, 0.5])


@pytest.mark.parametrize("suffix", [".usda", ".usdc"])
def test_usd_skel_round_trip(tmp_path, suffix):
    curves = arkit_curves(frames=25, fps=24.0)
    path = write_skel_animation(tmp_path / f"a2f{suffix}", curves)
    assert detect_format(path) == "usdskel"
    back = read_driver(path)
    assert back.names == list(ARKIT_CHANNELS) and back.fps == 24.0
    np.testing.assert_allclose(back.times, curves.times, atol=1e-12)
    np.testing.assert_allclose(back.values, curves.values, atol=1e-7)  # blendShapeWeights are float[]


def test_skel_stage_written_by_plain_usd(tmp_path):
    """An Audio2Face-style stage authored with pxr directly (not warpface's writer)."""
    from pxr import Usd, UsdSkel

    stage = Usd.Stage.CreateNew(str(tmp_path / "a2f.usda"))
    stage.SetTimeCodesPerSecond(30)
    UsdSkel.Root.Define(stage, "/World")
    animation = UsdSkel.Animation.Define(stage, "/World/anim")
    animation.CreateBlendShapesAttr(["browInnerUp", "jawOpen", "mouthSmileLeft"])
    weights = animation.CreateBlendShapeWeightsAttr()
    for frame in range(10):
        weights.Set([frame / 10, 0.0, 1 - frame / 10], Usd.TimeCode(frame))
    stage.Save()
    back = read_skel_animation(tmp_path / "a2f.usda")
    np.testing.assert_allclose(back.times, np.arange(10) / 30)
    np.testing.assert_allclose(back.channel("browInnerUp"), np.arange(10) / 10, atol=1e-7)


def test_real_openface_recordings():
    folder = shared_data_path("auplayer_openface_au")
    if folder is None:
        pytest.skip("../shared/data/auplayer_openface_au is not present")
    for name in ("10_3_au.txt", "19_3_au.txt"):
        curves = read_driver(folder / name)
        assert curves.names[:3] == ["AU01", "AU02", "AU04"] and "AU45" in curves.names
        assert 10 < curves.fps < 25 and curves.frame_count > 250
        assert 0 <= curves.values.min() and curves.values.max() <= 5
        assert curves.values.max() > 1  # real motion, not zeros


def test_real_mediapipe_scores():
    path = shared_data_path("mediapipe", "face_blendshapes_out.prototxt")
    if path is None:
        pytest.skip("../shared/data/mediapipe is not present")
    curves = read_driver(path)
    assert len(curves.names) == 51 and "tongueOut" not in curves.names  # MediaPipe has no tongue
    assert curves.channel("browDownLeft")[0] > 0.8 and curves.channel("browInnerUp")[0] < 0.01


# ---------------------------------------------------------------------------------------------- bad input


BAD_CSV = {
    "empty": "",
    "header only": "Timecode,BlendshapeCount,BrowInnerUp\n",
    "no timecode": "Time,BrowInnerUp\n0,0.1\n",
    "bad timecode": "Timecode,BlendshapeCount,BrowInnerUp\n12:00,52,0.1\n",
    "nan weight": "Timecode,BlendshapeCount,BrowInnerUp\n00:00:00:01.000,52,nan\n00:00:00:02.000,52,0.2\n",
    "duplicate time": "Timecode,BlendshapeCount,BrowInnerUp\n00:00:00:01.000,52,0.1\n00:00:00:01.000,52,0.2\n",
    "backwards": "Timecode,BlendshapeCount,BrowInnerUp\n00:00:00:05.000,52,0.1\n00:00:00:02.000,52,0.2\n",
    "short row": "Timecode,BlendshapeCount,BrowInnerUp\n00:00:00:05.000,52\n",
    "openface no AU": "frame, timestamp, success\n1, 0, 1\n",
    "openface untracked": "frame, timestamp, success, AU01_r\n1, 0, 0, 1.0\n2, 0.1, 0, 1.0\n",
    "openface text": "frame, timestamp, success, AU01_r\n1, 0, 1, high\n",
}


@pytest.mark.parametrize("case", sorted(BAD_CSV))
def test_bad_files_give_one_line_value_errors(tmp_path, case):
    path = tmp_path / "bad.csv"
    path.write_text(BAD_CSV[case])
    with pytest.raises(ValueError) as error:
        read_driver(path)
    assert "\n" not in str(error.value) and str(path.name) in str(error.value)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    tokens=st.lists(
        st.sampled_from(
            [
                "0",
                "1.5",
                "-2",
                "7",
                "nan",
                "inf",
                "1e400",
                ":",
                ".",
                ",",
                ", ",
                "\n",
                " ",
                "00:00:00:01.5",
                "00:00:01:59.999",
                "AU01_r",
                "AU12_r",
                "timestamp",
                "Timecode",
                "BrowInnerUp",
                "MouthSmileLeft",
                "success",
                "HeadYaw",
                "x",
            ]
        ),
        max_size=60,
    )
)
def test_fuzzed_csv_reads_or_says_why(tmp_path, tokens):
    path = tmp_path / "fuzz.csv"
    path.write_text("".join(tokens))
    try:
        curves = read_driver(path)
    except ValueError as error:
        assert "\n" not in str(error)
        return
    assert np.isfinite(curves.values).all() and np.all(np.diff(curves.times) > 0)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    records=st.lists(
        st.one_of(
            st.fixed_dictionaries(
                {
                    "timestamp_ms": st.one_of(st.floats(allow_nan=True), st.integers(), st.text(max_size=3)),
                    "blendshapes": st.dictionaries(
                        st.sampled_from(["jawOpen", "browInnerUp", "foo", "_neutral"]),
                        st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=2)),
                        max_size=3,
                    ),
                }
            ),
            st.integers(),
            st.text(max_size=5),
        ),
        max_size=5,
    )
)
def test_fuzzed_jsonl_reads_or_says_why(tmp_path, records):
    path = tmp_path / "fuzz.jsonl"
    path.write_text("\n".join(json.dumps(r) for r in records))
    try:
        curves = read_driver(path)
    except ValueError as error:
        assert "\n" not in str(error)
        return
    assert np.isfinite(curves.values).all() and np.all(np.diff(curves.times) > 0)


def test_live_link_app_spelling_and_column_order(tmp_path):
    """The app writes ``BlendShapeCount`` and ARKit's enum order (EyeBlinkLeft first), not alphabetical."""
    path = tmp_path / "app.csv"
    path.write_text(
        "Timecode,BlendShapeCount,EyeBlinkLeft,JawOpen,MouthSmileLeft,HeadYaw\n"
        "09:15:00:58.500,52,0.1,0.2,0.3,0.01\n09:15:00:59.500,52,0.2,0.4,0.6,0.02\n"
        "09:15:01:00.500,52,0.3,0.6,0.9,0.03\n"
    )
    curves = read_driver(path)
    assert curves.names == ["eyeBlinkLeft", "jawOpen", "mouthSmileLeft"] and not curves.notes
    assert curves.fps == 60.0
    np.testing.assert_allclose(curves.times, [0, 1 / 60, 2 / 60])
    np.testing.assert_array_equal(curves.channel("mouthSmileLeft"), [0.3, 0.6, 0.9])


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    names=st.lists(st.sampled_from(["jawOpen", "browInnerUp", "foo"]), max_size=3),
    samples=st.dictionaries(
        st.floats(-5, 100), st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), max_size=4), max_size=4
    ),
)
def test_fuzzed_skel_stage_reads_or_says_why(tmp_path, names, samples):
    from pxr import Usd, UsdSkel

    stage = Usd.Stage.CreateInMemory("fuzz.usda")
    animation = UsdSkel.Animation.Define(stage, "/Anim")
    animation.CreateBlendShapesAttr(names)
    weights = animation.CreateBlendShapeWeightsAttr()
    for time, values in samples.items():
        weights.Set(values, Usd.TimeCode(time))
    try:
        curves = read_skel_animation(stage)
    except ValueError as error:
        assert "\n" not in str(error)
        return
    assert np.isfinite(curves.values).all() and np.all(np.diff(curves.times) > 0)
    assert curves.values.shape == (len(curves.times), len(names))


def test_read_driver_without_usd_core(tmp_path):
    """With usd-core absent, ``import warpface`` imports no pxr, ``warpface.usd.read_driver`` reads a CSV, and a
    USD layer is one clear ValueError."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    csv = write_live_link(tmp_path / "take.csv", arkit_curves(frames=3, fps=30.0))
    layer = write_skel_animation(tmp_path / "take.usda", arkit_curves(frames=3, fps=30.0))
    code = (
        "import sys\nsys.modules['pxr'] = None  # as if usd-core were not installed\n"
        "import warpface, warpface.usd\n"
        f"curves = warpface.usd.read_driver({str(csv)!r})\n"
        "try:\n"
        f"    warpface.usd.read_driver({str(layer)!r})\n"
        "except ValueError as error:\n"
        "    print('ValueError', error)\n"
        "print(curves.frame_count, len(curves.names), sys.modules['pxr'] is None)\n"
    )
    root = Path(__file__).resolve().parents[1]
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(root)}
    )
    assert result.returncode == 0, result.stderr
    error, counts = result.stdout.strip().splitlines()
    assert error.startswith("ValueError") and "usd-core" in error
    assert counts == f"3 {len(ARKIT_CHANNELS)} True"
