"""Orchestration: the parts of warpface wired together for a task (what the CLI runs).

* :mod:`~warpface.pipelines.capture` — landmark sources from a spec, the synthetic capture of the
  built-in face, :func:`~warpface.pipelines.capture.record` (source → adapter → USD, nothing lost).
* :mod:`~warpface.pipelines.tissue_drive` — the tracking → tissue FEM coupling (SPEC §3 step 4).
* :mod:`~warpface.pipelines.track` — the ``warpface track`` command;
  :mod:`~warpface.pipelines.track_solve` — tracking through the activation solver (``track --solve``);
  :mod:`~warpface.pipelines.track_compare` — the geometric and solved paths compared on ground truth.

Pipelines may import every layer (tracking, fem, usd, assets); no layer imports pipelines.
"""

from .capture import CaptureStats, SyntheticCapture, open_source, record, synthetic_capture

__all__ = ["CaptureStats", "SyntheticCapture", "open_source", "record", "synthetic_capture"]
