"""Tissue volume from a surface: topology checks, offset shell, self-intersections, fTetWild meshing."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import patch

from warpface.fem import TetMesh
from warpface.fem.embedding import embed_points
from warpface.fem.shell import offset_shell
from warpface.fem.tetmesh import tet_signed_volumes
from warpface.fem.tetwild import validated_tets
from warpface.fem.volume import mesh_tissue, tissue_from_surface
from warpface.geometry.surface_checks import boundary_loops, check_surface, find_self_intersections


def edge_use(triangles):
    directed = triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    undirected = {}
    for a, b in directed:
        undirected.setdefault((min(a, b), max(a, b)), []).append((a, b))
    return undirected


# ------------------------------------------------------------------------------------------ topology


def test_boundary_loops_of_a_patch_with_a_hole():
    points, triangles = patch()
    boundary = check_surface(points, triangles, closed=False)
    loops = boundary_loops(boundary)
    assert [len(loop) for loop in loops] == [4 * 12, 4 * 2]
    edge_set = {tuple(e) for e in boundary.tolist()}
    for loop in loops:  # consecutive loop vertices are boundary edges, in winding order, closing the loop
        assert {(int(a), int(b)) for a, b in zip(loop, np.roll(loop, -1))} <= edge_set
    assert sum(len(loop) for loop in loops) == len(boundary)


def test_check_surface_rejects_bad_topology():
    points, triangles = patch(5, hole=False)
    flipped = triangles.copy()
    flipped[3] = flipped[3, ::-1]
    with pytest.raises(ValueError, match="same direction"):
        check_surface(points, flipped, closed=False)
    extra = np.r_[points, [[0.0, 0.0, 0.01]]]
    t = triangles[0]
    fan = np.r_[triangles, [[t[2], t[0], len(points)]]]  # a third triangle on the cell diagonal
    with pytest.raises(ValueError, match="shared by 3 triangles"):
        check_surface(extra, fan, closed=False)
    with pytest.raises(ValueError, match="not watertight"):
        check_surface(points, triangles, closed=True)
    with pytest.raises(ValueError, match="repeats a vertex"):
        check_surface(points, np.r_[triangles, [[0, 0, 1]]], closed=False)
    # two patches sharing one corner vertex: a bow tie on the boundary
    p2 = points + [0.2, 0.2, 0.0]
    corner_a = np.argmax(points[:, 0] + points[:, 1])
    corner_b = np.argmin(p2[:, 0] + p2[:, 1])
    p2[corner_b] = points[corner_a]
    both = np.r_[points, p2]
    tris = np.r_[triangles, triangles + len(points)]
    tris[tris == corner_b + len(points)] = corner_a
    with pytest.raises(ValueError, match="boundary loops"):
        check_surface(both, tris, closed=False)


# ------------------------------------------------------------------------------------------ self-intersection


def _segment_hits_triangle(p0, p1, a, b, c):
    e1, e2, d = b - a, c - a, p1 - p0
    h = np.cross(d, e2)
    det = e1 @ h
    if abs(det) < 1e-300:
        return False
    s = p0 - a
    u = (s @ h) / det
    q = np.cross(s, e1)
    v = (d @ q) / det
    t = (e2 @ q) / det
    return 0.0 <= u <= 1.0 and 0.0 <= v and u + v <= 1.0 and 0.0 <= t <= 1.0


def _triangles_cross(A, B):
    return any(_segment_hits_triangle(A[i], A[(i + 1) % 3], *B) for i in range(3)) or any(
        _segment_hits_triangle(B[i], B[(i + 1) % 3], *A) for i in range(3)
    )


def test_self_intersections_match_a_brute_force_oracle(rng):
    # random millimetre triangles in a 2 cm box (metre units: the scale Moeller's absolute epsilon breaks)
    centres = rng.uniform(0.0, 0.02, (120, 3))
    points = (centres[:, None, :] + rng.normal(0.0, 0.002, (120, 3, 3))).reshape(-1, 3)
    triangles = np.arange(360).reshape(120, 3)
    count, pairs = find_self_intersections(points, triangles, max_pairs=10_000, device="cpu")
    expected = {
        (i, j)
        for i in range(120)
        for j in range(i + 1, 120)
        if _triangles_cross(points[triangles[i]], points[triangles[j]])
    }
    assert len(expected) > 10
    assert count == len(expected)
    assert {tuple(p) for p in pairs.tolist()} == expected


def test_parallel_sheets_a_millimetre_apart_do_not_intersect():
    points, triangles = patch(9, size=0.02, hole=False)
    other = points + [0.0, 0.0, 0.001]
    both = np.r_[points, other]
    tris = np.r_[triangles, triangles + len(points)]
    count, _ = find_self_intersections(both, tris, device="cpu")
    assert count == 0


# ------------------------------------------------------------------------------------------ shell


def test_offset_shell_of_a_flat_patch_is_exact_and_watertight():
    points, triangles = patch()
    h = 0.004
    shell = offset_shell(points, triangles, h, device="cpu")
    n = len(points)
    assert shell.smoothing_iterations == 0
    np.testing.assert_allclose(shell.points[n:], points - [0.0, 0.0, h], atol=1e-15)
    # every edge used twice, in opposite directions
    for uses in edge_use(shell.triangles).values():
        assert len(uses) == 2 and uses[0] == uses[1][::-1]
    area = 0.06**2 - (0.06 / 12 * 2) ** 2
    assert shell.volume == pytest.approx(area * h, rel=1e-12)
    assert len(shell.loops) == 2


def test_per_vertex_thickness_and_curved_patch():
    points, triangles = patch(bend=10.0)
    h = 0.002 + 0.004 * (points[:, 1] - points[:, 1].min()) / np.ptp(points[:, 1])
    shell = offset_shell(points, triangles, h, device="cpu")
    inner = shell.points[len(points) :]
    np.testing.assert_allclose(np.linalg.norm(points - inner, axis=1), h, rtol=1e-12)
    # on a cylinder the vertex normals are radial: the inner surface is the cylinder of radius R - h
    axis_distance = np.hypot(inner[:, 0], inner[:, 2] + 0.1)
    np.testing.assert_allclose(axis_distance, 0.1 - h, atol=2e-5)


def test_offset_that_folds_is_rejected_with_the_location():
    # a cylinder of radius 5 mm, thickened by 8 mm: the inward offset passes through the axis
    points, triangles = patch(13, size=0.02, hole=False, bend=200.0)
    with pytest.raises(ValueError, match="folds over itself.*radius of curvature"):
        offset_shell(points, triangles, 0.008, max_smoothing=0, device="cpu")


def test_thickness_larger_than_a_gap_is_rejected():
    # two sheets 2 mm apart: thickening the upper one by 5 mm pushes it through the lower one
    upper, tris = patch(9, size=0.02, hole=False)
    lower = upper - [0.0, 0.0, 0.002]
    points = np.r_[upper, lower]
    triangles = np.r_[tris, tris + len(upper)]
    with pytest.raises(ValueError, match="intersects itself"):
        offset_shell(points, triangles, 0.005, device="cpu")


@pytest.mark.parametrize(
    "thickness, message",
    [(0.0, "vertex 0 must be finite and > 0"), (-0.001, "> 0"), (np.nan, "> 0"), (np.ones(3), "one value per vertex")],
)
def test_bad_thickness(thickness, message):
    points, triangles = patch(5, hole=False)
    with pytest.raises(ValueError, match=message):
        offset_shell(points, triangles, thickness, device="cpu")


def test_closed_input_is_rejected_and_winding_picks_the_side():
    points, triangles = patch(7, hole=False)
    shell = offset_shell(points, triangles, 0.003, device="cpu")
    with pytest.raises(ValueError, match="no boundary loop"):
        offset_shell(shell.points, shell.triangles, 0.001, device="cpu")
    # reversed winding puts the tissue on the other side, with the same (positive) volume
    flipped = offset_shell(points, triangles[:, ::-1], 0.003, device="cpu")
    np.testing.assert_allclose(flipped.points[len(points) :, 2], 0.003)
    assert flipped.volume == pytest.approx(shell.volume, rel=1e-12) and shell.volume > 0.0


# ------------------------------------------------------------------------------------------ meshing


def test_mesh_tissue_small_patch_quality_and_volume(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    points, triangles = patch(17, size=0.05, bend=8.0)
    result = mesh_tissue((points, triangles), 0.006, target_nodes=800, device="cpu")
    assert list(tmp_path.iterdir()) == []  # fTetWild's debug files stay in its scratch folder
    mesh, report = result.tetmesh, result.report
    assert isinstance(mesh, TetMesh)
    assert np.all(tet_signed_volumes(mesh.points, mesh.tets) > 0.0)
    assert report.quality.inverted_count == 0
    assert report.quality.min_dihedral_deg > 0.5
    assert report.volume_error < 0.01
    assert report.tet_volume == pytest.approx(result.shell.volume, rel=0.01)
    assert 300 <= report.node_count <= 2000
    assert report.boundary_loops == 2
    # the tet boundary reproduces the outer surface within fTetWild's envelope
    bbox = np.linalg.norm(np.ptp(result.shell.points, axis=0))
    lo, hi = mesh.points.min(axis=0), mesh.points.max(axis=0)
    np.testing.assert_allclose(lo, result.shell.points.min(axis=0), atol=2e-3 * bbox)
    np.testing.assert_allclose(hi, result.shell.points.max(axis=0), atol=2e-3 * bbox)
    assert "nodes" in str(report) and report.timings["total"] > 0.0


def test_self_intersecting_input_is_rejected_before_meshing():
    a, tris = patch(9, size=0.03, hole=False)
    b = a[:, [2, 1, 0]] + [0.0, 0.0, 0.0]  # the same sheet turned upright: crosses the first along y
    points = np.r_[a, b]
    triangles = np.r_[tris, tris + len(a)]
    with pytest.raises(ValueError, match="face surface intersects itself"):
        tissue_from_surface((points, triangles), 0.002, target_nodes=500, device="cpu")
    # tolerated on input, the crossing survives into the shell, which is always checked
    with pytest.raises(ValueError, match="tissue shell intersects itself"):
        tissue_from_surface((points, triangles), 0.002, target_nodes=500, input_intersections="ignore", device="cpu")


def test_mesh_tissue_argument_checks():
    points, triangles = patch(5, hole=False)
    with pytest.raises(ValueError, match="target_nodes"):
        mesh_tissue((points, triangles), 0.002, target_nodes=None, device="cpu")
    with pytest.raises(ValueError, match="edge_length"):
        mesh_tissue((points, triangles), 0.002, edge_length=-1.0, device="cpu")
    with pytest.raises(ValueError, match="out of range"):
        mesh_tissue((points, np.r_[triangles, [[0, 1, 99]]]), 0.002, device="cpu")
    with pytest.raises(TypeError, match="FaceMesh or a"):
        mesh_tissue(42, 0.002, device="cpu")
    with pytest.raises(ValueError, match="input_intersections"):
        mesh_tissue((points, triangles), 0.002, input_intersections="maybe", device="cpu")


def test_tet_validation_orients_and_rejects():
    from warpface.fem import box_tet_mesh

    box = box_tet_mesh((0.02, 0.01, 0.01), (2, 1, 1))
    volume = box.total_volume
    flipped = box.tets[:, [0, 1, 3, 2]]  # all one (the other) orientation: turned around
    mesh = validated_tets(box.points, flipped, volume)
    assert np.all(mesh.volumes > 0.0) and mesh.total_volume == pytest.approx(volume)
    mixed = box.tets.copy()
    mixed[4] = mixed[4][[0, 1, 3, 2]]
    with pytest.raises(ValueError, match="1 inverted tets.*tet 4"):
        validated_tets(box.points, mixed, volume)
    flat = np.r_[box.points, [[0.005, 0.005, 0.0], [0.006, 0.005, 0.0]]]
    n = len(box.points)
    degenerate = np.r_[box.tets, [[0, 1, n, n + 1]]]  # four points on the plane z = 0
    with pytest.raises(ValueError, match="rejected.*degenerate"):
        validated_tets(flat, degenerate, volume)
    with pytest.raises(ValueError, match="not filled correctly"):
        validated_tets(box.points, box.tets[: len(box.tets) // 2], volume)


def _with_degenerate_tet(nodes, tets):
    """fTetWild's output plus one tet of exactly zero volume (its fourth node a copy of its first)."""
    a, b, c = tets[0][:3]
    nodes = np.r_[nodes, nodes[a][None]]
    return nodes, np.r_[tets, [[a, b, c, len(nodes) - 1]]]


def test_a_rejected_ftetwild_run_is_retried(tmp_path, monkeypatch):
    """fTetWild is not deterministic; a run that leaves degenerate tets is repeated, not fatal."""
    import warpface.fem.tetwild as tetwild

    monkeypatch.chdir(tmp_path)
    real = tetwild.tetrahedralize
    calls = []

    def first_run_degenerate(points, triangles, **options):
        calls.append(1)
        nodes, tets = real(points, triangles, **options)
        return _with_degenerate_tet(nodes, tets) if len(calls) == 1 else (nodes, tets)

    monkeypatch.setattr(tetwild, "tetrahedralize", first_run_degenerate)
    points, triangles = patch(11, size=0.04, bend=8.0)
    result = mesh_tissue((points, triangles), 0.006, target_nodes=400, device="cpu")
    # fTetWild itself fails validation now and then, so a later run may also have been needed
    assert len(calls) >= 2 and result.report.tetwild_runs == len(calls)
    assert f"{len(calls)} fTetWild runs" in str(result.report)
    assert np.all(tet_signed_volumes(result.tetmesh.points, result.tetmesh.tets) > 0.0)


def test_ftetwild_gives_up_after_the_last_attempt(tmp_path, monkeypatch):
    import warpface.fem.tetwild as tetwild

    monkeypatch.chdir(tmp_path)
    real = tetwild.tetrahedralize
    outputs = []

    def always_degenerate(points, triangles, **options):
        if not outputs:
            outputs.append(real(points, triangles, **options))
        else:
            outputs.append(outputs[0])
        return _with_degenerate_tet(*outputs[0])

    monkeypatch.setattr(tetwild, "tetrahedralize", always_degenerate)
    points, triangles = patch(11, size=0.04, bend=8.0)
    with pytest.raises(ValueError, match=rf"fTetWild .*after {tetwild.TETWILD_ATTEMPTS} fTetWild runs"):
        mesh_tissue((points, triangles), 0.006, target_nodes=400, device="cpu")
    assert len(outputs) == tetwild.TETWILD_ATTEMPTS


def test_built_in_face_meshes_with_default_options_and_reports_progress(tmp_path, monkeypatch):
    """The built-in face meshes with default options at 3,000 nodes: at a uniform 6 mm the inner offsets
    of the lips cross, and thickness clamping (thin_defects, on by default) thins them until they do not.
    The skin is not moved, so every vertex of the render surface still embeds in the tissue.
    (`warpface track synthetic --fem` uses 4 mm, which the face takes without clamping.)"""
    from warpface.assets import default_rig

    monkeypatch.chdir(tmp_path)
    rig = default_rig()
    stages = []
    result = mesh_tissue(
        rig.mesh,
        0.006,
        target_nodes=3000,
        device="cpu",
        progress=lambda stage, seconds: stages.append((stage, seconds)),
    )
    report = result.report
    assert report.thinning_rounds >= 1 and report.fairing_rounds == 0
    assert report.thickness_range[1] == pytest.approx(0.006)
    assert 0.006 * 0.85**6 - 1e-12 <= report.thickness_range[0] < 0.006
    assert "thickness clamping rounds" in str(report)
    embed_points(result.tetmesh, rig.mesh.points, device="cpu")  # raises if a skin vertex is off the tissue
    assert report.quality.inverted_count == 0 and report.volume_error < 0.05
    assert find_self_intersections(result.shell.points, result.shell.triangles, device="cpu")[0] == 0
    names = [s for s, _ in stages]
    assert [s for i, s in enumerate(names) if i == 0 or names[i - 1] != s] == list(volume_stages())
    waits = [t for s, t in stages if s == "tetrahedralize"]
    assert len(waits) >= 2 and waits == sorted(waits)  # reported while fTetWild ran, time increasing
    with pytest.raises(TypeError, match="progress"):
        mesh_tissue(rig.mesh, 0.004, progress="yes", device="cpu")
    with pytest.raises(ValueError, match="thin_defects must be an integer >= 0"):
        mesh_tissue(rig.mesh, 0.004, thin_defects=-1, device="cpu")
    with pytest.raises(TypeError, match="fair_folds must be an integer"):
        mesh_tissue(rig.mesh, 0.004, fair_folds=2.5, device="cpu")


def volume_stages():
    from warpface.fem.volume import MESHING_STAGES

    return MESHING_STAGES
