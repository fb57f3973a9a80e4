"""Animation drivers: curves from the tools animators use (ARKit/MediaPipe weights, Audio2Face, FACS
action units) cleaned and mapped onto a rig's controls (SPEC §6.4), and exported back as ARKit weights.

    >>> from warpface.usd import read_driver
    >>> from warpface.drivers import mapping_for_rig, clean
    >>> curves = clean(read_driver("take.csv"), fps=60.0)          # doctest: +SKIP
    >>> mapping, _, _ = mapping_for_rig(rig)                          # doctest: +SKIP
    >>> controls = mapping.apply(curves)                              # doctest: +SKIP

Every driver file, USD ``SkelAnimation`` layers included, is read by :func:`warpface.usd.read_driver`
(CSV and MediaPipe files need no usd-core). Mappings on the rig stage are in
:mod:`warpface.usd.mapping_io`, ``UsdSkel.Animation`` weights in :mod:`warpface.usd.skel_io`; the command
is ``warpface animate`` (:mod:`warpface.commands.animate`).
"""

from .calibrate import calibrate_mapping
from .channels import ARKIT_CHANNELS, Curves
from .cleanup import OneEuroFilter, calibrate_neutral, clamp_to_range, clean, resample
from .csv_formats import write_live_link, write_openface
from .default_tables import default_table, mapping_for_rig
from .export import controls_to_curves, project_controls
from .io import DRIVER_FORMATS, detect_format
from .mapping import MappedControls, Mapping
from .mediapipe_format import write_mediapipe_jsonl, write_mediapipe_textproto
from .mouth_close import close_mouth

__all__ = [
    "ARKIT_CHANNELS",
    "Curves",
    "DRIVER_FORMATS",
    "detect_format",
    "write_openface",
    "write_live_link",
    "write_mediapipe_textproto",
    "write_mediapipe_jsonl",
    "Mapping",
    "MappedControls",
    "default_table",
    "mapping_for_rig",
    "close_mouth",
    "clean",
    "OneEuroFilter",
    "calibrate_neutral",
    "clamp_to_range",
    "resample",
    "project_controls",
    "controls_to_curves",
    "calibrate_mapping",
]
