"""Block LDLᵀ with a float32 factor and float64 refinement (the CPU direct solver), against SciPy's float64 solves."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sps
import scipy.sparse.linalg as spla

from warpface.fem import TissueMaterial, TissueSimulation, assemble, box_tet_mesh, shell_tet_mesh
from warpface.fem.ldlt import DEFAULT_ORDERINGS, ORDERINGS, RUN_COST, BlockLDLT, UnsuitableFactor, node_ordering
from warpface.fem.solver_direct import SuperLUFactor, node_dofs

KATO = TissueMaterial(192.4e3, 0.495, 476.8, 1100.0)
DT = 1e-3


@pytest.fixture(scope="module")
def face():
    """A small face-like shell: upper part fixed, a lower band driven down like an opening jaw."""
    mesh = shell_tet_mesh(10, 10, 3)
    p = mesh.points
    fixed = np.flatnonzero(p[:, 1] > np.quantile(p[:, 1], 0.6))
    driven = np.flatnonzero(p[:, 1] < np.quantile(p[:, 1], 0.08))
    return mesh, fixed, driven


def _system(mesh, fixed, driven, formulation):
    K, M, C = assemble(mesh, KATO, formulation=formulation, device="cpu").to_scipy()
    free = np.setdiff1d(np.arange(mesh.node_count), np.union1d(fixed, driven))
    A = (K + 4 / DT**2 * M + 2 / DT * C).tocsr()
    o = node_dofs(free)
    return A, o, node_dofs(driven), K, M, C


@pytest.mark.parametrize("formulation", ["linear", "anp"])
@pytest.mark.parametrize("ordering", ORDERINGS)
def test_solves_match_scipy_and_refine_in_one_round_from_a_close_start(face, formulation, ordering):
    A, o, *_ = _system(*face, formulation)
    A_oo = A[o][:, o].tocsc()
    factor = BlockLDLT(A_oo, orderings=(ordering,))
    assert factor.ordering == ordering and 0.0 < factor.contraction < 1e-4
    rng = np.random.default_rng(1)
    rhs = rng.standard_normal(o.size)
    expected = spla.spsolve(A_oo, rhs)
    got = np.array(factor.solve(rhs))
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-11 * np.abs(expected).max())
    assert factor.rounds >= 2  # a float32 round alone is not float64-accurate from zero
    close = expected * (1.0 + 1e-7 * rng.standard_normal(o.size))
    before = factor.rounds
    got = np.array(factor.solve(rhs, close))
    assert factor.rounds == before + 1 and factor.solves == 2
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def test_orderings_report_the_factor_they_produce(face):
    A, o, *_ = _system(*face, "anp")
    A_oo = A[o][:, o]
    n = o.size // 3
    blocks = sps.bsr_matrix(A_oo, blocksize=(3, 3))
    pattern = sps.csr_matrix((np.ones(blocks.indices.size), blocks.indices, blocks.indptr), shape=(n, n))
    pattern = (pattern + pattern.T).tocsr()
    for name in ORDERINGS:
        order, chosen, blocks = node_ordering(pattern, (name,))
        assert chosen == name
        np.testing.assert_array_equal(np.sort(order), np.arange(n))
        factor = BlockLDLT(A_oo, orderings=(name,))
        if name == "rcm":
            assert factor.block_count <= blocks  # the envelope bounds the factor
        else:
            assert factor.block_count == blocks
        assert factor.factor_nnz == 9 * factor.block_count + 6 * n
    _, best, _ = node_ordering(pattern, ORDERINGS)
    costs = {name: BlockLDLT(A_oo, orderings=(name,)) for name in ORDERINGS}
    assert min(costs.values(), key=lambda f: f.block_count + RUN_COST * f.run_count) is costs[best]
    assert BlockLDLT(A_oo).ordering in DEFAULT_ORDERINGS


@pytest.mark.parametrize("formulation", ["linear", "anp"])
def test_direct_solver_matches_a_scipy_newmark_loop_within_1e_9_m(face, formulation):
    """TissueSimulation's CPU path against an independent SPEC §2 loop with SciPy's splu, 120 steps of a
    mouth opening: float64 agreement; one refinement round per step in smooth motion (two while the motion is
    tiny against the float32 rounding, and a few steps after the ramp's kink)."""
    mesh, fixed, driven = face
    steps = 120
    s = 0.5 * (1.0 - np.cos(np.pi * np.clip(DT * np.arange(1, steps + 1) / 0.08, 0.0, 1.0)))
    trajectory = np.zeros((steps, driven.size, 3))
    trajectory[:, :, 1] = -4e-3 * s[:, None]
    sim = TissueSimulation(mesh, KATO, DT, fixed=fixed, driven=driven, formulation=formulation, device="cpu")
    assert isinstance(sim.solver.factor, BlockLDLT)
    out = sim.run(trajectory[:60])
    for row in trajectory[60:100]:
        sim.step(row)
    factor = sim.solver.factor
    rounds = factor.rounds
    for row in trajectory[100:]:  # smooth motion: one round per step
        sim.step(row)
    assert factor.rounds - rounds == steps - 100 and factor.rounds <= 1.5 * factor.solves

    A, o, c, K, M, C = _system(mesh, fixed, driven, formulation)
    lu = spla.splu(A[o][:, o].tocsc())
    A_oc = A[o][:, c]
    Qd, Qv = (4 / DT**2 * M + 2 / DT * C).tocsr(), (4 / DT * M + C).tocsr()
    d, v, a = (np.zeros(3 * mesh.node_count) for _ in range(3))
    for t, row in enumerate(trajectory):
        q = Qd @ d + Qv @ v + M @ a
        d_new = np.zeros_like(d)
        d_new[o] = lu.solve(q[o] - A_oc @ row.ravel())
        d_new[c] = row.ravel()
        a = 4 / DT**2 * (d_new - d) - 4 / DT * v - a
        v = 2 / DT * (d_new - d) - v
        d = d_new
        if t == 59:
            np.testing.assert_allclose(out[-1], d.reshape(-1, 3), rtol=0, atol=1e-9)  # float32 record
    assert np.abs(d).max() > 1e-3
    np.testing.assert_allclose(sim.d, d.reshape(-1, 3), rtol=0, atol=1e-12)
    np.testing.assert_allclose(sim.v, v.reshape(-1, 3), rtol=0, atol=1e-9)


def test_restart_and_jumps_keep_float64_accuracy(face):
    """A reset (the extrapolation history no longer applies) and jumps in the driven motion (a poor start)
    cost refinement rounds, not accuracy."""
    mesh, fixed, driven = face
    trajectory = np.zeros((30, driven.size, 3))
    trajectory[:, :, 1] = -2e-3 * np.sin(np.linspace(0.1, 1.2, 30))[:, None]
    trajectory[[11, 23], :, 2] = 2e-3
    sim = TissueSimulation(mesh, KATO, DT, fixed=fixed, driven=driven, formulation="anp", device="cpu")
    ref = TissueSimulation(mesh, KATO, DT, fixed=fixed, driven=driven, formulation="anp", device="cpu")
    assert isinstance(sim.solver.factor, BlockLDLT)
    A, o, *_ = _system(mesh, fixed, driven, "anp")
    ref.solver.factor = SuperLUFactor(A[o][:, o])  # float64 throughout
    expected = ref.run(trajectory)
    got = sim.run(trajectory)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(sim.d, ref.d, rtol=0, atol=1e-12)
    sim.reset()
    ref.reset()
    np.testing.assert_allclose(sim.run(trajectory[::-1]), ref.run(trajectory[::-1]), rtol=0, atol=1e-9)
    np.testing.assert_allclose(sim.d, ref.d, rtol=0, atol=1e-12)


def test_ill_conditioned_systems_use_the_float64_factor():
    """A long thin nearly incompressible bar with a 10 s step: the float32 factor would not refine, so the
    solver falls back to SuperLU in float64 and still matches SciPy."""
    mesh = box_tet_mesh((1.0, 0.01, 0.01), (100, 1, 1))
    fixed = np.flatnonzero(mesh.points[:, 0] < 1e-12)
    material = TissueMaterial(1e5, 0.4999, 0.0, 1e-3)
    K, M, C = assemble(mesh, material, device="cpu").to_scipy()
    free = np.setdiff1d(np.arange(mesh.node_count), fixed)
    A_oo = (K + 4 / 100.0 * M + 2 / 10.0 * C).tocsr()[node_dofs(free)][:, node_dofs(free)]
    with pytest.raises(UnsuitableFactor, match="contraction"):
        BlockLDLT(A_oo)
    sim = TissueSimulation(mesh, material, 10.0, fixed=fixed, device="cpu")
    assert isinstance(sim.solver.factor, SuperLUFactor)
    rhs = np.random.default_rng(2).standard_normal(A_oo.shape[0])
    expected = spla.spsolve(A_oo.tocsc(), rhs)
    np.testing.assert_allclose(sim.solver.solve(rhs), expected, rtol=0, atol=1e-6 * np.abs(expected).max())  # κ ~ 1e9


def test_bad_matrices_are_rejected():
    good = sps.eye(6, format="csr") * 2.0
    BlockLDLT(good)
    with pytest.raises(ValueError, match="3x3 node blocks"):
        BlockLDLT(sps.eye(5))
    with pytest.raises(ValueError, match="3x3 node blocks"):
        BlockLDLT(sps.csr_matrix((6, 9)))
    with pytest.raises(ValueError, match="3x3 node blocks"):
        BlockLDLT(sps.csr_matrix((0, 0)))
    with pytest.raises(ValueError, match="not positive definite"):
        BlockLDLT(-good)
    nan = good.copy()
    nan[1, 1] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        BlockLDLT(nan)
    with pytest.raises(TypeError, match="BlockLDLT"):
        BlockLDLT("matrix")
    for options in (dict(rtol=0.0), dict(rtol=float("nan")), dict(max_rounds=0)):
        with pytest.raises(ValueError, match="BlockLDLT"):
            BlockLDLT(good, **options)
    for options in (dict(max_rounds=True), dict(max_rounds=2.0), dict(rtol="1e-8")):
        with pytest.raises(TypeError, match="BlockLDLT: (max_rounds|rtol)"):
            BlockLDLT(good, **options)
