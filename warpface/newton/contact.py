"""Newton's particle–shape soft contacts as normal forces on the skin nodes, solved with the tissue's step
(docs/NEWTON.md §3).

A contact ``k`` (node ``i``, outward shape normal ``n``, surface point ``s``, all in the head frame at the end of
the step) keeps the node at least its particle radius ``ρ`` off the surface: gap ``g_k = n·(X_i + d_i − s) − ρ
≥ 0``. Its force ``λ_k n`` (``λ_k ≥ 0``, acting only while the gap is closed) enters the Newmark step like any
external force; the step being linear, the displacement is the contact-free one plus ``A_oo⁻¹ Σ λ_k e_k``, so
the gaps are ``g = g⁰ + W λ`` with the Delassus matrix ``W_jk = e_jᵀ A_oo⁻¹ e_k`` (``e_k``: ``n`` at node
``i``). ``λ`` solves the complementarity problem ``λ ≥ 0, g ≥ 0, λ·g = 0`` (active set on the small dense
``W``). A solution that would squash a tet below :data:`MIN_VOLUME_FRACTION` of its rest volume (or invert it)
is scaled back until no tet does, and the step reports the clamp.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..fem.tetmesh import tet_signed_volumes

__all__ = ["MIN_VOLUME_FRACTION", "ContactReport", "ContactSet", "gather_contacts", "solve_contacts"]


@dataclass(frozen=True)
class ContactSet:
    """Soft contacts on the face's contact nodes, in the head frame (float64)."""

    nodes: np.ndarray
    """Tissue node of each contact, shape (K,), int64."""
    normals: np.ndarray
    """Unit outward normal of the shape, shape (K, 3)."""
    points: np.ndarray
    """Closest point of the shape's surface, shape (K, 3) [m]."""


@dataclass(frozen=True)
class ContactReport:
    """What the last step did with its contacts."""

    count: int = 0
    """Contacts Newton reported on the face's contact nodes."""
    active: int = 0
    """Contacts that pushed (λ > 0)."""
    total_force: float = 0.0
    """Σ λ [N]."""
    scale: float = 1.0
    """Fraction of the contact solution applied: < 1 when it was clamped to keep every tet upright."""

    @property
    def clamped(self) -> bool:
        """True when the contact forces were scaled back (a tet would have been squashed or inverted)."""
        return self.scale < 1.0


MIN_VOLUME_FRACTION = 0.05
"""A contact may squash a tet to this fraction of its rest volume, no further (0 would be inversion)."""


def gather_contacts(model, contacts, state_out, particle_start: int, contact_mask: np.ndarray, motion) -> ContactSet:
    """The soft contacts of Newton's ``contacts`` on the face's contact nodes (``contact_mask``, (N,) bool), moved
    into the head frame of ``motion`` with the shapes' bodies at their ``state_out`` poses."""
    from .frame import quat_matrix

    count = int(contacts.soft_contact_count.numpy()[0]) if contacts is not None else 0
    count = min(count, contacts.soft_contact_particle.shape[0]) if count else 0
    empty = ContactSet(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
    if count == 0:
        return empty
    node = contacts.soft_contact_particle.numpy()[:count].astype(np.int64) - particle_start
    inside = (node >= 0) & (node < contact_mask.size)
    inside[inside] = contact_mask[node[inside]]
    if not inside.any():
        return empty
    node = node[inside]
    shape = contacts.soft_contact_shape.numpy()[:count][inside]
    local = contacts.soft_contact_body_pos.numpy()[:count][inside].astype(np.float64)
    normal = contacts.soft_contact_normal.numpy()[:count][inside].astype(np.float64)
    body = model.shape_body.numpy()[shape]
    world = local.copy()
    if (body >= 0).any():
        poses = state_out.body_q.numpy()
        for k in np.flatnonzero(body >= 0):
            pose = poses[body[k]]
            world[k] = pose[:3] + quat_matrix(pose[3:7]) @ local[k]
    rt = motion.rotation.T
    return ContactSet(node, normal @ rt.T, (world - motion.position) @ rt.T)


def _complementarity(W: np.ndarray, g0: np.ndarray, iterations: int = 100) -> np.ndarray:
    """λ ≥ 0 with ``g0 + W λ ≥ 0`` and ``λ·(g0 + W λ) = 0`` for a symmetric positive (semi)definite W (K, K)."""
    k = len(g0)
    scale = max(float(np.abs(g0).max()), 1e-300)
    active = g0 < 0.0
    lam = np.zeros(k)
    for _ in range(iterations):
        lam = np.zeros(k)
        if active.any():
            sub = W[np.ix_(active, active)]
            lam[active] = np.linalg.lstsq(sub, -g0[active], rcond=None)[0]
        negative = active & (lam < 0.0)
        if negative.any():
            active[np.argmin(np.where(negative, lam, np.inf))] = False  # drop the most negative, one at a time
            continue
        gap = g0 + W @ lam
        violated = ~active & (gap < -1e-9 * scale)
        if not violated.any():
            return lam
        active[np.argmin(np.where(violated, gap, np.inf))] = True
    return np.maximum(lam, 0.0)


def solve_contacts(
    contacts: ContactSet, rest: np.ndarray, d: np.ndarray, radius: float, free_index: np.ndarray, solve
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The contact forces of one step: ``(λ (K,) [N], correction (3F,) [m] of the free dofs, gaps (K,) [m]
    before the forces)``.

    Args:
        contacts: The step's contacts (head frame).
        rest: Rest positions X (N, 3) [m].
        d: Contact-free displacement at the end of the step (N, 3) [m].
        radius: Particle radius ρ [m].
        free_index: Position of each node among the free nodes, -1 for constrained ones, shape (N,).
        solve: ``A_oo⁻¹`` on a free-dof vector (3F,).
    """
    nodes, normals = contacts.nodes, contacts.normals
    g0 = np.einsum("kj,kj->k", normals, rest[nodes] + d[nodes] - contacts.points) - radius
    dofs = 3 * int((free_index >= 0).sum())
    slots = free_index[nodes]
    columns = np.zeros((dofs, len(nodes)))
    needed = np.flatnonzero(g0 < radius)  # gaps already wider than the radius stay open: their forces are 0
    for k in needed:
        e = np.zeros(dofs)
        e[3 * slots[k] : 3 * slots[k] + 3] = normals[k]
        columns[:, k] = solve(e)
    lam = np.zeros(len(nodes))
    if needed.size:
        along = columns[np.add.outer(3 * slots[needed], np.arange(3)).ravel()][:, needed]  # (3K', K')
        W = np.einsum("kj,kjl->kl", normals[needed], along.reshape(needed.size, 3, needed.size))
        W = 0.5 * (W + W.T)
        lam[needed] = _complementarity(W, g0[needed])
    return lam, columns @ lam, g0


def upright_scale(tets: np.ndarray, rest_volumes: np.ndarray, positions, correction) -> float:
    """The largest ``s`` in [0, 1] for which ``positions + s·correction`` (N, 3) keeps every tet above
    :data:`MIN_VOLUME_FRACTION` of its rest volume (bisection, 1e-3 wide); 1 when ``s = 1`` already does."""

    def upright(s: float) -> bool:
        volumes = tet_signed_volumes(positions + s * correction, tets)
        return bool(np.all(volumes > MIN_VOLUME_FRACTION * rest_volumes))

    if upright(1.0):
        return 1.0
    low, high = 0.0, 1.0
    while high - low > 1e-3:
        mid = 0.5 * (low + high)
        low, high = (mid, high) if upright(mid) else (low, mid)
    return low
