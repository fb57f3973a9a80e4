""":func:`run`: a manifest's takes through an engine into an output folder, with report, contact sheet and shoot."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

__all__ = ["run", "BatchResult", "ENGINES", "DEFAULT_RETRIES"]

ENGINES = ("local", "ray")
"""``local``: worker processes on this machine (:mod:`~warpface.batch.pool`); ``ray``: Ray tasks
(:mod:`~warpface.batch.cluster`)."""

DEFAULT_RETRIES = 2
"""How many times a take whose worker was lost is run again before it is reported failed."""


@dataclass
class BatchResult:
    """What :func:`run` did."""

    takes: list[dict]
    """Every take's report entry, in manifest order (see :mod:`warpface.batch.report`)."""
    report: Path
    sheet: Path
    shoot: Path | None
    """``shoot.usda``, or None when no take is complete."""

    def count(self, status: str) -> int:
        return sum(entry["status"] == status for entry in self.takes)

    @property
    def failed(self) -> list[dict]:
        return [entry for entry in self.takes if entry["status"] == "failed"]


def run(
    manifest,
    out,
    *,
    engine: str = "local",
    address: str | None = None,
    force: bool = False,
    jobs: int | None = None,
    retries: int = DEFAULT_RETRIES,
    device=None,
    progress: bool = True,
) -> BatchResult:
    """Run every take of ``manifest`` into ``out/<id>/`` and write ``out/report.json``, ``out/report.png`` and
    ``out/shoot.usda``.

    Args:
        manifest: a manifest file (TOML, JSON or CSV; see :mod:`warpface.batch.manifest`) or a
            :class:`~warpface.batch.manifest.Manifest`.
        out: the output folder (created when missing).
        engine: ``"local"`` (worker processes here) or ``"ray"`` (a local Ray, or the cluster of ``address`` /
            ``RAY_ADDRESS``).
        address: the Ray cluster's address (``engine="ray"`` only).
        force: redo takes that are complete and unchanged (default: skip them).
        jobs: takes at once (local engine; default one per CPU core, or one per CUDA device).
        retries: runs again of a take whose worker was lost (killed) before it counts as failed.
        device: ``"cpu"``, ``"cuda"``/``"cuda:N"``, or None (CUDA when there is a device).
        progress: show one progress bar over the takes.

    The local engine spawns its workers (a fresh Python each, never a fork): a script that calls :func:`run`
    does so under ``if __name__ == "__main__":``, as with any :mod:`multiprocessing` pool.

    A take that fails (an unreadable input, channels the rig cannot use) is reported with its one-line error;
    the others go on. Ctrl-C (KeyboardInterrupt) stops the workers, keeps the finished takes, removes the
    unfinished ones and writes the report before re-raising.

    Raises:
        TypeError: an argument of the wrong type.
        ValueError: a bad manifest row (named), an output folder that is a file, a bad engine or option; raised
            before any take starts.
    """
    from .._validate import as_count, as_path, expect_instance
    from .manifest import Manifest, read_manifest
    from .report import Report
    from .take import completed_take, remove_leftovers, take_digest

    expect_instance(engine, str, "engine")
    for flag, name in ((force, "force"), (progress, "progress")):
        expect_instance(flag, bool, name)
    if address is not None:
        expect_instance(address, str, "address")
    if engine not in ENGINES:
        raise ValueError(f"--engine {engine!r}: expected one of {', '.join(ENGINES)}")
    if address is not None and engine != "ray":
        raise ValueError("--address applies to --engine ray only")
    if jobs is not None:
        as_count(jobs, "--jobs", minimum=1)
    as_count(retries, "retries")
    out = _output_folder(as_path(out, "--out"))
    if engine == "ray":
        from .cluster import import_ray

        import_ray()
    manifest = manifest if isinstance(manifest, Manifest) else read_manifest(manifest)
    out.mkdir(parents=True, exist_ok=True)
    report = Report(out, manifest, engine)
    work = []
    for take in manifest.takes:
        digest = take_digest(take)
        record = None if force else completed_take(out, take.id, digest)
        if record is None:
            work.append((take, digest))
        else:
            stage = str(out / take.id / record["stage"])
            report.entries[take.id] = {**record, "status": "skipped", "error": None, "stage": stage}
    report.write()
    try:
        _run_work(work, out, report, engine, address, jobs, retries, device, progress)
        report.finished = True
    except KeyboardInterrupt:
        report.interrupted = True
        raise
    finally:
        for take in manifest.takes:
            remove_leftovers(out, take.id)
        report.write()
        sheet, shoot = _overview(out, report)
    return BatchResult(takes=report.takes, report=report.path, sheet=sheet, shoot=shoot)


def _output_folder(out: Path) -> Path:
    """The output folder, absolute; ValueError when it is a file or cannot be made."""
    from .._files import check_output_folder

    out = out.absolute()
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: is a file, not a folder")
    check_output_folder(out, "--out", out)
    return out


def _run_work(work, out: Path, report, engine, address, jobs, retries, device, progress: bool) -> None:
    """Run ``work`` on the engine, adding each landed take to ``report`` and advancing one progress bar."""
    from tqdm import tqdm

    if not work:
        return
    cache = _kernel_cache()
    if engine == "ray":
        from .cluster import ray_results

        results = ray_results(work, out, device=device, address=address, retries=retries, kernel_cache=cache)
    else:
        from .pool import local_results, worker_devices

        devices = worker_devices(jobs, device=device)
        results = local_results(work, out, devices=devices, retries=retries, kernel_cache=cache)
    frames = failed = 0
    with tqdm(total=len(work), desc="batch", unit="take", disable=not progress) as bar:
        try:
            for entry in results:
                report.add(entry)
                frames += int(entry.get("frames") or 0)
                failed += entry["status"] == "failed"
                bar.set_postfix(frames=frames, failed=failed, refresh=False)
                bar.update(1)
        finally:
            results.close()


def _kernel_cache() -> str | None:
    """This process's Warp kernel cache folder, for the workers to share (None: Warp's default)."""
    from .. import init_runtime

    init_runtime(quiet=True)
    import warp as wp

    folder = getattr(wp.config, "kernel_cache_dir", None)
    return os.fspath(folder) if folder else None


def _overview(out: Path, report) -> tuple[Path, Path | None]:
    """Write the contact sheet and the shoot stage of the takes landed so far."""
    from .report import write_contact_sheet
    from .shoot import write_shoot

    sheet = write_contact_sheet(out / "report.png", report.takes)
    return sheet, write_shoot(out / "shoot.usda", report.takes)
