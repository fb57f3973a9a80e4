"""Shared helpers for benchmarks: robust timing, a plain-text table, JSON results with machine info."""

from __future__ import annotations

import json
import platform
import statistics
import time
from pathlib import Path
from typing import Callable

RESULTS = Path(__file__).resolve().parent / "results"


def time_call(
    function: Callable[[], object], *, repeats: int = 20, warmup: int = 2, min_seconds: float = 0.0, sync=None
) -> float:
    """Median wall time of ``function()`` in seconds over ``repeats`` runs (after ``warmup`` runs).

    ``sync`` (e.g. ``warp.synchronize_device``) is called after each run so asynchronous device work
    is counted. With ``min_seconds`` the run count grows until that much time has been measured.
    """
    for _ in range(warmup):
        function()
        if sync:
            sync()
    samples: list[float] = []
    started = time.perf_counter()
    while len(samples) < repeats or time.perf_counter() - started < min_seconds:
        begin = time.perf_counter()
        function()
        if sync:
            sync()
        samples.append(time.perf_counter() - begin)
    return statistics.median(samples)


def print_table(rows: list[dict], columns: list[tuple[str, str, str]]) -> None:
    """Print ``rows`` as an aligned table; ``columns`` are (key, header, format spec)."""
    cells = [[header for _, header, _ in columns]]
    for row in rows:
        cells.append([("-" if row.get(key) is None else format(row[key], spec)) for key, _, spec in columns])
    widths = [max(len(line[i]) for line in cells) for i in range(len(columns))]
    for index, line in enumerate(cells):
        print("  ".join(cell.rjust(width) for cell, width in zip(line, widths)))
        if index == 0:
            print("  ".join("-" * width for width in widths))


def machine_info(device=None) -> dict:
    info = {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "processor": platform.processor() or platform.machine(),
    }
    try:
        import warp as wp

        info["warp"] = wp.config.version
        if device is not None:
            info["device"] = str(device)
            info["device_name"] = wp.get_device(device).name
    except ImportError:
        pass
    return info


def write_results(name: str, payload: dict) -> Path:
    """Write ``payload`` to ``benchmarks/results/<name>.json`` and return the path."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.json"
    path.write_text(json.dumps(payload, indent=2, default=float))
    return path
