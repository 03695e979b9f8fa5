"""Bad WOMD records in closed loop (``rollout --womd``, WOMD suites): each scene is checked
as ``tap-bench ingest`` checks it, a bad one fails alone with an error naming the file, the
record, the track and the field, the others still run, and no table the contract refuses
leaves tap-bench; an empty file and seeds beyond the files are refused up front (exit 2); a
scenario held twice runs once, with a warning naming both files.

The files are WOMD ``Scenario`` TFRecords written with the project's own writer
(:mod:`tap_bench.womd.writer`), their map features appended as WOMD's map.proto encodes
them, and the bad values set in the decoded protos."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from womd_records import record, set_state, set_time, straight_lane, straight_scene, womd_file

import tap_bench  # noqa: F401  (registers the envs)
from tap_bench.cli import main
from tap_bench.errors import ParameterError
from tap_bench.sim.rollout import rollout
from tap_bench.sim.womd_scene import SceneError, WomdScenes, scene_catalog
from tap_bench.trajectories import validate_trajectories

# what is spoilt -> what the error names (the track, the column, the problem)
BAD = {
    "nan-x": (set_state(0, 30, center_x=float("nan")), r"track_id='1'.*\bx\b|x.*track_id='1'"),
    "inf-y": (set_state(1, 50, center_y=float("inf")), r"track_id='2'"),
    "far-off": (set_state(1, 5, center_x=1e300), r"track_id='2'.*1e\+?300|1e\+?300"),
    "nan-heading": (set_state(0, 60, heading=float("nan")), r"track_id='1'"),
    "nan-time": (set_time(40, float("nan")), r"\bt\b"),
    "backward-time": (set_time(41, 3.95), r"\bt\b"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_record_fails_alone_naming_file_record_track_and_field(tmp_path, case, capsys):
    spoil, named = BAD[case]
    path = womd_file(tmp_path / "scenes.tfrecord", record(straight_scene("good")),
                     record(straight_scene("bad"), spoil=spoil),
                     record(straight_scene("also-good", angle=-2.0), lane=straight_lane(-2.0)))
    out = tmp_path / "idm.parquet"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        code = main(["rollout", "--womd", path, "--policy", "idm", "-o", str(out),
                     "--no-progress"])
    assert code == 0
    err = capsys.readouterr().err
    episodes = pd.read_parquet(tmp_path / "idm.episodes.parquet")
    status = dict(zip(episodes["seed"], episodes["status"], strict=True))
    assert status == {0: "ok", 1: "error", 2: "ok"}
    message = episodes.loc[episodes["seed"] == 1, "error"].iloc[0]
    assert "scenes.tfrecord: record 1 at byte" in message, message
    assert "trajectory contract" in message and "'bad'" in message, message
    import re

    assert re.search(named, message), message
    assert "seed 1 failed" in err
    table = pd.read_parquet(out)
    assert set(table["scenario_id"]) == {"good", "also-good"}
    validate_trajectories(table)  # nothing leaves that the contract refuses


def test_the_bad_records_fail_in_a_suite_and_the_rest_run(tmp_path):
    from tap_bench.bench.run.runner import run_suite
    from tap_bench.bench.suite import suite_from_dict

    path = womd_file(tmp_path / "scenes.tfrecord", record(straight_scene("good")),
                     record(straight_scene("bad"), spoil=set_state(0, 30, center_x=1e300)))
    suite = suite_from_dict({"name": "bad", "envs": [{"womd": path}], "policies": ["log", "idm"],
                             "reference_policy": "log", "seeds": "all",
                             "bootstrap": {"n_resamples": 200}})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_suite(suite, tmp_path / "run", workers=1, progress=False,
                           report=False)  # the tables only: no page or viewer read
    eps = result.episodes
    assert set(eps.loc[eps["status"] == "ok", "seed"]) == {0}
    failed = eps[eps["status"] != "ok"]
    assert len(failed) == 2 and failed["error"].str.contains("record 1 at byte").all()
    assert (eps.loc[eps["status"] == "ok", "log_ade"].fillna(0) < 1e3).all()
    validate_trajectories(pd.read_parquet(tmp_path / "run" / "trajectories.parquet"))


def test_lanes_whose_points_coincide_are_built_or_left_out(tmp_path, capsys):
    lane = straight_lane()
    path = womd_file(tmp_path / "lanes.tfrecord",
                     record(straight_scene("clean"), lane=lane),
                     record(straight_scene("repeated"), lane=np.repeat(lane, 3, axis=0)),
                     record(straight_scene("one-point"), lane=np.repeat(lane[:1], 40, axis=0)))
    out = tmp_path / "idm.parquet"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        code = main(["rollout", "--womd", path, "--policy", "idm", "-o", str(out),
                     "--no-progress"])
    assert code == 0
    rows = pd.read_parquet(tmp_path / "idm.episodes.parquet").set_index("seed")
    # every point three times: the same lane, the same drive
    assert (rows.loc[[0, 1], "status"] == "ok").all()
    assert rows.loc[0, "route_progress"] > 0.9
    for measure in ("route_progress", "log_ade", "mean_speed"):
        assert rows.loc[1, measure] == pytest.approx(rows.loc[0, measure], abs=1e-6), measure
    # a lane of one distinct point is no road: the scene says so and what to do
    assert rows.loc[2, "status"] == "error"
    assert "one-point" in rows.loc[2, "error"] and "no lanes" in rows.loc[2, "error"]
    assert "lanes.tfrecord record 2" in rows.loc[2, "error"]


def test_an_empty_file_is_refused_up_front(tmp_path, capsys):
    empty = tmp_path / "empty.tfrecord"
    empty.write_bytes(b"")
    code = main(["rollout", "--womd", str(empty), "--policy", "idm",
                 "-o", str(tmp_path / "x.parquet"), "--no-progress"])
    assert code == 2
    err = capsys.readouterr().err
    assert "empty.tfrecord" in err and "no scenario in this file" in err
    assert not (tmp_path / "x.parquet").exists()
    assert not (tmp_path / "x.episodes.parquet").exists()


def test_seeds_beyond_the_files_are_refused_up_front(tmp_path, capsys):
    path = womd_file(tmp_path / "two.tfrecord", record(straight_scene("a")),
                     record(straight_scene("b")))
    code = main(["rollout", "--womd", path, "--policy", "idm", "--seeds", "0-4",
                 "-o", str(tmp_path / "x.parquet"), "--no-progress"])
    assert code == 2
    err = capsys.readouterr().err
    assert "seeds 2, 3, 4: beyond the 2 scenario(s)" in err and "two.tfrecord" in err
    assert not (tmp_path / "x.episodes.parquet").exists()
    with pytest.raises(ParameterError, match="seeds 7: beyond"):
        rollout(WomdScenes((path,)), "idm", [0, 7])
    from tap_bench.bench.suite import suite_from_dict
    from tap_bench.errors import FileFormatError

    with pytest.raises(FileFormatError, match="seeds 5: beyond the 2"):
        suite_from_dict({"name": "s", "envs": [{"womd": path}], "policies": ["idm"],
                         "seeds": [0, 5]})


def test_a_scenario_held_twice_runs_once_with_a_warning_naming_both_files(tmp_path):
    a = womd_file(tmp_path / "a.tfrecord", record(straight_scene("s1")))
    b = womd_file(tmp_path / "b.tfrecord", record(straight_scene("s2")),
                  record(straight_scene("s1")))
    with pytest.warns(UserWarning, match=r"scenario s1 is in .*a\.tfrecord record 0 and "
                                         r"again in .*b\.tfrecord record 1"):
        refs = scene_catalog([a, b])
    assert [(Path(r.path).name, r.record) for r in refs] == [("a.tfrecord", 0),
                                                              ("b.tfrecord", 0)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = rollout(WomdScenes((a, b)), "idm", "all")
    assert sorted(result.episodes["scenario_id"]) == ["s1", "s2"]
    validate_trajectories(result.trajectories)  # no duplicate rows


def test_a_folder_leaves_out_what_is_not_womd(tmp_path, capsys):
    folder = tmp_path / "data"
    folder.mkdir()
    womd_file(folder / "scenes.tfrecord", record(straight_scene("s1")))
    (folder / "README.md").write_text("# my scenes\n")
    out = tmp_path / "log.parquet"
    with pytest.warns(UserWarning, match="README.md: skipped"):
        code = main(["rollout", "--womd", str(folder / "*"), "--policy", "log", "-o", str(out),
                     "--no-progress"])
    assert code == 0
    assert set(pd.read_parquet(out)["scenario_id"]) == {"s1"}
    empty = tmp_path / "nothing.tfrecord"  # named on its own: refused, not left out
    empty.write_bytes(b"")
    with pytest.raises(SceneError, match=r"nothing\.tfrecord: no scenario in this file"):
        scene_catalog([str(empty)])


def test_a_suite_over_a_folder_leaves_out_what_is_not_womd(tmp_path):
    from tap_bench.bench.run.runner import run_suite
    from tap_bench.bench.suite import suite_from_dict

    folder = tmp_path / "data"
    folder.mkdir()
    womd_file(folder / "scenes.tfrecord", record(straight_scene("s1")))
    (folder / "README.md").write_text("# my scenes\n")
    suite = suite_from_dict({"name": "folder", "envs": [{"womd": str(folder / "*")}],
                             "policies": ["log", "idm"], "reference_policy": "log",
                             "seeds": "all", "bootstrap": {"n_resamples": 200}})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = run_suite(suite, tmp_path / "run", workers=1, progress=False)
    assert (result.episodes["status"] == "ok").all(), result.episodes["error"].tolist()
    roads = pd.read_parquet(tmp_path / "run" / "roads.parquet")
    assert set(roads["map_id"]) == {"s1"}
    assert (tmp_path / "run" / "viewer" / "index.html").is_file()
    # the viewer reads the files again for the signals, as the run read them
    assert not [w for w in caught if "could not be read again" in str(w.message)]
