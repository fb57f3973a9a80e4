"""ExpressionModel against the independent float64 reference, and the properties SPEC §1 states."""

from __future__ import annotations

import numpy as np
import pytest
import reference_expression as ref
import warp as wp
from helpers import grid_surface

import warpface as wf
from warpface.expression import bezier_distances, project_points
from warpface.expression.kernels import contraction_factor


def random_rig(rng, n=22):
    """A random wavy patch with random linear/sphincter muscles and planar/cylindrical wrinkles.

    Returns the warpface objects and the same parameters as plain dicts for the reference.
    """
    points, triangles = grid_surface(n, seed=int(rng.integers(1 << 30)))
    muscles, spec_muscles = [], []
    for i in range(5):
        v1 = np.r_[rng.uniform(-0.8, 0.8, 2), -0.6]
        v2 = np.r_[rng.uniform(-0.8, 0.8, 2), 0.1]
        zone, rs = rng.uniform(20, 70), rng.uniform(0.1, 0.6)
        rf = rs + rng.uniform(0.3, 1.2)
        muscles.append(wf.LinearMuscle(f"lin{i}", v1, v2, zone, rs, rf))
        spec_muscles.append(dict(kind="linear", v1=v1, v2=v2, zone=zone, rs=rs, rf=rf))
    for i in range(2):
        center = np.r_[rng.uniform(-0.5, 0.5, 2), 0.0]
        angle = rng.uniform(0, np.pi)
        ex = np.array([np.cos(angle), np.sin(angle), 0.1])
        ey = np.array([-np.sin(angle), np.cos(angle), 0.0])
        lx, ly = rng.uniform(0.2, 0.6, 2)
        muscles.append(wf.SphincterMuscle(f"sph{i}", center, ex, ey, (lx, ly)))
        spec_muscles.append(dict(kind="sphincter", center=center, ex=ex, ey=ey, lx=lx, ly=ly))
    wrinkles, spec_wrinkles = [], []
    for i in range(4):
        control = rng.uniform(-0.9, 0.9, (4, 2))
        kd, kw, kr = rng.uniform(0.01, 0.05), rng.uniform(0.04, 0.15), [0.0, 0.35][i % 2]
        if i < 2:
            origin, u, v = rng.normal(size=3) * 0.1, np.array([1.0, 0.1, 0.0]), np.array([0.0, 1.0, 0.2])
            projection = wf.PlanarProjection(origin, u, v)
            spec_projection = dict(kind="planar", origin=origin, u=u, v=v)
        else:
            origin, axis, reference = np.array([0.0, 0.0, -1.5]), np.array([0.0, 1.0, 0.0]), np.array([0.1, 0.0, 1.0])
            projection = wf.CylindricalProjection(origin, axis, reference, 1.5)
            spec_projection = dict(kind="cylindrical", origin=origin, axis=axis, reference=reference, radius=1.5)
        wrinkles.append(wf.Wrinkle(f"w{i}", control, projection, kd, kw, kr))
        spec_wrinkles.append(dict(projection=spec_projection, control=control, kd=kd, kw=kw, kr=kr))
    thickness = rng.uniform(0.02, 0.08, len(points))
    contractions = np.r_[rng.uniform(0.05, 0.15, 5), rng.uniform(0.2, 0.5, 2)]
    mesh = wf.FaceMesh(points, triangles)
    return mesh, muscles, wrinkles, thickness, contractions, spec_muscles, spec_wrinkles


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_every_stage_matches_float64_reference(seed):
    rng = np.random.default_rng(seed)
    mesh, muscles, wrinkles, thickness, contractions, spec_muscles, spec_wrinkles = random_rig(rng)
    model = wf.ExpressionModel(mesh, muscles, wrinkles, thickness, device="cpu")
    got = model.stages(contractions)
    expected = ref.evaluate(mesh.points, mesh.triangles, spec_muscles, contractions, spec_wrinkles, thickness)
    assert expected["stretch"].min() < 0.9 and expected["stretch"].max() > 1.1, (
        "the random rig should compress and stretch"
    )
    for stage in ("muscle", "bulge", "final"):
        displacement = expected[stage] - mesh.points
        error = np.abs(got[stage] - expected[stage]).max() / np.abs(displacement).max()
        assert error <= 1e-5, f"{stage}: relative error {error:.2e}"
    assert np.abs(got["stretch"] - expected["stretch"]).max() <= 1e-5
    assert np.all(np.isfinite(got.final))


@pytest.mark.parametrize("frames_per_launch", [None, 1, 2, 5])
def test_batch_equals_single_frames(rng, frames_per_launch):
    """Several frames per launch (the CUDA default, a partial last chunk with 2) equal single frames bit for bit."""
    mesh, muscles, wrinkles, thickness, contractions, *_ = random_rig(rng, n=12)
    model = wf.ExpressionModel(mesh, muscles, wrinkles, thickness, device="cpu")
    frames = np.outer(np.linspace(0, 1, 5), contractions)
    depths = np.outer(np.linspace(1, 2, 5), model.default_depths)
    batch = model.evaluate(frames, wrinkle_depths=depths, frames_per_launch=frames_per_launch)
    for i in range(5):
        np.testing.assert_array_equal(batch[i], model.evaluate(frames[i], wrinkle_depths=depths[i]))


def test_frames_per_launch_beyond_32_bit_thread_indices_is_refused(rng):
    mesh, muscles, wrinkles, thickness, contractions, *_ = random_rig(rng, n=6)
    model = wf.ExpressionModel(mesh, muscles, wrinkles, thickness, device="cpu")
    too_many = (1 << 31) // mesh.triangle_count + 1
    with pytest.raises(ValueError, match="exceeds one launch"):
        model.evaluate(contractions[None], frames_per_launch=too_many)


@pytest.mark.parametrize("bad", [0, -1, 1.5, "2"])
def test_frames_per_launch_must_be_positive_integer(rng, bad):
    mesh, muscles, wrinkles, thickness, contractions, *_ = random_rig(rng, n=6)
    model = wf.ExpressionModel(mesh, muscles, wrinkles, thickness, device="cpu")
    with pytest.raises(ValueError if isinstance(bad, int) else TypeError, match="frames_per_launch"):
        model.evaluate(contractions[None], frames_per_launch=bad)


def test_named_contractions_equal_ordered_array(rng):
    mesh, muscles, wrinkles, thickness, contractions, *_ = random_rig(rng, n=10)
    model = wf.ExpressionModel(mesh, muscles, wrinkles, thickness, device="cpu")
    by_name = model.evaluate(dict(zip(model.muscle_names, contractions)))
    np.testing.assert_array_equal(by_name, model.evaluate(contractions))


def test_zero_contraction_is_identity(rng):
    mesh, muscles, wrinkles, thickness, *_ = random_rig(rng, n=12)
    flat_wrinkles = [wf.Wrinkle(w.name, w.control_points, w.projection, w.depth, w.width, 0.0) for w in wrinkles]
    model = wf.ExpressionModel(mesh, muscles, flat_wrinkles, thickness, device="cpu")
    np.testing.assert_array_equal(model.evaluate(), mesh.points.astype(np.float32))
    np.testing.assert_array_equal(model.evaluate(np.zeros((2, len(muscles))))[1], mesh.points.astype(np.float32))


def test_results_are_not_overwritten_by_later_frames(rng):
    mesh, muscles, wrinkles, thickness, contractions, *_ = random_rig(rng, n=10)
    model = wf.ExpressionModel(mesh, muscles, wrinkles, thickness, device="cpu")
    first, first_stages = model.evaluate(contractions), model.stages(contractions)
    kept, kept_stretch = first.copy(), first_stages.stretch.copy()
    model.stages(contractions * 2)
    np.testing.assert_array_equal(first, kept)
    np.testing.assert_array_equal(first_stages.stretch, kept_stretch)


def test_displacements_are_not_cumulative(rng):
    mesh, muscles, wrinkles, thickness, contractions, *_ = random_rig(rng, n=12)
    model = wf.ExpressionModel(mesh, muscles, wrinkles, thickness, device="cpu")
    first = model.evaluate(contractions)
    model.evaluate(contractions * 2)
    np.testing.assert_array_equal(model.evaluate(contractions), first)


def _muscle_displacement(muscle, points, k=1.0):
    mesh_points, triangles = grid_surface(4, seed=None)
    weights = wf.expression.muscle_weights(points, [muscle], device="cpu")
    displacement = np.zeros_like(points)
    for v in range(len(points)):
        for e in range(weights.offsets[v], weights.offsets[v + 1]):
            displacement[v] += k * weights.weight[e]
    return displacement


def test_linear_muscle_vanishes_continuously_at_zone_edge_and_falloff_finish():
    muscle = wf.LinearMuscle("m", [0, 0, 0], [1, 0, 0], 40.0, 1.0, 3.0)
    eps = np.array([1e-2, 1e-3, 1e-4])
    edge = np.radians(40.0) - eps
    inside_edge = np.c_[2.0 * np.cos(edge), 2.0 * np.sin(edge), np.zeros(3)]
    outside_edge = np.c_[2.0 * np.cos(edge + 2 * eps), 2.0 * np.sin(edge + 2 * eps), np.zeros(3)]
    near_finish = np.c_[3.0 - eps, np.zeros(3), np.zeros(3)]
    near_attachment = np.c_[eps, np.zeros(3), np.zeros(3)]
    for points in (inside_edge, near_finish, near_attachment):
        size = np.linalg.norm(_muscle_displacement(muscle, points), axis=1)
        assert np.all(size > 0) and np.all(size < 2.0 * eps), size  # linear decay toward zero
    assert np.all(_muscle_displacement(muscle, outside_edge) == 0)
    peak = np.linalg.norm(_muscle_displacement(muscle, np.array([[1.0, 0, 0]])))
    assert peak == pytest.approx(1.0, abs=1e-12)  # μ = 0, D = Rs: full contraction


def test_sphincter_zero_at_centre_and_rim_and_pulls_inward():
    muscle = wf.SphincterMuscle("s", [0, 0, 0], [1, 0, 0], [0, 1, 0], (2.0, 1.0))
    points = np.array([[0, 0, 0], [2.0, 0, 0], [0, 1.0, 0], [1.0, 0, 0.3], [0, 0.5, 0], [3, 0, 0]], dtype=float)
    d = _muscle_displacement(muscle, points, k=0.5)
    assert np.all(d[[0, 1, 2, 5]] == 0)
    np.testing.assert_allclose(d[3], [-0.5 * 0.5 * 1.0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(d[4], [0, -0.5 * 0.5 * 0.5, 0], atol=1e-12)


@wp.kernel
def _contraction_factor_kernel(r: wp.array(dtype=float), kr: float, out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = contraction_factor(r[i], kr)


def _c(r, kr):
    out = wp.empty(len(r), dtype=float, device="cpu")
    wp.launch(
        _contraction_factor_kernel,
        dim=len(r),
        inputs=[wp.array(np.asarray(r, np.float32), device="cpu"), kr],
        outputs=[out],
        device="cpu",
    )
    return out.numpy().astype(np.float64)


@pytest.mark.parametrize("kr", [0.0, 0.2, 0.5, 1.0])
def test_contraction_factor_range_and_smoothness(kr):
    r = np.linspace(0.0, 4.0, 4001)
    c = _c(r, kr)
    assert np.all((c >= 0.0) & (c <= 1.0))
    assert c[0] == pytest.approx(1.0) and _c([1.0], kr)[0] == pytest.approx(kr)
    h = 1e-3
    left = (_c([1.0], kr)[0] - _c([1.0 - h], kr)[0]) / h
    right = (_c([1.0 + h], kr)[0] - _c([1.0], kr)[0]) / h
    if kr > 0:
        assert left == pytest.approx(kr - 1.0, abs=1e-3) and right == pytest.approx(kr - 1.0, abs=5e-3)  # C¹ at r = 1
    else:
        assert np.all(_c([1.01, 2.0, 10.0], 0.0) == 0.0)


def test_wrinkle_profile_integrates_to_zero_across_a_straight_furrow():
    # A flat strip perpendicular to a straight furrow, kr = 1 so that C = 1 at rest (r = 1).
    xs = np.linspace(0.0, 60.0, 6001)
    points = np.c_[np.repeat(xs, 2), np.tile([0.0, 1.0], len(xs)), np.zeros(2 * len(xs))]
    index = np.arange(len(xs) - 1) * 2
    triangles = np.r_[np.c_[index, index + 2, index + 3], np.c_[index, index + 3, index + 1]]
    line = np.array([[0.0, -10.0], [0.0, -3.0], [0.0, 4.0], [0.0, 11.0]])
    wrinkle = wf.Wrinkle("w", line, wf.PlanarProjection([0, 0, 0], [1, 0, 0], [0, 1, 0]), 2.0, 1.5, 1.0)
    model = wf.ExpressionModel(wf.FaceMesh(points, triangles), [], [wrinkle], 0.0, device="cpu")
    height = model.evaluate()[0::2, 2].astype(np.float64)
    assert height[0] == pytest.approx(-2.0, rel=1e-6)  # furrow depth k_d at d = 0
    integral = np.trapezoid(height, xs)
    assert abs(integral) < 1e-4 * 2.0 * 1.5  # ∫₀^∞ S = 0 relative to k_d·k_w
    assert height.max() > 0.2  # raised shoulders beside the furrow


def test_flat_unstretched_skin_does_not_bulge():
    points, triangles = grid_surface(10, height=0.0, seed=None)
    muscle = wf.LinearMuscle("m", [0, -2, 0], [0, 0, 0], 50, 0.5, 3.0)  # in-plane: the sheet stays flat
    model = wf.ExpressionModel(wf.FaceMesh(points, triangles), [muscle], [], 0.3, device="cpu")
    stages = model.stages({"m": 0.0})
    np.testing.assert_array_equal(stages.bulge, stages.muscle)
    stages = model.stages({"m": 0.2})  # stretched/compressed skin bulges along ±z only
    moved = np.abs(stages.stretch - 1.0) > 1e-3
    assert moved.any() and np.all(np.abs(stages.bulge[:, :2] - stages.muscle[:, :2]) < 1e-6)
    assert np.all(np.sign(stages.bulge[moved, 2]) == np.sign(1.0 / stages.stretch[moved] - 1.0))


@pytest.mark.parametrize("seed", [4, 5])
def test_bezier_distance_matches_dense_sampling(seed):
    rng = np.random.default_rng(seed)
    control = rng.uniform(-50, 50, (4, 2))
    control[3] = control[0] + rng.normal(size=2)  # nearly closed loop: several competing minima
    uv = rng.uniform(-80, 80, (3000, 2))
    got = bezier_distances(uv, control, device="cpu")
    expected = ref.bezier_distance(uv, control)
    size = np.ptp(control, axis=0).max()
    assert np.abs(got - expected).max() <= 1e-6 * size


def test_projections_give_lengths_in_mesh_units(rng):
    points = rng.normal(size=(50, 3))
    planar = wf.PlanarProjection([0.1, 0.2, 0.3], [2, 0, 0], [0, 0, 3])
    np.testing.assert_allclose(
        project_points(planar, points, device="cpu"),
        ref.project(
            points,
            dict(kind="planar", origin=np.array([0.1, 0.2, 0.3]), u=np.array([1.0, 0, 0]), v=np.array([0, 0, 1.0])),
        ),
        atol=1e-12,
    )
    cylinder = wf.CylindricalProjection([0, 0, 0], [0, 1, 0], [0, 0, 1], 2.0)
    uv = project_points(cylinder, np.array([[0, 5, 1.0], [1.0, -1, 0], [0, 0, -1.0]]), device="cpu")
    np.testing.assert_allclose(uv, [[0, 5], [2.0 * np.pi / 2, -1], [2.0 * np.pi, 0]], atol=1e-12)


def test_thickness_changes_only_the_bulge(rng):
    mesh, muscles, wrinkles, thickness, contractions, *_ = random_rig(rng, n=10)
    thin = wf.ExpressionModel(mesh, muscles, [], 0.0, device="cpu").stages(contractions)
    thick = wf.ExpressionModel(mesh, muscles, [], thickness, device="cpu").stages(contractions)
    np.testing.assert_array_equal(thin.muscle, thick.muscle)
    np.testing.assert_array_equal(thin.bulge, thin.muscle)
    assert np.abs(thick.bulge - thick.muscle).max() > 1e-3
