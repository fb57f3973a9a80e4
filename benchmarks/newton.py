"""warpface's tissue step inside Newton: the plug's overhead, and Newton's own soft-body solvers on the same tets.

Tissue: the face-like shell of :func:`warpface.fem.shell_tet_mesh` (12 mm thick, its inner layer fixed: the skull),
Kato's uniform material (E = 192.4 kPa, nu = 0.495, eta = 476.8 Pa s, rho = 1100 kg/m^3).

Rows:

* ``standalone TissueSimulation`` — :class:`warpface.fem.TissueSimulation` stepping on its own: the peer. Both it
  and the plug start from the same released sag, so each step solves for real motion (on a Kato-size shell,
  ``--overhead-cells 40``: 6,724 nodes).
* ``SolverFace (plug)`` — the same step as a Newton solver (``SolverFace.step`` with a fixed head, no contact:
  the standalone step plus reading the controls and the head, and writing the particles). "× standalone" is
  its time per step over the peer's: the plug's overhead (goal <= 1.10).
* ``standalone TissueSimulation, CG`` — the peer on the CG solver (the host-free path's tissue solver; on CUDA
  the same as the first row).
* ``SolverFace host-free, eager`` / ``own graphs`` / ``graph replay`` — the plug with ``graph_capturable=True``
  (docs/NEWTON.md §5: every part of the step on the device, the tissue on the CG solver with the head's body force
  on its right-hand side, taken even with a still head): its launches stepped eagerly (``step_graphs=False``),
  replayed by ``SolverFace.step`` from graphs of its own (``step_graphs=True``, the CUDA default: what the plug row
  is on CUDA), and as one step captured by the caller with ``wp.ScopedCapture`` and replayed with
  ``wp.capture_launch`` (a CPU graph on the CPU, a CUDA graph on CUDA). "launches" counts the host's launch calls
  per step (kernels, tiled kernels, recorded launches, graph launches, memsets and copies; on the CPU the CG loop's
  iterations are launches too, on CUDA its persistent kernel is one).
* ``SolverFace 2 g load`` and Newton's ``SolverVBD``, ``SolverXPBD``, ``SolverSemiImplicit`` — the same tets,
  material (Newton's tets get the material's Lamé parameters, damping and density) and fixed nodes under a
  uniform 2 g body load (the head's extra gravity in a "hyper" replay), each stepped for the same simulated
  time with its own time step; "error" is the largest distance of a node from the static reference solution
  ``K_oo d = (M 1⊗b)_o`` (float64 SciPy solve of warpface's assembly) over the reference's largest displacement,
  averaged over the last 10 % of the steps (a run stops at ``--max-steps``: "sim s" says how far it got).
  Newton's tets are Neo-Hookean: at these strains (< 1e-3) the linear reference is theirs too. Newton's
  semi-implicit solver diverges at dt = 2e-5 s on these nearly incompressible tets (nu = 0.495), so it runs at
  5e-6 s; its particles get a 0.1 mm radius (Newton's default 0.1 m makes neighbouring nodes repel).

    python -m benchmarks.newton [--cells 16] [--seconds 0.1] [--max-steps 4000] [--device cpu|cuda:0] [--quick]
        [--overhead-only] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import scipy.sparse.linalg as spla
import warp as wp

from benchmarks._timing import machine_info, print_table, write_results

LOAD = np.array([0.0, -2.0 * 9.81, 0.0])
"""The body load [m/s²]: 2 g downwards (y up)."""


def shell(cells: int):
    from warpface.fem import kato_uniform_material, shell_tet_mesh

    tetmesh = shell_tet_mesh(cells, cells, 3, thickness=0.012)
    return tetmesh, kato_uniform_material(), np.arange((cells + 1) ** 2)


def static_reference(tetmesh, material, fixed) -> np.ndarray:
    """``K_oo d = (M 1⊗LOAD)_o``, displacements (N, 3) [m], float64."""
    from warpface.fem import assemble
    from warpface.fem.solver_direct import node_dofs

    K, M, _ = assemble(tetmesh, material, device="cpu").to_scipy()
    free = np.setdiff1d(np.arange(tetmesh.node_count), fixed)
    dofs = node_dofs(free)
    force = M @ np.tile(LOAD, tetmesh.node_count)
    d = np.zeros((tetmesh.node_count, 3))
    d[free] = spla.spsolve(K.tocsc()[dofs][:, dofs], force[dofs]).reshape(-1, 3)
    return d


def face_world(tetmesh, material, fixed, device):
    """A Newton model holding the shell as a warpface face (world-fixed skull) and its NewtonFace."""
    import newton

    from warpface.newton import add_face
    from warpface.rig import FaceRig

    rig = FaceRig(_skin(tetmesh, fixed), [], [], 0.012)
    builder = newton.ModelBuilder()
    face = add_face(builder, rig, tissue=(tetmesh, material), fixed=fixed, driven=[])
    return builder.finalize(device=device), face


def _skin(tetmesh, fixed):
    """The shell's outer layer as a FaceMesh (the render skin of the face)."""
    from warpface.mesh import FaceMesh

    per = fixed.size
    side = int(round(np.sqrt(per)))
    grid = np.arange(per).reshape(side, side)
    a, b, c, d = grid[:-1, :-1].ravel(), grid[:-1, 1:].ravel(), grid[1:, :-1].ravel(), grid[1:, 1:].ravel()
    return FaceMesh(tetmesh.points[-per:], np.r_[np.c_[a, b, d], np.c_[a, d, c]], name="shell")


def overhead_rows(tetmesh, material, fixed, device, steps: int) -> list[dict]:
    """Both start from the same moving state (the tissue released from a static sag), so every step solves. The
    host-free (graph-capturable) SolverFace runs eagerly and as one captured step replayed (a CPU graph here)."""
    from warpface.fem import TissueSimulation
    from warpface.newton import SolverFace

    dt = 1.0e-3
    model, face = face_world(tetmesh, material, fixed, device)
    solver = SolverFace(model, face, dt=dt)
    standalone = TissueSimulation(tetmesh, material, dt, fixed=fixed, device=device)
    start = 20.0 * static_reference(tetmesh, material, fixed)  # ~0.5 mm: a released sag, ringing down
    standalone.reset(start)
    solver.simulation.reset(start)
    standalone_cg = TissueSimulation(tetmesh, material, dt, fixed=fixed, device=device, solver="cg")
    standalone_cg.reset(start)
    sync = wp.synchronize_device if not wp.get_device(device).is_cpu else (lambda: None)

    def stepper(face_solver):
        states, control = [model.state(), model.state()], model.control()

        def step():
            face_solver.step(states[0], states[1], control, None, dt)
            states.reverse()

        return step

    host_free, own, captured = (
        SolverFace(model, face, dt=dt, graph_capturable=True, step_graphs=graphs) for graphs in (False, True, False)
    )
    for free in (host_free, own, captured):
        free.simulation.reset(start)
    replay_states, replay_control = model.state(), model.control()
    captured.step(replay_states, replay_states, replay_control, None, dt)  # binds the arrays, loads the kernels
    with wp.ScopedCapture(device=device) as capture:
        captured.step(replay_states, replay_states, replay_control, None, dt)

    def replay():
        wp.capture_launch(capture.graph)

    # interleaved, step by step, so that a load change on a shared machine hits both alike
    functions = [standalone.step, stepper(solver), standalone_cg.step, stepper(host_free), stepper(own), replay]
    samples = {function: [] for function in functions}
    for k in range(steps + 5):  # the own graphs: an eager step and a capture per state pair first
        for function, times in samples.items():
            begin = time.perf_counter()
            function()
            sync()
            if k >= 5:
                times.append(time.perf_counter() - begin)
    for free in (host_free, own, captured):
        free.synchronize()
    names = ("standalone TissueSimulation", "SolverFace (plug)", "standalone TissueSimulation, CG")
    names += ("SolverFace host-free, eager", "SolverFace host-free, own graphs", "SolverFace host-free, graph replay")
    peer = float(np.median(samples[functions[0]]))
    return [
        {"row": name, "ms": 1e3 * ms, "ratio": ms / peer, "launches": launches_per_step(function)}
        for name, function, ms in zip(names, functions, (float(np.median(t)) for t in samples.values()))
    ]


def launches_per_step(function, steps: int = 4) -> float:
    """The host's launch calls per call of ``function`` (kernels, tiled kernels, recorded launches, graph launches,
    memsets, copies, ``wp.capture_while``), counted by wrapping Warp's entry points over ``steps`` calls."""
    count = [0]

    def counting(real):
        def counted(*args, **kwargs):
            count[0] += 1
            return real(*args, **kwargs)

        return counted

    entries = [(wp, name) for name in ("launch", "launch_tiled", "capture_launch", "copy", "capture_while")]
    entries += [(wp.array, "zero_"), (wp.array, "fill_"), (wp.Launch, "launch")]
    saved = [getattr(owner, name) for owner, name in entries]
    for (owner, name), real in zip(entries, saved):
        setattr(owner, name, counting(real))
    try:
        for _ in range(steps):
            function()
    finally:
        for (owner, name), real in zip(entries, saved):
            setattr(owner, name, real)
    return count[0] / steps


def _loaded_newton(tetmesh, material, fixed, device):
    """Newton's own model of the shell: the same tets, Lamé parameters, damping and density, fixed nodes massless."""
    import newton

    builder = newton.ModelBuilder()
    builder.gravity = tuple(LOAD)
    fields = material.per_tet(tetmesh.tet_count)
    lam, mu = material.lame(tetmesh.tet_count)
    builder.add_soft_mesh(
        pos=wp.vec3(0.0, 0.0, 0.0),
        rot=wp.quat_identity(),
        scale=1.0,
        vel=wp.vec3(0.0, 0.0, 0.0),
        vertices=tetmesh.points.astype(np.float32),
        indices=tetmesh.tets.astype(np.int32).ravel(),
        density=float(fields["rho"][0]),
        k_mu=mu,
        k_lambda=lam,
        k_damp=fields["eta"],
        particle_radius=1.0e-4,  # Newton's default radius (0.1 m) would make every node collide with its neighbours
    )
    for node in fixed:
        builder.particle_mass[node] = 0.0
    builder.color()  # VBD solves per graph colour
    return builder.finalize(device=device)


def accuracy_rows(
    tetmesh, material, fixed, device, seconds: float, reference: np.ndarray, max_steps: int
) -> list[dict]:
    import newton

    from warpface.newton import SolverFace

    scale = float(np.abs(reference).max())
    rows = []

    def run(name, model, make_solver, dt, positions, collide=False):
        solver = make_solver(model)
        s0, s1, control = model.state(), model.state(), model.control()
        contacts = model.contacts() if collide else None
        steps = max(1, min(int(round(seconds / dt)), max_steps))
        errors = []
        start = time.perf_counter()
        for k in range(steps):
            s0.clear_forces()
            solver.step(s0, s1, control, contacts, dt)
            s0, s1 = s1, s0
            if k >= steps - max(1, steps // 10):
                moved = positions(s0) - tetmesh.points
                errors.append(float(np.abs(moved - reference).max()) / scale)
        wp.synchronize_device(device)
        elapsed = time.perf_counter() - start
        rows.append(
            {
                "row": name,
                "dt": dt,
                "steps": steps,
                "simulated": steps * dt,
                "ms": 1e3 * elapsed / steps,
                "total": elapsed,
                "error": np.mean(errors),
            }
        )

    model, face = face_world(tetmesh, material, fixed, device)
    particles = face.particles

    def face_positions(state):
        return state.particle_q.numpy()[particles].astype(np.float64)

    run(
        "SolverFace 2 g load",
        model,
        lambda m: SolverFace(m, face, dt=1.0e-3, gravity=LOAD, rest_gravity=(0.0, 0.0, 0.0)),
        1.0e-3,
        face_positions,
    )
    newton_model = _loaded_newton(tetmesh, material, fixed, device)

    def own_positions(state):
        return state.particle_q.numpy().astype(np.float64)

    for name, make, dt in (
        ("Newton SolverVBD (10 it)", lambda m: newton.solvers.SolverVBD(m, iterations=10), 1.0e-3),
        ("Newton SolverXPBD (10 it)", lambda m: newton.solvers.SolverXPBD(m, iterations=10), 1.0e-3),
        ("Newton SolverSemiImplicit", lambda m: newton.solvers.SolverSemiImplicit(m), 5.0e-6),  # 2e-5 diverges
    ):
        try:
            run(name, newton_model, make, dt, own_positions)
        except Exception as exc:  # a solver this Newton build cannot run on these tets: say so in the table
            rows.append({"row": f"{name}: {type(exc).__name__}: {str(exc)[:60]}"})
    for row in rows:
        if "total" in row:
            row["ratio"] = row["total"] / rows[0]["total"]
    return rows


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cells", type=int, default=16, help="shell cells per side (3 layers) of the accuracy rows")
    parser.add_argument(
        "--overhead-cells", type=int, default=40, help="the same for the overhead rows (40: Kato's size)"
    )
    parser.add_argument("--seconds", type=float, default=0.1, help="simulated time of the accuracy runs [s]")
    parser.add_argument("--steps", type=int, default=200, help="timed steps of the overhead rows")
    parser.add_argument("--max-steps", type=int, default=4000, help="cap on any accuracy run's steps")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--quick", action="store_true", help="a small shell, short runs")
    parser.add_argument("--overhead-only", action="store_true", help="only the plug's overhead rows")
    parser.add_argument("--out", default=None, help="also write the JSON results into this folder")
    args = parser.parse_args(argv)
    if args.quick:
        args.cells, args.overhead_cells, args.seconds, args.steps, args.max_steps = 8, 16, 0.01, 50, 2000
    wp.config.quiet = True
    tetmesh, material, fixed = shell(args.cells)
    print(f"tissue: {tetmesh}, {fixed.size} fixed nodes, device {args.device}")
    big, big_material, big_fixed = shell(args.overhead_cells)
    print(f"overhead rows: {big}")
    overhead = overhead_rows(big, big_material, big_fixed, args.device, args.steps)
    columns = [("row", "row", "s"), ("ms", "ms/step", ".3f"), ("ratio", "× standalone", ".3f")]
    print_table(overhead, [*columns, ("launches", "launches", ".1f")])
    accuracy = [] if args.overhead_only else _accuracy(tetmesh, material, fixed, args)
    name = "newton_" + str(args.device).replace(":", "") + ("_quick" if args.quick else "")
    name += "_overhead" if args.overhead_only else ""
    payload = {
        "machine": machine_info(args.device),
        "nodes": tetmesh.node_count,
        "tets": tetmesh.tet_count,
        "seconds": args.seconds,
        "overhead": overhead,
        "accuracy": accuracy,
    }
    print(f"\nwrote {write_results(name, payload)}")
    if args.out:
        path = Path(args.out) / f"{name}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(payload, indent=2, default=float))
        print(f"wrote {path}")


def _accuracy(tetmesh, material, fixed, args) -> list[dict]:
    reference = static_reference(tetmesh, material, fixed)
    print(f"\nstatic reference: largest displacement {1e6 * np.abs(reference).max():.2f} µm under 2 g")
    accuracy = accuracy_rows(tetmesh, material, fixed, args.device, args.seconds, reference, args.max_steps)
    print_table(
        accuracy,
        [
            ("row", "row", "s"),
            ("dt", "dt s", ".0e"),
            ("steps", "steps", "d"),
            ("simulated", "sim s", ".3f"),
            ("ms", "ms/step", ".3f"),
            ("total", "total s", ".2f"),
            ("ratio", "× SolverFace time", ".2f"),
            ("error", "error / max|d|", ".2e"),
        ],
    )
    return accuracy


if __name__ == "__main__":
    main()
