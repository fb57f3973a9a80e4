"""Static cantilever vs Euler–Bernoulli: convergence at nu = 0.3, locking at nu = 0.495, and its cure.

Beam L = 1, square section h = 0.1 (L/h = 10), clamped at x = 0, unit shear load on the end face,
Kuhn-split hex grid (the mesh kind on which SPEC §2.1 quotes the thesis's ratios). The ratio is the
mean end-face deflection over ``P L^3 / (3 E I)``.
"""

from __future__ import annotations

import numpy as np
import pytest

from warpface.fem import TissueMaterial, assemble, box_tet_mesh
from warpface.fem.solver_direct import factorize_spd

L, H, E = 1.0, 0.1, 1.0e6


def tip_ratio(layers: int, nu: float, formulation: str) -> float:
    mesh = box_tet_mesh((L, H, H), (10 * layers, layers, layers))
    K = assemble(mesh, TissueMaterial(E, nu, 0.0, 1000.0), formulation=formulation, device="cpu").to_scipy()[0]
    p = mesh.points
    free = np.flatnonzero(p[:, 0] > 1e-12)
    o = (3 * free[:, None] + np.arange(3)).ravel()
    # uniform shear traction on the end face, total force 1 N in -y, as consistent nodal loads
    faces = mesh.boundary_faces[np.all(np.abs(p[mesh.boundary_faces][:, :, 0] - L) < 1e-12, axis=1)]
    t = p[faces]
    area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    f = np.zeros((mesh.node_count, 3))
    np.add.at(f[:, 1], faces.ravel(), np.repeat(-area / area.sum() / 3.0, 3))
    u = np.zeros(3 * mesh.node_count)
    u[o] = factorize_spd(K.tocsr()[o][:, o]).solve(f.ravel()[o])
    end = np.flatnonzero(np.abs(p[:, 0] - L) < 1e-12)
    beam = 1.0 * L**3 / (3.0 * E * H**4 / 12.0)
    return float(-u.reshape(-1, 3)[end, 1].mean() / beam)


def test_plain_tets_reproduce_the_thesis_ratios():
    """SPEC §2.1: 0.51 / 0.79 / 0.89 at nu = 0.3 and 0.06 / 0.18 / 0.32 at nu = 0.495 (2 / 4 / 6 layers)."""
    for layers, r03, r0495 in [(2, 0.51, 0.06), (4, 0.79, 0.18), (6, 0.89, 0.32)]:
        assert tip_ratio(layers, 0.3, "linear") == pytest.approx(r03, abs=0.006)
        assert tip_ratio(layers, 0.495, "linear") == pytest.approx(r0495, abs=0.006)


def test_locking_and_locking_free_convergence():
    coarse = {k: tip_ratio(4, *k) for k in [(0.3, "linear"), (0.495, "linear"), (0.495, "anp")]}
    fine = {k: tip_ratio(8, *k) for k in coarse}
    # Richardson extrapolation with the O(h^2) rate of linear tets in displacement
    limit = {k: (4.0 * fine[k] - coarse[k]) / 3.0 for k in coarse}

    # nu = 0.3: converges to Euler-Bernoulli (the 3-D beam is within ~1 % of it at L/h = 10)
    assert fine[(0.3, "linear")] > 0.93
    assert limit[(0.3, "linear")] == pytest.approx(1.0, abs=0.03)
    # nu = 0.495, plain tets lock: less than half the deflection even with 8 layers, and not converging
    assert fine[(0.495, "linear")] < 0.5
    assert limit[(0.495, "linear")] < 0.6
    # nu = 0.495, average nodal pressure: within ~5 % at 8 layers and converging to the beam
    assert fine[(0.495, "anp")] > 0.935
    assert limit[(0.495, "anp")] == pytest.approx(1.0, abs=0.03)
