"""``tap-bench view``: writes the viewer of a run or of WOMD files; refuses a run without
trajectories with the fix."""

from __future__ import annotations

import shutil

import pytest

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


def _index(folder) -> dict:
    import json

    text = (folder / "data" / "index.js").read_text()
    return json.loads(text[len("TAPVIEW.index("):-len(");\n")])


def _rollout_tables(tiny_run, tmp_path) -> list[str]:
    """The tiny run's trajectories as two rollout tables (``tap-bench rollout`` output),
    one per policy."""
    import pandas as pd

    traj = pd.read_parquet(tiny_run / "trajectories.parquet")
    paths = []
    for policy in ("random", "idm"):
        path = tmp_path / f"{policy}.parquet"
        traj[traj["policy"] == policy].to_parquet(path, index=False)
        paths.append(str(path))
    return paths


def test_view_puts_two_rollout_tables_side_by_side(tiny_run, tmp_path, capsys):
    a, b = _rollout_tables(tiny_run, tmp_path)
    out = tmp_path / "tv"
    assert main(["view", a, b, "-o", str(out), "--no-open"]) == 0
    assert "viewer: " in capsys.readouterr().out
    index = _index(out)
    assert index["run"]["reference"] == "idm"  # the last table is the reference
    episodes = {(e["env"], e["policy"], e["seed"]) for e in index["episodes"]}
    assert episodes == {(env, policy, seed) for env in ("highway", "roundabout")
                        for policy in ("random", "idm") for seed in range(3)}
    # one chunk per (env, seed) holding both policies' episodes, and each env's road
    assert len(list((out / "data").glob("*.js"))) == 1 + 2 * 3
    assert set(index["maps"]) == {"highway", "roundabout"} and all(index["maps"].values())
    assert all(e["map"] == e["env"] for e in index["episodes"])


def test_view_opens_compare_output(tiny_run, tmp_path, capsys):
    a, b = _rollout_tables(tiny_run, tmp_path)
    cmp = tmp_path / "cmp"
    assert main(["compare", a, b, "-o", str(cmp)]) == 0
    assert (cmp / "trajectories.parquet").is_file() and (cmp / "roads.parquet").is_file()
    capsys.readouterr()
    out = tmp_path / "cv"
    assert main(["view", str(cmp), "-o", str(out), "--rebuild", "--no-open"]) == 0
    index = _index(out)
    assert {e["policy"] for e in index["episodes"]} == {"random", "idm"}
    assert set(index["maps"]) == {"highway", "roundabout"}
    assert main(["view", str(cmp), "--no-open"]) == 0  # the viewer compare wrote
    assert (cmp / "viewer" / "index.html").is_file()


def test_view_refuses_a_label_table_and_mixed_inputs(tiny_run, tmp_path, capsys):
    import pandas as pd

    a, _ = _rollout_tables(tiny_run, tmp_path)
    labels = str(tmp_path / "idm_labels.parquet")
    table = pd.read_parquet(tiny_run / "labels.parquet")
    table[table["policy"] == "idm"].to_parquet(labels, index=False)
    assert main(["view", a, labels, "-o", str(tmp_path / "x"), "--no-open"]) == 2
    assert "a label table, no trajectories to replay" in capsys.readouterr().err
    assert main(["view", a, str(tiny_run), "--no-open"]) == 2
    assert "a table among other inputs" in capsys.readouterr().err


def test_view_of_a_womd_glob_leaves_a_readme_out(womd_dir, tmp_path, capsys):
    """A folder of WOMD files with a README.md (as Waymo's downloads and ours have): the
    glob's README is left out with a note, as ingest does."""
    data = tmp_path / "womd"
    data.mkdir()
    (data / "womd_scenario_input.tfrecord").symlink_to(womd_dir / "womd_scenario_input.tfrecord")
    (data / "README.md").write_text("# Real Waymo samples\n")
    out = tmp_path / "w"
    with pytest.warns(UserWarning, match="README.md: skipped"):
        assert main(["view", str(data / "*"), "-o", str(out), "--no-open"]) == 0
    assert (out / "data" / "ee519cf571686d19.js").is_file()
