"""warpface.solve with the jaw's controls: exact Jacobian columns and closed loops on the built-in face."""

from __future__ import annotations

import numpy as np
import pytest
import solve_reference as reference

from warpface.assets import default_rig, rig_scale
from warpface.assets.rig import BODY_CONTROL_NAMES
from warpface.expression import JAW_CONTROL_NAMES, SphincterMuscle
from warpface.solve import LocalExpression, fit
from warpface.solve.solver import rig_operators


@pytest.fixture(scope="module")
def rig():
    made = default_rig(device="cpu")
    assert made.jaw is not None
    return made


@pytest.fixture(scope="module")
def model(rig):
    return rig.model(device="cpu")


def controls_with_jaw(rig, rng, count=6, jaw=(0.18, 0.02, -0.015)):
    """Sparse muscle contractions in (0.03, 0.1) face units (sphincters dimensionless), then the jaw's
    opening [rad] and slides [face units]; every muscle value is away from 0 (the wrinkle and sliding
    terms have kinks at rest)."""
    scale = rig_scale(rig)
    controls = np.zeros(len(rig.control_names))
    # a sparse draw leaves the lips' and corners' body controls (docs/RIG.md §15–17) at rest: the draw the tests were
    # written with
    drawn = [m for m, muscle in enumerate(rig.muscles) if muscle.name not in BODY_CONTROL_NAMES]
    drawn = drawn if count <= len(drawn) else np.arange(len(rig.muscles))
    for m in rng.choice(drawn, count, replace=False):
        controls[m] = rng.uniform(0.03, 0.1) * (1.0 if isinstance(rig.muscles[m], SphincterMuscle) else scale)
    controls[len(rig.muscles) :] = np.array(jaw) * np.array([1.0, scale, scale])
    return controls


def test_control_order_names_the_jaw_last(rig):
    assert rig.control_names[-3:] == list(JAW_CONTROL_NAMES)


def test_jaw_columns_match_the_full_model_and_finite_differences(rig, model, rng):
    controls = controls_with_jaw(rig, rng, count=len(rig.muscles))
    local = LocalExpression(rig_operators(rig, "cpu"), rig.landmarks, device="cpu")
    assert local.control_count == len(rig.control_names)
    x, jacobian = local.evaluate(controls[None])
    full = np.asarray(model.evaluate(controls), dtype=np.float64)
    scale = rig_scale(rig)
    assert np.abs(x[0] - full[local.vertices]).max() < 1e-5 * scale  # float32 model vs float64
    muscles = len(rig.muscles)
    for column, step in zip(range(muscles, muscles + 3), (1e-4, 3e-4 * scale, 3e-4 * scale)):
        plus, minus = controls.copy(), controls.copy()
        plus[column] += step
        minus[column] -= step
        difference = (
            local.evaluate(plus[None], jacobian=False)[0] - local.evaluate(minus[None], jacobian=False)[0]
        ) / (2 * step)
        size = np.abs(jacobian[..., column]).max()
        assert size > 1e-3 * (1.0 if column > muscles else scale)  # the jaw moves the landmarks
        assert np.abs(difference - jacobian[..., column]).max() < 1e-5 * size, rig.control_names[column]
    # The angle column is the chain rule of the rotation, not the displacement at θ = 0.
    at_rest = controls.copy()
    at_rest[muscles] = 0.0
    assert np.abs(local.evaluate(at_rest[None])[1][..., muscles] - jacobian[..., muscles]).max() > 1e-3 * size


def test_kernel_evaluation_matches_numpy_with_the_jaw(rig, rng):
    # Every muscle on: at rest a rigidly moved vertex has stretch exactly 1, where the wrinkle factor of a
    # kr = 0 wrinkle has a kink and float rounding may pick either side.
    every = len(rig.muscles)
    controls = np.stack(
        [controls_with_jaw(rig, rng, count=every), controls_with_jaw(rig, rng, count=every, jaw=(0.35, -0.03, 0.04))]
    )
    kernel = LocalExpression(rig_operators(rig, "cpu"), rig.landmarks, device="cpu")
    x, jacobian = reference.evaluate(kernel.neighbourhood, controls)
    xk, jacobian_k = kernel.evaluate(controls)
    assert np.abs(x - xk).max() < 1e-12
    assert np.abs(jacobian - jacobian_k).max() < 1e-9 * np.abs(jacobian).max()


def test_device_normal_equations_with_the_jaw_match_numpy(rig, rng):
    """The normal equations take the jaw's chain rule from the per-basis derivatives themselves and sum the
    upper triangle only: against ``JᵀWJ``, ``JᵀWe`` of the NumPy Jacobian (per control) of the same points."""
    from warpface.solve.objective import DeviceObjective
    from warpface.solve.targets import observation

    every = len(rig.muscles)
    controls = np.stack(
        [controls_with_jaw(rig, rng, count=every), controls_with_jaw(rig, rng, count=every, jaw=(0.35, -0.03, 0.04))]
    )
    obs = observation(rig.mesh, vertices=rig.landmarks)
    local = LocalExpression(rig_operators(rig, "cpu"), obs.vertices, device="cpu")
    unit = rig_scale(rig)
    objective = DeviceObjective(local, obs, pose=False, origin=np.zeros(3), unit=unit)
    frames = len(controls)
    targets = rng.normal(size=(frames, obs.count, 3))
    weights = rng.uniform(0.1, 1.0, (frames, obs.count))
    objective.bind(targets, weights)
    identity = np.tile(np.eye(3), (frames, 1, 1))
    misfit, hessian, gradient = objective.evaluate(
        controls, identity, np.zeros((frames, 3)), np.ones(frames, bool), jacobian=True
    )
    x, dx = reference.evaluate(local.neighbourhood, controls)
    e = obs.apply_frames(x) / unit - targets
    columns = obs.apply_frames(dx)  # (F, N, 3, C)
    jaw_open = every
    for f in range(frames):
        w = np.repeat(weights[f], 3)
        flat = columns[f].reshape(-1, columns.shape[3])
        expected = flat.T @ (w[:, None] * flat)
        assert np.abs(expected[jaw_open, jaw_open]) > 0.0  # the jaw's columns take part
        np.testing.assert_array_equal(hessian[f], hessian[f].T)
        assert np.allclose(hessian[f], expected, rtol=1e-9, atol=1e-10 * np.abs(expected).max())
        assert np.allclose(gradient[f], flat.T @ (w * e[f].ravel()), rtol=1e-9, atol=1e-10 * np.abs(gradient[f]).max())
        assert misfit[f] == pytest.approx(np.sum(weights[f] * np.sum(e[f] ** 2, axis=1)), rel=1e-12)


@pytest.mark.parametrize("landmarks_only", [False, True])
def test_closed_loop_recovers_jaw_and_muscles(rig, model, rng, landmarks_only):
    truth = controls_with_jaw(rig, rng, count=4, jaw=(0.25, 0.03, -0.02))
    target = np.asarray(model.evaluate(truth), dtype=np.float64)
    if landmarks_only:
        # from 68 points a lip's roll-in and roll-out together (their chords' radial part) and its protrusion trade
        # against jaw_forward (docs/RIG.md §15–17): the truth moves no lip or corner as a body, so those are held here
        held = {name: (0.0, 0.0) for name in BODY_CONTROL_NAMES if name in rig.control_names}
        # and the plain ridge: fit's sparse-target prior trades exactness on exact data for reach (docs/RIG.md §13)
        result = fit(rig, target[rig.landmarks], vertices=rig.landmarks, device="cpu", bounds=held, ridge_points=1)
    else:
        result = fit(rig, target, device="cpu")
    scale = rig_scale(rig)
    assert set(JAW_CONTROL_NAMES) <= set(result.controls)
    surface = np.linalg.norm(result.points - target, axis=1)
    if landmarks_only:
        surface = surface[rig.landmarks]
    assert surface.mean() < 1e-3 * scale
    assert abs(result.controls["jaw_open"] - truth[-3]) < 0.01  # [rad]
    assert abs(result.controls["jaw_forward"] - truth[-2]) < 0.01 * scale
    assert abs(result.controls["jaw_left"] - truth[-1]) < 0.01 * scale


def test_jaw_bounds_come_from_its_range_and_hold(rig, model):
    from warpface.expression.jaw import JAW_RANGE

    controls = np.zeros(len(rig.control_names))
    controls[len(rig.muscles)] = 0.5
    target = np.asarray(model.evaluate(controls), dtype=np.float64)
    result = fit(rig, target, device="cpu", bounds={"jaw_open": (0.0, 0.3)})
    assert 0.299 <= result.controls["jaw_open"] <= 0.3 + 1e-12
    assert JAW_RANGE["jaw_open"][0] < 0.0 < JAW_RANGE["jaw_open"][1]


def test_jaw_can_be_left_out_of_the_solve(rig):
    target = np.asarray(rig.mesh.points, dtype=np.float64)[rig.landmarks]
    result = fit(rig, target, vertices=rig.landmarks, device="cpu", jaw=False)
    assert list(result.controls) == rig.muscle_names
    assert result.residual < 1e-6 * rig_scale(rig)
