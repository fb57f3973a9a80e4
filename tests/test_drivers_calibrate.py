"""A mapping calibrated from example shapes reproduces each example with a one-hot weight (SPEC §6.4)."""

from __future__ import annotations

import numpy as np
import pytest

import warpface as wf
from warpface.assets import default_rig
from warpface.data import ict_face_region, ict_landmark_indices
from warpface.drivers import Curves
from warpface.drivers.calibrate import calibrate_mapping

CENTIMETRE = 0.01
# ICT-FaceKit shape names → ARKit channels (ICT's _L is the subject's left, as ARKit's Left)
ICT_CHANNELS = {
    "browInnerUp_L": "browInnerUp",
    "browOuterUp_L": "browOuterUpLeft",
    "browOuterUp_R": "browOuterUpRight",
    "eyeSquint_L": "eyeSquintLeft",
    "eyeSquint_R": "eyeSquintRight",
    "jawOpen": "jawOpen",
}


def one_hot(channel: str) -> Curves:
    return Curves(times=np.array([0.0]), names=[channel], values=np.array([[1.0]]))


def reproduce(model, mapping, channel):
    controls = mapping.apply(one_hot(channel))
    return model.evaluate(dict(zip(controls.names, controls.values[0])))


def test_one_hot_weights_reproduce_synthetic_examples_exactly():
    """Closed loop: examples made by known controls come back from their one-hot weights."""
    rig = default_rig(device="cpu", anatomy="classic")
    model = rig.model(device="cpu")
    truth = {
        "mouthSmileLeft": {"zygomaticus_major_L": 0.008, "risorius_L": 0.003},
        "BrowInnerUp": {"frontalis_inner_L": 0.006, "frontalis_inner_R": 0.006},
    }
    examples = {channel: model.evaluate(controls) for channel, controls in truth.items()}
    mapping, fits = calibrate_mapping(rig, examples, device="cpu")
    assert mapping.channels == ["mouthSmileLeft", "browInnerUp"]
    scale = np.ptp(rig.mesh.points, axis=0).max()
    for channel, original in zip(mapping.channels, truth):
        points = reproduce(model, mapping, channel)
        assert np.sqrt(np.mean(np.sum((points - examples[original]) ** 2, axis=1))) < 1e-4 * scale
        assert fits[channel].residual < 1e-4 * scale


def test_bad_examples_are_named():
    rig = default_rig(device="cpu", anatomy="classic")
    with pytest.raises(ValueError, match="non-empty"):
        calibrate_mapping(rig, {}, device="cpu")
    with pytest.raises(ValueError, match="given twice"):
        calibrate_mapping(rig, {"BrowInnerUp": rig.mesh.points, "browInnerUp": rig.mesh.points}, device="cpu")
    with pytest.raises(ValueError, match=r"examples\['smile'\]"):
        calibrate_mapping(rig, {"smile": rig.mesh.points[:10]}, device="cpu")


@pytest.mark.slow  # fits every ICT shape, ~30 s on the 2-core CI machine
@pytest.mark.skipif(
    ict_face_region() is None or ict_landmark_indices() is None,
    reason="ICT-FaceKit data not in ../shared/data (set WARPFACE_SHARED_DATA)",
)
def test_ict_shapes_calibrate_a_mapping_whose_one_hot_weights_reproduce_each_fit():
    """The ICT face's own shapes calibrate its mapping: a one-hot weight gives the solver's fit of that
    shape, so the distance to the real shape is the solver's residual (what the rig can reach)."""
    neutral = wf.FaceMesh.from_obj(ict_face_region())
    mesh = wf.FaceMesh(neutral.points * CENTIMETRE, neutral.triangles, name="ict_face")
    rig = default_rig(mesh, ict_landmark_indices(), name="ICTFace", device="cpu")
    examples = {channel: wf.load_obj(ict_face_region(shape))[0] * CENTIMETRE for shape, channel in ICT_CHANNELS.items()}
    mapping, fits = calibrate_mapping(rig, examples, device="cpu")
    model = rig.model(device="cpu")
    for channel, shape in examples.items():
        points = reproduce(model, mapping, channel)
        rms = np.sqrt(np.mean(np.sum((points - shape) ** 2, axis=1)))
        before = np.sqrt(np.mean(np.sum((mesh.points - shape) ** 2, axis=1)))
        assert rms == pytest.approx(fits[channel].residual, rel=1e-3, abs=1e-6), channel
        assert rms < before, f"{channel}: the calibrated weight moved the face away from its example"
    # channels combine linearly: both brow-outer channels at once move both brows
    both = Curves(times=np.array([0.0]), names=["browOuterUpLeft", "browOuterUpRight"], values=np.array([[1.0, 1.0]]))
    controls = mapping.apply(both)
    expected = (
        mapping.apply(one_hot("browOuterUpLeft")).values[0] + mapping.apply(one_hot("browOuterUpRight")).values[0]
    )
    np.testing.assert_allclose(controls.values[0], expected - mapping.offsets, atol=1e-12)
