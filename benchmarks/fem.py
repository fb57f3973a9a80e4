"""Time per Newmark step of the tissue FEM: warpface's solvers vs a plain SciPy ``splu``-once baseline.

Mesh: a procedural face-like tissue shell (:func:`warpface.fem.shell_tet_mesh`, an ellipsoidal cap
12 mm thick) at ~6.4k nodes (the size of Kato's face, SPEC §2.1) and ~4x that. Material: Kato's
uniform tissue (E = 192.4 kPa, nu = 0.495, eta = 476.8 Pa s, rho = 1100 kg/m^3), dt = 1e-3 s.
Constraints as in the thesis's experiment: the upper part of the face fixed, lips and jaw points
driven by a mouth-opening trajectory.

Rows per mesh:

* ``scipy splu baseline`` — a plain implementation of SPEC §2: ``A = K + 4/dt² M + 2/dt C``,
  ``splu(A_oo)`` once with SciPy's defaults, then per step ``q`` from the full matrices, the
  Dirichlet right-hand side, one solve and the Newmark update, all float64 NumPy.
* ``scipy splu baseline anp`` — the same on the average-nodal-pressure matrices: the peer of the
  ``... anp`` rows (same matrices), whose "ratio" is against it; "× plain splu" is every row's
  time against the plain baseline (different physics: ANP couples two rings of neighbours).
* ``warpface cpu direct`` — :class:`warpface.fem.TissueSimulation` on the CPU (its default solver).
* ``warpface cuda cg`` — the graph-captured CG path, when a CUDA device is present (its default loop:
  one persistent kernel for all CG iterations); ``... launched`` the same with three launched kernels
  per iteration in a conditional graph loop (``CGOptions(loop="launched")``). "x cupy" is the CuPy peer's time
  per step over the row's.
* ``... anp`` — the same with the locking-free average-nodal-pressure stiffness.
* ``cupy cg (jacobi) peer`` — the GPU peer (CUDA, when CuPy is installed): CuPy's sparse CG on the same
  matrices, solving for the correction to the Newmark predictor with the same relative tolerance.
* ``warpface cuda cg batch xB`` — :class:`warpface.fem.TissueBatch` of B models (Kato's uniform tissue
  and a sweep of E and eta) stepped together, first mesh size only (``--batch``); "ms/step/model" is
  its time per step over B; "x one model" its time per step over the single-model ``warpface cuda cg``
  row's, "x slowest alone" over the ``step()`` time of the batch's slowest model (most CG iterations)
  stepped alone by its own ``TissueSimulation``: a batched step cannot end before that model's does.
  Its max diff is model 0's (Kato's uniform tissue) against the baseline. Rows suffixed
  ``fsai_each`` refit the FSAI support to every model (``--batch-preconditioners``).

CPU rows are timed step by step, interleaved with the baseline (median per step). On CUDA,
"ms/step run()" times :meth:`TissueSimulation.run` (displacements of every node recorded and copied
to the host) and "ms/step step()" one ``step()`` call per frame as a live tracker would (the host
then waits only once per ring of ``CGOptions.chunk`` steps). "ratio" is the baseline's time per
step over the row's run() time; "x real time" is dt over the run() time per step.
The max difference to the baseline's displacements checks that every row computes the same motion.
"CG iters max / mean" are the most and the mean CG iterations per step of the run() pass.

    python -m benchmarks.fem [--steps 200] [--sizes 40 80] [--no-anp] [--batch 1 3 10 100] [--device cuda:0] [--quick]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import scipy.sparse.linalg as spla
import warp as wp

from warpface.fem import (
    KATO_UNIFORM,
    CGOptions,
    TissueBatch,
    TissueControl,
    TissueMaterial,
    TissueSimulation,
    assemble,
    kato_uniform_material,
    shell_tet_mesh,
)
from warpface.fem.solver_direct import node_dofs

from ._timing import machine_info, print_table, write_results

DT = 1.0e-3


def face_problem(cells: int):
    """Shell mesh with ``cells`` x ``cells`` x 3 cells, fixed upper face, 7 driven lip/jaw patches."""
    mesh = shell_tet_mesh(cells, cells, 3)
    p = mesh.points
    height = p[:, 1].max() - p[:, 1].min()
    fixed = np.flatnonzero(p[:, 1] > p[:, 1].min() + 0.62 * height)
    outer = mesh.surface_nodes[p[mesh.surface_nodes, 2] > 0.0]
    mouth_y = p[:, 1].min() + 0.25 * height
    targets = np.array(
        [
            [0.0, mouth_y + 0.006],
            [-0.02, mouth_y],
            [0.02, mouth_y],
            [0.0, mouth_y - 0.006],  # lips
            [-0.035, p[:, 1].min() + 0.02],
            [0.0, p[:, 1].min() + 0.01],
            [0.035, p[:, 1].min() + 0.02],
        ]  # jaw
    )
    driven, lower = [], []
    for k, (x, y) in enumerate(targets):
        near = outer[np.hypot(p[outer, 0] - x, p[outer, 1] - y) < 0.006]
        near = np.setdiff1d(near, np.concatenate([fixed, *driven]) if driven else fixed)
        driven.append(near)
        lower.append(np.full(near.size, k != 0))
    driven_nodes = np.concatenate(driven)
    return mesh, fixed, driven_nodes, np.concatenate(lower)


def mouth_opening(steps: int, opens_down: np.ndarray) -> np.ndarray:
    """Trajectory (steps, D, 3) [m]: lower lip and jaw 12 mm down over 0.4 s, upper lip 2 mm up."""
    t = DT * np.arange(1, steps + 1)
    s = 0.5 * (1.0 - np.cos(np.pi * np.clip(t / 0.4, 0.0, 1.0)))
    traj = np.zeros((steps, opens_down.size, 3))
    traj[:, :, 1] = np.where(opens_down, -0.012, 0.002)[None, :] * s[:, None]
    traj[:, :, 2] = np.where(opens_down, -0.003, 0.0)[None, :] * s[:, None]
    return traj


class SplitBaseline:
    """Plain SPEC §2 Newmark with SciPy ``splu`` (default options) factorised once."""

    def __init__(self, mesh, material, fixed, driven, formulation: str = "linear"):
        t0 = time.perf_counter()
        K, M, C = assemble(mesh, material, formulation=formulation, device="cpu").to_scipy()
        self.assembly_seconds = time.perf_counter() - t0
        n = mesh.node_count
        free = np.setdiff1d(np.arange(n), np.union1d(fixed, driven))
        self.o, self.c = node_dofs(free), node_dofs(driven)
        self.A = (K + 4 / DT**2 * M + 2 / DT * C).tocsr()
        self.Qd = (4 / DT**2 * M + 2 / DT * C).tocsr()
        self.Qv = (4 / DT * M + C).tocsr()
        self.M = M.tocsr()
        self.A_oc = self.A[self.o][:, self.c]
        t0 = time.perf_counter()
        self.lu = spla.splu(self.A[self.o][:, self.o].tocsc())
        self.factor_seconds = time.perf_counter() - t0
        self.d = np.zeros(3 * n)
        self.v = np.zeros(3 * n)
        self.a = np.zeros(3 * n)

    def step(self, driven: np.ndarray) -> None:
        dc = driven.ravel()
        q = self.Qd @ self.d + self.Qv @ self.v + self.M @ self.a
        d_new = np.zeros_like(self.d)
        d_new[self.o] = self.lu.solve(q[self.o] - self.A_oc @ dc)
        d_new[self.c] = dc
        delta = d_new - self.d
        self.a = 4 / DT**2 * delta - 4 / DT * self.v - self.a
        self.v = 2 / DT * delta - self.v
        self.d = d_new


def interleaved_step_times(steppers: list, trajectory: np.ndarray) -> list[float]:
    """Median seconds per step of each stepper, stepping all of them through each row in turn.

    Interleaving puts every solver under the same machine load at the same moment, and the median
    ignores steps disturbed by other processes, so the ratios stay meaningful on a busy machine.
    """
    samples = np.zeros((len(steppers), len(trajectory)))
    for t, row in enumerate(trajectory):
        for k, step in enumerate(steppers):
            begin = time.perf_counter()
            step(row)
            samples[k, t] = time.perf_counter() - begin
    return [float(x) for x in np.median(samples, axis=1)]


def cuda_step_times(sim: TissueSimulation, trajectory: np.ndarray) -> tuple[float, float, np.ndarray, int, float]:
    """Seconds per step through run() and through step() calls, the final displacement of run(), and
    the most and mean CG iterations per step of run()."""
    sim.run(trajectory[:1])  # warm-up; the graph was captured at construction
    start = time.perf_counter()
    out = sim.run(trajectory[1:], progress=False)
    per_run = (time.perf_counter() - start) / (len(trajectory) - 1)
    final = out[-1].astype(np.float64)
    most, mean = sim.cg_iterations[0], sim.cg_mean_iterations
    # live use: one step() per tracked frame, no read-back (the host waits once per ring of steps)
    sim.reset()
    sim.step(trajectory[0])
    sim.synchronize()
    start = time.perf_counter()
    for row in trajectory[1:]:
        sim.step(row)
    sim.synchronize()
    return per_run, (time.perf_counter() - start) / (len(trajectory) - 1), final, most, mean


def cupy_step_seconds(base: SplitBaseline, trajectory: np.ndarray, tol: float) -> tuple[float, np.ndarray, float]:
    """The GPU peer: CuPy's ``cupyx.scipy.sparse.linalg.cg`` (Jacobi preconditioner) on the baseline's matrices.

    Each step solves for the correction to the Newmark predictor ``d + dt v + dt²/2 a`` (as warpface's CG)
    from zero with ``tol`` relative to the predictor's residual, warpface's CG criterion. Returns seconds per step,
    the final displacement (N, 3) and the mean CG iterations per step.
    """
    import inspect

    import cupy as cp
    import cupyx.scipy.sparse as csp
    import cupyx.scipy.sparse.linalg as cspla

    A_oo = csp.csr_matrix(base.A[base.o][:, base.o])
    A_oc, Qd, Qv, M = (csp.csr_matrix(x) for x in (base.A_oc, base.Qd, base.Qv, base.M))
    inverse_diagonal = cp.asarray(1.0 / base.A[base.o][:, base.o].diagonal())
    jacobi = cspla.LinearOperator(A_oo.shape, matvec=lambda r: inverse_diagonal * r, dtype=cp.float64)
    o, c = cp.asarray(base.o), cp.asarray(base.c)
    tolerance = {"rtol" if "rtol" in inspect.signature(cspla.cg).parameters else "tol": tol}
    iterations = [0]

    def count(_):
        iterations[0] += 1

    def simulate(rows):
        d = cp.zeros(base.d.shape[0])
        v, a = cp.zeros_like(d), cp.zeros_like(d)
        for row in rows:
            q = Qd @ d + Qv @ v + M @ a
            predictor = d + DT * v + 0.5 * DT * DT * a
            rhs = q[o] - A_oc @ row - A_oo @ predictor[o]
            delta, _ = cspla.cg(A_oo, rhs, M=jacobi, callback=count, **tolerance)
            d_new = cp.zeros_like(d)
            d_new[o] = predictor[o] + delta
            d_new[c] = row
            a_new = 4 / DT**2 * (d_new - d) - 4 / DT * v - a
            v = 2 / DT * (d_new - d) - v
            d, a = d_new, a_new
        return d

    driven = cp.asarray(trajectory.reshape(len(trajectory), -1))
    simulate(driven[:3])  # warm-up: CuPy compiles its kernels on first use (a fresh machine has no cache)
    iterations[0] = 0
    cp.cuda.Device().synchronize()
    start = time.perf_counter()
    d = simulate(driven)
    cp.cuda.Device().synchronize()
    seconds = (time.perf_counter() - start) / len(trajectory)
    return seconds, cp.asnumpy(d).reshape(-1, 3), iterations[0] / len(trajectory)


def batch_step_seconds(mesh, fixed, driven, trajectory, models: int, device, preconditioner: str = "fsai") -> dict:
    """A :class:`warpface.fem.TissueBatch` of ``models`` materials (model 0 Kato's uniform tissue, the rest a sweep
    of E over 0.5-2x and eta over 0.5-2x): the final displacement of model 0 after the whole trajectory, then
    seconds per batched step (graph launches only, the driven inputs already on the device)."""
    scale = np.linspace(0.5, 2.0, max(models - 1, 1))
    materials = [kato_uniform_material()] + [
        TissueMaterial(KATO_UNIFORM["E"] * e, KATO_UNIFORM["nu"], KATO_UNIFORM["eta"] * eta, KATO_UNIFORM["rho"])
        for e, eta in zip(scale, scale[::-1])
    ][: models - 1]
    start = time.perf_counter()
    batch = TissueBatch(
        mesh,
        materials,
        DT,
        fixed=fixed,
        driven=driven,
        solver="cg",
        device=device,
        cg=CGOptions(chunk=16, preconditioner=preconditioner),
    )
    setup = time.perf_counter() - start
    batch.run(trajectory, nodes=np.zeros(1, dtype=np.int64))
    final = batch.d[0]
    iterations = batch.cg_iterations
    batch.reset()
    batch.run(trajectory[:16], nodes=np.zeros(1, dtype=np.int64))
    controls = []  # the first 16 driven rows on the device, stepped in turn (a graph each, captured here)
    for row in trajectory[:16]:
        control = TissueControl(driven.size, models=models, device=device)
        control.driven.assign(np.repeat(row[None], models, axis=0))
        batch.solver.step(batch.state, batch.state, control)
        controls.append(control)
    steps = len(trajectory)
    wp.synchronize_device(device)
    start = time.perf_counter()
    for t in range(steps):
        batch.solver.step(batch.state, batch.state, controls[t % 16])
    batch.synchronize()
    seconds = (time.perf_counter() - start) / steps
    slowest = int(np.argmax(iterations[:, 2]))
    return dict(
        setup=setup,
        seconds=seconds,
        final=final,
        most=int(iterations[:, 0].max()),
        mean=float(iterations[:, 2].max()) / steps,
        slowest=materials[slowest],
    )


def bench_mesh(
    cells: int, steps: int, with_anp: bool, cuda_device, batch_sizes=(), batch_preconditioners=("fsai",)
) -> list[dict]:
    mesh, fixed, driven, lower = face_problem(cells)
    print(f"  {mesh.node_count} nodes: factorising the baselines, building the solvers", flush=True)
    material = kato_uniform_material()
    trajectory = mouth_opening(steps + 1, lower)
    label = f"{mesh.node_count} nodes"

    base = SplitBaseline(mesh, material, fixed, driven)
    bases = {"linear": base}
    if with_anp:
        bases["anp"] = SplitBaseline(mesh, material, fixed, driven, formulation="anp")
    configs = [("warpface cpu direct", "linear", "cpu", {})]
    if with_anp:
        configs.append(("warpface cpu direct anp", "anp", "cpu", {}))
    if cuda_device is not None:
        configs.append(("warpface cuda cg", "linear", cuda_device, {}))
        configs.append(("warpface cuda cg launched", "linear", cuda_device, {"cg": CGOptions(loop="launched")}))
        if with_anp:
            configs.append(("warpface cuda cg anp", "anp", cuda_device, {}))
    sims = [
        (
            name,
            formulation,
            TissueSimulation(
                mesh, material, DT, fixed=fixed, driven=driven, formulation=formulation, device=device, **options
            ),
        )
        for name, formulation, device, options in configs
    ]
    print(f"  timing {len(bases)} baseline and {len(sims)} warpface rows", flush=True)
    cpu_sims = [sim for _, _, sim in sims if sim.solver_kind == "direct"]
    steppers = [b.step for b in bases.values()] + [sim.step for sim in cpu_sims]
    for step in steppers:
        step(trajectory[0])
    cpu_times = interleaved_step_times(steppers, trajectory[1:])
    base_times = dict(zip(bases, cpu_times))
    base_step = base_times["linear"]
    reference = base.d.reshape(-1, 3)
    references = {formulation: b.d.reshape(-1, 3) for formulation, b in bases.items()}
    rows = [
        dict(
            mesh=label,
            path="scipy splu baseline" + ("" if formulation == "linear" else f" {formulation}"),
            assembly_s=b.assembly_seconds,
            factor_s=b.factor_seconds,
            factor_nnz=b.lu.L.nnz + b.lu.U.nnz,
            step_ms=1e3 * base_times[formulation],
            step_call_ms=1e3 * base_times[formulation],
            ratio=1.0,
            ratio_plain=base_step / base_times[formulation],
            realtime=DT / base_times[formulation],
            max_diff=0.0,
        )
        for formulation, b in bases.items()
    ]
    cpu_times = iter(cpu_times[len(bases) :])
    for name, formulation, sim in sims:
        if sim.solver_kind == "direct":
            per_step = step_calls = next(cpu_times)
            final, iterations, mean_iterations = sim.d, None, None
        else:
            per_step, step_calls, final, iterations, mean_iterations = cuda_step_times(sim, trajectory)
        diff = float(np.abs(final - references[formulation]).max())
        rows.append(
            dict(
                mesh=label,
                path=name,
                assembly_s=sim.timings["assembly"],
                factor_s=sim.timings.get("factorization", sim.timings["solver_setup"]),
                factor_nnz=getattr(sim.solver, "factor_nnz", None),
                step_ms=1e3 * per_step,
                step_call_ms=1e3 * step_calls,
                ratio=base_times[formulation] / per_step if formulation in base_times else base_step / per_step,
                ratio_plain=base_step / per_step,
                realtime=DT / per_step,
                max_diff=diff,
                cg_iterations=iterations,
                cg_mean_iterations=mean_iterations,
            )
        )
    if cuda_device is not None:
        try:
            import cupy  # noqa: F401
        except ImportError:
            print("  (cupy not installed: no CuPy CG row)")
        else:
            seconds, final, mean = cupy_step_seconds(base, trajectory, 1.0e-5)
            rows.append(
                dict(
                    mesh=label,
                    path="cupy cg (jacobi) peer",
                    step_ms=1e3 * seconds,
                    step_call_ms=1e3 * seconds,
                    ratio=base_step / seconds,
                    realtime=DT / seconds,
                    max_diff=float(np.abs(final - reference).max()),
                    cg_mean_iterations=mean,
                )
            )
            for row in rows:
                if row["path"].startswith("warpface cuda cg"):
                    row["x_cupy"] = seconds / (1e-3 * row["step_ms"])
        single = next((row["step_ms"] for row in rows if row["path"] == "warpface cuda cg"), None)
        for preconditioner in batch_preconditioners:
            for models in batch_sizes:
                print(f"  batch of {models} models ({preconditioner})", flush=True)
                result = batch_step_seconds(mesh, fixed, driven, trajectory, models, cuda_device, preconditioner)
                # the batch cannot finish a step before its slowest model: that model alone, stepped the same way
                alone = TissueSimulation(mesh, result["slowest"], DT, fixed=fixed, driven=driven, device=cuda_device)
                slowest_ms = 1e3 * cuda_step_times(alone, trajectory)[1]
                suffix = "" if preconditioner == "fsai" else f" {preconditioner}"
                rows.append(
                    dict(
                        mesh=label,
                        path=f"warpface cuda cg batch x{models}{suffix}",
                        factor_s=result["setup"],
                        step_ms=1e3 * result["seconds"],
                        step_call_ms=1e3 * result["seconds"],
                        model_ms=1e3 * result["seconds"] / models,
                        ratio=base_step / result["seconds"],
                        realtime=DT / result["seconds"],
                        max_diff=float(np.abs(result["final"] - reference).max()),
                        cg_iterations=result["most"],
                        cg_mean_iterations=result["mean"],
                        x_single=None if not single else 1e3 * result["seconds"] / single,
                        slowest_alone_ms=slowest_ms,
                        x_slowest_alone=1e3 * result["seconds"] / slowest_ms,
                    )
                )
    print(
        f"  {label}: {mesh.tet_count} tets, {fixed.size} fixed, {driven.size} driven nodes; "
        f"max displacement {np.abs(reference).max() * 1e3:.2f} mm after {steps + 1} steps"
    )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200, help="timed steps per row (default 200)")
    parser.add_argument(
        "--sizes", type=int, nargs="+", default=[40, 80], help="shell cells per side: 40 -> 6.7k nodes, 80 -> 26k nodes"
    )
    parser.add_argument("--no-anp", action="store_true", help="skip the locking-free rows")
    parser.add_argument(
        "--batch",
        type=int,
        nargs="*",
        default=[1, 3, 10, 100],
        help="models per TissueBatch row on CUDA, on the first mesh size (default 1 3 10 100)",
    )
    parser.add_argument(
        "--batch-preconditioners",
        nargs="*",
        default=["fsai", "fsai_each"],
        help="TissueBatch preconditioners, one set of batch rows each (default fsai fsai_each)",
    )
    parser.add_argument("--device", default=None, help="CUDA device for the CG rows (default: first CUDA device)")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="smoke run: one 2.5k-node mesh, 100 steps, batches of 1 and 3 (fsai): about 5 s on the CPU",
    )
    args = parser.parse_args()
    if args.quick:
        args.sizes, args.steps, args.batch, args.batch_preconditioners = [24], min(args.steps, 100), [1, 3], ["fsai"]

    wp.config.quiet = True
    wp.init()
    cuda = args.device or ("cuda:0" if wp.is_cuda_available() else None)
    rows = []
    for index, cells in enumerate(args.sizes):
        print(f"shell of {cells} cells per side: {args.steps} steps per row ({'CPU and ' + cuda if cuda else 'CPU'})")
        rows.extend(
            bench_mesh(
                cells, args.steps, not args.no_anp, cuda, args.batch if index == 0 else (), args.batch_preconditioners
            )
        )
    print_table(
        rows,
        [
            ("mesh", "mesh", "s"),
            ("path", "path", "s"),
            ("assembly_s", "assembly s", ".2f"),
            ("factor_s", "factor/setup s", ".2f"),
            ("factor_nnz", "factor nnz", "d"),
            ("step_ms", "ms/step run()", ".3f"),
            ("step_call_ms", "ms/step step()", ".3f"),
            ("model_ms", "ms/step/model", ".4f"),
            ("x_single", "x one model", ".2f"),
            ("x_slowest_alone", "x slowest alone", ".2f"),
            ("ratio", "ratio vs splu", ".2f"),
            ("x_cupy", "x cupy", ".1f"),
            ("ratio_plain", "x plain splu", ".2f"),
            ("realtime", "x real time", ".3f"),
            ("max_diff", "max diff m", ".1e"),
            ("cg_iterations", "CG iters max", "d"),
            ("cg_mean_iterations", "CG iters mean", ".1f"),
        ],
    )
    name = f"fem_{str(cuda).replace(':', '')}" if cuda else "fem"  # a CUDA run keeps the CPU file
    path = write_results(
        name,
        {
            "dt": DT,
            "material": dict(KATO_UNIFORM),
            "steps": args.steps,
            "machine": machine_info(cuda or "cpu"),
            "cpu_count": os.cpu_count(),
            "load_average": os.getloadavg(),
            "rows": rows,
        },
    )
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
