"""Calibrate a channel → control mapping from a character's own example shapes (SPEC §6.4).

A character that ships its blendshapes (its ARKit shapes, say) already says what each channel should
look like. Solving every example for the rig's controls with the activation solver (SPEC §6.1) gives
one control vector per channel; :meth:`Mapping.from_examples` turns those into the columns of ``M``, so
a one-hot weight on a channel reproduces the solver's fit of that channel's example — to within the
solver's residual, which is what the rig can reach of that shape.
"""

from __future__ import annotations

from collections.abc import Mapping as MappingABC

import numpy as np

from .._validate import expect_instance
from ..rig import FaceRig
from .channels import canonical_channel
from .mapping import Mapping

__all__ = ["calibrate_mapping"]


def calibrate_mapping(
    rig, examples, *, neutral=None, vertices=None, device=None, name: str = "calibrated", **solve_options
):
    """A :class:`Mapping` whose one-hot weights reproduce each example shape.

    Args:
        rig: the :class:`warpface.FaceRig` whose controls the mapping drives.
        examples: ``{channel: shape}``: each channel's example at full weight, shape (V, 3) with the rig's
            topology, in the rig's units. Channel names are canonicalised (``BrowInnerUp`` → ``browInnerUp``).
        neutral: the character's neutral shape (V, 3); solved too and used as the offset ``c₀``. Default:
            the rig's rest shape (``c₀ = 0``).
        vertices: (N,) vertex indices: fit only these points of each shape (e.g. its landmarks).
        device: Warp device of the solves.
        name: the mapping's name (its prim name on a rig stage).
        **solve_options: options of :func:`warpface.solve.fit` (``l1``, ``symmetry``, ...).

    Returns:
        ``(mapping, fits)``: the calibrated mapping and ``{channel: Fit}`` (each fit's ``residual`` is the
        RMS distance, in the rig's units, that the rig leaves of that example).

    Raises:
        ValueError: no examples, a repeated channel, or a shape the solver refuses (named).
    """
    expect_instance(rig, FaceRig, "rig")
    from ..solve import fit

    if not isinstance(examples, MappingABC):
        raise TypeError(f"examples: expected a {{channel: (V, 3) shape}} mapping, got {type(examples).__name__}")
    if len(examples) == 0:
        raise ValueError("examples: expected a non-empty {channel: (V, 3) shape} mapping")
    channels = [canonical_channel(channel) for channel in examples]
    repeated = sorted({c for c in channels if channels.count(c) > 1})
    if repeated:
        raise ValueError(f"examples: channels given twice after canonical naming: {repeated}")
    index = None if vertices is None else np.asarray(vertices)

    def solve(label, shape):
        target = np.asarray(shape, dtype=np.float64)
        if index is not None and target.ndim == 2 and len(target) == rig.mesh.vertex_count:
            target = target[index]
        try:
            return fit(rig, target, vertices=index, device=device, **solve_options)
        except (ValueError, TypeError) as error:
            raise type(error)(f"examples[{label!r}]: {error}") from None

    fits = {channel: solve(original, shape) for channel, (original, shape) in zip(channels, examples.items())}
    controls = list(next(iter(fits.values())).controls)
    solved = np.array([[fits[c].controls[k] for k in controls] for c in channels])
    neutral_controls = None
    if neutral is not None:
        base = solve("neutral", neutral)
        neutral_controls = np.array([base.controls[k] for k in controls])
    return Mapping.from_examples(channels, controls, solved, neutral_controls, name=name), fits
