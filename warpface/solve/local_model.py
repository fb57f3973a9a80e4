"""The expression pipeline (SPEC §1) and its exact Jacobian on the neighbourhood a target needs, in float64.

The model ``x3(c)`` at a vertex depends on a bounded neighbourhood of the rest mesh:

* ``x3_v = x2_v + height_v(r_v) · N(x2)_v`` needs ``x2`` on the one-ring of ``v`` (the normal);
* ``x2_u = x1_u + (1/r_u − 1) · h_u · N(x1)_u`` needs ``x1`` on the one-ring of ``u``;
* ``x1 = x_rest + W c`` is linear in the controls (a sphincter's displacement is ``K`` times a rest
  field as well), so ``∂x1/∂c = W`` exactly.
* With a jaw (SPEC §6.2) ``x1 = x_jaw(θ, f, l) + W c``. By Rodrigues' formula
  ``R(θ)(x − p) = (x − p) + sin θ · a×(x − p) + (1 − cos θ) · a×(a×(x − p))``, so
  ``x_jaw = x_rest + w·(sin θ · A + (1 − cos θ) · B + f·e_forward + l·e_left)`` is linear in the *basis*
  ``b = (sin θ, 1 − cos θ, f, l)`` with constant fields ``w·A``, ``w·B``, ``w·e_forward``, ``w·e_left``.
  The pipeline runs on the basis (four extra columns of ``W``) and the chain rule
  ``∂x/∂θ = cos θ · ∂x/∂b₀ + sin θ · ∂x/∂b₁`` turns its derivatives into the jaw's three controls.

:class:`LocalExpression` gathers the two rings around the observed vertices once, then evaluates
``x3`` and, in forward mode, ``∂x3/∂c`` (one derivative column per control) on those rows only:
a 68-landmark solve touches ~1.5k of the built-in face's 9.4k vertices. Every stage is the chain rule
of the formulas the Warp kernels evaluate (same stretch floor, same degenerate-triangle weights), so
``x3`` agrees with :class:`~warpface.ExpressionModel` to float32 rounding. Arrays carry a frame axis
second — values ``(n, F, 3)``, derivatives ``(n, F, 3, M)`` — so many frames evaluate in one pass and
the incidence sums are single sparse products; results are returned frame-first.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .._validate import MAX_COORDINATE, as_finite_array, expect_instance
from ..expression.tissue import skin_muscle_weights
from ..expression.wrinkles import wrinkle_shapes
from ..rig import FaceRig

__all__ = ["RigOperators", "LocalExpression", "STRETCH_FLOOR", "REST_STRETCH_BAND", "jaw_basis", "jaw_chain_rule"]

STRETCH_FLOOR = 1.0e-4
"""Lower bound on the stretch ratio before ``1/r`` (the value the bulge kernel uses)."""
REST_STRETCH_BAND = 1.0e-12
"""A stretch ratio within this of 1 takes the compressed side of the wrinkle factor. A ``kr = 0``
wrinkle has a kink at ``r = 1`` (slope −1 below, 0 above), and skin the jaw moves rigidly has ``r = 1``
up to rounding: without the band an ulp would pick the derivative's side at random, and two evaluations
of the same iterate (on the host and on the device) would take different Gauss–Newton steps. The value
changes by at most the band times the wrinkle depth."""


@dataclass(frozen=True)
class RigOperators:
    """Everything about a rig the solver needs, precomputed once in float64.

    Attributes:
        rest: rest positions, (V, 3).
        triangles: (T, 3) int64.
        triangle_weight: 1 for counted triangles, 0 for ignored degenerate ones, (T,).
        rest_length: ``|(p1 − p0) × (p2 − p0)|`` at rest (1 for ignored triangles), (T,).
        incident_counts: counted incident triangles per vertex, (V,).
        incidence: vertex × triangle incidence, sparse (V, T) CSR of ones.
        muscle_field: displacement per unit control, sparse rows of ``W``: (V·3, M) CSR.
        thickness: (V,) [mesh units].
        wrinkle_profile: ``depth_w · s_w(v)``, sparse (V, W) CSR.
        wrinkle_kr: (W,).
        jaw_field: the jaw's four basis fields (module docstring), sparse (V·3, 4) CSR, or None without a jaw.
    """

    rest: np.ndarray
    triangles: np.ndarray
    triangle_weight: np.ndarray
    rest_length: np.ndarray
    incident_counts: np.ndarray
    incidence: sp.csr_matrix
    muscle_field: sp.csr_matrix
    thickness: np.ndarray
    wrinkle_profile: sp.csr_matrix
    wrinkle_kr: np.ndarray
    jaw_field: sp.csr_matrix | None = None

    @property
    def muscle_count(self) -> int:
        return self.muscle_field.shape[1]

    @property
    def control_count(self) -> int:
        """Muscles, then the jaw's three controls when there is a jaw."""
        return self.muscle_count + (0 if self.jaw_field is None else 3)

    def control_reach(self) -> np.ndarray:
        """Largest skin displacement per unit of each control, (control_count,) [mesh units per unit]
        (0 for a control that moves nothing): muscles, then jaw_open (per radian), jaw_forward, jaw_left."""
        reach = np.abs(self.muscle_field).max(axis=0).toarray().ravel()
        if self.jaw_field is None:
            return reach
        fields = np.asarray(self.jaw_field.toarray()).reshape(-1, 3, 4)
        length = np.linalg.norm(fields, axis=1).max(axis=0)
        return np.concatenate([reach, [length[0], length[2], length[3]]])

    @classmethod
    def from_rig(cls, rig, *, device=None) -> "RigOperators":
        expect_instance(rig, FaceRig, "rig")
        mesh = rig.mesh
        rest = np.asarray(mesh.points, dtype=np.float64)
        triangles = mesh.triangles.astype(np.int64)
        vertex_count, triangle_count = len(rest), len(triangles)
        weight = (~mesh.degenerate_triangles).astype(np.float64)
        p = rest[triangles]
        length = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
        rest_length = np.where(weight > 0.0, length, 1.0)
        counts = np.bincount(triangles[weight > 0.0].ravel(), minlength=vertex_count).astype(np.float64)
        incidence = sp.csr_matrix(
            (np.ones(3 * triangle_count), (triangles.ravel(), np.repeat(np.arange(triangle_count), 3))),
            shape=(vertex_count, triangle_count),
        )
        muscles = skin_muscle_weights(
            mesh, list(rig.muscles), rig.thickness, device=device
        )  # with sliding and bunching
        entry_vertex = np.repeat(np.arange(vertex_count), np.diff(muscles.offsets))
        rows = (3 * entry_vertex[:, None] + np.arange(3)[None, :]).ravel()
        columns = np.repeat(muscles.muscle.astype(np.int64), 3)
        field = sp.csr_matrix((muscles.weight.ravel(), (rows, columns)), shape=(3 * vertex_count, len(rig.muscles)))
        wrinkles = wrinkle_shapes(rest, list(rig.wrinkles), device=device)
        depth = np.array([w.depth for w in rig.wrinkles], dtype=np.float64)
        entry_vertex = np.repeat(np.arange(vertex_count), np.diff(wrinkles.offsets))
        profile = sp.csr_matrix(
            (depth[wrinkles.wrinkle] * wrinkles.shape, (entry_vertex, wrinkles.wrinkle.astype(np.int64))),
            shape=(vertex_count, len(rig.wrinkles)),
        )
        kr = np.array([w.kr for w in rig.wrinkles], dtype=np.float64)
        jaw = getattr(rig, "jaw", None)
        return cls(
            rest,
            triangles,
            weight,
            rest_length,
            counts,
            incidence,
            field,
            np.asarray(rig.thickness, dtype=np.float64),
            profile,
            kr,
            None if jaw is None else _jaw_fields(jaw, rest),
        )


def _jaw_fields(jaw, rest: np.ndarray) -> sp.csr_matrix:
    """``w·(a×(x − p), a×(a×(x − p)), e_forward, e_left)`` per vertex: (V·3, 4) CSR (module docstring)."""
    arm = rest - jaw.pivot
    across = np.cross(jaw.axis, arm)
    twice = np.cross(jaw.axis, across)
    ones = np.ones_like(arm)
    columns = np.stack([across, twice, ones * jaw.forward, ones * jaw.left], axis=2) * jaw.weights[:, None, None]
    matrix = sp.csr_matrix(columns.reshape(-1, 4))
    matrix.eliminate_zeros()
    return matrix


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


def _incident(incidence: sp.csr_matrix, vertices: np.ndarray) -> np.ndarray:
    return np.unique(incidence[vertices].indices)


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


class LocalExpression:
    """``x3(c)`` and ``∂x3/∂c`` at a fixed set of vertices (the union of what the targets touch).

    Args:
        operators: the rig's :class:`RigOperators`.
        vertices: the vertices whose final positions are needed, (n,) int.
    """

    def __init__(self, operators: RigOperators, vertices: np.ndarray):
        ops = self.operators = operators
        s0 = np.unique(np.asarray(vertices, dtype=np.int64))
        t0 = _incident(ops.incidence, s0)
        s1 = np.union1d(s0, np.unique(ops.triangles[t0]))
        t1 = _incident(ops.incidence, s1)
        s2 = np.union1d(s1, np.unique(ops.triangles[t1]))
        self.vertices = s0
        self.count = len(s0)
        self.muscle_count = ops.muscle_count
        self.has_jaw = ops.jaw_field is not None
        self.control_count = ops.control_count
        """Controls of :meth:`evaluate`: muscles, then the jaw's three."""
        self.basis_count = self.muscle_count + (4 if self.has_jaw else 0)
        """Columns the pipeline propagates (the jaw's angle as ``sin θ, 1 − cos θ``)."""
        field_matrix = ops.muscle_field if not self.has_jaw else sp.hstack([ops.muscle_field, ops.jaw_field]).tocsr()
        local2 = np.full(len(ops.rest), -1, dtype=np.int64)
        local2[s2] = np.arange(len(s2))
        local1 = np.full(len(ops.rest), -1, dtype=np.int64)
        local1[s1] = np.arange(len(s1))
        self.s1_in_s2 = local2[s1]
        self.s0_in_s1 = local1[s0]
        self.triangles1 = local2[ops.triangles[t1]]
        self.triangle_weight1 = ops.triangle_weight[t1]
        self.rest_length1 = ops.rest_length[t1]
        self.triangles0 = local1[ops.triangles[t0]]
        self.triangle_weight0 = ops.triangle_weight[t0]
        self.incidence1 = sp.csr_matrix(ops.incidence[s1][:, t1])
        self.incidence0 = sp.csr_matrix(ops.incidence[s0][:, t0])
        self.counts1 = ops.incident_counts[s1]
        self.thickness1 = ops.thickness[s1]
        rows = (3 * s2[:, None] + np.arange(3)[None, :]).ravel()
        field = field_matrix[rows].toarray().reshape(len(s2), 3, self.basis_count)
        self.rest2 = ops.rest[s2]
        self.field2 = field
        """``W`` (and the jaw's basis fields) on the neighbourhood, (n2, 3, basis_count)."""
        self._field_matrix = sp.csr_matrix(field.reshape(len(s2) * 3, self.basis_count))
        self._dx1 = field[:, None]  # (n2, 1, 3, M): constant in the controls and the same for every frame
        self.profile0 = ops.wrinkle_profile[s0].toarray()
        self.kr = ops.wrinkle_kr
        self._wrinkled0 = np.flatnonzero(np.any(self.profile0 != 0.0, axis=1))

    @property
    def reach(self) -> int:
        """Vertices the evaluation touches (the two rings around the targets)."""
        return len(self.rest2)

    def evaluate(self, controls: np.ndarray, *, jacobian: bool = True):
        """Final positions at ``vertices`` for each frame, and their derivatives.

        Args:
            controls: (F, C) contractions in muscle order, then the jaw's controls when there is a jaw.
            jacobian: also return ``∂x3/∂c``.

        Returns:
            ``x3`` (F, n, 3) and, with ``jacobian``, ``∂x3/∂c`` (F, n, 3, C) — else ``None``.
        """
        controls = as_finite_array(controls, "controls", shape=(None, self.control_count), max_abs=MAX_COORDINATE)
        if not self.has_jaw:
            return self._evaluate_basis(controls, jacobian)
        x3, dx3 = self._evaluate_basis(jaw_basis(controls, self.muscle_count), jacobian)
        return x3, (None if dx3 is None else jaw_chain_rule(dx3, controls, self.muscle_count))

    def _evaluate_basis(self, controls: np.ndarray, jacobian: bool):
        frames = controls.shape[0]
        moved = (self._field_matrix @ controls.T).reshape(len(self.rest2), 3, frames).transpose(0, 2, 1)
        x1 = self.rest2[:, None, :] + moved
        dx1 = self._dx1 if jacobian else None

        # Stretch and normal of the muscle-deformed surface on the first ring.
        i, j, k = self.triangles1[:, 0], self.triangles1[:, 1], self.triangles1[:, 2]
        e1, e2 = x1[j] - x1[i], x1[k] - x1[i]
        w1 = self.triangle_weight1[:, None, None]
        area = w1 * _cross(e1, e2)
        length = np.linalg.norm(area, axis=2)
        ratio = length / self.rest_length1[:, None]
        counts = self.counts1[:, None]
        has = counts > 0.0
        r = np.where(has, _spmul(self.incidence1, ratio) / np.where(has, counts, 1.0), 1.0)
        normal, dnormal = None, None
        normal_sum = _spmul(self.incidence1, area)
        if jacobian:
            de1, de2 = dx1[j] - dx1[i], dx1[k] - dx1[i]
            darea = w1[..., None] * (_cross(de1, e2[..., None]) + _cross(e1[..., None], de2))
            safe = np.where(length > 0.0, length, 1.0)
            dratio = np.einsum("tfi,tfim->tfm", area, darea) / (safe * self.rest_length1[:, None])[..., None]
            dratio = np.where((length > 0.0)[..., None], dratio, 0.0)
            dr = np.where(has[..., None], _spmul(self.incidence1, dratio) / np.where(has, counts, 1.0)[..., None], 0.0)
            normal, dnormal = _normalize(normal_sum, _spmul(self.incidence1, darea))
        else:
            normal, _ = _normalize(normal_sum, None)
        clamped = np.maximum(r, STRETCH_FLOOR)
        growth = 1.0 / clamped - 1.0
        h = self.thickness1[:, None]
        x2 = x1[self.s1_in_s2] + (growth * h)[..., None] * normal
        if jacobian:
            dgrowth = np.where((r > STRETCH_FLOOR)[..., None], -dr / (clamped * clamped)[..., None], 0.0)
            dx2 = dx1[self.s1_in_s2] + h[..., None, None] * (
                dgrowth[:, :, None, :] * normal[..., None] + growth[..., None, None] * dnormal
            )

        # Wrinkles along the normal of the bulged surface, on the target vertices.
        x3 = x2[self.s0_in_s1].copy()
        dx3 = (
            np.broadcast_to(dx2[self.s0_in_s1], (self.count, frames, 3, self.basis_count)).copy() if jacobian else None
        )
        rows = self._wrinkled0
        if len(rows):
            r0 = r[self.s0_in_s1][rows]  # (n, F)
            kr = self.kr[None, None, :]
            below = r0[..., None] <= 1.0 + REST_STRETCH_BAND
            safe_kr = np.where(kr > 0.0, kr, 1.0)
            above = np.where(kr > 0.0, kr * np.exp((1.0 - 1.0 / safe_kr) * (r0[..., None] - 1.0)), 0.0)
            factor = np.where(below, (kr - 1.0) * r0[..., None] + 1.0, above)
            profile = self.profile0[rows][:, None, :]
            height = np.sum(profile * factor, axis=2)
            i, j, k = self.triangles0[:, 0], self.triangles0[:, 1], self.triangles0[:, 2]
            e1, e2 = x2[j] - x2[i], x2[k] - x2[i]
            w0 = self.triangle_weight0[:, None, None]
            area = w0 * _cross(e1, e2)
            incidence = self.incidence0[rows]
            if jacobian:
                de1, de2 = dx2[j] - dx2[i], dx2[k] - dx2[i]
                darea = w0[..., None] * (_cross(de1, e2[..., None]) + _cross(e1[..., None], de2))
                n2, dn2 = _normalize(_spmul(incidence, area), _spmul(incidence, darea))
                slope = np.where(below, kr - 1.0, np.where(kr > 0.0, (1.0 - 1.0 / safe_kr) * above, 0.0))
                dheight = np.sum(profile * slope, axis=2)[..., None] * dr[self.s0_in_s1][rows]
                dx3[rows] += dheight[:, :, None, :] * n2[..., None] + height[..., None, None] * dn2
            else:
                n2, _ = _normalize(_spmul(incidence, area), None)
            x3[rows] += height[..., None] * n2
        return x3.transpose(1, 0, 2), (dx3.transpose(1, 0, 2, 3) if jacobian else None)
