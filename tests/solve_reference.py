"""A float64 NumPy reference of the solver's neighbourhood evaluation: x3 and its exact Jacobian.

The oracle the Warp kernels of :mod:`warpface.solve.local_kernels` are tested against: the same
formulas (SPEC §1, the jaw's basis of :mod:`warpface.solve.local_model`) written with dense NumPy
arrays and sparse incidence products instead of per-element threads and active-column lists. Arrays
carry a frame axis second — values ``(n, F, 3)``, derivatives ``(n, F, 3, M)``; results are frame-first.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from warpface.solve.local_model import REST_STRETCH_BAND, STRETCH_FLOOR


def jaw_basis(controls: np.ndarray, muscle_count: int) -> np.ndarray:
    """Controls (F, M + 3) → pipeline basis (F, M + 4): ``θ`` becomes ``(sin θ, 1 − cos θ)``."""
    angle = controls[:, muscle_count : muscle_count + 1]
    return np.concatenate(
        [controls[:, :muscle_count], np.sin(angle), 1.0 - np.cos(angle), controls[:, muscle_count + 1 :]], axis=1
    )


def jaw_chain_rule(derivative: np.ndarray, controls: np.ndarray, muscle_count: int) -> np.ndarray:
    """Basis derivatives (F, …, M + 4) → control derivatives (F, …, M + 3) at controls (F, M + 3)."""
    angle = controls[:, muscle_count].reshape((-1,) + (1,) * (derivative.ndim - 2))
    m = muscle_count
    opening = derivative[..., m] * np.cos(angle) + derivative[..., m + 1] * np.sin(angle)
    return np.concatenate([derivative[..., :m], opening[..., None], derivative[..., m + 2 :]], axis=-1)


def _cross(u, v):
    """Cross product over axis 2 of (n, F, 3[, M]) arrays (broadcasting)."""
    return np.stack(
        [
            u[:, :, 1] * v[:, :, 2] - u[:, :, 2] * v[:, :, 1],
            u[:, :, 2] * v[:, :, 0] - u[:, :, 0] * v[:, :, 2],
            u[:, :, 0] * v[:, :, 1] - u[:, :, 1] * v[:, :, 0],
        ],
        axis=2,
    )


def _normalize(m, dm):
    """Unit vector of ``m`` (n, F, 3) and its derivative from ``dm`` (n, F, 3, M); zero where |m| = 0."""
    length = np.linalg.norm(m, axis=2, keepdims=True)
    safe = np.where(length > 0.0, length, 1.0)
    n = np.where(length > 0.0, m / safe, 0.0)
    if dm is None:
        return n, None
    along = np.einsum("nfi,nfim->nfm", n, dm)
    dn = (dm - n[..., None] * along[:, :, None, :]) / safe[..., None]
    return n, np.where(length[..., None] > 0.0, dn, 0.0)


def _spmul(matrix: sp.csr_matrix, values: np.ndarray) -> np.ndarray:
    """``matrix @ values`` over the leading axis of an n-D array."""
    out = matrix @ values.reshape(values.shape[0], -1)
    return np.asarray(out).reshape((matrix.shape[0],) + values.shape[1:])


def evaluate(local, controls: np.ndarray, *, jacobian: bool = True):
    """``x3`` (F, n, 3) at ``local.vertices`` and, with ``jacobian``, ``∂x3/∂c`` (F, n, 3, C), else None.

    ``local`` is a :class:`~warpface.solve.local_model.Neighbourhood`; ``controls`` (F, C): muscles, then
    the jaw's three when the rig has a jaw.
    """
    controls = np.asarray(controls, dtype=np.float64).reshape(-1, local.control_count)
    if not local.has_jaw:
        return _evaluate_basis(local, controls, jacobian)
    x3, dx3 = _evaluate_basis(local, jaw_basis(controls, local.muscle_count), jacobian)
    return x3, (None if dx3 is None else jaw_chain_rule(dx3, controls, local.muscle_count))


def _evaluate_basis(local, controls: np.ndarray, jacobian: bool):
    frames = controls.shape[0]
    field = sp.csr_matrix(local.field2.reshape(len(local.rest2) * 3, local.basis_count))
    moved = (field @ controls.T).reshape(len(local.rest2), 3, frames).transpose(0, 2, 1)
    x1 = local.rest2[:, None, :] + moved
    dx1 = local.field2[:, None] if jacobian else None  # constant in the controls, the same for every frame

    # Stretch and normal of the muscle-deformed surface on the first ring.
    i, j, k = local.triangles1[:, 0], local.triangles1[:, 1], local.triangles1[:, 2]
    e1, e2 = x1[j] - x1[i], x1[k] - x1[i]
    w1 = local.triangle_weight1[:, None, None]
    area = w1 * _cross(e1, e2)
    length = np.linalg.norm(area, axis=2)
    ratio = length / local.rest_length1[:, None]
    counts = local.counts1[:, None]
    has = counts > 0.0
    r = np.where(has, _spmul(local.incidence1, ratio) / np.where(has, counts, 1.0), 1.0)
    normal, dnormal = None, None
    normal_sum = _spmul(local.incidence1, area)
    if jacobian:
        de1, de2 = dx1[j] - dx1[i], dx1[k] - dx1[i]
        darea = w1[..., None] * (_cross(de1, e2[..., None]) + _cross(e1[..., None], de2))
        safe = np.where(length > 0.0, length, 1.0)
        dratio = np.einsum("tfi,tfim->tfm", area, darea) / (safe * local.rest_length1[:, None])[..., None]
        dratio = np.where((length > 0.0)[..., None], dratio, 0.0)
        dr = np.where(has[..., None], _spmul(local.incidence1, dratio) / np.where(has, counts, 1.0)[..., None], 0.0)
        normal, dnormal = _normalize(normal_sum, _spmul(local.incidence1, darea))
    else:
        normal, _ = _normalize(normal_sum, None)
    clamped = np.maximum(r, STRETCH_FLOOR)
    growth = 1.0 / clamped - 1.0
    h = local.thickness1[:, None]
    x2 = x1[local.s1_in_s2] + (growth * h)[..., None] * normal
    if jacobian:
        dgrowth = np.where((r > STRETCH_FLOOR)[..., None], -dr / (clamped * clamped)[..., None], 0.0)
        dx2 = dx1[local.s1_in_s2] + h[..., None, None] * (
            dgrowth[:, :, None, :] * normal[..., None] + growth[..., None, None] * dnormal
        )

    # Wrinkles along the normal of the bulged surface, on the target vertices.
    x3 = x2[local.s0_in_s1].copy()
    dx3 = np.broadcast_to(dx2[local.s0_in_s1], (local.count, frames, 3, local.basis_count)).copy() if jacobian else None
    rows = np.flatnonzero(np.any(local.profile0 != 0.0, axis=1))
    if len(rows):
        r0 = r[local.s0_in_s1][rows]  # (n, F)
        kr = local.kr[None, None, :]
        below = r0[..., None] <= 1.0 + REST_STRETCH_BAND
        safe_kr = np.where(kr > 0.0, kr, 1.0)
        above = np.where(kr > 0.0, kr * np.exp((1.0 - 1.0 / safe_kr) * (r0[..., None] - 1.0)), 0.0)
        factor = np.where(below, (kr - 1.0) * r0[..., None] + 1.0, above)
        profile = local.profile0[rows][:, None, :]
        height = np.sum(profile * factor, axis=2)
        i, j, k = local.triangles0[:, 0], local.triangles0[:, 1], local.triangles0[:, 2]
        e1, e2 = x2[j] - x2[i], x2[k] - x2[i]
        w0 = local.triangle_weight0[:, None, None]
        area = w0 * _cross(e1, e2)
        incidence = local.incidence0[rows]
        if jacobian:
            de1, de2 = dx2[j] - dx2[i], dx2[k] - dx2[i]
            darea = w0[..., None] * (_cross(de1, e2[..., None]) + _cross(e1[..., None], de2))
            n2, dn2 = _normalize(_spmul(incidence, area), _spmul(incidence, darea))
            slope = np.where(below, kr - 1.0, np.where(kr > 0.0, (1.0 - 1.0 / safe_kr) * above, 0.0))
            dheight = np.sum(profile * slope, axis=2)[..., None] * dr[local.s0_in_s1][rows]
            dx3[rows] += dheight[:, :, None, :] * n2[..., None] + height[..., None, None] * dn2
        else:
            n2, _ = _normalize(_spmul(incidence, area), None)
        x3[rows] += height[..., None] * n2
    return x3.transpose(1, 0, 2), (dx3.transpose(1, 0, 2, 3) if jacobian else None)
