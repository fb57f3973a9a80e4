"""Procedural meshes and rigs shared by the test modules, and a field-by-field rig comparison.

A plain module, not a test module: tests import it (``from helpers import grid_surface``); fixtures that
wrap these live in ``conftest.py``.
"""

from __future__ import annotations

import numpy as np

from warpface import CylindricalProjection, FaceMesh, FaceRig, LinearMuscle, PlanarProjection, SphincterMuscle, Wrinkle
from warpface.expression.lids import LidMuscle
from warpface.tracking import LandmarkFrame, vertex_landmark_names

__all__ = [
    "grid_surface",
    "small_face_rig",
    "patch",
    "icosphere_like",
    "assert_rigs_equal",
    "scaled_rig",
    "DisappearingCamera",
    "live_link_csv",
]


def grid_surface(n: int = 24, size: float = 2.0, height: float = 0.3, seed: int | None = 0):
    """A wavy height-field patch: points (n·n, 3) float64, triangles (2(n−1)², 3) int.

    With ``seed`` a little random jitter is added so normals and areas are all different.
    """
    xs = np.linspace(-size / 2, size / 2, n)
    x, y = np.meshgrid(xs, xs)
    z = height * np.sin(1.7 * x) * np.cos(1.3 * y)
    points = np.c_[x.ravel(), y.ravel(), z.ravel()]
    if seed is not None:
        rng = np.random.default_rng(seed)
        points += rng.uniform(-0.15, 0.15, points.shape) * (size / n)
    index = np.arange(n * n).reshape(n, n)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    triangles = np.r_[np.c_[a, b, d], np.c_[a, d, c]]
    return points, triangles


def small_face_rig(n: int = 16, *, name: str = "Face"):
    """A small procedural :class:`warpface.FaceRig` on a :func:`grid_surface` patch (for USD I/O tests).

    Points are rounded to float32 (USD stores mesh points as point3f) so round trips can be exact.
    Two linear muscles, one sphincter, a planar and a cylindrical wrinkle, a varying thickness,
    four landmarks; one name is not a valid USD identifier.
    """
    points, triangles = grid_surface(n, size=0.2, height=0.02, seed=3)
    points = points.astype(np.float32).astype(np.float64)
    muscles = [
        LinearMuscle(
            "zygomaticus major L",
            attachment=[0.09, 0.08, -0.03],
            insertion=[0.02, -0.02, 0.01],
            zone_angle_deg=35.0,
            falloff_start=0.05,
            falloff_finish=0.14,
        ),
        LinearMuscle(
            "frontalis_R",
            attachment=[-0.05, 0.12, -0.02],
            insertion=[-0.04, 0.03, 0.01],
            zone_angle_deg=28.5,
            falloff_start=0.04,
            falloff_finish=0.11,
        ),
        SphincterMuscle(
            "orbicularis_oris",
            center=[0.0, -0.03, 0.0],
            axis_x=[1.0, 0.0, 0.1],
            axis_y=[0.0, 1.0, 0.0],
            semi_axes=(0.05, 0.03),
        ),
    ]
    wrinkles = [
        Wrinkle(
            "forehead_1",
            control_points=[[-0.06, 0.05], [-0.02, 0.06], [0.02, 0.06], [0.06, 0.05]],
            projection=PlanarProjection([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
            depth=0.002,
            width=0.004,
            kr=0.0,
        ),
        Wrinkle(
            "crow_L",
            control_points=[[0.01, -0.02], [0.015, -0.01], [0.02, 0.0], [0.022, 0.015]],
            projection=CylindricalProjection([0.0, 0.0, -0.1], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], 0.1),
            depth=0.0015,
            width=0.003,
            kr=0.25,
        ),
    ]
    thickness = 0.004 + 0.003 * (points[:, 0] - points[:, 0].min()) / np.ptp(points[:, 0])
    mesh = FaceMesh(points, triangles, name="skin mesh")
    return FaceRig(
        mesh=mesh,
        muscles=muscles,
        wrinkles=wrinkles,
        thickness=thickness,
        landmarks=np.array([0, 5, n * n - 1, n + 3]),
        name=name,
    )


def patch(n: int = 13, size: float = 0.06, hole: bool = True, bend: float = 0.0):
    """A square patch [m] in the xy plane (normals +z), optionally with a square hole in the middle
    and bent into a cylinder of curvature ``bend`` around the y axis (convex toward +z)."""
    xs = np.linspace(-size / 2, size / 2, n)
    x, y = np.meshgrid(xs, xs)
    z = np.zeros_like(x)
    if bend:
        radius = 1.0 / bend
        angle = x / radius
        x, z = radius * np.sin(angle), radius * (np.cos(angle) - 1.0)
    points = np.c_[x.ravel(), y.ravel(), z.ravel()]
    index = np.arange(n * n).reshape(n, n)
    cells = [(i, j) for i in range(n - 1) for j in range(n - 1)]
    if hole:
        mid = (n - 1) // 2
        cells = [(i, j) for i, j in cells if not (mid - 1 <= i <= mid and mid - 1 <= j <= mid)]
    i, j = np.array(cells).T
    a, b, c, d = index[i, j], index[i, j + 1], index[i + 1, j], index[i + 1, j + 1]
    triangles = np.r_[np.c_[a, b, d], np.c_[a, d, c]]
    used = np.unique(triangles)
    remap = np.full(len(points), -1)
    remap[used] = np.arange(len(used))
    return points[used], remap[triangles]


def icosphere_like(n=16):
    """A UV sphere of radius 2 (poles merged), for checking outward normals."""
    theta = np.linspace(0, np.pi, n)[1:-1]
    phi = np.linspace(0, 2 * np.pi, 2 * n, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.c_[np.sin(t).ravel() * np.cos(p).ravel(), np.sin(t).ravel() * np.sin(p).ravel(), np.cos(t).ravel()]
    points = 2.0 * np.r_[[[0, 0, 1]], ring, [[0, 0, -1]]]
    rows, cols = len(theta), len(phi)
    idx = 1 + np.arange(rows * cols).reshape(rows, cols)
    nxt = np.roll(idx, -1, axis=1)
    tris = [np.c_[np.zeros(cols, int), idx[0], nxt[0]]]
    for r in range(rows - 1):
        tris += [np.c_[idx[r], idx[r + 1], nxt[r + 1]], np.c_[idx[r], nxt[r + 1], nxt[r]]]
    last = len(points) - 1
    tris.append(np.c_[np.full(cols, last), nxt[-1], idx[-1]])
    return points, np.concatenate(tris)


def assert_rigs_equal(a: FaceRig, b: FaceRig) -> None:
    """Every field identical (bit-exact arrays, same types and order)."""
    assert a.name == b.name
    assert a.mesh.name == b.mesh.name
    assert np.array_equal(a.mesh.points, b.mesh.points)
    assert np.array_equal(a.mesh.triangles, b.mesh.triangles)
    assert np.array_equal(a.thickness, b.thickness)
    assert (a.landmarks is None) == (b.landmarks is None)
    if a.landmarks is not None:
        assert np.array_equal(a.landmarks, b.landmarks)
    assert [type(m) for m in a.muscles] == [type(m) for m in b.muscles]
    for m, n in zip(a.muscles, b.muscles):
        fields = (
            ("attachment", "insertion", "zone_angle_deg", "falloff_start", "falloff_finish")
            if isinstance(m, LinearMuscle)
            else ("center", "axis", "vertices", "angles", "slides", "lifts")
            if isinstance(m, LidMuscle)
            else ("center", "axis_x", "axis_y", "semi_axes")
        )
        assert m.name == n.name
        fields += ("pairs",) if hasattr(m, "pairs") else ()
        for field in fields:
            assert np.array_equal(getattr(m, field), getattr(n, field)), (m.name, field)
    assert len(a.wrinkles) == len(b.wrinkles)
    for w, v in zip(a.wrinkles, b.wrinkles):
        assert (w.name, w.depth, w.width, w.kr) == (v.name, v.depth, v.width, v.kr)
        assert np.array_equal(w.control_points, v.control_points)
        assert type(w.projection) is type(v.projection)
        for field in vars(w.projection):
            assert np.array_equal(getattr(w.projection, field), getattr(v.projection, field)), (w.name, field)


def scaled_rig(rig: FaceRig, factor: float) -> FaceRig:
    """The same rig with every length multiplied by ``factor``."""
    muscles = []
    for m in rig.muscles:
        if isinstance(m, LinearMuscle):
            muscles.append(
                LinearMuscle(
                    m.name,
                    m.attachment * factor,
                    m.insertion * factor,
                    m.zone_angle_deg,
                    m.falloff_start * factor,
                    m.falloff_finish * factor,
                )
            )
        elif isinstance(m, LidMuscle):
            muscles.append(
                LidMuscle(m.name, m.center * factor, m.axis, m.vertices, m.angles, m.slides * factor, m.lifts * factor)
            )
        else:
            muscles.append(
                SphincterMuscle(m.name, m.center * factor, m.axis_x, m.axis_y, tuple(np.multiply(m.semi_axes, factor)))
            )
    wrinkles = []
    for w in rig.wrinkles:
        p = w.projection
        projection = (
            PlanarProjection(p.origin * factor, p.u_axis, p.v_axis)
            if isinstance(p, PlanarProjection)
            else CylindricalProjection(p.origin * factor, p.axis, p.reference, p.radius * factor)
        )
        wrinkles.append(
            Wrinkle(w.name, w.control_points * factor, projection, w.depth * factor, w.width * factor, w.kr)
        )
    mesh = FaceMesh(rig.mesh.points * factor, rig.mesh.triangles, name=rig.mesh.name)
    return FaceRig(mesh, muscles, wrinkles, rig.thickness * factor, rig.landmarks, rig.name)


# float32 positions: a few units in the last place of the face's size, from FMA contraction and
# libdevice/libm differences in the per-frame kernels (each stage rounds a handful of times; the
# stretch → bulge step multiplies a ratio's rounding by the thickness, millimetres, so adds less).
# Measured on an H200 with the full rig: 2.2e-6 of the size at one vertex of 69k (a thin corner
# triangle, where the bulge's 1/r amplifies the ratio's rounding); the bound leaves 2x above that.
FLOAT32_FACE_TOLERANCE = 5e-6
"""Cross-device tolerance of float32 face positions, as a fraction of the mesh's size (0.28 m → 0.6 µm)."""


def expression_controls(rig, frames: int, seed: int):
    """(F, M[+3]) controls (linear muscles up to 0.15 face units, sphincters up to 0.5, then the jaw's
    three when the rig has a jaw) and (F, W) depths."""
    from warpface.assets import rig_scale
    from warpface.expression import SphincterMuscle

    rng = np.random.default_rng(seed)
    sphincter = np.array([isinstance(m, SphincterMuscle) for m in rig.muscles])
    contractions = rng.uniform(0.0, 0.15, (frames, len(rig.muscles))) * np.where(sphincter, 1.0, rig_scale(rig))
    contractions[:, sphincter] = rng.uniform(0.0, 0.5, (frames, int(sphincter.sum())))
    contractions[rng.uniform(size=contractions.shape) < 0.5] = 0.0  # sparse, as expressions are
    depths = rng.uniform(0.0, 2.0, (frames, len(rig.wrinkles))) * np.array([w.depth for w in rig.wrinkles])
    if getattr(rig, "jaw", None) is not None:  # jaw opening [rad], protrusion and slide [lengths]
        jaw = rng.uniform(0.0, 1.0, (frames, 3)) * np.array([0.2, 0.02 * rig_scale(rig), 0.01 * rig_scale(rig)])
        contractions = np.concatenate([contractions, jaw], axis=1)
    return contractions, depths


class DisappearingCamera:
    """A landmark source that moves its landmarks up 1 mm a frame and dies after ``frames`` frames, like an
    unplugged camera (ConnectionError)."""

    def __init__(self, rest, vertices, frames):
        self.landmark_names = vertex_landmark_names(vertices)
        self.fps = 30.0
        self.rest, self.vertices, self.frame_count = rest, vertices, frames

    def frames(self):
        for i in range(self.frame_count):
            points = self.rest[self.vertices] + np.array([0.0, 0.001 * i, 0.0])
            yield LandmarkFrame(timestamp=i / 30.0, points=points, confidence=np.ones(len(points)), index=i)
        raise ConnectionError("camera disconnected")


def parity_device():
    """The Warp device of the CPU ↔ CUDA parity tests (``WARPFACE_PARITY_DEVICE``, default ``cuda:0``);
    skips the calling test module, with the reason, where Warp cannot use it."""
    import os

    import pytest
    import warp as wp

    name = os.environ.get("WARPFACE_PARITY_DEVICE", "cuda:0")
    try:
        return wp.get_device(name)
    except Exception as exc:  # noqa: BLE001 - Warp raises ValueError/RuntimeError for an unknown device
        pytest.skip(
            f"parity device {name!r} is not available here ({exc}); set WARPFACE_PARITY_DEVICE", allow_module_level=True
        )


def interrupted_track(tmp_path, *options: str, delay: float) -> tuple[int, int, str, object]:
    """Run ``warpface track synthetic`` in a child process, send it Ctrl-C ``delay`` seconds after its stage
    appears (its first flush), and return (exit code, frames it reported, its stderr, the stage path).

    The frames reported are those of "kept all N" after Ctrl-C, or of "tracked N" when the capture finished
    before the signal arrived.
    """
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    stage = tmp_path / "out" / "capture.usda"
    command = [sys.executable, "-m", "warpface.cli", "--device", "cpu", "--quiet", "track", "synthetic"]
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    with open(tmp_path / "err.txt", "w") as errors:
        child = subprocess.Popen(
            [*command, "--stage", str(stage), *options], stdout=subprocess.PIPE, stderr=errors, text=True, env=env
        )
    try:
        deadline = time.monotonic() + 120
        while not stage.exists() and child.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)  # the stage appears with the first flush
        time.sleep(delay)
        child.send_signal(signal.SIGINT)
        out = child.stdout.read()
        child.wait(timeout=60)
    finally:
        child.kill()
    error = (tmp_path / "err.txt").read_text()[-2000:]
    if child.returncode not in (0, 130):
        return child.returncode, 0, error, stage
    marker = "kept all " if child.returncode == 130 else "tracked "
    return child.returncode, int(out.split(marker)[1].split()[0]), error, stage


def shell_face(cells: int = 8, layers: int = 2, *, span_u: float = 2.4, span_v: float = 2.0, thickness: float = 0.012):
    """A face-like tissue shell (:func:`warpface.fem.shell_tet_mesh`) with a one-muscle rig on its outer surface.

    Returns ``(rig, tetmesh, fixed, outer)``: ``fixed`` the inner (skull-side) layer's nodes, ``outer`` the
    outer layer's node indices as a (cells + 1, cells + 1) grid (row: elevation, column: azimuth); the rig's skin
    vertices are the outer nodes in that order, its landmarks five vertices along the top row.
    """
    from warpface.fem import shell_tet_mesh

    tetmesh = shell_tet_mesh(cells, cells, layers, thickness=thickness, span_u=span_u, span_v=span_v)
    per = (cells + 1) ** 2
    grid = np.arange(per).reshape(cells + 1, cells + 1)
    a, b, c, d = grid[:-1, :-1].ravel(), grid[:-1, 1:].ravel(), grid[1:, :-1].ravel(), grid[1:, 1:].ravel()
    mesh = FaceMesh(tetmesh.points[layers * per :], np.r_[np.c_[a, b, d], np.c_[a, d, c]], name="shell")
    top, middle = mesh.points[grid[-1, cells // 2]], mesh.points[grid[cells // 2, cells // 2]]
    muscle = LinearMuscle(
        "levator",
        attachment=top + np.array([0.0, 0.01, -0.01]),
        insertion=middle,
        zone_angle_deg=40.0,
        falloff_start=0.3 * np.ptp(mesh.points[:, 1]),
        falloff_finish=0.8 * np.ptp(mesh.points[:, 1]),
    )
    landmarks = grid[-1, np.linspace(1, cells - 1, 5).astype(int)]
    rig = FaceRig(mesh, [muscle], [], thickness, landmarks=landmarks)
    return rig, tetmesh, np.arange(per), grid + layers * per


def live_link_csv(path, frames: int, channels: dict[str, float]):
    """A Live Link Face CSV written by hand: each named channel ramps from 0 to its peak and back."""
    from warpface.drivers import ARKIT_CHANNELS

    columns = [name[0].upper() + name[1:] for name in ARKIT_CHANNELS]
    ramp = np.sin(np.linspace(0.0, np.pi, frames))
    lines = ["Timecode,BlendshapeCount," + ",".join(columns)]
    for frame in range(frames):
        weights = [f"{channels.get(name, 0.0) * ramp[frame]:.5f}" for name in ARKIT_CHANNELS]
        lines.append(f"01:02:03:{frame:02d}.000,52," + ",".join(weights))
    path.write_text("\n".join(lines) + "\n")
    return path
