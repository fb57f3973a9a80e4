"""Channel → control mappings (SPEC §6.4): ``c = M·s + c₀``, one column of ``M`` per channel.

A :class:`Mapping` is plain data: channel names, control names, the matrix and the offsets, in the
rig's control units (linear-muscle contractions in the rig's length unit, sphincter contractions and
angles dimensionless). Channels combine linearly: two channels that pull the same muscle add up.
"""

from __future__ import annotations

from collections.abc import Mapping as MappingABC
from dataclasses import dataclass, field

import numpy as np

from .._validate import as_finite_array, expect_instance, expect_iterable
from .channels import Curves

__all__ = ["Mapping", "MappedControls"]


@dataclass(frozen=True)
class MappedControls:
    """Controls over time from :meth:`Mapping.apply`."""

    times: np.ndarray
    """Timestamps [s], shape (F,)."""
    names: list[str]
    """Control names, K of them."""
    values: np.ndarray
    """Control values, shape (F, K)."""
    unmapped_channels: list[str]
    """Channels of the curves the mapping has no column for (ignored)."""
    active_channels: list[list[str]] = field(default_factory=list)
    """Per frame, the mapped channels with a non-zero value, strongest first (for labels)."""

    def as_dict(self) -> dict[str, np.ndarray]:
        return {name: self.values[:, k] for k, name in enumerate(self.names)}


def _entry(item, position: int) -> tuple[str, str, float]:
    """One ``(channel, control, weight)`` triple of :meth:`Mapping.from_entries`, checked."""
    if isinstance(item, (str, bytes)) or not isinstance(item, (tuple, list)):
        raise TypeError(f"entries[{position}]: expected a (channel, control, weight) triple, got {type(item).__name__}")
    if len(item) != 3:
        raise ValueError(f"entries[{position}]: expected a (channel, control, weight) triple, got {len(item)} items")
    channel, control, weight = item
    if not isinstance(channel, str) or not isinstance(control, str):
        raise TypeError(f"entries[{position}]: channel and control must be names (str)")
    return channel, control, float(as_finite_array(weight, f"entries[{position}] weight", shape=()))


@dataclass(frozen=True)
class Mapping:
    """``controls = matrix · channels + offsets``.

    Attributes:
        channels: channel names, C of them (canonical spelling, see :func:`canonical_channel`).
        controls: control names, K of them (muscle names of the rig; jaw controls when the rig has them).
        matrix: shape (K, C), float64, finite: control value per unit of each channel.
        offsets: shape (K,), float64, finite: ``c₀``, the controls at all-zero channels.
        name: the mapping's name (its prim name under ``<rig>/Drivers`` on a stage).
    """

    channels: list[str]
    controls: list[str]
    matrix: np.ndarray
    offsets: np.ndarray | None = None
    name: str = "default"

    def __post_init__(self) -> None:
        channels = [str(c) for c in expect_iterable(self.channels, f"mapping {self.name!r}: channels", item_types=str)]
        controls = [str(c) for c in expect_iterable(self.controls, f"mapping {self.name!r}: controls", item_types=str)]
        for kind, names in (("channel", channels), ("control", controls)):
            if len(set(names)) != len(names):
                raise ValueError(
                    f"mapping {self.name!r}: {kind} {next(n for n in names if names.count(n) > 1)!r} appears twice"
                )
            if any(not n for n in names):
                raise ValueError(f"mapping {self.name!r}: empty {kind} name")
        try:
            matrix = np.array(self.matrix, dtype=np.float64).reshape(len(controls), len(channels))
            offsets = (
                np.zeros(len(controls))
                if self.offsets is None
                else np.array(self.offsets, dtype=np.float64).reshape(len(controls))
            )
        except (TypeError, ValueError):
            raise ValueError(
                f"mapping {self.name!r}: matrix must be ({len(controls)}, {len(channels)}) numbers and "
                f"offsets ({len(controls)},)"
            ) from None
        bad = np.argwhere(~np.isfinite(matrix))
        if len(bad):
            row, column = bad[0]
            raise ValueError(
                f"mapping {self.name!r}: weight of channel {channels[column]!r} on control {controls[row]!r} is not "
                "finite"
            )
        if not np.isfinite(offsets).all():
            raise ValueError(
                f"mapping {self.name!r}: offset of control {controls[int(np.argmin(np.isfinite(offsets)))]!r} is not "
                "finite"
            )
        object.__setattr__(self, "channels", channels)
        object.__setattr__(self, "controls", controls)
        object.__setattr__(self, "matrix", matrix)
        object.__setattr__(self, "offsets", offsets)

    @classmethod
    def from_entries(cls, entries, *, name: str = "default", offsets: dict[str, float] | None = None) -> "Mapping":
        """A mapping from ``(channel, control, weight)`` triples (repeated pairs add up) and ``{control: c₀}``."""
        entries = [_entry(item, position) for position, item in enumerate(expect_iterable(entries, "entries"))]
        if offsets is not None:
            expect_instance(offsets, MappingABC, "offsets")
            offsets = {
                str(control): float(as_finite_array(value, f"offsets[{control!r}]", shape=()))
                for control, value in offsets.items()
            }
        channels = list(dict.fromkeys(ch for ch, _, _ in entries))
        controls = list(dict.fromkeys([co for _, co, _ in entries] + list(offsets or {})))
        matrix = np.zeros((len(controls), len(channels)))
        for channel, control, weight in entries:
            matrix[controls.index(control), channels.index(channel)] += weight
        c0 = np.array([float((offsets or {}).get(c, 0.0)) for c in controls])
        return cls(channels=channels, controls=controls, matrix=matrix, offsets=c0, name=name)

    @classmethod
    def from_examples(
        cls, channels, controls, example_controls, neutral_controls=None, *, name: str = "calibrated"
    ) -> "Mapping":
        """A mapping calibrated from example shapes: one solved control vector per channel.

        When a character's own blendshapes (its ARKit shapes, say) are solved for the rig's controls
        (SPEC §6.1), the shape of channel ``j`` at full weight gives ``example_controls[j]`` and the
        neutral gives ``neutral_controls``; then ``M[:, j] = (example_j − neutral) / full_j`` (``full`` =
        the channel's top, 1 or 5) and ``c₀ = neutral``, so a one-hot weight reproduces its example.

        Args:
            channels: C channel names.
            controls: K control names.
            example_controls: shape (C, K), the controls that reproduce each channel's example at full weight.
            neutral_controls: shape (K,), the controls of the neutral (default zeros).
        """
        from .channels import channel_range

        channels = [str(c) for c in expect_iterable(channels, "channels", item_types=str)]
        controls = [str(c) for c in expect_iterable(controls, "controls", item_types=str)]
        examples = as_finite_array(example_controls, "example_controls")
        if examples.shape != (len(channels), len(controls)):
            raise ValueError(
                f"example_controls: expected shape ({len(channels)}, {len(controls)}), got {examples.shape}"
            )
        neutral = (
            np.zeros(len(controls))
            if neutral_controls is None
            else as_finite_array(neutral_controls, "neutral_controls")
        )
        if neutral.shape != (len(controls),):
            raise ValueError(f"neutral_controls: expected shape ({len(controls)},), got {neutral.shape}")
        tops = np.array([channel_range(c)[1] for c in channels])
        return cls(
            channels=channels,
            controls=list(controls),
            matrix=((examples - neutral) / tops[:, None]).T,
            offsets=neutral,
            name=name,
        )

    def entries(self) -> list[tuple[str, str, float]]:
        """The non-zero weights as ``(channel, control, weight)``, channel by channel."""
        return [
            (ch, self.controls[k], float(self.matrix[k, c]))
            for c, ch in enumerate(self.channels)
            for k in np.flatnonzero(self.matrix[:, c])
        ]

    def restricted_to(self, available_controls) -> tuple["Mapping", list[str], list[str]]:
        """This mapping without the controls a rig lacks.

        Returns:
            (mapping, dropped controls, channels left with no control at all).
        """
        available = set(expect_iterable(available_controls, "available_controls", item_types=str))
        keep = [k for k, c in enumerate(self.controls) if c in available]
        dropped = [c for c in self.controls if c not in available]
        matrix = self.matrix[keep]
        columns = [c for c in range(len(self.channels)) if np.any(matrix[:, c] != 0.0)]
        orphaned = [ch for c, ch in enumerate(self.channels) if c not in columns and np.any(self.matrix[:, c] != 0.0)]
        return (
            Mapping(
                channels=[self.channels[c] for c in columns],
                controls=[self.controls[k] for k in keep],
                matrix=matrix[:, columns],
                offsets=self.offsets[keep],
                name=self.name,
            ),
            dropped,
            orphaned,
        )

    def merged(self, other: "Mapping", *, name: str | None = None) -> "Mapping":
        """The sum of two mappings over the union of their channels and controls (offsets add too)."""
        expect_instance(other, Mapping, "other")
        channels = list(dict.fromkeys(self.channels + other.channels))
        controls = list(dict.fromkeys(self.controls + other.controls))
        matrix = np.zeros((len(controls), len(channels)))
        offsets = np.zeros(len(controls))
        for part in (self, other):
            rows = [controls.index(c) for c in part.controls]
            columns = [channels.index(c) for c in part.channels]
            matrix[np.ix_(rows, columns)] += part.matrix
            offsets[rows] += part.offsets
        return Mapping(channels=channels, controls=controls, matrix=matrix, offsets=offsets, name=name or self.name)

    def apply(self, curves: Curves, *, active_threshold: float = 0.05) -> MappedControls:
        """Controls over time, ``c(t) = M·s(t) + c₀``, shape (F, K).

        Channels of ``curves`` that the mapping does not know are ignored and listed in
        ``unmapped_channels``; mapped channels the curves lack count as zero.
        """
        expect_instance(curves, Curves, "curves")
        active_threshold = float(as_finite_array(active_threshold, "active_threshold", shape=()))
        index = {name: k for k, name in enumerate(curves.names)}
        present = [c for c, ch in enumerate(self.channels) if ch in index]
        signal = curves.values[:, [index[self.channels[c]] for c in present]]
        values = signal @ self.matrix[:, present].T + self.offsets
        unmapped = [name for name in curves.names if name not in set(self.channels)]
        names = [self.channels[c] for c in present]
        order = np.argsort(-signal, axis=1, kind="stable")
        active = [[names[j] for j in row if signal[f, j] > active_threshold][:4] for f, row in enumerate(order)]
        return MappedControls(
            times=curves.times,
            names=list(self.controls),
            values=values,
            unmapped_channels=unmapped,
            active_channels=active,
        )
