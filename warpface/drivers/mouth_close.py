"""ARKit's ``mouthClose`` against ``jawOpen``: the lips held together while the jaw opens (docs/RIG.md §12).

A linear mapping cannot do it: the closing a frame needs grows with the jaw's opening and must vanish when
``mouthClose`` comes alone or above ``jawOpen``. :func:`close_mouth` therefore sets the lip seal's control per frame,
after the linear mapping, to ``min(1, mouthClose / jawOpen)`` times the seal's closing share at the frame's jaw pose
(:func:`~warpface.assets.lips.mouth_close_shares`) — the product the mouthClose preset applies at its own jaw.
"""

from __future__ import annotations

import numpy as np

from .._validate import expect_instance
from ..rig import FaceRig
from .channels import Curves
from .mapping import MappedControls

__all__ = ["close_mouth"]

_JAW = ("jaw_open", "jaw_forward", "jaw_left")


def close_mouth(rig: FaceRig, curves: Curves, mapped: MappedControls) -> MappedControls:
    """``mapped`` with the lip seal's control (``lips_part``) set per frame from the ``mouthClose`` and ``jawOpen``
    channels of ``curves`` (the curves the controls were mapped from, same frames). Returned unchanged when the rig
    has no seal or jaw, the curves no ``mouthClose``, or the mapping drives ``lips_part`` itself."""
    from ..assets.lips import LIP_SEAL_NAME, mouth_close_shares

    expect_instance(rig, FaceRig, "rig")
    expect_instance(curves, Curves, "curves")
    expect_instance(mapped, MappedControls, "mapped")
    known = set(rig.control_names)
    if rig.jaw is None or LIP_SEAL_NAME not in known or LIP_SEAL_NAME in mapped.names:
        return mapped
    if "mouthClose" not in curves.names or len(curves.times) != len(mapped.times):
        return mapped
    values = mapped.as_dict()
    jaw = np.stack([values.get(name, np.zeros(len(mapped.times))) for name in _JAW], axis=1)
    jaw_open = curves.channel("jawOpen") if "jawOpen" in curves.names else np.zeros(len(curves.times))
    shares = mouth_close_shares(rig, jaw, curves.channel("mouthClose"), jaw_open)
    return MappedControls(
        times=mapped.times,
        names=[*mapped.names, LIP_SEAL_NAME],
        values=np.concatenate([mapped.values, shares[:, None]], axis=1),
        unmapped_channels=mapped.unmapped_channels,
        active_channels=mapped.active_channels,
    )
