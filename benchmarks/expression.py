"""Frame time of the expression model: Warp vs a vectorised NumPy float32 version of the same math.

Rows: a ~10k-vertex face (the real ICT face region when ``../shared/data`` is present, otherwise
the built-in face) and wavy grids of 10k, 100k and 1M vertices, each with 16 linear muscles and 21
wrinkles. Both sides use the same rig-time precomputation (sparse muscle weights, wrinkle
profiles); the per-frame work — muscles, stretch, normals, bulge, normals again, wrinkles — is
timed. "warp ms" includes copying the result to host memory; on CUDA "device ms" is the graph
replay alone.

    python -m benchmarks.expression [--device cuda:0] [--sizes 10000 100000 1000000] [--quick]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import warp as wp

import warpface as wf
from warpface.data import ict_face_region
from warpface.expression import muscle_weights
from warpface.expression.wrinkles import wrinkle_shapes

from ._timing import machine_info, print_table, time_call, write_results

MUSCLES = 16
WRINKLES = 21


def wavy_grid(vertex_count: int, size: float = 0.2) -> wf.FaceMesh:
    """A face-sized (``size`` m square) wavy height field with about ``vertex_count`` vertices."""
    n = int(round(np.sqrt(vertex_count)))
    xs = np.linspace(-size / 2, size / 2, n)
    x, y = np.meshgrid(xs, xs)
    z = 0.02 * np.cos(np.pi * x / size) * np.cos(np.pi * y / size) + 0.003 * np.sin(40 * x) * np.sin(30 * y)
    index = np.arange(n * n).reshape(n, n)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    return wf.FaceMesh(np.c_[x.ravel(), y.ravel(), z.ravel()], np.r_[np.c_[a, b, d], np.c_[a, d, c]], name=f"grid{n * n}")


def benchmark_rig(mesh: wf.FaceMesh):
    """16 linear muscles on a 4×4 lattice and 21 furrows (7×3) spread over the mesh, sized from its extent."""
    lo, hi = mesh.bounding_box
    centre, extent = 0.5 * (lo + hi), hi - lo
    height = float(max(extent[0], extent[1]))
    rng = np.random.default_rng(7)
    muscles = []
    for i in range(MUSCLES):
        row, col = divmod(i, 4)
        insertion = centre + np.array([(col - 1.5) * 0.2 * extent[0], (row - 1.5) * 0.2 * extent[1], 0.5 * extent[2]])
        angle = rng.uniform(0, 2 * np.pi)
        attachment = insertion + 0.15 * height * np.array([np.cos(angle), np.sin(angle), -0.5])
        muscles.append(wf.LinearMuscle(f"m{i}", attachment, insertion, 35.0, 0.1 * height, 0.35 * height))
    projection = wf.PlanarProjection(centre, [1, 0, 0], [0, 1, 0])
    wrinkles = []
    for i in range(WRINKLES):
        row, col = divmod(i, 7)
        u0, v0 = (col - 3) * 0.12 * extent[0], (row - 1) * 0.25 * extent[1]
        span = 0.05 * extent[0]
        control = np.array([[u0 - span, v0], [u0 - span / 3, v0 + 0.01 * height], [u0 + span / 3, v0 - 0.01 * height], [u0 + span, v0]])
        wrinkles.append(wf.Wrinkle(f"w{i}", control, projection, 0.004 * height, 0.012 * height, 0.0))
    contractions = 0.02 * height * rng.uniform(0.5, 1.0, MUSCLES)
    return muscles, wrinkles, 0.02 * height, contractions


class NumpyExpression:
    """The per-frame math of ``ExpressionModel`` in vectorised NumPy float32 (scatter with bincount)."""

    def __init__(self, mesh: wf.FaceMesh, muscles, wrinkles, thickness: float, device):
        weights = muscle_weights(mesh.points, muscles, device=device)
        shapes = wrinkle_shapes(mesh.points, wrinkles, device=device)
        v = mesh.vertex_count
        self.v = v
        self.rest = mesh.points.astype(np.float32)
        self.triangles = mesh.triangles
        self.corners = mesh.triangles.T.ravel()
        self.corner_count = np.bincount(self.corners, minlength=v).astype(np.float32)
        self.muscle_row = np.repeat(np.arange(v), np.diff(weights.offsets))
        self.muscle_col = weights.muscle
        self.muscle_weight = weights.weight.astype(np.float32)
        self.wrinkle_row = np.repeat(np.arange(v), np.diff(shapes.offsets))
        self.wrinkle_col = shapes.wrinkle
        self.wrinkle_shape = shapes.shape.astype(np.float32)
        self.kr = np.array([w.kr for w in wrinkles], dtype=np.float32)
        self.thickness = np.float32(thickness)
        self.rest_length = np.linalg.norm(self._area_vectors(self.rest), axis=1)

    def _area_vectors(self, x):
        p0, p1, p2 = x[self.triangles[:, 0]], x[self.triangles[:, 1]], x[self.triangles[:, 2]]
        return np.cross(p1 - p0, p2 - p0)

    def _gather3(self, rows, values):
        return np.stack([np.bincount(rows, values[:, c], minlength=self.v) for c in range(3)], axis=1).astype(np.float32)

    def _normals(self, area_vectors):
        total = self._gather3(self.corners, np.tile(area_vectors, (3, 1)))
        length = np.linalg.norm(total, axis=1, keepdims=True)
        return np.divide(total, length, out=np.zeros_like(total), where=length > 0)

    def frame(self, contraction: np.ndarray, depth: np.ndarray) -> np.ndarray:
        contraction = contraction.astype(np.float32)
        x1 = self.rest + self._gather3(self.muscle_row, self.muscle_weight * contraction[self.muscle_col][:, None])
        av = self._area_vectors(x1)
        ratio = np.linalg.norm(av, axis=1) / self.rest_length
        r = (np.bincount(self.corners, np.tile(ratio, 3), minlength=self.v) / self.corner_count).astype(np.float32)
        x2 = x1 + ((1.0 / np.maximum(r, 1e-4) - 1.0) * self.thickness)[:, None] * self._normals(av)
        n2 = self._normals(self._area_vectors(x2))
        rr, kr = r[self.wrinkle_row], self.kr[self.wrinkle_col]
        c = ((kr - 1) * rr + 1).astype(np.float32)
        above = rr > 1
        c[above] = 0.0
        fading = above & (kr > 0)  # k_r = 0: no furrow on stretched skin
        c[fading] = kr[fading] * np.exp((1 - 1 / kr[fading]) * (rr[fading] - 1))
        height = np.bincount(self.wrinkle_row, depth.astype(np.float32)[self.wrinkle_col] * self.wrinkle_shape * c, minlength=self.v)
        return x2 + height.astype(np.float32)[:, None] * n2


def face_mesh() -> tuple[wf.FaceMesh, str]:
    path = ict_face_region()
    if path is not None:
        return wf.FaceMesh.from_obj(path), "ICT face region"
    try:
        from warpface.assets import default_face

        return default_face(), "built-in face"
    except ImportError:
        return wavy_grid(10_000), "grid (no face available)"


def run_case(label: str, mesh: wf.FaceMesh, device, quick: bool) -> dict:
    muscles, wrinkles, thickness, contractions = benchmark_rig(mesh)
    started = time.perf_counter()
    model = wf.ExpressionModel(mesh, muscles, wrinkles, thickness, device=device)
    setup = time.perf_counter() - started
    numpy_model = NumpyExpression(mesh, muscles, wrinkles, thickness, device)
    depths = model.default_depths
    check = np.abs(model.evaluate(contractions) - numpy_model.frame(contractions, depths)).max()
    big = mesh.vertex_count > 200_000
    repeats = 3 if (quick or big) else 20
    warp_s = time_call(lambda: model.evaluate(contractions), repeats=repeats, min_seconds=0.0 if quick else 0.5)
    numpy_s = time_call(lambda: numpy_model.frame(contractions, depths), repeats=repeats, warmup=1, min_seconds=0.0 if quick else 0.5)
    device_s = None
    if model.device.is_cuda:
        graph = model._single.graph
        device_s = time_call(lambda: wp.capture_launch(graph), repeats=200, sync=lambda: wp.synchronize_device(model.device))
    frames = 64 if not big else 8
    batch = np.tile(contractions, (frames, 1))
    batch_s = time_call(lambda: model.evaluate_batch(batch), repeats=3, warmup=1) / frames
    return {
        "mesh": label,
        "vertices": mesh.vertex_count,
        "triangles": mesh.triangle_count,
        "muscle_entries": model.muscle_entry_count,
        "wrinkle_entries": model.wrinkle_entry_count,
        "setup_s": setup,
        "warp_ms": warp_s * 1e3,
        "device_ms": None if device_s is None else device_s * 1e3,
        "batch_ms_per_frame": batch_s * 1e3,
        "numpy_ms": numpy_s * 1e3,
        "speedup": numpy_s / warp_s,
        "max_abs_diff_vs_numpy": float(check),
    }


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default=None, help="Warp device (default: Warp's preferred device)")
    parser.add_argument("--sizes", type=int, nargs="*", default=[10_000, 100_000, 1_000_000], help="grid vertex counts")
    parser.add_argument("--quick", action="store_true", help="fewer repeats (smoke run)")
    args = parser.parse_args(argv)
    wp.config.quiet = True
    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    device = wp.get_device(args.device)
    face, face_label = face_mesh()
    cases = [(face_label, face)] + [(f"grid {size:,}", wavy_grid(size)) for size in args.sizes]
    rows = []
    for label, mesh in cases:
        rows.append(run_case(label, mesh, device, args.quick))
        print(f"  measured {label}: {rows[-1]['warp_ms']:.3f} ms/frame", flush=True)
    print(f"\nExpression model, {MUSCLES} linear muscles + {WRINKLES} wrinkles, device {device} ({device.name})")
    print("baseline: vectorised NumPy float32 of the same per-frame math, same run\n")
    print_table(rows, [
        ("mesh", "mesh", "s"), ("vertices", "vertices", ",d"), ("warp_ms", "warp ms", ".3f"), ("device_ms", "device ms", ".3f"),
        ("batch_ms_per_frame", "batch ms/frame", ".3f"), ("numpy_ms", "numpy ms", ".3f"), ("speedup", "× numpy", ".1f"),
        ("setup_s", "setup s", ".2f"),
    ])
    path = write_results(f"expression_{device.alias.replace(':', '')}", {"benchmark": "expression", "machine": machine_info(device), "rows": rows})
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
