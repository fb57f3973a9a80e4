"""The expression formulas (warpface.expression.formulas) against NumPy, in float64 and float32.

The NumPy side is written from SPEC §1 and §6.2 directly; the derivative functions are checked against
central differences of the float64 value functions.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import warp as wp

from warpface.expression import formulas as fm

N = 64
FLOOR = 1.0e-4


@wp.kernel
def _evaluate(
    p0: wp.array(dtype=Any),
    p1: wp.array(dtype=Any),
    p2: wp.array(dtype=Any),
    d1: wp.array(dtype=Any),
    d2: wp.array(dtype=Any),
    s: wp.array(dtype=Any),
    kr: wp.array(dtype=Any),
    h: wp.array(dtype=Any),
    vectors: wp.array2d(dtype=Any),
    scalars: wp.array2d(dtype=Any),
):
    i = wp.tid()
    a, b, c = p0[i], p1[i], p2[i]
    r = s[i]
    k = kr[i]
    floor = type(r)(FLOOR)
    rotation = fm.jaw_rotation(r, wp.normalize(c))
    slide = fm.jaw_slide(k, h[i], a, wp.normalize(c))
    vectors[i, 0] = fm.jaw_blend(a, h[i], b, rotation, slide)
    vectors[i, 1] = fm.muscle_pull(a, k, b)
    area = fm.area_vector(a, b, c, h[i])
    vectors[i, 2] = area
    d_area = fm.d_area_vector(b - a, c - a, d1[i], d2[i], h[i])
    vectors[i, 3] = d_area
    vectors[i, 4] = fm.unit_or_zero(a)
    vectors[i, 5] = fm.d_unit_or_zero(a, d1[i])
    vectors[i, 6] = fm.bulge_point(a, b, r, h[i], floor)
    vectors[i, 7] = fm.wrinkle_point(a, k, b)
    vectors[i, 8] = fm.unit_or_zero(a - a)
    scalars[i, 0] = fm.area_ratio(area, k)
    scalars[i, 1] = fm.d_area_ratio(area, d_area, k)
    scalars[i, 2] = fm.stretch_ratio(r, h[i] - type(r)(0.5))
    scalars[i, 3] = fm.bulge_growth(r, floor)
    scalars[i, 4] = fm.d_bulge_growth(r, h[i], floor)
    scalars[i, 5] = fm.wrinkle_profile(r, h[i])
    scalars[i, 6] = fm.contraction_factor(r, k)
    scalars[i, 7] = fm.contraction_factor_from_rate(r, k, fm.contraction_rate(k))
    value, slope = fm.contraction_factor_and_slope(r, k, type(r)(1.0))
    scalars[i, 8] = value
    scalars[i, 9] = slope
    scalars[i, 10] = fm.wrinkle_term(k, h[i], r)


def _inputs(rng):
    vec = lambda: rng.normal(size=(N, 3))  # noqa: E731
    r = rng.uniform(0.0, 2.0, N)
    r[:4] = (0.0, 1.0, 0.5e-4, 1.0)  # below the floor, exactly 1 (the knee)
    kr = rng.uniform(0.0, 1.0, N)
    kr[:8:2] = 0.0
    h = rng.uniform(0.0, 1.5, N)
    return vec(), vec(), vec(), vec(), vec(), r, kr, h


def _run(inputs, scalar, vector):
    device = "cpu"
    arrays = [wp.array(x, dtype=vector, device=device) for x in inputs[:5]]
    arrays += [wp.array(x, dtype=scalar, device=device) for x in inputs[5:]]
    vectors = wp.zeros((N, 9), dtype=vector, device=device)
    scalars = wp.zeros((N, 11), dtype=scalar, device=device)
    wp.launch(_evaluate, dim=N, inputs=[*arrays, vectors, scalars], device=device)
    return vectors.numpy().astype(np.float64), scalars.numpy().astype(np.float64)


def _unit(v):
    length = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, length, out=np.zeros_like(v), where=length > 0)


def _rotate(axis, angle, v):
    """Rodrigues' rotation of ``v`` by ``angle`` about the unit ``axis``."""
    cos, sin = np.cos(angle)[:, None], np.sin(angle)[:, None]
    return v * cos + np.cross(axis, v) * sin + axis * np.sum(axis * v, axis=1, keepdims=True) * (1 - cos)


def _contraction(r, kr):
    below = (kr - 1.0) * r + 1.0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        above = np.where(kr > 0, kr * np.exp((1.0 - 1.0 / np.where(kr > 0, kr, 1.0)) * (r - 1.0)), 0.0)
    return np.where(r <= 1.0, below, above)


def _reference(inputs):
    a, b, c, d1, d2, r, kr, h = inputs
    axis = _unit(c)
    moved = _rotate(axis, r, a - b) + b + kr[:, None] * a + h[:, None] * axis
    area = h[:, None] * np.cross(b - a, c - a)
    length = np.linalg.norm(area, axis=1)
    n = _unit(a)
    count = h - 0.5
    d_area = h[:, None] * (np.cross(d1, c - a) + np.cross(b - a, d2))
    vectors = [
        a + h[:, None] * (moved - a),
        a + kr[:, None] * b,
        area,
        d_area,
        n,
        (d1 - n * np.sum(n * d1, axis=1, keepdims=True)) / np.linalg.norm(a, axis=1, keepdims=True),
        a + ((1.0 / np.maximum(r, FLOOR) - 1.0) * h)[:, None] * _unit(b),
        a + kr[:, None] * _unit(b),
        np.zeros_like(a),
    ]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(kr > 0, length / kr, np.inf)
        scalars = [
            ratio,
            np.where(length > 0, np.sum(area * d_area, axis=1) / (length * kr), 0.0),
            np.where(count > 0, r / count, 1.0),
            1.0 / np.maximum(r, FLOOR) - 1.0,
            np.where(r > FLOOR, -h / r**2, 0.0),
            (r / h - 1.0) * np.exp(-r / h),
        ]
    factor = _contraction(r, kr)
    rate = np.where(kr > 0, 1.0 - 1.0 / np.where(kr > 0, kr, 1.0), 0.0)
    slope = np.where(r <= 1.0, kr - 1.0, rate * factor)
    scalars += [factor, factor, factor, slope, kr * h * r]
    return np.stack(vectors, axis=1), np.stack(scalars, axis=1)


@pytest.mark.parametrize(
    "scalar, vector, rtol", [(wp.float64, wp.vec3d, 1e-12), (wp.float32, wp.vec3, 2e-5)], ids=["float64", "float32"]
)
def test_formulas_match_numpy(scalar, vector, rtol):
    inputs = _inputs(np.random.default_rng(7))
    vectors, scalars = _run(inputs, scalar, vector)
    want_vectors, want_scalars = _reference(inputs)
    finite = np.isfinite(want_scalars)
    np.testing.assert_allclose(vectors, want_vectors, rtol=rtol, atol=rtol)
    np.testing.assert_allclose(scalars[finite], want_scalars[finite], rtol=rtol, atol=rtol)
    assert np.all(np.isinf(scalars[~finite]))  # a zero rest length (k_r drawn 0) divides to inf, as NumPy


def test_contraction_factor_is_c1_and_bounded():
    """C(1) = k_r from both sides, C(0) = 1, the slope is continuous at r = 1 (k_r > 0), and C stays in [0, 1]."""
    kr = np.linspace(0.0, 1.0, N // 2)
    eps = 1e-7
    r = np.concatenate([np.full(len(kr), 1.0 - eps), np.full(len(kr), 1.0 + eps)])
    inputs = list(_inputs(np.random.default_rng(3)))
    inputs[5], inputs[6] = r, np.concatenate([kr, kr])
    _, scalars = _run(inputs, wp.float64, wp.vec3d)
    below, above = scalars[: len(kr)], scalars[len(kr) :]
    np.testing.assert_allclose(below[:, 6], kr, atol=1e-6)
    np.testing.assert_allclose(above[:, 6], kr, atol=1e-6)
    np.testing.assert_allclose(below[1:, 9], above[1:, 9], atol=1e-4)  # k_r = 0 has C = 0 above 1
    assert np.all((scalars[:, 6] >= 0.0) & (scalars[:, 6] <= 1.0))
    inputs[5] = np.zeros(N)
    _, scalars = _run(inputs, wp.float64, wp.vec3d)
    np.testing.assert_array_equal(scalars[:, 6], 1.0)


def test_derivatives_match_central_differences():
    """d_area_vector, d_area_ratio, d_unit_or_zero, d_bulge_growth and the slope of C against differences."""
    rng = np.random.default_rng(11)
    inputs = list(_inputs(rng))
    inputs[5] = rng.uniform(0.1, 2.0, N)  # away from the floor and the knee
    inputs[5][np.abs(inputs[5] - 1.0) < 1e-3] = 1.5
    inputs[6] = rng.uniform(0.1, 1.0, N)  # rest lengths and k_r away from 0
    step = 1e-6
    vectors, scalars = _run(inputs, wp.float64, wp.vec3d)
    a, b, c, d1, d2, r, kr, h = inputs

    def shifted(sign):
        moved = list(inputs)
        moved[0] = a + sign * step * d1  # p0 along d1 (the unit normal's derivative is taken along d1)
        moved[1] = b + sign * step * (d1 + d1)  # p1 − p0 moves along d1, p2 − p0 along d2 − d1
        moved[2] = c + sign * step * (d2 + d1)
        moved[5] = r + sign * step * h  # r along dr = h
        return _run(moved, wp.float64, wp.vec3d)

    (v_plus, s_plus), (v_minus, s_minus) = shifted(1.0), shifted(-1.0)
    diff_v = (v_plus - v_minus) / (2 * step)
    diff_s = (s_plus - s_minus) / (2 * step)
    np.testing.assert_allclose(vectors[:, 3], diff_v[:, 2], rtol=1e-6, atol=1e-6)  # d(area) with de1 = d1, de2 = d2
    np.testing.assert_allclose(vectors[:, 5], diff_v[:, 4], rtol=1e-6, atol=1e-6)  # d(unit) along d1
    np.testing.assert_allclose(scalars[:, 4], diff_s[:, 3], rtol=1e-6, atol=1e-6)  # d(growth), dr = h
    np.testing.assert_allclose(scalars[:, 9] * h, diff_s[:, 6], rtol=1e-6, atol=1e-6)  # dC/dr · dr
    np.testing.assert_allclose(scalars[:, 1], diff_s[:, 0], rtol=1e-6, atol=1e-6)  # d(S'/S)
