"""Shared checks of the controls that move the lips and the mouth's corners as bodies (docs/RIG.md §15–17)."""

from __future__ import annotations

import numpy as np
from helpers import assert_rigs_equal

import warpface as wf
from warpface.assets.quality import LIP_PAIRS, face_up, pair_heights


def random_mixes(names, count: int, seed: int) -> list[dict[str, float]]:
    """``count`` frames of every control in ``names`` at a uniform random value in [0, 1)."""
    rng = np.random.default_rng(seed)
    return [dict(zip(names, rng.uniform(0.0, 1.0, len(names)))) for _ in range(count)]


def assert_inner_lips_never_close(rig, frames, tolerance_mm: float, device: str = "cpu") -> None:
    """No frame brings an inner-lip pair (iBUG 61/67, 62/66, 63/65) closer along the face's up axis than at rest by
    more than ``tolerance_mm`` (the rig in metres)."""
    model = rig.model(device=device)
    up = face_up(rig.mesh, rig.landmarks)
    rest = pair_heights(model.evaluate({}), rig.landmarks, LIP_PAIRS, up, 1000.0)
    for frame in frames:
        heights = pair_heights(model.evaluate(frame), rig.landmarks, LIP_PAIRS, up, 1000.0)
        assert np.all(heights >= rest - tolerance_mm), (frame, heights - rest)


def turned_face(mesh, scale: float, rotation: np.ndarray, shift) -> wf.FaceMesh:
    """``mesh`` scaled, turned by ``rotation`` (3, 3) and shifted: ``scale · R p + shift``."""
    return wf.FaceMesh(scale * mesh.points @ rotation.T + np.asarray(shift), mesh.triangles, name="moved")


def assert_hinges_round_trip(rig, hinges, frame: dict[str, float], path, device: str = "cpu") -> None:
    """A rig of ``hinges`` alone (float32-exact points) written to ``path`` and read back: the same rig, fit limits
    and expression at ``frame``."""
    exact = wf.FaceRig(
        wf.FaceMesh(rig.mesh.points.astype(np.float32).astype(np.float64), rig.mesh.triangles, name=rig.mesh.name),
        list(hinges),
        [],
        0.0,
        name=rig.name,
    )
    wf.usd.write_rig(path, exact)
    back = wf.usd.read_rig(path)
    assert_rigs_equal(exact, back)
    assert {m.name: m.fit_limit for m in back.muscles} == {m.name: m.fit_limit for m in exact.muscles}
    np.testing.assert_allclose(
        back.model(device=device).evaluate(frame), exact.model(device=device).evaluate(frame), atol=1e-6
    )
