"""``tap-bench view``: writes the viewer of a run or of WOMD files; refuses a run without
trajectories with the fix."""

from __future__ import annotations

import shutil

from tap_bench.cli import main


def test_view_writes_a_runs_viewer(tiny_run, tmp_path, capsys):
    out = tmp_path / "v"
    assert main(["view", str(tiny_run), "-o", str(out), "--no-open"]) == 0
    printed = capsys.readouterr().out
    assert (out / "index.html").is_file() and (out / "data" / "index.js").is_file()
    assert f"viewer: {(out / 'index.html').resolve().as_uri()}" in printed
    # every (env, seed) of the run is one data chunk holding each policy's episode
    assert len(list((out / "data").glob("*.js"))) == 1 + 2 * 3


def test_view_refuses_a_run_without_trajectories(tiny_run, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run, ignore=shutil.ignore_patterns("trajectories.parquet",
                                                                  "viewer"))
    assert main(["view", str(run), "--no-open"]) == 2
    err = capsys.readouterr().err
    assert "no trajectories.parquet to replay" in err and "--no-trajectories" in err


def test_view_writes_womd_scenarios(womd_dir, tmp_path, capsys):
    out = tmp_path / "w"
    files = [str(womd_dir / "womd_scenario_input.tfrecord")]
    assert main(["view", *files, "-o", str(out), "--no-open"]) == 0
    assert (out / "data" / "ee519cf571686d19.js").is_file()


def test_an_older_run_without_segments_or_roads_is_relabelled(tiny_run, tmp_path):
    import json

    from tap_bench.bench.runner import run_viewer

    run = tmp_path / "old"
    shutil.copytree(tiny_run, run, ignore=shutil.ignore_patterns("segments.parquet",
                                                                  "roads.parquet", "viewer"))
    page = run_viewer(run)
    fresh = (tiny_run / "viewer" / "data" / "highway-0.js").read_text()
    again = (page.parent / "data" / "highway-0.js").read_text()
    assert again == fresh  # the egos' labels and the roads are built again, identically
    index = (page.parent / "data" / "index.js").read_text()
    doc = json.loads(index[len("TAPVIEW.index("):-len(");\n")])
    assert set(doc["maps"]) == {"highway", "roundabout"} and all(doc["maps"].values())
