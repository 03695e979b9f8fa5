"""Collisions of idm traffic on tap_bench/womd-v0 (``traffic="idm"``): traffic vehicles crash
into each other and into replayed agents as highway-env's vehicles do, stop, and the
episode table counts them; generated crossings (angles, speeds, timings) and the four real
files checked against the recorded boxes pair by pair."""

from __future__ import annotations

import math
import pickle
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from highway_env import utils
from highway_env.road.road import Road

from tap_bench.sim.policies import load_policy
from tap_bench.sim.rollout import rollout
from tap_bench.sim.traffic import near_pairs, near_pairs_of, shapes_of, swept_apart
from tap_bench.sim.womd_env import make_womd_env
from tap_bench.sim.womd_road import _pairs_to_check
from tap_bench.sim.womd_scene import CURRENT_STEP, WomdScenes

FILES = ["motion_data_one_scenario.tfrecord", "womd_scenario_input.tfrecord",
         "motion_data_one_example.tfrecord", "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl"]
T = np.arange(91) * 0.1


def track(x0: float, y0: float, angle: float, speed: float, *, valid_from: float = 0.0,
          length: float = 4.5, width: float = 2.0) -> dict:
    """A ScenarioNet vehicle track: a straight line from (x0, y0) at ``angle`` [rad] and
    ``speed`` [m/s], valid from ``valid_from`` [s]."""
    d = np.array([math.cos(angle), math.sin(angle)])
    xy = np.array([x0, y0]) + np.outer(speed * T, d)
    return {"type": "VEHICLE", "state": {
        "position": np.c_[xy, np.zeros(91)], "heading": np.full(91, angle),
        "velocity": np.tile(speed * d, (91, 1)), "valid": T >= valid_from - 1e-9,
        "length": np.full(91, length), "width": np.full(91, width)}}


def lane(x0: float, y0: float, angle: float, length: float = 220.0) -> dict:
    s = np.arange(0.0, length, 0.5)
    return {"type": "LANE_SURFACE_STREET", "entry_lanes": [], "exit_lanes": [],
            "polyline": np.c_[x0 + s * math.cos(angle), y0 + s * math.sin(angle)]}


def scene(path: Path, tracks: dict, lanes: dict) -> str:
    """A ScenarioNet pickle: an ego driving its own lane far from the others, and
    ``tracks`` on ``lanes``."""
    features = {"1": lane(-10.0, -80.0, 0.0), **lanes}
    meta = {"scenario_id": path.stem, "ts": T, "dataset": "waymo", "sdc_id": "ego"}
    with path.open("wb") as f:
        pickle.dump({"metadata": meta, "map_features": features, "dynamic_map_states": {},
                     "tracks": {"ego": track(0.0, -80.0, 0.0, 8.0), **tracks}}, f)
    return str(path)


def crossing(path: Path, angle: float, speed: float, delay: float, meet: float = 5.0) -> str:
    """Car 2 along +x and car 3 at ``angle`` both through the origin at ``speed``; car 3
    reaches it ``delay`` [s] after car 2 (``meet`` s after the start)."""
    reach = meet * speed
    tracks = {"2": track(-reach, 0.0, 0.0, speed),
              "3": track(-(reach + delay * speed) * math.cos(angle),
                         -(reach + delay * speed) * math.sin(angle), angle, speed)}
    far = reach + delay * speed + 20.0
    lanes = {"2": lane(-far, 0.0, 0.0, 2 * far),
             "3": lane(-far * math.cos(angle), -far * math.sin(angle), angle, 2 * far)}
    return scene(path, tracks, lanes)


def drive(env, policy: str = "log", seed: int = 0):
    p = load_policy(policy)
    obs, _ = env.reset(seed=seed)
    p.reset(env, seed=seed)
    done = False
    while not done:
        obs, _, terminated, truncated, _ = env.step(p.act(obs))
        done = terminated or truncated
    return env.trajectories(policy=policy), env.episode_info()


@pytest.mark.parametrize("angle_deg", [60, 90, 125])
@pytest.mark.parametrize("speed", [6.0, 11.0])
def test_idm_traffic_that_crosses_collides_and_stops(tmp_path, angle_deg, speed):
    # they meet 1 s after the current time: too close to stop comfortably, so neither gives
    # way (test_womd_idm_drivers: with room to stop, one does)
    env = make_womd_env(crossing(tmp_path / "sd_cross.pkl", math.radians(angle_deg), speed,
                                 0.0, meet=2.0), traffic="idm")
    table, info = drive(env)
    assert set(env.unwrapped.simulated) == {1, 2}  # rows of tracks 2 and 3
    assert info["traffic_collisions"] == 1 and info["traffic_collisions_with_log"] == 0
    assert info["traffic_collided"].startswith("2 x 3 at ")
    at = float(info["traffic_collided"].split(" at ")[1].rstrip(" s"))
    assert 1.0 <= at <= 2.2  # IDM keeps their logged speed: they meet near t = 2 s
    for tid in ("2", "3"):
        rows = table[table["track_id"] == tid]
        crashed = rows["crashed"].to_numpy(bool)
        first = int(np.argmax(crashed))
        assert crashed[first:].all() and not crashed[:first].any()
        assert rows["t"].iloc[first] == pytest.approx(at)
        # a crashed vehicle brakes to a stop, as highway-env's do
        assert rows["speed"].iloc[-1] < 0.15 * speed
    assert not env.unwrapped.vehicle.crashed  # the ego was not in it


@pytest.mark.parametrize("delay", [-2.0, 2.0])
def test_idm_traffic_that_crosses_apart_does_not_collide(tmp_path, delay):
    env = make_womd_env(crossing(tmp_path / "sd_apart.pkl", math.radians(90), 8.0, delay),
                        traffic="idm")
    table, info = drive(env)
    assert info["traffic_collisions"] == 0 and info["traffic_collided"] == ""
    assert not table.loc[table["track_id"].isin(["2", "3"]), "crashed"].any()
    # the log traffic of the same scene never checks traffic pairs
    env = make_womd_env(crossing(tmp_path / "sd_log.pkl", math.radians(90), 8.0, 0.0))
    assert drive(env)[1]["traffic_collisions"] == 0


def test_a_late_replayed_car_that_rear_ends_idm_traffic_is_counted(tmp_path):
    # cyclist 5 appears at 2 s and replays at 12 m/s into car 2 (idm, 8 m/s, its logged
    # speed): a replayed agent cannot yield, the count says so (a car appearing later is
    # driven by IDM since issue 33: cyclists still replay)
    tracks = {"2": track(0.0, 0.0, 0.0, 8.0),
              "5": {**track(-30.0, 0.0, 0.0, 12.0, valid_from=2.0), "type": "CYCLIST"}}
    env = make_womd_env(scene(tmp_path / "sd_rear.pkl", tracks, {"2": lane(-60, 0, 0)}),
                        traffic="idm")
    table, info = drive(env)
    assert list(env.unwrapped.simulated) == [1]
    assert info["traffic_collisions"] == info["traffic_collisions_with_log"] == 1
    assert info["traffic_collided"].startswith("2 x 5 (log) at ")
    for tid in ("2", "5"):  # both marked in the table, the replayed car too
        assert table.loc[table["track_id"] == tid, "crashed"].any()


def test_vehicles_that_overlap_in_the_log_at_the_start_are_not_a_collision(tmp_path):
    # car 2 starts 2 m behind parked car 4's centre (their boxes overlap in the record)
    tracks = {"2": track(-8.0, 0.0, 0.0, 5.0), "4": track(0.0, 0.0, 0.0, 0.0)}
    env = make_womd_env(scene(tmp_path / "sd_overlap.pkl", tracks, {"2": lane(-60, 0, 0)}),
                        traffic="idm")
    _, info = drive(env)
    assert env.unwrapped.road.exempt == {(1, 2)}
    assert info["traffic_collisions"] == 0


@pytest.fixture
def real(womd_dir) -> list[str]:
    return [str(womd_dir / f) for f in FILES]


def boxes_overlap(a: np.ndarray, b: np.ndarray, da=(0.0, 0.0), db=(0.0, 0.0)) -> bool:
    """Whether two boxes (x, y, heading, length, width) intersect (moved by da and db
    [m]: will intersect)."""
    def polygon(x, y, h, length, width):
        c, s = math.cos(h), math.sin(h)
        corners = np.array([[-1, -1], [-1, 1], [1, 1], [1, -1]]) * [length / 2, width / 2]
        pts = corners @ np.array([[c, s], [-s, c]]) + [x, y]
        return np.vstack([pts, pts[:1]])
    now, soon, _ = utils.are_polygons_intersecting(polygon(*a), polygon(*b), np.asarray(da),
                                                   np.asarray(db))
    return now or soon


def test_traffic_collisions_on_the_real_files_are_the_overlapping_boxes(real):
    # every counted pair overlaps in the recorded table at the step it is counted, and no
    # other pair with a simulated vehicle overlaps at any step (the ego and the pairs that
    # overlap at the start aside): the count is the recorded boxes'
    env = make_womd_env(real, traffic="idm")
    totals = []
    for seed in range(len(env.catalog)):
        table, info = drive(env, "log", seed)
        inner = env.unwrapped
        scene = env.scene
        n = scene.x.shape[0]
        cols = table[["x", "y", "heading", "length", "width"]].to_numpy().reshape(n, -1, 5)
        valid = table["valid"].to_numpy(bool).reshape(n, -1)
        vehicles = {v.row for v in inner.road.vehicles[1:] if getattr(v, "row", -1) >= 0}
        diagonal = np.hypot(cols[:, 0, 3], cols[:, 0, 4])
        sim = np.array(sorted(inner.simulated))
        others = np.array(sorted(vehicles))
        found = {}
        for k in range(CURRENT_STEP + 1, cols.shape[1]):
            gap = np.hypot(cols[sim, k, None, 0] - cols[None, others, k, 0],
                           cols[sim, k, None, 1] - cols[None, others, k, 1])
            near = gap <= (diagonal[sim, None] + diagonal[None, others]) / 2
            for i, j in zip(*np.nonzero(near), strict=True):
                a, b = int(sim[i]), int(others[j])
                pair = (min(a, b), max(a, b))
                if a == b or pair in found or pair in inner.road.exempt \
                        or not (valid[a, k] and valid[b, k]):
                    continue
                if boxes_overlap(cols[a, k], cols[b, k]):
                    found[pair] = k
        counted = {(a, b): k for k, a, b in inner.road.traffic_collisions}
        # highway-env also crashes a pair that will intersect within the step (pushed apart,
        # crashed at the next step): those may never overlap
        for pair, k in found.items():
            assert pair in counted and counted[pair] <= k, (scene.scenario_id, pair)
        for (a, b), k in counted.items():
            if (a, b) in found:
                continue
            speed = table["speed"].to_numpy().reshape(n, -1)
            va, vb = (speed[r, k - 1] * np.array([math.cos(cols[r, k - 1, 2]),
                                                  math.sin(cols[r, k - 1, 2])]) * 0.1
                      for r in (a, b))
            assert boxes_overlap(cols[a, k - 1], cols[b, k - 1], va, vb), (a, b, k)
        assert info["traffic_collisions"] == len(counted)
        totals.append(info["traffic_collisions"])
    # the reactive traffic of the samples is not clean (see docs/closed_loop.md)
    assert sum(totals) > 0


def test_the_episode_table_counts_traffic_collisions(real):
    result = rollout(WomdScenes((real[0], real[3]), traffic="idm"), "idm", "all")
    assert {"traffic_collisions", "traffic_collisions_with_log",
            "traffic_collided"} <= set(result.episodes.columns)
    assert (result.episodes["traffic_collisions"] >= 0).all()
    assert (result.episodes["traffic_collisions_with_log"]
            <= result.episodes["traffic_collisions"]).all()
    logged = rollout(WomdScenes((real[0],), traffic="log"), "idm", "all").episodes
    assert (logged["traffic_collisions"] == 0).all()


# ----------------------------------------------------------------- yielding to walkers

T15 = np.arange(151) * 0.1
CROSS_X = 75.0  # [m] where the pedestrian crosses, 20 m into the street's second lane


def walker_scene(path: Path, *, car_speed: float, walk_speed: float, angle: float,
                 side: int, offset: float | None = None) -> str:
    """A 15 s ScenarioNet pickle: car 2 along +x from x = 0 at ``car_speed``; a pedestrian
    crossing the street at x = :data:`CROSS_X`, heading ``angle`` [rad] to the lane from its
    ``side`` (+1: from the left), reaching the lane centre when the car would be 15 m short
    of it (or walking along the lane ``offset`` metres to its side when given)."""
    def moving(x0, y0, heading, speed, kind, length, width):
        d = np.array([math.cos(heading), math.sin(heading)])
        xy = np.array([x0, y0]) + np.outer(speed * T15, d)
        return {"type": kind, "state": {
            "position": np.c_[xy, np.zeros(151)], "heading": np.full(151, heading),
            "velocity": np.tile(speed * d, (151, 1)), "valid": np.ones(151, bool),
            "length": np.full(151, length), "width": np.full(151, width)}}

    cross_x = CROSS_X
    if offset is None:
        heading = -side * angle  # from the left (+y) walking towards -y, or the reverse
        meet = (cross_x - 15.0) / car_speed  # [s] when it is on the lane centre
        x0 = cross_x - math.cos(heading) * walk_speed * meet
        y0 = -math.sin(heading) * walk_speed * meet
        walker = moving(x0, y0, heading, walk_speed, "PEDESTRIAN", 0.5, 0.5)
    else:
        walker = moving(0.0, offset, 0.0, walk_speed, "PEDESTRIAN", 0.5, 0.5)
    s = np.arange(0.0, 400.0, 0.5)
    before, after = np.arange(-10.0, 55.0, 0.5), np.arange(55.0, 390.0, 0.5)
    features = {"1": {"type": "LANE_SURFACE_STREET", "entry_lanes": [], "exit_lanes": [],
                      "polyline": np.c_[s - 10.0, np.full_like(s, -80.0)]},
                # the street is two lanes, one after the other: the crossing is on the
                # second, beyond what a vehicle on the first sees as its leader
                "2": {"type": "LANE_SURFACE_STREET", "entry_lanes": [], "exit_lanes": ["3"],
                      "polyline": np.c_[before, np.zeros_like(before)]},
                "3": {"type": "LANE_SURFACE_STREET", "entry_lanes": ["2"], "exit_lanes": [],
                      "polyline": np.c_[after, np.zeros_like(after)]}}
    meta = {"scenario_id": path.stem, "ts": T15, "dataset": "waymo", "sdc_id": "ego"}
    tracks = {"ego": moving(0.0, -80.0, 0.0, 8.0, "VEHICLE", 4.5, 2.0),
              "2": moving(0.0, 0.0, 0.0, car_speed, "VEHICLE", 4.5, 2.0), "p": walker}
    with path.open("wb") as f:
        pickle.dump({"metadata": meta, "map_features": features, "dynamic_map_states": {},
                     "tracks": tracks}, f)
    return str(path)


@pytest.mark.parametrize("car_speed", [8.0, 13.0])
@pytest.mark.parametrize("walk_speed", [1.0, 1.6])
@pytest.mark.parametrize("angle_deg, side", [(90, 1), (90, -1), (60, 1), (120, -1)])
def test_idm_traffic_yields_to_a_crossing_pedestrian(tmp_path, car_speed, walk_speed,
                                                     angle_deg, side):
    env = make_womd_env(walker_scene(tmp_path / "sd_walk.pkl", car_speed=car_speed,
                                     walk_speed=walk_speed, angle=math.radians(angle_deg),
                                     side=side), traffic="idm")
    table, info = drive(env)
    assert list(env.unwrapped.simulated) == [1]
    assert info["traffic_collisions"] == 0, info["traffic_collided"]
    car = table[table["track_id"] == "2"]
    walker = table[table["track_id"] == "p"]
    # it slowed down (or stopped) for the pedestrian before the crossing, braking within
    # IDM's comfortable 5 m/s^2 (seen only from the crossing's lane, IDM brakes at 5.5-6),
    # then drove on
    decel = -np.diff(car["speed"].to_numpy()) / 0.1
    assert decel.max() < 5.0
    slowest = car.loc[car["speed"].idxmin()]
    # (idm traffic sees where the pedestrian will be along its logged path and slows as much
    # as it needs: to 51-54 % of 8 m/s for the 1.6 m/s walker, who is across by then)
    assert slowest["speed"] < 0.6 * car_speed and slowest["x"] < CROSS_X - 2.25
    assert car["x"].iloc[-1] > CROSS_X + 5.0
    gap = np.hypot(car["x"].to_numpy() - walker["x"].to_numpy(),
                   car["y"].to_numpy() - walker["y"].to_numpy())
    assert gap.min() > 2.0


def test_idm_does_not_yield_to_a_pedestrian_beside_the_lane(tmp_path):
    # walking along the street 4 m to the side: no slowing down
    env = make_womd_env(walker_scene(tmp_path / "sd_side.pkl", car_speed=10.0,
                                     walk_speed=1.4, angle=0.0, side=1, offset=4.0),
                        traffic="idm")
    table, _ = drive(env)
    car = table[(table["track_id"] == "2") & (table["t"] >= 1.0)]
    assert car["speed"].min() > 9.5



@pytest.mark.parametrize("traffic", ["log", "idm"])
def test_an_idm_ego_yields_to_a_crossing_pedestrian(tmp_path, traffic):
    # car 2 driven as the ego by the idm policy: the same rule
    env = make_womd_env(walker_scene(tmp_path / "sd_ego.pkl", car_speed=10.0,
                                     walk_speed=1.4, angle=math.radians(90), side=-1),
                        ego="2", traffic=traffic)
    table, _ = drive(env, "idm")
    assert not env.unwrapped.vehicle.crashed
    ego = table[table["is_ego"]]
    assert ego["speed"].min() < 5.0 and ego["x"].iloc[-1] > CROSS_X + 5.0
    walker = table[table["track_id"] == "p"]
    assert np.hypot(ego["x"].to_numpy() - walker["x"].to_numpy(),
                    ego["y"].to_numpy() - walker["y"].to_numpy()).min() > 2.0


def test_the_command_says_how_clean_the_reactive_traffic_was(real, tmp_path, capsys):
    from tap_bench.cli import main

    out = tmp_path / "log.parquet"
    assert main(["rollout", "--womd", real[3], "--policy", "log", "--traffic", "idm",
                 "-o", str(out)]) == 0
    episodes = pd.read_parquet(tmp_path / "log.episodes.parquet")
    n, with_log = (int(episodes[c].sum()) for c in ("traffic_collisions",
                                                    "traffic_collisions_with_log"))
    assert n > 0  # eb4b91b10ca94ff2: late replayed cars run into idm traffic
    printed = capsys.readouterr().out
    assert (f"idm traffic collisions (the ego's aside): {n} in 1 of 1 episodes, "
            f"{with_log} with a replayed agent") in printed


@pytest.mark.parametrize("traffic", ["log", "idm"])
@pytest.mark.parametrize("policy", ["log", "idm"])
def test_the_roads_state_arrays_are_its_vehicles_states(womd_dir, traffic, policy):
    # the arrays the step reads (the log's laid out once, the others' from their
    # attributes) against every vehicle's own attributes, and the near pairs they give
    # against near_pairs of the vehicles, after every simulated step of a busy real scene
    env = make_womd_env(str(womd_dir / "motion_data_one_example.tfrecord"), traffic=traffic)
    inner = env.unwrapped
    checked = []
    swept = {True: 0, False: 0}
    neighbours = {True: 0, False: 0}

    def check() -> None:
        road = inner.road
        layout, now = road._snapshot()
        vehicles = list(road.vehicles)
        assert list(layout.vehicles) == vehicles
        np.testing.assert_array_equal(now["position"], [v.position for v in vehicles])
        np.testing.assert_array_equal(now["heading"], [v.heading for v in vehicles])
        np.testing.assert_array_equal(now["speed"], [v.speed for v in vehicles])
        np.testing.assert_array_equal(now["collidable"], [v.collidable for v in vehicles])
        moving = now["collidable"]
        movers = [v for v in vehicles if v.collidable]
        shapes = shapes_of(now["position"][moving], layout.diagonal[moving],
                           layout.length[moving], layout.width[moving],
                           now["heading"][moving], now["speed"][moving],
                           now["checks"][moving], now["own"][moving])
        near = near_pairs_of(shapes, len(movers), 0.1)
        np.testing.assert_array_equal(near, near_pairs(movers, [], 0.1))
        # pairs swept apart over the step: highway-env's test finds nothing there either
        i, j = np.nonzero(np.triu(near | near.T, 1))
        position = now["position"][moving]
        got = _pairs_to_check(np.ascontiguousarray(position[:, 0]),
                              np.ascontiguousarray(position[:, 1]), layout.diagonal[moving],
                              layout.length[moving], layout.width[moving],
                              now["heading"][moving], now["speed"][moving],
                              now["checks"][moving], now["own"][moving], 0.1)
        np.testing.assert_array_equal(got[0], i)  # the compiled pairs: the same
        np.testing.assert_array_equal(got[1], j)
        np.testing.assert_array_equal(got[2], swept_apart(shapes, i, j, 0.1))
        for a, b, far in zip(i, j, swept_apart(shapes, i, j, 0.1), strict=True):
            found = utils.are_polygons_intersecting(
                movers[a].polygon(), movers[b].polygon(), movers[a].velocity * 0.1,
                movers[b].velocity * 0.1)
            if far:
                assert not found[0] and not found[1]
            swept[bool(far)] += 1
        # between steps (the decision's own act comes here) the neighbour search runs
        # over every vehicle's arrays: highway-env's search over the vehicles, the same
        for vehicle in (inner.vehicle, *vehicles[1::7]):
            lane_index = getattr(vehicle, "lane_index", None)
            if not lane_index:
                continue
            for index in (lane_index, *road.network.side_lanes(lane_index)):
                assert road.neighbour_vehicles(vehicle, index) == \
                    Road.neighbour_vehicles(road, vehicle, index)
                neighbours[road.neighbour_vehicles(vehicle, index) != (None, None)] += 1
        checked.append(len(vehicles))

    p = load_policy(policy)
    obs, _ = env.reset(seed=0)
    p.reset(env, seed=0)
    record = inner.frame_listener
    inner.frame_listener = lambda k, measured: (check(), record(k, measured))
    check()
    done = False
    while not done:
        obs, _, terminated, truncated, _ = env.step(p.act(obs))
        done = terminated or truncated
    assert len(checked) > 5 and min(checked) > 100
    assert neighbours[True] > 0  # some have a leader or follower there
    assert swept[True] > 0  # some near pairs are swept apart (and skipped by the step)
