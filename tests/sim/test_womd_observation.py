"""The route in the RL observation of tap_bench/womd-v0 (``KinematicsRoute``): its values on
generated two-lane scenes (rotated, both sides, several speeds), the space holding every
observation on the real files and their Kinematics part equal to highway-env's (one module
fixture drives the real scenes for both), and an SB3 agent trained on it through the
command."""

from __future__ import annotations

import json
import math
import pickle
from pathlib import Path

import numpy as np
import pytest

from tap_bench.errors import UnknownNameError
from tap_bench.sim.policies import load_policy
from tap_bench.sim.womd_env import make_womd_env
from tap_bench.sim.womd_observation import LEADER_FEATURES, ROUTE_FEATURES, route_feature_names

FILES = ["motion_data_one_scenario.tfrecord", "womd_scenario_input.tfrecord",
         "motion_data_one_example.tfrecord", "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl"]
WIDTH = 3.7
CHANGE_X = 50.0  # [m] where the second lane becomes the first's neighbour


def two_lanes(path: Path, *, theta: float, side: int, speed: float) -> str:
    """A ScenarioNet pickle: two parallel straight lanes (the second on the ``side`` of the
    first, +1 left), neighbours from x = 50 m; the ego drives the first at ``speed`` from
    x = 0 and changes to the second between x = 50 and 60 m; everything rotated by
    ``theta``."""
    c, s = math.cos(theta), math.sin(theta)

    def rot(xy: np.ndarray) -> np.ndarray:
        return np.c_[c * xy[:, 0] - s * xy[:, 1], s * xy[:, 0] + c * xy[:, 1]]

    xs = np.arange(-10.0, 200.0, 0.5)
    first = rot(np.c_[xs, np.zeros_like(xs)])
    second = rot(np.c_[xs, np.full_like(xs, side * WIDTH)])
    start = int(np.searchsorted(xs, CHANGE_X))
    near = {"feature_id": "2", "self_start_index": start, "self_end_index": len(xs) - 1,
            "neighbor_start_index": start, "neighbor_end_index": len(xs) - 1}
    back = {**near, "feature_id": "1"}
    features = {
        "1": {"type": "LANE_SURFACE_STREET", "polyline": first, "entry_lanes": [],
              "exit_lanes": [], "left_neighbor": [near] if side > 0 else [],
              "right_neighbor": [near] if side < 0 else []},
        "2": {"type": "LANE_SURFACE_STREET", "polyline": second, "entry_lanes": [],
              "exit_lanes": [], "left_neighbor": [back] if side < 0 else [],
              "right_neighbor": [back] if side > 0 else []},
    }
    t = np.arange(91) * 0.1
    x = speed * t
    y = side * WIDTH * np.clip((x - CHANGE_X) / 10.0, 0.0, 1.0)
    xy = rot(np.c_[x, y])
    vel = np.gradient(xy, 0.1, axis=0)
    heading = np.arctan2(vel[:, 1], vel[:, 0])
    ego = {"type": "VEHICLE", "state": {
        "position": np.c_[xy, np.zeros(91)], "heading": heading, "velocity": vel,
        "valid": np.ones(91, bool), "length": np.full(91, 4.5), "width": np.full(91, 2.0)}}
    meta = {"scenario_id": path.stem, "ts": t, "dataset": "waymo", "sdc_id": "ego"}
    with path.open("wb") as f:
        pickle.dump({"metadata": meta, "tracks": {"ego": ego}, "map_features": features,
                     "dynamic_map_states": {}}, f)
    return str(path)


def route_part(env, obs: np.ndarray) -> dict[str, np.ndarray | float]:
    observation = env.unwrapped.observation_type
    values = obs[observation.kinematics_size:]
    names = route_feature_names(observation.route_points, observation.leader_features)
    assert len(values) == len(names) == observation.route_size
    named = dict(zip(names, values, strict=True))
    points = values[:2 * observation.route_points].reshape(-1, 2) * observation.horizon
    return {"points": points, **{k: named[k] for k in ROUTE_FEATURES}}


@pytest.mark.parametrize("theta", [0.0, 0.7, 2.0, -2.6])
@pytest.mark.parametrize("side", [1, -1])
@pytest.mark.parametrize("speed", [8.0, 11.0, 14.0])
def test_the_route_is_observed_from_the_ego(tmp_path, theta, side, speed):
    env = make_womd_env(two_lanes(tmp_path / "sd_two.pkl", theta=theta, side=side,
                                  speed=speed))
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert env.unwrapped.route == [("1", "1>", 0), ("2", "2>", 0)]
    route = route_part(env, obs)
    # the ego is at x = speed (t = 1 s); the route changes lane at x = 50 m, then follows
    # the second lane: the points 10, 20 ... 50 m ahead, in the ego's frame (y to the left)
    ahead = 10.0 * np.arange(1, 6)
    expected = np.c_[ahead, np.where(ahead > CHANGE_X - speed, side * WIDTH, 0.0)]
    np.testing.assert_allclose(route["points"], expected, atol=0.05)
    assert route["change_distance"] == pytest.approx((CHANGE_X - speed) / 50.0, abs=1e-3)
    assert route["change_side"] == side
    assert route["on_route"] == 1.0
    assert route["offset"] == pytest.approx(0.0, abs=1e-3)
    assert route["sin_heading"] == pytest.approx(0.0, abs=1e-3)
    assert route["cos_heading"] == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize("side", [1, -1])
def test_the_route_follows_the_ego_as_it_drives(tmp_path, side):
    # the change comes closer as the ego drives; lane keeping stays in the first lane, so
    # past x = 50 m the change is due at once and the route's points lie in the second
    # lane; IDM takes the route's lane change and is then on the last route lane
    env = make_womd_env(two_lanes(tmp_path / "sd_two.pkl", theta=0.4, side=side,
                                  speed=10.0))
    for name in ("lane-keeping", "idm"):
        policy = load_policy(name)
        obs, _ = env.reset(seed=0)
        policy.reset(env, seed=0)
        seen, lanes, done = [], [], False
        while not done:
            seen.append(route_part(env, obs))
            lanes.append(env.unwrapped.vehicle.lane_index[0])
            assert env.observation_space.contains(obs)
            obs, _, terminated, truncated, _ = env.step(policy.act(obs))
            done = terminated or truncated
        distances = [r["change_distance"] for r in seen]
        before = [d for d, r in zip(distances, seen, strict=True) if r["change_side"] != 0]
        assert before == sorted(before, reverse=True) and len(before) >= 3
        assert all(r["on_route"] == 1.0 for r in seen)
        last = seen[-1]
        if name == "lane-keeping":
            assert last["change_side"] == side and last["change_distance"] == 0.0
            np.testing.assert_allclose(last["points"][:, 1], side * WIDTH, atol=0.3)
        else:
            assert last["change_side"] == 0 and last["change_distance"] == 1.0
            assert abs(last["offset"]) < 0.1
            np.testing.assert_allclose(last["points"][:, 1], 0.0, atol=0.3)
            # once changed it keeps the route's lane (MOBIL does not swing it back)
            assert lanes[lanes.index("2"):] == ["2"] * (len(lanes) - lanes.index("2"))


@pytest.fixture
def real(womd_dir) -> list[str]:
    return [str(womd_dir / f) for f in FILES]


@pytest.fixture(scope="module", params=["log", "idm"])
def real_rollouts(request, womd_dir):
    """Every real scene driven by each ego policy under the logged traffic, and under IDM
    traffic (what the parameter varies) by the IDM ego alone (the three egos cost three
    times the CPU there): the env and, at every decision, the route observation with
    highway-env's own Kinematics observation of the scene (pandas), then the observation
    after the last step (with None). The space and the Kinematics tests read the same
    rollouts."""
    from highway_env.envs.common.observation import KinematicObservation

    traffic = request.param
    env = make_womd_env([str(womd_dir / f) for f in FILES], traffic=traffic)
    seen = []
    for seed in range(len(env.catalog)):
        for name in ("log", "idm", "random") if traffic == "log" else ("idm",):
            policy = load_policy(name)
            obs, _ = env.reset(seed=seed)
            policy.reset(env, seed=seed)
            config = {k: v for k, v in env.unwrapped.config["observation"].items()
                      if k not in ("type", "route_points", "route_spacing", "leader")}
            done = False
            while not done:
                theirs = KinematicObservation(env.unwrapped, **config).observe().ravel()
                seen.append((obs.copy(), theirs))
                obs, _, terminated, truncated, _ = env.step(policy.act(obs))
                done = terminated or truncated
            seen.append((obs.copy(), None))
    return env, seen


def test_the_space_holds_every_observation_of_the_real_scenes(real_rollouts):
    env, seen = real_rollouts
    # highway-env's Kinematics defaults: 5 vehicles x 5 features, then the route
    assert env.observation_space.shape == (5 * 5 + 2 * 5 + len(ROUTE_FEATURES)
                                          + len(LEADER_FEATURES),)
    for obs, _ in seen:
        assert obs.dtype == np.float32 and env.observation_space.contains(obs)


def test_the_route_points_lie_on_the_logged_path(real):
    # the human (replayed) at every decision: the route points within its logged path's
    # reach lie near that path (the route is the lanes it drove)
    from tap_bench.sim.womd_road import path_progress

    env = make_womd_env(real[:2] + real[3:])  # a3bb's roadgraph misses the SDC's lane
    policy = load_policy("log")
    for seed in range(len(env.catalog)):
        obs, _ = env.reset(seed=seed)
        policy.reset(env, seed=0)
        inner = env.unwrapped
        checked, done = 0, False
        while not done:
            ego = inner.vehicle
            s0, _ = path_progress(inner.path, inner.path_cum, ego.position)
            c, s = math.cos(ego.heading), math.sin(ego.heading)
            for k, (fwd, left) in enumerate(route_part(env, obs)["points"], start=1):
                if s0 + 10.0 * k > inner.path_length - 2.0:
                    break
                world = ego.position + fwd * np.array([c, s]) - left * np.array([-s, c])
                assert path_progress(inner.path, inner.path_cum, world)[1] < 2.5
                checked += 1
            obs, _, terminated, truncated, _ = env.step(policy.act(obs))
            done = terminated or truncated
        if inner.path_length > 15.0:
            assert checked


def test_the_command_trains_an_agent_on_the_route_observation(real, tmp_path, capsys,
                                                              monkeypatch):
    """The command's reward, observation and ego settings reach the definition and the
    model's observation space. The training is PPO's smallest (one update of 32 steps,
    where the defaults' 256 steps and 10 epochs cost 2-3 CPU s): what is checked is what
    the command records, not what the agent learns."""
    pytest.importorskip("stable_baselines3")
    from tap_bench.cli import main
    from tap_bench.rl import training
    from tap_bench.sim.rollout import rollout
    from tap_bench.sim.womd_scene import WomdScenes

    monkeypatch.setitem(training.HYPERPARAMETERS, "ppo",
                        {**training.HYPERPARAMETERS["ppo"], "n_steps": 32, "batch_size": 16,
                         "n_epochs": 1})

    out = tmp_path / "ppo-route.zip"
    with pytest.raises(SystemExit, match="'speed_reward' is not a reward setting"):
        main(["train", "--algo", "ppo", "--env", "womd", "--womd", real[1], "--reward",
              "speed_reward=1", "--timesteps", "64", "-o", str(out)])
    with pytest.raises(SystemExit, match="--observation crossing=yes: 'yes' is not a JSON"):
        main(["train", "--algo", "ppo", "--env", "womd", "--womd", real[1], "--observation",
              "crossing=yes", "--timesteps", "64", "-o", str(out)])
    assert main(["train", "--algo", "ppo", "--env", "womd", "--womd", real[1],
                 "--egos", "all", "--reward", "progress_gain_reward=2",
                 "--observation", "crossing=true", "leader_corners=true",
                 "--timesteps", "32", "--n-envs", "1", "-o", str(out)]) == 0
    doc = json.loads(out.with_suffix(".json").read_text())
    assert doc["params"]["observation"] == {"type": "KinematicsRoute", "leader": True,
                                            "crossing": True, "leader_corners": True}
    assert doc["params"]["reward"] == {"collision_reward": -1.0, "progress_reward": 1.0,
                                       "off_road_reward": -1.0, "ttc_reward": -0.05,
                                       "progress_gain_reward": 2.0, "at_fault_reward": 0.0}
    assert doc["params"]["egos"] == "all"
    assert "--egos all --reward progress_gain_reward=2 --observation crossing=true " \
        "leader_corners=true" in doc["params"]["command"]
    from stable_baselines3 import PPO

    model = PPO.load(out, device="cpu")
    # Kinematics, route, leader, 2 crossing road users
    assert model.observation_space.shape == (5 * 5 + 16 + 4 + 2 * 3,)
    result = rollout(WomdScenes((real[1],)), str(out.with_suffix(".json")), "all")
    assert list(result.episodes["status"]) == ["ok"]


def _kinematics_matches_highway_env(env, policy_names=("log", "idm", "random"), seeds=None):
    """At every decision, the Kinematics part of the route observation equals highway-env's
    own Kinematics observation of the scene (pandas), within 1e-9 (another library: a
    tolerance, never the last bit of its float rounding); returns the decisions compared."""
    from highway_env.envs.common.observation import KinematicObservation

    compared = 0
    for seed in seeds if seeds is not None else range(len(env.catalog)):
        for name in policy_names:
            policy = load_policy(name)
            obs, _ = env.reset(seed=seed)
            policy.reset(env, seed=seed)
            observation = env.unwrapped.observation_type
            config = {k: v for k, v in env.unwrapped.config["observation"].items()
                      if k not in ("type", "route_points", "route_spacing", "leader")}
            done = False
            while not done:
                theirs = KinematicObservation(env.unwrapped, **config).observe().ravel()
                ours = obs[:observation.kinematics_size]
                np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-9)
                compared += 1
                obs, _, terminated, truncated, _ = env.step(policy.act(obs))
                done = terminated or truncated
    return compared


@pytest.mark.parametrize("side", [1, -1])
def test_the_kinematics_part_is_highway_envs_observation(tmp_path, side):
    env = make_womd_env(two_lanes(tmp_path / "sd_two.pkl", theta=0.4, side=side, speed=10.0))
    assert _kinematics_matches_highway_env(env, ("idm", "random"), seeds=[0]) > 5


def test_the_kinematics_part_is_highway_envs_observation_on_the_real_scenes(real_rollouts):
    # at every decision of every real scene's rollouts, within 1e-9
    env, seen = real_rollouts
    size = env.unwrapped.observation_type.kinematics_size
    compared = [(obs, theirs) for obs, theirs in seen if theirs is not None]
    for obs, theirs in compared:
        np.testing.assert_allclose(obs[:size], theirs, rtol=0, atol=1e-9)
    assert len(compared) > 50


def test_a_misspelt_observation_option_is_refused_with_the_known_ones(tmp_path):
    # highway-env's Kinematics ignores keys it does not know: "crosing" would train an
    # agent without the crossing features, and its definition would record the typo
    path = two_lanes(tmp_path / "sd_two.pkl", theta=0.0, side=1, speed=10.0)
    config = {"observation": {"type": "KinematicsRoute", "crosing": True}}
    with pytest.raises(UnknownNameError, match=r"crosing.*crossing"):
        make_womd_env(path, config=config).reset(seed=0)
    env = make_womd_env(path, config={"observation": {"type": "KinematicsRoute",
                                                       "crossing": True, "see_behind": True}})
    env.reset(seed=0)
    assert env.unwrapped.observation_type.crossing_features
