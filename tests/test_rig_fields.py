"""The rig-time fields are computed once per rig's data and shared by the expression model and the solver."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from helpers import small_face_rig

from warpface.expression import fields_cache
from warpface.expression import rig_fields as fields_module
from warpface.expression.fold_guard import face_size
from warpface.expression.lids import bulging_thickness
from warpface.expression.lift_guard import guarded_lifts
from warpface.expression.rig_fields import rig_fields
from warpface.expression.tissue import skin_muscle_weights
from warpface.expression.wrinkles import skin_wrinkle_shapes
from warpface.solve.local_model import RigOperators


def _tissue_rig():
    """The small procedural rig with a skin response on its first muscle (so the fold guards run)."""
    rig = small_face_rig()
    muscles = [replace(rig.muscles[0], sliding=0.4, bunching=0.3), *rig.muscles[1:]]
    return replace(rig, muscles=muscles)


def _thicker_rigs(count: int) -> list:
    """``count`` tissue rigs whose thickness differs by 1 % from one to the next (so each has fields of its own)."""
    rig = _tissue_rig()
    return [replace(rig, thickness=rig.thickness * (1.0 + 0.01 * i)) for i in range(count)]


def _fields(rig):
    return rig_fields(rig.mesh, rig.muscles, rig.wrinkles, rig.thickness, rig.jaw, _size(rig), device="cpu")


def _size(rig) -> float:
    return face_size(rig.mesh.points, rig.landmarks)


@pytest.fixture
def computed(monkeypatch):
    """Counts the computations behind :func:`rig_fields` (the process's kept fields emptied first)."""
    monkeypatch.setattr(fields_module, "_KEPT", type(fields_module._KEPT)())
    calls = []
    compute = fields_module._computed

    def counted(*args):
        calls.append(args)
        return compute(*args)

    monkeypatch.setattr(fields_module, "_computed", counted)
    return calls


def test_the_fields_are_those_of_the_functions_they_come_from(computed):
    rig = _tissue_rig()
    fields = _fields(rig)
    size = _size(rig)
    weights = skin_muscle_weights(rig.mesh, list(rig.muscles), rig.thickness, device="cpu", size=size)
    shapes = skin_wrinkle_shapes(rig.mesh, list(rig.wrinkles), rig.muscles, device="cpu")
    bulging, faded = guarded_lifts(
        rig.mesh,
        bulging_thickness(rig.thickness, rig.muscles),
        list(rig.muscles),
        weights,
        list(rig.wrinkles),
        shapes,
        rig.jaw,
        size,
    )
    for name in ("offsets", "muscle", "weight"):
        np.testing.assert_array_equal(getattr(fields.weights, name), getattr(weights, name))
    for name in ("offsets", "wrinkle", "shape"):
        np.testing.assert_array_equal(getattr(fields.shapes, name), getattr(shapes, name))
    np.testing.assert_array_equal(fields.bulging, bulging)
    np.testing.assert_array_equal(fields.faded, faded)
    assert np.any(fields.weights.weight != 0.0)


def test_model_and_solver_share_one_computation_and_equal_data_shares_it_too(computed):
    rig = _tissue_rig()
    rig.model(device="cpu")
    RigOperators.from_rig(rig, device="cpu")
    assert len(computed) == 1
    again = _tissue_rig()  # another rig object holding the same numbers
    assert _fields(again) is _fields(rig)
    assert len(computed) == 1


@pytest.mark.parametrize(
    "change",
    [
        lambda rig: replace(rig, muscles=[replace(rig.muscles[0], sliding=0.41), *rig.muscles[1:]]),
        lambda rig: replace(rig, thickness=rig.thickness * 1.01),
        lambda rig: replace(
            rig, wrinkles=[replace(rig.wrinkles[0], depth=rig.wrinkles[0].depth * 2), *rig.wrinkles[1:]]
        ),
        lambda rig: replace(rig, mesh=type(rig.mesh)(rig.mesh.points + [0.0, 0.0, 1e-9], rig.mesh.triangles)),
    ],
    ids=["a muscle's sliding", "the thickness", "a wrinkle's depth", "a point moved 1e-9"],
)
def test_any_changed_number_computes_the_fields_afresh(computed, change):
    rig = _tissue_rig()
    before = _fields(rig)
    after = _fields(change(rig))
    assert after is not before and len(computed) == 2


def test_the_fields_are_read_only_and_leave_the_rig_s_own_arrays_writable(computed):
    rig = _tissue_rig()
    fields = _fields(rig)
    for array in (fields.weights.weight, fields.weights.offsets, fields.shapes.shape, fields.bulging, fields.faded):
        with pytest.raises(ValueError, match="read-only"):
            array[...] = 0.0
    assert rig.thickness.flags.writeable and rig.mesh.points.flags.writeable


def test_the_process_keeps_the_last_fields_only(computed):
    rigs = _thicker_rigs(3)
    for rig in rigs:
        _fields(rig)
    assert len(computed) == 3 == fields_module.KEPT + 1
    _fields(rigs[-1])
    assert len(computed) == 3
    _fields(rigs[0])  # the oldest was let go
    assert len(computed) == 4


# ---------------------------------------------------------------------------------------------- on disk


@pytest.fixture
def folder(tmp_path, monkeypatch, computed):
    """The cache pointed at a temporary folder: its ``rig_fields`` subfolder."""
    monkeypatch.setenv("WARPFACE_CACHE", str(tmp_path))
    return tmp_path / "rig_fields"


def _forget(monkeypatch):
    """Empty the process's kept fields, as a new process starts."""
    monkeypatch.setattr(fields_module, "_KEPT", type(fields_module._KEPT)())


def test_a_later_process_reads_the_fields_from_disk_bit_for_bit(folder, computed, monkeypatch):
    rig = _tissue_rig()
    first = rig.model(device="cpu")
    assert len(computed) == 1 and len(list(folder.glob("*.npz"))) == 1
    _forget(monkeypatch)
    again = rig.model(device="cpu")
    assert len(computed) == 1  # read, not computed
    controls = np.random.default_rng(1).uniform(0.0, 0.2, size=(3, len(first.control_names)))
    np.testing.assert_array_equal(again.evaluate(controls), first.evaluate(controls))
    cached, fresh = _fields(rig), fields_module._computed(*computed[0])
    np.testing.assert_array_equal(cached.weights.weight, fresh.weights.weight)
    np.testing.assert_array_equal(cached.faded, fresh.faded)
    assert not cached.weights.weight.flags.writeable


@pytest.mark.parametrize("damage", ["truncated", "other shapes", "not a zip"])
def test_a_damaged_file_is_computed_again_and_replaced(folder, computed, monkeypatch, damage):
    rig = _tissue_rig()
    fields = _fields(rig)
    (path,) = folder.glob("*.npz")
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[:200])
    elif damage == "other shapes":  # a whole file whose arrays do not fit this rig
        arrays = fields_module._arrays(fields)
        np.savez(path, **{**arrays, "offsets": arrays["offsets"][:-1]})
    else:
        path.write_text("not numpy")
    _forget(monkeypatch)
    again = _fields(rig)
    assert len(computed) == 2
    np.testing.assert_array_equal(again.weights.weight, fields.weights.weight)
    _forget(monkeypatch)
    _fields(rig)
    assert len(computed) == 2  # the replaced file reads


def test_other_code_never_reads_the_fields(folder, computed, monkeypatch):
    rig = _tissue_rig()
    _fields(rig)
    _forget(monkeypatch)
    monkeypatch.setattr(fields_cache, "code_digest", lambda: "another version of warpface")
    _fields(rig)
    assert len(computed) == 2 and len(list(folder.glob("*.npz"))) == 2


def test_off_or_an_unwritable_folder_only_costs_the_time(tmp_path, computed, monkeypatch):
    rig = _tissue_rig()
    monkeypatch.setenv("WARPFACE_CACHE", "off")
    assert fields_cache.cache_folder() is None
    _fields(rig)
    blocked = tmp_path / "blocked"
    blocked.write_text("a file where the cache folder would be")
    monkeypatch.setenv("WARPFACE_CACHE", str(blocked))
    _forget(monkeypatch)
    fields = _fields(rig)
    assert len(computed) == 2 and np.any(fields.weights.weight != 0.0)
    assert not any(tmp_path.rglob("*.npz"))


def test_the_folder_keeps_the_newest_files(folder, computed, monkeypatch):
    monkeypatch.setattr(fields_cache, "KEPT_FILES", 2)
    rigs = _thicker_rigs(3)
    for rig in rigs:
        _fields(rig)
    assert len(list(folder.glob("*.npz"))) == 2
    _forget(monkeypatch)
    _fields(rigs[2])
    assert len(computed) == 3  # the newest was kept
    _fields(rigs[0])
    assert len(computed) == 4  # the oldest was removed


def test_the_default_folder_follows_xdg_then_home_and_without_a_home_there_is_none(monkeypatch, tmp_path):
    monkeypatch.delenv("WARPFACE_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert fields_cache.cache_folder() == tmp_path / "warpface" / "rig_fields"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path))
    assert fields_cache.cache_folder() == tmp_path / ".cache" / "warpface" / "rig_fields"
    monkeypatch.delenv("HOME")

    def homeless():
        raise RuntimeError("Could not determine home directory.")

    monkeypatch.setattr(fields_cache.Path, "home", staticmethod(homeless))
    assert fields_cache.cache_folder() is None
