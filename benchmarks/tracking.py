"""Per-frame cost of the tracking adapter on a ~33k-vertex dense face (the thesis's size).

Dense mesh: the ICT face region subdivided once (≈ 37k vertices) when ``../shared/data`` is present,
else a 182 × 182 procedural face (33,124 vertices). Sparse mesh: 121 landmarks on it (the size of
the thesis's CANDIDE-like tracked mesh), Delaunay-triangulated. Each row names its baseline,
measured in the same run:

* ``detect dots``: :class:`DotTracker` on a 640×480 image with the 121 dots (rendered by the
  synthetic camera when pyrender is available, else painted) — baseline ``cv2.SimpleBlobDetector``.
* ``back-project``: robust quadric fit over 9×9 windows for 121 landmarks (Warp kernel) —
  baseline: the nearest depth pixel (NumPy), which carries the sensor noise and every hole; with
  the synthetic camera both are also scored against ground truth (mean 3-D error).
* ``correspondence (once)``: :func:`closest_points` with the ``wp.Mesh`` BVH — baseline the same
  Voronoi-region function over all triangles per vertex (O(V·T) Warp kernel); again with MediaPipe's
  468-point face mesh (898 triangles) as the sparse mesh, in SPEC §3 normalised coordinates.
* ``transfer``: :meth:`TrackingAdapter.track_frame` (sparse update, kernel, copy to host) — baseline the
  same math vectorised in NumPy.
* ``frame total``: detect + back-project + transfer, and the frame rate it allows; then the same
  with the incremental USD write (``transfer + USD write``) in place of the transfer alone.
* ``frame loop with USD write``: the capture loop itself, measured end to end — detect, back-project,
  ``track_frame(copy=False)`` and ``TrackingStageWriter.add`` for 120 frames (four chunk flushes and
  the final close included) — as wall time and as this process's CPU time per frame; on a shared
  machine the wall time includes waiting for a core, the CPU time does not. Then the same loop with
  the source's side (detect, back-project) read ahead in a second thread by
  :func:`warpface.tracking.prefetch`, as ``record(..., prefetch=2)`` runs it, against the one-thread loop
  (interleaved repetitions, wall time): the two sides overlap on the machine's two cores.

Every row reports the median and the minimum over its repetitions (``min ms``).

    python -m benchmarks.tracking [--device cpu] [--repeats 20]
"""

from __future__ import annotations

import argparse
import os

import numpy as np
import warp as wp

from warpface.geometry import closest_point_on_triangle

from ._timing import machine_info, print_table, time_call, write_results


def subdivide(points: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One midpoint subdivision: every triangle becomes four."""
    tri = np.asarray(triangles, dtype=np.int64)
    edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    unique, inverse = np.unique(edges, axis=0, return_inverse=True)
    mid = 0.5 * (points[unique[:, 0]] + points[unique[:, 1]])
    m = inverse.reshape(3, -1).T + len(points)  # midpoints of edges 01, 12, 20
    a, b, c = tri.T
    new = np.concatenate(
        [np.stack([a, m[:, 0], m[:, 2]], 1), np.stack([m[:, 0], b, m[:, 1]], 1), np.stack([m[:, 2], m[:, 1], c], 1), m]
    )
    return np.vstack([points, mid]), new.astype(np.int32)


def dense_face() -> tuple[np.ndarray, np.ndarray, str]:
    from warpface.data import ict_face_region

    path = ict_face_region("neutral")
    if path is not None:
        from warpface.mesh import load_obj

        points, triangles = load_obj(path)
        points, triangles = subdivide(points * 0.01, triangles)
        return points, triangles, "ICT face region, subdivided"
    from warpface.tracking.synthetic import procedural_face

    points, triangles = procedural_face(182)
    return points, triangles, "procedural face 182×182"


@wp.kernel
def _brute_force_kernel(
    vertices: wp.array(dtype=wp.vec3),
    triangles: wp.array2d(dtype=wp.int32),
    queries: wp.array(dtype=wp.vec3),
    out_distance: wp.array(dtype=float),
):
    i = wp.tid()
    p = queries[i]
    best = float(1.0e30)
    for t in range(triangles.shape[0]):
        a = vertices[triangles[t, 0]]
        b = vertices[triangles[t, 1]]
        c = vertices[triangles[t, 2]]
        w = closest_point_on_triangle(p, a, b, c)
        best = wp.min(best, wp.length_sq(p - (w[0] * a + w[1] * b + w[2] * c)))
    out_distance[i] = wp.sqrt(best)


def timed(function, *, repeats: int, sync=None) -> tuple[float, float]:
    """(median, minimum) wall time of ``function()`` [s] over ``repeats`` runs after two warm-ups."""
    import time

    for _ in range(2):
        function()
        if sync:
            sync()
    samples = []
    for _ in range(repeats):
        begin = time.perf_counter()
        function()
        if sync:
            sync()
        samples.append(time.perf_counter() - begin)
    return float(np.median(samples)), float(np.min(samples))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default=None, help="Warp device (default: Warp's preferred)")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--landmarks", type=int, default=121)
    args = parser.parse_args()

    from warpface.geometry import TriangleMeshIndex, closest_points
    from warpface.tracking import KINECT_V1_INTRINSICS, KinectNoise, TrackingAdapter, backproject, place_fiducials
    from warpface.tracking.correspondence import triangulate_landmarks
    from warpface.tracking.synthetic import default_model_to_camera

    device = wp.get_device(args.device)
    wp.config.quiet = True
    dense, dense_tri, dense_name = dense_face()
    camera_to_model = np.linalg.inv(default_model_to_camera(dense))
    eye = camera_to_model[:3, 3]
    fid = place_fiducials(dense, dense_tri, args.landmarks, spacing=0.008, camera_position=eye, device=device)
    sparse = dense[fid]
    sparse_tri = triangulate_landmarks(sparse)
    print(
        f"dense: {dense_name}, {len(dense)} vertices, {len(dense_tri)} triangles; "
        f"sparse: {len(sparse)} landmarks, {len(sparse_tri)} triangles; device {device}"
    )
    rows: list[dict] = []
    sync = lambda: wp.synchronize_device(device)  # noqa: E731

    # -- colour image and depth ------------------------------------------------------------------
    intr = KINECT_V1_INTRINSICS
    color = depth = truth = None
    image_source = None
    try:
        os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
        import pyrender  # noqa: F401

        from warpface.tracking import SyntheticRGBDCamera

        cam = SyntheticRGBDCamera(dense, dense_tri, fid, dot_radius=0.002)
        frame = cam.frame(0)
        color, depth = frame.color, frame.depth_m
        depth = KinectNoise().apply(depth, np.random.default_rng(0)).astype(np.float32)
        pixels0 = cam.landmark_pixels(0)
        truth = cam.landmark_positions(0)
        image_source = "synthetic camera (pyrender), Kinect depth noise"
        cam.close()
    except ImportError:
        cam_pts = dense @ np.linalg.inv(camera_to_model)[:3, :3].T + np.linalg.inv(camera_to_model)[:3, 3]
        pixels0 = intr.project(cam_pts[fid])
        # Depth of the nearest vertex per pixel is not a rendering; use a plane at the face's depth.
        depth = np.full((intr.height, intr.width), float(np.median(cam_pts[:, 2])), np.float32)
        depth = KinectNoise().apply(depth, np.random.default_rng(0)).astype(np.float32)
        image_source = "painted dots on a plane (no pyrender)"
    try:
        import cv2

        from warpface.tracking import DotTracker

        if color is None:
            color = np.full((intr.height, intr.width, 3), (200, 150, 120), np.uint8)
            for u, v in pixels0:
                cv2.circle(color, (int(u * 16), int(v * 16)), 3 * 16, (25, 25, 25), -1, cv2.LINE_AA, shift=4)
        tracker = DotTracker(pixels0)

        def detect():
            tracker.reset(pixels0)
            tracker.detect(color)

        pixels, conf = tracker.detect(color)
        t_detect, t_detect_min = timed(detect, repeats=args.repeats)
        params = cv2.SimpleBlobDetector_Params()
        params.filterByColor, params.blobColor = True, 0
        params.minArea, params.maxArea = 6, 2000
        blob = cv2.SimpleBlobDetector_create(params)
        gray = cv2.cvtColor(color, cv2.COLOR_RGB2GRAY)
        t_blob = time_call(lambda: blob.detect(gray), repeats=args.repeats)
        rows.append(
            {
                "stage": "detect dots",
                "n": len(pixels0),
                "ms": t_detect * 1e3,
                "min_ms": t_detect_min * 1e3,
                "baseline": "cv2.SimpleBlobDetector",
                "baseline_ms": t_blob * 1e3,
                "found": int(conf.sum()),
            }
        )
    except ImportError:
        pixels = pixels0
        tracker = None
        t_detect = t_detect_min = 0.0
        print("OpenCV not installed: detection row skipped")

    # -- back-projection -------------------------------------------------------------------------
    pix = np.where(np.isfinite(pixels), pixels, pixels0)
    backproject(pix, depth, intr, device=device)
    t_back, t_back_min = timed(lambda: backproject(pix, depth, intr, device=device), repeats=args.repeats, sync=sync)

    def nearest():
        near = np.clip(np.round(pix).astype(int), 0, [intr.width - 1, intr.height - 1])
        return intr.unproject(pix, depth[near[:, 1], near[:, 0]])

    t_near = time_call(nearest, repeats=args.repeats)
    row = {
        "stage": "back-project (quadric 9×9)",
        "n": len(pix),
        "ms": t_back * 1e3,
        "min_ms": t_back_min * 1e3,
        "baseline": "nearest depth pixel (NumPy)",
        "baseline_ms": t_near * 1e3,
    }
    if truth is not None:  # accuracy against the synthetic camera's ground truth
        lifted, _ = backproject(pix, depth, intr, device=device)
        ok = np.isfinite(lifted).all(axis=1)
        row["error_mm"] = float(np.linalg.norm(lifted[ok] - truth[ok], axis=1).mean() * 1e3)
        near = nearest()
        ok = near[:, 2] > 0
        row["baseline_error_mm"] = float(np.linalg.norm(near[ok] - truth[ok], axis=1).mean() * 1e3)
    rows.append(row)

    # -- correspondence (once) -------------------------------------------------------------------
    index = TriangleMeshIndex(sparse, sparse_tri, device=device)
    index.query(dense)
    t_corr = time_call(
        lambda: closest_points(dense, sparse, sparse_tri, device=device), repeats=max(3, args.repeats // 4), sync=sync
    )
    verts = wp.array((sparse - index.center).astype(np.float32), dtype=wp.vec3, device=device)
    tris = wp.array(sparse_tri, dtype=wp.int32, device=device)
    queries = wp.array((dense - index.center).astype(np.float32), dtype=wp.vec3, device=device)
    brute = wp.empty(len(dense), dtype=float, device=device)

    def brute_force():
        wp.launch(_brute_force_kernel, dim=len(dense), inputs=[verts, tris, queries], outputs=[brute], device=device)

    brute_force()
    t_brute = time_call(brute_force, repeats=max(3, args.repeats // 4), sync=sync)
    _, _, dist = index.query(dense)
    assert np.allclose(dist, brute.numpy(), atol=1e-6), "BVH and brute force disagree"
    rows.append(
        {
            "stage": "correspondence (once)",
            "n": len(dense),
            "ms": t_corr * 1e3,
            "baseline": "all triangles per vertex (Warp)",
            "baseline_ms": t_brute * 1e3,
        }
    )

    # The MediaPipe face mesh as the sparse mesh (898 triangles), in normalised coordinates.
    from warpface.data import shared_data_path

    mp_path = shared_data_path("mediapipe", "canonical_face_model.obj")
    if mp_path is not None and dense_name.startswith("ICT"):
        from warpface.data import ict_landmark_indices
        from warpface.mesh import load_obj
        from warpface.tracking import FaceNormalization

        mp, mp_tri = load_obj(mp_path)
        s_norm = FaceNormalization.measure(mp, eye_y=mp[[33, 263], 1].mean())
        d_norm = FaceNormalization.measure(dense, eye_y=dense[ict_landmark_indices()[[36, 45]], 1].mean())
        mp_n, dense_n = s_norm.normalize(mp), d_norm.normalize(dense, match=s_norm)
        closest_points(dense_n, mp_n, mp_tri, device=device)
        t_mp = time_call(
            lambda: closest_points(dense_n, mp_n, mp_tri, device=device), repeats=max(3, args.repeats // 4), sync=sync
        )
        mp_index = TriangleMeshIndex(mp_n, mp_tri, device=device)
        mp_verts = wp.array((mp_n - mp_index.center).astype(np.float32), dtype=wp.vec3, device=device)
        mp_tris = wp.array(mp_tri.astype(np.int32), dtype=wp.int32, device=device)
        mp_queries = wp.array((dense_n - mp_index.center).astype(np.float32), dtype=wp.vec3, device=device)

        def mp_brute():
            wp.launch(
                _brute_force_kernel,
                dim=len(dense),
                inputs=[mp_verts, mp_tris, mp_queries],
                outputs=[brute],
                device=device,
            )

        t_mp_brute = time_call(mp_brute, repeats=3, sync=sync)
        rows.append(
            {
                "stage": "correspondence, MediaPipe mesh",
                "n": len(dense),
                "ms": t_mp * 1e3,
                "baseline": "all triangles per vertex (Warp)",
                "baseline_ms": t_mp_brute * 1e3,
            }
        )

    # -- transfer --------------------------------------------------------------------------------
    adapter = TrackingAdapter(sparse, sparse_tri, dense, camera_to_model=camera_to_model, device=device)
    from warpface.tracking import LandmarkFrame

    model_to_camera = np.linalg.inv(camera_to_model)
    rest_cam = sparse @ model_to_camera[:3, :3].T + model_to_camera[:3, 3]
    rng = np.random.default_rng(0)
    frames = [
        LandmarkFrame(
            i / 30, rest_cam + (rng.normal(scale=0.001, size=rest_cam.shape) if i else 0.0), np.ones(len(sparse)), i
        )
        for i in range(64)
    ]
    adapter.track_frame(frames[0])
    counter = iter(range(10**9))
    t_transfer, t_transfer_min = timed(
        lambda: adapter.track_frame(frames[1 + next(counter) % 63], copy=False),
        repeats=max(args.repeats, 50),
        sync=sync,
    )
    corr = adapter.correspondence
    bary = corr.barycentric
    corners = sparse_tri[corr.triangle]
    weights = adapter.weights[:, None]
    rest32 = dense.astype(np.float32)

    def numpy_transfer():
        disp = adapter.update_sparse(frames[5]).astype(np.float32)
        return rest32 + weights * np.einsum("vj,vjk->vk", bary, disp[corners])

    t_numpy = time_call(numpy_transfer, repeats=max(args.repeats, 50))
    rows.append(
        {
            "stage": "transfer per frame",
            "n": len(dense),
            "ms": t_transfer * 1e3,
            "min_ms": t_transfer_min * 1e3,
            "baseline": "NumPy einsum",
            "baseline_ms": t_numpy * 1e3,
        }
    )

    usd_row = _usd_write_row(adapter, frames, dense_tri)
    if usd_row is not None:
        rows.append(usd_row)

    total = t_detect + t_back + t_transfer
    rows.append(
        {
            "stage": "frame total (detect+lift+transfer)",
            "n": len(dense),
            "ms": total * 1e3,
            "min_ms": (t_detect_min + t_back_min + t_transfer_min) * 1e3,
        }
    )
    if usd_row is not None:  # the USD row includes the transfer
        rows.append(
            {
                "stage": "frame total with USD write",
                "n": len(dense),
                "ms": (t_detect + t_back) * 1e3 + usd_row["ms"],
                "min_ms": (t_detect_min + t_back_min) * 1e3 + usd_row["min_ms"],
            }
        )
        if tracker is not None:
            rows.extend(
                _frame_loop_rows(
                    tracker, pixels0, color, depth, intr, adapter, dense_tri, device, repeats=max(3, args.repeats // 4)
                )
            )
    for row in rows:
        if row.get("baseline_ms"):
            row["speedup"] = row["baseline_ms"] / row["ms"]
        row["fps"] = 1e3 / row["ms"]
    print(f"image: {image_source}; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print_table(
        rows,
        [
            ("stage", "stage", "s"),
            ("n", "n", "d"),
            ("ms", "ms", ".3f"),
            ("min_ms", "min ms", ".3f"),
            ("cpu_ms", "CPU ms", ".3f"),
            ("fps", "frames/s", ".0f"),
            ("baseline", "baseline", "s"),
            ("baseline_ms", "baseline ms", ".3f"),
            ("baseline_cpu_ms", "baseline CPU ms", ".3f"),
            ("speedup", "speed-up", ".1f"),
            ("error_mm", "error mm", ".2f"),
            ("baseline_error_mm", "baseline error mm", ".2f"),
        ],
    )
    name = "tracking" if device.is_cpu else f"tracking_{str(device).replace(':', '')}"
    path = write_results(
        name,
        {
            "benchmark": "tracking",
            "dense": dense_name,
            "dense_vertices": len(dense),
            "dense_triangles": len(dense_tri),
            "sparse_landmarks": len(sparse),
            "sparse_triangles": len(sparse_tri),
            "image": image_source,
            "machine": machine_info(device),
            "load_average": os.getloadavg(),
            "cpu_count": os.cpu_count(),
            "rows": rows,
        },
    )
    print(f"wrote {path}")


def _usd_write_row(adapter, frames, triangles, count: int = 120, repeats: int = 5) -> dict | None:
    """Transfer + incremental USD write (value-clip chunks of 30 frames, each flushed through a
    temporary file) per frame, against writing the same samples on a stage saved once at the end;
    each timed ``repeats`` times over ``count`` frames."""
    try:
        from pxr import Usd, UsdGeom, Vt
    except ImportError:
        return None
    import tempfile
    import time
    from pathlib import Path

    from warpface.usd.tracking_io import TrackingStageWriter

    names = [f"l{i}" for i in range(len(frames[0].points))]

    def ours(folder: Path) -> tuple[float, float]:
        started, started_cpu = time.perf_counter(), time.process_time()
        with TrackingStageWriter(
            folder / "capture.usda", names, 30.0, dense_rest=adapter.dense_rest, triangles=triangles
        ) as writer:
            for i in range(count):
                frame = frames[1 + i % 63]
                writer.add(i / 30.0, frame.points, frame.confidence, adapter.track_frame(frame, copy=False))
        return (time.perf_counter() - started) / count, (time.process_time() - started_cpu) / count

    def naive(folder: Path) -> tuple[float, float]:
        started, started_cpu = time.perf_counter(), time.process_time()
        stage = Usd.Stage.CreateNew(str(folder / "naive.usdc"))
        points = UsdGeom.Mesh.Define(stage, "/Face").GetPointsAttr()
        for i in range(count):
            points.Set(Vt.Vec3fArray.FromNumpy(adapter.track_frame(frames[1 + i % 63])), float(i))
        stage.Save()
        return (time.perf_counter() - started) / count, (time.process_time() - started_cpu) / count

    results = {}
    for name, write in (("ours", ours), ("naive", naive)):
        samples = []
        for _ in range(repeats):
            with tempfile.TemporaryDirectory() as folder:
                samples.append(write(Path(folder)))
        results[name] = np.array(samples)  # (repeats, [wall, CPU])
    ours_s, naive_s = results["ours"], results["naive"]
    return {
        "stage": "transfer + USD write per frame",
        "n": len(adapter.dense_rest),
        "ms": float(np.median(ours_s[:, 0])) * 1e3,
        "min_ms": float(np.min(ours_s[:, 0])) * 1e3,
        "cpu_ms": float(np.median(ours_s[:, 1])) * 1e3,
        "baseline": "Attribute.Set, one save at the end",
        "baseline_ms": float(np.median(naive_s[:, 0])) * 1e3,
        "baseline_cpu_ms": float(np.median(naive_s[:, 1])) * 1e3,
    }


def _frame_loop_rows(
    tracker, pixels0, color, depth, intrinsics, adapter, triangles, device, *, repeats: int, count: int = 120
) -> list[dict]:
    """The capture loop end to end (detect → back-project → transfer → ``TrackingStageWriter.add``)
    over ``count`` frames, ``repeats`` times: wall and process CPU time per frame."""
    import tempfile
    import time
    from pathlib import Path

    from warpface.tracking import LandmarkFrame, backproject, prefetch
    from warpface.usd.tracking_io import TrackingStageWriter

    names = [f"l{i}" for i in range(len(pixels0))]

    def landmark_frames():  # the source's side: detect and back-project
        for i in range(count):
            pixels, confidence = tracker.detect(color)
            points, _ = backproject(pixels, depth, intrinsics, device=device)
            yield LandmarkFrame(i / 30.0, points, confidence, i)

    samples = {False: ([], []), True: ([], [])}  # prefetched? -> (wall, CPU) per repetition
    for _ in range(repeats):
        for prefetched in (False, True):  # interleaved: both under the same machine load
            tracker.reset(pixels0)
            frames = prefetch(landmark_frames(), depth=2) if prefetched else landmark_frames()
            with tempfile.TemporaryDirectory() as folder:
                started, started_cpu = time.perf_counter(), time.process_time()
                with TrackingStageWriter(
                    Path(folder) / "capture.usda", names, 30.0, dense_rest=adapter.dense_rest, triangles=triangles
                ) as writer:
                    for frame in frames:
                        dense = adapter.track_frame(frame, copy=False)
                        writer.add(frame.timestamp, frame.points, frame.confidence, dense)
                samples[prefetched][0].append((time.perf_counter() - started) / count)
                samples[prefetched][1].append((time.process_time() - started_cpu) / count)
    (wall, cpu), (wall_ahead, cpu_ahead) = samples[False], samples[True]
    return [
        {
            "stage": "frame loop with USD write (wall)",
            "n": len(adapter.dense_rest),
            "ms": float(np.median(wall)) * 1e3,
            "min_ms": float(np.min(wall)) * 1e3,
            "cpu_ms": float(np.median(cpu)) * 1e3,
        },
        {
            "stage": "frame loop with USD write (CPU time)",
            "n": len(adapter.dense_rest),
            "ms": float(np.median(cpu)) * 1e3,
            "min_ms": float(np.min(cpu)) * 1e3,
        },
        {
            "stage": "frame loop, source prefetched in a thread (wall)",
            "n": len(adapter.dense_rest),
            "ms": float(np.median(wall_ahead)) * 1e3,
            "min_ms": float(np.min(wall_ahead)) * 1e3,
            "cpu_ms": float(np.median(cpu_ahead)) * 1e3,
            "baseline": "the same loop in one thread (wall)",
            "baseline_ms": float(np.median(wall)) * 1e3,
        },
    ]


if __name__ == "__main__":
    main()
