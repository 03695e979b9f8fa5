"""OpenLABEL export: valid against the ASAM OpenLABEL 1.0.0 JSON schema (shipped in
tests/data, no download) and readable back into the same segment table."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tap_bench.cli import main
from tap_bench.errors import FileFormatError, LabelTableError
from tap_bench.labelling import tap
from tap_bench.openlabel import read_openlabel, to_openlabel, write_openlabel

jsonschema = pytest.importorskip("jsonschema")
SCHEMA = json.loads((Path(__file__).resolve().parents[1] / "data"
                     / "openlabel_json_schema-v1.0.0.json").read_text())
T = np.round(np.arange(80) / 10, 10)


def cut_in_scene(sid: str = "scene/1") -> pd.DataFrame:
    u = np.clip((T - 2) / 3, 0, 1)
    y = 2 + 2 * np.cos(np.pi * u)
    dy = np.gradient(y, T)
    ego = pd.DataFrame({"track_id": "ego", "t": T, "x": 15 * T, "y": 0.0, "heading": 0.0,
                        "speed": 15.0, "is_ego": True})
    cut = pd.DataFrame({"track_id": "cutter", "t": T, "x": 20 + 15 * T, "y": y,
                        "heading": np.arctan2(dy, 15), "speed": np.hypot(15, dy),
                        "is_ego": False})
    return pd.concat([ego, cut], ignore_index=True).assign(scenario_id=sid,
                                                           object_type="vehicle")


def segments() -> pd.DataFrame:
    scene = pd.concat([cut_in_scene("scene/1"), cut_in_scene("scene/2")], ignore_index=True)
    return tap(scene, interactions="ego").segments("maneuver")


def test_export_is_valid_openlabel_and_reads_back():
    segs = segments()
    docs = to_openlabel(segs)
    assert set(docs) == {"scene/1", "scene/2"}
    validator = jsonschema.Draft7Validator(SCHEMA)
    for doc in docs.values():
        errors = sorted(validator.iter_errors(doc), key=str)
        assert not errors, errors[0].message
    ol = docs["scene/1"]["openlabel"]
    cut = [a for a in ol["actions"].values() if a["type"] == "Cut-in"]
    assert len(cut) == 1 and cut[0]["frame_intervals"][0]["frame_start"] == 26
    back = read_openlabel(docs.values())
    cols = ["scenario_id", "track_id", "axis", "label", "t_start", "t_end", "other_track_id"]
    expect = segs[cols].astype({"other_track_id": "string"}).reset_index(drop=True)
    got = back[cols].sort_values(["scenario_id"], kind="stable").reset_index(drop=True)
    pd.testing.assert_frame_equal(got.astype(str), expect.astype(str))
    assert (back["level"] == "maneuver").all()
    named = back[back["label"] == "Cut-in"]
    assert list(named["other_track_id"]) == ["cutter", "cutter"]


def test_the_schema_catches_a_broken_document():
    doc = to_openlabel(segments())["scene/1"]
    del doc["openlabel"]["metadata"]["schema_version"]
    assert list(jsonschema.Draft7Validator(SCHEMA).iter_errors(doc))


def test_cli_export_writes_files_and_errors(tmp_path, capsys):
    src = tmp_path / "t.parquet"
    pd.concat([cut_in_scene("a"), cut_in_scene("b")], ignore_index=True).to_parquet(src)
    out = tmp_path / "ol"
    assert main(["export", str(src), "--format", "openlabel", "-o", str(out)]) == 0
    files = sorted(out.glob("*.json"))
    assert [f.name for f in files] == ["a.json", "b.json"]
    for f in files:
        jsonschema.validate(json.loads(f.read_text()), SCHEMA)
    assert len(read_openlabel(out)) > 0
    with pytest.raises(FileFormatError, match="directory"):
        write_openlabel(segments(), tmp_path / "one.json")
    with pytest.raises(LabelTableError, match="segment table"):
        to_openlabel(pd.DataFrame({"scenario_id": ["s"]}))
    bad = tmp_path / "bad.json"
    bad.write_text('{"x": 1}')
    with pytest.raises(FileFormatError, match="not an OpenLABEL"):
        read_openlabel(bad)


@pytest.mark.parametrize("level", ["action", "maneuver"])
def test_cli_export_takes_the_level_label_wrote(tmp_path, capsys, level):
    """``label --segments`` then ``export`` agree on the level without ``--level``."""
    src = tmp_path / "t.parquet"
    cut_in_scene("a").to_parquet(src)
    seg = tmp_path / "segments.parquet"
    assert main(["label", str(src), "-o", str(tmp_path / "labels.parquet"), "--level", level,
                 "--interactions", "all", "--segments", str(seg)]) == 0
    out = tmp_path / "ol"
    assert main(["export", str(seg), "--format", "openlabel", "-o", str(out)]) == 0
    assert f"at level {level}" in capsys.readouterr().out
    assert set(read_openlabel(out)["level"]) == {level}
    other = "maneuver" if level == "action" else "action"
    # asking for a level the table lacks still fails clearly
    assert main(["export", str(seg), "--format", "openlabel", "-o", str(tmp_path / "o2"),
                 "--level", other]) == 2
    assert f"no rows at level '{other}'" in capsys.readouterr().err
