"""The runner labels and measures a recorded (WOMD) scene along the lanes of its own map (SPEC
7: the path beyond the record goes on along the ego's lane where there is a map), through the
same code path as a highway-env road; the label cache key says so. On the real sample files
(skipped when absent)."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.cache import SCENE_MAP
from tap_bench.bench.measures import ego_measures
from tap_bench.bench.run import tasks as run_tasks
from tap_bench.bench.run.plan import _Task, _tasks, plan_suite
from tap_bench.bench.suite import suite_from_dict
from tap_bench.labelling import tap
from tap_bench.sim.rollout import resolve_policy, rollout
from tap_bench.sim.womd_scene import WomdScenes, load_scene, scene_catalog
from tap_bench.sources.maps import read_maps
from tap_bench.thresholds import resolve_thresholds

EGO_LENGTH = 4.8  # the default length of a track whose table has no length column


def _task(scenes: WomdScenes, policy: str = "log", seed: int = 0) -> _Task:
    return _Task("womd", scenes, policy, resolve_policy(policy), seed,
                 resolve_thresholds("paper"), "maneuver", False)


def _row(seed: int, policy: str) -> dict:
    return {"env": "womd", "policy": policy, "seed": seed, "return": 0.0, "length": 1,
            "duration_s": 1.0, "crashed": False, "mean_speed": 5.0, "terminated": False,
            "truncated": True, "status": "ok", "error": ""}


def _label_in_the_runner(scenes: WomdScenes, table: pd.DataFrame, policy: str = "log",
                         seed: int = 0) -> dict:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run_tasks._label_together((_task(scenes, policy, seed),),
                                         [(table, _row(seed, policy), False, 1.0, None)])[0]


def _cut_short(scene, end: int, gap: float) -> tuple[pd.DataFrame, float]:
    """The scene's ego (its recorded motion) with its record cut at step ``end``, and a car
    standing where the ego was ``gap`` m further along its recorded path (on its lane, in
    the turn it drove). Ids as in a run (``<WOMD id>/log``). Returns the table and the
    bumper gap at the last step over the ego's speed there [s]."""
    e = scene.ego
    x, y, h, v = scene.x[e], scene.y[e], scene.heading[e], scene.speed[e]
    driven = np.r_[0.0, np.cumsum(np.hypot(np.diff(x), np.diff(y)))]
    at = int(np.searchsorted(driven, driven[end] + gap))
    n = end + 1
    ids = {"scenario_id": f"{scene.scenario_id}/log", "womd_scenario_id": scene.scenario_id,
           "env": "womd", "policy": "log", "seed": 0, "object_type": "vehicle",
           "valid": True, "crashed": False, "t": np.arange(n) / 10}
    ego = pd.DataFrame({"track_id": "ego", "x": x[:n], "y": y[:n], "heading": h[:n],
                        "speed": v[:n], "is_ego": True, **ids})
    car = pd.DataFrame({"track_id": "car", "x": x[at], "y": y[at], "heading": h[at],
                        "speed": 0.0, "is_ego": False, **ids})
    return (pd.concat([ego, car], ignore_index=True),
            (driven[at] - driven[end] - EGO_LENGTH) / v[end])


# the SDC of ee519cf5 (a Scenario record) turns right by 80 degrees, the one of a3bb37c2 (a
# tf.Example record) left by 90: records cut where the arc of the ego's last curvature leaves
# the turn before the standing car, while its lane goes through it
CASES = [("womd_scenario_input.tfrecord", 40, 12.0), ("womd_scenario_input.tfrecord", 45, 12.0),
         ("motion_data_one_example.tfrecord", 65, 18.0)]


@pytest.mark.parametrize(("name", "end", "gap"), CASES)
def test_a_leader_in_the_turn_beyond_the_record_is_found_along_the_scenes_lanes(
        womd_dir, name, end, gap):
    scenes = WomdScenes((str(womd_dir / name),))
    scene = load_scene(scene_catalog(scenes.files)[0])
    table, expected = _cut_short(scene, end, gap)
    alone = ego_measures(table).iloc[0]  # along the arc: the car is off the line
    assert np.isnan(alone["min_ttc_s"]) and np.isnan(alone["min_headway_s"])
    result = _label_in_the_runner(scenes, table)
    episode = result["episodes"].iloc[0]
    # along the lanes: the leader, its gap closing at the ego's speed (the ego's last
    # steps at a near-constant speed; the path along the lane is within a few % of the
    # ego's driven one)
    assert episode["min_ttc_s"] == pytest.approx(expected, rel=0.06)
    assert episode["min_headway_s"] == pytest.approx(expected, rel=0.06)
    labels = result["labels"]
    ego = labels[labels["track_id"].astype(str) == "ego"]
    assert ego["interaction"].str.contains("Following (car)", regex=False).any()


def test_each_episode_gets_its_own_scenes_lanes_under_its_run_id(womd_dir, monkeypatch):
    files = tuple(str(p) for p in sorted(womd_dir.glob("*.tfrecord")))
    scenes = WomdScenes(files)
    table = pd.concat([load_scene(ref).table() for ref in scene_catalog(files)],
                      ignore_index=True)
    run = table.assign(womd_scenario_id=table["scenario_id"], env="womd",
                       scenario_id=table["scenario_id"] + "/idm")
    road = run_tasks._road(_task(scenes, "idm"), run)
    truth = read_maps(files)
    truth = truth[truth["kind"] == "lane"]
    assert set(road["map_id"]) == set(run["scenario_id"])
    for sid in table["scenario_id"].unique():
        mine = road[road["map_id"] == f"{sid}/idm"]
        theirs = truth[truth["map_id"] == sid]
        assert len(mine) == len(theirs) > 0
        np.testing.assert_array_equal(mine[["x", "y"]].to_numpy(),
                                      theirs[["x", "y"]].to_numpy())
    # with room for one scene only, the batch still gets every scene's lanes (the scenes
    # it needs are never the ones let go)
    monkeypatch.setattr(run_tasks, "SCENE_LANES_KEPT", 1)
    run_tasks._SCENE_LANES.clear()
    two = run["womd_scenario_id"].isin(run["womd_scenario_id"].unique()[:2])
    run_tasks._road(_task(scenes, "idm"), run[two])  # two scenes read, a third to come
    again = run_tasks._road(_task(scenes, "idm"), run)
    cols = ["map_id", "kind", "x", "y"]  # feature ids count the features read together
    pd.testing.assert_frame_equal(again[cols], road[cols])
    # with its seeds (a run's table), each scene's record is read alone: the same lanes
    run_tasks._SCENE_LANES.clear()
    seed_of = {sid: k for k, sid in enumerate(table["scenario_id"].unique())}
    from tap_bench.sources import maps as source_maps

    monkeypatch.setattr(source_maps, "read_maps", None)  # the files are not read through
    alone = run_tasks._road(_task(scenes, "idm"),
                            run.assign(seed=table["scenario_id"].map(seed_of)))
    pd.testing.assert_frame_equal(alone[cols], road[cols])
    # a table without the WOMD id (not a run of recorded scenes) is measured along the arc
    assert run_tasks._road(_task(scenes), run.drop(columns="womd_scenario_id")) is None


def test_log_replay_in_the_runner_equals_the_logs_labels_along_its_map(womd_dir):
    # the human's episode, labelled and measured by the runner along its scene's lanes,
    # equals the recorded log labelled and measured with the same map (under the WOMD id)
    files = (str(womd_dir / "womd_scenario_input.tfrecord"),
             str(womd_dir / "motion_data_one_example.tfrecord"))
    scenes = WomdScenes(files)
    lanes = read_maps(files)
    for seed, ref in enumerate(scene_catalog(files)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            replay, _ = rollout(scenes, "log", [seed], progress=False)
        run = run_tasks._run_ids(_task(scenes, "log", seed), replay)
        ours = _label_in_the_runner(scenes, run, "log", seed)
        log = load_scene(ref).table()
        theirs = tap(log, "paper", interactions="ego", map_table=lanes)
        mine = ours["labels"][ours["labels"]["level"] == "maneuver"]
        logs = theirs.labels("maneuver")
        logs = logs[logs["track_id"].isin(mine["track_id"].unique())]
        assert mine["sdl"].tolist() == logs["sdl"].tolist()
        assert mine["interaction"].tolist() == logs["interaction"].tolist()
        measured = ego_measures(log, lanes).iloc[0]
        for col in ("min_ttc_s", "min_headway_s"):
            np.testing.assert_allclose(ours["episodes"][col].iat[0], measured[col])


def test_the_label_cache_key_says_the_scenes_lanes_were_used(womd_dir):
    suite = suite_from_dict({"name": "keys", "policies": ["log"], "seeds": "0",
                             "envs": [{"womd": [str(womd_dir / "womd_scenario_input.tfrecord")],
                                       "name": "womd"}]}, check_names=False)

    class _NoCache:
        root = None

    tasks = _tasks(plan_suite(suite), False, _NoCache())
    assert tasks[0].label_doc["map"] == SCENE_MAP


@pytest.mark.parametrize("as_table", [False, True])
def test_the_label_command_labels_along_a_map_it_is_given(womd_dir, tmp_path, capsys,
                                                          as_table):
    from tap_bench.cli import main

    name = "womd_scenario_input.tfrecord"
    scene = load_scene(scene_catalog([str(womd_dir / name)])[0])
    table, _ = _cut_short(scene, 40, 12.0)
    table = table.assign(scenario_id=scene.scenario_id).drop(columns="womd_scenario_id")
    table.to_parquet(tmp_path / "cut.parquet")
    where = str(womd_dir / name)
    if as_table:  # a map table (as a run's roads.parquet), not the WOMD file
        read_maps([where]).to_parquet(tmp_path / "roads.parquet")
        where = str(tmp_path / "roads.parquet")

    def following(*extra: str) -> bool:
        out = tmp_path / "labels.parquet"
        assert main(["label", str(tmp_path / "cut.parquet"), "-o", str(out),
                     "--interactions", *extra]) == 0
        labels = pd.read_parquet(out)
        ego = labels[labels["track_id"].astype(str) == "ego"]
        return bool(ego["interaction"].str.contains("Following (car)", regex=False).any())

    assert not following()  # along the arc the car in the turn is not ahead
    assert following("--map", where)
    capsys.readouterr()
    # another scene's map: labelled along the arc, and the command says why
    assert not following("--map", str(womd_dir / "motion_data_one_example.tfrecord"))
    assert "has a map in --map" in capsys.readouterr().err
    # the map serves the interaction axis only: without it the command says so
    assert main(["label", str(tmp_path / "cut.parquet"), "-o", str(tmp_path / "x.parquet"),
                 "--map", where]) == 2
    assert "--interactions" in capsys.readouterr().err
