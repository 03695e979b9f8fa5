"""``tap_bench/womd-v0`` as a Gymnasium env: Gymnasium's ``check_env`` in both forms (the
wrapper ``gym.make`` builds and ``env.unwrapped``, render check included) on every real
scene we have and on generated ones, observations inside the space for every
``vehicles_count``, any integer seed, ``rgb_array`` frames; and ``vehicles_count`` 0 and 1
on the registered highway envs."""

from __future__ import annotations

import math
import pickle
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import tap_bench  # noqa: F401  (registers the envs)
from tap_bench.errors import ParameterError
from tap_bench.sim.registration import WOMD_ENV_ID
from tap_bench.womd.tfrecord import TFRecordWriter, iter_records

DEV = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "womd-dev" / \
    "dev.tfrecord"


def two_lane_road(path: Path, *, angle: float = 0.0, n_cars: int = 2) -> str:
    """A ScenarioNet pickle: two neighbouring 200 m lanes heading ``angle`` [rad], the ego
    at 10 m/s in the right one, ``n_cars`` cars ahead of it (alternating lanes, 8 m/s) and
    a pedestrian walking beside the road."""
    t = np.arange(91) * 0.1
    c, s = math.cos(angle), math.sin(angle)

    def rotate(lon, lat):
        return np.c_[lon * c - lat * s, lon * s + lat * c]

    def track(lon0, lat, speed, kind="VEHICLE", heading=0.0, length=4.5, width=2.0):
        lon = lon0 + speed * t * math.cos(heading)
        lats = lat + speed * t * math.sin(heading)
        xy = rotate(lon, lats)
        return {"type": kind, "state": {
            "position": np.c_[xy, np.zeros(91)], "heading": np.full(91, angle + heading),
            "velocity": np.c_[np.full(91, speed * math.cos(angle + heading)),
                              np.full(91, speed * math.sin(angle + heading))],
            "valid": np.ones(91, bool), "length": np.full(91, length),
            "width": np.full(91, width)}}

    lon = np.arange(-20.0, 180.0, 1.0)
    features = {
        "1": {"type": "LANE_SURFACE_STREET", "polyline": rotate(lon, np.zeros_like(lon)),
              "entry_lanes": [], "exit_lanes": [], "left_neighbor": [2]},
        "2": {"type": "LANE_SURFACE_STREET", "polyline": rotate(lon, np.full_like(lon, 3.7)),
              "entry_lanes": [], "exit_lanes": [], "right_neighbor": [1]}}
    tracks = {"ego": track(0.0, 0.0, 10.0)}
    for k in range(n_cars):
        tracks[f"car{k}"] = track(25.0 + 15.0 * k, 3.7 * (k % 2), 8.0)
    tracks["walker"] = track(30.0, 7.0, 1.2, kind="PEDESTRIAN", heading=math.pi / 2 * 0.1,
                             length=0.5, width=0.5)
    meta = {"scenario_id": path.stem, "ts": t, "dataset": "waymo", "sdc_id": "ego"}
    with path.open("wb") as f:
        pickle.dump({"metadata": meta, "tracks": tracks, "map_features": features,
                     "dynamic_map_states": {}}, f)
    return str(path)


def real_scene_files(womd_dir: Path, tmp_path: Path) -> list[str]:
    """Every real scene we have, one file each: the four samples, and the development
    scenes split into one-record files in ``tmp_path`` (skipped when absent)."""
    files = [str(p) for p in sorted(womd_dir.iterdir()) if p.suffix in (".tfrecord", ".pkl")]
    if DEV.is_file():
        for record in iter_records(DEV):
            out = tmp_path / f"dev-{record.index:02d}.tfrecord"
            with TFRecordWriter(out) as writer:
                writer.write(record.data)
            files.append(str(out))
    return files


def check_both_forms(files, **kwargs) -> None:
    """Gymnasium's checker on the env ``gym.make`` builds and on ``env.unwrapped``, with
    the render check (``rgb_array``, and every declared mode through the spec)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = gym.make(WOMD_ENV_ID, files=files, render_mode="rgb_array", **kwargs)
        check_env(env)
        check_env(env.unwrapped)
        env.close()


@pytest.mark.parametrize("angle", [0.0, 2.4, -1.9])
def test_check_env_passes_on_a_generated_scene_in_every_heading(tmp_path, angle):
    check_both_forms(two_lane_road(tmp_path / "sd_two.pkl", angle=angle))


@pytest.mark.slow  # 16 scenes x 2 forms, each check_env builds four envs
@pytest.mark.womd
def test_check_env_passes_on_every_real_scene(womd_dir, tmp_path):
    files = real_scene_files(womd_dir, tmp_path)
    assert len(files) >= 4
    for path in files:
        check_both_forms(path)
        # and every observation of a whole episode of drawn actions lies in the space
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            env = gym.make(WOMD_ENV_ID, files=path)
            env.action_space.seed(7)
            obs, _ = env.reset(seed=7)
            done = False
            while not done:
                assert env.observation_space.contains(obs), path
                obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
                done = terminated or truncated
            assert env.observation_space.contains(obs), path


@pytest.mark.parametrize("count", [0, 1, 2, 5, 9])
@pytest.mark.parametrize("kind", ["KinematicsRoute", "Kinematics"])
def test_every_observation_lies_in_the_space_for_any_vehicles_count(tmp_path, kind, count):
    path = two_lane_road(tmp_path / "sd_two.pkl", n_cars=4)
    config = {"observation": {"type": kind, "vehicles_count": count}}
    env = gym.make(WOMD_ENV_ID, files=path, config=config)
    space = env.observation_space
    rows = count * 5  # the default features: presence, x, y, vx, vy
    assert space.shape == ((rows + 16,) if kind == "KinematicsRoute" else (count, 5))
    obs, _ = env.reset(seed=0)
    done, n = False, 0
    while not done:
        assert obs.shape == space.shape and space.contains(obs), (n, obs)
        obs, _, terminated, truncated, _ = env.step(4)  # slower: to the log's end
        done, n = terminated or truncated, n + 1
    assert space.contains(obs) and truncated and n == 16
    if count >= 2 and kind == "Kinematics":  # the car ahead is seen
        assert obs[1, 0] == 1.0
    check_both_forms(path, config=config)


@pytest.mark.parametrize("count", [-1, 1.5, True, "3"])
def test_a_vehicles_count_that_cannot_hold_is_refused(tmp_path, count):
    path = two_lane_road(tmp_path / "sd_two.pkl")
    with pytest.raises(ValueError, match=f"vehicles_count {count!r} must be an integer >= 0"):
        gym.make(WOMD_ENV_ID, files=path,
                 config={"observation": {"type": "Kinematics", "vehicles_count": count}})


def test_the_space_is_fixed_when_the_env_is_built(tmp_path):
    env = gym.make(WOMD_ENV_ID, files=two_lane_road(tmp_path / "sd_two.pkl"))
    space = env.observation_space
    env.reset(seed=0, options={"config": {"scaling": 4.0}})  # other config: fine
    assert env.observation_space is space
    with pytest.raises(ParameterError, match="observation space is fixed"):
        env.reset(seed=0, options={"config": {"observation": {"type": "KinematicsRoute",
                                                               "vehicles_count": 3}}})


def test_any_integer_seed_is_a_scene_and_the_index_stays_an_option(tmp_path):
    files = [two_lane_road(tmp_path / f"sd_{name}.pkl", angle=a)
             for name, a in (("a", 0.0), ("b", 1.0), ("c", 2.0))]
    env = gym.make(WOMD_ENV_ID, files=files)
    inner = env.unwrapped
    for seed in (0, 1, 2, 3, 123, 2**31 - 1, 10**12 + 5):
        env.reset(seed=seed)
        assert inner.scene_index == seed % 3
        assert inner.scene.scenario_id == f"sd_{'abc'[seed % 3]}"
    a, _ = env.reset(seed=4)
    b, _ = env.reset(seed=1)
    np.testing.assert_array_equal(a, b)  # the same scene, the same start
    env.reset(seed=7, options={"scene": 2})
    assert inner.scene.scenario_id == "sd_c"
    env.reset(options={"scenario_id": "sd_a"})
    assert inner.scene_index == 0
    env.reset()  # the next one
    assert inner.scene_index == 1
    with pytest.raises(ParameterError, match="scene must be 0 to 2"):
        env.reset(options={"scene": 3})
    # the unwrapped env picks its scenes itself
    inner.reset(seed=5)
    assert inner.scene_index == 2 and inner.road is not None


def test_rgb_array_frames_show_the_scene(tmp_path):
    env = gym.make(WOMD_ENV_ID, files=two_lane_road(tmp_path / "sd_two.pkl", angle=0.7),
                   render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render().copy()  # highway-env may hand back its own buffer
    for _ in range(3):
        env.step(1)
    later = env.render()
    assert first.dtype == np.uint8 and first.ndim == 3 and first.shape[2] == 3
    assert first.shape == later.shape and not np.array_equal(first, later)
    assert len(np.unique(first.reshape(-1, 3), axis=0)) > 3  # road, lines, vehicles


@pytest.mark.parametrize("env_id", ["tap_bench/highway-v0", "tap_bench/merge-v0",
                                    "tap_bench/roundabout-v0"])
@pytest.mark.parametrize("count", [0, 1])
def test_highway_envs_observe_vehicles_count_rows(env_id, count):
    config = {"observation": {"type": "Kinematics", "vehicles_count": count}}
    env = gym.make(env_id, duration=2, config=config)
    obs, _ = env.reset(seed=3)
    assert obs.shape == env.observation_space.shape == (count, 5)
    for _ in range(3):
        obs, *_ = env.step(1)
        assert env.observation_space.contains(obs)
    if count == 1:
        assert obs[0, 0] == 1.0  # the ego's row
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(env.unwrapped)
        check_env(env, skip_render_check=True)


GRID = (0.0, 2.5, 5.0, 7.5, 10.0, 12.5, 15.0, 17.5, 20.0, 25.0, 30.0)  # TARGET_SPEEDS


def _ego_with(tmp_path: Path, speed_index: str | None = None):
    action = {"type": "DiscreteMetaAction", "target_speeds": list(GRID)}
    if speed_index is not None:
        action["speed_index"] = speed_index
    env = gym.make(WOMD_ENV_ID, files=two_lane_road(tmp_path / "sd_two.pkl"),
                   config={"action": action})
    env.reset(seed=0)
    return env.unwrapped.vehicle


def test_faster_and_slower_step_one_grid_speed_from_the_ego_s_speed(tmp_path):
    """From every speed of the grid (2.5 m/s apart to 20, then 5: not evenly spaced),
    FASTER targets the next grid speed and SLOWER the one before; between two grid speeds
    the nearer one counts. highway-env's formula, which takes the grid as evenly spaced,
    left FASTER at the ego's speed from 7.5 m/s up and took 5 m/s off with SLOWER."""
    ego = _ego_with(tmp_path)
    for k, speed in enumerate(GRID):
        for jitter in (-0.4, 0.0, 0.4):
            ego.speed = max(speed + jitter, 0.0)
            ego.act("FASTER")
            assert ego.target_speed == GRID[min(k + 1, len(GRID) - 1)], (speed, jitter)
            ego.act("SLOWER")
            assert ego.target_speed == GRID[max(k - 1, 0)], (speed, jitter)


def test_the_models_trained_before_the_grid_fix_keep_highway_env_s_reading(tmp_path):
    """speed_index "uniform" drives as those models trained: FASTER from 10 m/s targets
    10 m/s again, SLOWER 5 m/s; a value that is neither is refused naming the field."""
    ego = _ego_with(tmp_path, "uniform")
    ego.speed = 10.0
    ego.act("FASTER")
    assert ego.target_speed == 10.0
    ego.act("SLOWER")
    assert ego.target_speed == 5.0
    with pytest.raises(ParameterError, match="speed_index"):
        _ego_with(tmp_path, "even")


def test_the_start_s_target_speed_is_the_nearest_grid_speed(tmp_path):
    """The ego starts at the route's speed limit on the grid: the nearest grid speed (13.4
    m/s, 30 mph, is 12.5; highway-env's formula gave 10)."""
    ego = _ego_with(tmp_path)
    for limit, nearest in ((13.4, 12.5), (11.2, 10.0), (15.6, 15.0), (22.4, 20.0),
                           (23.0, 25.0)):
        ego.speed_index = ego.speed_to_index(limit)
        assert ego.index_to_speed(ego.speed_index) == nearest, limit


def test_every_shipped_womd_model_drives_with_the_grid_it_trained_with():
    """Every WOMD model's definition says how it reads the grid (one without would drive
    with the default, not with what it trained with): those trained before the grid fix
    (2026-12-05; e.g. the tenth version's) pin "uniform"; the env's default action, which
    `tap-bench train` records in a new model's definition, is "nearest"."""
    import json

    from tap_bench.sim.scenario_format import suite_dir
    from tap_bench.sim.womd_env import _WomdHighwayEnv

    assert _WomdHighwayEnv.default_config()["action"]["speed_index"] == "nearest"
    read = {}
    for path in sorted(suite_dir("policies").glob("*.json")):
        definition = json.loads(path.read_text())
        params = definition.get("params", {})
        if definition.get("kind") == "sb3" and "womd" in params.get("env", ""):
            read[definition["name"]] = params["action"].get("speed_index")
    assert len(read) >= 34 and None not in read.values(), read
    assert {read[f"ppo-womd-tenth-seed{s}"] for s in range(3)} == {"uniform"}


def _grids():
    """Strictly increasing target-speed grids of 2 to 12 speeds in [0, 40] m/s, evenly
    spaced or not."""
    from hypothesis import strategies as st

    return st.lists(st.integers(0, 160), min_size=2, max_size=12, unique=True).map(
        lambda quarters: [q / 4.0 for q in sorted(quarters)])


def test_faster_and_slower_step_one_grid_speed_on_any_grid_from_any_speed():
    """Property over generated grids and speeds: FASTER targets the grid speed after the
    one nearest the vehicle's speed, SLOWER the one before (clipped at the ends), and the
    start's target is the grid speed nearest the one given; "uniform" gives highway-env's
    formula on any grid (its index of round((v - first) / (last - first) * (n - 1)))."""
    from highway_env.road.road import Road, RoadNetwork
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from tap_bench.sim.womd_road import WomdMDPVehicle

    road = Road(network=RoadNetwork.straight_road_network(1))

    @settings(max_examples=300, deadline=None)
    @given(grid=_grids(), speed=st.floats(0.0, 45.0), start=st.floats(0.0, 45.0))
    def check(grid, speed, start):
        ego = WomdMDPVehicle(road, [10.0, 0.0], speed=speed, target_speed=start,
                             target_speeds=grid)
        distance = [abs(g - start) for g in grid]
        assert abs(ego.target_speed - start) == min(distance)
        nearest = min(range(len(grid)), key=lambda k: (abs(grid[k] - speed), k))
        ego.act("FASTER")
        assert ego.target_speed == grid[min(nearest + 1, len(grid) - 1)]
        ego.act("SLOWER")
        assert ego.target_speed == grid[max(nearest - 1, 0)]
        old = WomdMDPVehicle(road, [10.0, 0.0], speed=speed, target_speed=start,
                             target_speeds=grid, speed_index="uniform")
        x = (speed - grid[0]) / (grid[-1] - grid[0]) * (len(grid) - 1)
        assert old.speed_to_index(speed) == int(np.clip(np.round(x), 0, len(grid) - 1))

    check()
