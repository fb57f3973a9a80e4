"""What the three Newton examples share: the built-in face on a rig stage with a coarse tissue, a kinematic head
body, the loop's outputs (the rig stage's point cache and an MP4). Not an example of its own."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import warp as wp

from warpface.assets import default_rig
from warpface.fem import TissueMaterial, kato_uniform_material
from warpface.fem.volume import mesh_tissue

MIN_THICKNESS = {"kato": 0.004, "fat": 0.008}
"""Thinner tissue than this [m] is meshed at this thickness (the built-in face's lids and lips are thinner); the
soft "fat" layer is thicker, as the cheeks' fat pads are."""

FAT = TissueMaterial(E=3.0e3, nu=0.45, eta=2.0, rho=1000.0)
"""Subcutaneous fat (E of a few kPa, lightly damped): Kato's skin-like tissue (E = 192 kPa, eta = 477 Pa s) on a
4 mm layer moves by microns under a head's accelerations; a fat layer jiggles visibly."""


def face_stage(out: Path, nodes: int, material: str = "fat") -> tuple[Path, object]:
    """Write the built-in face's rig with a tissue of about ``nodes`` nodes (``material`` "fat" or "kato") to
    ``out/face.usda``; returns the stage path and the rig."""
    from warpface.usd import write_rig, write_tissue_mesh

    out.mkdir(parents=True, exist_ok=True)
    rig = default_rig()
    start = time.perf_counter()
    thickness = np.maximum(rig.thickness, MIN_THICKNESS[material])
    meshing = mesh_tissue(rig.mesh, thickness, target_nodes=nodes, device="cpu")
    print(f"tissue: {meshing.tetmesh} ({time.perf_counter() - start:.1f} s)")
    path = out / "face.usda"
    stage = write_rig(path, rig)
    skin = next(p for p in stage.Traverse() if p.GetTypeName() == "Mesh")
    tissue = FAT if material == "fat" else kato_uniform_material()
    write_tissue_mesh(stage, "/Tissue", meshing.tetmesh, tissue, skin_path=str(skin.GetPath()))
    stage.GetRootLayer().Save()
    return path, rig


def arguments(argv, doc: str, name: str, extra=None):
    """The examples' command line (``--out``, ``--nodes``, ``--material`` and ``extra(parser)``'s options), parsed;
    also quiets Warp."""
    import argparse

    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("out") / name)
    parser.add_argument("--nodes", type=int, default=600, help="tissue nodes (coarse: fast on a CPU)")
    parser.add_argument("--material", choices=("fat", "kato"), default="fat", help="soft fat or Kato's tissue")
    if extra is not None:
        extra(parser)
    wp.config.quiet = True
    return parser.parse_args(argv)


def set_body(state, body: int, position, velocity, rotation=(0.0, 0.0, 0.0, 1.0), omega=(0.0, 0.0, 0.0)) -> None:
    """Write a prescribed pose (quaternion x, y, z, w) and twist of ``body`` (COM at its origin) into ``state``."""
    q, qd = state.body_q.numpy(), state.body_qd.numpy()
    q[body, :3], q[body, 3:] = position, rotation
    qd[body, :3], qd[body, 3:] = velocity, omega
    state.body_q.assign(q)
    state.body_qd.assign(qd)


def quat_about(axis, angle: float) -> np.ndarray:
    """Quaternion (x, y, z, w) of a rotation by ``angle`` [rad] about the unit ``axis``."""
    axis = np.asarray(axis, dtype=np.float64)
    return np.r_[np.sin(0.5 * angle) * axis, np.cos(0.5 * angle)]


def finish(recorder, stage_path: Path, out: Path, name: str, fps: float, labels=None) -> None:
    """Write the recorded skin as the rig stage's point cache and render it to ``out/<name>.mp4``."""
    from warpface import preview

    cache = recorder.write(stage_path)
    print(f"cache: {cache} ({len(recorder.frames)} frames)")
    triangles = recorder.solver.face.rig.mesh.triangles
    frames = np.stack(recorder.frames)
    camera = preview.Camera.framing(frames[0], aspect=4.0 / 3.0)
    try:
        video = preview.write_video(
            list(frames), triangles, out / f"{name}.mp4", fps=fps, camera=camera, label=labels, progress=False
        )
        print(f"video: {video}")
    except Exception as exc:  # no offscreen OpenGL here: the cache is still written
        print(f"video skipped: {exc}")


def head_world(builder_cls):
    """A y-up builder (the face's frame: y up, facing +z) with the head body (kinematic: its pose is written every
    step) at the origin."""
    builder = builder_cls()
    builder.gravity = (0.0, -9.81, 0.0)
    head = builder.add_body(xform=wp.transform((0.0, 0.0, 0.0), wp.quat_identity()), is_kinematic=True)
    return builder, head


def live_link_take(path: Path, seconds: float = 2.0, fps: float = 30.0) -> Path:
    """Write a Live Link Face take (ARKit weights: a smile with raised brows and an open jaw, and a blink) to
    ``path``."""
    from warpface.drivers import Curves, write_live_link

    times = np.arange(int(seconds * fps)) / fps
    rise = np.clip((times - 0.2) / 0.4, 0.0, 1.0) * np.clip((seconds - 0.1 - times) / 0.4, 0.0, 1.0)
    blink = np.exp(-(((times - 0.5 * seconds) / 0.06) ** 2))
    channels = {
        "mouthSmileLeft": 0.8 * rise,
        "mouthSmileRight": 0.8 * rise,
        "browInnerUp": 0.6 * rise,
        "jawOpen": 0.3 * rise,
        "eyeBlinkLeft": blink,
        "eyeBlinkRight": blink,
    }
    curves = Curves(times, list(channels), np.stack(list(channels.values()), axis=1), source=path.name, fps=fps)
    return write_live_link(path, curves)


def take_controls(path: Path, rig) -> tuple[np.ndarray, np.ndarray]:
    """``(times (F,), controls (F, C) in the rig's control order)`` of a driver file, through the default table."""
    from warpface.drivers.default_tables import mapping_for_rig
    from warpface.usd import read_driver

    mapping, _, _ = mapping_for_rig(rig)
    mapped = mapping.apply(read_driver(path))
    controls = np.zeros((len(mapped.times), len(rig.control_names)))
    for k, name in enumerate(mapped.names):
        controls[:, rig.control_names.index(name)] = mapped.values[:, k]
    return mapped.times, controls


def play_take(stage_path: Path, rig, take: Path, head_pose, *, dt: float, fps: float, **solver_options):
    """Play a driver take on the face whose skull is a kinematic body moved by ``head_pose(t) -> (position,
    quaternion, velocity, angular velocity)``; returns the :class:`~warpface.newton.SkinRecorder` of the run
    (head-frame skin, one frame per ``1/fps``) and the tissue's largest displacement [m] per frame."""
    import newton

    from warpface.newton import SkinRecorder, SolverFace, add_face

    times, controls = take_controls(take, rig)
    builder, head = head_world(newton.ModelBuilder)
    face = add_face(builder, stage_path, head_body=head)
    model = builder.finalize(device="cpu")
    solver = SolverFace(model, face, **solver_options)
    state_in, state_out, control = model.state(), model.state(), model.control()
    position, rotation, velocity, omega = head_pose(0.0)
    set_body(state_in, head, position, velocity, rotation, omega)
    solver.reset(state_in)
    recorder = SkinRecorder(solver)
    every = int(round(1.0 / (fps * dt)))
    steps = int(round(times[-1] / dt))
    lag = []
    start = time.perf_counter()
    for k in range(steps):
        t1 = (k + 1) * dt
        row = min(int(np.searchsorted(times, t1, side="right")) - 1, len(times) - 1)
        control.warpface.activation.assign(controls[row].astype(np.float32))
        position, rotation, velocity, omega = head_pose(t1)
        set_body(state_out, head, position, velocity, rotation, omega)
        solver.step(state_in, state_out, control, None, dt)
        state_in, state_out = state_out, state_in
        if (k + 1) % every == 0:
            recorder.record((k + 1) // every, state_in)
            lag.append(float(np.abs(solver.simulation.d).max()))
    print(f"{steps} steps of {1e3 * dt:g} ms in {time.perf_counter() - start:.1f} s")
    return recorder, np.array(lag)
