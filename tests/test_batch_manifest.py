"""Batch manifests: the same takes from CSV, JSON and TOML; every bad manifest refused before any work, naming the
row, with nothing written (malformed CSV rows drawn by hypothesis)."""

from __future__ import annotations

import json
import sys

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from warpface.batch import read_manifest
from warpface.cli import main


@pytest.fixture
def folder(tmp_path):
    (tmp_path / "a.csv").write_text("Timecode,BlendshapeCount,BrowInnerUp\n00:00:00:01.000,52,0.1\n")
    (tmp_path / "takes").mkdir()
    (tmp_path / "takes" / "b.csv").write_text("x\n")
    return tmp_path


def test_csv_json_and_toml_give_the_same_takes(folder):
    (folder / "m.csv").write_text(
        "id,input,kind,options\n"
        "one,a.csv,animate,--fps 24 --no-video\n"
        'two,takes/b.csv,animate,"{""gain"": [""browInnerUp=2""], ""filter"": true}"\n'
    )
    document = {
        "defaults": {"kind": "animate", "options": {"no_video": True}},
        "takes": [
            {"id": "one", "input": "a.csv", "options": {"fps": 24}},
            {
                "id": "two",
                "input": "takes/b.csv",
                "options": {"gain": ["browInnerUp=2"], "filter": True, "no-video": False},
            },
        ],
    }
    (folder / "m.json").write_text(json.dumps(document))
    (folder / "m.toml").write_text(
        '[defaults]\nkind = "animate"\n\n[[take]]\nid = "one"\ninput = "a.csv"\noptions = "--fps 24 --no-video"\n\n'
        '[[take]]\nid = "two"\ninput = "takes/b.csv"\noptions = { gain = ["browInnerUp=2"], filter = true }\n'
    )
    forms = ["m.csv", "m.json"] + (["m.toml"] if sys.version_info >= (3, 11) else [])
    manifests = [read_manifest(folder / name) for name in forms]
    for manifest in manifests:
        one, two = manifest.takes
        assert (one.id, one.kind, one.input) == ("one", "animate", folder / "a.csv")
        assert two.input == folder / "takes" / "b.csv" and two.rig is None and two.mapping is None
        assert one.settings["fps"] == 24.0 and one.settings["no_video"] is True
        assert two.settings["gain"] == ["browInnerUp=2"] and two.settings["filter"] is True
        assert two.settings["no_video"] is False and two.settings["fps"] is None
    assert len({tuple(sorted(str(t.settings) for t in m.takes)) for m in manifests}) == 1


BAD = {
    "missing input": ("id,input,kind\nx,nowhere.csv,animate\n", "row 2 (take 'x'): input nowhere.csv: file not found"),
    "duplicate id": ("id,input,kind\nx,a.csv,animate\nx,a.csv,animate\n", "row 3 (take 'x'): duplicate take id"),
    "unknown kind": ("id,input,kind\nx,a.csv,paint\n", "row 2 (take 'x'): unknown kind 'paint'"),
    "unknown option": ("id,input,kind,options\nx,a.csv,animate,--colour red\n", "unknown option --colour"),
    "abbreviated option": ("id,input,kind,options\nx,a.csv,animate,--no-vid\n", "unknown option --no-vid"),
    "option of the batch": ("id,input,kind,options\nx,a.csv,animate,--out y.usda\n", "--out is set by the batch"),
    "bad option value": ("id,input,kind,options\nx,a.csv,track,--frames 0\n", "row 2 (take 'x'): options:"),
    "option for another kind": ("id,input,kind,options\nx,a.csv,animate,--frames 3\n", "unknown option --frames"),
    "missing column": ("id,kind\nx,animate\n", "lacks column 'input'"),
    "short row": ("id,input,kind\nx,a.csv\n", "row 2: 2 cells, the header has 3"),
    "bad id": ("id,input,kind\n../x,a.csv,animate\n", "take id '../x'"),
    "rig does not load": ("id,input,kind,rig\nx,a.csv,animate,broken.usda\n", "rig broken.usda: does not load"),
    "missing rig": ("id,input,kind,rig\nx,a.csv,animate,none.usda\n", "rig none.usda: file not found"),
    "fit without rig": ("id,input,kind\nx,a.csv,fit\n", "a fit take needs a rig"),
    "mapping on track": ("id,input,kind,mapping\nx,synthetic,track,m\n", "mapping applies to animate takes only"),
    "empty": ("id,input,kind\n", "no takes"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_manifests_are_refused_before_any_work(folder, case, capsys):
    text, fragment = BAD[case]
    (folder / "broken.usda").write_text("#usda 1.0\ndef Xform 'Face' {\n")
    manifest = folder / "m.csv"
    manifest.write_text(text)
    out = folder / "out"
    assert main(["--quiet", "--device", "cpu", "batch", str(manifest), "--out", str(out)]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and fragment in error and "m.csv" in error
    assert not out.exists()  # nothing written, not even the folder


def test_an_output_folder_that_is_a_file_is_refused(folder, capsys):
    (folder / "m.csv").write_text("id,input,kind\nx,a.csv,animate\n")
    (folder / "out").write_text("a file")
    assert main(["--quiet", "batch", str(folder / "m.csv"), "--out", str(folder / "out")]) == 2
    assert "is a file" in capsys.readouterr().err and (folder / "out").read_text() == "a file"


@pytest.mark.parametrize(
    ("name", "text", "fragment"),
    [
        ("m.json", '{"takes": [{"id": "x", "input": "a.csv", "kind": "animate", "colour": 1}]}', "take 1"),
        ("m.json", '{"takes": [{"id": "x", "input": "a.csv", "kind": "animate"}, {"id": "y"}]}', "take 2"),
        ("m.json", '{"takes": [', "not valid JSON"),
        ("m.json", '{"defaults": {"id": "x"}, "takes": []}', "defaults: unknown field 'id'"),
        ("m.json", '[{"id": 3, "input": "a.csv", "kind": "animate"}]', "id must be text"),
        ("m.toml", '[[take]]\nid = "x"\ninput = "a.csv"\nkind = "animate"\noptions = {fps = "fast"}\n', "take 1"),
        ("m.toml", "[[take]\n", "not valid TOML"),
        ("m.txt", "id,input,kind\n", "expected a .toml, .json or .csv"),
    ],
)
def test_bad_json_and_toml_manifests_name_the_take(folder, name, text, fragment):
    if name.endswith(".toml") and sys.version_info < (3, 11):
        pytest.skip("TOML manifests need Python 3.11 (tomllib) or tomli")
    (folder / name).write_text(text)
    with pytest.raises(ValueError) as error:
        read_manifest(folder / name)
    assert fragment in str(error.value) and "\n" not in str(error.value)


CELLS = st.sampled_from(
    ["x", "y", "a.csv", "nowhere.csv", "animate", "track", "fit", "synthetic", "--no-video", "--fps", "-1", "0",
     '"', "", " ", "{", '{"fps": 1}', "--frames 2", "a,b", "../a.csv", "é", "\x00"]
)  # fmt: skip


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rows=st.lists(st.lists(CELLS, min_size=0, max_size=5), min_size=0, max_size=4), options=st.booleans())
def test_malformed_csv_rows_give_a_one_line_error_naming_the_row_or_good_takes(folder, rows, options):
    header = "id,input,kind" + (",options" if options else "")
    lines = [header] + [",".join(row) for row in rows]
    manifest = folder / "fuzz.csv"
    manifest.write_text("\n".join(lines) + "\n")
    try:
        takes = read_manifest(manifest).takes
    except ValueError as error:
        message = str(error)
        assert "\n" not in message and "fuzz.csv" in message
        return
    assert takes and len({t.id for t in takes}) == len(takes)
    for take in takes:
        assert take.kind in ("animate", "track", "fit") and (take.input.exists() or str(take.input) == "synthetic")
