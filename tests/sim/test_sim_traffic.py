"""The traffic core (tap_bench.sim.traffic) against highway-env's own vehicles.

Equivalence is behaviour within a tolerance: on every shipped scene, with the ego driven by
IDM/MOBIL or by drawn discrete actions, the core and highway-env's own ``Road`` (same seed,
same scene) make the same lane-change decisions (each vehicle's lane and target lane at
every decision), the same crashes, and keep every vehicle within 1e-6 m of highway-env's
over 20 simulated seconds (or to the episode's end). The driver models are also checked on
values worked out by hand.
"""

from __future__ import annotations

import functools
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("highway_env")

from highway_env.road.road import Road
from highway_env.vehicle.behavior import IDMVehicle

from tap_bench.sim import driver_models as dm
from tap_bench.sim import traffic
from tap_bench.sim.idm import IDMParameters, take_over_ego
from tap_bench.sim.lane_frames import LaneSet, lane_coordinates, lane_heading
from tap_bench.sim.scenario_env import make_env
from tap_bench.sim.traffic import TrafficRoad, near_pairs

ROOT = Path(__file__).resolve().parents[2]
SCENES = sorted(json.loads(p.read_text())["name"] for p in (ROOT / "envs").glob("*.json"))
POSITION_TOLERANCE = 1e-6  # [m]


def _highway_env_road(road: Road) -> Road:
    """highway-env's own Road with ``road``'s network, vehicles and objects."""
    plain = Road.__new__(Road)
    plain.__dict__.update(vars(road))
    for obj in plain.vehicles + plain.objects:
        if obj.road is road:
            obj.road = plain
    return plain


def _run(scene: str, seed: int, *, core: bool, ego: str, seconds: float = 20.0,
         config: dict | None = None, fast: bool = False) -> list[list[tuple]]:
    """Every vehicle's (x, y, heading, speed, crashed, lane, target lane) after each
    decision of one episode."""
    env = make_env(scene, record=False, fast=fast, config=config)
    try:
        env.reset(seed=seed)
        inner = env.unwrapped
        assert isinstance(inner.road, TrafficRoad)
        if not core:
            inner.road = _highway_env_road(inner.road)
        if ego == "idm":
            take_over_ego(env, IDMParameters())
        rng = np.random.default_rng(seed)
        n = env.action_space.n
        out = []
        steps = round(seconds * inner.config["policy_frequency"])
        for _ in range(steps):
            action = 1 if ego == "idm" else int(rng.integers(n))
            _, _, terminated, truncated, _ = env.step(action)
            out.append([(*map(float, v.position), float(v.heading), float(v.speed),
                         bool(v.crashed), v.lane_index, getattr(v, "target_lane_index", None))
                        for v in inner.road.vehicles])
            if terminated or truncated:
                break
        return out
    finally:
        env.close()


def _assert_same(ours: list, theirs: list) -> dict[str, float]:
    assert len(ours) == len(theirs), "the episodes end at different steps"
    worst = 0.0
    changes = 0
    for t, (a, b) in enumerate(zip(ours, theirs, strict=True)):
        assert len(a) == len(b), f"step {t}: different vehicle counts"
        for k, (va, vb) in enumerate(zip(a, b, strict=True)):
            worst = max(worst, float(np.hypot(va[0] - vb[0], va[1] - vb[1])))
            assert va[4:] == vb[4:], f"step {t}, vehicle {k}: crash/lane/target {va[4:]} " \
                                     f"against highway-env's {vb[4:]}"
            changes += va[5] != va[6]
    assert worst <= POSITION_TOLERANCE, f"positions {worst:.3g} m apart"
    return {"worst": worst, "changing": changes}


def _force(monkeypatch, path: str) -> None:
    """Make the core compute every road one vehicle at a time (``"one-by-one"``) or as
    arrays (``"arrays"``), whatever its size."""
    big = 10**9 if path == "one-by-one" else -1
    monkeypatch.setattr(traffic, "SCALAR_MAX_OBJECTS", big)


@functools.cache
def _highway_envs_idm_run(scene: str) -> list[list[tuple]]:
    """highway-env's own road on ``scene``, seed 3, IDM ego (``_run``; made once per scene
    with the core's default path, the reference of both paths below: the tests only read
    it)."""
    return _run(scene, 3, core=False, ego="idm")


@pytest.mark.parametrize("path", ["one-by-one", "arrays"])
@pytest.mark.parametrize("scene", SCENES)
def test_core_drives_every_scene_as_highway_env_does(scene, path, monkeypatch):
    """IDM ego, one seed, 20 s, the core's either path: same decisions and crashes,
    positions within 1e-6 m."""
    theirs = _highway_envs_idm_run(scene)
    _force(monkeypatch, path)
    ours = _run(scene, 3, core=True, ego="idm")
    _assert_same(ours, theirs)


@pytest.mark.parametrize("scene", ["highway", "roundabout"])
def test_core_with_an_ego_of_drawn_actions(scene):
    ours = _run(scene, 11, core=True, ego="drawn")
    theirs = _run(scene, 11, core=False, ego="drawn")
    _assert_same(ours, theirs)


@pytest.mark.parametrize("path", ["one-by-one", "arrays"])
def test_fast_variant_and_dense_traffic(path, monkeypatch):
    """The fast training variant (5 Hz, only the ego checks collisions) with 40 vehicles
    on 4 lanes, lane changes happening, the core's either path."""
    _force(monkeypatch, path)
    config = {"vehicles_count": 40, "lanes_count": 4}
    ours = _run("highway", 5, core=True, ego="drawn", config=config, fast=True)
    theirs = _run("highway", 5, core=False, ego="drawn", config=config, fast=True)
    assert _assert_same(ours, theirs)["changing"] > 0


@pytest.mark.slow
@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("ego", ["idm", "drawn"])
def test_core_across_drawn_seeds(scene, ego):
    seeds = np.random.default_rng(34).integers(0, 10_000, 4).tolist()
    for seed in seeds:
        _assert_same(_run(scene, seed, core=True, ego=ego),
                     _run(scene, seed, core=False, ego=ego))


@pytest.mark.slow
@pytest.mark.parametrize("count", [1, 5, 12, 30, 60])
def test_core_across_vehicle_counts(count):
    for seed in (0, 1):
        config = {"vehicles_count": count}
        _assert_same(_run("highway", seed, core=True, ego="drawn", config=config),
                     _run("highway", seed, core=False, ego="drawn", config=config))


def test_a_vehicle_with_its_own_act_is_driven_by_highway_env_and_the_run_says_so(monkeypatch):
    """A user's IDM subclass that overrides ``act``: the core leaves it to highway-env
    (its act runs every step) and warns once."""
    from tap_bench.sim import traffic

    calls = []

    class Stubborn(IDMVehicle):
        def act(self, action=None):
            calls.append(self)
            super().act(action)

    monkeypatch.setattr(traffic, "_WARNED", set())
    env = make_env("highway", record=False)
    env.reset(seed=0)
    road = env.unwrapped.road
    road.vehicles[3] = Stubborn.create_from(road.vehicles[3])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(3):
            env.step(1)
    said = [w for w in caught if "Stubborn" in str(w.message)]
    assert len(said) == 1 and "defines its own act" in str(said[0].message)
    assert len(calls) == 3 * env.unwrapped.config["simulation_frequency"]
    env.close()


# --- the driver models, by hand --------------------------------------------------------

def test_idm_free_road_and_desired_gap():
    one = np.ones(1)
    # at the desired speed on a free road: no acceleration; standing: a_max
    assert dm.idm_acceleration(20 * one, 20 * one, 4 * one, 3 * one)[0] == 0.0
    assert dm.idm_acceleration(0 * one, 20 * one, 4 * one, 3 * one)[0] == 3.0
    # s* = s0 + v T + v dv / (2 sqrt(a b)) = 10 + 30 + 20 * 2 / (2 * sqrt(3 * 5))
    s_star = dm.desired_gap(20 * one, 2 * one, 10 * one, 1.5 * one, 3 * one, 5 * one)
    assert s_star[0] == pytest.approx(40 + 20 / np.sqrt(15))
    # a leader at exactly s*, at the desired speed: -a_max
    a = dm.idm_acceleration(20 * one, 20 * one, 4 * one, 3 * one, s_star, s_star,
                            np.ones(1, bool))
    assert a[0] == pytest.approx(-3.0)


def test_mobil_incentive_weighs_the_followers_by_politeness():
    got = dm.mobil_incentive(np.array([1.0]), np.array([-0.5]), np.array([0.3]),
                             np.array([0.5]))
    assert got[0] == pytest.approx(1.0 + 0.5 * (-0.5 + 0.3))


def test_bicycle_goes_straight_and_turns():
    x, y, h, v = dm.bicycle_step(np.zeros(2), np.zeros(2), np.zeros(2), np.array([10.0, 10.0]),
                                 np.array([0.0, 0.1]), np.array([1.0, 0.0]), np.full(2, 5.0),
                                 0.1)
    assert (x[0], y[0], h[0], v[0]) == (1.0, 0.0, 0.0, 10.1)
    slip = np.arctan(np.tan(0.1) / 2)
    assert y[1] == pytest.approx(np.sin(slip)) and h[1] == pytest.approx(
        10 * np.sin(slip) / 2.5 * 0.1)


def test_steering_is_zero_on_the_lane_centre_and_towards_it_off_it():
    args = dict(heading=np.zeros(3), lane_heading=np.zeros(3), speed=np.full(3, 20.0),
                length=np.full(3, 5.0), kp_lateral=np.ones(3), kp_heading=np.ones(3),
                max_angle=np.full(3, np.pi / 3))
    got = dm.steering_angle(np.array([0.0, 1.0, -1.0]), **args)
    assert got[0] == 0.0 and got[1] < 0 < got[2]  # lateral offset to the left: steer right


# --- lane frames and the lane lookup ---------------------------------------------------

@pytest.mark.parametrize("scene", ["highway", "merge", "roundabout", "intersection", "exit"])
def test_lane_frames_match_highway_env_lanes(scene):
    env = make_env(scene, record=False)
    env.reset(seed=0)
    network = env.unwrapped.road.network
    rng = np.random.default_rng(1)
    lanes = [((a, b, i), lane) for a, ends in network.graph.items()
             for b, row in ends.items() for i, lane in enumerate(row)]
    points = np.concatenate([
        np.array([lane.position(s, r) for _, lane in lanes
                  for s, r in zip(rng.uniform(-10, lane.length + 10, 8),
                                  rng.uniform(-6, 6, 8), strict=True)]),
        rng.uniform(-200, 600, (100, 2))])
    headings = rng.uniform(-np.pi, np.pi, len(points))
    for _, lane in lanes:
        s, r = lane_coordinates(lane, points)
        want = np.array([lane.local_coordinates(p) for p in points])
        np.testing.assert_allclose(s, want[:, 0], atol=1e-9)
        np.testing.assert_allclose(r, want[:, 1], atol=1e-9)
        np.testing.assert_allclose(lane_heading(lane, s),
                                   [lane.heading_at(v) for v in s], atol=1e-12)
    lane_set = LaneSet(lanes)
    for j, (_, lane) in enumerate(lanes):  # one lane or one point at a time
        s, r = lane_set.frame_one(j, points[:, 0].tolist(), points[:, 1].tolist())
        want = np.array([lane.local_coordinates(p) for p in points])
        np.testing.assert_allclose(s, want[:, 0], atol=1e-9)
        np.testing.assert_allclose(r, want[:, 1], atol=1e-9)
        assert np.allclose([lane_set.point_frame(j, *p) for p in points.tolist()], want,
                           rtol=0, atol=1e-9)
        np.testing.assert_allclose([lane_set.heading_one(j, v) for v in s],
                                   [lane.heading_at(v) for v in s], atol=1e-12)
    want = [network.get_closest_lane_index(p, h) for p, h in zip(points, headings, strict=True)]
    assert lane_set.closest(network, points, headings) == want
    assert [lane_set.closest_one(network, *p, h)
            for p, h in zip(points.tolist(), headings.tolist(), strict=True)] == want
    env.close()


def test_one_vehicle_forms_equal_the_array_forms():
    """The ``*_one`` driver models give the array forms' values on drawn inputs, standing
    vehicles and touching gaps included."""
    rng = np.random.default_rng(5)
    n = 200
    speed = np.concatenate([rng.uniform(-2, 40, n - 2), [0.0, 0.005]])
    approach, gap = rng.uniform(-10, 10, n), np.concatenate([rng.uniform(-1, 80, n - 1), [0]])
    s0, time_gap, a_max, b = (rng.uniform(1, 10, n), rng.uniform(0.5, 2, n),
                              rng.uniform(1, 6, n), rng.uniform(1, 6, n))
    desired, delta = rng.uniform(0, 40, n), np.full(n, 4.0)
    s_star = dm.desired_gap(speed, approach, s0, time_gap, a_max, b)
    has_leader = rng.random(n) < 0.7
    want = dm.idm_acceleration(speed, desired, delta, a_max, gap, s_star, has_leader)
    for i in range(n):
        one_star = dm.desired_gap_one(*(float(x[i]) for x in (speed, approach, s0, time_gap,
                                                              a_max, b)))
        assert one_star == pytest.approx(s_star[i], rel=1e-12)
        got = dm.idm_one(float(speed[i]), float(desired[i]), 4.0, float(a_max[i]),
                         float(gap[i]) if has_leader[i] else None, one_star)
        assert got == pytest.approx(want[i], rel=1e-9, abs=1e-9)
    lateral, heading, lane_heading = (rng.uniform(-6, 6, n), rng.uniform(-4, 4, n),
                                      rng.uniform(-4, 4, n))
    length, kp, max_angle = rng.uniform(3, 12, n), rng.uniform(0.1, 5, (2, n)), np.full(n, 1.0)
    want = dm.steering_angle(lateral, heading, lane_heading, speed, length, kp[0], kp[1],
                             max_angle)
    got = [dm.steering_one(*(float(x[i]) for x in (lateral, heading, lane_heading, speed,
                                                   length, kp[0], kp[1], max_angle)))
           for i in range(n)]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    steer, acc = rng.uniform(-1, 1, n), rng.uniform(-6, 6, n)
    x, y = rng.uniform(-100, 100, (2, n))
    want = np.array(dm.bicycle_step(x, y, heading, speed, steer, acc, length, 0.1)).T
    got = [dm.bicycle_one(*(float(v[i]) for v in (x, y, heading, speed, steer, acc, length)),
                          0.1) for i in range(n)]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def test_touching_pairs_one_by_one_equal_the_array_test():
    """On crowded drawn states the one-pair-at-a-time test keeps exactly the pairs the
    array test (near, not swept apart) keeps."""
    from tap_bench.sim.traffic import _near, _shapes, _swept_apart, _touching_pairs_one_by_one

    env = make_env("highway", record=False, config={"vehicles_count": 30})
    env.reset(seed=4)
    vehicles = env.unwrapped.road.vehicles
    rng = np.random.default_rng(3)
    kept = 0
    for _ in range(20):
        for v in vehicles:
            v.position = rng.uniform(0, 50, 2)
            v.heading = float(rng.uniform(-np.pi, np.pi))
            v.speed = float(rng.uniform(-5, 30))
            v.check_collisions = bool(rng.random() < 0.7)
        shapes = _shapes(vehicles)
        i, j = np.nonzero(np.triu(_near(shapes, len(vehicles), 0.1), 1))
        keep = ~_swept_apart(shapes, i, j, 0.1)
        want = list(zip(i[keep].tolist(), j[keep].tolist(), strict=True))
        assert _touching_pairs_one_by_one(vehicles, len(vehicles), 0.1) == want
        kept += len(want)
    assert kept > 20
    env.close()


def _near_by_definition(objects: list, n: int, dt: float) -> np.ndarray:
    """Every (vehicle, object) pair tested: centres at most half the diagonals' sum plus the
    relative speed times dt (plus TOUCH_MARGIN) apart, one of the two checking collisions,
    both collidable."""
    near = np.zeros((n, len(objects)), dtype=bool)
    for i in range(n):
        a = objects[i]
        for j, b in enumerate(objects):
            relative = np.hypot(*(a.velocity - b.velocity)) * dt
            bound = (a.diagonal + b.diagonal) / 2 + relative + traffic.TOUCH_MARGIN
            near[i, j] = (np.hypot(*(a.position - b.position)) <= bound
                          and (a.check_collisions or b.check_collisions)
                          and a.collidable and b.collidable)
    return near


@pytest.mark.parametrize("spread", [30.0, 400.0])
@pytest.mark.parametrize("checking", [0.7, 0.05])
def test_near_pairs_by_a_sweep_and_by_checkers_equal_the_definition(spread, checking,
                                                                     monkeypatch):
    """near_pairs all against all, only the rows and columns of the objects that check
    collisions (when few do), and by a sweep along x (on many objects): each the matrix of
    the definition, on drawn states packed (30 m) and spread (400 m)."""
    env = make_env("highway", record=False, config={"vehicles_count": 60})
    env.reset(seed=6)
    road = env.unwrapped.road
    vehicles, objects = road.vehicles[:50], road.vehicles[50:60]
    rng = np.random.default_rng(8)
    pairs = 0
    for _ in range(6):
        for v in vehicles + objects:
            v.position = rng.uniform(0, spread, 2)
            v.heading = float(rng.uniform(-np.pi, np.pi))
            v.speed = float(rng.uniform(-5, 30))
            v.check_collisions = bool(rng.random() < checking)
        want = _near_by_definition(vehicles + objects, 50, 0.1)
        for dense_max in (10, 10**9):  # swept; all against all or by checkers
            monkeypatch.setattr(traffic, "_DENSE_MAX_OBJECTS", dense_max)
            got = near_pairs(vehicles, objects, 0.1)
            assert got.shape == (50, 60)
            np.testing.assert_array_equal(got, want)
        pairs += int(np.triu(want, 1).sum())
    assert pairs > 3 or spread > 100  # packed states have near pairs to find
    env.close()


def test_near_pairs_keeps_every_pair_highway_env_finds_touching():
    """Crowded drawn states: every pair highway-env's own check finds touching now or
    within the step is near (near_pairs) and not swept apart (the separating-axis test
    that skips highway-env's check), and the test does skip most pairs that are near."""
    from tap_bench.sim.traffic import _shapes, _swept_apart

    env = make_env("highway", record=False, config={"vehicles_count": 50})
    env.reset(seed=2)
    vehicles = env.unwrapped.road.vehicles
    rng = np.random.default_rng(0)
    found = skipped = 0
    for _ in range(30):  # crowd them
        for v in vehicles:
            v.position = rng.uniform(0, 60, 2)
            v.heading = float(rng.uniform(-np.pi, np.pi))
            v.speed = float(rng.uniform(-5, 30))
            v.check_collisions = bool(rng.random() < 0.7)
        near = near_pairs(vehicles, [], 0.1)
        i, j = np.nonzero(np.triu(near, 1))
        apart = dict(zip(zip(i.tolist(), j.tolist(), strict=True),
                         _swept_apart(_shapes(vehicles), i, j, 0.1).tolist(), strict=True))
        skipped += sum(apart.values())
        for i, a in enumerate(vehicles):
            for j in range(i + 1, len(vehicles)):
                b = vehicles[j]
                touching, will, _ = a._is_colliding(b, 0.1)
                if (touching or will) and (a.check_collisions or b.check_collisions):
                    found += 1
                    assert near[i, j] and not apart[i, j], (i, j)
    assert found > 20 and skipped > found
    env.close()
