"""The workflow a researcher runs on real scenes: ``rollout --womd`` tables of a policy and
of the human compare with ``tap-bench compare`` and open side by side in ``tap-bench view``,
paired by scenario id, also when the two rollouts read the files in another order; the
example suite that ships reads the real scenes by a relative glob."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import pandas as pd
import pytest
from womd_records import record, straight_lane, straight_scene, womd_file

from tap_bench.cli import main


def scene_files(tmp_path: Path) -> tuple[str, str]:
    """Two WOMD files of three scenes (two headings, one with a slower car ahead)."""
    a = womd_file(tmp_path / "a.tfrecord", record(straight_scene("s-east", angle=0.0),
                                                  lane=straight_lane(0.0)),
                  record(straight_scene("s-north", angle=1.6), lane=straight_lane(1.6)))
    b = womd_file(tmp_path / "b.tfrecord", record(straight_scene("s-west", angle=3.0),
                                                  lane=straight_lane(3.0)))
    return a, b


def rollout_cli(files: list[str], policy: str, out: Path) -> str:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["rollout", "--womd", *files, "--policy", policy, "-o", str(out),
                     "--no-progress"]) == 0
    return str(out)


def viewer_index(folder: Path) -> dict:
    text = (folder / "data" / "index.js").read_text()
    return json.loads(text[len("TAPVIEW.index("):-len(");\n")])


def test_a_policy_and_the_human_compare_and_view_paired_by_scenario(tmp_path, capsys):
    a, b = scene_files(tmp_path)
    human = rollout_cli([a, b], "log", tmp_path / "human.parquet")
    idm = rollout_cli([a, b], "idm", tmp_path / "idm.parquet")
    capsys.readouterr()
    assert main(["compare", idm, human, "-o", str(tmp_path / "cmp")]) == 0
    out = capsys.readouterr().out
    assert "womd: 3 seeds paired" in out
    episodes = pd.read_parquet(tmp_path / "cmp" / "episodes.parquet")
    ids = set(episodes["scenario_id"])
    assert ids == {f"{s}/{p}" for s in ("s-east", "s-north", "s-west") for p in ("log", "idm")}
    assert main(["view", human, idm, "-o", str(tmp_path / "tv"), "--no-open"]) == 0
    index = viewer_index(tmp_path / "tv")
    pairs = {(e["seed"], e["policy"]): e["id"] for e in index["episodes"]}
    for seed in range(3):  # the same seed is the same scenario in both tables
        assert pairs[seed, "log"].split("/")[0] == pairs[seed, "idm"].split("/")[0]
    assert all(e["map"] is None for e in index["episodes"])  # the tables name no files
    assert main(["view", human, idm, "-o", str(tmp_path / "tm"), "--no-open",
                 "--maps", str(tmp_path / "*.tfrecord")]) == 0
    index = viewer_index(tmp_path / "tm")
    assert {"s-east", "s-north", "s-west"} <= set(index["maps"])
    assert all(e["map"] == e["id"].split("/")[0] for e in index["episodes"])
    assert all(index["maps"][name] for name in ("s-east", "s-north", "s-west"))
    assert main(["view", str(tmp_path / "cmp"), "-o", str(tmp_path / "cv"), "--no-open"]) == 0


def test_rollouts_of_the_files_in_another_order_pair_by_scenario(tmp_path, capsys):
    a, b = scene_files(tmp_path)
    one = rollout_cli([a, b], "log", tmp_path / "one.parquet")  # s-east, s-north, s-west
    two = rollout_cli([b, a], "log", tmp_path / "two.parquet")  # s-west, s-east, s-north
    capsys.readouterr()
    assert main(["compare", one, two, "--names", "first", "second",
                 "-o", str(tmp_path / "cmp")]) == 0
    captured = capsys.readouterr()
    assert "number the recorded scenes differently" in captured.err
    assert "one.parquet" in captured.err and "two.parquet" in captured.err
    episodes = pd.read_parquet(tmp_path / "cmp" / "episodes.parquet")
    seeds = episodes.groupby("seed")["scenario_id"].apply(
        lambda ids: sorted({i.split("/")[0] for i in ids}))
    assert all(len(v) == 1 for v in seeds), seeds  # each seed is one scenario
    # the human against itself, scene by scene: the same label everywhere, no difference
    paired = pd.read_parquet(tmp_path / "cmp" / "paired.parquet")
    assert paired["n_pairs"].iloc[0] == 3 and paired["agreement"].iloc[0] == 1.0
    measures = pd.read_parquet(tmp_path / "cmp" / "paired_measures.parquet")
    assert (measures["diff"].fillna(0).abs() < 1e-9).all(), measures


def test_the_example_suite_for_real_scenes_reads_them_by_a_relative_glob(womd_dir,
                                                                          monkeypatch):
    from tap_bench.bench.suite import load_suite
    from tap_bench.sim import womd_scene

    monkeypatch.setattr(womd_scene, "_NOTED", set())  # the README is noted once a process
    dev = womd_dir.parent / "womd-dev" / "dev.tfrecord"
    with pytest.warns(UserWarning, match="README.md: skipped"):
        suite = load_suite("womd-sample")
    assert suite.envs == ("womd",) and suite.reference_policy == "log"
    assert set(suite.policies) == {"log", "idm"}
    scenes = suite.scenes["womd"]
    assert all(not Path(f).is_absolute() or ".." in f for f in scenes.files)
    n = 4 + (12 if dev.is_file() else 0)
    assert suite.env_seeds("womd") == tuple(range(n))
