"""``DIR/shoot.usda``: every completed take of a batch in one stage, for a reviewer to open.

* ``/Shoot/Character`` carries the variant set ``take``, one variant per take, each referencing the take's
  stage (its default prim: the rig with its baked cache, or a capture): switch the variant to play another take.
* ``/Shoot/Takes/<take>``, one prim per take referencing its stage, hidden (``invisible``) so the character is
  what a viewer shows; each has the take's kind, input, frames and status in ``customData``.

References are relative (``./<id>/<id>.usda``), so the folder can move as a whole. USD scales a take whose
``timeCodesPerSecond`` differs from the shoot's (the first take's rate) onto the shoot's time line.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["write_shoot", "SHOOT_PRIM", "CHARACTER_PRIM", "TAKES_PRIM", "VARIANT_SET"]

SHOOT_PRIM = "/Shoot"
CHARACTER_PRIM = "/Shoot/Character"
TAKES_PRIM = "/Shoot/Takes"
VARIANT_SET = "take"


def write_shoot(path: Path, entries: list[dict]) -> Path | None:
    """Write the shoot stage for the completed takes among ``entries`` (status ``done`` or ``skipped``); returns
    its path, or None when no take is complete (an older shoot stage is then removed)."""
    from pxr import Sdf, Tf

    from ..usd import export_layer_atomically

    path = Path(path)
    complete = [entry for entry in entries if entry["status"] in ("done", "skipped") and entry.get("stage")]
    if not complete:
        path.unlink(missing_ok=True)
        return None
    timing = [_timing(Path(entry["stage"])) for entry in complete]
    rate, _, _, up, meters = timing[0]
    layer = Sdf.Layer.CreateAnonymous(".usda")  # authored as specs: nothing composes before it is saved
    layer.timeCodesPerSecond = layer.framesPerSecond = rate
    layer.startTimeCode = min(start * rate / own for own, start, *_ in timing)
    layer.endTimeCode = max(end * rate / own for own, _, end, *_ in timing)
    layer.pseudoRoot.SetInfo("upAxis", up)
    layer.pseudoRoot.SetInfo("metersPerUnit", meters)
    shoot = Sdf.PrimSpec(layer.pseudoRoot, SHOOT_PRIM.rsplit("/", 1)[1], Sdf.SpecifierDef, "Xform")
    layer.defaultPrim = shoot.name
    character = Sdf.PrimSpec(shoot, CHARACTER_PRIM.rsplit("/", 1)[1], Sdf.SpecifierDef, "Xform")
    variants = Sdf.VariantSetSpec(character, VARIANT_SET)
    character.variantSetNameList.Prepend(VARIANT_SET)
    character.variantSelections[VARIANT_SET] = complete[0]["id"]
    takes = Sdf.PrimSpec(shoot, TAKES_PRIM.rsplit("/", 1)[1], Sdf.SpecifierDef, "Xform")
    visibility = Sdf.AttributeSpec(takes, "visibility", Sdf.ValueTypeNames.Token, Sdf.VariabilityVarying)
    visibility.default = "invisible"  # the character is what a viewer shows
    names = set()
    for entry in complete:
        reference = Sdf.Reference("./" + Path(entry["stage"]).relative_to(path.parent).as_posix())
        Sdf.VariantSpec(variants, entry["id"]).primSpec.referenceList.Prepend(reference)
        name = Tf.MakeValidIdentifier(entry["id"])
        while name in names:
            name += "_"
        names.add(name)
        prim = Sdf.PrimSpec(takes, name, Sdf.SpecifierDef)
        prim.referenceList.Prepend(reference)
        prim.customData = {
            "take": entry["id"],
            "kind": entry.get("kind", ""),
            "input": entry.get("input", ""),
            "frames": int(entry.get("frames") or 0),
            "status": entry["status"],
        }
    export_layer_atomically(layer, path)
    return path


def _timing(stage_path: Path) -> tuple:
    """(timeCodesPerSecond, start, end, up axis, meters per unit) of a take's stage, from its root layer."""
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(stage_path))
    if layer is None:
        raise ValueError(f"{stage_path}: cannot open the take's stage")
    rate = layer.timeCodesPerSecond if layer.HasTimeCodesPerSecond() else 24.0
    start = layer.startTimeCode if layer.HasStartTimeCode() else 0.0
    end = layer.endTimeCode if layer.HasEndTimeCode() else start
    info = layer.pseudoRoot
    up = info.GetInfo("upAxis") if info.HasInfo("upAxis") else "Y"
    meters = info.GetInfo("metersPerUnit") if info.HasInfo("metersPerUnit") else 0.01
    return rate, start, end, up, meters
