"""idm traffic that drives like people (issue 33): drivers drawn per rollout, IDM with the
ACC heuristic's comfortable braking, giving way at crossings by gap acceptance, stopping at
stop signs. Generated scenes (ScenarioNet pickles of test_womd_traffic)."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from tap_bench.sim.policies import load_policy
from tap_bench.sim.womd_env import make_womd_env
from tap_bench.sim.womd_road import (
    NOMINAL_DRIVER,
    DriverParameters,
    _idm_acc,
    _idm_compiled,
    _segment_hits,
    draw_driver,
)
from tap_bench.sim.womd_scene import CURRENT_STEP
from tap_bench.stats.bootstrap import named_rng

T = np.arange(91) * 0.1


# scenes as in test_womd_traffic (its helpers cannot be imported under --import-mode=importlib)
def track(x0: float, y0: float, angle: float, speed: float) -> dict:
    """A ScenarioNet vehicle track along a straight line at ``speed`` [m/s]."""
    d = np.array([math.cos(angle), math.sin(angle)])
    xy = np.array([x0, y0]) + np.outer(speed * T, d)
    return {"type": "VEHICLE", "state": {
        "position": np.c_[xy, np.zeros(91)], "heading": np.full(91, angle),
        "velocity": np.tile(speed * d, (91, 1)), "valid": np.ones(91, bool),
        "length": np.full(91, 4.5), "width": np.full(91, 2.0)}}


def lane(x0: float, y0: float, angle: float, length: float = 220.0) -> dict:
    s = np.arange(0.0, length, 0.5)
    return {"type": "LANE_SURFACE_STREET", "entry_lanes": [], "exit_lanes": [],
            "polyline": np.c_[x0 + s * math.cos(angle), y0 + s * math.sin(angle)]}


def scene(path, tracks: dict, features: dict) -> str:
    """A ScenarioNet pickle: an ego on its own lane far away, ``tracks`` on ``features``."""
    meta = {"scenario_id": path.stem, "ts": T, "dataset": "waymo", "sdc_id": "ego"}
    with path.open("wb") as f:
        pickle.dump({"metadata": meta, "map_features": {"1": lane(-10.0, -80.0, 0.0),
                                                        **features},
                     "dynamic_map_states": {},
                     "tracks": {"ego": track(0.0, -80.0, 0.0, 8.0), **tracks}}, f)
    return str(path)


def crossing(path, angle: float, speed: float) -> str:
    """Car 2 along +x and car 3 at ``angle``, both through the origin at 5 s."""
    reach = 5.0 * speed
    far = reach + 20.0
    return scene(path, {"2": track(-reach, 0.0, 0.0, speed),
                        "3": track(-reach * math.cos(angle), -reach * math.sin(angle), angle,
                                   speed)},
                 {"2": lane(-far, 0.0, 0.0, 2 * far),
                  "3": lane(-far * math.cos(angle), -far * math.sin(angle), angle, 2 * far)})


def drive(env):
    policy = load_policy("log")
    obs, _ = env.reset(seed=0)
    policy.reset(env, seed=0)
    done = False
    while not done:
        obs, _, terminated, truncated, _ = env.step(policy.act(obs))
        done = terminated or truncated
    return env.trajectories(policy="log"), env.episode_info()


def test_drawn_drivers_stay_in_their_ranges_around_the_nominal_one():
    rng = named_rng(0, "test", "drivers")
    drivers = [draw_driver(rng) for _ in range(2000)]
    gaps = np.array([d.time_gap for d in drivers])
    assert gaps.min() >= 0.6 and gaps.max() <= 2.5
    assert np.median(gaps) == pytest.approx(NOMINAL_DRIVER.time_gap, abs=0.05)
    factors = np.array([d.speed_factor for d in drivers])
    assert np.median(factors) == pytest.approx(1.0, abs=0.02)
    assert 0.75 <= factors.min() and factors.max() <= 1.3
    assert np.median([d.comfortable_braking for d in drivers]) == pytest.approx(2.0, abs=0.1)
    assert all(0 <= d.politeness <= 0.5 for d in drivers)
    with pytest.raises(ValueError, match="emergency_braking"):
        DriverParameters(comfortable_braking=3.0, emergency_braking=2.0)


def crossings(px: np.ndarray, py: np.ndarray, ax, ay, bx, by) -> list[tuple]:
    """The definition of where a polyline crosses or touches segments (not collinear):
    (its segment, the segment, d1, d2) for every pair, in order."""
    out = []
    for k in range(len(px) - 1):
        for q in range(len(ax)):
            d1 = (bx[q] - ax[q]) * (py[k] - ay[q]) - (by[q] - ay[q]) * (px[k] - ax[q])
            d2 = (bx[q] - ax[q]) * (py[k + 1] - ay[q]) - (by[q] - ay[q]) * (px[k + 1] - ax[q])
            d3 = (px[k + 1] - px[k]) * (ay[q] - py[k]) - (py[k + 1] - py[k]) * (ax[q] - px[k])
            d4 = (px[k + 1] - px[k]) * (by[q] - py[k]) - (py[k + 1] - py[k]) * (bx[q] - px[k])
            if d1 * d2 <= 0 and d3 * d4 <= 0 and d1 != d2 and d3 != d4:
                out.append((k, q, d1, d2))
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lane_crossings_are_every_segment_pair_that_crosses_or_touches(seed):
    rng = np.random.default_rng(seed)
    line = np.cumsum(rng.normal(0.0, 3.0, (30, 2)), axis=0)
    a = rng.uniform(line.min(0) - 5, line.max(0) + 5, (200, 2))
    b = a + rng.normal(0.0, 6.0, (200, 2))
    # lanes sampled through the same point (touching) and along the same line (collinear)
    a[:10], b[:10] = line[5:15], line[5:15] + rng.normal(0.0, 2.0, (10, 2))
    a[10:20], b[10:20] = line[10:20], line[11:21]
    # level and upright segments through its points (flat boxes), and ones ending on them
    level, upright = np.array([3.0, 0.0]), np.array([0.0, 3.0])
    a[20:30], b[20:30] = line[0:10] - level, line[0:10] + level
    a[30:40], b[30:40] = line[0:10] - upright, line[0:10]
    near = np.arange(200)
    got = _segment_hits(line[:, 0].copy(), line[:, 1].copy(), near, a[:, 0].copy(),
                        a[:, 1].copy(), b[:, 0].copy(), b[:, 1].copy())
    want = crossings(line[:, 0], line[:, 1], a[:, 0], a[:, 1], b[:, 0], b[:, 1])
    assert len(want) > 20  # touching ones among them
    assert [(int(k), int(q)) for k, q, *_ in got] == [(k, q) for k, q, *_ in want]
    np.testing.assert_allclose(got[:, 2:], np.array([w[2:] for w in want]), rtol=1e-12,
                               atol=1e-12)
    # collinear overlaps are not crossings
    assert not any(10 <= q < 20 and k == q for k, q, *_ in want)

def test_compiled_idm_is_the_plain_one_bit_for_bit():
    # drawn drivers, speeds from standing to fast, gaps from touching to far, leaders slower
    # and faster (the heuristic's branch and IDM's): the same float every time
    rng = np.random.default_rng(3)
    for _ in range(3000):
        p = draw_driver(rng)
        v, v0 = rng.uniform(0.0, 30.0), rng.uniform(0.01, 30.0)
        gap = rng.choice([rng.uniform(-1.0, 0.5), rng.uniform(0.0, 10.0),
                          rng.uniform(0.0, 200.0)])
        lead = rng.choice([0.0, rng.uniform(0.0, 30.0), v])
        want = _idm_acc(p, v, v0, gap, lead)
        got = _idm_compiled(v, v0, gap, lead, p.min_gap, p.time_gap, p.max_acceleration,
                            p.comfortable_braking, p.delta, p.coolness, 2.0)
        assert got == want, (v, v0, gap, lead, p)


def test_a_tight_but_harmless_gap_is_closed_at_comfortable_braking():
    # 10 m/s, 10 m behind a leader at 9 m/s: plain IDM brakes at 1.5 (1 - (10/15)^4 -
    # (16.89/10)^2) = -3.07 m/s^2; the leader keeping its speed needs only 0.05 m/s^2, so
    # the ACC heuristic brakes about b = 2
    p = NOMINAL_DRIVER
    a = _idm_acc(p, 10.0, 15.0, 10.0, 9.0)
    s_star = p.min_gap + 10 * p.time_gap + 10 * 1 / (2 * math.sqrt(p.max_acceleration
                                                                   * p.comfortable_braking))
    plain = p.max_acceleration * (1 - (10 / 15) ** 4 - (s_star / 10) ** 2)
    assert plain < -3.0
    assert -p.comfortable_braking - 0.1 < a < -1.0
    # free road at the desired speed: no acceleration; standing: a
    assert _idm_acc(p, 15.0, 15.0, 1e6, 15.0) == pytest.approx(0.0, abs=1e-9)
    assert _idm_acc(p, 0.0, 15.0, 1e6, 0.0) == pytest.approx(p.max_acceleration)
    # a real emergency still brakes hard (the vehicle clips it at its emergency braking)
    assert _idm_acc(p, 15.0, 15.0, 3.0, 0.0) < -p.emergency_braking


def _states(env, seed: int, rollout: int) -> dict:
    policy = load_policy("log")
    obs, _ = env.reset(seed=seed, options={"rollout": rollout})
    policy.reset(env, seed=seed)
    done = False
    while not done:
        obs, _, terminated, truncated, _ = env.step(policy.act(obs))
        done = terminated or truncated
    return env.recorded_states()


def test_rollouts_differ_and_each_is_reproducible(tmp_path):
    # a car at 8 m/s behind one at 6 m/s on a straight lane: its drawn driver decides how
    # close it follows and how fast it would go
    tracks = {"2": track(0.0, 0.0, 0.0, 8.0), "3": track(25.0, 0.0, 0.0, 6.0)}
    env = make_womd_env(scene(tmp_path / "sd_follow.pkl", tracks, {"2": lane(-60, 0, 0)}),
                        traffic="idm")
    first = _states(env, 0, 1)
    again = _states(env, 0, 1)
    other = _states(env, 0, 2)
    for name in ("x", "y", "heading", "speed"):
        np.testing.assert_array_equal(first[name], again[name])  # bit for bit
    assert not np.array_equal(first["x"][1], other["x"][1], equal_nan=True)
    assert env.unwrapped.simulated[1].driver != NOMINAL_DRIVER
    _states(env, 0, 0)  # rollout 0: the nominal driver
    assert env.unwrapped.simulated[1].driver == NOMINAL_DRIVER


@pytest.mark.parametrize("angle_deg", [60, 90, 125])
@pytest.mark.parametrize("speed", [6.0, 11.0])
def test_traffic_gives_way_at_an_unsignalled_crossing(tmp_path, angle_deg, speed):
    # the two cars reach the crossing point together (test_womd_traffic: they collide): one
    # gives way (the later one by scene row), both get through, nobody collides
    env = make_womd_env(crossing(tmp_path / "sd_cross.pkl", math.radians(angle_deg), speed),
                        traffic="idm")
    table, info = drive(env)
    assert info["traffic_collisions"] == 0
    slowest = {tid: table.loc[table["track_id"] == tid, "speed"].iloc[CURRENT_STEP + 1:].min()
               for tid in ("2", "3")}
    assert min(slowest.values()) < 0.6 * speed  # someone gave way
    assert max(slowest.values()) > 0.8 * speed  # the other went on
    for tid, angle in (("2", 0.0), ("3", math.radians(angle_deg))):  # both go on
        rows = table[table["track_id"] == tid]
        ahead = rows["x"].iloc[-1] * math.cos(angle) + rows["y"].iloc[-1] * math.sin(angle)
        assert ahead > 0.0 or rows["speed"].iloc[-1] > 1.0  # through, or on its way


def test_traffic_stops_at_a_stop_sign_then_goes(tmp_path):
    # a lane ending at a stop sign 23 m ahead at 1.0 s, continued by an exit lane; the logged car
    # drives through at 8 m/s; idm stops at the sign, then goes on
    s = np.arange(0.0, 60.0, 0.5)
    approach = {"type": "LANE_SURFACE_STREET", "entry_lanes": [], "exit_lanes": ["21"],
                "polyline": np.c_[s - 20.0, np.zeros_like(s)]}
    beyond = {"type": "LANE_SURFACE_STREET", "entry_lanes": ["20"], "exit_lanes": [],
              "polyline": np.c_[s + 40.0 - 0.0, np.zeros_like(s)]}
    features = {"20": approach, "21": beyond,
                "30": {"type": "STOP_SIGN", "position": [39.5, 1.5], "lane": []}}
    env = make_womd_env(scene(tmp_path / "sd_stop.pkl", {"2": track(10.0, 0.0, 0.0, 6.0)},
                              features), traffic="idm")
    table, info = drive(env)
    car = table[table["track_id"] == "2"].iloc[CURRENT_STEP:]
    near = car[(car["x"] > 30.0) & (car["x"] < 39.5)]
    assert near["speed"].min() < 1.0  # stopped before the sign
    assert car["x"].iloc[-1] > 42.0  # and went on
    assert info["traffic_collisions"] == 0
