"""Offscreen previews: the mesh is visible and shaded, colours follow values, videos are complete."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import icosphere_like

from warpface import preview


@pytest.fixture(scope="module")
def sphere():
    return icosphere_like(20)


def test_render_shows_a_shaded_mesh_in_the_middle(tmp_path, sphere):
    points, triangles = sphere
    image = preview.render(points, triangles, tmp_path / "sphere.png", size=(160, 120))
    assert image.shape == (120, 160, 3) and image.dtype == np.uint8
    assert (tmp_path / "sphere.png").is_file()
    centre, corner = image[50:70, 70:90].astype(float), image[:10, :10].astype(float)
    assert np.all(corner == 255)  # white background
    assert centre.mean() < 250 and centre.std() > 0.5  # the sphere is there, and shaded (not flat)
    red_over_blue = image[40:80, 60:100, 0].astype(float).mean() / image[40:80, 60:100, 2].astype(float).mean()
    assert red_over_blue > 1.1  # skin colour


def test_heat_map_colours_follow_values(sphere):
    points, triangles = sphere
    hot_right = preview.render_heat_map(points, triangles, points[:, 0], size=(160, 120), cmap="coolwarm")
    assert hot_right.shape[1] > 160  # colour bar appended
    left, right = hot_right[40:80, 45:65].astype(float), hot_right[40:80, 95:115].astype(float)
    warmth = lambda patch: (patch[..., 0] - patch[..., 2]).mean()  # red minus blue, independent of shading
    assert warmth(right) > 40 and warmth(left) < -40  # warm on +x, cool on −x


def test_video_has_every_frame(tmp_path, sphere):
    import cv2

    points, triangles = sphere
    frames = [points * (1.0 + 0.1 * i) for i in range(5)]
    path = preview.write_video(frames, triangles, tmp_path / "anim.mp4", fps=10, size=(96, 64), progress=False)
    capture = cv2.VideoCapture(str(path))
    assert int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) == 5
    capture.release()
    assert not list(tmp_path.glob(".*partial*"))


def test_non_finite_points_are_refused(sphere):
    points, triangles = sphere
    bad = points.copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        preview.render(bad, triangles, size=(32, 32))


def test_no_gl_gives_one_line_naming_what_to_install(monkeypatch):
    from warpface import offscreen

    monkeypatch.delenv("PYOPENGL_PLATFORM", raising=False)
    monkeypatch.setattr(offscreen, "egl_works", lambda: False)
    monkeypatch.setattr(offscreen, "osmesa_usable", lambda: False)
    monkeypatch.delitem(__import__("sys").modules, "OpenGL.platform", raising=False)
    with pytest.raises(offscreen.OffscreenUnavailable, match="apt install libegl1") as error:
        offscreen.choose_platform()
    assert "\n" not in str(error.value)
    monkeypatch.setattr(offscreen, "egl_works", lambda: True)
    assert offscreen.choose_platform() == "egl"


def test_egl_is_probed_without_choosing_pyopengls_platform():
    import subprocess
    import sys

    probe = "import sys; from warpface import offscreen; offscreen.egl_works(); print('OpenGL.platform' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and result.stdout.strip() == "False"


def test_shared_heat_scale_and_clean_labels():
    assert preview.scale_label(8.68e-08, 15.0) == "0"
    assert preview.scale_label(15.0, 15.0) == "15.0"
    assert preview.scale_label(2.5, 5.0) == "2.50"
    low = preview.heat_colors(np.array([1.0]), vmin=0.0, vmax=10.0)
    high = preview.heat_colors(np.array([1.0]), vmin=0.0, vmax=2.0)
    assert not np.allclose(low, high)  # the colour follows the given scale, not the values' own range
