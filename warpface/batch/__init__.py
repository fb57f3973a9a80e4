"""Many takes at once: a manifest of takes (``animate``, ``track``, ``fit``) run on worker processes or a Ray
cluster into one folder per take, with a report, a contact sheet and a shoot stage.

``warpface.batch.run(manifest, out, engine="local")`` is the ``warpface batch`` command
(:mod:`warpface.batch.command`):

* :mod:`~warpface.batch.manifest` — TOML/JSON/CSV manifests, every row checked before any work;
* :mod:`~warpface.batch.kinds` — a take's options checked and run by the command of its kind;
* :mod:`~warpface.batch.take` — one take built in a hidden folder and renamed when complete; the resume digest;
* :mod:`~warpface.batch.pool` (``local``) and :mod:`~warpface.batch.cluster` (``ray``) — the engines;
* :mod:`~warpface.batch.report` — ``report.json`` and the contact sheet ``report.png``;
* :mod:`~warpface.batch.shoot` — ``shoot.usda``, the completed takes as variants of one character.

Nothing here is imported with :mod:`warpface`; Ray is imported only by the ``ray`` engine.
"""

from .manifest import Manifest, Take, read_manifest
from .runner import ENGINES, BatchResult, run

__all__ = ["run", "read_manifest", "Manifest", "Take", "BatchResult", "ENGINES"]
