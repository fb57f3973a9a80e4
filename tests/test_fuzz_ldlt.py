"""Property-based tests of the block LDLᵀ solver: random, badly scaled, indefinite and non-finite matrices.

Every call either returns a finite float64-accurate solution or raises ValueError/TypeError naming
``BlockLDLT``; never another exception, NaN or inf.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
import scipy.sparse as sps

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from warpface.fem.ldlt import BlockLDLT  # noqa: E402

FUZZ = settings(max_examples=int(os.environ.get("WARPFACE_FUZZ_EXAMPLES", 40)), deadline=None)


@FUZZ
@given(
    nodes=st.integers(1, 6),
    seed=st.integers(0, 2**16),
    shift=st.floats(allow_nan=True, allow_infinity=True),
    scale=st.sampled_from([1e-300, 1e-40, 1e-12, 1.0, 1e12, 1e40, 1e300]),
    sparse=st.booleans(),
    rhs_value=st.sampled_from([0.0, 1.0, float("nan"), float("inf")]),
)
def test_block_ldlt_solves_accurately_or_rejects(nodes, seed, shift, scale, sparse, rhs_value):
    rng = np.random.default_rng(seed)
    n = 3 * nodes
    B = rng.standard_normal((n, n))
    if sparse:
        B[np.abs(B) < 0.8] = 0.0
    with np.errstate(all="ignore"):
        dense = scale * (B @ B.T + shift * np.eye(n))
    try:
        factor = BlockLDLT(sps.csr_matrix(dense))
    except (ValueError, TypeError) as exc:
        assert "BlockLDLT" in str(exc), exc
        return
    assert np.all(np.isfinite(dense))
    rhs = rng.standard_normal(n)
    rhs[0] = rhs_value if rhs_value else rhs[0]
    try:
        x = np.array(factor.solve(rhs))
    except ValueError as exc:
        assert "BlockLDLT" in str(exc) and not np.isfinite(rhs_value), exc
        return
    assert np.all(np.isfinite(x))
    residual = rhs - dense @ x
    assert np.abs(residual).max() <= 1e-6 * (np.abs(dense).max() * np.abs(x).max() + np.abs(rhs).max())
