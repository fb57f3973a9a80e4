"""warpface.solve: the local model against the full pipeline, and closed loops with ground truth."""

from __future__ import annotations

import numpy as np
import pytest
import solve_reference as reference

from warpface.assets import default_rig, expression_timeline, rig_scale
from warpface.expression import SphincterMuscle
from warpface.solve import LocalExpression, Solver, fit
from warpface.solve.pose import rotation_from_vector
from warpface.solve.solver import rig_operators


@pytest.fixture(scope="module")
def rig():
    return default_rig(device="cpu", anatomy="classic")  # the closed loops were tuned on the classic rig


@pytest.fixture(scope="module")
def model(rig):
    return rig.model(device="cpu")


def random_controls(rig, rng, count=5, low=0.03, high=0.15):
    """Sparse random contractions: ``count`` muscles at [low, high] inter-ocular units (sphincters dimensionless)."""
    scale = rig_scale(rig)
    controls = np.zeros(len(rig.muscles))
    for m in rng.choice(len(rig.muscles), count, replace=False):
        controls[m] = rng.uniform(low, high) * (1.0 if isinstance(rig.muscles[m], SphincterMuscle) else scale)
    return controls


def test_local_model_matches_full_pipeline_and_finite_differences(rig, model, rng):
    controls = random_controls(rig, rng, count=len(rig.muscles))
    local = LocalExpression(rig_operators(rig, "cpu"), rig.landmarks, device="cpu")
    x, jac = local.evaluate(controls[None])
    full = model.evaluate(controls)
    assert np.abs(x[0] - full[local.vertices]).max() < 1e-6 * rig_scale(rig)
    # float64 central differences of the same forward pass (every control is interior here, so the
    # wrinkle factor's kink at r = 1 is not crossed)
    step = 1e-6 * rig_scale(rig)
    for m in range(len(controls)):
        plus, minus = controls.copy(), controls.copy()
        plus[m] += step
        minus[m] -= step
        difference = (
            local.evaluate(plus[None], jacobian=False)[0] - local.evaluate(minus[None], jacobian=False)[0]
        ) / (2 * step)
        assert np.allclose(jac[..., m], difference, atol=1e-6, rtol=1e-5), rig.muscles[m].name


def test_kernels_match_numpy_reference(rig, rng):
    controls = np.stack([random_controls(rig, rng, count=len(rig.muscles)) for _ in range(3)])
    vertices = rng.choice(rig.mesh.vertex_count, 300, replace=False)
    kernel = LocalExpression(rig_operators(rig, "cpu"), vertices, device="cpu")
    x, jac = reference.evaluate(kernel.neighbourhood, controls)
    xk, jack = kernel.evaluate(controls)
    assert np.abs(x - xk).max() < 1e-12
    assert np.abs(jac - jack).max() < 1e-10
    assert np.abs(kernel.evaluate(controls, jacobian=False)[0] - x).max() < 1e-12


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_dense_closed_loop_recovers_surface(rig, model, seed):
    rng = np.random.default_rng(seed)
    truth = random_controls(rig, rng)
    target = model.evaluate(truth).astype(np.float64)
    result = fit(rig, target, device="cpu")
    iod = rig_scale(rig)
    error = np.linalg.norm(result.points - target, axis=1).mean()
    assert result.converged
    assert error < 1e-3 * iod
    assert result.residual < 1e-3 * iod
    assert np.all(np.isfinite(result.points))
    assert set(result.controls) == set(rig.muscle_names)


def test_dense_closed_loop_large_expressions(rig, model):
    """Six muscles up to 0.3 inter-ocular units each (seed 118: a mentalis a Gauss–Newton start from
    neutral with little damping fits in the wrong basin)."""
    iod = rig_scale(rig)
    for seed in range(110, 120):
        rng = np.random.default_rng(seed)
        truth = np.zeros(len(rig.muscles))
        for m in rng.choice(len(rig.muscles), 6, replace=False):
            truth[m] = rng.uniform(0.0, 0.3) * (1.0 if isinstance(rig.muscles[m], SphincterMuscle) else iod)
        target = model.evaluate(truth).astype(np.float64)
        result = fit(rig, target, device="cpu")
        assert np.linalg.norm(result.points - target, axis=1).mean() < 1e-4 * iod, seed


def test_landmark_closed_loop(rig, model):
    rng = np.random.default_rng(7)
    truth = random_controls(rig, rng)
    target = model.evaluate(truth).astype(np.float64)
    # the plain ridge: fit's sparse-target prior (FIT_RIDGE_POINTS) trades exactness on exact data for reach on real
    # shapes (docs/RIG.md §13), which is not what a closed loop checks
    result = fit(rig, target[rig.landmarks], vertices=rig.landmarks, device="cpu", ridge_points=1)
    iod = rig_scale(rig)
    surface = np.linalg.norm(result.points - target, axis=1).mean()
    print(f"landmark-only closed loop: landmark RMS {result.residual / iod:.2e}, surface mean {surface / iod:.2e} IOD")
    assert result.residual < 1e-3 * iod
    assert surface < 1e-2 * iod


def test_sparse_targets_get_the_ridge_scaled_by_their_count(rig, model):
    from warpface.solve import SolveOptions
    from warpface.solve.solver import FIT_RIDGE_POINTS

    rng = np.random.default_rng(11)
    target = model.evaluate(random_controls(rig, rng)).astype(np.float64)
    sparse = target[rig.landmarks]
    scaled = fit(rig, sparse, vertices=rig.landmarks, device="cpu")
    # the same fit written out by hand: a plain ridge of l2·N₀/N
    by_hand = fit(rig, sparse, vertices=rig.landmarks, device="cpu", ridge_points=1, l2=1e-6 * FIT_RIDGE_POINTS / 68)
    assert np.allclose(scaled.vector, by_hand.vector, rtol=0.0, atol=1e-9)
    plain = fit(rig, sparse, vertices=rig.landmarks, device="cpu", ridge_points=1)
    assert np.sum(scaled.vector**2) < np.sum(plain.vector**2)  # a stronger ridge holds the loose controls back
    # a dense face gets the same prior against its summed error: l2·N₀/V; a Solver keeps l2 for any count
    count = rig.mesh.vertex_count
    assert count < FIT_RIDGE_POINTS
    dense = fit(rig, target, device="cpu")
    by_hand = fit(rig, target, device="cpu", ridge_points=1, l2=1e-6 * FIT_RIDGE_POINTS / count)
    assert np.allclose(dense.vector, by_hand.vector, rtol=0.0, atol=1e-9)
    assert Solver(rig, None, device="cpu", ridge_points=count // 2).ridge == SolveOptions().l2  # denser than N₀
    assert Solver(rig, rig.landmarks, device="cpu").ridge == SolveOptions().l2
    assert Solver(rig, rig.landmarks, device="cpu", ridge_points=680, l2=1e-5).ridge == pytest.approx(1e-4)
    with pytest.raises(ValueError, match="ridge_points"):
        fit(rig, sparse, vertices=rig.landmarks, ridge_points=0)
    with pytest.raises(TypeError, match="ridge_points"):
        fit(rig, sparse, vertices=rig.landmarks, ridge_points=2.5)


def test_surface_points_closed_loop(rig, model, rng):
    truth = random_controls(rig, rng)
    points = model.evaluate(truth).astype(np.float64)
    triangles = rng.choice(rig.mesh.triangle_count, 200, replace=False)
    bary = rng.dirichlet([1.0, 1.0, 1.0], 200)
    target = np.einsum("nk,nki->ni", bary, points[rig.mesh.triangles[triangles]])
    # exact data: the plain ridge (fit's sparse-target prior biases an exact loop, docs/RIG.md §13)
    result = fit(rig, target, triangles=triangles, barycentrics=bary, device="cpu", ridge_points=1)
    assert result.residual < 1e-3 * rig_scale(rig)


def test_warm_start_and_temporal_sequence(rig, model):
    timeline = expression_timeline("smile", rig, seconds=0.5, fps=30.0)
    frames = model.evaluate(timeline).astype(np.float64)[:, rig.landmarks]
    solver = Solver(rig, rig.landmarks, device="cpu")
    warm = [solver.solve(frame) for frame in frames]
    cold = [Solver(rig, rig.landmarks, device="cpu").solve(frame) for frame in frames[5:8]]
    assert all(f.converged for f in warm)
    assert sum(f.iterations for f in warm[5:8]) < sum(f.iterations for f in cold)
    again = solver.solve(frames[-1])  # the same target as the previous call: nothing left to do
    assert again.iterations <= 2
    iod = rig_scale(rig)
    assert max(f.residual for f in warm) < 1e-3 * iod
    sequence = Solver(rig, rig.landmarks, device="cpu").solve_sequence(frames)
    assert np.allclose(sequence.controls, np.stack([f.vector for f in warm]), atol=1e-12)
    assert np.array_equal(sequence.iterations, [f.iterations for f in warm])
    # A heavy temporal term holds a frame near the previous frame's controls (here: neutral).
    peak = frames[len(frames) // 2]
    free = Solver(rig, rig.landmarks, device="cpu").solve(peak)
    held = Solver(rig, rig.landmarks, device="cpu", smoothness=1e2).solve(peak)
    assert np.abs(held.vector).max() < 0.5 * np.abs(free.vector).max()


def test_batched_equals_per_frame(rig, model, rng):
    truths = np.stack([random_controls(rig, rng) for _ in range(5)])
    frames = model.evaluate(truths).astype(np.float64)[:, rig.landmarks]
    frames[2, 3:9] = np.nan
    solver = Solver(rig, rig.landmarks, device="cpu")
    batch = solver.solve_batch(frames)
    for f in range(len(frames)):
        single = Solver(rig, rig.landmarks, device="cpu").solve(frames[f])
        assert np.allclose(batch.controls[f], single.vector, atol=1e-9 * rig_scale(rig), rtol=1e-6)
        assert batch.converged[f] == single.converged
        assert abs(batch.residual[f] - single.residual) < 1e-6 * rig_scale(rig)
    assert batch.mapping(0).keys() == set(rig.muscle_names)


def test_nan_targets_are_dropped_and_empty_frames_keep_previous(rig, model, rng):
    truth = random_controls(rig, rng)
    target = model.evaluate(truth).astype(np.float64)[rig.landmarks]
    holed = target.copy()
    holed[rng.choice(68, 20, replace=False)] = np.nan
    solver = Solver(rig, rig.landmarks, device="cpu")
    result = solver.solve(holed)
    assert result.valid_points == 48 and not result.skipped
    assert result.residual < 1e-3 * rig_scale(rig)
    previous = result.vector.copy()
    empty = np.full_like(target, np.nan)
    empty[:2] = target[:2]
    flagged = solver.solve(empty)
    assert flagged.skipped and not flagged.converged
    assert np.array_equal(flagged.vector, previous)
    assert np.isfinite(flagged.residual) and np.all(np.isfinite(flagged.points))


def test_bounds_hold(rig, model):
    # A target that only a negative (pushing) linear contraction and an over-full sphincter could reach.
    names = rig.muscle_names
    iod = rig_scale(rig)
    reach = np.zeros(len(names))
    reach[names.index("zygomaticus_major_L")] = -0.1 * iod
    reach[names.index("orbicularis_oris")] = 1.6
    target = model.evaluate(reach).astype(np.float64)
    result = fit(rig, target, device="cpu")
    assert result.vector.min() >= 0.0
    assert result.controls["orbicularis_oris"] <= 1.0 + 1e-12
    capped = fit(rig, target, device="cpu", bounds={"orbicularis_oris": (0.0, 0.5)})
    assert capped.controls["orbicularis_oris"] <= 0.5 + 1e-12
    assert np.all(np.isfinite(capped.points))


def test_symmetry_pulls_pairs_together(rig, model):
    names = rig.muscle_names
    iod = rig_scale(rig)
    truth = np.zeros(len(names))
    truth[names.index("zygomaticus_major_L")] = 0.15 * iod
    truth[names.index("zygomaticus_major_R")] = 0.05 * iod
    target = model.evaluate(truth).astype(np.float64)[rig.landmarks]
    free = fit(rig, target, vertices=rig.landmarks, device="cpu")
    tied = fit(rig, target, vertices=rig.landmarks, device="cpu", symmetry=10.0)
    gap = lambda r: abs(r.controls["zygomaticus_major_L"] - r.controls["zygomaticus_major_R"])  # noqa: E731
    assert gap(tied) < 0.2 * gap(free)


def test_head_pose_is_recovered(rig, model):
    names = rig.muscle_names
    truth = np.zeros(len(names))
    truth[names.index("frontalis_inner_L")] = 0.1 * rig_scale(rig)
    points = model.evaluate(truth).astype(np.float64)[rig.landmarks]
    rotation = rotation_from_vector(np.array([[0.15, -0.2, 0.05]]))[0]
    shift = np.array([0.01, -0.02, 0.03])
    target = points @ rotation.T + shift
    result = fit(rig, target, vertices=rig.landmarks, device="cpu", pose=True, ridge_points=1)  # exact: plain ridge
    assert result.converged
    assert result.residual < 1e-3 * rig_scale(rig)
    posed = result.posed_points[rig.landmarks]
    assert np.abs(posed - target).max() < 1e-3 * rig_scale(rig)
    assert np.abs(result.rotation - rotation).max() < 1e-3


def test_non_convergence_returns_best_iterate(rig, model, rng):
    truth = random_controls(rig, rng)
    target = model.evaluate(truth).astype(np.float64)[rig.landmarks]
    result = fit(rig, target, vertices=rig.landmarks, device="cpu", max_iterations=1)
    assert not result.converged
    start = fit(rig, np.asarray(rig.mesh.points[rig.landmarks]), vertices=rig.landmarks, device="cpu")
    assert np.isfinite(result.residual) and result.residual <= np.sqrt(
        np.mean(np.sum((target - start.points[rig.landmarks]) ** 2, axis=1))
    )


@pytest.mark.parametrize("pose", [False, True])
def test_device_normal_equations_match_numpy_reference(rig, rng, pose):
    from warpface.solve.objective import DeviceObjective
    from warpface.solve.pose import skew
    from warpface.solve.targets import observation

    triangles = rng.choice(rig.mesh.triangle_count, 40, replace=False)
    bary = rng.dirichlet([1.0, 1.0, 1.0], 40)
    obs = observation(rig.mesh, triangles=triangles, barycentrics=bary)
    kernel = LocalExpression(rig_operators(rig, "cpu"), obs.vertices, device="cpu")
    unit, origin = 0.06, obs.apply(rig.mesh.points).mean(axis=0)
    objective = DeviceObjective(kernel, obs, pose=pose, origin=origin, unit=unit)
    frames = 3
    controls = np.stack([random_controls(rig, rng, count=8) for _ in range(frames)])
    rotation = rotation_from_vector(rng.normal(scale=0.1, size=(frames, 3)))
    translation = rng.normal(scale=0.05, size=(frames, 3))
    if not pose:  # the solver passes the identity pose then
        rotation, translation = np.tile(np.eye(3), (frames, 1, 1)), np.zeros((frames, 3))
    targets = rng.normal(size=(frames, obs.count, 3))
    weights = rng.uniform(0.0, 1.0, (frames, obs.count))
    weights[1, :5] = 0.0
    objective.bind(targets, weights)
    on = np.array([True, True, False])
    misfit, hessian, gradient = objective.evaluate(controls, rotation, translation, on, jacobian=True)

    x, dx = reference.evaluate(kernel.neighbourhood, controls)  # NumPy float64 reference
    observed, jac = obs.apply_frames(x), obs.apply_frames(dx)  # (F, N, 3), (F, N, 3, M)
    arm = np.einsum("fij,fnj->fni", rotation, observed - origin)
    e = (arm + origin) / unit + translation[:, None] - targets
    columns = np.einsum("fij,fnjm->fnim", rotation, jac)
    if pose:
        lever = -skew(arm)
        columns = np.concatenate([columns, lever, np.broadcast_to(unit * np.eye(3), lever.shape)], axis=3)
    for f in range(frames):
        if not on[f]:
            assert misfit[f] == 0.0 and not hessian[f].any()
            continue
        w = np.repeat(weights[f], 3)
        flat = columns[f].reshape(-1, columns.shape[3])
        assert misfit[f] == pytest.approx(np.sum(weights[f] * np.sum(e[f] ** 2, axis=1)), rel=1e-12)
        assert np.allclose(hessian[f], flat.T @ (w[:, None] * flat), rtol=1e-10, atol=1e-12 * np.abs(hessian[f]).max())
        assert np.allclose(gradient[f], flat.T @ (w * e[f].ravel()), rtol=1e-10, atol=1e-12 * np.abs(gradient[f]).max())


@pytest.mark.slow  # four solvers of the full 86-control rig, ~45 s on the 2-core CI machine
def test_trackers_hold_the_lip_hinges_and_fit_frees_them():
    """A :class:`Solver` (the trackers) holds the lip hinges at rest unless asked (docs/RIG.md §15); ``fit`` and
    ``bounds`` free them: a rolled-in upper lip's landmarks are reached only where they are free."""
    from warpface.assets.rig import BODY_CONTROL_NAMES

    rig = default_rig(device="cpu")
    rolled = {"lip_upper_roll_in_L": 0.8, "lip_upper_roll_in_R": 0.8}
    target = np.asarray(rig.model(device="cpu").evaluate(rolled), dtype=np.float64)[rig.landmarks]
    held = Solver(rig, rig.landmarks, device="cpu").solve(target)
    assert all(held.controls[name] == 0.0 for name in BODY_CONTROL_NAMES)  # and the slides and corners (§16–17)
    for solved in (
        fit(rig, target, vertices=rig.landmarks, device="cpu"),
        Solver(rig, rig.landmarks, device="cpu", lip_rolls=True).solve(target),
        Solver(rig, rig.landmarks, device="cpu", bounds={name: (0.0, 1.0) for name in rolled}).solve(target),
    ):
        assert solved.controls["lip_upper_roll_in_L"] > 0.5
        assert solved.residual < 0.2 * held.residual
