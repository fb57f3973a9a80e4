"""A shoot's manifest: one row per take (id, input file, kind, rig, mapping, options), read from TOML, JSON or CSV.

Forms (relative paths are resolved against the manifest's folder):

* **CSV** with the header ``id,input,kind`` and optional columns ``rig,mapping,options``; ``options`` holds the
  kind's own command-line options (``--fps 24 --no-video``) or a JSON object (``{"fps": 24}``).
* **JSON**: ``{"defaults": {...}, "takes": [{...}, ...]}`` or a bare list of takes.
* **TOML** (Python 3.11+, or 3.10 with ``tomli``): an optional ``[defaults]`` table and ``[[take]]`` tables.

``defaults`` gives any field (``kind``, ``rig``, ``mapping``, ``options``) to every take that lacks it; a take's
options are merged over the defaults' options. Options are the kind's command's own options
(``warpface animate --help``, ``track --help``, ``fit --help``), by flag name with ``-`` or ``_``; the inputs,
outputs, ``--rig`` and ``--map`` are set by the batch. Every row is checked before any work starts
(:func:`read_manifest`); an error names the manifest and the row.
"""

from __future__ import annotations

import csv
import io
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["Take", "Manifest", "read_manifest", "TAKE_ID", "FIELDS"]

TAKE_ID = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_-]{0,99}$")
"""A take id: a folder name and a USD variant name (letters, digits, ``_`` and ``-``; not starting with ``-``)."""

FIELDS = ("id", "input", "kind", "rig", "mapping", "options")
"""The fields of a take, in CSV column order."""

_REQUIRED = ("id", "input", "kind")


@dataclass(frozen=True)
class Take:
    """One checked row of a manifest."""

    id: str
    input: Path
    """The input file or folder, absolute (or the word ``synthetic`` for a ``track`` take)."""
    kind: str
    """``animate``, ``track`` or ``fit``."""
    rig: Path | None
    """The rig stage, absolute; None: the built-in face."""
    mapping: str | None
    """``animate``'s ``--map``: a name stored on the rig, or an absolute ``FILE.usda[:NAME]``."""
    options: tuple[str, ...]
    """The kind's command-line options, checked (``("--fps", "24", "--no-video")``)."""
    row: str
    """Where the take is in the manifest (``takes.csv row 3``), for messages."""
    settings: dict = field(default_factory=dict, compare=False)
    """The kind's options as parsed (every option, defaults included): what the resume digest records."""
    rig_vertices: int = 0
    """The rig's skin vertex count (0: the built-in face), for sizing a take's share of a GPU."""


@dataclass(frozen=True)
class Manifest:
    """The checked takes of a manifest file, in its order."""

    path: Path
    takes: tuple[Take, ...]


def read_manifest(path) -> Manifest:
    """Read and check a manifest (TOML, JSON or CSV by extension).

    Every row is checked before it is accepted: a known kind, an existing input, a unique id, known options with
    good values, a rig stage that loads. Nothing is written.

    Raises:
        TypeError: ``path`` is not a path.
        ValueError: unreadable manifest or a bad row; the one-line message names the manifest and the row.
    """
    from .._files import read_text
    from .._validate import as_path

    path = as_path(path, "manifest").absolute()
    if not path.is_file():
        raise ValueError(f"manifest {path}: file not found")
    suffix = path.suffix.lower()
    if suffix not in (".toml", ".json", ".csv"):
        raise ValueError(f"manifest {path}: expected a .toml, .json or .csv file")
    text = read_text(path)
    if suffix == ".csv":
        defaults, rows = {}, _csv_rows(text, path)
    else:
        defaults, rows = _document_rows(_parse_toml(text, path) if suffix == ".toml" else _parse_json(text, path), path)
    if not rows:
        raise ValueError(f"manifest {path}: no takes")
    from .kinds import RigCheck

    rigs, takes, seen = RigCheck(), [], {}
    for where, row in rows:
        take = _take(row, defaults, path.parent, f"{path.name} {where}", rigs)
        if take.id in seen:
            raise ValueError(f"{take.row}: duplicate take id {take.id!r} (first at {seen[take.id]})")
        seen[take.id] = take.row
        takes.append(take)
    return Manifest(path=path, takes=tuple(takes))


def _parse_toml(text: str, path: Path):
    try:
        import tomllib
    except ImportError:  # Python 3.10
        try:
            import tomli as tomllib
        except ImportError:
            raise ValueError(
                f"manifest {path}: reading TOML needs Python 3.11 or the tomli package; use a JSON or CSV manifest"
            ) from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"manifest {path}: not valid TOML ({' '.join(str(error).split())})") from None


def _parse_json(text: str, path: Path):
    try:
        return json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(f"manifest {path}: not valid JSON ({error.msg} at line {error.lineno})") from None


def _document_rows(document, path: Path) -> tuple[dict, list[tuple[str, dict]]]:
    """(defaults, [(where, row)]) of a parsed TOML/JSON manifest."""
    if isinstance(document, list):
        document = {"takes": document}
    if not isinstance(document, dict):
        raise ValueError(f"manifest {path}: expected a table of takes, got {type(document).__name__}")
    unknown = sorted(set(document) - {"defaults", "take", "takes"})
    if unknown:
        raise ValueError(f"manifest {path}: unknown top-level key {unknown[0]!r} (expected defaults, take or takes)")
    if "take" in document and "takes" in document:
        raise ValueError(f"manifest {path}: give the takes as 'take' or 'takes', not both")
    key = "take" if "take" in document else "takes"
    rows = document.get(key, [])
    if not isinstance(rows, list):
        raise ValueError(f"manifest {path}: {key!r} must be a list of tables")
    defaults = document.get("defaults", {})
    if not isinstance(defaults, dict):
        raise ValueError(f"manifest {path}: 'defaults' must be a table")
    bad = sorted(set(defaults) - set(FIELDS[2:]))
    if bad:
        raise ValueError(f"manifest {path}: defaults: unknown field {bad[0]!r} (known: kind, rig, mapping, options)")
    found = []
    for index, row in enumerate(rows, start=1):
        if not isinstance(row, dict):
            raise ValueError(f"manifest {path}: {key}[{index}] must be a table, got {type(row).__name__}")
        found.append((f"take {index}", row))
    return defaults, found


def _csv_rows(text: str, path: Path) -> list[tuple[str, dict]]:
    """[(``row N`` with N the file's line number, row)] of a CSV manifest."""
    try:
        lines = list(csv.reader(io.StringIO(text, newline=""), strict=True))
    except csv.Error as error:
        raise ValueError(f"manifest {path}: not valid CSV ({error})") from None
    numbered = [(number, cells) for number, cells in enumerate(lines, start=1) if any(c.strip() for c in cells)]
    if not numbered:
        raise ValueError(f"manifest {path}: empty (expected the header id,input,kind)")
    header = [cell.strip().lower() for cell in numbered[0][1]]
    missing = [name for name in _REQUIRED if name not in header]
    if missing:
        raise ValueError(f"manifest {path}: the header lacks column {missing[0]!r} (expected id,input,kind[,rig,...])")
    unknown = [name for name in header if name not in FIELDS]
    if unknown or len(set(header)) != len(header):
        what = f"unknown column {unknown[0]!r}" if unknown else "a repeated column"
        raise ValueError(f"manifest {path}: the header has {what} (columns: {', '.join(FIELDS)})")
    rows = []
    for number, cells in numbered[1:]:
        if len(cells) != len(header):
            raise ValueError(f"{path.name} row {number}: {len(cells)} cells, the header has {len(header)}")
        rows.append((f"row {number}", {name: cell.strip() for name, cell in zip(header, cells) if cell.strip()}))
    return rows


def _take(row: dict, defaults: dict, folder: Path, where: str, rigs) -> Take:
    """A checked :class:`Take` from one row (``where`` names it in messages)."""
    from .kinds import KINDS, parse_options

    unknown = sorted(set(row) - set(FIELDS))
    if unknown:
        raise ValueError(f"{where}: unknown field {unknown[0]!r} (known: {', '.join(FIELDS)})")
    for name in _REQUIRED:
        if name not in row and name not in defaults:
            raise ValueError(f"{where}: missing {name!r}")
    values = {name: row.get(name, defaults.get(name)) for name in FIELDS[:5]}
    for name, value in values.items():
        if value is not None and not isinstance(value, str):
            raise ValueError(f"{where}: {name} must be text, got {type(value).__name__}")
    take_id = values["id"]
    if not TAKE_ID.match(take_id):
        raise ValueError(f"{where}: take id {take_id!r} must be letters, digits, '_' or '-' (at most 100)")
    where = f"{where} (take {take_id!r})"
    kind = values["kind"].strip().lower()
    if kind not in KINDS:
        raise ValueError(f"{where}: unknown kind {values['kind']!r} (known: {', '.join(KINDS)})")
    source = values["input"]
    if kind == "track" and source == "synthetic":
        input_path = Path(source)
    else:
        input_path = (folder / source).absolute()
        if not input_path.exists():
            raise ValueError(f"{where}: input {source}: file not found")
    rig = None if values["rig"] is None else (folder / values["rig"]).absolute()
    if kind == "fit" and rig is None:
        raise ValueError(f"{where}: a fit take needs a rig (the stage its presets are fitted to)")
    rig_vertices = 0 if rig is None else rigs.check(rig, f"{where}: rig {values['rig']}")
    mapping = values["mapping"]
    if mapping is not None:
        if kind != "animate":
            raise ValueError(f"{where}: mapping applies to animate takes only, not {kind}")
        mapping = _mapping(mapping, folder, where)
    words, off = _merged_options(defaults.get("options"), row.get("options"), where)
    options, settings = parse_options(kind, words, off, where)
    return Take(take_id, input_path, kind, rig, mapping, options, where, settings, rig_vertices)


def _mapping(spec: str, folder: Path, where: str) -> str:
    """``NAME`` unchanged, or ``FILE.usda[:NAME]`` with FILE made absolute and checked."""
    file, colon, name = spec.rpartition(":")
    if not colon or Path(file).suffix.lower() not in (".usda", ".usdc", ".usd"):
        file, name = spec, None
    if Path(file).suffix.lower() not in (".usda", ".usdc", ".usd"):
        return spec  # a mapping stored on the take's rig stage
    path = (folder / file).absolute()
    if not path.is_file():
        raise ValueError(f"{where}: mapping {spec}: file not found")
    return f"{path}:{name}" if name else str(path)


def _merged_options(defaults, own, where: str) -> tuple[list[str], list[str]]:
    """(command-line words, flags switched off): the defaults' options followed by the take's own (later ones
    win; a flag the take sets to false is dropped from the defaults)."""
    base, base_off = _option_words(defaults, f"{where}: defaults' options")
    words, off = _option_words(own, f"{where}: options")
    return [word for word in base if word not in off] + words, base_off + off


def _option_words(options, where: str) -> tuple[list[str], list[str]]:
    """(command-line words, flags given as false) of options: a table (``{fps = 24, no_video = true}``), a JSON
    object text, or command-line text (``--fps 24 --no-video``)."""
    import shlex

    if options is None:
        return [], []
    if isinstance(options, str):
        text = options.strip()
        if text.startswith("{"):
            try:
                options = json.loads(text)
            except json.JSONDecodeError as error:
                raise ValueError(f"{where}: not a JSON object ({error.msg})") from None
        else:
            try:
                return shlex.split(text), []
            except ValueError as error:
                raise ValueError(f"{where}: {error}") from None
    if not isinstance(options, dict):
        raise ValueError(f"{where}: expected a table of options, got {type(options).__name__}")
    words, off = [], []
    for name, value in options.items():
        flag = "--" + str(name).lstrip("-").replace("_", "-")
        values = value if isinstance(value, list) else [value]
        for item in values:
            if isinstance(item, bool):
                (words if item else off).append(flag)
                continue
            if not isinstance(item, (int, float, str)):
                raise ValueError(f"{where}: option {name!r} must be a number, text or true/false")
            words += [flag, str(item)]
    return words, off
