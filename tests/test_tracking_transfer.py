"""Sparse → dense transfer: eq. 4.15 against NumPy, linear precision, smooth blend weights, and the
TrackingAdapter's frame handling (reference, stabilisation, missing landmarks, names)."""

import numpy as np
import pytest

from warpface.tracking import LandmarkFrame, RecordedLandmarks, TrackingAdapter, compute_correspondence
from warpface.tracking.correspondence import triangulate_landmarks
from warpface.tracking.synthetic import procedural_face
from warpface.tracking.transfer import blend_weights, transfer_displacements


@pytest.fixture(scope="module")
def meshes():
    """A sparse landmark mesh over the middle of a procedural face, and the denser face itself."""
    dense, dense_tri = procedural_face(41)
    inner = np.flatnonzero((np.abs(dense[:, 0]) < 0.055) & (np.abs(dense[:, 1]) < 0.075))
    sparse_idx = inner[::23]
    sparse = dense[sparse_idx]
    return sparse, triangulate_landmarks(sparse), dense, dense_tri


def random_surface_points(sparse, tri, count, rng):
    t = rng.integers(0, len(tri), count)
    b = rng.dirichlet(np.ones(3), count)
    return np.einsum("qj,qjk->qk", b, sparse[tri[t]])


def test_transfer_matches_numpy_and_has_linear_precision(meshes):
    sparse, tri, _, _ = meshes
    rng = np.random.default_rng(2)
    dense = random_surface_points(sparse, tri, 500, rng)
    corr = compute_correspondence(dense, sparse, tri, device="cpu")
    # Random displacements: eq. 4.15 evaluated in float64 NumPy.
    disp = rng.normal(scale=0.003, size=sparse.shape)
    weights = rng.uniform(0, 1, len(dense)).astype(np.float32)
    got = transfer_displacements(disp, tri, corr, weights, scale=1.7, device="cpu")
    want = (
        1.7 * weights[:, None] * np.einsum("vj,vjk->vk", corr.barycentric.astype(np.float64), disp[tri[corr.triangle]])
    )
    np.testing.assert_allclose(got, want, atol=1e-7)
    # An affine sparse motion moves points on the sparse surface exactly affinely.
    a = np.array([[0.01, 0.02, -0.01], [0.0, -0.03, 0.02], [0.015, 0.0, 0.01]])
    b = np.array([0.001, -0.002, 0.0005])
    got = transfer_displacements(sparse @ a.T + b, tri, corr, device="cpu")
    np.testing.assert_allclose(got, dense @ a.T + b, atol=2e-7)


def test_blend_weights_are_smooth_and_fade_beyond_the_contour(meshes):
    sparse, tri, dense, dense_tri = meshes
    corr = compute_correspondence(dense, sparse, tri, device="cpu")
    falloff = 0.03  # ≈ 6 grid spacings
    w = blend_weights(dense, corr, cover_falloff=(0.0, falloff), device="cpu")
    assert w.dtype == np.float32 and w.min() >= 0.0 and w.max() <= 1.0
    inside = corr.overhang < 1e-6
    assert np.all(w[inside] == 1.0)
    assert np.all(w[corr.overhang >= falloff] == 0.0)
    band = ~inside & (corr.overhang < falloff)
    assert band.sum() > 20  # a real transition zone, not a switch
    # Lipschitz bound of the smoothstep (max slope 1.5/falloff) over every mesh edge; the
    # thesis's hard region switch jumps by 1 across one edge.
    edges = np.concatenate([dense_tri[:, [0, 1]], dense_tri[:, [1, 2]], dense_tri[:, [2, 0]]])
    length = np.linalg.norm(dense[edges[:, 0]] - dense[edges[:, 1]], axis=1)
    jump = np.abs(w[edges[:, 0]] - w[edges[:, 1]])
    assert np.all(jump <= 1.5 * length / falloff * 1.05 + 1e-6)
    hard = (corr.overhang < 1e-6).astype(float)
    assert np.abs(hard[edges[:, 0]] - hard[edges[:, 1]]).max() == 1.0
    assert jump.max() < 0.5
    # Monotone in the overhang.
    order = np.argsort(corr.overhang)
    assert np.all(np.diff(w[order]) <= 1e-7)


def test_region_weights_follow_distance_to_region(meshes):
    sparse, tri, dense, _ = meshes
    corr = compute_correspondence(dense, sparse, tri, device="cpu")
    region = dense[:, 1] > 0.0
    falloff = 0.02
    w = blend_weights(dense, corr, region=region, region_falloff=falloff, cover_falloff=(0.0, 1.0), device="cpu")
    cover = 1.0 - _smoothstep(0.0, 1.0, corr.overhang)
    dist = np.sqrt(((dense[:, None, :] - dense[region][None, :, :]) ** 2).sum(-1)).min(axis=1)
    want = cover * (1.0 - _smoothstep(0.0, falloff, dist))
    np.testing.assert_allclose(w, want, atol=2e-5)
    with pytest.raises(ValueError, match="region"):
        blend_weights(dense, corr, region=np.zeros(len(dense), bool), device="cpu")
    with pytest.raises(ValueError, match="cover_falloff"):
        blend_weights(dense, corr, cover_falloff=(0.02, 0.01), device="cpu")


def _smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


CAMERA_TO_MODEL = np.array([[1.0, 0, 0, 0], [0, -1.0, 0, 0], [0, 0, -1.0, 0.6], [0, 0, 0, 1]])  # its own inverse


def camera_frame(model_points, index, t=0.0, confidence=None):
    cam = model_points @ CAMERA_TO_MODEL[:3, :3].T + CAMERA_TO_MODEL[:3, 3]
    conf = np.ones(len(cam)) if confidence is None else confidence
    return LandmarkFrame(t, cam, conf, index)


def test_adapter_translation_rotation_and_missing_landmarks(meshes):
    sparse, tri, dense, _ = meshes
    names = [f"lm{i}" for i in range(len(sparse))]
    adapter = TrackingAdapter(sparse, tri, dense, landmark_names=names, camera_to_model=CAMERA_TO_MODEL, device="cpu")
    adapter.bind(names)
    rest = adapter.track_frame(camera_frame(sparse, 0))
    np.testing.assert_allclose(rest, dense, atol=1e-7)
    # A translation of every landmark moves each dense vertex by w × that translation (model frame).
    shift = np.array([0.002, -0.001, 0.003])
    moved = adapter.track_frame(camera_frame(sparse + shift, 1, 0.033))
    np.testing.assert_allclose(moved - dense, adapter.weights[:, None] * shift, atol=2e-7)
    adapter.scale = 2.0  # the sparse → dense scale is read every frame
    doubled = adapter.track_frame(camera_frame(sparse + shift, 1, 0.034), copy=False)
    np.testing.assert_allclose(doubled - dense, 2.0 * adapter.weights[:, None] * shift, atol=4e-7)
    adapter.scale = 1.0
    # Missing landmarks (NaN, or confidence 0) hold their last displacement: nothing NaN, no jump.
    frame = camera_frame(sparse + shift, 2, 0.066)
    pts = frame.points.copy()
    pts[:5] = np.nan
    conf = np.ones(len(sparse))
    conf[5:8] = 0.0
    held = adapter.track_frame(LandmarkFrame(0.066, pts, conf, 2))
    assert np.all(np.isfinite(held))
    np.testing.assert_allclose(held, moved, atol=1e-7)


def test_adapter_stabilisation_removes_head_motion(meshes):
    sparse, tri, dense, _ = meshes
    adapter = TrackingAdapter(sparse, tri, dense, camera_to_model=CAMERA_TO_MODEL, stabilize=True, device="cpu")
    adapter.track_frame(camera_frame(sparse, 0))
    angle = np.radians(8.0)
    rot = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    turned = (sparse - sparse.mean(0)) @ rot.T + sparse.mean(0) + [0.01, 0.0, -0.02]
    out = adapter.track_frame(camera_frame(turned, 1, 0.1))
    np.testing.assert_allclose(out, dense, atol=1e-6)
    # Without stabilisation the same head turn moves the face.
    plain = TrackingAdapter(sparse, tri, dense, camera_to_model=CAMERA_TO_MODEL, device="cpu")
    plain.track_frame(camera_frame(sparse, 0))
    assert np.abs(plain.track_frame(camera_frame(turned, 1, 0.1)) - dense).max() > 1e-3


def test_adapter_fits_camera_transform_and_matches_names(meshes, tmp_path):
    sparse, tri, dense, _ = meshes
    names = [f"lm{i}" for i in range(len(sparse))]
    adapter = TrackingAdapter(sparse, tri, dense, landmark_names=names, device="cpu")
    # A source with the landmarks shuffled and two extra ones; recorded, then tracked.
    rng = np.random.default_rng(4)
    order = rng.permutation(len(sparse))
    src_names = [names[i] for i in order] + ["extra_a", "extra_b"]
    lift = np.array([0.0, 0.004, 0.0])
    frames = []
    for k, offset in enumerate([np.zeros(3), lift]):
        model = sparse.copy()
        model[:, 1] += offset[1] * (model[:, 1] < 0)  # only the lower half moves
        cam = model @ CAMERA_TO_MODEL[:3, :3].T + CAMERA_TO_MODEL[:3, 3]
        pts = np.vstack([cam[order], rng.normal(size=(2, 3))])
        frames.append(LandmarkFrame(k / 30, pts, np.ones(len(pts)), k))
    path = RecordedLandmarks.write(tmp_path / "lm.npz", frames, src_names, fps=30)
    outputs = list(adapter.track(RecordedLandmarks(path)))
    assert len(outputs) == 2
    np.testing.assert_allclose(adapter.camera_to_model, CAMERA_TO_MODEL, atol=1e-9)
    expected_sparse = np.where((sparse[:, 1] < 0)[:, None], lift, 0.0)
    np.testing.assert_allclose(adapter.sparse_displacement, expected_sparse, atol=1e-12)
    want = transfer_displacements(expected_sparse, tri, adapter.correspondence, adapter.weights, device="cpu")
    np.testing.assert_allclose(outputs[1][1] - dense, want, atol=1e-7)

    with pytest.raises(ValueError, match="lacks 1 of the sparse mesh's landmarks: 'lm0'"):
        adapter.bind([n for n in names if n != "lm0"])
    unnamed = TrackingAdapter(sparse, tri, dense, device="cpu")
    with pytest.raises(ValueError, match="landmarks but the sparse mesh has"):
        unnamed.bind(names + ["x"])
    unnamed.track_frame(camera_frame(sparse, 0))
    with pytest.raises(ValueError, match="frame 1 has"):
        unnamed.track_frame(LandmarkFrame(0.1, np.zeros((len(sparse) + 1, 3)), np.ones(len(sparse) + 1), 1))


def test_adapter_blends_other_field(meshes):
    sparse, tri, dense, _ = meshes
    adapter = TrackingAdapter(sparse, tri, dense, camera_to_model=CAMERA_TO_MODEL, device="cpu")
    adapter.track_frame(camera_frame(sparse, 0))
    other = np.tile([0.0, 0.0, 0.005], (len(dense), 1))
    out = adapter.track_frame(camera_frame(sparse, 1, 0.1), other=other)
    np.testing.assert_allclose(out - dense, (1.0 - adapter.weights)[:, None] * other, atol=1e-7)
    driven = adapter.driven_vertices()
    assert driven.size > 0 and np.all(adapter.weights[driven] >= 0.999)
    with pytest.raises(ValueError, match="other"):
        adapter.track_frame(camera_frame(sparse, 2, 0.2), other=np.zeros((3, 3)))
