"""The solver's Levenberg–Marquardt iteration on the device (``device_steps``) against the NumPy loop, on the CPU."""

from __future__ import annotations

import numpy as np
import pytest

from warpface.assets import default_rig, expression_timeline, rig_scale
from warpface.expression import SphincterMuscle
from warpface.solve import Solver, fit
from warpface.solve.pose import rotation_from_vector


@pytest.fixture(scope="module")
def rig():
    return default_rig(device="cpu")


@pytest.fixture(scope="module")
def model(rig):
    return rig.model(device="cpu")


def random_controls(rig, rng, count=5, high=0.2):
    controls = np.zeros(len(rig.muscles))
    for m in rng.choice(len(rig.muscles), count, replace=False):
        controls[m] = rng.uniform(0.02, high) * (1.0 if isinstance(rig.muscles[m], SphincterMuscle) else rig_scale(rig))
    return controls


def assert_same(a, b, iod):
    """Two batch results agree to rounding: same iterations and flags, controls to 1e-10 IOD."""
    assert np.array_equal(a.iterations, b.iterations)
    assert np.array_equal(a.converged, b.converged) and np.array_equal(a.skipped, b.skipped)
    assert np.abs(a.controls - b.controls).max() < 1e-10 * iod
    assert np.abs(a.residual - b.residual).max() < 1e-10 * iod
    assert np.abs(a.rotation - b.rotation).max() < 1e-10
    assert np.abs(a.translation - b.translation).max() < 1e-10 * iod


@pytest.mark.parametrize("options", [{}, {"pose": True}, {"symmetry": 1e-2, "l1": 1e-4},
                                     {"bounds": {"orbicularis_oris": (0.0, 0.05), "zygomaticus_major_L": (0.0, 1e-3)}},
                                     {"max_iterations": 2}])
def test_device_steps_match_host_loop(rig, model, options):
    rng = np.random.default_rng(3)
    truths = np.stack([random_controls(rig, rng) for _ in range(9)])
    truths[4, rig.muscle_names.index("orbicularis_oris")] = 0.4
    frames = model.evaluate_batch(truths).astype(np.float64)[:, rig.landmarks]
    frames[2, 3:30] = np.nan
    frames[5] = np.nan  # skipped: keeps the start
    if options.get("pose"):
        rotation = rotation_from_vector(np.array([[0.1, -0.15, 0.05]]))[0]
        frames = frames @ rotation.T + np.array([0.004, -0.01, 0.02])
    host = Solver(rig, rig.landmarks, device="cpu", device_steps=False, **options).solve_batch(frames)
    device = Solver(rig, rig.landmarks, device="cpu", device_steps=True, **options).solve_batch(frames)
    assert_same(host, device, rig_scale(rig))
    assert device.skipped[5] and not device.converged[5] and np.all(device.controls[5] == 0.0)
    assert np.all(np.isfinite(device.controls)) and np.all(np.isfinite(device.residual))
    if "bounds" in options:
        assert device.controls[:, rig.muscle_names.index("orbicularis_oris")].max() <= 0.05 + 1e-12
    if options.get("max_iterations") == 2:
        assert not device.converged.all() and np.all(device.iterations <= 2)


def test_device_steps_sequence_matches_host_loop(rig, model):
    """Warm-started, smoothed frame after frame: the constant-velocity guess and the temporal anchor."""
    timeline = expression_timeline("smile", rig, seconds=0.4, fps=30.0)
    frames = model.evaluate_batch(timeline).astype(np.float64)[:, rig.landmarks]
    host = Solver(rig, rig.landmarks, device="cpu", device_steps=False, smoothness=1e-3).solve_sequence(frames)
    device = Solver(rig, rig.landmarks, device="cpu", device_steps=True, smoothness=1e-3).solve_sequence(frames)
    assert_same(host, device, rig_scale(rig))


def test_device_steps_closed_loop(rig, model):
    """Ground truth: dense targets of random expressions are recovered by the on-device iteration."""
    rng = np.random.default_rng(11)
    iod = rig_scale(rig)
    truths = np.stack([random_controls(rig, rng, count=4, high=0.15) for _ in range(4)])
    shapes = model.evaluate_batch(truths).astype(np.float64)
    batch = Solver(rig, device="cpu", device_steps=True).solve_batch(shapes)
    assert batch.converged.all()
    for f, shape in enumerate(shapes):
        points = model.evaluate(batch.controls[f])
        assert np.linalg.norm(points - shape, axis=1).mean() < 1e-3 * iod
    single = fit(rig, shapes[0], device="cpu", device_steps=True)
    assert single.converged and single.residual < 1e-3 * iod


def test_device_steps_option_is_checked(rig):
    with pytest.raises(TypeError, match="device_steps"):
        Solver(rig, rig.landmarks, device="cpu", device_steps="yes")
