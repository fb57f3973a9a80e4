"""Material regions from landmarks and Kato's models 1–3 (SPEC §2.1)."""

from __future__ import annotations

import numpy as np
import pytest

from warpface.fem import TissueMaterial, box_tet_mesh
from warpface.fem.regions import (
    KATO_MODELS,
    KATO_REGIONS,
    kato_material_model,
    kato_regions,
    landmark_regions,
    tet_centroids,
)
from warpface.metrics import kato_landmarks


@pytest.fixture(scope="module")
def slab():
    """A 10 x 8 x 1 cm slab of tissue, 1 cm below z = 0."""
    mesh = box_tet_mesh((0.10, 0.08, 0.01), (20, 16, 2))
    return mesh


def kato_points():
    """Kato landmarks laid out on the slab's top face like a face's lower half (mirror symmetric in x)."""

    def pair(x, y):
        return [x, y, 0.01], [0.1 - x, y, 0.01]

    names = {}
    for key, (x, y) in {
        "ch": (0.02, 0.02),
        "cphi": (0.042, 0.035),
        "cphs": (0.045, 0.05),
        "al": (0.035, 0.06),
        "ex": (0.005, 0.075),
        "pi": (0.02, 0.07),
    }.items():
        names[f"{key}_R"], names[f"{key}_L"] = (np.array(p) for p in pair(x, y))
    return names


def test_landmark_regions_are_nearest_landmark_within_radius(slab):
    centres = {"a": [[0.02, 0.02, 0.01], [0.08, 0.02, 0.01]], "b": [0.05, 0.03, 0.005]}
    masks = landmark_regions(slab, centres, {"a": 0.015, "b": 0.02})
    c = tet_centroids(slab)
    da = np.minimum(np.linalg.norm(c - [0.02, 0.02, 0.01], axis=1), np.linalg.norm(c - [0.08, 0.02, 0.01], axis=1))
    db = np.linalg.norm(c - [0.05, 0.03, 0.005], axis=1)
    expected_a = (da <= db) & (da <= 0.015)
    expected_b = (db < da) & (db <= 0.02)
    np.testing.assert_array_equal(masks["a"], expected_a)
    np.testing.assert_array_equal(masks["b"], expected_b)
    assert masks["a"].sum() > 20 and masks["b"].sum() > 20
    assert not np.any(masks["a"] & masks["b"])


def test_landmark_regions_bad_input(slab):
    with pytest.raises(ValueError, match="no regions"):
        landmark_regions(slab, {}, 0.01)
    with pytest.raises(ValueError, match="radius of region 'a'"):
        landmark_regions(slab, {"a": [0, 0, 0]}, 0.0)
    with pytest.raises(ValueError, match="no radius for region 'b'"):
        landmark_regions(slab, {"a": [0, 0, 0], "b": [1, 0, 0]}, {"a": 0.01})
    with pytest.raises(ValueError, match="shape"):
        landmark_regions(slab, {"a": [0, 0]}, 0.01)


def test_kato_regions_partition_the_tets(slab):
    regions = kato_regions(slab, kato_points(), radius=0.01)
    assert list(regions) == list(KATO_REGIONS)
    stacked = np.stack(list(regions.values()))
    np.testing.assert_array_equal(stacked.sum(axis=0), 1)  # every tet in exactly one region
    for name in KATO_REGIONS:
        assert regions[name].sum() > 0, name
    # brute force: each tet's nearest region landmark, if within the radius, names its region
    lm = kato_points()
    names = ["cphs_L", "cphs_R", "ch_L", "ch_R", "cphi_L", "cphi_R", "al_L", "al_R"]
    region_of = ["cphs_L", "cphs_R", "cheilion", "cheilion", "cphi", "cphi", "alare", "alare"]
    d = np.linalg.norm(tet_centroids(slab)[:, None] - np.stack([lm[n] for n in names])[None], axis=2)
    nearest = np.argmin(d, axis=1)
    for i, region in enumerate(region_of):
        chosen = (nearest == i) & (d.min(axis=1) <= 0.01)
        assert np.all(regions[region][chosen])
    np.testing.assert_array_equal(regions["cheek"], d.min(axis=1) > 0.01)


@pytest.mark.parametrize("model", [1, 2, 3])
def test_kato_models_follow_the_tables(slab, model):
    lm = kato_points()
    regions = kato_regions(slab, lm, radius=0.01)
    material = kato_material_model(slab, lm, model, radius=0.01)
    assert isinstance(material, TissueMaterial) and material.tet_count == slab.tet_count
    for name in KATO_REGIONS:
        np.testing.assert_array_equal(material.E[regions[name]], KATO_MODELS[model]["E"][name])
        np.testing.assert_array_equal(material.eta[regions[name]], KATO_MODELS[model]["eta"][name])
    assert np.all(np.asarray(material.nu) == 0.495) and np.all(np.asarray(material.rho) == 1100.0)


def test_models_differ_only_at_the_right_cphs(slab):
    lm = kato_points()
    m1, m2, m3 = (kato_material_model(slab, lm, k) for k in (1, 2, 3))
    cphs_r = kato_regions(slab, lm)["cphs_R"]
    for other in (m2, m3):
        changed = (other.E != m1.E) | (other.eta != m1.eta)
        np.testing.assert_array_equal(changed, cphs_r)
    assert np.all(m2.E[cphs_r] == 205.6e3) and np.all(m3.E[cphs_r] == 92.2e3)
    assert np.all(m2.eta[cphs_r] == 427.8) and np.all(m3.eta[cphs_r] == 389.4)


def test_kato_material_from_ibug_points_and_bad_input(slab):
    # iBUG input goes through warpface.metrics.kato_landmarks
    rng = np.random.default_rng(0)
    ibug = rng.uniform([0, 0, 0.0], [0.1, 0.08, 0.01], (68, 3))
    from_ibug = kato_material_model(slab, ibug, 2)
    from_names = kato_material_model(slab, kato_landmarks(ibug), 2)
    np.testing.assert_array_equal(from_ibug.E, from_names.E)
    with pytest.raises(ValueError, match="model must be one of"):
        kato_material_model(slab, kato_points(), 4)
    lm = kato_points()
    del lm["al_L"]
    with pytest.raises(ValueError, match=r"\['al_L'\] for region 'alare' missing"):
        kato_material_model(slab, lm, 1)
    with pytest.raises(ValueError, match="nu"):
        kato_material_model(slab, kato_points(), 1, nu=0.5)
