"""The local engine: worker processes on this machine, each running takes one after another.

Workers are started with ``spawn`` (never ``fork``: the parent may hold a CUDA context) and live for the whole
batch, so Python's start-up, warpface's imports, Warp's kernel loads and each rig's expression model
(:class:`~warpface.commands.rig_models.RigModels`) are paid once per worker, not once per take; all share the
parent's Warp kernel cache folder. The parent hands a worker one take at a time over a pipe, so it always knows
which take a worker holds: a worker that dies (SIGKILL, out of memory) has its take retried on a fresh worker, up
to ``retries`` times. Workers ignore SIGINT; on Ctrl-C the parent ends them, and their unfinished takes (only ever
in hidden ``.partial`` folders) are removed by the caller.
"""

from __future__ import annotations

import os
from collections import deque
from dataclasses import dataclass

__all__ = ["local_results", "worker_devices", "init_worker", "freeze_survivors"]


def worker_devices(jobs: int | None, *, device: str | None = None) -> list[str]:
    """The device of each worker: ``jobs`` workers (default one per CPU core) on the CPU, or on CUDA one per
    device by default (one GPU job at a time per device), given ``jobs`` spread over the devices in turn."""
    import warp as wp

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    if device is None:
        device = "cuda" if wp.get_cuda_device_count() > 0 else "cpu"
    if device == "cpu":
        return ["cpu"] * (jobs or cores)
    gpus = [device] if ":" in device else [f"cuda:{n}" for n in range(wp.get_cuda_device_count())]
    return [gpus[n % len(gpus)] for n in range(jobs or len(gpus))]


def init_worker(kernel_cache: str | None) -> None:
    """Set up a worker process: Warp's kernel cache in the parent's folder, Warp initialised quietly."""
    import warp as wp

    from .. import init_runtime

    if kernel_cache:
        wp.config.kernel_cache_dir = kernel_cache
    init_runtime(quiet=True)


def freeze_survivors() -> None:
    """Collect garbage once, then leave what survives (modules, Warp's kernels, the worker's rig models) out of
    every later collection.

    Each take's contact-sheet picture closes an offscreen renderer, and pyrender runs a full ``gc.collect()`` on
    close: over a warmed-up worker's quarter million objects that is 0.2 s a take, over the objects of one take a
    fraction of a millisecond. Frozen objects are still freed when their last reference goes.
    """
    import gc

    gc.collect()
    gc.freeze()


def _worker_main(connection, device: str, kernel_cache: str | None) -> None:
    """A worker's loop: receive ``(take, digest, out)``, send back the take's report entry; ``None`` ends it."""
    import signal
    from pathlib import Path

    from ..commands.rig_models import RigModels
    from .take import run_take

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides what Ctrl-C stops
    init_worker(kernel_cache)
    rigs = RigModels()  # each rig read and its model built once per worker
    frozen = False
    while True:
        try:
            job = connection.recv()
        except EOFError:
            return
        if job is None:
            return
        take, digest, out = job
        connection.send(run_take(take, Path(out), device=device, digest=digest, rigs=rigs))
        if not frozen:
            freeze_survivors()
            frozen = True


@dataclass
class _Worker:
    process: object
    connection: object
    device: str
    job: tuple | None = None


def local_results(work, out, *, devices: list[str], retries: int, kernel_cache: str | None):
    """Run ``work`` (``[(take, digest)]``) on worker processes, one per entry of ``devices``; yields each take's
    report entry as it lands (in finishing order).

    A take whose worker died is retried up to ``retries`` times, then reported failed.
    """
    import multiprocessing
    from multiprocessing.connection import wait

    context = multiprocessing.get_context("spawn")
    queue = deque((take, digest, str(out)) for take, digest in work)
    lost: dict[str, int] = {}
    workers: list[_Worker | None] = [None] * min(len(devices), len(queue))

    def start(device: str) -> _Worker:
        mine, theirs = context.Pipe()
        process = context.Process(
            target=_worker_main, args=(theirs, device, kernel_cache), name="warpface-batch", daemon=True
        )
        process.start()
        theirs.close()
        return _Worker(process, mine, device)

    try:
        while queue or any(w is not None and w.job is not None for w in workers):
            for slot, worker in enumerate(workers):
                if worker is None and queue:
                    worker = workers[slot] = start(devices[slot])
                if worker is not None and worker.job is None and queue:
                    worker.job = queue.popleft()
                    worker.connection.send(worker.job)
            busy = [w for w in workers if w is not None and w.job is not None]
            ready = wait([w.connection for w in busy] + [w.process.sentinel for w in busy])
            for slot, worker in enumerate(workers):
                if worker is None or worker.job is None:
                    continue
                if worker.connection in ready or worker.process.sentinel in ready:
                    entry = _receive(worker)
                    if entry is not None:
                        worker.job = None
                        yield entry
                        continue
                    workers[slot] = None  # the worker died holding its take
                    take = worker.job[0]
                    lost[take.id] = lost.get(take.id, 0) + 1
                    if lost[take.id] > retries:
                        yield _lost_entry(worker.job, lost[take.id], worker.process.exitcode)
                    else:
                        queue.appendleft(worker.job)
    finally:
        _stop([w for w in workers if w is not None])


def _receive(worker: _Worker) -> dict | None:
    """The entry the worker sent, or None when it died first."""
    import pickle

    try:
        if worker.connection.poll():
            return worker.connection.recv()
    except (EOFError, OSError, pickle.UnpicklingError):  # died before or while sending
        pass
    worker.process.join(timeout=5)
    worker.connection.close()
    return None


def _lost_entry(job, times: int, exitcode) -> dict:
    from .take import failed_entry

    take, digest, _ = job
    cause = f"killed by signal {-exitcode}" if exitcode is not None and exitcode < 0 else f"exit code {exitcode}"
    return failed_entry(take, digest, f"its worker was lost {times} times ({cause})")


def _stop(workers: list[_Worker]) -> None:
    """End the workers: idle ones are asked to leave, busy ones (Ctrl-C, an error in the parent) are terminated."""
    for worker in workers:
        if worker.job is None and worker.process.is_alive():
            try:
                worker.connection.send(None)
            except OSError:
                pass
        else:
            worker.process.terminate()
    for worker in workers:
        worker.process.join(timeout=10)
        if worker.process.is_alive():
            worker.process.kill()
            worker.process.join()
        worker.connection.close()
