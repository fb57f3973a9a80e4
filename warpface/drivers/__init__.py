"""Animation drivers: curves from the tools animators use (ARKit/MediaPipe weights, Audio2Face, FACS
action units) read, cleaned and mapped onto a rig's controls (SPEC §6.4), and exported back as ARKit weights.

    >>> from warpface.drivers import read_driver, mapping_for_rig, clean
    >>> curves = clean(read_driver("take.csv"), fps=60.0)          # doctest: +SKIP
    >>> mapping, _, _ = mapping_for_rig(rig)                          # doctest: +SKIP
    >>> controls = mapping.apply(curves)                              # doctest: +SKIP

USD pieces live in :mod:`warpface.usd.mapping_io` (mappings on the rig stage) and
:mod:`warpface.usd.skel_io` (``UsdSkel.Animation`` blendshape weights); the command is
``warpface animate`` (:mod:`warpface.commands.animate`).
"""

from .calibrate import calibrate_mapping
from .channels import ARKIT_CHANNELS, ARKIT_RANGE, AU_RANGE, Curves, canonical_channel, channel_range
from .cleanup import OneEuroFilter, calibrate_neutral, clamp_to_range, clean, resample
from .csv_formats import read_live_link, read_openface, write_live_link, write_openface
from .default_tables import (
    ARKIT_TABLE,
    FACS_TABLE,
    JAW_CONTROLS,
    control_scales,
    default_table,
    mapping_for_rig,
    rig_control_names,
)
from .export import controls_to_curves, project_controls
from .io import DRIVER_FORMATS, detect_format, read_driver
from .mapping import MappedControls, Mapping
from .mediapipe_format import (
    read_mediapipe_jsonl,
    read_mediapipe_textproto,
    write_mediapipe_jsonl,
    write_mediapipe_textproto,
)

__all__ = [
    "ARKIT_CHANNELS",
    "ARKIT_RANGE",
    "AU_RANGE",
    "Curves",
    "canonical_channel",
    "channel_range",
    "read_openface",
    "write_openface",
    "read_live_link",
    "write_live_link",
    "read_mediapipe_textproto",
    "read_mediapipe_jsonl",
    "write_mediapipe_textproto",
    "write_mediapipe_jsonl",
    "read_driver",
    "detect_format",
    "DRIVER_FORMATS",
    "Mapping",
    "MappedControls",
    "ARKIT_TABLE",
    "FACS_TABLE",
    "JAW_CONTROLS",
    "default_table",
    "mapping_for_rig",
    "rig_control_names",
    "control_scales",
    "clean",
    "OneEuroFilter",
    "calibrate_neutral",
    "clamp_to_range",
    "resample",
    "project_controls",
    "controls_to_curves",
    "calibrate_mapping",
]
