"""Tissue proxy of a render surface: cavities capped, curls removed, thickness limited; ICT end to end."""

from __future__ import annotations

import numpy as np
import pytest

from warpface.fem.embedding import embed_points
from warpface.fem.proxy import default_center, tissue_proxy
from warpface.fem.tetmesh import tet_signed_volumes
from warpface.fem.volume import mesh_tissue
from warpface.geometry.surface_checks import boundary_loops, check_surface, find_self_intersections


def grid(n: int, size: float, hole: tuple[int, int] | None = None):
    """A square ``n × n``-vertex grid [m] in the plane z = 0 (normals +z), optionally without the
    cells ``hole[0] <= i, j < hole[1]``. Returns points (V, 3), triangles (T, 3), cell-index map."""
    xs = np.linspace(-size / 2, size / 2, n)
    x, y = np.meshgrid(xs, xs)
    points = np.c_[x.ravel(), y.ravel(), np.zeros(n * n)]
    index = np.arange(n * n).reshape(n, n)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    keep = (
        np.ones_like(i, dtype=bool)
        if hole is None
        else ~((i >= hole[0]) & (i < hole[1]) & (j >= hole[0]) & (j < hole[1]))
    )
    i, j = i[keep], j[keep]
    a, b, c, d = index[i, j], index[i, j + 1], index[i + 1, j], index[i + 1, j + 1]
    return points, np.r_[np.c_[a, b, d], np.c_[a, d, c]]


def pitted_plate(depth: float = 0.008):
    """A 6 cm plate with a square pit 1 cm wide and ``depth`` deep in its middle (walls and floor
    wound so normals point out of the tissue, i.e. into the pit)."""
    n, size = 13, 0.06
    points, triangles = grid(n, size, hole=(5, 7))
    index = np.arange(n * n).reshape(n, n)
    rim = np.r_[index[5, 5:7], index[5:7, 7], index[7, 7:5:-1], index[7:5:-1, 5]]  # the hole's loop, 8 vertices
    # the loop runs counter-clockwise seen from +z, against the plate's boundary edges around the
    # hole; walls go down in steps to a floor fanned around its centre
    levels = 4
    new_points, new_triangles = [], []
    upper = rim
    for level in range(1, levels + 1):
        lower = len(points) + sum(len(p) for p in new_points) + np.arange(len(rim))
        new_points.append(points[rim] - [0.0, 0.0, depth * level / levels])
        nxt_u, nxt_l = np.roll(upper, -1), np.roll(lower, -1)
        new_triangles += [np.c_[upper, nxt_u, nxt_l], np.c_[upper, nxt_l, lower]]
        upper = lower
    floor_centre = len(points) + sum(len(p) for p in new_points)
    new_points.append(points[rim].mean(axis=0, keepdims=True) - [0.0, 0.0, depth])
    new_triangles.append(np.c_[upper, np.roll(upper, -1), np.full(len(rim), floor_centre)])
    plate = len(triangles)
    points = np.concatenate([points, *new_points])
    triangles = np.concatenate([triangles, *new_triangles])
    return points, triangles, plate


def test_pitted_plate_fixture_is_an_oriented_manifold():
    points, triangles, plate = pitted_plate()
    assert len(triangles) - plate == 4 * 16 + 8
    loops = boundary_loops(check_surface(points, triangles, closed=False))
    assert [len(loop) for loop in loops] == [48]  # only the plate's rim: the pit is closed at its floor
    assert find_self_intersections(points, triangles, device="cpu")[0] == 0


def test_a_pit_is_capped_flat_and_its_depth_is_the_deviation():
    depth = 0.008
    points, triangles, plate = pitted_plate(depth)
    proxy = tissue_proxy(
        (points, triangles),
        0.003,
        center=[0.0, 0.0, -0.05],
        margin=0.0,
        boundary_passes=0,
        crease_gap=0.0,
        device="cpu",
    )
    # the walls face sideways (cosine 0 to the ray from below) and are removed, the floor is cut off
    # with them; the opening is closed by a membrane, flat since its loop is
    assert proxy.capped_loops == 1
    assert [len(loop) for loop in boundary_loops(check_surface(proxy.points, proxy.triangles, closed=False))] == [48]
    cap = proxy.source < 0
    assert cap.sum() > 0
    np.testing.assert_allclose(proxy.points[:, 2], 0.0, atol=1e-12)
    # input vertices kept are untouched (margin and boundary passes off)
    kept = ~cap
    np.testing.assert_array_equal(proxy.points[kept], points[proxy.source[kept]])
    assert proxy.removed_triangles == len(triangles) - plate  # walls and floor
    # the floor's centre is the farthest input point from the proxy: right below the cap
    assert proxy.max_deviation == pytest.approx(depth, abs=1e-6)
    assert find_self_intersections(proxy.points, proxy.triangles, device="cpu")[0] == 0


def test_close_near_caps_the_chosen_hole_and_the_rim_is_refused():
    points, triangles = grid(13, 0.06, hole=(5, 7))
    below = [0.0, 0.0, -0.05]  # the default centre would lie in the plate's plane
    open_proxy = tissue_proxy((points, triangles), 0.003, center=below, margin=0.0, boundary_passes=0, device="cpu")
    assert open_proxy.capped_loops == 0  # an eye or the mouth stays open by default
    assert len(boundary_loops(check_surface(open_proxy.points, open_proxy.triangles, closed=False))) == 2
    closed = tissue_proxy(
        (points, triangles),
        0.003,
        center=below,
        close_near=[[0.0, 0.0, 0.0]],
        margin=0.0,
        boundary_passes=0,
        device="cpu",
    )
    assert closed.capped_loops == 1
    assert len(boundary_loops(check_surface(closed.points, closed.triangles, closed=False))) == 1
    np.testing.assert_allclose(closed.points[:, 2], 0.0, atol=1e-12)
    with pytest.raises(ValueError, match="outer rim"):
        tissue_proxy((points, triangles), 0.003, center=below, close_near=[[0.031, 0.0, 0.0]], device="cpu")


def test_curled_margin_is_removed():
    # a plate whose last rows roll down and back under it (a lip margin): those face away from the
    # ray from the head's centre and are hidden behind the plate
    n, size = 17, 0.04
    points, triangles = grid(n, size)
    x = points[:, 0]
    start = size / 4
    radius = 0.004
    beyond = x > start
    angle = (x[beyond] - start) / radius  # arc length past the start of the roll, up to ~2.5 rad
    points[beyond, 0] = start + radius * np.sin(angle)
    points[beyond, 2] = radius * (np.cos(angle) - 1.0)
    assert angle.max() > 2.0
    center = np.array([0.0, 0.0, -0.05])
    proxy = tissue_proxy((points, triangles), 0.002, center=center, margin=0.0, boundary_passes=0, device="cpu")
    p = proxy.points[proxy.triangles]
    normals = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    rays = p.mean(axis=1) - center
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", normals, rays).min() >= 0.1  # min_facing
    assert proxy.removed_triangles > 0
    # the roll is kept to about 97 degrees (cosine 0.1 to the ray, which leans outward by ~13
    # degrees): its underside, turned further, is all gone
    assert proxy.points[:, 2].min() > radius * (np.cos(2.0) - 1.0)
    assert points[:, 2].min() < radius * (np.cos(2.4) - 1.0)


def test_thickness_is_limited_by_the_inward_gap_and_the_slope():
    # a sphere cap past the equator: an inward ray from a vertex whose antipode lies on the cap
    # crosses it again after the diameter 2R
    radius, h = 0.02, 0.05
    theta, phi = np.meshgrid(
        np.linspace(0.0, np.radians(140.0), 25), np.linspace(0.0, 2 * np.pi, 48, endpoint=False), indexing="ij"
    )
    rings = np.c_[(np.sin(theta) * np.cos(phi)).ravel(), (np.sin(theta) * np.sin(phi)).ravel(), np.cos(theta).ravel()]
    points = radius * np.r_[[[0.0, 0.0, 1.0]], rings[48:]]  # the pole once
    index = np.arange(1, len(points)).reshape(24, 48)
    fan = np.c_[np.zeros(48, dtype=int), index[0], np.roll(index[0], -1)]
    a, b = index[:-1], np.roll(index[:-1], -1, axis=1)
    c, d = index[1:], np.roll(index[1:], -1, axis=1)
    triangles = np.r_[fan, np.c_[a.ravel(), c.ravel(), d.ravel()], np.c_[a.ravel(), d.ravel(), b.ravel()]]
    check_surface(points, triangles, closed=False)
    proxy = tissue_proxy(
        (points, triangles),
        h,
        center=[0.0, 0.0, 0.0],
        margin=0.0,
        boundary_passes=0,
        crease_gap=0.0,
        boundary_thickness=None,
        device="cpu",
    )
    assert proxy.removed_triangles == 0 and proxy.capped_loops == 0
    polar = np.arccos(np.clip(proxy.points[:, 2] / radius, -1.0, 1.0))
    antipode_on_cap = polar >= np.radians(50.0)  # clear of the rim, where a tilted ray may slip past
    # gap 2R (chord through the centre, to within the polygonal sphere's sag)
    assert proxy.thickness[antipode_on_cap].max() <= 0.45 * 2.0 * radius * 1.001
    assert proxy.thickness.max() < h  # the slope limit carries the bound to the pole
    assert proxy.thinned_vertices == len(proxy.points)
    edges = np.unique(np.sort(proxy.triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    rise = np.abs(proxy.thickness[edges[:, 0]] - proxy.thickness[edges[:, 1]])
    run = np.linalg.norm(proxy.points[edges[:, 0]] - proxy.points[edges[:, 1]], axis=1)
    assert np.all(rise <= 0.5 * run + 1e-12)


def test_default_center_lies_behind_the_face():
    points = np.array([[-1.0, -2.0, 0.5], [3.0, 2.0, 2.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(default_center(points), [1.0, 0.0, 0.5])
    np.testing.assert_allclose(default_center(points, forward=(1.0, 0.0, 0.0)), [-1.0, 0.0, 1.25])


@pytest.mark.parametrize(
    "options, message",
    [
        ({"min_facing": 1.0}, "min_facing"),
        ({"margin": -0.001}, "margin"),
        ({"gap_fraction": 0.6}, "gap_fraction"),
        ({"max_slope": 0.0}, "max_slope"),
        ({"boundary_thickness": -0.001}, "boundary_thickness"),
        ({"cap_rings": 0}, "cap_rings"),
        ({"center": [0.0, np.nan, 0.0]}, "center"),
    ],
)
def test_bad_options(options, message):
    points, triangles = grid(5, 0.02)
    with pytest.raises(ValueError, match=message):
        tissue_proxy((points, triangles), 0.002, device="cpu", **options)


def test_bad_thickness_and_surface():
    points, triangles = grid(5, 0.02)
    with pytest.raises(ValueError, match="vertex 3 must be finite and > 0"):
        tissue_proxy((points, triangles), np.where(np.arange(25) == 3, -1.0, 0.002), device="cpu")
    with pytest.raises(ValueError, match="one value per vertex"):
        tissue_proxy((points, triangles), np.ones(3), device="cpu")
    flipped = triangles.copy()
    flipped[0] = flipped[0, ::-1]
    with pytest.raises(ValueError, match="same direction"):
        tissue_proxy((points, flipped), 0.002, device="cpu")


def test_fair_folds_thins_a_shell_through_a_gap(tmp_path, monkeypatch):
    # two sheets 2 mm apart, thickened by 5 mm: the plain mesher refuses, local fairing thins the
    # upper sheet where its offset crosses the lower one until the shell is clean
    monkeypatch.chdir(tmp_path)
    upper, tris = grid(9, 0.02)
    points = np.r_[upper, upper - [0.0, 0.0, 0.002]]
    triangles = np.r_[tris, tris + len(upper)]
    with pytest.raises(ValueError, match="intersects itself"):
        mesh_tissue((points, triangles), 0.005, target_nodes=300, decimate=False, thin_defects=0, device="cpu")
    result = mesh_tissue(
        (points, triangles), 0.005, target_nodes=300, decimate=False, thin_defects=0, fair_folds=30, device="cpu"
    )
    report = result.report
    assert 1 <= report.fairing_rounds <= 30
    assert report.quality.inverted_count == 0
    assert np.all(tet_signed_volumes(result.tetmesh.points, result.tetmesh.tets) > 0.0)
    assert find_self_intersections(result.shell.points, result.shell.triangles, device="cpu")[0] == 0
    assert report.thickness_range[0] < 0.002 < report.thickness_range[1]  # thinned only where needed
    with pytest.raises(ValueError, match="fair_folds"):
        mesh_tissue((points, triangles), 0.005, fair_folds=-1, device="cpu")


# ------------------------------------------------------------------------------------------ ICT-FaceKit


def test_ict_narrow_face_gives_a_valid_tissue_with_every_vertex_embedded(tmp_path, monkeypatch):
    from warpface import FaceMesh
    from warpface.assets import default_thickness
    from warpface.data import ict_face_region, ict_landmark_indices

    path, landmarks = ict_face_region("neutral"), ict_landmark_indices()
    if path is None or landmarks is None:
        pytest.skip("ICT-FaceKit face not in ../shared/data (set WARPFACE_SHARED_DATA)")
    monkeypatch.chdir(tmp_path)
    raw = FaceMesh.from_obj(path)
    narrow = 6706  # the data README's narrow face region, vertices 0..6705; centimetres -> metres
    face = FaceMesh(raw.points[:narrow] * 0.01, raw.triangles[(raw.triangles < narrow).all(axis=1)], name="ict")
    assert find_self_intersections(face.points, face.triangles, device="cpu")[0] > 0  # why a proxy is needed
    thickness = np.maximum(default_thickness(face, landmarks, device="cpu"), 0.002)
    ibug = face.points[landmarks]
    eyes = np.stack([ibug[36:42].mean(axis=0), ibug[42:48].mean(axis=0)])

    proxy = tissue_proxy(face, thickness, close_near=eyes, device="cpu")
    assert find_self_intersections(proxy.points, proxy.triangles, device="cpu")[0] == 0
    loops = boundary_loops(check_surface(proxy.points, proxy.triangles, closed=False))
    assert len(loops) == 2  # the rim and the mouth: nostrils and eyes capped, the mouth kept open
    assert proxy.capped_loops >= 4
    assert np.all(proxy.thickness > 0.0) and proxy.thickness.max() <= thickness.max()

    result = mesh_tissue(
        (proxy.points, proxy.triangles), proxy.thickness, target_nodes=1600, fair_folds=10, device="cpu"
    )
    mesh, report = result.tetmesh, result.report
    assert report.quality.inverted_count == 0
    assert np.all(tet_signed_volumes(mesh.points, mesh.tets) > 0.0)
    assert report.volume_error < 0.01
    assert report.boundary_loops == 2

    reach = proxy.max_deviation + report.edge_length
    embedding = embed_points(mesh, face, max_distance=reach, device="cpu")  # raises if a vertex is left out
    assert embedding.point_count == face.vertex_count
    assert embedding.distances.max() <= reach
    # the skin that was kept lies on the tissue (within the mesher's envelope): only removed parts
    # (nostril interiors, inner lips, lid margins) bind from afar
    kept = np.zeros(face.vertex_count, dtype=bool)
    kept[proxy.source[(proxy.source >= 0)]] = True
    assert np.quantile(embedding.distances[kept], 0.95) < 0.5 * report.edge_length
    # the mouth corners and the landmarks Kato's ξ measures sit on the tissue
    assert embedding.distances[landmarks[[48, 54, 50, 52, 31, 35]]].max() < 0.5 * report.edge_length
