"""Scenes held out of training on recorded scenes, and the training env's scene cache."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from tap_bench.errors import ParameterError
from tap_bench.rl.heldout import MIN_TRAVEL, SceneSubset, drivers, split_scenes
from tap_bench.sim.womd_env import WomdEnv
from tap_bench.sim.womd_road import LogVehicle
from tap_bench.sim.womd_scene import CURRENT_STEP, SceneError, WomdScenes


@pytest.fixture
def four(womd_dir) -> WomdScenes:
    """The four sample files: scenes 0-3 in file order."""
    return WomdScenes((str(womd_dir),))


def test_a_split_names_the_scenes_trained_on_and_held_out(four):
    split = split_scenes(four, "1,3")
    assert split.train == (0, 2) and split.held_out == (1, 3)
    record = split.record()
    assert record["held_out_scenes"] == [1, 3] and record["train_scenes"] == [0, 2]
    assert "motion_data_one_scenario" in record["held_out_refs"][0]
    assert split_scenes(four, None).held_out == ()
    with pytest.raises(ParameterError, match="none is left to train on"):
        split_scenes(four, "0-3")
    with pytest.raises(ParameterError, match="beyond"):
        split_scenes(four, "7")


def test_the_training_env_never_starts_a_held_out_scene(four):
    env = SceneSubset(WomdEnv(four, record=False, cycle=True), (0, 2))
    seen = []
    env.reset(seed=5)  # seed 5 -> the second training scene, as seeds wrap around
    seen.append(env.unwrapped.scene_index)
    for _ in range(4):
        env.reset()
        seen.append(env.unwrapped.scene_index)
    assert seen == [2, 0, 2, 0, 2]


def test_a_scene_built_again_from_the_cache_gives_the_same_episode(four):
    cached = WomdEnv(four, record=False, cycle=True)
    fresh = WomdEnv(four, record=False)
    runs = []
    for env, resets in ((cached, 2), (fresh, 1)):
        for _ in range(resets):  # the cached env builds scene 0, then takes it from its cache
            obs, _ = env.reset(options={"scene": 0})
            network = env.unwrapped.road.network
            trace = [obs]
            for _ in range(6):
                obs, _reward, terminated, truncated, _ = env.step(3)  # FASTER
                trace.append(obs)
                if terminated or truncated:
                    break
        runs.append((network, np.array(trace)))
    assert cached.unwrapped._built, "the cycling env keeps its built scenes"
    assert runs[0][0] is cached.unwrapped._built[cached.catalog[0], cached.scene.ego][0]
    np.testing.assert_allclose(runs[0][1], runs[1][1], atol=1e-6)


def test_train_records_the_held_out_scenes_and_never_trains_on_them(four, tmp_path):
    pytest.importorskip("stable_baselines3")
    from tap_bench.rl.training import train

    result = train("ppo", four, timesteps=32, seed=0, output=tmp_path / "ppo-womd.zip",
                   n_envs=1, hold_out="1,3", log_dir=tmp_path / "log",
                   hyperparameters={"n_steps": 16, "batch_size": 16, "n_epochs": 1})
    params = json.loads(result.definition_path.read_text())["params"]
    assert params["held_out_scenes"] == [1, 3] and params["train_scenes"] == [0, 2]
    assert 0 < params["cpu_seconds"] and params["train_seconds"] > 0
    assert sorted(p.name for p in (tmp_path / "log").glob("weights_*_steps.zip"))
    assert params["egos"] == "sdc"
    with pytest.raises(ParameterError, match="synthetic"):
        train("ppo", "highway", timesteps=32, seed=0, output=tmp_path / "x.zip",
              n_envs=1, hold_out="1")
    for bad, where in (("all", "highway"), ("everyone", four)):
        with pytest.raises(ParameterError, match="egos"):
            train("ppo", where, timesteps=32, seed=0, output=tmp_path / "y.zip", n_envs=1,
                  egos=bad)


def test_a_definition_with_the_split_and_cpu_time_loads_as_a_policy(four, tmp_path):
    pytest.importorskip("stable_baselines3")
    from tap_bench.rl.training import train
    from tap_bench.sim.policies import load_policy

    result = train("ppo", four, timesteps=16, seed=0, output=tmp_path / "ppo-womd.zip",
                   n_envs=1, hold_out="3",
                   hyperparameters={"n_steps": 16, "batch_size": 16, "n_epochs": 1})
    policy = load_policy(str(result.definition_path))
    assert policy.training["held_out_scenes"] == [3]
    assert policy.training["cpu_seconds"] > 0


def test_the_drivers_of_a_scene_are_its_ego_then_every_vehicle_that_drives(four):
    scene = WomdEnv(four, record=False).scene_at(0)
    names = drivers(scene)
    assert names[0] == str(scene.track_ids[scene.ego])
    assert len(names) > 3 and len(set(names)) == len(names)
    for name in names[1:]:
        row = int(np.flatnonzero(scene.track_ids.astype(str) == name)[0])
        assert scene.object_types[row] == "vehicle"
        assert scene.valid[row, CURRENT_STEP:].all()
        travel = np.hypot(np.diff(scene.x[row, CURRENT_STEP:]),
                          np.diff(scene.y[row, CURRENT_STEP:])).sum()
        assert travel >= MIN_TRAVEL
    parked = [str(t) for r, t in enumerate(scene.track_ids) if scene.valid[r].all()
              and scene.object_types[r] == "vehicle"
              and np.hypot(np.diff(scene.x[r]), np.diff(scene.y[r])).sum() < 1.0]
    assert parked and not set(parked) & set(names)


def test_an_episode_drives_another_track_and_the_scene_ego_replays(four):
    env = WomdEnv(four, record=False, cycle=True)
    scene = env.scene_at(0)
    track = drivers(scene)[1]
    env.reset(options={"scene": 0, "ego": track})
    inner = env.unwrapped
    row = inner.scene.ego
    assert str(inner.scene.track_ids[row]) == track and row != scene.ego
    assert inner.route and np.allclose(inner.vehicle.position,
                                       [scene.x[row, CURRENT_STEP], -scene.y[row, CURRENT_STEP]])
    assert any(isinstance(v, LogVehicle) and v.row == scene.ego for v in inner.road.vehicles)
    own_route = None
    for ego in (None, track, None):  # the routes of both egos are kept apart
        env.reset(options={"scene": 0, "ego": ego})
        if ego is None:
            own_route = own_route or list(inner.route)
            assert inner.route == own_route and inner.scene.ego == scene.ego
    with pytest.raises(SceneError, match="no track 'nobody'"):
        WomdEnv(four, record=False).reset(options={"scene": 0, "ego": "nobody"})


def test_training_on_all_drivers_drives_each_in_turn(four):
    env = SceneSubset(WomdEnv(four, record=False, cycle=True), (0,), egos="all")
    names = drivers(env.unwrapped.scene_at(0))
    seen = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a driver without a route is dropped, warned
        for _ in range(2 * len(names)):
            env.reset()
            inner = env.unwrapped
            assert inner.scene_index == 0 and inner.route and not inner.route_missing
            seen.append(str(inner.scene.track_ids[inner.scene.ego]))
    driven = env._drivers[0]  # those without a route were dropped
    assert seen[:2] == names[:2] and set(seen) == set(driven) and len(driven) > 3
    with pytest.raises(ParameterError, match="egos"):
        SceneSubset(WomdEnv(four, record=False, cycle=True), (0,), egos="everyone")


def test_the_scenes_a_definition_trained_on_are_found_in_other_files_by_their_record(
        womd_dir, tmp_path):
    """Trained on scenes 1, 2, 5, 9, 12-15 of the samples and the development file: in the
    development file alone (scene k is its record k there) it trained on records 1, 5, 8-11
    and held out the rest; a file it never read is new to it; from a folder where its
    training files are not, nothing is known."""
    import os

    from tap_bench.rl.heldout import seen_in_training

    dev = womd_dir.parent / "womd-dev" / "dev.tfrecord"
    if not dev.is_file():
        pytest.skip(f"{dev} not found")
    root = womd_dir.parent.parent.parent  # a folder the relative paths below start from
    rel = os.path.relpath
    files = [rel(womd_dir, root), rel(dev, root)]
    params = {"womd": files, "train_scenes": [1, 2, 5, 9, 12, 13, 14, 15],
              "held_out_scenes": [0, 3, 4, 6, 7, 8, 10, 11],
              "held_out_refs": [f"{rel(womd_dir, root)}/motion_data_one_example.tfrecord record 0",
                                f"{rel(womd_dir, root)}/womd_scenario_input.tfrecord record 0",
                                *(f"{rel(dev, root)} record {k}" for k in (0, 2, 3, 4, 6, 7))]}
    refs = [f"{dev} record {k}" for k in range(12)] + [str(tmp_path / "other.tfrecord record 0")]
    seen = seen_in_training(params, refs, [tmp_path, root])
    assert seen[:12] == [k in (1, 5, 8, 9, 10, 11) for k in range(12)]
    assert seen[12] is None
    assert seen_in_training(params, refs, [tmp_path]) == [None] * 13
    assert seen_in_training({"womd": files}, refs, [root]) == []


def test_a_rollout_of_a_trained_agent_gives_its_unseen_and_training_scenes_apart(
        womd_dir, tmp_path, capsys, monkeypatch):
    """Pooled, the summary would pass training scenes off as a test. Run from elsewhere:
    the definition's relative training paths start from the project root (policies/..)."""
    pytest.importorskip("stable_baselines3")
    from tap_bench.cli import main

    dev = womd_dir.parent / "womd-dev" / "dev.tfrecord"
    if not dev.is_file():
        pytest.skip(f"{dev} not found")
    monkeypatch.chdir(tmp_path)
    main(["rollout", "--womd", str(dev), "--policy", "ppo-womd-grid-foldb-seed1", "--seeds",
          "0,1", "-o", str(tmp_path / "r.parquet"), "--no-progress"])
    out = capsys.readouterr().out
    assert "ppo-womd-grid-foldb-seed1 (its definition's training split):" in out
    assert "  held out of its training (never seen): 1 scene(s) (0): route progress" in out
    assert "  trained on: 1 scene(s) (1): route progress" in out


def test_a_definition_that_cannot_be_read_again_does_not_fail_the_rollout(monkeypatch):
    """The split line comes after the outputs are written: a definition gone since (or
    unreadable) gives a line saying so, not an error."""
    import tap_bench.sim.policies as policies
    from tap_bench.cli.rollout import _training_split
    from tap_bench.errors import FileFormatError

    def gone(name):
        raise FileFormatError(f"{name}: no such policy file.")

    monkeypatch.setattr(policies, "get_definition", gone)
    lines = _training_split("my.json", None, None)
    assert lines == ["(which scenes my.json trained on is not known: my.json: no such policy "
                     "file.)"]
