"""Rig ↔ USD: exact round trips, units, transforms, readers without the plugin, and bad input."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("pxr")

from helpers import assert_rigs_equal, scaled_rig, small_face_rig  # noqa: E402
from pxr import Gf, Sdf, Usd, UsdGeom, Vt  # noqa: E402

import warpface.usd._files as usd_files  # noqa: E402
from warpface import FaceMesh, FaceRig, LinearMuscle, PlanarProjection, RigError  # noqa: E402
from warpface.usd import read_rig, read_tissue, validate_stage, write_rig, write_tissue  # noqa: E402

# ---------------------------------------------------------------------------------------------- helpers


def _without_plugin(code: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "PXR_PLUGINPATH_NAME"}
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)


# ---------------------------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("suffix", [".usda", ".usdc"])
def test_round_trip_through_a_file_is_exact(tmp_path, small_rig, suffix):
    path = tmp_path / f"face{suffix}"
    write_rig(path, small_rig)
    assert path.is_file() and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp files left
    assert_rigs_equal(read_rig(path), small_rig)
    assert_rigs_equal(read_rig(str(path)), small_rig)


def test_round_trip_in_memory_and_rewrite(small_rig):
    stage = Usd.Stage.CreateInMemory()
    write_rig(stage, small_rig)
    assert_rigs_equal(read_rig(stage), small_rig)
    other = small_face_rig(n=9)
    write_rig(stage, other)  # replaces the rig at the same root
    assert_rigs_equal(read_rig(stage), other)


def test_round_trip_without_landmarks_or_items():
    base = small_face_rig(n=6)
    bare = FaceRig(base.mesh, thickness=0.0, name="bare rig")  # name is not a prim identifier
    stage = write_rig(Usd.Stage.CreateInMemory(), bare)
    back = read_rig(stage)
    assert_rigs_equal(back, bare)
    assert back.landmarks is None and stage.GetPrimAtPath("/bare_rig")


def test_float64_points_come_back_rounded_to_float32(small_rig):
    jittered = FaceMesh(small_rig.mesh.points + 1e-9, small_rig.mesh.triangles, name=small_rig.mesh.name)
    rig = FaceRig(
        jittered, small_rig.muscles, small_rig.wrinkles, small_rig.thickness, small_rig.landmarks, small_rig.name
    )
    back = read_rig(write_rig(Usd.Stage.CreateInMemory(), rig))
    assert np.array_equal(back.mesh.points, rig.mesh.points.astype(np.float32).astype(np.float64))
    assert np.array_equal(back.thickness, rig.thickness)  # doubles everywhere else


def test_stage_metadata_and_layout(tmp_path, small_rig):
    stage = write_rig(tmp_path / "face.usda", small_rig, fps=24)
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and stage.HasAuthoredMetadata("metersPerUnit")
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y and stage.HasAuthoredMetadata("upAxis")
    assert stage.GetMetadata("kilogramsPerUnit") == 1.0
    assert stage.GetTimeCodesPerSecond() == 24 and stage.GetFramesPerSecond() == 24
    assert stage.HasAuthoredMetadata("timeCodesPerSecond") and stage.HasAuthoredMetadata("framesPerSecond")
    assert stage.GetDefaultPrim().GetPath() == Sdf.Path("/Face")
    skin = stage.GetPrimAtPath("/Face/Skin")
    assert skin.IsA(UsdGeom.Mesh) and skin.HasAPI("WarpFaceSkinAPI")
    assert UsdGeom.Mesh(skin).GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    names = [p.GetName() for p in stage.GetPrimAtPath("/Face/Muscles").GetChildren()]
    assert names == ["zygomaticus_major_L", "frontalis_R", "orbicularis_oris"]
    assert stage.GetPrimAtPath("/Face/Muscles/zygomaticus_major_L").GetDisplayName() == "zygomaticus major L"
    assert [str(t) for t in skin.GetRelationship("warpFace:wrinkles").GetTargets()] == [
        "/Face/Wrinkles/forehead_1",
        "/Face/Wrinkles/crow_L",
    ]


def test_interpolation_and_purpose_are_authored_explicitly(tmp_path, small_rig):
    path = tmp_path / "face.usda"
    write_rig(path, small_rig)
    layer = Sdf.Layer.OpenAsAnonymous(str(path))
    thickness = layer.GetAttributeAtPath("/Face/Skin.primvars:warpFace:thickness")
    assert thickness.GetInfo("interpolation") == "vertex"
    for item in ("/Face/Muscles/frontalis_R", "/Face/Muscles/orbicularis_oris", "/Face/Wrinkles/crow_L"):
        assert layer.GetAttributeAtPath(f"{item}.purpose").default == "guide"
        assert layer.GetAttributeAtPath(f"{item}.kr" if "Wrinkles" in item else f"{item}.contraction").HasDefaultValue()


def test_stage_written_by_warpface_reads_without_the_plugin(tmp_path, small_rig):
    path = tmp_path / "face.usda"
    write_rig(path, small_rig)
    expected = {
        "points": small_rig.mesh.points.astype(np.float32).tolist(),
        "thickness": small_rig.thickness.tolist(),
        "attachment": small_rig.muscles[1].attachment.tolist(),
        "semi": list(small_rig.muscles[2].semi_axes),
        "control": small_rig.wrinkles[1].control_points.tolist(),
        "kr": small_rig.wrinkles[1].kr,
    }
    code = f"""
import json, sys
from pxr import Usd, UsdGeom, Tf
assert Tf.Type.FindByName("WarpFaceLinearMuscle").isUnknown, "plugin must not be registered here"
assert "warpface" not in sys.modules
stage = Usd.Stage.Open({str(path)!r})
skin = stage.GetPrimAtPath("/Face/Skin")
muscle = stage.GetPrimAtPath("/Face/Muscles/frontalis_R")
wrinkle = stage.GetPrimAtPath("/Face/Wrinkles/crow_L")
thickness = UsdGeom.PrimvarsAPI(skin).GetPrimvar("warpFace:thickness")
out = dict(
    types=[
        muscle.GetTypeName(),
        wrinkle.GetTypeName(),
        stage.GetPrimAtPath("/Face/Muscles/orbicularis_oris").GetTypeName(),
    ],
    points=[list(p) for p in UsdGeom.Mesh(skin).GetPointsAttr().Get()],
    interpolation=thickness.GetInterpolation(),
    thickness=list(thickness.Get()),
    purposes=[UsdGeom.Imageable(p).ComputePurpose() for p in (muscle, wrinkle)],
    attachment=list(muscle.GetAttribute("attachment").Get()),
    semi=list(stage.GetPrimAtPath("/Face/Muscles/orbicularis_oris").GetAttribute("semiAxes").Get()),
    control=[list(c) for c in wrinkle.GetAttribute("controlPoints").Get()],
    kr=wrinkle.GetAttribute("kr").Get(),
    target=[str(t) for t in muscle.GetRelationship("targetMesh").GetTargets()],
    subdivision=UsdGeom.Mesh(skin).GetSubdivisionSchemeAttr().Get(),
)
print(json.dumps(out))
"""
    result = _without_plugin(code)
    assert result.returncode == 0, result.stderr
    import json

    out = json.loads(result.stdout.strip().splitlines()[-1])
    assert out["types"] == ["WarpFaceLinearMuscle", "WarpFaceWrinkle", "WarpFaceSphincterMuscle"]
    assert out["points"] == expected["points"]
    assert out["interpolation"] == "vertex" and out["thickness"] == expected["thickness"]
    assert out["purposes"] == ["guide", "guide"]
    assert out["attachment"] == expected["attachment"] and out["semi"] == expected["semi"]
    assert out["control"] == expected["control"] and out["kr"] == expected["kr"]
    assert out["target"] == ["/Face/Skin"] and out["subdivision"] == "none"


# ---------------------------------------------------------------------------------------------- units and transforms


def test_centimetre_stage_is_converted(small_rig):
    in_cm = scaled_rig(small_rig, 100.0)
    stage = write_rig(Usd.Stage.CreateInMemory(), in_cm, meters_per_unit=0.01)
    assert UsdGeom.GetStageMetersPerUnit(stage) == 0.01
    back_cm = read_rig(stage, meters_per_unit=0.01)
    assert_rigs_equal(back_cm, read_rig(write_rig(Usd.Stage.CreateInMemory(), in_cm)))  # no conversion: as authored
    in_m = read_rig(stage)
    expected = scaled_rig(back_cm, 0.01)
    assert np.allclose(in_m.mesh.points, expected.mesh.points, rtol=1e-15, atol=0)
    assert np.allclose(in_m.mesh.points, small_rig.mesh.points, rtol=1e-6, atol=1e-9)
    assert np.allclose(in_m.thickness, small_rig.thickness, rtol=1e-12)
    for got, want in zip(in_m.muscles, small_rig.muscles):
        if isinstance(want, LinearMuscle):
            assert np.allclose(got.attachment, want.attachment, rtol=1e-12)
            assert math.isclose(got.falloff_finish, want.falloff_finish, rel_tol=1e-12)
            assert got.zone_angle_deg == want.zone_angle_deg
        else:
            assert np.allclose(got.semi_axes, want.semi_axes, rtol=1e-12)
    for got, want in zip(in_m.wrinkles, small_rig.wrinkles):
        assert np.allclose(got.control_points, want.control_points, rtol=1e-12)
        assert math.isclose(got.depth, want.depth, rel_tol=1e-12) and math.isclose(got.width, want.width, rel_tol=1e-12)


def test_unauthored_meters_per_unit_means_centimetres(small_rig):
    stage = write_rig(Usd.Stage.CreateInMemory(), small_rig)
    stage.GetRootLayer().pseudoRoot.ClearInfo("metersPerUnit")  # USD's fallback is 0.01
    assert np.allclose(read_rig(stage).mesh.points, small_rig.mesh.points * 0.01, rtol=1e-15)


def test_item_transforms_are_composed_into_skin_space(small_rig):
    """Author the items in a rotated, scaled, translated scope with inverse-transformed values: the rig reads
    back the same."""
    stage = write_rig(Usd.Stage.CreateInMemory(), small_rig)
    scale, rotation, translation = 2.5, Gf.Rotation(Gf.Vec3d(1, 2, 3).GetNormalized(), 37.0), Gf.Vec3d(0.1, -0.2, 0.05)
    matrix = Gf.Matrix4d().SetScale(scale) * Gf.Matrix4d().SetRotate(rotation) * Gf.Matrix4d().SetTranslate(translation)
    inverse = matrix.GetInverse()
    for scope in ("/Face/Muscles", "/Face/Wrinkles"):  # Scopes are not Xformable: transform each item
        for prim in stage.GetPrimAtPath(scope).GetChildren():
            UsdGeom.Xformable(prim).AddTransformOp().Set(matrix)
    point = lambda v: inverse.Transform(Gf.Vec3d(*v))  # noqa: E731
    direction = lambda v: inverse.TransformDir(Gf.Vec3d(*v))  # noqa: E731
    for m in small_rig.muscles:
        prim = stage.GetPrimAtPath("/Face/Muscles/" + m.name.replace(" ", "_"))
        if isinstance(m, LinearMuscle):
            prim.GetAttribute("attachment").Set(point(m.attachment))
            prim.GetAttribute("insertion").Set(point(m.insertion))
            prim.GetAttribute("falloffStart").Set(m.falloff_start / scale)
            prim.GetAttribute("falloffFinish").Set(m.falloff_finish / scale)
        else:
            prim.GetAttribute("center").Set(point(m.center))
            prim.GetAttribute("axisX").Set(direction(m.axis_x))
            prim.GetAttribute("axisY").Set(direction(m.axis_y))
            prim.GetAttribute("semiAxes").Set(Gf.Vec2d(*m.semi_axes) / scale)
    for w in small_rig.wrinkles:
        prim = stage.GetPrimAtPath("/Face/Wrinkles/" + w.name)
        p = w.projection
        prim.GetAttribute("projection:origin").Set(point(p.origin))
        if isinstance(p, PlanarProjection):
            prim.GetAttribute("projection:uAxis").Set(direction(p.u_axis))
            prim.GetAttribute("projection:vAxis").Set(direction(p.v_axis))
        else:
            prim.GetAttribute("projection:axis").Set(direction(p.axis))
            prim.GetAttribute("projection:reference").Set(direction(p.reference))
            prim.GetAttribute("projection:radius").Set(p.radius / scale)
        prim.GetAttribute("controlPoints").Set(Vt.Vec2dArray.FromNumpy(w.control_points / scale))
        prim.GetAttribute("width").Set(w.width / scale)
        prim.GetAttribute("depth").Set(w.depth / scale)
    back = read_rig(stage)
    for got, want in zip(back.muscles, small_rig.muscles):
        for field in (
            ("attachment", "insertion", "falloff_start", "falloff_finish", "zone_angle_deg")
            if isinstance(want, LinearMuscle)
            else ("center", "axis_x", "axis_y", "semi_axes")
        ):
            assert np.allclose(getattr(got, field), getattr(want, field), rtol=1e-12, atol=1e-14), (want.name, field)
    for got, want in zip(back.wrinkles, small_rig.wrinkles):
        assert np.allclose(got.control_points, want.control_points, rtol=1e-12, atol=1e-15)
        assert math.isclose(got.width, want.width, rel_tol=1e-12) and math.isclose(got.depth, want.depth, rel_tol=1e-12)
        for field in vars(want.projection):
            assert np.allclose(
                getattr(got.projection, field), getattr(want.projection, field), rtol=1e-12, atol=1e-14
            ), field


def test_non_uniform_scale_on_a_muscle_is_refused(small_rig):
    stage = write_rig(Usd.Stage.CreateInMemory(), small_rig)
    UsdGeom.Xformable(stage.GetPrimAtPath("/Face/Muscles/frontalis_R")).AddScaleOp().Set(Gf.Vec3f(1, 2, 1))
    with pytest.raises(RigError, match=r"/Face/Muscles/frontalis_R.*uniform scale"):
        read_rig(stage)


# ---------------------------------------------------------------------------------------------- bad input


@pytest.fixture
def rig_stage(small_rig):
    return write_rig(Usd.Stage.CreateInMemory(), small_rig)


def test_stage_without_a_skin(rig_stage):
    rig_stage.GetPrimAtPath("/Face/Skin").RemoveAPI("WarpFaceSkinAPI")
    with pytest.raises(RigError, match=r"no Mesh with WarpFaceSkinAPI.*WarpFace prims found"):
        read_rig(rig_stage)
    plain = Usd.Stage.CreateInMemory()
    UsdGeom.Mesh.Define(plain, "/Mesh")
    with pytest.raises(RigError, match="no Mesh with WarpFaceSkinAPI"):
        read_rig(plain)


def test_muscle_without_the_schema_type(rig_stage):
    rig_stage.GetPrimAtPath("/Face/Muscles/frontalis_R").SetTypeName("Xform")
    with pytest.raises(RigError, match=r"^/Face/Muscles/frontalis_R: is a Xform, expected WarpFaceLinearMuscle"):
        read_rig(rig_stage)


def test_skin_api_on_a_wrong_prim_type(rig_stage):
    prim = rig_stage.DefinePrim("/Other", "Xform")
    prim.SetMetadata("apiSchemas", Sdf.TokenListOp.Create(prependedItems=["WarpFaceSkinAPI"]))  # bypasses CanApplyAPI
    with pytest.raises(RigError, match=r"^/Other: WarpFaceSkinAPI is applied to a Xform"):
        read_rig(rig_stage, skin_path="/Other")


def test_missing_thickness_primvar(rig_stage):
    rig_stage.GetPrimAtPath("/Face/Skin").RemoveProperty("primvars:warpFace:thickness")
    with pytest.raises(RigError, match=r"^/Face/Skin.primvars:warpFace:thickness: missing"):
        read_rig(rig_stage)


def test_wrong_length_thickness_primvar(rig_stage, small_rig):
    attr = rig_stage.GetPrimAtPath("/Face/Skin").GetAttribute("primvars:warpFace:thickness")
    attr.Set(Vt.DoubleArray.FromNumpy(small_rig.thickness[:-3]))
    with pytest.raises(
        RigError, match=rf"^/Face/Skin.primvars:warpFace:thickness: has {small_rig.mesh.vertex_count - 3} values"
    ):
        read_rig(rig_stage)


def test_target_mesh_pointing_at_nothing(rig_stage):
    rig_stage.GetPrimAtPath("/Face/Muscles/orbicularis_oris").GetRelationship("targetMesh").SetTargets(
        ["/Face/Nothing"]
    )
    with pytest.raises(
        RigError, match=r"^/Face/Muscles/orbicularis_oris.targetMesh: points at /Face/Nothing, which does not exist"
    ):
        read_rig(rig_stage)


def test_muscle_list_pointing_at_a_missing_prim(rig_stage):
    rig_stage.RemovePrim("/Face/Muscles/frontalis_R")
    with pytest.raises(
        RigError, match=r"^/Face/Skin.warpFace:muscles: target /Face/Muscles/frontalis_R does not exist"
    ):
        read_rig(rig_stage)


def test_wrinkle_with_three_control_points(rig_stage):
    rig_stage.GetPrimAtPath("/Face/Wrinkles/crow_L").GetAttribute("controlPoints").Set(
        Vt.Vec2dArray([(0, 0), (1, 0), (2, 1)])
    )
    with pytest.raises(
        RigError, match=r"^/Face/Wrinkles/crow_L.controlPoints: a cubic Bézier needs 4 control points, got 3"
    ):
        read_rig(rig_stage)


@pytest.mark.parametrize(
    "prim, attribute, value, message",
    [
        (
            "/Face/Muscles/frontalis_R",
            "attachment",
            Gf.Vec3d(0, float("nan"), 0),
            r"attachment: non-finite value nan at index 1",
        ),
        ("/Face/Muscles/frontalis_R", "falloffFinish", float("inf"), r"falloffFinish: non-finite value inf"),
        ("/Face/Wrinkles/forehead_1", "depth", float("nan"), r"depth: non-finite value nan"),
        (
            "/Face/Muscles/orbicularis_oris",
            "semiAxes",
            Gf.Vec2d(0.1, float("-inf")),
            r"semiAxes: non-finite value -inf",
        ),
    ],
)
def test_non_finite_values(rig_stage, prim, attribute, value, message):
    rig_stage.GetPrimAtPath(prim).GetAttribute(attribute).Set(value)
    with pytest.raises(RigError, match=rf"^{prim}.{message}"):
        read_rig(rig_stage)


def test_non_finite_points_and_thickness(small_rig):
    stage = write_rig(Usd.Stage.CreateInMemory(), small_rig)
    thickness = small_rig.thickness.copy()
    thickness[7] = np.inf
    stage.GetPrimAtPath("/Face/Skin").GetAttribute("primvars:warpFace:thickness").Set(
        Vt.DoubleArray.FromNumpy(thickness)
    )
    with pytest.raises(RigError, match=r"^/Face/Skin.primvars:warpFace:thickness: non-finite value inf at index 7"):
        read_rig(stage)
    stage = write_rig(Usd.Stage.CreateInMemory(), small_rig)
    points = small_rig.mesh.points.astype(np.float32)
    points[3, 2] = np.nan
    skin = stage.GetPrimAtPath("/Face/Skin")
    with skin.GetVariantSets().GetVariantSet("warpFaceShape").GetVariantEditContext():
        UsdGeom.Mesh(skin).GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(points))
    with pytest.raises(RigError, match=r"^/Face/Skin.points: non-finite value nan at index \(3, 2\)"):
        read_rig(stage)


def test_out_of_range_values_name_the_prim(rig_stage):
    rig_stage.GetPrimAtPath("/Face/Muscles/frontalis_R").GetAttribute("zoneAngle").Set(200.0)
    with pytest.raises(RigError, match=r"^/Face/Muscles/frontalis_R: .*zone_angle_deg must be in \(0, 180\)"):
        read_rig(rig_stage)


def test_bad_faces(rig_stage):
    mesh = UsdGeom.Mesh(rig_stage.GetPrimAtPath("/Face/Skin"))
    counts = np.array(mesh.GetFaceVertexCountsAttr().Get())
    counts[4] = 2
    mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(counts))
    with pytest.raises(RigError, match=r"^/Face/Skin.faceVertexCounts: face 4 has 2 vertices"):
        read_rig(rig_stage)


def test_polygons_are_fan_triangulated_and_orientation_respected():
    stage = Usd.Stage.CreateInMemory()
    base = small_face_rig(n=4)
    write_rig(stage, FaceRig(base.mesh, thickness=0.001))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin"))
    # a quad and a pentagon over the 4×4 grid's first rows (indices: row-major)
    mesh.GetFaceVertexCountsAttr().Set([4, 5])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 5, 4, 1, 2, 6, 10, 5])
    mesh.GetOrientationAttr().Set(UsdGeom.Tokens.leftHanded)
    rig = read_rig(stage, degenerate="ignore")
    assert rig.mesh.triangles.tolist() == [[0, 5, 1], [0, 4, 5], [1, 6, 2], [1, 10, 6], [1, 5, 10]]


def test_unwritable_output_paths(tmp_path, small_rig):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    for path, message in (
        (tmp_path / "missing" / "face.usda", "does not exist"),
        (blocker / "face.usda", "does not exist"),
        (tmp_path / "face.txt", "must end in"),
        (tmp_path, "must end in"),
    ):
        with pytest.raises(ValueError, match=message):
            write_rig(path, small_rig)
    folder = tmp_path / "folder.usda"
    folder.mkdir()
    with pytest.raises(ValueError, match="it is a folder"):
        write_rig(folder, small_rig)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt", "folder.usda"]


def test_failed_write_keeps_the_previous_file(tmp_path, small_rig, monkeypatch):
    path = tmp_path / "face.usda"
    write_rig(path, small_rig)
    before = path.read_bytes()

    def interrupted(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(usd_files.os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_rig(path, small_face_rig(n=7))
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["face.usda"]  # temporary file removed


def test_reading_a_missing_or_broken_file(tmp_path):
    with pytest.raises(ValueError, match="not found"):
        read_rig(tmp_path / "nope.usda")
    broken = tmp_path / "broken.usda"
    broken.write_text('#usda 1.0\ndef Mesh "A" { point3f[] points = [(0, 0 }\n')
    with pytest.raises(ValueError, match="cannot open"):
        read_rig(broken)


# ---------------------------------------------------------------------------------------------- validation and tissue


def test_validate_stage_accepts_a_written_rig_and_reports_problems(tmp_path, small_rig):
    path = tmp_path / "face.usda"
    write_rig(path, small_rig)
    assert [p for p in validate_stage(path) if p.severity == "error"] == []
    stage = Usd.Stage.Open(str(path))
    stage.GetPrimAtPath("/Face/Wrinkles/crow_L").GetAttribute("controlPoints").Set(Vt.Vec2dArray([(0, 0)] * 3))
    stage.DefinePrim("/Face/Stray", "WarpFaceWrinkle")
    problems = validate_stage(stage)
    assert any(p.severity == "error" and "/Face/Wrinkles/crow_L.controlPoints" in p.message for p in problems)
    assert any(p.severity == "warning" and p.path == "/Face/Stray" for p in problems)
    stage.GetRootLayer().pseudoRoot.ClearInfo("metersPerUnit")
    assert any(p.source != "warpface" and "metersPerUnit" in p.message for p in validate_stage(stage))
    assert validate_stage(tmp_path / "missing.usda")[0].severity == "error"


def test_tissue_round_trip_and_errors(small_rig):
    stage = write_rig(Usd.Stage.CreateInMemory(), small_rig)
    rng = np.random.default_rng(4)
    points = rng.uniform(-0.05, 0.05, (30, 3)).astype(np.float32).astype(np.float64)
    tets = np.array([rng.choice(30, 4, replace=False) for _ in range(40)])
    young = rng.uniform(9e4, 2.2e5, 40)
    write_tissue(
        stage,
        "/Face/Tissue",
        points,
        tets,
        youngs_modulus=young,
        poisson_ratio=0.495,
        viscosity=476.8,
        density=1100.0,
        regions={"cheek": [0, 3, 9], "alare": np.arange(20, 25)},
        skin_path="/Face/Skin",
    )
    tissue = read_tissue(stage)
    assert np.array_equal(tissue.points, points) and np.array_equal(tissue.tets, tets)
    assert np.array_equal(tissue.youngs_modulus, young) and tissue.poisson_ratio == 0.495 and tissue.density == 1100.0
    assert {k: v.tolist() for k, v in tissue.regions.items()} == {"cheek": [0, 3, 9], "alare": [20, 21, 22, 23, 24]}
    prim = stage.GetPrimAtPath("/Face/Tissue")
    assert UsdGeom.PrimvarsAPI(prim).GetPrimvar("warpFace:youngsModulus").GetInterpolation() == "uniform"
    assert UsdGeom.PrimvarsAPI(prim).GetPrimvar("warpFace:density").GetInterpolation() == "constant"
    prim.GetAttribute("primvars:warpFace:viscosity").Set(Vt.DoubleArray([1.0, 2.0]))
    with pytest.raises(RigError, match=r"^/Face/Tissue.primvars:warpFace:viscosity: 'constant' primvar with 2 values"):
        read_tissue(stage)
    with pytest.raises(ValueError, match=r"poisson_ratio must be in \[0, 0.4999\]"):
        write_tissue(stage, "/Face/T2", points, tets, youngs_modulus=1e5, poisson_ratio=0.5, viscosity=1.0, density=1.0)
    with pytest.raises(ValueError, match=r"tet 0 has node index out of range"):
        write_tissue(
            stage, "/Face/T3", points, tets + 30, youngs_modulus=1e5, poisson_ratio=0.3, viscosity=1.0, density=1.0
        )


def test_landmarks_out_of_range(rig_stage, small_rig):
    skin = rig_stage.GetPrimAtPath("/Face/Skin")
    skin.GetAttribute("warpFace:landmarkIndices").Set(Vt.IntArray([0, small_rig.mesh.vertex_count]))
    with pytest.raises(RigError, match=r"^/Face/Skin: .*landmark 1 index 256 out of range"):
        read_rig(rig_stage)
