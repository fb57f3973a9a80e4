"""Bad landmark input is one clear line: wrong count, type, range, repeated vertices, wrong order (issue 24)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from warpface.assets import default_face, default_landmarks
from warpface.cli import main
from warpface.rigging import landmarks_from_values

VERTICES = 500
POINTS = np.random.default_rng(0).normal(size=(VERTICES, 3))

entries = st.one_of(
    st.integers(min_value=-(10**9), max_value=10**9),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=3),
    st.booleans(),
    st.none(),
    st.lists(st.floats(allow_nan=False, allow_infinity=False, width=32), min_size=0, max_size=4),
)


@settings(max_examples=150, deadline=None)
@given(st.lists(entries, min_size=0, max_size=80))
def test_any_list_either_gives_68_distinct_enough_vertices_or_one_line_naming_the_input(values):
    try:
        indices = landmarks_from_values(values, POINTS, "marks.json")
    except (TypeError, ValueError) as exc:
        message = str(exc)
        assert message.startswith("marks.json: ") and "\n" not in message
        return
    assert indices.shape == (68,) and indices.dtype == np.int64
    assert indices.min() >= 0 and indices.max() < VERTICES
    assert np.bincount(indices).max() <= 2


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, VERTICES - 1), min_size=68, max_size=68, unique=True), st.data())
def test_a_vertex_named_by_three_landmarks_is_refused_naming_them(indices, data):
    chosen = data.draw(st.lists(st.integers(0, 67), min_size=3, max_size=6, unique=True))
    repeated = list(indices)
    for k in chosen:
        repeated[k] = indices[chosen[0]]
    with pytest.raises(ValueError, match=rf"name the same vertex {indices[chosen[0]]}; give each landmark its own"):
        landmarks_from_values(repeated, POINTS, "marks.json")
    two = list(indices)
    two[chosen[1]] = indices[chosen[0]]  # two landmarks on one vertex (mouth corners of a coarse mesh) are fine
    assert landmarks_from_values(two, POINTS).tolist() == two


@pytest.fixture(scope="module")
def face_obj(tmp_path_factory):
    face = default_face()
    path = tmp_path_factory.mktemp("head") / "face.obj"
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in 100.0 * face.points]
    path.write_text("\n".join(lines + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in face.triangles]) + "\n")
    return path


MARKS = default_landmarks()


@pytest.mark.parametrize(
    ("content", "fragment"),
    [
        (MARKS[:67].tolist(), "expected 68 iBUG landmarks, got 67"),
        ([str(v) for v in MARKS], "must be numbers"),
        ([True] * 68, "must be numbers"),
        ((MARKS + 0.5).tolist(), "whole numbers"),
        ([-1, *MARKS[1:].tolist()], "vertex index -1"),
        ([int(MARKS[0])] * 68, "name the same vertex"),
        ({"a": 1}, "no 'landmarks'"),
        ([[0.0, 0.0, 0.0]] * 68, "off the mesh"),
        (MARKS[::-1].tolist(), "not in iBUG order"),
        (np.r_[MARKS[0:36], MARKS[42:48], MARKS[36:42], MARKS[48:68]].tolist(), "iBUG 36–41 are right of 42–47"),
    ],
)
def test_warpface_rig_refuses_bad_landmark_files_in_one_line(face_obj, tmp_path, capsys, content, fragment):
    marks = tmp_path / "marks.json"
    marks.write_text(json.dumps(content))
    out = tmp_path / "rig.usda"
    assert main(["--quiet", "rig", str(face_obj), "--landmarks", str(marks), "--out", str(out)]) == 2
    error = capsys.readouterr().err.strip()
    assert fragment in error and "\n" not in error
    assert sorted(p.name for p in tmp_path.iterdir()) == ["marks.json"]
