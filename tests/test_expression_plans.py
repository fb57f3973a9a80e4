"""Both plans of the model — staged (five kernels, the CPU's default) and tiled (one kernel, CUDA's) — equal
the five-kernel sequence of kernels.py (launched by expression_plans) bit for bit, on the default rig (jaw and
wrinkles) and on a rig without a jaw, single frames and batches, to NumPy and to device arrays."""

import numpy as np
import pytest
import warp as wp
from expression_plans import build_model, five_kernel_frames, random_controls
from helpers import small_face_rig

from warpface import ExpressionModel

DEVICE = "cpu"


@pytest.fixture(
    scope="module",
    params=[
        ("default rig", "staged"),
        ("default rig", "tiled"),
        ("small rig without jaw", "staged"),
        ("small rig without jaw", "tiled"),
    ],
    ids=["default-staged", "default-tiled", "small-staged", "small-tiled"],
)
def model(request):
    return build_model(*request.param)


def test_single_frame_and_stages_equal_the_five_kernel_sequence(model, rng):
    contractions, depths = random_controls(model, rng, 1)
    expected = five_kernel_frames(model, contractions, depths)
    moved = np.linalg.norm(expected["final"][0] - model.mesh.points, axis=1).max()
    assert moved > 1e-3 * model.mesh.size  # a real expression
    if model.wrinkles:
        assert np.abs(expected["final"] - expected["bulge"]).max() > 0  # wrinkles act
    stages = model.stages(contractions[0], wrinkle_depths=depths[0])
    for name in ("muscle", "stretch", "bulge", "final"):
        np.testing.assert_array_equal(stages[name], expected[name][0], err_msg=name)
    np.testing.assert_array_equal(model.evaluate(contractions[0], wrinkle_depths=depths[0]), expected["final"][0])


@pytest.mark.parametrize("frames_per_launch", [None, 3])
def test_batches_equal_the_five_kernel_sequence(model, rng, frames_per_launch):
    contractions, depths = random_controls(model, rng, 5)
    expected = five_kernel_frames(model, contractions, depths)["final"]
    np.testing.assert_array_equal(
        model.evaluate(contractions, wrinkle_depths=depths, frames_per_launch=frames_per_launch), expected
    )
    out = wp.empty((5, model.mesh.vertex_count), dtype=wp.vec3, device=DEVICE)
    model.evaluate(
        wp.array(contractions.astype(np.float32), device=DEVICE),
        out=out,
        wrinkle_depths=wp.array(depths.astype(np.float32), device=DEVICE),
        frames_per_launch=frames_per_launch,
    )
    np.testing.assert_array_equal(out.numpy(), expected)


@pytest.mark.parametrize("bad", ["fused", 1, True, "Tiled"])
def test_plan_must_be_a_known_name(bad):
    rig = small_face_rig()
    with pytest.raises(ValueError, match="plan"):
        ExpressionModel(rig.mesh, rig.muscles, rig.wrinkles, rig.thickness, device=DEVICE, plan=bad)


def test_default_plan_by_device():
    rig = small_face_rig()
    assert ExpressionModel(rig.mesh, rig.muscles, device=DEVICE).plan == "staged"  # the CPU's default
    assert ExpressionModel(rig.mesh, rig.muscles, device=DEVICE, plan="tiled").plan == "tiled"


def test_one_evaluate_takes_a_frame_or_a_batch_by_shape(model, rng):
    """(C,) is one frame, (F, C) a batch, [] no frames; an evaluator of its own (own buffers) gives the same
    bits; any other rank is refused naming ``controls``."""
    contractions, depths = random_controls(model, rng, 3)
    batch = model.evaluate(contractions, wrinkle_depths=depths)
    assert batch.shape == (3, model.mesh.vertex_count, 3)
    other = model.evaluator()
    for frame in range(3):
        single = other.evaluate(contractions[frame], wrinkle_depths=depths[frame])
        np.testing.assert_array_equal(single, batch[frame])
    np.testing.assert_array_equal(other.evaluate(contractions, wrinkle_depths=depths), batch)
    assert model.evaluate([]).shape == (0, model.mesh.vertex_count, 3)
    with pytest.raises(ValueError, match=r"^controls: .*3 axes"):
        model.evaluate(contractions[None])
