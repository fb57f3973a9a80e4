"""The solver's view of a rig: its operators in float64 and the neighbourhood a set of targets needs.

The model ``x3(c)`` of SPEC §1 at a vertex depends on a bounded neighbourhood of the rest mesh:

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

:class:`RigOperators` holds the rig's data once per rig; :class:`Neighbourhood` gathers the two rings
around the observed vertices (a 68-landmark solve touches ~1.5k of the built-in face's 9.4k vertices).
The evaluation of ``x3`` and ``∂x3/∂c`` on them is :class:`.local_kernels.LocalExpression` (Warp kernels).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .._validate import expect_instance
from ..expression.fold_guard import face_size
from ..expression.kernels import STRETCH_FLOOR as EXPRESSION_STRETCH_FLOOR
from ..expression.rig_fields import rig_fields
from ..rig import FaceRig

__all__ = ["RigOperators", "Neighbourhood", "STRETCH_FLOOR", "REST_STRETCH_BAND"]

STRETCH_FLOOR = float(EXPRESSION_STRETCH_FLOOR)
"""Lower bound on the stretch ratio before ``1/r``: the expression model's own, so both bulge alike."""
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
        size = face_size(rest, getattr(rig, "landmarks", None))  # as ExpressionModel.from_rig measures it
        jaw = getattr(rig, "jaw", None)
        fields = rig_fields(mesh, rig.muscles, rig.wrinkles, rig.thickness, jaw, size, device=device)  # the model's
        muscles, wrinkles = fields.weights, fields.shapes
        bulging, shape = fields.bulging, fields.faded  # the guarded h and profiles (docs/RIG.md §14)
        entry_vertex = np.repeat(np.arange(vertex_count), np.diff(muscles.offsets))
        rows = (3 * entry_vertex[:, None] + np.arange(3)[None, :]).ravel()
        columns = np.repeat(muscles.muscle.astype(np.int64), 3)
        field = sp.csr_matrix((muscles.weight.ravel(), (rows, columns)), shape=(3 * vertex_count, len(rig.muscles)))
        depth = np.array([w.depth for w in rig.wrinkles], dtype=np.float64)
        entry_vertex = np.repeat(np.arange(vertex_count), np.diff(wrinkles.offsets))
        profile = sp.csr_matrix(
            (depth[wrinkles.wrinkle] * shape, (entry_vertex, wrinkles.wrinkle.astype(np.int64))),
            shape=(vertex_count, len(rig.wrinkles)),
        )
        kr = np.array([w.kr for w in rig.wrinkles], dtype=np.float64)
        return cls(
            rest,
            triangles,
            weight,
            rest_length,
            counts,
            incidence,
            field,
            bulging,
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


def _incident(incidence: sp.csr_matrix, vertices: np.ndarray) -> np.ndarray:
    return np.unique(incidence[vertices].indices)


class Neighbourhood:
    """The two rings of the rest mesh around a set of vertices, and the rig's data restricted to them.

    ``s0`` are the vertices asked for, ``t0`` their incident triangles, ``s1`` the corners of ``t0``,
    ``t1`` the triangles incident to ``s1`` and ``s2`` their corners (module docstring): ``x3`` on ``s0``
    needs ``x2`` on ``s1`` and ``x1`` on ``s2``. Local indices: ``triangles1`` index ``s2``,
    ``triangles0`` index ``s1``; ``s1_in_s2`` and ``s0_in_s1`` place each ring in the next.

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
        """Controls of an evaluation: muscles, then the jaw's three."""
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
        self.rest2 = ops.rest[s2]
        self.field2 = field_matrix[rows].toarray().reshape(len(s2), 3, self.basis_count)
        """``W`` (and the jaw's basis fields) on the neighbourhood, (n2, 3, basis_count)."""
        self.profile0 = ops.wrinkle_profile[s0].toarray()
        """``depth_w · s_w(v)`` on the target vertices, (n, W)."""
        self.kr = ops.wrinkle_kr

    @property
    def reach(self) -> int:
        """Vertices an evaluation touches (the two rings around the targets)."""
        return len(self.rest2)
