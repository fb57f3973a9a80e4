"""Frame time of the expression model: Warp vs a vectorised NumPy float32 version of the same math.

Rows: a ~10k-vertex face (the real ICT face region when ``../shared/data`` is present, otherwise
the built-in face) and wavy grids of 10k, 100k and 1M vertices, each with 16 linear muscles and 21
wrinkles. Both sides use the same rig-time precomputation (sparse muscle weights, wrinkle
profiles); the per-frame work — muscles, stretch, normals, bulge, normals again, wrinkles — is
timed. "warp ms" includes copying the result to host memory; on CUDA "device ms" is the graph
replay alone, host call and synchronisation included ("event ms": GPU time between CUDA events), for
the device's default plan (tiled) with the staged plan beside it; every device row is set against a
``wp.copy`` of the same bytes timed in the same run, and the largest mesh's batch chunk is split by
kernel (CUDA events, no graph).

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
from warpface.expression.plans import plan_launches
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
    return wf.FaceMesh(
        np.c_[x.ravel(), y.ravel(), z.ravel()], np.r_[np.c_[a, b, d], np.c_[a, d, c]], name=f"grid{n * n}"
    )


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
        control = np.array(
            [[u0 - span, v0], [u0 - span / 3, v0 + 0.01 * height], [u0 + span / 3, v0 - 0.01 * height], [u0 + span, v0]]
        )
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
        return np.stack([np.bincount(rows, values[:, c], minlength=self.v) for c in range(3)], axis=1).astype(
            np.float32
        )

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
        height = np.bincount(
            self.wrinkle_row, depth.astype(np.float32)[self.wrinkle_col] * self.wrinkle_shape * c, minlength=self.v
        )
        return x2 + height.astype(np.float32)[:, None] * n2


class TorchExpression:
    """The same per-frame math in PyTorch float32, vectorised over frames: gathers and ``index_add_`` scatters.

    Built from a :class:`NumpyExpression` (the same rig-time precomputation). ``torch`` is passed in
    (imported lazily by the caller); :meth:`frames` takes (B, M) contractions and (B, W) depths and
    returns (B, V, 3) positions. Stretch ratio and normal sum share one 4-wide scatter, as in the
    Warp kernels' packed per-triangle terms.
    """

    def __init__(self, reference: NumpyExpression, torch, device: str):
        self.torch, self.v = torch, reference.v

        def tensor(values, dtype=torch.float32):
            return torch.as_tensor(np.ascontiguousarray(values), dtype=dtype, device=device)

        self.rest = tensor(reference.rest)[None]
        self.corner_a, self.corner_b, self.corner_c = (tensor(reference.triangles[:, i], torch.int64) for i in range(3))
        self.corners = tensor(reference.corners, torch.int64)
        counts = reference.corner_count
        self.inverse_count = tensor(np.where(counts > 0, 1.0 / np.maximum(counts, 1), 0.0))
        self.no_triangles = tensor(counts == 0, torch.bool)
        self.muscle_row, self.muscle_col = (
            tensor(reference.muscle_row, torch.int64),
            tensor(reference.muscle_col, torch.int64),
        )
        self.muscle_weight = tensor(reference.muscle_weight)[None]
        self.wrinkle_row, self.wrinkle_col = (
            tensor(reference.wrinkle_row, torch.int64),
            tensor(reference.wrinkle_col, torch.int64),
        )
        self.wrinkle_shape = tensor(reference.wrinkle_shape)[None]
        kr = reference.kr[reference.wrinkle_col]
        self.kr = tensor(kr)[None]
        self.fade_rate = tensor(np.where(kr > 0, 1.0 - 1.0 / np.where(kr > 0, kr, 1.0), 0.0))[None]
        self.thickness = float(reference.thickness)
        self.inverse_rest_length = tensor(1.0 / reference.rest_length)[None]

    def _scatter(self, rows, values):
        """Per-entry (B, E, C) values summed into per-vertex (B, V, C)."""
        out = self.torch.zeros((values.shape[0], self.v, values.shape[2]), dtype=values.dtype, device=values.device)
        return out.index_add_(1, rows, values)

    def _area_vectors(self, x):
        p0 = x[:, self.corner_a]
        return self.torch.cross(x[:, self.corner_b] - p0, x[:, self.corner_c] - p0, dim=-1)

    def _unit(self, vectors):
        """Normalised rows; zero rows stay zero (as ``safe_normalize``)."""
        length = self.torch.linalg.vector_norm(vectors, dim=-1, keepdim=True)
        return vectors / self.torch.clamp(length, min=1e-30)

    def frames(self, contraction, depth):
        torch = self.torch
        x1 = self.rest + self._scatter(self.muscle_row, self.muscle_weight * contraction[:, self.muscle_col, None])
        av = self._area_vectors(x1)
        ratio = torch.linalg.vector_norm(av, dim=-1, keepdim=True) * self.inverse_rest_length[..., None]
        terms = torch.cat([av, ratio], dim=-1)
        summed = self._scatter(self.corners, torch.cat([terms, terms, terms], dim=1))
        r = torch.where(self.no_triangles, 1.0, summed[..., 3] * self.inverse_count)
        growth = (1.0 / torch.clamp(r, min=1e-4) - 1.0) * self.thickness
        x2 = x1 + growth[..., None] * self._unit(summed[..., :3])
        av2 = self._area_vectors(x2)
        n2 = self._unit(self._scatter(self.corners, torch.cat([av2, av2, av2], dim=1)))
        rr = r[:, self.wrinkle_row]
        fading = torch.where(self.kr > 0, self.kr * torch.exp(self.fade_rate * (rr - 1.0)), 0.0)
        c = torch.where(rr <= 1.0, (self.kr - 1.0) * rr + 1.0, fading)
        height = self._scatter(self.wrinkle_row, (depth[:, self.wrinkle_col] * self.wrinkle_shape * c)[..., None])
        return x2 + height * n2


def face_mesh() -> tuple[wf.FaceMesh, str]:
    path = ict_face_region()
    if path is not None:
        return wf.FaceMesh.from_obj(path), "ICT face region"
    try:
        from warpface.assets import default_face

        return default_face(), "built-in face"
    except ImportError:
        return wavy_grid(10_000), "grid (no face available)"


TORCH_TOLERANCE = 1e-5
"""Torch peer vs warpface, max |Δx| as a fraction of the mesh size: float32 sums in another order."""


def torch_rows(reference: NumpyExpression, model, contractions: np.ndarray, depths: np.ndarray, quick: bool) -> dict:
    """The PyTorch CUDA peer on the model's device: single frame (synchronised) and batched; {} without torch/CUDA."""
    if not model.device.is_cuda:
        return {}
    try:
        import torch
    except ImportError:
        return {}
    if not torch.cuda.is_available():
        return {}
    device = f"cuda:{model.device.ordinal}"
    peer = TorchExpression(reference, torch, device)
    one_c = torch.as_tensor(contractions[None], dtype=torch.float32, device=device)
    one_d = torch.as_tensor(depths[None], dtype=torch.float32, device=device)
    frames = int(np.clip((1 << 22) // reference.v, 1, 512))
    rng = np.random.default_rng(3)
    batch_c = torch.as_tensor(
        contractions * rng.uniform(0.5, 1.0, (frames, len(contractions))), dtype=torch.float32, device=device
    )
    batch_d = one_d.expand(frames, -1).contiguous()
    with torch.inference_mode():
        got = peer.frames(batch_c[:2], batch_d[:2]).cpu().numpy()
        expected = model.evaluate(batch_c[:2].cpu().numpy().astype(np.float64), wrinkle_depths=np.tile(depths, (2, 1)))
        difference = float(np.abs(got - expected).max())
        sync = torch.cuda.synchronize
        single_s = time_call(lambda: peer.frames(one_c, one_d), repeats=20 if quick else 200, sync=sync)
        batch_s = time_call(lambda: peer.frames(batch_c, batch_d), repeats=3 if quick else 10, sync=sync) / frames
    size = float(np.linalg.norm(np.ptp(reference.rest, axis=0)))
    return {
        "torch_ms": single_s * 1e3,
        "torch_batch_ms_per_frame": batch_s * 1e3,
        "torch_batch_frames": frames,
        "max_abs_diff_vs_torch": difference,
        "torch_matches": difference <= TORCH_TOLERANCE * size,
    }


def copy_bandwidth(device, megabytes: int = 512) -> float:
    """Device-to-device ``wp.copy`` bandwidth [bytes/s] counting read + write, median of 20 copies."""
    count = megabytes * (1 << 20) // 4
    source = wp.zeros(count, dtype=wp.float32, device=device)
    target = wp.empty(count, dtype=wp.float32, device=device)
    seconds = time_call(lambda: wp.copy(target, source), repeats=20, sync=lambda: wp.synchronize_device(device))
    return 2 * 4 * count / seconds


def frame_bytes(vertex_count: int, control_count: int) -> int:
    """Minimum bytes one frame moves: rest positions read and final positions written (12 B each per
    vertex, float32 xyz) and its controls read (4 B each); intermediates and rig data are not counted."""
    return 24 * vertex_count + 4 * control_count


def same_bytes_copy_seconds(device, vec3_count: int) -> float:
    """Median time of a device-to-device ``wp.copy`` of ``vec3_count`` float32 xyz values: it reads and
    writes 24 B per value, the minimum traffic of a frame over that many vertices."""
    source = wp.zeros(vec3_count, dtype=wp.vec3, device=device)
    target = wp.empty(vec3_count, dtype=wp.vec3, device=device)
    return time_call(lambda: wp.copy(target, source), repeats=50, warmup=3, sync=lambda: wp.synchronize_device(device))


def device_batch_rows(model, contractions: np.ndarray, quick: bool, bandwidth: float | None) -> dict:
    """``evaluate(..., out=...)`` into a device array from device controls (one replayed graph per batch), against
    a ``wp.copy`` of the same bytes (rest read + result written) timed in the same run."""
    if not model.device.is_cuda:
        return {}
    vertex_count = model.mesh.vertex_count
    frames = int(np.clip((1 << 26) // vertex_count, 16, 4096))
    rng = np.random.default_rng(5)
    controls = contractions * rng.uniform(0.5, 1.0, (frames, len(contractions)))
    device_c = wp.array(controls.astype(np.float32), dtype=wp.float32, device=model.device)
    device_d = wp.array(
        np.tile(model.default_depths, (frames, 1)).astype(np.float32), dtype=wp.float32, device=model.device
    )
    out = wp.empty((frames, vertex_count), dtype=wp.vec3, device=model.device)
    run = lambda: model.evaluate(device_c, out=out, wrinkle_depths=device_d)  # noqa: E731
    seconds = time_call(run, repeats=3 if quick else 10, warmup=2, sync=lambda: wp.synchronize_device(model.device))
    check = min(frames, 4)
    exact = bool(np.array_equal(out[:check].numpy(), model.evaluate(controls[:check])))
    rate = frames / seconds
    moved = frame_bytes(vertex_count, len(model.control_names) + len(model.wrinkle_names)) * rate
    copy_s = same_bytes_copy_seconds(model.device, frames * vertex_count)
    return {
        "device_batch_frames": frames,
        "device_batch_frames_per_s": rate,
        "device_batch_ms_per_frame": 1e3 / rate,
        "device_batch_bytes_per_s": moved,
        "device_batch_GB_per_s": moved / 1e9,
        "device_batch_exact": exact,
        "device_batch_pct_copy_bw": None if not bandwidth else 100.0 * moved / bandwidth,
        "same_bytes_copy_ms_per_frame": 1e3 * copy_s / frames,
        "device_batch_pct_same_bytes_copy": 100.0 * copy_s / seconds,
    }


def kernel_split_rows(model, contractions: np.ndarray) -> dict:
    """Where a batch chunk's time goes: each kernel of the default plan timed alone with CUDA events
    (launched one by one, no graph), in ms per frame, over one chunk of the batched path."""
    if not model.device.is_cuda:
        return {}
    frames = max(1, min(64, (1 << 24) // model.mesh.vertex_count))
    buffers = model.evaluator()._frame_buffers(frames)
    buffers.upload_controls(np.tile(contractions, (frames, 1)), np.tile(model.default_depths, (frames, 1)))
    launches = plan_launches(model, buffers, frames, buffers.contraction, buffers.depth, buffers.final_points)
    events = [wp.Event(device=model.device, enable_timing=True) for _ in range(len(launches) + 1)]
    samples: list[list[float]] = [[] for _ in launches]
    for repeat in range(13):
        wp.record_event(events[0])
        for index, (kernel, dim, inputs, outputs) in enumerate(launches):
            wp.launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=model.device, block_dim=model.block_dim)
            wp.record_event(events[index + 1])
        wp.synchronize_device(model.device)
        if repeat >= 3:
            for index, sample in enumerate(samples):
                sample.append(wp.get_event_elapsed_time(events[index], events[index + 1]))
    return {
        "kernel_split_frames": frames,
        "kernel_split_ms_per_frame": {
            kernel.key: float(np.median(sample)) / frames for (kernel, *_), sample in zip(launches, samples)
        },
    }


def graph_event_ms(graph, device, repeats: int = 500, warmup: int = 20) -> float:
    """Median GPU time of one replay of ``graph`` [ms] between CUDA events recorded on the stream just
    before and after it: the frame on the device, without the host's call and synchronisation."""
    start, end = (wp.Event(device=device, enable_timing=True) for _ in range(2))
    samples = []
    for index in range(warmup + repeats):
        wp.record_event(start)
        wp.capture_launch(graph)
        wp.record_event(end)
        wp.synchronize_event(end)
        if index >= warmup:
            samples.append(wp.get_event_elapsed_time(start, end))
    return float(np.median(samples))


def single_frame_graph(model):
    """The CUDA graph of ``model``'s single frame (captured by its first ``evaluate`` in this thread)."""
    model.evaluate(None)
    return model._evaluator._frame_buffers(1).graph


def single_frame_rows(model, contractions: np.ndarray, plans: dict) -> dict:
    """On CUDA: the single-frame graph of each plan (``plans``: models by plan name, ``model`` among them) timed
    two ways: the host's replay + synchronize (wall, what a synchronous caller waits) and CUDA events around the
    replay (GPU time); and a ``wp.copy`` of the frame's 24·V bytes."""
    if not model.device.is_cuda:
        return {}
    sync = lambda: wp.synchronize_device(model.device)  # noqa: E731
    row = {}
    expected = model.evaluate(contractions)
    for plan, other in plans.items():
        same = bool(np.array_equal(other.evaluate(contractions), expected))
        graph = single_frame_graph(other)
        row[f"device_ms_{plan}"] = time_call(lambda g=graph: wp.capture_launch(g), repeats=500, sync=sync) * 1e3
        row[f"event_ms_{plan}"] = graph_event_ms(graph, model.device)
        row[f"same_bits_{plan}"] = same
    copy_s = same_bytes_copy_seconds(model.device, model.mesh.vertex_count)
    device_ms = row[f"device_ms_{model.plan}"]
    row.update(
        device_ms=device_ms,
        event_ms=row[f"event_ms_{model.plan}"],
        copy_ms_same_bytes=copy_s * 1e3,
        device_pct_same_bytes_copy=100.0 * copy_s * 1e3 / device_ms,
    )
    return row


def run_case(label: str, mesh: wf.FaceMesh, device, quick: bool, bandwidth: float | None = None) -> dict:
    muscles, wrinkles, thickness, contractions = benchmark_rig(mesh)
    started = time.perf_counter()
    model = wf.ExpressionModel(mesh, muscles, wrinkles, thickness, device=device)  # the device's default plan
    setup = time.perf_counter() - started
    numpy_model = NumpyExpression(mesh, muscles, wrinkles, thickness, device)
    depths = model.default_depths
    check = np.abs(model.evaluate(contractions) - numpy_model.frame(contractions, depths)).max()
    big = mesh.vertex_count > 200_000
    repeats = 3 if (quick or big) else 20
    warp_s = time_call(lambda: model.evaluate(contractions), repeats=repeats, min_seconds=0.0 if quick else 0.5)
    numpy_s = time_call(
        lambda: numpy_model.frame(contractions, depths), repeats=repeats, warmup=1, min_seconds=0.0 if quick else 0.5
    )
    staged = None
    if model.device.is_cuda:  # the staged plan, timed beside the default (tiled)
        staged = wf.ExpressionModel(mesh, muscles, wrinkles, thickness, device=device, plan="staged")
    single = single_frame_rows(model, contractions, {model.plan: model, "staged": staged})
    device_s = single["device_ms"] / 1e3 if single else None
    frames = 64 if not big else 8
    batch = np.tile(contractions, (frames, 1))
    batch_s = time_call(lambda: model.evaluate(batch), repeats=3, warmup=1) / frames
    row = {
        "mesh": label,
        "vertices": mesh.vertex_count,
        "triangles": mesh.triangle_count,
        "muscle_entries": model.muscle_entry_count,
        "wrinkle_entries": model.wrinkle_entry_count,
        "setup_s": setup,
        "warp_ms": warp_s * 1e3,
        "device_ms": None if device_s is None else device_s * 1e3,
        **single,
        "batch_ms_per_frame": batch_s * 1e3,
        "numpy_ms": numpy_s * 1e3,
        "speedup": numpy_s / warp_s,
        "max_abs_diff_vs_numpy": float(check),
    }
    row.update(device_batch_rows(model, contractions, quick, bandwidth))
    if staged is not None:
        row.update(
            {f"staged_{key}": value for key, value in device_batch_rows(staged, contractions, quick, bandwidth).items()}
        )
        row["x_staged_batch"] = row["device_batch_frames_per_s"] / row["staged_device_batch_frames_per_s"]
        check = np.tile(contractions, (4, 1)) * np.linspace(0.5, 1.0, 4)[:, None]
        row["max_abs_diff_vs_staged"] = float(np.abs(staged.evaluate(check) - model.evaluate(check)).max())
    if big:
        row.update(kernel_split_rows(model, contractions))
    row.update(torch_rows(numpy_model, model, contractions, depths, quick))
    if row.get("torch_ms") and device_s:
        row["x_torch"] = row["torch_ms"] / row["device_ms"]
    if row.get("torch_batch_ms_per_frame") and row.get("device_batch_ms_per_frame"):
        row["x_torch_batch"] = row["torch_batch_ms_per_frame"] / row["device_batch_ms_per_frame"]
    return row


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
    bandwidth = copy_bandwidth(device) if device.is_cuda else None
    rows = []
    for label, mesh in cases:
        rows.append(run_case(label, mesh, device, args.quick, bandwidth))
        print(f"  measured {label}: {rows[-1]['warp_ms']:.3f} ms/frame", flush=True)
    print(f"\nExpression model, {MUSCLES} linear muscles + {WRINKLES} wrinkles, device {device} ({device.name})")
    print("baseline: vectorised NumPy float32 of the same per-frame math, same run\n")
    print_table(
        rows,
        [
            ("mesh", "mesh", "s"),
            ("vertices", "vertices", ",d"),
            ("warp_ms", "warp ms", ".3f"),
            ("device_ms", "device ms", ".3f"),
            ("batch_ms_per_frame", "batch ms/frame", ".3f"),
            ("numpy_ms", "numpy ms", ".3f"),
            ("speedup", "× numpy", ".1f"),
            ("setup_s", "setup s", ".2f"),
        ],
    )
    if device.is_cuda:
        print(
            f"\nOn device: evaluate(..., out=) a device array from device controls, one CUDA graph per batch;"
            f"\ncopy bandwidth (wp.copy, read + write) {bandwidth / 1e9:.0f} GB/s; bytes/frame = 24·V + 4·(controls)"
            f" (rest read + result written + controls)"
        )
        print(
            "PyTorch peer: the same math in float32 on the same GPU (index_add_ scatters), synchronised per call;"
            f"\nmatch = max |Δx| ≤ {TORCH_TOLERANCE:g} × mesh size; × torch = torch ms / warp device ms (both host"
            "\nwall times, synchronised per call); event ms = the frame's graph between CUDA events (GPU time, no host"
            " call)\n"
        )
        print_table(
            rows,
            [
                ("mesh", "mesh", "s"),
                ("vertices", "vertices", ",d"),
                ("device_ms", "device ms", ".4f"),
                ("event_ms", "event ms", ".4f"),
                ("torch_ms", "torch ms", ".4f"),
                ("x_torch", "× torch", ".1f"),
                ("device_batch_frames_per_s", "batched on device (frames/s)", ",.0f"),
                ("torch_batch_ms_per_frame", "torch batch ms/frame", ".4f"),
                ("x_torch_batch", "× torch batch", ".1f"),
                ("device_batch_pct_copy_bw", "% copy bw", ".0f"),
                ("device_batch_exact", "batch exact", ""),
                ("torch_matches", "torch match", ""),
            ],
        )
        print(
            "\nTiled plan (the CUDA default: one kernel, vertex tiles with a two-ring halo in shared memory) against"
            "\nthe staged plan (five kernels), batched on device as above; × staged = tiled frames/s / staged"
            "\nframes/s (same run); max |Δ| = against the staged plan over 4 frames (FMA contraction)\n"
        )
        print_table(
            rows,
            [
                ("mesh", "mesh", "s"),
                ("vertices", "vertices", ",d"),
                ("staged_device_batch_frames_per_s", "staged frames/s", ",.0f"),
                ("device_batch_frames_per_s", "tiled frames/s", ",.0f"),
                ("x_staged_batch", "× staged", ".2f"),
                ("staged_device_batch_pct_copy_bw", "staged % copy bw", ".1f"),
                ("device_batch_pct_copy_bw", "tiled % copy bw", ".1f"),
                ("device_batch_pct_same_bytes_copy", "tiled % copy (batch)", ".1f"),
                ("max_abs_diff_vs_staged", "max |Δ|", ".2e"),
                ("device_batch_exact", "tiled exact", ""),
                ("setup_s", "setup s", ".2f"),
            ],
        )
        print(
            "\nSingle-frame graph per plan (ExpressionModel(plan=...); the CUDA default: tiled),"
            "\n'same' = bit-identical to the default; a wp.copy of the same bytes (24·V: rest read + result"
            "\nwritten) in the same run; % = copy time / warp time; 'event' = GPU time between CUDA events\n"
        )
        print_table(
            rows,
            [
                ("mesh", "mesh", "s"),
                ("vertices", "vertices", ",d"),
                ("device_ms_tiled", "tiled ms", ".4f"),
                ("device_ms_staged", "staged ms", ".4f"),
                ("event_ms_tiled", "tiled event", ".4f"),
                ("event_ms_staged", "staged event", ".4f"),
                ("same_bits_staged", "staged same", ""),
                ("copy_ms_same_bytes", "copy ms", ".4f"),
                ("device_pct_same_bytes_copy", "% copy (frame)", ".0f"),
                ("device_batch_GB_per_s", "batch GB/s", ",.0f"),
                ("same_bytes_copy_ms_per_frame", "copy ms/frame", ".5f"),
                ("device_batch_pct_same_bytes_copy", "% copy (batch)", ".0f"),
            ],
        )
    results = {
        "benchmark": "expression",
        "machine": machine_info(device),
        "rows": rows,
        "copy_bandwidth_bytes_per_s": bandwidth,
        "torch_tolerance_fraction_of_size": TORCH_TOLERANCE,
    }
    path = write_results(f"expression_{device.alias.replace(':', '')}", results)
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
