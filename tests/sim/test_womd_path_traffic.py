"""idm traffic along the logged paths: each vehicle drives the path its driver drove, IDM
deciding only its speed; generated scenes (every heading, curves, rear-ends, a lane change,
a late vehicle) and hand-worked geometry."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from tap_bench.sim.policies import load_policy
from tap_bench.sim.womd_env import make_womd_env
from tap_bench.sim.womd_road import (
    PATH_EXTENSION,
    PATH_SPACING,
    _first_crossing,
    _path_blockers,
    _project_path,
    _project_window,
    _window_chunks,
    logged_path,
    path_columns,
    path_progress,
)
from tap_bench.sim.womd_scene import CURRENT_STEP

T = np.arange(91) * 0.1


def along(points: np.ndarray, speed: np.ndarray | float, *, valid: np.ndarray | None = None
          ) -> dict:
    """A ScenarioNet vehicle track along a polyline (n, 2) at ``speed`` [m/s] per step."""
    speed = np.broadcast_to(np.asarray(speed, float), T.shape)
    s = np.r_[0.0, np.cumsum(speed[:-1] * 0.1)]
    cum = np.r_[0.0, np.cumsum(np.hypot(*np.diff(points, axis=0).T))]
    x, y = np.interp(s, cum, points[:, 0]), np.interp(s, cum, points[:, 1])
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(points) - 2)
    d = points[k + 1] - points[k]
    heading = np.arctan2(d[:, 1], d[:, 0])
    return {"type": "VEHICLE", "state": {
        "position": np.c_[x, y, np.zeros(91)], "heading": heading,
        "velocity": np.c_[speed * np.cos(heading), speed * np.sin(heading)],
        "valid": np.ones(91, bool) if valid is None else valid,
        "length": np.full(91, 4.5), "width": np.full(91, 2.0)}}


def lane_of(points: np.ndarray) -> dict:
    return {"type": "LANE_SURFACE_STREET", "entry_lanes": [], "exit_lanes": [],
            "polyline": points}


def scene(path, tracks: dict, lanes: list[np.ndarray]) -> str:
    meta = {"scenario_id": path.stem, "ts": T, "dataset": "waymo", "sdc_id": "ego"}
    far = np.c_[np.arange(0.0, 200.0, 0.5) - 10.0, np.full(400, -300.0)]
    features = {str(k + 2): lane_of(p) for k, p in enumerate(lanes)}
    with path.open("wb") as f:
        pickle.dump({"metadata": meta, "map_features": {"1": lane_of(far), **features},
                     "dynamic_map_states": {},
                     "tracks": {"ego": along(far, 8.0), **tracks}}, f)
    return str(path)


def rotate(points: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return points @ np.array([[c, s], [-s, c]])


def bend(angle: float) -> np.ndarray:
    """40 m straight, a 90 deg left bend of radius 20 m, 60 m straight; rotated by
    ``angle``."""
    straight = np.c_[np.arange(-40.0, 0.0, 0.5), np.zeros(80)]
    a = np.linspace(0.0, math.pi / 2, 63)
    arc = np.c_[20.0 * np.sin(a), 20.0 * (1 - np.cos(a))]
    out = np.c_[np.full(120, 20.0), 20.0 + np.arange(0.5, 60.5, 0.5)]
    return rotate(np.vstack([straight, arc, out]), angle)


def drive(env, policy_name: str = "log"):
    policy = load_policy(policy_name)
    obs, _ = env.reset(seed=0)
    policy.reset(env, seed=0)
    done = False
    while not done:
        obs, _, terminated, truncated, _ = env.step(policy.act(obs))
        done = terminated or truncated
    return env.recorded_states(), env.episode_info()


def test_a_logged_path_drops_the_standstill_jitter_and_goes_on_straight():
    # 5 samples standing within 0.1 m, then 1 m steps along +x
    xy = np.array([[0.0, 0.0], [0.05, 0.02], [0.02, -0.03], [0.08, 0.0], [0.1, 0.05],
                   [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    path = logged_path(xy, np.zeros(8), np.r_[np.zeros(5), 10.0, 10.0, 10.0],
                       np.arange(10, 18))
    # kept: the first, then every point >= 0.5 m from the last kept one, then the extension
    np.testing.assert_allclose(path.points[:-1], xy[[0, 5, 6, 7]])
    np.testing.assert_allclose(path.cum, [0.0, 1.0, 2.0, 3.0, 3.0 + PATH_EXTENSION])
    assert path.length == pytest.approx(3.0)
    assert path.at(1.5) == pytest.approx((1.5, 0.0, 0.0))
    assert path.at(13.0) == pytest.approx((13.0, 0.0, 0.0))  # on the extension
    # the log was at 2 m at step 16, beyond its end never
    assert path.step_at(2.0) == 16 and path.step_at(1.5) == 16 and path.step_at(50.0) == np.inf
    # desired speed's scale: the fastest logged speed 10 m behind to 20 m ahead
    assert path.reference_at(0.0) == pytest.approx(10.0)
    assert PATH_SPACING == 0.5


def test_first_crossing_of_two_paths():
    a = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    b = np.array([[14.0, -5.0], [14.0, 5.0]])
    ca = np.r_[0.0, 10.0, 20.0]
    cb = np.r_[0.0, 10.0]
    sa, sb = _first_crossing(a[:, 0], a[:, 1], ca, 3, b[:, 0], b[:, 1], cb, 2, 0.087)
    assert (sa, sb) == pytest.approx((14.0, 5.0))
    # parallel (following on the same line) is no crossing
    c = np.array([[-5.0, 0.0], [30.0, 0.0]])
    assert np.isnan(_first_crossing(a[:, 0], a[:, 1], ca, 3, c[:, 0], c[:, 1],
                                    np.r_[0.0, 35.0], 2, 0.087)[0])


@pytest.mark.parametrize("angle_deg", [0, 45, 90, 135, 180, 225, 270, 315])
def test_traffic_drives_its_logged_bend_at_every_heading(tmp_path, angle_deg):
    # car 2 drove the bend at 8 m/s; the map's lane is 3 m to the side (the path, not the
    # lane centre, is what it follows): it stays within the jitter of its logged path
    points = bend(math.radians(angle_deg))
    normal = rotate(np.array([[0.0, 3.0]]), math.radians(angle_deg))[0]
    env = make_womd_env(scene(tmp_path / f"sd_bend{angle_deg}.pkl",
                              {"2": along(points, 8.0)}, [points + normal]), traffic="idm")
    rec, _ = drive(env)
    assert list(env.unwrapped.simulated) == [1]
    logged = np.c_[env.scene.x[1], env.scene.y[1]].astype(float)
    cum = np.r_[0.0, np.cumsum(np.hypot(*np.diff(logged, axis=0).T))]
    for k in range(CURRENT_STEP + 1, 91):
        _, d = path_progress(logged, cum, np.array([rec["x"][1, k], rec["y"][1, k]]))
        assert d < 0.05
    # heading along the path (the log's headings), speed near the logged 8 m/s
    assert np.nanmax(np.abs(np.diff(np.unwrap(rec["heading"][1, CURRENT_STEP:])))) < 0.1
    assert 7.0 < rec["speed"][1, -1] < 9.0


@pytest.mark.parametrize("angle_deg", [0, 90, 200, 300])
@pytest.mark.parametrize("gap, lead_speed", [(20.0, 4.0), (12.0, 0.0)])
def test_a_faster_car_behind_on_the_same_path_does_not_rear_end(tmp_path, angle_deg, gap,
                                                                 lead_speed):
    # car 3 drove 10 m/s where car 2 (ahead by `gap` m) drove slower (or stood): car 3's
    # log overlaps car 2's, the simulated car 3 follows and stops behind it
    points = rotate(np.c_[np.arange(-60.0, 200.0, 0.5), np.zeros(520)],
                    math.radians(angle_deg))
    # at 1.0 s car 3 is at x = -40 and car 2 `gap` m ahead
    xs_lead = np.arange(-40.0 + gap - lead_speed * 1.0, 200.0, 0.5)
    xs_behind = np.arange(-50.0, 200.0, 0.5)
    lead = rotate(np.c_[xs_lead, np.zeros(len(xs_lead))], math.radians(angle_deg))
    behind = rotate(np.c_[xs_behind, np.zeros(len(xs_behind))], math.radians(angle_deg))
    env = make_womd_env(scene(tmp_path / f"sd_rear{angle_deg}.pkl",
                              {"2": along(lead, lead_speed), "3": along(behind, 10.0)},
                              [points]), traffic="idm")
    rec, info = drive(env)
    assert info["traffic_collisions"] == 0, info["traffic_collided"]
    centre = np.hypot(rec["x"][2] - rec["x"][1], rec["y"][2] - rec["y"][1])
    # bumpers apart (7.5 m at 10 m/s to a standing car is close to an emergency: it stops
    # about 0.5 m short of it)
    assert centre[CURRENT_STEP:].min() > 4.5 + 0.2
    braking = -np.diff(rec["speed"][2, CURRENT_STEP:]) / 0.1
    assert braking.max() <= 8.0 + 1e-9  # never beyond the emergency braking


def test_a_late_vehicle_waits_until_its_place_is_free(tmp_path):
    # car 2 drove through where car 4 stands (a log that overlaps); simulated, it stops
    # behind car 4, about x = -16.5. Car 3 appears at 3.0 s at x = -20, where car 2 now
    # stands: it waits off the road (not recorded) instead of appearing inside car 2
    line = np.c_[np.arange(-50.0, 200.0, 0.5), np.zeros(500)]
    late = along(np.c_[np.arange(-20.0, 200.0, 0.5), np.zeros(440)], 5.0)
    late["state"]["valid"] = T >= 3.0 - 1e-9
    late["state"]["position"][:, 0] = -20.0 + 0.5 * (np.arange(91) - 30)
    env = make_womd_env(scene(tmp_path / "sd_late.pkl", {
        "2": along(np.c_[np.arange(-40.0, 200.0, 0.5), np.zeros(480)], 8.0),
        "4": along(np.c_[np.arange(-10.0, 200.0, 0.5), np.zeros(420)], 0.0), "3": late},
        [line]), traffic="idm")
    rec, info = drive(env)
    rows = {str(t): k for k, t in enumerate(env.scene.track_ids)}
    assert rows["3"] in env.unwrapped.simulated
    assert info["traffic_collisions"] == 0, info["traffic_collided"]
    assert abs(rec["x"][rows["2"], 60] + 16.5) < 1.0  # car 2 stands behind car 4
    assert not rec["valid"][rows["3"], 30:].any()  # car 3 never had room


@pytest.mark.parametrize("rotation_deg", [0, 120, 240])
@pytest.mark.parametrize("late", [0.0, 0.4])
def test_crossing_paths_go_in_the_log_order_at_every_heading(tmp_path, rotation_deg, late):
    # car 2 along +x and car 3 along +y (the scene turned by rotation_deg), both logged
    # through the crossing at 5 s (car 3 `late` s after car 2): car 3 waits, car 2 goes on
    rot = math.radians(rotation_deg)
    xs = np.arange(-80.0, 80.0, 0.5)
    east = rotate(np.c_[xs, np.zeros_like(xs)], rot)
    north = rotate(np.c_[np.zeros_like(xs), xs], rot)
    speed = 10.0
    car2 = along(rotate(np.c_[np.arange(-50.0, 80.0, 0.5), np.zeros(260)], rot), speed)
    start3 = -50.0 - speed * late  # logged through the crossing `late` s after car 2
    ys = np.arange(start3, 80.0, 0.5)
    car3 = along(rotate(np.c_[np.zeros_like(ys), ys], rot), speed)
    env = make_womd_env(scene(tmp_path / f"sd_x{rotation_deg}_{late}.pkl",
                              {"2": car2, "3": car3}, [east, north]), traffic="idm")
    rec, info = drive(env)
    assert info["traffic_collisions"] == 0, info["traffic_collided"]
    rows = {str(t): k for k, t in enumerate(env.scene.track_ids)}
    slowest = {tid: np.nanmin(rec["speed"][rows[tid], CURRENT_STEP + 1:]) for tid in ("2", "3")}
    assert slowest["2"] > 0.8 * speed  # first in the log: goes
    assert slowest["3"] < 0.6 * speed  # second: gives way
    # both are beyond the crossing at the end
    for tid, axis in (("2", (math.cos(rot), math.sin(rot))),
                      ("3", (-math.sin(rot), math.cos(rot)))):
        r = rows[tid]
        assert rec["x"][r, -1] * axis[0] + rec["y"][r, -1] * axis[1] > 5.0


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_the_chunked_path_search_finds_the_same_nearest_point(seed):
    # winding paths (tight turns, spirals back on themselves), windows anywhere along them
    # and points near, far, beyond the ends and on the path: the same (s, d, direction)
    rng = np.random.default_rng(seed)
    turn = np.cumsum(rng.normal(0.0, 0.4, 400))
    step = rng.uniform(0.0, 1.5, 400)
    step[::37] = 0.0  # repeated points (zero-length segments)
    xy = np.cumsum(np.c_[step * np.cos(turn), step * np.sin(turn)], axis=0)
    px, py = xy[:, 0].copy(), xy[:, 1].copy()
    cum = np.r_[0.0, np.cumsum(np.hypot(np.diff(px), np.diff(py)))]
    for _ in range(300):
        s0 = rng.uniform(-5.0, cum[-1] + 5.0)
        s1 = s0 + rng.uniform(0.0, 80.0)
        k0, k1, centres, radii = _window_chunks(px, py, cum, s0, s1)
        k = rng.integers(len(px))
        q = xy[k] + rng.normal(0.0, rng.choice([0.0, 1.0, 10.0, 60.0]), 2)
        want = _project_path(px, py, cum, s0, s1, q[0], q[1])
        got = _project_window(px, py, cum, k0, k1, centres, radii, q[0], q[1])
        np.testing.assert_array_equal(got, want)


def test_the_path_blockers_leave_out_the_paths_own_vehicle():
    # a mover skipped (the path's own vehicle) has NaN rows, the others the rows they have
    # when nobody is skipped; each skipped mover is in the way when not skipped
    rng = np.random.default_rng(7)
    px = np.linspace(0.0, 100.0, 201)
    py = 0.3 * np.sin(px / 10.0)
    cum = np.r_[0.0, np.cumsum(np.hypot(np.diff(px), np.diff(py)))]
    m = 12
    xs, ys = rng.uniform(2.0, 60.0, m), rng.normal(0.0, 2.0, m)
    hs, vs = rng.uniform(-np.pi, np.pi, m), rng.uniform(0.0, 10.0, m)
    ls, ws = rng.uniform(3.5, 5.0, m), rng.uniform(1.6, 2.1, m)
    margins = np.full(m, 0.1)
    horizons = np.array([0.0, 1.0, 2.0])
    unpredicted = rng.random(m) < 0.3
    args = (px, py, cum, 0.0, 50.0, 0.0, 0.0, 1.0, 2.3, margins, xs, ys, hs, vs, ls, ws,
            horizons, unpredicted)
    everyone = _path_blockers(*args, -1)
    in_way = np.flatnonzero(np.isfinite(everyone[:, 0])) // len(horizons)
    assert len(set(in_way.tolist())) >= 3
    for j in sorted(set(in_way.tolist())):
        want = everyone.copy()
        want[j * 3:(j + 1) * 3] = np.nan
        np.testing.assert_array_equal(_path_blockers(*args, j), want)


def test_path_progress_is_the_nearest_segments_arc_length():
    # the definition on every segment at once (numpy), against the one-pass search, on
    # paths with repeated points, far from the origin, points on, near and far off them
    rng = np.random.default_rng(5)
    for _ in range(200):
        m = int(rng.integers(2, 80))
        path = np.cumsum(rng.normal(0.0, rng.choice([0.1, 1.0, 5.0]), (m, 2)), axis=0) \
            + rng.uniform(-5000.0, 5000.0, 2)
        path[int(rng.integers(m))] = path[int(rng.integers(m))]
        cum = np.r_[0.0, np.cumsum(np.hypot(*np.diff(path, axis=0).T))]
        a, ab = path[:-1], np.diff(path, axis=0)
        n2 = np.maximum((ab ** 2).sum(axis=1), 1e-12)
        for _ in range(10):
            p = path[int(rng.integers(m))] + rng.normal(0.0, rng.choice([0.0, 0.5, 20.0]), 2)
            u = np.clip(((p - a) * ab).sum(axis=1) / n2, 0, 1)
            d = np.hypot(*(p - (a + u[:, None] * ab)).T)
            k = int(np.argmin(d))
            s, dist = path_progress(path, cum, p)
            # the columns made once (as the env does at reset) give the same answer
            assert path_progress(path, cum, p, path_columns(path, cum)) == (s, dist)
            assert dist == pytest.approx(d[k], abs=1e-9)
            assert s == pytest.approx(cum[k] + u[k] * math.sqrt(n2[k]), abs=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_all_path_vehicles_at_once_equal_each_one_alone(tmp_path, seed):
    # every heading, bends, cars behind faster cars on one path (rear-ends), crossing
    # paths, a pedestrian crossing, a car standing at the kerb: at every simulated step the
    # road's one compiled call gives each path vehicle exactly what its own search gives
    rng = np.random.default_rng(seed)
    angle = rng.uniform(0.0, 2 * math.pi)
    road = bend(angle)
    tracks = {}
    cum = np.r_[0.0, np.cumsum(np.hypot(*np.diff(road, axis=0).T))]
    for k in range(6):  # along the bend, from behind to ahead, faster behind
        start = rng.uniform(0.0, 60.0)
        pts = road[np.searchsorted(cum, start):]
        tracks[str(10 + k)] = along(pts, rng.uniform(0.0, 12.0))
    across = rotate(np.c_[np.full(200, 10.0), np.arange(-50.0, 50.0, 0.5)], angle)
    tracks["20"] = along(across, rng.uniform(5.0, 12.0))
    kerb = rotate(np.c_[np.full(40, -20.0) + np.arange(40) * 0.01, np.full(40, 2.6)], angle)
    tracks["21"] = along(kerb, 0.0)  # standing at the kerb, half in the lane
    walk = rotate(np.c_[np.full(40, 0.0), np.linspace(-8.0, 8.0, 40)], angle)
    tracks["22"] = {**along(walk, 1.4), "type": "PEDESTRIAN"}
    env = make_womd_env(scene(tmp_path / f"sd_batch{seed}.pkl", tracks,
                              [road, across]), traffic="idm")
    policy = load_policy("idm")
    obs, _ = env.reset(seed=0)
    policy.reset(env, seed=0)
    inner = env.unwrapped
    checked = []
    batch = inner.road._ahead_of_paths

    def check(layout):
        got = batch(layout)
        for vehicle in inner.road.vehicles:
            if id(vehicle) in got:
                v = max(float(vehicle.speed), 0.0)
                v0 = vehicle.target_speed
                assert got[id(vehicle)] == (vehicle.ahead_acceleration(v, v0), v0)
                checked.append(got[id(vehicle)][0])
        return got

    inner.road._ahead_of_paths = check
    done = False
    while not done:
        obs, _, terminated, truncated, _ = env.step(policy.act(obs))
        done = terminated or truncated
    assert len(checked) > 300
    assert min(checked) < -1.0  # some braked behind something in the way


@pytest.mark.parametrize("n", [1, 2, 3, 7, 64, 91, 200])
def test_window_maxima_equal_each_windows_max(n):
    """window_max = numpy's max of each window, for windows of every length and place
    (monotone ones as a logged path's, and any others)."""
    from tap_bench.sim.womd_road import window_max

    rng = np.random.default_rng(n)
    values = np.round(rng.normal(8.0, 5.0, n), 1)  # ties too
    lo = rng.integers(0, n, 3 * n)
    hi = np.minimum(lo + rng.integers(1, n + 1, 3 * n), n)
    lo, hi = np.r_[lo, np.arange(n), 0], np.r_[hi, np.arange(n) + 1, n]
    want = np.array([values[a:b].max() for a, b in zip(lo, hi, strict=True)])
    assert np.array_equal(window_max(values, lo, hi), want)
