"""warpface.solve at the boundary: bad input gets a clear error naming the item; anything else a finite result."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import small_face_rig
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from warpface import FaceRig, RigError
from warpface.solve import Solver, fit

RIG = small_face_rig()
V = RIG.mesh.vertex_count
SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def test_rig_without_muscles():
    bare = FaceRig(mesh=RIG.mesh, name="Bare")
    with pytest.raises(RigError, match="Bare.*no muscles"):
        fit(bare, RIG.mesh.points)
    with pytest.raises(TypeError, match="rig"):
        fit("face.usda", RIG.mesh.points)


def test_topology_and_count_mismatch():
    with pytest.raises(ValueError, match=f"target: {V - 1} points.*{V} vertices"):
        fit(RIG, RIG.mesh.points[:-1], device="cpu")
    with pytest.raises(ValueError, match="target: 3 points but 4"):
        fit(RIG, np.zeros((3, 3)), vertices=[0, 1, 2, 3], device="cpu")
    with pytest.raises(ValueError, match="target: expected shape"):
        fit(RIG, np.zeros((4, 2)), vertices=[0, 1, 2, 3], device="cpu")
    with pytest.raises(ValueError, match="target: infinite"):
        fit(RIG, np.full((2, 3), np.inf), vertices=[0, 1], device="cpu")


@pytest.mark.parametrize(
    "vertices, match",
    [
        ([0, V], f"vertices: index {V} at position 1 is out of range"),
        ([-1, 2], "vertices: index -1"),
        ([0.5, 1.0], "vertices: indices must be integers"),
        ([[0, 1]], "vertices: expected a 1-D array"),
        ([], "vertices: no target points"),
        (np.array([True, False]), "vertices: expected integer indices, got a boolean array"),
    ],
)
def test_bad_vertices(vertices, match):
    with pytest.raises(ValueError, match=match):
        Solver(RIG, vertices, device="cpu")


def test_bad_surface_points_weights_and_options():
    with pytest.raises(ValueError, match="triangles: index"):
        Solver(RIG, triangles=[RIG.mesh.triangle_count], barycentrics=[[1, 0, 0]], device="cpu")
    with pytest.raises(ValueError, match="barycentrics: row 0 sums"):
        Solver(RIG, triangles=[0], barycentrics=[[1, 1, 0]], device="cpu")
    with pytest.raises(ValueError, match="triangles: surface points need both"):
        Solver(RIG, triangles=[0], device="cpu")
    with pytest.raises(ValueError, match="weights: non-finite weight nan at point 1"):
        Solver(RIG, [0, 1, 2], weights=[1.0, np.nan, 1.0], device="cpu")
    with pytest.raises(ValueError, match="weights: negative"):
        Solver(RIG, [0, 1, 2], weights=[1.0, -1.0, 1.0], device="cpu")
    with pytest.raises(ValueError, match="weights: expected shape"):
        Solver(RIG, [0, 1, 2], weights=[1.0, 1.0], device="cpu")
    with pytest.raises(TypeError, match="unknown solve option 'lambda2'"):
        Solver(RIG, [0, 1, 2], lambda2=1.0, device="cpu")
    with pytest.raises(ValueError, match="l2: expected a finite number"):
        Solver(RIG, [0, 1, 2], l2=np.nan, device="cpu")
    with pytest.raises(ValueError, match="bounds: unknown control 'nose'"):
        Solver(RIG, [0, 1, 2], bounds={"nose": (0, 1)}, device="cpu")
    name = RIG.muscle_names[0]
    with pytest.raises(ValueError, match=f"bounds\\[{name!r}\\]"):
        Solver(RIG, [0, 1, 2], bounds={name: (1, 0)}, device="cpu")
    with pytest.raises(ValueError, match="lower bound must be ≥ 0"):
        Solver(RIG, [0, 1, 2], bounds={name: (-1, 0)}, device="cpu")


def test_wrong_types_are_type_errors_naming_the_argument():
    name = RIG.muscle_names[0]
    for options, match in (
        ({"l2": "small"}, "l2: expected a number"),
        ({"max_iterations": 2.5}, "max_iterations: expected an integer"),
        ({"frames_per_pass": "all"}, "frames_per_pass: expected an integer"),
        ({"bounds": [(name, (0, 1))]}, "bounds: expected a dict"),
        ({"bounds": {name: None}}, f"bounds\\[{name!r}\\]: expected a pair"),
    ):
        with pytest.raises(TypeError, match=match):
            Solver(RIG, [0, 1, 2], device="cpu", **options)
    with pytest.raises(ValueError, match="max_iterations: expected a positive integer"):
        Solver(RIG, [0, 1, 2], device="cpu", max_iterations=0)
    solver = Solver(RIG, [0, 1, 2], device="cpu")
    with pytest.raises(TypeError, match="target: expected numbers"):
        solver.solve([["a", "b", "c"]] * 3)
    with pytest.raises(TypeError, match="weights: expected numbers"):
        solver.solve(RIG.mesh.points[:3], weights=["x", "y", "z"])
    from warpface.solve import LocalExpression

    with pytest.raises(TypeError, match="vertices: indices must be integers, got dtype <U1"):
        Solver(RIG, ["a", "b"], device="cpu")
    with pytest.raises(TypeError, match="operators"):
        LocalExpression("rig", [0, 1, 2], device="cpu")


coordinates = st.floats(min_value=-10.0, max_value=10.0) | st.just(np.nan)


@SETTINGS
@given(
    target=hnp.arrays(np.float64, (8, 3), elements=coordinates),
    weights=hnp.arrays(np.float64, (8,), elements=st.floats(0.0, 1e3)),
    pose=st.booleans(),
)
def test_any_finite_or_missing_target_gives_a_finite_fit(target, weights, pose):
    vertices = np.arange(0, V, V // 8)[:8]
    scaled = RIG.mesh.points[vertices] + 0.01 * target  # near the face or anywhere up to 10 cm off
    result = fit(RIG, scaled, vertices=vertices, weights=weights, pose=pose, device="cpu", max_iterations=8)
    assert np.all(np.isfinite(result.vector)) and np.isfinite(result.residual)
    assert np.all(np.isfinite(result.points)) and np.all(np.isfinite(result.rotation))
    assert np.all(result.vector >= 0.0)


@SETTINGS
@given(vertices=hnp.arrays(np.int64, st.integers(1, 6), elements=st.integers(-3 * V, 3 * V)))
def test_any_index_array_is_used_or_rejected_by_name(vertices):
    try:
        solver = Solver(RIG, vertices, device="cpu")
    except ValueError as error:
        assert "vertices" in str(error)
        return
    result = solver.solve(RIG.mesh.points[vertices])
    assert np.all(np.isfinite(result.vector))


@SETTINGS
@given(frames=hnp.arrays(np.float64, st.tuples(st.integers(0, 3), st.just(4), st.just(3)), elements=coordinates))
def test_batches_of_any_finite_or_missing_frames_are_finite(frames):
    solver = Solver(RIG, [0, 5, 9, 40], device="cpu", max_iterations=5)
    batch = solver.solve_batch(RIG.mesh.points[[0, 5, 9, 40]] + 0.01 * frames)
    assert len(batch) == len(frames)
    assert np.all(np.isfinite(batch.controls)) and np.all(np.isfinite(batch.residual))
