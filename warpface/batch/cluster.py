"""The Ray engine: one Ray task per take, on a local Ray (started here) or a cluster (``--address`` or
``RAY_ADDRESS``).

Each task asks for one CPU and, when the cluster has GPUs and the batch is not on the CPU, a GPU: a whole one for
a large rig, :data:`SMALL_RIG_GPU` of one for a rig under :data:`SMALL_RIG_VERTICES` vertices (several small takes
share a device). A task whose worker is lost (killed, its node gone) is retried by Ray up to ``retries`` times; a
take's own error is caught inside the task and reported, so it is never retried (``retry_exceptions`` off). Ray
reuses its worker processes, so Warp initialises (with the driver's kernel cache folder when the node has it) and
each rig's expression model is built once per worker. On a cluster the output folder must be on a file system every
node shares, and warpface installed on every node.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["ray_results", "import_ray", "SMALL_RIG_VERTICES", "SMALL_RIG_GPU"]

SMALL_RIG_VERTICES = 50_000
"""Rigs with fewer skin vertices than this share a GPU (:data:`SMALL_RIG_GPU` of one per take)."""

SMALL_RIG_GPU = 0.25
"""The fraction of a GPU a take of a small rig asks for."""

_worker_rigs = None
"""This Ray worker's :class:`~warpface.commands.rig_models.RigModels` (None until its first take)."""


def import_ray():
    """The ``ray`` module; ValueError saying how to install it when it is missing."""
    try:
        import ray
    except ImportError:
        raise ValueError("--engine ray needs Ray: pip install 'warpface[ray]'") from None
    return ray


def _ray_take(take, digest: str, out: str, device: str, kernel_cache: str | None) -> dict:
    """The body of a Ray task: one take (see :func:`warpface.batch.take.run_take`)."""
    global _worker_rigs
    from .pool import freeze_survivors
    from .take import run_take

    first = _worker_rigs is None
    if first:
        from ..commands.rig_models import RigModels
        from .pool import init_worker

        init_worker(kernel_cache if kernel_cache and Path(kernel_cache).is_dir() else None)
        _worker_rigs = RigModels()
    entry = run_take(take, Path(out), device=device, digest=digest, rigs=_worker_rigs)
    if first:
        freeze_survivors()  # after the worker's first take (see there)
    return entry


def ray_results(work, out, *, device: str | None, address: str | None, retries: int, kernel_cache: str | None):
    """Run ``work`` (``[(take, digest)]``) as Ray tasks; yields each take's report entry as it lands.

    Starts a local Ray unless one is running in this process already (then it is used and left running) or
    ``address``/``RAY_ADDRESS`` names a cluster; shuts down what it started.
    """
    ray = import_ray()
    started = not ray.is_initialized()
    if started:
        import logging

        ray.init(
            address=address or os.environ.get("RAY_ADDRESS") or None,
            include_dashboard=False,
            log_to_driver=False,
            logging_level=logging.WARNING,
        )
    pending = {}
    try:
        gpus = ray.cluster_resources().get("GPU", 0)
        if device is not None and device.startswith("cuda") and not gpus:
            raise ValueError(f"--device {device}: the Ray cluster has no GPUs")
        on_gpu = device != "cpu" and gpus > 0
        task = ray.remote(_ray_take)
        for take, digest in work:
            share = 0 if not on_gpu else SMALL_RIG_GPU if take.rig_vertices < SMALL_RIG_VERTICES else 1
            options = task.options(num_cpus=1, num_gpus=share, max_retries=retries, retry_exceptions=False)
            reference = options.remote(take, digest, str(out), "cuda:0" if on_gpu else "cpu", kernel_cache)
            pending[reference] = (take, digest)
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for reference in ready:
                take, digest = pending.pop(reference)
                yield _entry(ray, reference, take, digest)
    finally:
        for reference in pending:
            ray.cancel(reference, force=True)
        if started:
            ray.shutdown()


def _entry(ray, reference, take, digest: str) -> dict:
    """The task's report entry; a take whose task could not finish (its worker lost ``retries`` + 1 times, its
    node gone) is reported failed with Ray's reason."""
    from ..commands.common import one_line

    try:
        return ray.get(reference)
    except ray.exceptions.RayError as error:
        from .take import failed_entry

        return failed_entry(take, digest, f"its Ray task failed: {one_line(error).split('. ')[0]}")
