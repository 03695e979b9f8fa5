"""The road user in the ego's own swept box (``swept_leader``: where the ego's box goes over
the next 3 s from its heading, speed and steering) and the safety layer that caps the ego's
acceleration by IDM's braking for it (:mod:`tap_bench.sim.womd_safety`): values worked out
by hand."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from tap_bench.errors import ParameterError
from tap_bench.sim.womd_env import make_womd_env
from tap_bench.sim.womd_observation import (
    CLOSING_SCALE,
    LEADER_FEATURES,
    SWEPT_HORIZON,
    SWEPT_MARGIN,
    SWEPT_STEP,
    swept_leader,
    swept_poses,
)
from tap_bench.sim.womd_safety import SafetyLayer, safety_layer


def car(x: float, y: float, heading: float = 0.0, speed: float = 0.0, steering: float = 0.0,
        length: float = 4.5, width: float = 2.0) -> SimpleNamespace:
    return SimpleNamespace(position=np.array([x, y]), heading=heading, speed=speed,
                           velocity=speed * np.array([math.cos(heading), math.sin(heading)]),
                           LENGTH=length, WIDTH=width, action={"steering": steering,
                                                               "acceleration": 0.0})


@pytest.mark.parametrize("angle", [0.0, 2.0, -1.2])
def test_a_car_standing_beside_the_route_inside_the_swept_box_is_seen(angle):
    """Ego 2 m wide at 10 m/s heading ``angle``: its swept box reaches 1 + 0.25 m to each
    side over 30 m. A car standing 2.8 m to its right, 20 m ahead, turned 30 degrees towards
    the ego's line: its near front corner is 2.8 - (2.25 sin 30 + 1 cos 30) = 0.81 m from the
    line, inside; the ego's front meets it after about 20 - 2.25 - 2.25 cos 30 ... (the first
    pose at which the boxes overlap, found by a fine walk below)."""
    c, s = math.cos(angle), math.sin(angle)

    def at(lon: float, lat: float) -> tuple[float, float]:  # lat: + to the ego's left
        return lon * c - lat * s, lon * s + lat * c

    ego = car(0.0, 0.0, heading=angle, speed=10.0)
    inside = car(*at(20.0, -2.8), heading=angle + math.radians(30))
    lead = swept_leader(ego, [inside])
    assert math.isfinite(lead.gap)
    # by hand: the box's corners in the ego's frame; the ego's front (lon 2.25 + s) meets
    # the corner whose |lat| <= 1.25 nearest along: the near front corner (lon 20 + 2.25 cos
    # 30 - 1 sin 30... on the ego's side) at lat -2.8 + 2.25 sin 30 + 1 cos 30 = -0.809
    h = math.radians(30)
    corners = [(20.0 + a * 2.25 * math.cos(h) - b * 1.0 * math.sin(h),
                -2.8 + a * 2.25 * math.sin(h) + b * 1.0 * math.cos(h))
               for a in (1, -1) for b in (1, -1)]
    near = [lon for lon, lat in corners if abs(lat) <= 1.0 + SWEPT_MARGIN]
    # the box edge between the near corners also crosses the band: the first contact is
    # the smallest lon of the box's part inside |lat| <= 1.25
    edge = _band_min_lon(corners, 1.0 + SWEPT_MARGIN)
    assert near and edge <= min(near)
    expected = edge - 2.25  # the ego's centre travel until its front reaches it
    assert expected - SWEPT_STEP - 1e-9 <= lead.gap <= expected + 1e-9
    assert lead.closing == pytest.approx(10.0)


def _band_min_lon(corners: list[tuple[float, float]], half: float) -> float:
    """The smallest lon of the convex polygon ``corners`` (in order around it or not) inside
    |lat| <= half: its corners inside, and where its edges cross lat = +-half."""
    pts = sorted(corners, key=lambda p: math.atan2(p[1] - np.mean([q[1] for q in corners]),
                                                   p[0] - np.mean([q[0] for q in corners])))
    found = [lon for lon, lat in pts if abs(lat) <= half]
    for (x0, y0), (x1, y1) in zip(pts, pts[1:] + pts[:1], strict=True):
        for bound in (-half, half):
            if (y0 - bound) * (y1 - bound) < 0:
                found.append(x0 + (bound - y0) / (y1 - y0) * (x1 - x0))
    return min(found)


@pytest.mark.parametrize("angle", [0.0, 2.0, -1.2])
def test_a_car_standing_outside_the_swept_box_is_not_seen(angle):
    """The same car parallel to the ego's line, 3.3 m to its right: its near side is 2.3 m
    from the line, beyond the swept box's 1.25; and one inside the box but behind the ego."""
    c, s = math.cos(angle), math.sin(angle)
    ego = car(0.0, 0.0, heading=angle, speed=10.0)
    beside = car(20.0 * c + 3.3 * s, 20.0 * s - 3.3 * c, heading=angle)
    behind = car(-8.0 * c, -8.0 * s, heading=angle)
    assert not math.isfinite(swept_leader(ego, [beside, behind]).gap)
    # moved 1.1 m nearer the line (near side at 1.2 m): in the box
    closer = car(20.0 * c + 2.2 * s, 20.0 * s - 2.2 * c, heading=angle)
    assert math.isfinite(swept_leader(ego, [beside, closer]).gap)


def test_the_swept_box_follows_the_steering_not_the_route():
    """Steering to one side: the arc bends that way (heading rate v sin(beta) / (L / 2)); a
    car standing on the arc 1 rad round is seen, one on the mirrored arc (the other way) is
    not; the poses straight on along the heading are swept too (a slow ego's steering swings
    from lock to lock: a car right ahead stays in the box); the turn stops at 90 degrees."""
    steering = 0.2
    ego = car(0.0, 0.0, speed=10.0, steering=steering)
    beta = math.atan(0.5 * math.tan(steering))
    kappa = math.sin(beta) / 2.25
    s, _, heading = swept_poses(ego)
    assert s.max() == pytest.approx(10.0 * SWEPT_HORIZON)
    assert heading[1] - heading[0] == pytest.approx(kappa * SWEPT_STEP)
    r = 1.0 / kappa  # [m] ~ 22.4 m: 30 m of way turns 1.34 rad
    x = r * math.sin(1.0 + beta) - r * math.sin(beta)
    y = r * math.cos(beta) - r * math.cos(1.0 + beta)
    on_arc = car(x, y, heading=1.0 + beta)
    mirrored = car(x, -y, heading=-1.0 - beta)
    ahead = car(20.0, 0.0)
    assert math.isfinite(swept_leader(ego, [on_arc]).gap)
    assert not math.isfinite(swept_leader(ego, [mirrored]).gap)
    assert 20.0 - 4.5 - SWEPT_STEP <= swept_leader(ego, [ahead]).gap <= 20.0 - 4.5
    wide = car(0.0, 0.0, speed=30.0, steering=0.3)
    _, _, heading = swept_poses(wide)
    arc = heading[:len(heading) // 2]  # then the poses straight on
    assert arc.max() - arc.min() == pytest.approx(math.pi / 2)


def test_the_safety_layer_caps_by_idm_s_braking_and_counts_its_steps():
    """A standing car 20.5 m ahead (bumper gap 16 m) of an ego at 10 m/s: IDM (a 3, b 3,
    T 1 s, s0 2 m) wants s* = 2 + 10 + 10 * 10 / (2 * 3) = 28.67 m, so the cap is
    3 (1 - (28.67 / gap)^2), gap the swept test's (16 m, less a step at most)."""
    layer = SafetyLayer()
    ego = car(0.0, 0.0, speed=10.0)
    ego.action["acceleration"] = 1.0
    lead = car(20.5, 0.0)
    gap = swept_leader(ego, [lead]).gap
    assert 16.0 - SWEPT_STEP <= gap <= 16.0
    layer.apply(ego, [lead], step=11)
    wanted = 2.0 + 10.0 + 100.0 / 6.0
    assert ego.action["acceleration"] == pytest.approx(max(3 * (1 - (wanted / gap) ** 2), -8))
    assert ego.action["acceleration"] < 0
    assert (layer.steps, layer.capped, layer.braked) == (1, 1, 1)
    layer.apply(ego, [lead], step=11)  # a decision acts twice in one step: counted once
    assert (layer.steps, layer.capped, layer.braked) == (1, 1, 1)
    free = car(0.0, 0.0, speed=10.0)
    free.action["acceleration"] = 2.5
    layer.apply(free, [], step=12)  # nothing in the box: the policy's acceleration
    assert free.action["acceleration"] == 2.5 and (layer.steps, layer.capped) == (2, 1)
    assert layer.cap(10.0, 0.05, 10.0) == -8.0  # never more than the emergency braking


def test_a_safety_layer_setting_is_a_flag_or_known_fields():
    assert safety_layer(None) is None and safety_layer(False) is None
    assert safety_layer(True) == SafetyLayer()
    assert safety_layer({"time_gap": 1.5}).time_gap == 1.5
    with pytest.raises(ParameterError, match="time_gap"):
        safety_layer({"time_gaps": 1.5})
    with pytest.raises(ParameterError, match="min_gap"):
        SafetyLayer(min_gap=-1.0)
    with pytest.raises(ParameterError):
        safety_layer("yes")


def _standing_beside(path, ego_lat: float, car_lat: float) -> str:
    """A ScenarioNet pickle: one straight lane along x (centre at lat 0; WOMD axes, lat +
    left); the ego drives it at 10 m/s from lon 0, ``ego_lat`` m off the centre; a car
    stands at lon 40, ``car_lat`` m off the centre, parallel to it."""
    import pickle

    t = np.arange(91) * 0.1

    def track(lon, lat, speed):
        x = lon + speed * t
        return {"type": "VEHICLE", "state": {
            "position": np.c_[x, np.full(91, lat), np.zeros(91)], "heading": np.zeros(91),
            "velocity": np.c_[np.full(91, speed), np.zeros(91)], "valid": np.ones(91, bool),
            "length": np.full(91, 4.5), "width": np.full(91, 2.0)}}

    lon = np.arange(-20.0, 300.0, 1.0)
    features = {"1": {"type": "LANE_SURFACE_STREET", "polyline": np.c_[lon, np.zeros_like(lon)],
                      "entry_lanes": [], "exit_lanes": []}}
    tracks = {"ego": track(0.0, ego_lat, 10.0), "parked": track(40.0, car_lat, 0.0)}
    meta = {"scenario_id": path.stem, "ts": t, "dataset": "waymo", "sdc_id": "ego"}
    with path.open("wb") as f:
        pickle.dump({"metadata": meta, "tracks": tracks, "map_features": features,
                     "dynamic_map_states": {}}, f)
    return str(path)


OBSERVATION = {"type": "KinematicsRoute", "leader": True, "leader_corners": True}


@pytest.mark.parametrize(("car_lat", "seen"), [(2.5, True), (4.0, False)])
def test_the_observation_s_leader_in_the_swept_box_beside_the_route(tmp_path, car_lat, seen):
    """The ego 1.5 m left of its lane's centre (its route's path converges on the centre);
    a car standing 2.5 m left of the centre is 1 m left of the ego's line: its box (lat 1.5
    to 3.5) is more than half the ego's width from the route's path (the centre: 1.5 > 1),
    so the route's leader (corners too) does not name it; the ego's swept box (lat 0.25 to
    2.75) meets it: gap 40 - 10 - 4.5 = 25.5 m (the ego at lon 10 at the current time). At
    4 m (box from lat 3) neither names it."""
    path = _standing_beside(tmp_path / f"sd_beside_{car_lat}.pkl", 1.5, car_lat)
    route = make_womd_env(path, config={"observation": OBSERVATION})
    swept = make_womd_env(path, config={"observation": {**OBSERVATION, "leader_swept": True}})
    obs_route, _ = route.reset(seed=0)
    obs_swept, _ = swept.reset(seed=0)
    horizon = swept.unwrapped.observation_type.horizon
    gap = obs_swept[-len(LEADER_FEATURES) + 1]
    assert obs_route[-len(LEADER_FEATURES) + 1] == 1.0  # no leader by the route
    if seen:
        assert (25.5 - SWEPT_STEP) / horizon - 1e-6 <= gap <= 25.5 / horizon + 1e-6
        assert obs_swept[-2] == pytest.approx(10.0 / CLOSING_SCALE, abs=1e-5)
    else:
        assert gap == 1.0


def test_the_safety_layer_stops_the_ego_before_the_car_in_its_swept_box(tmp_path):
    """Always FASTER: without the layer the ego drives into the car standing half in its
    lane (1.8 m left of the centre, its box from lat 0.8: the ego, steered to the centre,
    reaches lat 1) at fault; with it (the agent's action config) it stops short, and the
    layer counts the steps it braked in."""
    path = _standing_beside(tmp_path / "sd_shield.pkl", 1.5, 1.8)
    action = {"type": "DiscreteMetaAction", "target_speeds": [0.0, 5.0, 10.0, 15.0, 20.0]}
    results = {}
    for layer in (False, True):
        env = make_womd_env(path, config={"observation": OBSERVATION,
                                          "action": {**action, "safety_layer": layer}})
        env.reset(seed=0)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(3)
            done = terminated or truncated
        results[layer] = (env.episode_info(), env.unwrapped.vehicle.safety)
    hit, unhit = results[False][0], results[True][0]
    assert hit["crash_at_fault"] and results[False][1] is None
    assert not unhit["crash_at_fault"] and unhit["crash_fault"] == ""
    layer = results[True][1]
    assert layer.steps == 80 and layer.braked > 0 and layer.capped >= layer.braked


def test_an_agent_trained_with_the_layer_drives_with_it_wherever_it_is_rolled_out(
        womd_dir, tmp_path, monkeypatch):
    """``tap-bench train --action safety_layer=true`` records the action config in the
    definition; a rollout of that definition builds the env with it (the layer judges the
    ego's steps); a bad setting is refused before any work. The training is PPO's smallest
    (one update of 32 steps, where the defaults' 256 steps and 10 epochs cost 2-3 CPU s):
    what is checked is the config that the command records, not what the agent learns."""
    pytest.importorskip("stable_baselines3")
    import importlib

    from tap_bench.cli import main
    from tap_bench.rl import training

    monkeypatch.setitem(training.HYPERPARAMETERS, "ppo",
                        {**training.HYPERPARAMETERS["ppo"], "n_steps": 32, "batch_size": 16,
                         "n_epochs": 1})
    from tap_bench.sim.policies import load_policy
    from tap_bench.sim.womd_scene import WomdScenes

    rollouts = importlib.import_module("tap_bench.sim.rollout")  # the module, not the function
    files = str(womd_dir / "womd_scenario_input.tfrecord")
    out = tmp_path / "ppo-layer.zip"
    with pytest.raises(SystemExit, match="safety_layer"):
        main(["train", "--algo", "ppo", "--env", "womd", "--womd", files, "--action",
              'safety_layer={"gap": 1}', "--timesteps", "64", "-o", str(out)])
    assert main(["train", "--algo", "ppo", "--env", "womd", "--womd", files, "--observation",
                 "leader_swept=true", "--action", "safety_layer=true", "--timesteps", "32",
                 "--n-envs", "1", "-o", str(out)]) == 0
    doc = json.loads(out.with_suffix(".json").read_text())
    assert doc["params"]["action"]["safety_layer"] is True
    assert doc["params"]["observation"]["leader_swept"] is True
    assert "--action safety_layer=true" in doc["params"]["command"]
    policy = load_policy(str(out.with_suffix(".json")))
    assert rollouts.policy_overrides(policy)["action"]["safety_layer"] is True
    assert "action" not in rollouts.policy_overrides(load_policy("lane-keeping"))
    rollouts._ENVS.clear()
    result = rollouts.rollout(WomdScenes((files,)), str(out.with_suffix(".json")), "all",
                              workers=1)
    assert list(result.episodes["status"]) == ["ok"]
    (env,) = [e for e in rollouts._ENVS.values()]
    assert env.unwrapped.config["action"]["safety_layer"] is True
    assert env.unwrapped.vehicle.safety is not None and env.unwrapped.vehicle.safety.steps > 0
