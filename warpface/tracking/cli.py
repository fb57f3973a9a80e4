"""``warpface track SOURCE --stage out.usda``: a landmark stream → the built-in face → USD time samples."""

from __future__ import annotations

import numpy as np

__all__ = ["run_track"]


def run_track(args) -> int:
    """Handler of the ``track`` sub-command (arguments from :func:`warpface.cli.build_parser`)."""
    from ..assets import default_rig
    from ..usd.tracking_io import TrackingStageWriter
    from .capture import adapter_for_face, open_source, record, synthetic_capture

    rig = default_rig()
    rest = rig.mesh.points
    camera_to_model = None
    closers = []
    if args.source == "synthetic":
        capture = synthetic_capture(rig, expression=args.expression, device=args.device)
        source, camera_to_model = capture.source, np.linalg.inv(capture.camera.model_to_camera)
        closers.append(capture.camera.close)
    else:
        source = open_source(args.source, layout=getattr(args, "layout", None), device=args.device)
        closers.append(getattr(source, "close", lambda: None))
    fps = getattr(source, "fps", None) or 30.0
    try:
        adapter = adapter_for_face(rest, source.landmark_names, camera_to_model=camera_to_model, device=args.device)
        writer = TrackingStageWriter(args.stage, source.landmark_names, fps, dense_rest=rest, triangles=rig.mesh.triangles)
        drive = _tissue_drive(rig, adapter, fps, args) if args.fem else None
        stats = record(source, adapter, writer, max_frames=args.frames, progress=not args.quiet, on_frame=drive)
    finally:
        for close in closers:
            close()
    print(f"tracked {stats.frames} frames at {stats.frames_per_second:.0f} frames/s, "
          f"{100 * stats.landmarks_found:.0f}% of {len(source.landmark_names)} landmarks found per frame")
    if args.fem:
        print(f"  tissue FEM: {drive.simulation.tetmesh.node_count} nodes, "
              f"{len(drive.driven_nodes)} driven, {len(drive.fixed_nodes)} fixed, {drive.substeps} steps per frame")
    print(f"  stage {args.stage}  ({fps:g} time codes per second; dense points in {writer.folder.name}/)")
    return 0


def _tissue_drive(rig, adapter, fps: float, args):
    """Tissue under the built-in face (Kato's uniform material) driven by the tracked skin."""
    from ..fem import kato_uniform_material
    from ..fem.volume import tissue_from_surface
    from .tissue_drive import TissueDrive

    thickness = max(float(np.median(rig.thickness)), 0.004)
    tetmesh = tissue_from_surface(rig.mesh, thickness, target_nodes=args.fem_nodes, device=args.device)
    material = kato_uniform_material()
    return TissueDrive(adapter, tetmesh, material, fps=fps, dt=args.fem_dt, thickness=thickness, device=args.device)
