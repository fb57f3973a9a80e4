"""The solver's Levenberg–Marquardt iteration on the device (``device_steps``) against the NumPy loop, on the CPU.

The default rig has a jaw: the device kernels hand the model its (sin θ, 1 − cos θ, protrusion, slide)
basis, and these tests make sure that path runs (no fallback to the NumPy loop) and matches it.
"""

from __future__ import annotations

import numpy as np
import pytest

from warpface.assets import default_rig, expression_timeline, rig_scale
from warpface.expression import SphincterMuscle
from warpface.solve import Solver, fit
from warpface.solve.device_steps import DeviceSteps
from warpface.solve.host_steps import HostSteps
from warpface.solve.objective import DeviceObjective
from warpface.solve.pose import rotation_from_vector


@pytest.fixture(scope="module")
def rig():
    return default_rig(device="cpu")


@pytest.fixture(scope="module")
def model(rig):
    return rig.model(device="cpu")


def random_controls(rig, rng, count=5, high=0.2, jaw=(0.0, 0.0, 0.0)):
    """Sparse muscle contractions, then the jaw's opening [rad] and slides [face units → mesh units]."""
    controls = np.zeros(len(rig.control_names))
    for m in rng.choice(len(rig.muscles), count, replace=False):
        controls[m] = rng.uniform(0.02, high) * (1.0 if isinstance(rig.muscles[m], SphincterMuscle) else rig_scale(rig))
    controls[len(rig.muscles) :] = np.asarray(jaw) * np.array([1.0, rig_scale(rig), rig_scale(rig)])
    return controls


def assert_same(a, b, solver):
    """Two batch results agree to rounding: same iterations and flags; every control moves the skin by the
    same amount to 1e-11 IOD (the solver's scaled controls, face units: the jaw's angle is in radians);
    residuals and pose to 1e-10."""
    iod = rig_scale(solver.rig)
    assert np.array_equal(a.iterations, b.iterations)
    assert np.array_equal(a.converged, b.converged) and np.array_equal(a.skipped, b.skipped)
    assert (np.abs(a.controls - b.controls) * solver.control_scale).max() < 1e-11
    assert np.abs(a.residual - b.residual).max() < 1e-10 * iod
    assert np.abs(a.rotation - b.rotation).max() < 1e-10
    assert np.abs(a.translation - b.translation).max() < 1e-10 * iod


@pytest.mark.parametrize(
    "options",
    [
        {},
        {"pose": True},
        {"symmetry": 1e-2, "l1": 1e-4},
        {
            "bounds": {
                "orbicularis_oris": (0.0, 0.05),
                "zygomaticus_major_L": (0.0, 1e-3),
                "jaw_open": (0.0, 0.1),
                "jaw_left": (-1e-3, 0.0),
            }
        },
        {"max_iterations": 2},
        {"jaw": False},
    ],
)
def test_device_steps_match_host_loop(rig, model, options):
    rng = np.random.default_rng(3)
    jaws = [
        (0.0, 0.0, 0.0),
        (0.2, 0.0, 0.0),
        (0.0, 0.0, 0.0),
        (0.35, 0.02, 0.0),
        (0.0, 0.0, 0.0),
        (0.0, 0.0, 0.0),
        (0.1, 0.0, 0.03),
        (0.0, 0.0, 0.0),
        (0.25, -0.02, -0.02),
    ]
    truths = np.stack([random_controls(rig, rng, jaw=jaw) for jaw in jaws])
    truths[4, rig.muscle_names.index("orbicularis_oris")] = 0.4
    frames = model.evaluate(truths).astype(np.float64)[:, rig.landmarks]
    frames[2, 3:30] = np.nan
    frames[5] = np.nan  # skipped: keeps the start
    if options.get("pose"):
        rotation = rotation_from_vector(np.array([[0.1, -0.15, 0.05]]))[0]
        frames = frames @ rotation.T + np.array([0.004, -0.01, 0.02])
    host_solver = Solver(rig, rig.landmarks, device="cpu", device_steps=False, **options)
    device_solver = Solver(rig, rig.landmarks, device="cpu", device_steps=True, **options)
    assert isinstance(host_solver.steps, HostSteps) and isinstance(device_solver.steps, DeviceSteps)
    host, device = host_solver.solve_batch(frames), device_solver.solve_batch(frames)
    assert_same(host, device, device_solver)
    assert device.skipped[5] and not device.converged[5] and np.all(device.controls[5] == 0.0)
    assert np.all(np.isfinite(device.controls)) and np.all(np.isfinite(device.residual))
    if "bounds" in options:
        names = device.names
        assert device.controls[:, names.index("orbicularis_oris")].max() <= 0.05 + 1e-12
        assert device.controls[:, names.index("jaw_open")].min() >= 0.0
        assert device.controls[:, names.index("jaw_open")].max() <= 0.1 + 1e-12
        assert -1e-3 - 1e-12 <= device.controls[:, names.index("jaw_left")].min()
        assert device.controls[:, names.index("jaw_left")].max() <= 0.0
        assert np.isclose(device.controls[3, names.index("jaw_open")], 0.1)  # truth 0.35: held at the bound
    if options.get("jaw") is False:
        assert device.names == rig.muscle_names
    if options.get("max_iterations") == 2:
        assert not device.converged.all() and np.all(device.iterations <= 2)


def test_device_steps_sequence_matches_host_loop(rig, model):
    """Warm-started, smoothed frame after frame: the constant-velocity guess and the temporal anchor."""
    timeline = expression_timeline("smile", rig, seconds=0.4, fps=30.0)
    opening = np.linspace(0.0, 0.3, len(timeline))[:, None] * (np.arange(3) == 0)
    frames = model.evaluate(np.concatenate([timeline, opening], axis=1)).astype(np.float64)[:, rig.landmarks]
    host = Solver(rig, rig.landmarks, device="cpu", device_steps=False, smoothness=1e-3).solve_sequence(frames)
    solver = Solver(rig, rig.landmarks, device="cpu", device_steps=True, smoothness=1e-3)
    device = solver.solve_sequence(frames)
    assert_same(host, device, solver)
    # The smoothed ramp lags by a little (the calibrated rig's orbicularis oris shares the chin's motion with the
    # jaw: 2.3e-3 rad at the last frame, 1.8e-3 with the hand-placed anatomy).
    assert np.abs(device.controls[:, device.names.index("jaw_open")] - opening[:, 0]).max() < 3e-3  # [rad]


def test_device_steps_closed_loop(rig, model):
    """Ground truth: dense targets of random expressions are recovered by the on-device iteration."""
    rng = np.random.default_rng(11)
    iod = rig_scale(rig)
    truths = np.stack([random_controls(rig, rng, count=4, high=0.15) for _ in range(4)])
    shapes = model.evaluate(truths).astype(np.float64)
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


def test_default_rig_takes_the_device_path(rig, model, monkeypatch):
    """No silent fallback: with the jaw on, a batched and a sequential solve never touch the NumPy loop
    nor the host evaluation of the data term (the device loop only launches the recorded kernels)."""
    assert rig.jaw is not None
    solver = Solver(rig, rig.landmarks, device="cpu")
    assert isinstance(solver.steps, DeviceSteps) and solver.names[-3:] == ["jaw_open", "jaw_forward", "jaw_left"]
    assert solver.steps.basis_count == solver.steps.control_count + 1  # θ enters the model as sin θ, 1 − cos θ

    def refuse(*args, **kwargs):
        raise AssertionError("fell back to the host iteration")

    monkeypatch.setattr(HostSteps, "run", refuse)
    monkeypatch.setattr(DeviceObjective, "evaluate", refuse)
    truth = random_controls(rig, np.random.default_rng(5), count=3, jaw=(0.3, 0.0, 0.0))
    target = np.asarray(model.evaluate(truth), dtype=np.float64)[rig.landmarks]
    batch = solver.solve_batch(np.stack([target, target]))
    assert batch.converged.all() and abs(batch.controls[0, -3] - 0.3) < 2e-3
    single = solver.solve(target)
    assert single.converged and abs(single.controls["jaw_open"] - 0.3) < 2e-3


def test_device_closed_loop_with_the_jaw(rig, model):
    """Ground truth: random sparse contractions with the jaw open (and slid) → 68 landmarks → a batched
    on-device solve recovers the controls, and the NumPy loop finds the same to rounding."""
    rng = np.random.default_rng(21)
    iod = rig_scale(rig)
    jaws = [(rng.uniform(0.05, 0.4), rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03)) for _ in range(6)]
    truths = np.stack([random_controls(rig, rng, count=3, high=0.12, jaw=jaw) for jaw in jaws])
    shapes = model.evaluate(truths).astype(np.float64)
    solver = Solver(rig, rig.landmarks, device="cpu")
    batch = solver.solve_batch(shapes[:, rig.landmarks])
    host = Solver(rig, rig.landmarks, device="cpu", device_steps=False).solve_batch(shapes[:, rig.landmarks])
    assert_same(host, batch, solver)
    assert batch.converged.all()
    muscles = len(rig.muscles)
    for f in range(len(truths)):
        points = model.evaluate(batch.controls[f])[rig.landmarks]
        assert np.linalg.norm(points - shapes[f, rig.landmarks], axis=1).mean() < 1e-3 * iod
    assert np.abs(batch.controls[:, muscles] - truths[:, muscles]).max() < 5e-3  # jaw_open [rad]
    assert np.abs(batch.controls[:, muscles + 1 :] - truths[:, muscles + 1 :]).max() < 5e-3 * iod
