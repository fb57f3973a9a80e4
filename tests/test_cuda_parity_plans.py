"""CPU ↔ device parity of the expression model's launch plans (1 tiled kernel, 2 fused kernels, 3, 5) on the parity
device of ``tests/test_cuda_parity.py`` (``WARPFACE_PARITY_DEVICE``, default ``cuda:0``; skipped without it)::

    WARPFACE_PARITY_DEVICE=cpu python -m pytest -q tests/test_cuda_parity_plans.py   # logic, no GPU
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from helpers import FLOAT32_FACE_TOLERANCE, expression_controls, parity_device

DEVICE = parity_device()

CPU = wp.get_device("cpu")


@pytest.fixture(scope="module")
def face_rig():
    from warpface.assets import default_rig

    return default_rig(device="cpu")


@pytest.fixture(scope="module")
def models(face_rig):
    return face_rig.model(device=CPU), face_rig.model(device=DEVICE)


@pytest.mark.parametrize("launches", [2, 3, 5])
def test_launch_plans_agree_on_the_device(face_rig, models, launches):
    """The device default (the tiled one-launch plan: the fastest on the H200) against the 2-, 3- and 5-kernel
    plans on the same device: the same operations in the same order, so equal up to the compiler's choice of FMA
    contraction (measured: the benchmark's "same" columns), and both against the CPU. A batch of the
    two-launch plan and of the default, large enough for several frames per thread (``frames_per_thread`` > 1),
    equals single frames."""
    from warpface import ExpressionModel

    cpu_model, fused = models
    assert fused.launches_per_frame == (1 if DEVICE.is_cuda else 5)
    staged = ExpressionModel(
        face_rig.mesh,
        face_rig.muscles,
        face_rig.wrinkles,
        face_rig.thickness,
        device=DEVICE,
        jaw=face_rig.jaw,
        launches=launches,
    )
    contractions, depths = expression_controls(face_rig, 3, seed=4)
    tolerance = FLOAT32_FACE_TOLERANCE * face_rig.mesh.size
    for frame in range(3):
        got = fused.evaluate(contractions[frame], wrinkle_depths=depths[frame])
        np.testing.assert_allclose(
            got, staged.evaluate(contractions[frame], wrinkle_depths=depths[frame]), rtol=0, atol=tolerance
        )
        # Against the CPU: every plan on the H200 differs by up to 3.8e-6 m (2.7x the float32 tolerance) at
        # 6 of 11,492 vertices for these controls (float32 rounding amplified at a few points), so: the
        # tolerance at 99.9 % of the points, 4x it at the rest.
        off = np.linalg.norm(got - cpu_model.evaluate(contractions[frame], wrinkle_depths=depths[frame]), axis=1)
        assert np.mean(off > tolerance) < 1e-3 and off.max() < 4 * tolerance, (off.max(), np.sum(off > tolerance))
    if launches == 5:
        return  # the batch check below runs on the plans that evaluate several frames per thread (block)
    frames = max(8, 4 * (1 << 20) // face_rig.mesh.vertex_count + 1)  # > 2^20 frame·vertices per launch
    many_c, many_d = (
        np.resize(contractions, (frames, contractions.shape[1])),
        np.resize(depths, (frames, depths.shape[1])),
    )
    for model in (
        (staged, fused) if launches == 2 else (staged,)
    ):  # the two- or three-launch plan and the default (tiled)
        assert model._frames_per_thread(frames) > 1 or not DEVICE.is_cuda
        out = wp.empty((frames, face_rig.mesh.vertex_count), dtype=wp.vec3, device=DEVICE)
        model.evaluate_batch_into(out, many_c, wrinkle_depths=many_d)
        batch = out.numpy()
        for frame in range(3):
            np.testing.assert_array_equal(
                batch[frame], model.evaluate(contractions[frame], wrinkle_depths=depths[frame])
            )
            np.testing.assert_array_equal(batch[frames - 3 + frame], batch[(frames - 3 + frame) % 3])
