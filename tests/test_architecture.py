"""The shape of the code, checked from its source: layers, cycles, file sizes, private names, signatures.

Imports are read with :mod:`ast` (module level and inside functions alike), so a lazy import counts the
same as a top-level one. :data:`LAYERS` is the table that ``docs/ARCHITECTURE.md`` mirrors; a test below
keeps the two in step.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
import re
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "warpface"

LAYERS: dict[str, tuple[str, ...]] = {
    # lowest first; a part may import parts of its own layer or of any layer listed before it
    "core": ("errors", "_validate", "_files", "_signals", "data"),
    "geometry": ("geometry", "kernels_surface", "landmarks"),
    "models": ("mesh", "expression", "fem", "rig"),
    "content": ("assets", "metrics", "preview", "offscreen"),
    "solvers": ("solve", "drivers", "tracking", "rigging", "calibration"),
    "io": ("usd",),
    "apps": ("pipelines", "demo", "commands", "batch", "cli", "newton"),
}
"""Every top-level part of ``warpface`` by layer (``docs/ARCHITECTURE.md`` shows the same table)."""

MODEL_LAYER = ("expression", "fem", "geometry", "mesh", "kernels_surface", "rig", "_validate", "landmarks", "errors")
"""Parts that hold the math: they must not reach up into I/O, tracking, solvers or applications."""

FORBIDDEN_FOR_MODELS = (
    "usd",
    "tracking",
    "metrics",
    "assets",
    "cli",
    "commands",
    "pipelines",
    "solve",
    "drivers",
    "preview",
    "pxr",
)

MAX_LINES = 600
SOURCE_DIRS = ("warpface", "benchmarks", "examples", "tests")

ROOT_PACKAGE_IMPORTS = {"usd"}
"""What ``warpface/__init__.py`` may import besides the model layer it re-exports: ``usd.schema``, because
the codeless USD schema plugin must be registered before anything touches ``Usd.SchemaRegistry``
(registering later silently gives no prim definitions). The call is skipped without usd-core and
imports no ``pxr`` at module level, so the model layer still loads without USD."""


def _layer_of() -> dict[str, int]:
    return {part: rank for rank, parts in enumerate(LAYERS.values()) for part in parts}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path):
    """``(module, name or None, line)`` for every import in the file, relative imports resolved."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    here = _module_name(path).split(".")
    package = here if path.name == "__init__.py" else here[:-1]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, None, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            for alias in node.names:
                yield module, alias.name, node.lineno


def _part(module: str, name: str | None = None) -> str | None:
    """The top-level part of ``warpface`` a module belongs to (None: the root package itself)."""
    pieces = module.split(".")
    if pieces[0] != "warpface":
        return pieces[0]
    if len(pieces) > 1:
        return pieces[1]
    if name and ((PACKAGE / name).is_dir() or (PACKAGE / f"{name}.py").is_file()):
        return name  # ``from warpface import usd``
    return None


def _package_files():
    return sorted(PACKAGE.rglob("*.py"))


def _part_edges() -> dict[tuple[str, str], list[str]]:
    """``(importer part, imported part) → [file:line, …]`` over warpface/, root package excluded."""
    edges = defaultdict(list)
    for path in _package_files():
        if path == PACKAGE / "__init__.py":
            continue
        source = _part(_module_name(path))
        for module, name, line in _imports(path):
            target = _part(module, name)
            if module.split(".")[0] in ("warpface", "pxr") and target != source:
                target = target or "warpface"  # the root package re-exports the model layer
                edges[(source, target)].append(f"{path.relative_to(ROOT)}:{line}")
    return edges


def test_every_part_has_a_layer():
    parts = {
        p.stem if p.suffix == ".py" else p.name
        for p in PACKAGE.iterdir()
        if (p.suffix == ".py" and p.name != "__init__.py") or (p / "__init__.py").is_file()
    }
    assert parts == set(_layer_of()), "add new parts to LAYERS (and docs/ARCHITECTURE.md)"


def test_model_layer_imports_nothing_above_it():
    found = []
    for path in _package_files():
        part = _part(_module_name(path))
        if part not in MODEL_LAYER:
            continue
        for module, name, line in _imports(path):
            target = _part(module, name) if module.split(".")[0] in ("warpface", "pxr") else None
            if target in FORBIDDEN_FOR_MODELS:
                found.append(f"{path.relative_to(ROOT)}:{line} imports {module}{'.' + name if name else ''}")
    assert not found, "\n".join(found)


def test_imports_follow_the_layers():
    layer = _layer_of()
    layer["pxr"] = layer["usd"]  # only the I/O layer and above may touch pxr
    layer["warpface"] = layer["mesh"]  # ``from warpface import FaceRig``: the model layer's API
    upward = [
        f"{source} ({rank_name(layer[source])}) → {target} ({rank_name(layer[target])}): {', '.join(where)}"
        for (source, target), where in sorted(_part_edges().items())
        if layer[target] > layer[source]
    ]
    assert not upward, "\n".join(upward)


def rank_name(rank: int) -> str:
    return list(LAYERS)[rank]


def test_no_import_cycles_between_parts():
    graph = defaultdict(set)
    for source, target in _part_edges():
        graph[source].add(target)
    state: dict[str, int] = {}
    cycles = []

    def visit(node, trail):
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append(" → ".join(trail[trail.index(nxt) :] + [nxt]))
            elif nxt not in state:
                visit(nxt, trail + [nxt])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    assert not cycles, "\n".join(cycles)


def test_root_package_imports_only_models_and_the_schema_plugin():
    layer = _layer_of()
    extra = []
    for module, name, line in _imports(PACKAGE / "__init__.py"):
        target = _part(module, name) if module.startswith("warpface") else None
        if target is None or layer[target] <= layer["mesh"]:
            continue
        if target in ROOT_PACKAGE_IMPORTS and module == "warpface.usd.schema":
            continue
        extra.append(f"warpface/__init__.py:{line} imports {module}")
    assert not extra, "\n".join(extra)


def test_one_closest_point_on_triangle():
    """One definition in the shipped code (warpface/, benchmarks/, examples/); the float64 NumPy oracles in
    tests/ are independent references on purpose. Every other user imports it from ``geometry``."""
    pattern = re.compile(r"(closest|nearest|project).*(tri|face)", re.IGNORECASE)
    definitions = []
    for folder in ("warpface", "benchmarks", "examples"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.FunctionDef) and pattern.search(node.name):
                    definitions.append(f"{path.relative_to(ROOT)} {node.name}")
    assert definitions == ["warpface/geometry/funcs.py closest_point_on_triangle"], "\n".join(definitions)
    users = [
        path.relative_to(ROOT)
        for path in _package_files()
        if "closest_point_on_triangle(" in path.read_text() and path.parent.name != "geometry"
    ]
    for path in users:
        imported = {name for module, name, _ in _imports(ROOT / path) if module.startswith("warpface.geometry")}
        assert "closest_point_on_triangle" in imported, f"{path} uses closest_point_on_triangle without importing it"


def test_no_source_file_over_the_limit():
    long = []
    for folder in SOURCE_DIRS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            count = len(path.read_text(encoding="utf-8").splitlines())
            if count > MAX_LINES:
                long.append(f"{path.relative_to(ROOT)}: {count} lines")
    assert not long, "\n".join(long)


def _private_imports(path: Path):
    """Imports of ``_private`` names from another module, or of a private module from outside its package."""
    here = _module_name(path)
    in_tests = path.parent == ROOT / "tests"
    for module, name, line in _imports(path):
        if not module.startswith("warpface"):
            continue
        if name and name.startswith("_") and not name.startswith("__"):
            yield f"{path.relative_to(ROOT)}:{line} imports private name {name} from {module}"
        pieces = (module + ("." + name if name else "")).split(".")
        for depth, piece in enumerate(pieces[1:], start=1):
            if (
                piece.startswith("_")
                and not piece.startswith("__")
                and (PACKAGE.joinpath(*pieces[1 : depth + 1]).with_suffix(".py").is_file())
            ):
                owner = ".".join(pieces[:depth])
                if not in_tests and not (here == owner or here.startswith(owner + ".")):
                    yield f"{path.relative_to(ROOT)}:{line} imports {owner}'s private module {piece}"
                break


def test_no_private_names_imported_across_modules():
    """Private modules (``warpface._files``, ``warpface.usd._files``) serve their own package; tests may
    open them to test them, but no one imports a ``_name`` from another module."""
    found = [
        problem
        for folder in SOURCE_DIRS
        for path in sorted((ROOT / folder).rglob("*.py"))
        for problem in _private_imports(path)
    ]
    assert not found, "\n".join(found)


def test_tests_do_not_import_tests():
    found = []
    for path in sorted((ROOT / "tests").glob("*.py")):
        for module, _name, line in _imports(path):
            if module.startswith("test_") or module == "conftest" or module.startswith("tests."):
                found.append(f"{path.relative_to(ROOT)}:{line} imports {module}")
    assert not found, "\n".join(found)


def test_docs_mirror_the_layer_table():
    doc = (ROOT / "docs" / "ARCHITECTURE.md").read_text(encoding="utf-8")
    rows = dict(re.findall(r"^\|\s*`(\w+)`\s*\|\s*([^|]+?)\s*\|", doc, re.MULTILINE))
    documented = {layer: tuple(re.findall(r"`([\w.]+)`", parts)) for layer, parts in rows.items()}
    assert documented == LAYERS
    assert "docs/ARCHITECTURE.md" in (ROOT / "README.md").read_text(encoding="utf-8")


# ------------------------------------------------------------------------------------------- public API


def _public_modules():
    import warpface

    names = ["warpface"]
    for info in pkgutil.walk_packages(warpface.__path__, "warpface."):
        if any(piece.startswith("_") for piece in info.name.split(".")):
            continue
        names.append(info.name)
    modules = []
    for name in names:
        try:
            modules.append(importlib.import_module(name))
        except ImportError as exc:  # optional dependency (pxr, pyrender, cv2) missing on this machine
            if getattr(exc, "name", "") and exc.name.split(".")[0] == "warpface":
                raise
    return modules


def _public_callables():
    for module in _public_modules():
        names = getattr(module, "__all__", None)
        if names is None:
            names = [n for n in vars(module) if not n.startswith("_")]
        for name in names:
            try:
                obj = getattr(module, name)
            except (AttributeError, ImportError):
                continue
            if inspect.isclass(obj):
                for key, value in vars(obj).items():
                    if key.startswith("_") and key != "__init__":
                        continue
                    if isinstance(value, (classmethod, staticmethod)):
                        value = value.__func__
                    if inspect.isfunction(value):
                        yield f"{module.__name__}.{name}.{key}", value
            elif inspect.isfunction(obj):
                yield f"{module.__name__}.{name}", obj


def test_device_is_keyword_only_everywhere():
    positional = set()
    for qualified, function in _public_callables():
        parameter = inspect.signature(function).parameters.get("device")
        if parameter is not None and parameter.kind is not inspect.Parameter.KEYWORD_ONLY:
            positional.add(qualified)
    assert not positional, "\n".join(sorted(positional))


def test_step_means_the_fem_time_step():
    """``step`` is the FEM's time step only; the tracker's per-frame call is ``track_frame``, the
    expression model's ``evaluate``."""
    elsewhere = {
        q
        for q, _ in _public_callables()
        if "step" in q.rsplit(".", 1)[-1].lower()
        and not q.startswith("warpface.fem.")
        and not q.endswith(".SolverFace.step")  # Newton's SolverBase.step: the same FEM time step, in a Newton world
    }
    assert not elsewhere, "\n".join(sorted(elsewhere))
    from warpface.expression import ExpressionModel
    from warpface.tracking import TrackingAdapter

    assert callable(ExpressionModel.evaluate) and callable(TrackingAdapter.track_frame)


_IMPORT_PROBE = """
import os, sys
calls = []
import warp
for owner, name in ((warp, "init"), (os, "dup2"), (os, "umask")):
    original = getattr(owner, name)
    setattr(owner, name, lambda *a, _n=name, _o=original, **k: (calls.append(_n), _o(*a, **k))[1])
level, quiet = warp.config.log_level, getattr(warp.config, "quiet", "unset")
import warpface
import warpface.assets, warpface.drivers, warpface.geometry, warpface.tracking, warpface.pipelines
import warpface.commands, warpface.cli, warpface.metrics, warpface.usd
assert warpface.usd.read_driver and warpface.usd.open_stage  # lazy USD modules load too
changed = (warp.config.log_level, getattr(warp.config, "quiet", "unset")) != (level, quiet)
print(sorted(set(calls)), changed)
warpface.init_runtime(quiet=True)
print("init" in calls, warp.config.log_level)
"""


def test_import_has_no_side_effects():
    """``import warpface`` (and its packages) initialises no Warp runtime, changes no Warp setting, touches no
    file descriptor and no umask; :func:`warpface.init_runtime` is the one explicit call that does."""
    import subprocess
    import sys

    env = {**__import__("os").environ, "PYTHONPATH": str(ROOT)}
    result = subprocess.run([sys.executable, "-c", _IMPORT_PROBE], capture_output=True, text=True, env=env)
    assert result.returncode == 0, result.stderr
    import_line, init_line = result.stdout.split("\n")[:2]
    assert import_line == "[] False", import_line
    assert init_line.startswith("True"), init_line


if __name__ == "__main__":
    pytest.main([__file__, "-q"])
