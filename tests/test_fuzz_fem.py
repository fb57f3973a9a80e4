"""Property-based tests of the FEM's public calls: random valid, boundary and invalid inputs.

Every call either returns finite values or raises ValueError/TypeError (or warpface's RigError)
whose message names the item that was wrong; never another exception, NaN or inf.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from warpface.errors import RigError  # noqa: E402
from warpface.fem import (  # noqa: E402
    CGOptions,
    ConvergenceError,
    TetMesh,
    TissueMaterial,
    TissueSimulation,
    box_tet_mesh,
    embed_points,
)  # noqa: E402

ACCEPTED = (ValueError, TypeError, RigError)
FUZZ = settings(
    max_examples=int(os.environ.get("WARPFACE_FUZZ_EXAMPLES", 40)),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)

MESH = box_tet_mesh((0.03, 0.01, 0.01), (3, 1, 1))
FIXED = np.flatnonzero(MESH.points[:, 0] < 1e-12)
DRIVEN = np.flatnonzero(MESH.points[:, 0] > 0.03 - 1e-12)
SOFT = TissueMaterial(1e5, 0.45, 10.0, 1000.0)

# Numbers across the whole float64 range and the awkward values around it.
wild_floats = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-300, 1e-200, 1e-160, 1e-9, 0.25, 0.5, 1.0, 1e39, 1e300, -1e300]),
)
wild_values = st.one_of(
    wild_floats,
    st.integers(-(2**70), 2**70),
    st.booleans(),
    st.none(),
    st.text(max_size=3),
    st.lists(wild_floats, max_size=3),
)


def _finite(*arrays) -> bool:
    return all(np.all(np.isfinite(np.asarray(a, dtype=np.float64))) for a in arrays)


def _names(message: str, *items: str) -> bool:
    return any(item in message for item in items)


@FUZZ
@given(E=wild_values, nu=wild_values, eta=wild_values, rho=wild_values)
def test_material_accepts_only_its_ranges(E, nu, eta, rho):
    try:
        material = TissueMaterial(E, nu, eta, rho)
    except ACCEPTED as exc:
        assert _names(str(exc), "E", "nu", "eta", "rho"), exc
        return
    lam, mu = material.lame(4)
    assert _finite(lam, mu)


@FUZZ
@given(dt=wild_values, beta=wild_values, gamma=wild_values)
def test_simulation_constructor_checks_time_step_and_newmark(dt, beta, gamma):
    try:
        sim = TissueSimulation(MESH, SOFT, dt, fixed=FIXED, driven=DRIVEN, beta=beta, gamma=gamma, device="cpu")
    except ACCEPTED as exc:
        assert _names(str(exc), "dt", "beta", "gamma"), exc
        return
    assert math.isfinite(sim.dt) and sim.dt > 0.0
    sim.step(np.full((DRIVEN.size, 3), 1e-4))
    assert _finite(sim.d, sim.v, sim.a, sim.energy())


@FUZZ
@given(
    dt=st.floats(1e-8, 10.0),
    beta=st.floats(0.01, 1.0),
    gamma=st.floats(0.5, 1.0),
    E=st.floats(1e-3, 1e12),
    nu=st.floats(0.0, 0.4999),
    eta=st.floats(0.0, 1e9),
    rho=st.floats(1e-3, 1e6),
    amplitude=st.floats(-0.3, 0.3),
)
def test_every_accepted_setting_steps_finitely(dt, beta, gamma, E, nu, eta, rho, amplitude):
    sim = TissueSimulation(
        MESH, TissueMaterial(E, nu, eta, rho), dt, fixed=FIXED, driven=DRIVEN, beta=beta, gamma=gamma, device="cpu"
    )
    trajectory = np.zeros((3, DRIVEN.size, 3))
    trajectory[:, :, 1] = amplitude * np.array([0.3, 1.0, 0.5])[:, None]
    out = sim.run(trajectory)
    assert _finite(out, sim.d, sim.v, sim.a, sim.energy())


@FUZZ
@given(
    value=wild_floats,
    step=st.integers(0, 2),
    node=st.integers(0, DRIVEN.size - 1),
    axis=st.integers(0, 2),
    shape=st.sampled_from(["ok", "short", "flat"]),
)
def test_trajectories_are_bounded_and_finite(value, step, node, axis, shape):
    sim = TissueSimulation(MESH, SOFT, 1e-3, fixed=FIXED, driven=DRIVEN, device="cpu")
    trajectory = np.zeros((3, DRIVEN.size, 3))
    trajectory[step, node, axis] = value
    if shape == "short":
        trajectory = trajectory[:, :-1]
    elif shape == "flat":
        trajectory = trajectory.reshape(3, -1)
    try:
        out = sim.run(trajectory)
    except ACCEPTED as exc:
        assert _names(str(exc), "trajectory", "driven"), exc
        return
    assert abs(value) <= sim.max_displacement
    assert _finite(out, sim.d, sim.v, sim.a, sim.energy())


@FUZZ
@given(value=wild_values, which=st.sampled_from(["step", "reset_d", "reset_v"]))
def test_step_and_reset_reject_bad_values(value, which):
    sim = TissueSimulation(MESH, SOFT, 1e-3, fixed=FIXED, driven=DRIVEN, device="cpu")
    try:
        if which == "step":
            sim.step(np.full((DRIVEN.size, 3), value) if isinstance(value, float) else value)
        else:
            state = np.zeros((MESH.node_count, 3))
            free = sim.free_nodes[0]
            state[free] = value if isinstance(value, float) else 0.0
            sim.reset(**{("displacement" if which == "reset_d" else "velocity"): state})
            sim.step(np.zeros((DRIVEN.size, 3)))
    except ACCEPTED as exc:
        assert _names(str(exc), "driven", "reset"), exc
        return
    assert _finite(sim.d, sim.v, sim.a, sim.energy())


@FUZZ
@given(
    scale=st.one_of(
        st.sampled_from([1e-30, 1e-12, 1e-9, 1e-3, 1.0, 1e5, 1e6, 1e7, 1e20, 1e300]), st.floats(1e-40, 1e40)
    ),
    corrupt=st.sampled_from(["none", "nan", "index", "negative", "repeat", "float", "shape"]),
)
def test_tetmesh_and_embedding_reject_bad_geometry(scale, corrupt):
    points = MESH.points * scale
    tets = MESH.tets.astype(np.int64).copy()
    if corrupt == "nan":
        points = points.copy()
        points[1, 0] = np.nan
    elif corrupt == "index":
        tets[2, 1] = MESH.node_count
    elif corrupt == "negative":
        tets[0, 0] = -1
    elif corrupt == "repeat":
        tets[0, 1] = tets[0, 0]
    elif corrupt == "float":
        tets = tets + 0.5
    elif corrupt == "shape":
        tets = tets[:, :3]
    try:
        mesh = TetMesh(points, tets)
    except ACCEPTED as exc:
        assert _names(str(exc), "TetMesh"), exc
        return
    assert _finite(mesh.volumes) and np.all(mesh.volumes > 0.0)
    queries = np.array([[0.01, 0.005, 0.005], [0.02, 0.001, 0.009]]) * scale
    try:
        embedding = embed_points(mesh, queries, device="cpu")
    except ACCEPTED as exc:
        assert _names(str(exc), "embed_points"), exc
        return
    moved = embedding.apply(np.full((mesh.node_count, 3), 1e-3 * scale), device="cpu")
    assert _finite(moved)


@FUZZ
@given(
    queries=st.lists(st.tuples(wild_floats, wild_floats, wild_floats), min_size=0, max_size=4),
    max_distance=st.one_of(st.none(), wild_floats),
)
def test_embed_points_rejects_bad_queries(queries, max_distance):
    points = np.array(queries, dtype=np.float64).reshape(-1, 3)
    try:
        embedding = embed_points(MESH, points, max_distance=max_distance, device="cpu")
    except ACCEPTED as exc:
        assert _names(str(exc), "embed_points"), exc
        return
    moved = embedding.apply(np.full((MESH.node_count, 3), 1e-3), device="cpu")
    assert _finite(moved)
    assert moved.shape == (len(points), 3)


@FUZZ
@given(
    option=st.sampled_from(
        ["fixed", "driven", "formulation", "solver", "tolerance", "maxiter", "chunk", "preconditioner", "device"]
    ),
    value=st.one_of(
        wild_values,
        st.lists(st.integers(-5, 100), max_size=4),
        st.sampled_from(["cpu", "cuda:7", "anp", "cg", np.array([1, 2]), [[1, 2], [3]]]),
    ),
)
def test_simulation_options_are_checked(option, value):
    options = dict(fixed=FIXED, driven=DRIVEN, device="cpu", solver="cg")
    try:
        if option in ("tolerance", "maxiter", "chunk", "preconditioner"):  # the CG solver's options
            options["cg"] = CGOptions(**{option: value})
        else:
            options[option] = value
        sim = TissueSimulation(MESH, SOFT, 1e-3, **options)
    except ACCEPTED as exc:
        assert _names(str(exc), option, "fixed", "driven", "node"), exc
        return
    try:
        sim.step(np.full((sim.driven_nodes.size, 3), 1e-4) if sim.driven_nodes.size else None)
        state = (sim.d, sim.v, sim.a, sim.energy())
    except ConvergenceError as exc:  # the documented outcome of a tiny maxiter or tolerance
        assert option in ("maxiter", "tolerance") and "did not converge" in str(exc), exc
        return
    assert _finite(*state)
