"""A calibration's report: per-example reach before/after as JSON, the parameters, and a picture."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .._files import atomic_path

__all__ = ["report_data", "parameters_data", "write_report", "write_picture"]


def parameters_data(values: dict) -> dict:
    """``{(group, field): value}`` as ``{group: {field: value}}`` (sorted), the form of the calibration files."""
    out: dict[str, dict[str, float]] = {}
    for (group, name), value in sorted(values.items()):
        out.setdefault(group, {})[name] = float(value)
    return out


def _rows(rows, millimetre: float) -> list[dict]:
    return [
        {
            "name": row["name"],
            "moved": row["moved"],
            "before_mm": row["before"] / millimetre,
            "after_mm": row["after"] / millimetre,
            "max_before_mm": row["max_before"] / millimetre,
            "max_after_mm": row["max_after"] / millimetre,
            "reduction": row["reduction"],
            "converged": row["converged"],
        }
        for row in rows
    ]


def report_data(calibration, *, millimetre: float = 1e-3) -> dict:
    """The report as plain data: message, improved, seconds, parameters, per split the rows before/after and the
    mean reach, and the optimiser's trials."""
    splits = {}
    for split, pair in calibration.reach.items():
        splits[split] = {
            when: {"mean_reduction": float(np.mean([r["reduction"] for r in rows])), "shapes": _rows(rows, millimetre)}
            for when, rows in pair.items()
        }
    return {
        "message": calibration.message,
        "improved": calibration.improved,
        "seconds": calibration.seconds,
        "parameters": parameters_data(calibration.values),
        "reach": splits,
        "trials": [dict(vars(t)) for t in calibration.trials],
    }


def write_picture(data: dict, path) -> Path:
    """Bars of each example's reach before and after, one panel per split (PNG at ``path``)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    splits = list(data["reach"])
    figure, axes = plt.subplots(len(splits), 1, figsize=(12, 3.2 * len(splits)), squeeze=False)
    for axis, split in zip(axes[:, 0], splits):
        before = data["reach"][split]["before"]
        after = data["reach"][split]["after"]
        names = [row["name"] for row in before["shapes"]]
        x = np.arange(len(names))
        axis.bar(x - 0.2, [100 * r["reduction"] for r in before["shapes"]], 0.4, label="before")
        axis.bar(x + 0.2, [100 * r["reduction"] for r in after["shapes"]], 0.4, label="calibrated")
        axis.set_xticks(x, names, rotation=60, ha="right", fontsize=7)
        axis.set_ylabel("reach [%]")
        axis.set_title(
            f"{split}: mean {100 * before['mean_reduction']:.1f} % -> {100 * after['mean_reduction']:.1f} %", fontsize=9
        )
        axis.axhline(50.0, color="grey", lw=0.5)
        axis.legend(fontsize=7)
    figure.tight_layout()
    path = Path(path)
    figure.savefig(path, dpi=90)
    plt.close(figure)
    return path


def write_report(calibration, path, *, picture=None, millimetre: float = 1e-3) -> dict:
    """Write the report JSON at ``path`` (and the picture at ``picture``); returns the data."""
    data = report_data(calibration, millimetre=millimetre)
    with atomic_path(path, ".json") as tmp:
        tmp.write_text(json.dumps(data, indent=1) + "\n")
    if picture is not None:
        with atomic_path(picture, ".png") as tmp:
            write_picture(data, tmp)
    return data
