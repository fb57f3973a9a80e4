"""Lips that never cross: a constraint on every muscle's field (docs/RIG.md §12).

A :class:`LipSeal` is a hinge (:class:`~warpface.expression.lids.LidMuscle`) whose field parts the lips:
the upper lip turns up and the lower lip down about an axis behind the mouth. It also names ``pairs``
of (upper, lower) vertices facing each other across the lips' contact line. With ``p`` its field, the
parting of pair ``i`` under a field ``w`` is

``δ_i(w) = (w(u_i) − w(l_i)) · n̂_i``,  ``n̂_i`` the unit of ``p(u_i) − p(l_i)``,

and every other muscle's field (the Waters muscles', and those of hinges that only slide) is replaced, once per
rig, by ``w' = w + a·p`` with the least ``a ≥ 0`` that
makes ``δ_i(w') ≥ 0`` at every pair: ``a = max(0, max_i −δ_i(w)/δ_i(p))``. A muscle on its own then never
brings a pair closer along its parting direction, and since the muscle stage is ``x1 = x + Σ K·w'`` with
``K ≥ 0``, no combination of contractions does: the lips press together and stay sealed (``δ = 0``)
where the muscle would have pushed one through the other. The stage stays linear in the controls, so
the solver's Jacobian is still the weight matrix. The seal's own field and the hinges that turn (the lids, the
lips' rolls) are left as they are: their turns are the rig's own choice (docs/RIG.md §11, §15).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .lids import LidMuscle

__all__ = ["LipSeal", "seal_fields", "sealed_weights"]


@dataclass(frozen=True, eq=False)
class LipSeal(LidMuscle):
    """A lip-parting hinge that also seals every other muscle's field (module docstring).

    Args:
        name, center, axis, vertices, angles, slides, lifts: as :class:`~warpface.expression.LidMuscle`;
            ``K = 1`` parts the lips by its field.
        pairs: (upper, lower) vertex index pairs facing each other across the lips, shape (P, 2), P ≥ 1; its
            field must part each pair (``δ_i(p) > 0``).
    """

    pairs: np.ndarray | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        pairs = np.asarray(self.pairs if self.pairs is not None else np.zeros((0, 2), dtype=np.int64))
        if pairs.ndim != 2 or pairs.shape[1] != 2 or len(pairs) == 0 or not np.issubdtype(pairs.dtype, np.integer):
            raise ValueError(f"lip seal {self.name!r}: pairs must be (P, 2) ints with P ≥ 1, got {pairs.shape}")
        if pairs.min() < 0:
            raise ValueError(f"lip seal {self.name!r}: pairs must be vertex indices ≥ 0")
        object.__setattr__(self, "pairs", pairs.astype(np.int64))

    def check_vertex_count(self, vertex_count: int) -> None:
        super().check_vertex_count(vertex_count)
        if self.pairs.max() >= vertex_count:
            raise ValueError(
                f"lip seal {self.name!r}: pair vertex {int(self.pairs.max())} outside a mesh of {vertex_count} points"
            )


def seal_fields(muscles, fields: list[np.ndarray]) -> list[np.ndarray]:
    """Each muscle's dense field (V, 3) with the seal's share added (module docstring); unchanged without a seal.

    Raises:
        ValueError: more than one :class:`LipSeal`, or a seal whose field does not part one of its pairs.
    """
    seals = [index for index, muscle in enumerate(muscles) if isinstance(muscle, LipSeal)]
    if not seals:
        return fields
    if len(seals) > 1:
        raise ValueError(f"muscles: at most one lip seal, got {len(seals)}")
    seal = muscles[seals[0]]
    upper, lower = seal.pairs[:, 0], seal.pairs[:, 1]
    part = fields[seals[0]]
    opening = part[upper] - part[lower]
    parting = np.linalg.norm(opening, axis=1)
    if np.any(parting <= 0.0):
        raise ValueError(f"lip seal {seal.name!r}: its field does not part pair {int(np.argmin(parting))}")
    direction = opening / parting[:, None]
    out = []
    for muscle, field in zip(muscles, fields):
        if isinstance(muscle, LidMuscle) and (isinstance(muscle, LipSeal) or muscle.turns):
            out.append(field)
            continue
        closing = -np.sum((field[upper] - field[lower]) * direction, axis=1) / parting
        share = max(0.0, float(closing.max()))
        out.append(field + share * part if share > 0.0 else field)
    return out


def sealed_weights(muscles, weights):
    """:class:`~warpface.expression.muscles.MuscleWeights` with :func:`seal_fields` applied (the same weights when
    the muscles hold no :class:`LipSeal`)."""
    from .muscles import MuscleWeights  # muscles imports lids, as this module does

    if not any(isinstance(muscle, LipSeal) for muscle in muscles):
        return weights
    vertex_count = len(weights.offsets) - 1
    row = np.repeat(np.arange(vertex_count), np.diff(weights.offsets))
    fields = []
    for index in range(len(muscles)):
        mine = weights.muscle == index
        field = np.zeros((vertex_count, 3))
        field[row[mine]] = weights.weight[mine]
        fields.append(field)
    return MuscleWeights.from_fields(vertex_count, seal_fields(list(muscles), fields))
