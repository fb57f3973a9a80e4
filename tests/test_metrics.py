"""Kato's symmetry ξ (SPEC §4) on synthetic tracks with known answers; surface distances."""

from __future__ import annotations

import numpy as np
import pytest

from warpface.metrics import (
    KATO_LANDMARKS,
    SYMMETRY_PAIRS,
    kato_landmarks,
    point_distances,
    surface_error,
    symmetry,
    symmetry_side,
)

T = 50


def tracks(rate_left: float, rate_right: float, *, rng):
    """ch fixed at a point per side; ex, pi, al, cphi at random directions, their distance from ch
    scaled by (1 + rate t) with t = 0..1: ξ_side(t) = 4 rate t exactly."""
    t = np.linspace(0.0, 1.0, T)
    out = {}
    for side, rate, origin in (("L", rate_left, [0.03, -0.06, 0.09]), ("R", rate_right, [-0.03, -0.06, 0.09])):
        out[f"ch_{side}"] = np.tile(origin, (T, 1)).astype(float)
        for key in SYMMETRY_PAIRS:
            direction = rng.normal(size=3)
            direction *= rng.uniform(0.01, 0.05) / np.linalg.norm(direction)
            out[f"{key}_{side}"] = origin + (1.0 + rate * t)[:, None] * direction
    # a rigid motion of the whole face changes no distance
    angle = 0.3 * t
    rot = np.zeros((T, 3, 3))
    rot[:, 0, 0] = rot[:, 2, 2] = np.cos(angle)
    rot[:, 0, 2], rot[:, 2, 0] = np.sin(angle), -np.sin(angle)
    rot[:, 1, 1] = 1.0
    return {k: np.einsum("tij,tj->ti", rot, v) + [0.0, 0.01, 0.0] * t[:, None] for k, v in out.items()}, t


def test_xi_known_answer(rng):
    lm, t = tracks(0.10, 0.04, rng=rng)
    np.testing.assert_allclose(symmetry_side(lm, "L"), 4 * 0.10 * t, atol=1e-13)
    np.testing.assert_allclose(symmetry_side(lm, "R"), 4 * 0.04 * t, atol=1e-13)
    result = symmetry(lm)
    np.testing.assert_allclose(result.cost[1:], np.log(4 * 0.06 * t[1:]), rtol=1e-10)
    assert result.cost[0] == pytest.approx(np.log(1e-12))
    # the reference frame may be any frame
    later = symmetry_side(lm, "L", reference=10)
    np.testing.assert_allclose(later, (1 + 0.1 * t) / (1 + 0.1 * t[10]) * 4 - 4, atol=1e-13)


def test_symmetric_motion_has_floor_cost(rng):
    lm, _ = tracks(0.07, 0.07, rng=np.random.default_rng(3))
    # same rate but different directions: ξ_L == ξ_R regardless
    result = symmetry(lm, floor=1e-9)
    np.testing.assert_allclose(result.xi_left, result.xi_right, atol=1e-14)
    np.testing.assert_array_equal(result.cost, np.log(1e-9))


def test_more_asymmetry_costs_more(rng):
    costs = [symmetry(tracks(0.05, 0.05 + d, rng=np.random.default_rng(9))[0]).cost[-1] for d in (0.001, 0.01, 0.1)]
    assert costs[0] < costs[1] < costs[2]
    np.testing.assert_allclose(np.diff(costs), np.log(10.0), rtol=1e-9)


def test_kato_landmarks_from_ibug():
    from warpface.assets import default_face, default_landmarks

    face = default_face()
    ibug = face.points[default_landmarks()]
    lm = kato_landmarks(ibug)
    assert set(lm) == set(KATO_LANDMARKS)
    np.testing.assert_array_equal(lm["ch_R"], ibug[48])
    np.testing.assert_array_equal(lm["ch_L"], ibug[54])
    np.testing.assert_allclose(lm["pi_L"], 0.5 * (ibug[46] + ibug[47]))
    # the built-in face is mirror symmetric in x: so are the Kato landmarks
    for name, value in lm.items():
        if name.endswith("_L"):
            np.testing.assert_allclose(value, lm[name[:-1] + "R"] * [-1, 1, 1], atol=1e-12)
    # cphs sits between the cupid's-bow peak and the midline, at the nose base
    assert 0.0 < lm["cphs_L"][0] < lm["cphi_L"][0]
    assert lm["cphs_L"][1] > lm["cphi_L"][1]
    # affine combinations: a translation of the face translates every landmark; tracks keep their shape
    shifted = kato_landmarks(ibug + [0.1, -0.2, 0.3])
    for name in lm:
        np.testing.assert_allclose(shifted[name], lm[name] + [0.1, -0.2, 0.3], atol=1e-12)
    track = kato_landmarks(np.stack([ibug, ibug * 2.0]))
    np.testing.assert_allclose(track["cphs_R"][1], 2.0 * lm["cphs_R"], atol=1e-12)


def test_bad_input():
    with pytest.raises(ValueError, match=r"\(\.\.\., 68, 3\)"):
        kato_landmarks(np.zeros((67, 3)))
    with pytest.raises(ValueError, match="not finite"):
        kato_landmarks(np.full((68, 3), np.nan))
    lm, _ = tracks(0.1, 0.2, rng=np.random.default_rng(1))
    broken = dict(lm)
    del broken["al_R"]
    with pytest.raises(ValueError, match="'al_R' missing"):
        symmetry(broken)
    with pytest.raises(ValueError, match="side"):
        symmetry_side(lm, "X")
    coincide = dict(lm)
    coincide["ex_L"] = coincide["ch_L"].copy()
    with pytest.raises(ValueError, match="coincide"):
        symmetry(coincide)
    with pytest.raises(ValueError, match="reference frame"):
        symmetry(lm, reference=T)
    with pytest.raises(ValueError, match="floor"):
        symmetry(lm, floor=0.0)


def test_surface_distances():
    a = np.zeros((4, 3))
    b = np.array([[0, 0, 0], [0.003, 0, 0], [0, 0.004, 0], [0, 0.003, 0.004]], float)
    np.testing.assert_allclose(point_distances(b, a), [0, 0.003, 0.004, 0.005])
    err = surface_error(b, a)
    assert err.mean == pytest.approx(0.003) and err.max == pytest.approx(0.005) and err.argmax == 3
    assert err.rms == pytest.approx(np.sqrt((0.003**2 + 0.004**2 + 0.005**2) / 4))
    sub = surface_error(b, a, vertices=[0, 1])
    assert sub.max == pytest.approx(0.003) and sub.argmax == 1
    with pytest.raises(ValueError, match="same shape"):
        point_distances(a, a[:3])
    with pytest.raises(ValueError, match="out of range"):
        surface_error(b, a, vertices=[4])
