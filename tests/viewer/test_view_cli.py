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
    assert [e["name"] for e in _index(out)["episodes"]] == ["scenario ee519cf571686d19"]


def test_an_older_run_without_segments_or_roads_is_relabelled(tiny_run, tmp_path):
    import json

    from tap_bench.bench.run.runner import run_viewer

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


def _recorded_tables(two_cars_and_a_walker, tmp_path) -> list[str]:
    """Two hand-made ``rollout --womd`` tables (source ``womd-sim``), policies ``idm`` and
    ``log``, each driving the same two scenes under WOMD-like scenario ids, seeds 0 and 1."""
    table = two_cars_and_a_walker.copy()
    table.loc[table["scenario_id"] == "s2", "is_ego"] = True  # each scene has its ego
    womd = {"s1": "a1b2c3d4e5f60718", "s2": "0f1e2d3c4b5a6978"}
    table["seed"] = table["scenario_id"].map({"s1": 0, "s2": 1})
    table["scenario_id"] = table["scenario_id"].map(womd)
    paths = []
    for policy in ("idm", "log"):
        path = tmp_path / f"{policy}.parquet"
        table.assign(env="womd", policy=policy, source="womd-sim").to_parquet(path,
                                                                              index=False)
        paths.append(str(path))
    return paths


def test_the_viewer_names_real_scene_episodes_by_scenario_id(two_cars_and_a_walker,
                                                             tmp_path, capsys):
    """On real scenes an episode is paired by scenario id (SPEC section 8), so the viewer
    names it by that id ("scenario <id>", not "womd · seed N"), for rollout tables and for
    the run folder compare writes of them; the names the page shows come from the index."""
    a, b = _recorded_tables(two_cars_and_a_walker, tmp_path)
    out = tmp_path / "tv"
    assert main(["view", a, b, "-o", str(out), "--no-open"]) == 0
    cmp = tmp_path / "cmp"
    assert main(["compare", a, b, "-o", str(cmp)]) == 0
    assert main(["view", str(cmp), "-o", str(tmp_path / "cv"), "--rebuild",
                 "--no-open"]) == 0
    capsys.readouterr()
    for folder in (out, tmp_path / "cv"):
        names = {(e["policy"], e["name"]) for e in _index(folder)["episodes"]}
        assert names == {(policy, f"scenario {sid}") for policy in ("idm", "log")
                         for sid in ("a1b2c3d4e5f60718", "0f1e2d3c4b5a6978")}
    script = (out / "viewer.js").read_text()
    assert "e.name" in script and "seed ${e.seed}" not in script  # the page shows them


def test_highway_episodes_keep_env_and_seed_names(tiny_run, tmp_path, capsys):
    a, b = _rollout_tables(tiny_run, tmp_path)
    out = tmp_path / "tv"
    assert main(["view", a, b, "-o", str(out), "--no-open"]) == 0
    for e in _index(out)["episodes"]:
        assert e["name"] == f"{e['env']} · seed {e['seed']}"


def test_a_womd_suites_run_names_its_episodes_by_scenario_id(womd_dir, tmp_path):
    """A bench run of a WOMD suite (the run folder the viewer is built from): each policy's
    episode is named by the real scene's scenario id."""
    import warnings

    from tap_bench.bench.run.runner import run_suite
    from tap_bench.bench.suite import suite_from_dict

    suite = suite_from_dict({
        "name": "womd-names", "envs": [{"womd": [str(womd_dir / "womd_scenario_input.tfrecord")],
                                        "traffic": "log"}],
        "policies": ["idm", "log"], "reference_policy": "log", "seeds": "all",
        "bootstrap": {"n_resamples": 200}}, source="womd-names")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        folder = run_suite(suite, tmp_path / "run", workers=1, progress=False).folder
    names = {(e["policy"], e["name"]) for e in _index(folder / "viewer")["episodes"]}
    assert names == {("idm", "scenario ee519cf571686d19"), ("log", "scenario ee519cf571686d19")}
