"""The pruned neighbour search answers exactly what highway-env's does, so scenarios simulate
bit for bit as before."""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
import pandas as pd
import pytest
from highway_env.road.lane import StraightLane
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.objects import Landmark, Obstacle

from tap_bench.sim import make_env
from tap_bench.sim.fast_road import TOLERANCE, FastRoad, use_fast_road
from tap_bench.sim.idm import IDMParameters, take_over_ego


def _episodes(name: str, *, fast_road: bool, fast: bool = False, seeds=(0, 1),
              idm_ego: IDMParameters | None = None, others: type | None = None,
              **config) -> pd.DataFrame:
    """Every vehicle's state after every decision, with the ego's reward and observation
    (``idm_ego``: the ego is an IDM/MOBIL vehicle with these parameters; ``others``: the
    class the other vehicles are given after the reset)."""
    env = make_env(name, config=config or None, duration=8, record=not fast, fast=fast)
    rows = []
    for seed in seeds:
        env.reset(seed=seed)
        if idm_ego is not None:
            take_over_ego(env, idm_ego)
        road = env.unwrapped.road
        if others is not None:
            for vehicle in road.vehicles[1:]:
                vehicle.__class__ = others
        if not fast_road:  # back to highway-env's own methods
            for method in ("act", "step", "neighbour_vehicles"):
                vars(road).pop(method, None)
            vars(road.network).pop("get_closest_lane_index", None)
        rng = np.random.default_rng(seed)
        done, decision = False, 0
        while not done:
            action = int(rng.integers(env.action_space.n)) if rng.random() < 0.4 else 1
            obs, reward, terminated, truncated, _ = env.step(action)
            done, decision = terminated or truncated, decision + 1
            rows += [(seed, decision, k, *v.position, v.heading, v.speed, v.crashed,
                      v.lane_index[2], v.target_lane_index[2], getattr(v, "timer", 0.0),
                      float(v.action["steering"]), float(v.action["acceleration"]),
                      reward, *np.ravel(obs)[:10])
                     for k, v in enumerate(road.vehicles)]
    return pd.DataFrame(rows)


@pytest.fixture(params=["at once", "default"])
def _small_roads_at_once(request, monkeypatch):
    """Every road decides and moves at once (AT_ONCE_FROM = MOVE_AT_ONCE_FROM = 0), or only
    those big enough."""
    from tap_bench.sim import fast_road

    if request.param == "at once":
        monkeypatch.setattr(fast_road, "AT_ONCE_FROM", 0)
        monkeypatch.setattr(fast_road, "MOVE_AT_ONCE_FROM", 0)


@pytest.mark.usefixtures("_small_roads_at_once")
@pytest.mark.parametrize(("name", "fast", "config"), [
    ("highway", False, {}), ("highway", True, {}),
    ("highway", True, {"vehicles_count": 50, "lanes_count": 4}),
    ("merge", False, {}), ("merge", True, {}),  # an obstacle: checked by every vehicle
    ("exit", False, {}), ("cut_in", True, {}), ("lead_braking", False, {}),
    ("roundabout", False, {}),  # curved lanes: highway-env's own search
])
def test_scenarios_simulate_bit_for_bit_as_with_highway_envs_road(name, fast, config):
    ours = _episodes(name, fast_road=True, fast=fast, **config)
    theirs = _episodes(name, fast_road=False, fast=fast, **config)
    assert len(ours) > 50
    pd.testing.assert_frame_equal(ours, theirs, check_exact=True)
    if name == "highway" and not fast:
        assert ours[8].any()  # crashes happen in these episodes: collisions are compared


class _SlipIDM(IDMVehicle):
    """A user's vehicle whose velocity has a slip angle (desired_gap reads it)."""

    @property
    def velocity(self) -> np.ndarray:
        return self.speed * np.array([np.cos(self.heading + 0.05), np.sin(self.heading + 0.05)])


class _TurnedIDM(IDMVehicle):
    """A user's vehicle whose direction is not its heading's (desired_gap projects on it)."""

    @property
    def direction(self) -> np.ndarray:
        return np.array([np.cos(self.heading - 0.1), np.sin(self.heading - 0.1)])


class _BubbleIDM(IDMVehicle):
    """A user's vehicle with its own collision rule: a crash within its length + 6 m."""

    def _is_colliding(self, other, dt):
        if np.linalg.norm(other.position - self.position) < self.LENGTH + 6:
            return True, False, np.zeros(2)
        return False, False, np.zeros(2)


class _DragIDM(IDMVehicle):
    """A user's vehicle with its own motion: air drag after highway-env's step."""

    def step(self, dt):
        super().step(dt)
        self.speed -= 0.01 * self.speed ** 2 * dt


class _SnapIDM(IDMVehicle):
    """A user's vehicle that looks its lane up its own way: every other step (a slow
    sensor)."""

    def on_state_update(self):
        self.updates = getattr(self, "updates", 0) + 1
        if self.road and self.updates % 2:
            super().on_state_update()


@pytest.mark.usefixtures("_small_roads_at_once")
@pytest.mark.parametrize("fast", [False, True])
@pytest.mark.parametrize("others", [_SlipIDM, _TurnedIDM, _BubbleIDM, _DragIDM, _SnapIDM])
def test_user_vehicle_classes_simulate_as_with_highway_envs_road(others, fast):
    """A class that changes what the fast paths compute themselves (its own velocity or
    direction, its own collision rule, its own motion or lane lookup) is left to
    highway-env: the same states and crashes."""
    ours = _episodes("highway", fast_road=True, fast=fast, others=others,
                     vehicles_count=30)
    theirs = _episodes("highway", fast_road=False, fast=fast, others=others,
                       vehicles_count=30)
    pd.testing.assert_frame_equal(ours, theirs, check_exact=True)
    if others is _BubbleIDM:
        assert ours[8].any() and not ours[8].all()


@pytest.mark.parametrize(("name", "params"), [
    ("highway", IDMParameters()),
    ("highway", IDMParameters(time_wanted=0.8, distance_wanted=6.0, comfort_acc_max=4.5,
                              politeness=0.0, lane_change_min_acc_gain=0.05,
                              lane_change_delay=0.5, target_speed_factor=1.3)),
    ("merge", IDMParameters(politeness=0.5, comfort_acc_min=-3.0, delta=3.0)),
    ("exit", IDMParameters(target_speed_factor=0.7)),
])
def test_idm_egos_decide_bit_for_bit_as_with_highway_envs_road(name, params):
    """Every vehicle an IDM/MOBIL vehicle, the ego with its own constants (set on the
    instance), the others with random exponents (highway-env's randomize_behavior): the
    same actions, lane changes and timers as highway-env's Road.act."""
    config = {"vehicles_count": 40, "lanes_count": 4} if name == "highway" else {}
    ours = _episodes(name, fast_road=True, idm_ego=params, seeds=(0, 3), **config)
    theirs = _episodes(name, fast_road=False, idm_ego=params, seeds=(0, 3), **config)
    pd.testing.assert_frame_equal(ours, theirs, check_exact=True)
    if name == "highway":  # vehicles changed lanes: MOBIL's decisions were compared
        assert (ours[9] != ours.groupby([0, 2])[9].transform("first")).any()


def test_the_vehicles_decide_at_once():
    """The fast road hands plain IDM vehicles to fast_idm, and only those."""
    from highway_env.vehicle.behavior import IDMVehicle, LinearVehicle

    from tap_bench.sim import fast_idm

    env = make_env("highway", record=False, duration=2)
    env.reset(seed=0)
    road = env.unwrapped.road
    assert road.act.__self__._decide_at_once == fast_idm.array_kernels_agree()
    others = [v for v in road.vehicles if v is not env.unwrapped.vehicle]
    assert others and all(fast_idm.is_plain_idm(v) for v in others)
    assert not fast_idm.is_plain_idm(env.unwrapped.vehicle)  # the ego of a policy
    linear = LinearVehicle.create_from(others[0])
    assert not fast_idm.is_plain_idm(linear)  # its own acceleration
    plain = IDMVehicle.create_from(others[0])
    plain.act = lambda *args: None
    assert not fast_idm.is_plain_idm(plain)  # an instance's own act


@pytest.mark.parametrize("mutation", ["steering", "acceleration", "lane coordinate",
                                      "not zero", "velocity", "leader", "motion",
                                      "motion one at a time", "timer", "speed at once",
                                      "position at once", "lane at once"])
def test_a_changed_formula_is_caught(monkeypatch, mutation):
    """The comparison sees a change of one ulp in any action or motion, or a changed term
    of the vectorised formulas: the bit-for-bit tests can fail."""
    from tap_bench.sim import fast_idm, fast_road

    monkeypatch.setattr(fast_road, "MOVE_AT_ONCE_FROM", 0)  # every road moves at once

    if mutation in ("steering", "acceleration"):
        act = fast_idm._act_straight

        def one_ulp_off(road, vehicles, *args):
            act(road, vehicles, *args)
            for vehicle in vehicles:
                vehicle.action[mutation] = np.nextafter(vehicle.action[mutation], np.inf)

        monkeypatch.setattr(fast_idm, "_act_straight", one_ulp_off)
    elif mutation == "lane coordinate":
        projection = fast_idm.ActState.projection

        def off(self, lane):
            got = projection(self, lane)
            return got and (got[0], got[1], [np.nextafter(s, np.inf) for s in got[2]])

        monkeypatch.setattr(fast_idm.ActState, "projection", off)
    elif mutation == "not zero":
        not_zero = fast_idm._not_zero_one
        monkeypatch.setattr(fast_idm, "_not_zero_one",
                            lambda x, eps=0.01: np.nextafter(not_zero(x, eps), np.inf))
    elif mutation == "velocity":
        velocity = fast_idm.ActState.velocity
        monkeypatch.setattr(fast_idm.ActState, "velocity",
                            lambda self, obj: tuple(1.01 * v for v in velocity(self, obj)))
    elif mutation in ("motion", "motion one at a time"):  # one ulp in the kinematics
        one_at_a_time = mutation == "motion one at a time"
        name = "_kinematics" if one_at_a_time else "_kinematics_at_once"
        kinematics = getattr(fast_road, name)
        if one_at_a_time:  # as where numpy's array kernels differ from its scalar ones
            monkeypatch.setattr(fast_road, "array_kernels_agree", lambda: False)

        def one_ulp(moved, dt):
            kinematics(moved, dt)
            for vehicle in [moved] if one_at_a_time else moved:
                vehicle.heading = np.nextafter(vehicle.heading, np.inf)

        monkeypatch.setattr(fast_road, name, one_ulp)
    elif mutation in ("timer", "speed at once", "position at once"):
        kinematics = fast_road._kinematics_at_once

        def mutated(vehicles, dt):
            kinematics(vehicles, dt)
            for vehicle in vehicles:
                if mutation == "timer" and hasattr(vehicle, "timer"):
                    vehicle.timer -= dt  # IDMVehicle.step's timer forgotten
                elif mutation == "speed at once":
                    vehicle.speed = np.nextafter(vehicle.speed, np.inf)
                elif mutation == "position at once":
                    vehicle.position[1] = np.nextafter(vehicle.position[1], -np.inf)

        monkeypatch.setattr(fast_road, "_kinematics_at_once", mutated)
    elif mutation == "lane at once":  # the lane lookup at once: the last candidate kept
        estimates = fast_road._estimates

        def blurred(lanes, positions, headings):
            distance, exact = estimates(lanes, positions, headings)
            return np.round(distance), exact  # ties within a metre: candidates

        monkeypatch.setattr(fast_road, "_estimates", blurred)
        monkeypatch.setattr(fast_road, "_first_nearest",
                            lambda candidates, position, heading: candidates[-1][0])
    else:  # the leaders found at once: one vehicle's leader missed
        leaders = FastRoad.leaders

        def one_missed(self, vehicles, lane_indices):
            found = leaders(self, vehicles, lane_indices)
            return [None, *found[1:]] if found else found

        monkeypatch.setattr(FastRoad, "leaders", one_missed)
    ours = _episodes("highway", fast_road=True, idm_ego=IDMParameters(), seeds=(0,))
    theirs = _episodes("highway", fast_road=False, idm_ego=IDMParameters(), seeds=(0,))
    with pytest.raises(AssertionError):
        pd.testing.assert_frame_equal(ours, theirs, check_exact=True)


@pytest.mark.parametrize("mutation", ["steering", "acceleration", "desired gap", "lane"])
@pytest.mark.parametrize("name", ["merge", "roundabout"])
def test_a_changed_formula_of_one_vehicle_at_a_time_is_caught(monkeypatch, mutation, name):
    """Small roads (and curved lanes) decide one vehicle at a time with fast_idm's scalar
    formulas: one ulp in a steering command, an IDM acceleration, a desired gap or a lane
    coordinate is seen by the comparison."""
    from tap_bench.sim import fast_idm

    target = {"steering": "_steering", "acceleration": "_idm", "desired gap": "_desired_gap",
              "lane": "_local"}[mutation]
    formula = getattr(fast_idm, target)

    def one_ulp_off(*args):
        value = formula(*args)
        if mutation == "lane":
            return np.nextafter(value[0], np.inf), value[1]
        return np.nextafter(value, np.inf)

    monkeypatch.setattr(fast_idm, target, one_ulp_off)
    ours = _episodes(name, fast_road=True, seeds=(0,))
    theirs = _episodes(name, fast_road=False, seeds=(0,))
    with pytest.raises(AssertionError):
        pd.testing.assert_frame_equal(ours, theirs, check_exact=True)


def test_one_number_is_clipped_as_numpy_clips_it():
    """fast_idm._clip against np.clip on numbers, bounds and their ties: signed zeros,
    infinities, NaN (in the number or a bound), bounds the wrong way round."""
    from tap_bench.sim.fast_idm import _clip

    rng = np.random.default_rng(0)
    special = [0.0, -0.0, 1.0, -1.0, np.inf, -np.inf, np.nan, np.pi / 4, -np.pi / 4,
               np.pi / 3, 6.0, -6.0, 20.0, 5e-324, -5e-324]
    numbers = special + list(rng.uniform(-30, 30, 40))
    bounds = [(-1, 1), (0, 20), (0, 20.0), (-np.pi / 4, np.pi / 4), (-np.pi / 3, np.pi / 3),
              (-6.0, 6.0), (0.0, 0.0), (-0.0, 0.0), (0, -0.0), (-0.0, -0.0), (2.0, 1.0),
              (np.nan, 1.0), (0.0, np.nan), (-np.inf, np.inf)]
    checked = 0
    for x in numbers:
        for low, high in bounds:
            want = np.clip(np.float64(x), low, high)
            for got in (_clip(np.float64(x), low, high), _clip(float(x), low, high)):
                assert np.array_equal(want, got, equal_nan=True), (x, low, high)
                assert np.signbit(want) == np.signbit(got), (x, low, high)
                checked += 1
    assert checked > 1500


def test_machines_whose_array_kernels_differ_simulate_with_highway_envs_act(monkeypatch):
    from tap_bench.sim import fast_idm, fast_road

    monkeypatch.setattr(fast_road, "array_kernels_agree", lambda: False)
    monkeypatch.setattr(fast_idm, "act_all", None)  # would fail if called
    monkeypatch.setattr(fast_road, "act_all", None)
    ours = _episodes("highway", fast_road=True, seeds=(0,))
    theirs = _episodes("highway", fast_road=False, seeds=(0,))
    pd.testing.assert_frame_equal(ours, theirs, check_exact=True)


def test_every_query_in_dense_traffic_is_answered_as_highway_env_does(monkeypatch):
    """Each query of a simulation, inside and outside Road.act, on own and other lanes."""
    env = make_env("highway", config={"vehicles_count": 60, "lanes_count": 4}, duration=6)
    env.reset(seed=5)
    road = env.unwrapped.road
    index = road.neighbour_vehicles.__self__
    assert isinstance(index, FastRoad)
    asked = []
    fast_search = index.neighbour_vehicles

    def checked(vehicle, lane_index=None):
        answer = fast_search(vehicle, lane_index)
        assert answer == Road.neighbour_vehicles(road, vehicle, lane_index)
        asked.append(lane_index)
        return answer

    monkeypatch.setattr(road, "neighbour_vehicles", checked)
    for _ in range(6):
        env.step(1)
        for vehicle in road.vehicles:  # outside act, on every lane of the road
            for lane_index in road.network.all_side_lanes(vehicle.lane_index):
                checked(vehicle, lane_index)
    assert len(asked) > 1000


def _straight_road(positions, *, objects=(), lanes: int = 2, angle: float = 0.0
                   ) -> tuple[Road, list]:
    """Vehicles at ``positions`` (lane frame: along, across) on ``lanes`` straight lanes
    500 m long, turned by ``angle`` [rad] (slanted lanes round their projections)."""
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    network = RoadNetwork()
    for lane in range(lanes):
        network.add_lane("a", "b", StraightLane(rotation @ [0, 4 * lane],
                                                rotation @ [500, 4 * lane]))
    positions = [rotation @ np.asarray(p, dtype=float) for p in positions]
    road = Road(network=network, np_random=np.random.RandomState(0))
    vehicles = [IDMVehicle(road, np.array(p, dtype=float), angle, 20.0) for p in positions]
    road.vehicles.extend(vehicles)
    road.objects.extend(objects)
    return road, vehicles


@pytest.mark.parametrize("inside_act", [False, True])
def test_ties_edges_and_objects_are_resolved_as_highway_env_does(inside_act):
    half = StraightLane.DEFAULT_WIDTH / 2 + 1.0  # highway-env's on-lane margin is 1 m
    positions = [
        (100, 0), (100, 0),  # two vehicles at the same place: ties
        (130, 0), (130, 0.5), (70, 0), (70, -0.5),  # equal s, different lateral offsets
        (160, half), (160.5, half + 1e-9), (40, -half),  # on and just off the lane's edge
        (100 + 1e-12, 0), (100 - 1e-12, 4),  # within rounding of the querying vehicle
        (-5, 0), (-5 - 1e-9, 0), (505 - 1e-9, 0), (505, 0),  # the lane's ends
        (200, 4), (220, 8),  # the other lane, and off the road
    ]
    obstacle = Obstacle(None, np.array([115.0, 0.0]))
    landmark = Landmark(None, np.array([105.0, 0.0]))
    road, vehicles = _straight_road(positions, objects=[obstacle, landmark])
    obstacle.road = landmark.road = road
    index = FastRoad(road)
    expected, answered = [], []

    def ask_all():
        for vehicle in vehicles:
            for lane_index in (("a", "b", 0), ("a", "b", 1), None):
                expected.append(Road.neighbour_vehicles(road, vehicle, lane_index))
                answered.append(index.neighbour_vehicles(vehicle, lane_index))

    if inside_act:
        road.vehicles[0].act = lambda *args: ask_all()  # queried while the road acts
        index.act()
    else:
        ask_all()
    assert len(answered) == 3 * len(vehicles)
    assert answered == expected
    assert any(leader is obstacle for leader, _ in answered)
    assert not any(landmark in pair for pair in answered)


def test_the_tolerance_is_far_above_the_rounding_of_the_projection():
    """Positions up to 10 km: numpy's and highway-env's projections differ by far less."""
    rng = np.random.default_rng(0)
    lane = StraightLane([-300.0, 17.0], [9000.0, 2500.0])
    positions = rng.uniform(-10_000, 10_000, size=(2000, 2))
    delta = positions - lane.start
    vectorised = delta[:, 0] * lane.direction[0] + delta[:, 1] * lane.direction[1]
    exact = np.array([lane.local_coordinates(p)[0] for p in positions])
    assert np.max(np.abs(vectorised - exact)) < TOLERANCE / 1000


def test_only_highway_envs_own_road_gets_the_index():
    env = make_env("highway", record=False, duration=2)
    env.reset(seed=0)
    assert isinstance(env.unwrapped.road.neighbour_vehicles.__self__, FastRoad)
    assert not use_fast_road(env)  # already installed: not twice
    intersection = make_env("intersection", record=False, duration=2)
    intersection.reset(seed=0)  # a RegulatedRoad acts on its own
    assert not use_fast_road(intersection)


@pytest.mark.parametrize("at_once_from", [0, 100])
def test_collisions_are_checked_in_highway_envs_order_whoever_checks_them(monkeypatch,
                                                                         at_once_from):
    """Vehicles that check collisions anywhere in the road's list (an ego entered late, a
    scripted vehicle): the same crashes and impacts as highway-env's loop over all pairs,
    with the pairs pruned at once (numpy) or not (a small road)."""
    import copy

    from tap_bench.sim import fast_road

    monkeypatch.setattr(fast_road, "AT_ONCE_FROM", at_once_from)

    for checks in ([False, True, False, False, True, False], [True] * 6, [False] * 6,
                   [False, False, False, False, False, True]):
        # three overlapping pairs and a chain closing in within the step
        positions = [(100, 0), (102, 0), (140, 0), (141, 0.5), (180, 0), (184.9, 0)]
        obstacle = Obstacle(None, np.array([181.0, 0.0]))  # checks collisions itself
        road, vehicles = _straight_road(positions, objects=[obstacle])
        obstacle.road = road
        for vehicle, check in zip(vehicles, checks, strict=True):
            vehicle.check_collisions = check
        theirs = copy.deepcopy(road)
        FastRoad(road).step(0.2)
        Road.step(theirs, 0.2)
        for ours, reference in zip(road.vehicles, theirs.vehicles, strict=True):
            assert ours.crashed == reference.crashed
            np.testing.assert_array_equal(ours.position, reference.position)
            np.testing.assert_array_equal(np.asarray(ours.impact if ours.impact is not None
                                                     else np.nan),
                                          np.asarray(reference.impact
                                                     if reference.impact is not None
                                                     else np.nan))
        assert road.objects[0].crashed == theirs.objects[0].crashed
        assert any(v.crashed for v in road.vehicles)  # the obstacle's collisions at least


@pytest.mark.parametrize("angle", [0.3, -2.1])
@pytest.mark.parametrize("noise", [0.0, 0.4])
def test_slanted_lanes_and_projections_off_by_less_than_the_tolerance(monkeypatch, angle,
                                                                      noise):
    """On slanted lanes numpy's projection and highway-env's differ in the last bits; with
    ``noise`` the numpy coordinates are moreover moved by up to 0.4 tolerance: every query of
    a simulation is still answered as highway-env does, and so are ties out of road order."""
    from tap_bench.sim import fast_road

    rng = np.random.default_rng(7)
    along = np.repeat(rng.uniform(0, 480, 20), 2)  # pairs of vehicles at the same s
    across = rng.choice([0.0, 4.0, 8.0, 2.0, 5.0 + 1e-9], size=along.size)
    order = rng.permutation(along.size)  # road order unlike s order
    road, vehicles = _straight_road(list(zip(along[order], across[order], strict=True)),
                                    lanes=3, angle=angle)
    for vehicle in vehicles:
        vehicle.on_state_update()
    project = fast_road._project

    def noisy(lane, positions):
        surely, maybe_s, maybe_i = project(lane, positions)
        jitter = np.random.default_rng(len(maybe_s)).uniform(
            -noise, noise, len(surely) + len(maybe_s)) * TOLERANCE
        surely = sorted(v + j for v, j in zip(surely, jitter, strict=False))
        moved = [v + j for v, j in zip(maybe_s, jitter[len(surely):], strict=True)]
        keep = np.argsort(moved, kind="stable")
        return surely, [moved[k] for k in keep], [maybe_i[k] for k in keep]

    monkeypatch.setattr(fast_road, "_project", noisy)
    index = FastRoad(road)
    index.install()
    asked = 0

    def checked(vehicle, lane_index=None):
        nonlocal asked
        answer = index.neighbour_vehicles(vehicle, lane_index)
        assert answer == Road.neighbour_vehicles(road, vehicle, lane_index)
        asked += 1
        return answer

    road.neighbour_vehicles = checked
    for _ in range(20):
        road.act()
        road.step(0.1)
        for vehicle in road.vehicles:
            for lane_index in road.network.all_side_lanes(vehicle.lane_index):
                checked(vehicle, lane_index)
    assert asked > 2000


@pytest.mark.parametrize("angle", [0.0, 0.3, -2.1])
def test_the_closest_lane_is_highway_envs_on_boundaries_ends_and_headings(angle):
    """Positions on the boundary between two lanes (a tie: the first lane wins), beyond the
    lanes' ends, any heading or none: the lane highway-env finds, on slanted lanes too."""
    from highway_env.road.road import RoadNetwork

    road, _ = _straight_road([], lanes=4, angle=angle)
    road.network.add_lane("b", "c", StraightLane(*(
        np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        @ np.array([[500.0, 600.0], [0.0, 0.0]])).T))  # a second segment after the first
    fast = FastRoad(road)
    fast.install()
    assert "get_closest_lane_index" in vars(road.network)
    rng = np.random.default_rng(3)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    points = [(s, lateral) for s in (-50.0, 0.0, 250.0, 499.9, 500.0, 550.0, 700.0)
              for lateral in (-3.0, 0.0, 2.0, 4.0, 6.0, 13.5)]  # 2.0 and 6.0: on boundaries
    points += [tuple(p) for p in rng.uniform([-100, -10], [700, 20], size=(300, 2))]
    asked = 0
    for along, across in points:
        position = rotation @ np.array([along, across])
        for heading in (None, angle, angle + 0.4, angle - np.pi, rng.uniform(-7, 7)):
            assert fast.closest_lane_index(position, heading) == \
                RoadNetwork.get_closest_lane_index(road.network, position, heading)
            asked += 1
    assert asked > 1500


def test_only_networks_of_highway_envs_own_lanes_get_the_fast_lane_lookup():
    from highway_env.road.lane import PolyLaneFixedWidth

    for name in ("highway", "merge", "roundabout", "exit"):  # straight, sine, circular
        env = make_env(name, record=False, duration=2)
        env.reset(seed=0)
        assert "get_closest_lane_index" in vars(env.unwrapped.road.network), name

    class _OwnLane(StraightLane):  # a lane class of its own: its own distance, maybe
        pass

    for extra in (_OwnLane([0, 0], [10, 0]), PolyLaneFixedWidth([(0, 0), (5, 1), (10, 0)])):
        road, _ = _straight_road([], lanes=2)
        road.network.add_lane("b", "c", extra)
        FastRoad(road).install()
        assert "get_closest_lane_index" not in vars(road.network)
    road, _ = _straight_road([], lanes=2)
    road.network.graph["a"]["b"][0].distance_with_heading = lambda *args: 0.0  # on a lane
    FastRoad(road).install()
    assert "get_closest_lane_index" not in vars(road.network)


def _mixed_network(rng: np.random.Generator) -> RoadNetwork:
    """A network of straight, sine and circular lanes with drawn geometry: slants, radii,
    both turning directions, start phases anywhere (wraps across +-pi included), sine
    amplitudes, pulsations and phases, and lanes that share their start or centre."""
    from highway_env.road.lane import CircularLane, SineLane

    network = RoadNetwork()
    for k in range(int(rng.integers(3, 9))):
        kind = rng.integers(3)
        start = rng.uniform(-80, 80, 2)
        if kind == 0:
            lane = StraightLane(start, start + rng.uniform(-150, 150, 2),
                                width=float(rng.choice([3.0, 4.0, 5.5])))
        elif kind == 1:
            lane = SineLane(start, start + rng.uniform(-150, 150, 2),
                            amplitude=float(rng.uniform(0, 4)),
                            pulsation=float(rng.uniform(0.01, 0.5)),
                            phase=float(rng.uniform(-4, 4)))
        else:
            phase = float(rng.uniform(-2 * np.pi, 2 * np.pi))
            clockwise = bool(rng.integers(2))
            sweep = float(rng.uniform(0.2, 2 * np.pi)) * (1 if clockwise else -1)
            lane = CircularLane(start, float(rng.uniform(5, 120)), phase, phase + sweep,
                                clockwise=clockwise)
        network.add_lane(f"n{k % 3}", f"m{k}", lane)
        if rng.random() < 0.3:  # a second lane on the same geometry: an exact tie
            network.add_lane(f"n{k % 3}", f"m{k}", lane)
    return network


def _query_points(network: RoadNetwork, rng: np.random.Generator) -> list[np.ndarray]:
    """Positions anywhere, and on each lane's boundaries, centre line and ends, at a circular
    lane's centre and on the phase where it wraps (half a turn from its start)."""
    lanes = [lane for ends in network.graph.values() for row in ends.values() for lane in row]
    points = [rng.uniform(-250, 250, 2) for _ in range(150)]
    for lane in lanes:
        for s in (0.0, lane.length, rng.uniform(0, lane.length), -3.0, lane.length + 7.0):
            for lateral in (0.0, lane.width / 2, -lane.width / 2, 2.0, rng.uniform(-9, 9)):
                points.append(lane.position(s, lateral))
        if hasattr(lane, "center"):
            points.append(lane.center.copy())
            back = lane.start_phase + np.pi
            for eps in (0.0, 1e-12, -1e-12, 1e-7, -1e-7):
                points.append(lane.center + lane.radius * np.array([np.cos(back + eps),
                                                                    np.sin(back + eps)]))
    return [np.asarray(p, dtype=float) for p in points]


@pytest.mark.parametrize("seed", range(12))
def test_the_closest_lane_is_highway_envs_on_drawn_networks_of_every_lane_kind(seed):
    """Drawn networks of straight, sine and circular lanes; positions anywhere, on lane
    boundaries, on lane centres and ends, at a circular lane's centre and on the phase
    where it wraps; headings of every kind or none: the lane highway-env finds."""
    rng = np.random.default_rng(seed)
    network = _mixed_network(rng)
    road = Road(network=network, np_random=np.random.RandomState(0))
    fast = FastRoad(road)
    fast.install()
    assert "get_closest_lane_index" in vars(network)
    points = _query_points(network, rng)
    asked = 0
    for position in points:
        for heading in (None, 0.0, rng.uniform(-7, 7), rng.uniform(-40, 40), np.pi, -np.pi):
            assert fast.closest_lane_index(position, heading) == \
                RoadNetwork.get_closest_lane_index(network, position, heading)
            asked += 1
    assert asked > 900


@pytest.mark.parametrize("mutation", ["sine term", "circle direction", "circle heading",
                                      "off by two tolerances", "no wrap guard",
                                      "last minimum"])
def test_a_changed_lane_distance_is_caught(monkeypatch, mutation):
    """The drawn networks catch a changed term of the estimated distances, an estimate off
    by more than the tolerance, and ties resolved the other way."""
    from tap_bench.sim import fast_road

    estimate = fast_road._estimate

    def mutated(entry, x, y, heading):
        if mutation == "sine term" and entry[2] == fast_road._SINE:
            entry = (*entry[:11], 0.0, *entry[12:])  # amplitude 0
        elif mutation == "circle direction" and entry[2] == fast_road._CIRCULAR:
            entry = (*entry[:7], -entry[7], *entry[8:])
        elif mutation == "circle heading" and entry[2] == fast_road._CIRCULAR:
            heading = None if heading is None else heading + 0.5
        distance = estimate(entry, x, y, heading)
        if mutation == "off by two tolerances" and entry[0][2] == 0:
            distance += 2 * TOLERANCE
        return distance

    monkeypatch.setattr(fast_road, "_estimate", mutated)
    if mutation == "no wrap guard":  # estimated on the wrap, where a rounding may jump a turn
        monkeypatch.setattr(fast_road, "_WRAP_MARGIN", -1.0)
    differ = 0
    # a rounding that jumps a turn is rare: about one drawn network in ten meets one
    for seed in range(40 if mutation == "no wrap guard" else 12):
        rng = np.random.default_rng(seed)
        network = _mixed_network(rng)
        fast = FastRoad(Road(network=network, np_random=np.random.RandomState(0)))
        fast.install()
        for position in _query_points(network, rng):
            for heading in (None, rng.uniform(-7, 7)):
                answer = fast.closest_lane_index(position, heading)
                if mutation == "last minimum":  # the drawn ties decide: the last of equals
                    lanes = [(a, b, i) for a, ends in network.graph.items()
                             for b, row in ends.items() for i in range(len(row))]
                    distances = [network.get_lane(index).distance_with_heading(position,
                                                                               heading)
                                 for index in lanes]
                    answer = lanes[len(lanes) - 1 - int(np.argmin(distances[::-1]))]
                differ += answer != RoadNetwork.get_closest_lane_index(network, position,
                                                                       heading)
    assert differ > 0


@pytest.mark.parametrize("mul_add", [True, False])
def test_either_dot_product_simulates_bit_for_bit(monkeypatch, mul_add):
    """np.dot of 2-vectors is a0 * b0 + a1 * b1 with some BLAS kernels and a fused
    multiply-add with others (OpenBLAS picks by CPU): both ways of computing it give
    highway-env's simulation (run this file with and without OPENBLAS_CORETYPE=Haswell to
    meet both kernels)."""
    from tap_bench.sim import fast_idm

    if mul_add and not fast_idm._dot_is_mul_add():
        pytest.skip("this machine's BLAS fuses the multiply-add")
    monkeypatch.setattr(fast_idm, "_dot_is_mul_add", lambda: mul_add)
    ours = _episodes("highway", fast_road=True, idm_ego=IDMParameters(), seeds=(2,))
    theirs = _episodes("highway", fast_road=False, idm_ego=IDMParameters(), seeds=(2,))
    pd.testing.assert_frame_equal(ours, theirs, check_exact=True)


@pytest.mark.parametrize("angle", [0.0, 0.3])
def test_leaders_found_at_once_are_highway_envs_ties_edges_and_objects(angle):
    """FastRoad.leaders (every vehicle's leader on a lane at once, during Road.act): the
    objects highway-env's search returns, with ties (the last in road order wins), the
    lane's edges and ends, an obstacle and a landmark (never returned), on slanted lanes."""
    half = StraightLane.DEFAULT_WIDTH / 2 + 1.0
    positions = [(100, 0), (100, 0), (130, 0), (130, 0.5), (70, 0), (70, -0.5),
                 (160, half), (160.5, half + 1e-9), (40, -half), (100 + 1e-12, 0),
                 (100 - 1e-12, 4), (-5, 0), (-5 - 1e-9, 0), (505 - 1e-9, 0), (505, 0),
                 (200, 4), (220, 8), (130, 4), (130, 4.2)]
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    obstacle = Obstacle(None, rotation @ np.array([115.0, 0.0]))
    landmark = Landmark(None, rotation @ np.array([105.0, 0.0]))
    road, vehicles = _straight_road(positions, objects=[obstacle, landmark], angle=angle)
    obstacle.road = landmark.road = road
    index = FastRoad(road)
    checked = []

    def ask_all(*args):
        for lane_index in (("a", "b", 0), ("a", "b", 1), None):
            lanes = [lane_index] * len(vehicles)
            expected = [Road.neighbour_vehicles(road, v, lane_index)[0] for v in vehicles]
            assert index.leaders(vehicles, lanes) == expected
            checked.extend(expected)

    road.vehicles[0].act = ask_all  # asked while the road acts
    index.act()
    assert len(checked) == 3 * len(vehicles)
    assert any(v is obstacle for v in checked) and not any(v is landmark for v in checked)
    outside = index.leaders(vehicles, [None] * len(vehicles))  # outside act: one by one
    assert outside == [Road.neighbour_vehicles(road, v)[0] for v in vehicles]


def test_vehicles_move_through_highway_env_when_its_code_is_not_the_one_repeated(monkeypatch):
    """FastRoad.move repeats highway-env 1.12's Vehicle.step: another version's code (here:
    a digest that does not match) moves every vehicle by its own step."""
    from tap_bench.sim import fast_road

    monkeypatch.setattr(fast_road, "MOVE_AT_ONCE_FROM", 0)
    road, vehicles = _straight_road([(100, 0), (130, 4), (160, 0)])
    fast = FastRoad(road)
    fast.install()
    stepped = []
    monkeypatch.setattr(IDMVehicle, "step", lambda self, dt: stepped.append(self))
    fast_road._moving_class.cache_clear()
    fast.move(0.1)
    assert stepped == vehicles  # a class whose step is not highway-env's moves itself
    monkeypatch.undo()
    monkeypatch.setattr(fast_road, "MOVE_AT_ONCE_FROM", 0)
    fast_road._highway_env_moves_as_written.cache_clear()
    fast_road._moving_class.cache_clear()
    assert fast_road._highway_env_moves_as_written()
    monkeypatch.setitem(fast_road._MOVE_CODE, "Vehicle.step", "0" * 16)
    fast_road._highway_env_moves_as_written.cache_clear()
    fast_road._moving_class.cache_clear()
    kinematics = []
    monkeypatch.setattr(fast_road, "_kinematics", lambda v, dt: kinematics.append(v))
    monkeypatch.setattr(fast_road, "_kinematics_at_once",
                        lambda vs, dt: kinematics.extend(vs))
    before = [v.position.copy() for v in vehicles]
    fast.move(0.1)
    assert not kinematics and all((v.position != p).any()
                                  for v, p in zip(vehicles, before, strict=True))
    fast_road._highway_env_moves_as_written.cache_clear()
    fast_road._moving_class.cache_clear()


def _act_state(road: Road):
    """The road's state as FastRoad reads it for ``Road.act`` (fast_idm.ActState)."""
    from tap_bench.sim import fast_idm, fast_road

    others, positions = FastRoad(road)._snapshot()
    return fast_idm.ActState(others, positions, fast_idm.array_kernels_agree(),
                             projects=fast_road._projects)


def _dense_highway(seed: int) -> tuple[Any, Road]:
    """The fast highway env with 40 vehicles on 4 lanes, reset with ``seed`` (8 s episodes,
    no recording: many lane changes and close leaders), and its road."""
    env = make_env("highway", config={"vehicles_count": 40, "lanes_count": 4}, duration=8,
                   record=False, fast=True)
    env.reset(seed=seed)
    return env, env.unwrapped.road


def _lane_change_mismatches(seeds=(0, 1, 2)) -> dict[str, int]:
    """fast_idm's lane-change policy against highway-env's on drawn highway states.

    Dense 4-lane highways (every fifth other vehicle a user class with its own velocity or
    direction, which MOBIL's accelerations of a follower leave to highway-env) are run a few
    decisions; then each vehicle gets a drawn politeness,
    minimal gain, braking limit and timer (a due decision), and some an ongoing change to a
    side lane (so that vehicles change into the same lane and aborts happen). For every
    vehicle, ``fast_idm._change_lane_policy`` and highway-env's ``change_lane_policy`` run
    from the same state; their target lanes and timers are compared, and every
    ``acceleration`` MOBIL asks (each vehicle with each side lane's and its own lane's
    leader and follower) is compared bit for bit with ``fast_idm._idm``."""
    from tap_bench.sim import fast_idm

    counts = dict.fromkeys(["decisions", "changes", "aborts", "accelerations",
                            "user-class accelerations", "decision mismatches",
                            "acceleration mismatches"], 0)
    for seed in seeds:
        rng = np.random.default_rng(seed)
        env, road = _dense_highway(seed)
        for k, vehicle in enumerate(road.vehicles[1:]):
            if k % 5 == 4:
                vehicle.__class__ = (_SlipIDM, _TurnedIDM)[k % 2]
        for _ in range(5):
            env.step(1)
            vehicles = [v for v in road.vehicles if fast_idm.is_plain_idm(v)]
            for vehicle in vehicles:
                vehicle.POLITENESS = float(rng.choice([0.0, 0.25, 1.0, rng.uniform(0, 2)]))
                vehicle.LANE_CHANGE_MIN_ACC_GAIN = float(rng.uniform(-0.5, 0.5))
                vehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED = float(rng.uniform(0.5, 4))
                vehicle.timer = float(rng.uniform(0, 2))
                sides = road.network.side_lanes(vehicle.lane_index)
                if rng.random() < 0.3 and sides:
                    vehicle.target_lane_index = sides[int(rng.integers(len(sides)))]
            state = _act_state(road)
            for vehicle in vehicles:
                start = (vehicle.target_lane_index, vehicle.timer)
                ours = []
                for read in (None, state):  # the vehicles' own attributes, the road's state
                    fast_idm._change_lane_policy(vehicle, read)
                    ours.append((vehicle.target_lane_index, vehicle.timer))
                    vehicle.target_lane_index, vehicle.timer = start
                IDMVehicle.change_lane_policy(vehicle)
                theirs = (vehicle.target_lane_index, vehicle.timer)
                vehicle.target_lane_index, vehicle.timer = start
                counts["decisions"] += 1
                counts["decision mismatches"] += ours != [theirs, theirs]
                if start[0] != vehicle.lane_index:
                    counts["aborts"] += theirs[0] == vehicle.lane_index
                else:
                    counts["changes"] += theirs[0] != start[0]
                for lane_index in [*road.network.side_lanes(vehicle.lane_index), None]:
                    front, rear = road.neighbour_vehicles(vehicle, lane_index)
                    for ego, ahead in [(rear, front), (rear, vehicle), (vehicle, front)]:
                        want = vehicle.acceleration(ego_vehicle=ego, front_vehicle=ahead)
                        for read in (None, state):
                            got = fast_idm._idm(vehicle, ahead, ego, read) \
                                if ego is not vehicle \
                                else fast_idm._idm(vehicle, ahead, fast_idm._OWN, read)
                            counts["accelerations"] += 1
                            counts["user-class accelerations"] += isinstance(
                                ego, _SlipIDM | _TurnedIDM) or isinstance(
                                    ahead, _SlipIDM | _TurnedIDM)
                            counts["acceleration mismatches"] += (  # bits, signed zeros
                                np.float64(got).tobytes() != np.float64(want).tobytes())
        env.close()
    return counts


def test_the_lane_change_policy_decides_as_highway_envs_on_drawn_states():
    counts = _lane_change_mismatches()
    assert counts["decision mismatches"] == counts["acceleration mismatches"] == 0, counts
    # both outcomes of every branch are exercised
    assert counts["changes"] >= 10 and counts["decisions"] - counts["changes"] >= 100, counts
    assert counts["aborts"] >= 3 and counts["accelerations"] >= 1000, counts
    assert counts["user-class accelerations"] >= 100, counts


def _mutate(monkeypatch, name: str, old: str, new: str) -> None:
    """Replace fast_idm's function ``name`` by its source with ``old`` made ``new``."""
    import inspect

    from tap_bench.sim import fast_idm

    source = inspect.getsource(getattr(fast_idm, name))
    assert old in source  # the mutation applies to the code as it is
    namespace = dict(vars(fast_idm))
    exec(compile(source.replace(old, new, 1), fast_idm.__file__, "exec"), namespace)
    monkeypatch.setattr(fast_idm, name, namespace[name])


@pytest.mark.parametrize(("name", "old", "new"), [
    ("_mobil", "vehicle.POLITENESS *", "2 * vehicle.POLITENESS *"),  # wrong politeness
    ("_mobil", "self_pred_a - self_a", "self_a - self_pred_a"),  # wrong sign
    ("_mobil", "new_following_pred_a - new_following_a",
     "new_following_a - new_following_pred_a"),
    ("_mobil", "< -vehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED",
     "< vehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED"),
    ("_change_lane_policy", "0 < d < d_star", "0 < d < 0.5 * d_star"),  # abort gap
    ("_change_lane_policy", "vehicle.LANE_CHANGE_DELAY < vehicle.timer",
     "vehicle.LANE_CHANGE_DELAY <= vehicle.timer + 0.5"),
    ("_idm", "return acceleration", "return np.nextafter(acceleration, np.inf)"),  # 1 ulp
    ("_desired_gap", "+ speed * dv", "+ speed * np.nextafter(dv, np.inf)"),
    ("_idm", "max(speed, 0)", "max(vehicle.speed, 0)"),  # the follower's own speed
    ("_mobil", "own_lane.append(road.neighbour_vehicles(vehicle))",  # the own lane's
     "own_lane.append(road.neighbour_vehicles(vehicle, lane_index))"),  # neighbours
    ("_mobil", "own_lane[1:]", "own_lane[1:][::-1]"),  # the own lane's terms mixed up
    ("ActState", "return along[j] - along[k]", "return along[j] - along[k] + 1e-12"),
])
def test_a_changed_lane_change_policy_is_caught(monkeypatch, name, old, new):
    """A changed term of the lane-change policy (a wrong politeness, a sign, one ulp in an
    acceleration, desired gap or lane distance, another vehicle's speed, the own lane's
    terms kept between the side lanes wrongly) makes the comparison fail."""
    _mutate(monkeypatch, name, old, new)
    counts = _lane_change_mismatches(seeds=(0, 1, 2))
    assert counts["decision mismatches"] + counts["acceleration mismatches"] > 0, counts


def test_lane_changes_go_through_highway_env_when_its_code_is_not_the_one_repeated(
        monkeypatch):
    """The lane-change policy repeats highway-env 1.12's: another version's source (a digest
    that does not match) or a class with its own ``mobil`` decides by highway-env's code."""
    from tap_bench.sim import fast_idm

    called = []

    class _OwnMobil(IDMVehicle):
        def mobil(self, lane_index):
            called.append(self)
            return False

    _, vehicles = _straight_road([(100, 0), (130, 4), (160, 0)])
    for vehicle in vehicles:
        vehicle.timer = 5.0
    fast_idm._decides_as_written.cache_clear()
    assert fast_idm._decides_as_written(IDMVehicle)
    assert not fast_idm._decides_as_written(_OwnMobil)
    vehicles[0].__class__ = _OwnMobil
    fast_idm._change_lane_policy(vehicles[0])
    assert called == [vehicles[0]]
    monkeypatch.setitem(fast_idm._DECIDE_CODE, "IDMVehicle.mobil", "0" * 16)
    fast_idm._highway_env_decides_as_written.cache_clear()
    fast_idm._decides_as_written.cache_clear()
    asked = []
    monkeypatch.setattr(IDMVehicle, "change_lane_policy", lambda self: asked.append(self))
    fast_idm._change_lane_policy(vehicles[1])
    assert asked == [vehicles[1]]
    monkeypatch.undo()
    fast_idm._highway_env_decides_as_written.cache_clear()
    fast_idm._decides_as_written.cache_clear()
    assert fast_idm._decides_as_written(IDMVehicle)


def _table_mismatches(seeds=range(30)) -> dict[str, int]:
    """Every query of every vehicle on every lane (and on its own), asked while the road
    acts (FastRoad's lane tables), against highway-env's own search, on drawn straight
    roads: slanted or not, vehicles drawn from few coordinates (ties in s, equal s on
    other lanes, -0.0 and 0.0), on the lanes' edges and ends and just beyond them, in road
    orders unlike their order on the lane, with obstacles, a landmark and sometimes a
    vehicle whose position is not finite."""
    half = StraightLane.DEFAULT_WIDTH / 2 + 1.0  # highway-env's on-lane margin is 1 m
    counts = {"queries": 0, "mismatches": 0, "fronts": 0, "rears": 0, "tied answers": 0,
              "not finite": 0}
    lanes = [("a", "b", 0), ("a", "b", 1), ("a", "b", 2), None]
    for seed in seeds:
        rng = np.random.default_rng(seed)
        angle = float(rng.choice([0.0, 0.3, -2.1, np.pi / 2]))
        pool_s = np.concatenate([rng.uniform(-10, 510, 6),
                                 [-5, -5 - 1e-9, 505 - 1e-9, 505, 0.0, -0.0, 100, 100 + 1e-12]])
        pool_r = [0.0, 0.5, -0.5, half, half + 1e-9, -half, 4.0, 4 + half, 8.0, 2.0, 6.0, 13.0]
        n = int(rng.integers(3, 30))
        positions = list(zip(rng.choice(pool_s, n), rng.choice(pool_r, n), strict=True))
        rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        objects = [Obstacle(None, rotation @ np.array([rng.choice(pool_s), rng.choice(pool_r)]))
                   for _ in range(int(rng.integers(0, 3)))]
        landmark = Landmark(None, rotation @ np.array([rng.choice(pool_s), 0.0]))
        road, vehicles = _straight_road(positions, objects=[*objects, landmark], lanes=3,
                                        angle=angle)
        for obj in [*objects, landmark]:
            obj.road = road
        if rng.random() < 0.3:  # a vehicle whose position is not finite
            vehicles[int(rng.integers(n))].position = np.array([np.nan, 0.0])
            counts["not finite"] += 1
        index = FastRoad(road)

        def ask_all(*args, vehicles=vehicles, road=road, index=index):
            for vehicle in vehicles:
                for lane_index in lanes:
                    want = Road.neighbour_vehicles(road, vehicle, lane_index)
                    got = index.neighbour_vehicles(vehicle, lane_index)
                    counts["queries"] += 1
                    counts["mismatches"] += (got[0] is not want[0]) or (got[1] is not want[1])
                    lane = road.network.get_lane(lane_index or vehicle.lane_index)
                    s_of = {id(v): lane.local_coordinates(v.position)[0]  # on the lane
                            for v in road.vehicles + road.objects
                            if lane.on_lane(v.position, margin=1)}
                    for answer, key in zip(want, ("fronts", "rears"), strict=True):
                        if answer is not None:
                            counts[key] += 1
                            counts["tied answers"] += sum(
                                s == s_of[id(answer)] for k, s in s_of.items()
                                if k not in (id(answer), id(vehicle))) > 0

        road.vehicles[0].act = ask_all  # asked while the road acts
        index.act()
    return counts


def test_the_lane_tables_answer_as_highway_envs_search_on_drawn_roads():
    counts = _table_mismatches()
    assert counts["mismatches"] == 0, counts
    assert counts["queries"] >= 1500 and counts["fronts"] >= 500 and counts["rears"] >= 500
    assert counts["tied answers"] >= 50 and counts["not finite"] >= 2, counts


@pytest.mark.parametrize(("name", "old", "new"), [
    ("_from_table", "last = bisect.bisect_right(keys, keys[j], j) - 1", "last = j"),  # ties
    ("_from_table", "rows[bisect.bisect_left(keys, keys[start - 1])]", "rows[start - 1]"),
    ("_from_table", "if rows[last] == me:", "if False:"),  # the vehicle itself
    ("_from_table", "if j < len(keys) and rows[j] == me:", "if False:"),
    ("_from_table", "start = bisect.bisect_left(keys, s)", "start = bisect.bisect_right(keys, s)"),
    ("_from_table", "if s != s:", "if False:"),  # a position not finite
    ("_table", "lane.width / 2 + _MARGIN", "lane.width / 2"),  # the on-lane margin
    ("_table", "along < lane.length + lane.VEHICLE_LENGTH",
     "along <= lane.length + lane.VEHICLE_LENGTH"),
    ("_table", "np.lexsort((rows, along[rows]))", "np.lexsort((-rows, along[rows]))"),
])
def test_a_changed_lane_table_is_caught(monkeypatch, name, old, new):
    """A changed rule of the lane tables (ties kept in the wrong road order, the vehicle
    itself returned, s < s_v for s <= s_v, a missed margin or end, NaN not handled) makes
    the drawn comparison fail."""
    import inspect
    import textwrap

    from tap_bench.sim import fast_road

    source = textwrap.dedent(inspect.getsource(getattr(FastRoad, name)))
    assert old in source  # the mutation applies to the code as it is
    namespace = dict(vars(fast_road))
    exec(compile(source.replace(old, new, 1), fast_road.__file__, "exec"), namespace)
    monkeypatch.setattr(FastRoad, name, namespace[name])
    counts = _table_mismatches()
    assert counts["mismatches"] > 0, counts


def test_the_search_goes_through_highway_env_when_its_code_is_not_the_one_repeated(
        monkeypatch):
    """The lane tables repeat highway-env 1.12's search: another version's source (a digest
    that does not match), a lane with its own projection or a replaced method on the lane
    class: highway-env's own search answers."""
    from tap_bench.sim import fast_road

    road, vehicles = _straight_road([(100, 0), (130, 0), (160, 4)])
    from_table = FastRoad._from_table
    tabled = []

    def counted(self, *args):
        tabled.append(args)
        return from_table(self, *args)

    monkeypatch.setattr(FastRoad, "_from_table", counted)

    def ask() -> int:
        """How many of the vehicles' queries, asked while the road acts, the tables
        answered (each answer is highway-env's)."""
        index = FastRoad(road)
        answers = []
        vehicles[0].act = lambda *args: answers.extend(
            index.neighbour_vehicles(v) for v in vehicles)
        for vehicle in vehicles[1:]:
            vehicle.act = lambda *args: None
        tabled.clear()
        index.act()
        assert answers == [Road.neighbour_vehicles(road, v) for v in vehicles]
        return len(tabled)

    assert ask() == len(vehicles)  # the tables
    code = fast_road._SEARCH_CODE
    monkeypatch.setattr(fast_road, "_SEARCH_CODE", {**code, "AbstractLane.on_lane": "0" * 16})
    fast_road._search_sources_match.cache_clear()
    try:
        assert ask() == 0  # another highway-env's source
    finally:
        monkeypatch.setattr(fast_road, "_SEARCH_CODE", code)
        fast_road._search_sources_match.cache_clear()
    assert ask() == len(vehicles)
    lane = road.network.get_lane(("a", "b", 0))
    lane.local_coordinates = lambda position: StraightLane.local_coordinates(lane, position)
    assert ask() == 1  # the vehicle on the other lane
    del lane.local_coordinates
    monkeypatch.setattr(StraightLane, "width_at", lambda self, longitudinal: 3.0)
    assert ask() == 0


@pytest.mark.parametrize(("old", "new"), [
    ("speed * np.sin(beta) / half_length * dt", "speed * (np.sin(beta) / half_length) * dt"),
    ("np.stack([np.cos(angle), np.sin(angle)], axis=1) * dt",
     "(np.stack([np.cos(angle), np.sin(angle)], axis=1) * dt)"),
    ("angle = heading + beta", "angle = (heading + 2 * beta) - beta"),
    ("1 / 2 * np.tan(steering)", "np.tan(steering) / 2.0000000001"),
])
def test_a_changed_formula_of_the_motion_at_once_is_caught(monkeypatch, old, new):
    """The kinematics of all vehicles at once with a term reassociated or changed by rounding
    only: the bit-for-bit comparison of every vehicle's state sees it."""
    import inspect

    from tap_bench.sim import fast_road

    source = inspect.getsource(fast_road._kinematics_at_once)
    assert old in source  # the mutation applies to the code as it is
    namespace = dict(vars(fast_road))
    exec(compile(source.replace(old, new, 1), fast_road.__file__, "exec"), namespace)
    monkeypatch.setattr(fast_road, "_kinematics_at_once", namespace["_kinematics_at_once"])
    ours = _episodes("highway", fast_road=True, fast=True, seeds=(0,))
    theirs = _episodes("highway", fast_road=False, fast=True, seeds=(0,))
    with pytest.raises(AssertionError):
        pd.testing.assert_frame_equal(ours, theirs, check_exact=True)


def _act_mismatches(seeds=(0, 1, 2)) -> dict[str, int]:
    """FastRoad's ``Road.act`` (fast_idm on the road's ActState) against highway-env's own
    ``Road.act`` (and its own search) on drawn highway states.

    Dense 4-lane highways (every fifth other vehicle a user class whose velocity or
    direction is not highway-env's) are run a few decisions; then every plain IDM vehicle
    is moved up to 3 m across its lane and gets a drawn heading (up to 0.8 rad off the
    road), speed (negative, within ``not_zero``'s 0.01 of zero, or up to 40 m/s), target
    speed, exponent and timer (a due lane-change decision), some an ongoing change to a
    side lane, and some lanes a speed limit, so that every clip of the steering and of the
    acceleration binds. Both run from the same state; every vehicle's action (its bits,
    signed zeros included), target lane and timer are compared."""
    from highway_env.vehicle.behavior import IDMVehicle

    from tap_bench.sim import fast_idm

    counts = dict.fromkeys(["vehicles", "egos", "steering clipped", "acceleration clipped",
                            "changing", "limited", "slow", "mismatches"], 0)
    for seed in seeds:
        rng = np.random.default_rng(seed)
        env, road = _dense_highway(seed)
        fast = road.act
        for k, vehicle in enumerate(road.vehicles[1:]):
            if k % 5 == 4:
                vehicle.__class__ = (_SlipIDM, _TurnedIDM)[k % 2]
        lanes = [road.network.get_lane(("0", "1", i)) for i in range(4)]
        for _ in range(4):
            env.step(int(rng.integers(5)))
            for lane in lanes:
                lane.speed_limit = float(rng.choice([20.0, 25.0, 30.0])) \
                    if rng.random() < 0.5 else None
            for vehicle in road.vehicles:
                if not (fast_idm.is_plain_idm(vehicle) or vehicle is road.vehicles[0]):
                    continue  # the plain IDM vehicles and the ego (an MDPVehicle)
                vehicle.position = vehicle.position + np.array([0.0, rng.uniform(-3, 3)])
                vehicle.heading = float(rng.choice([rng.uniform(-0.8, 0.8), 0.0, -0.0]))
                vehicle.speed = float(rng.choice([rng.uniform(-3, 0), rng.uniform(-0.01, 0.01),
                                                  rng.uniform(0, 40), rng.uniform(15, 35)]))
                vehicle.target_speed = float(rng.choice([rng.uniform(-5, 45), 0.0, -0.0,
                                                         rng.uniform(-0.01, 0.01)]))
                vehicle.DELTA = float(rng.uniform(2, 6))
                vehicle.timer = float(rng.uniform(0, 2))
                sides = road.network.side_lanes(vehicle.lane_index)
                if rng.random() < 0.3 and sides:
                    vehicle.target_lane_index = sides[int(rng.integers(len(sides)))]
            saved = [(vehicle, dict(vars(vehicle))) for vehicle in road.vehicles]
            random_state = road.np_random.bit_generator.state
            outcomes = []
            for act in (fast, lambda road=road: Road.act(road)):
                for vehicle, attributes in saved:
                    vars(vehicle).clear()
                    vars(vehicle).update(attributes)
                road.np_random.bit_generator.state = random_state
                search = vars(road).pop("neighbour_vehicles") if act is not fast else None
                act()
                if search is not None:
                    road.neighbour_vehicles = search
                outcomes.append([(v.target_lane_index, getattr(v, "timer", None),
                                  np.float64(v.action["steering"]).tobytes(),
                                  np.float64(v.action["acceleration"]).tobytes())
                                 for v in road.vehicles])
            for vehicle, ours, theirs in zip(road.vehicles, *outcomes, strict=True):
                if vehicle is road.vehicles[0]:  # the ego: highway-env's act restated
                    counts["egos"] += fast_idm._controls_as_written(vehicle)
                    counts["mismatches"] += ours != theirs
                if not fast_idm.is_plain_idm(vehicle):
                    continue
                counts["vehicles"] += 1
                counts["mismatches"] += ours != theirs
                counts["steering clipped"] += abs(vehicle.action["steering"]) \
                    == vehicle.MAX_STEERING_ANGLE
                counts["acceleration clipped"] += abs(vehicle.action["acceleration"]) \
                    == vehicle.ACC_MAX
                counts["changing"] += vehicle.lane_index != vehicle.target_lane_index
                counts["limited"] += vehicle.lane.speed_limit is not None
                counts["slow"] += abs(vehicle.speed) < 0.01
            assert isinstance(road.vehicles[1], IDMVehicle)
        env.close()
    return counts


@pytest.mark.parametrize("one_at_a_time", [False, True])
def test_vehicles_act_as_with_highway_envs_act_on_drawn_states(monkeypatch, one_at_a_time):
    from tap_bench.sim import fast_road

    if one_at_a_time:
        monkeypatch.setattr(fast_road, "AT_ONCE_FROM", 10 ** 6)
    counts = _act_mismatches()
    assert counts["mismatches"] == 0, counts
    assert counts["vehicles"] >= 300 and counts["changing"] >= 30, counts
    assert counts["egos"] == 12, counts  # 3 seeds x 4 states
    assert min(counts["steering clipped"], counts["acceleration clipped"], counts["limited"],
               counts["slow"]) >= 10, counts


@pytest.mark.parametrize(("name", "old", "new"), [
    ("_act_straight", "heading_ref - heading + np.pi", "heading_ref + np.pi - heading"),
    ("_act_straight", "quarter = np.pi / 4", "quarter = np.pi / 3"),  # a wrong clip
    ("_act_straight", "target_speed = _clip(target_speed, 0, own[7])", "pass"),  # no limit
    ("_act_straight", "abs(_not_zero_one(target_speed))",
     "abs(_not_zero_one(target_speed, 0.02))"),
    ("_act_straight", "if changed < acceleration:", "if True:"),  # min() on the target lane
    ("_act_straight", "- own_s", "- np.nextafter(own_s, np.inf)"),  # one ulp in a gap
    ("_act_straight", "(2 * np.sqrt(-comfort_max * comfort_min))",
     "2 * np.sqrt(-comfort_max * comfort_min)"),
    ("ActState", "cos, sin = np.cos(heading).tolist(), np.sin(heading).tolist()",
     "cos, sin = np.cos(heading + 1e-9).tolist(), np.sin(heading).tolist()"),
    ("ActState", "return speed * cos, speed * sin", "return speed * cos, speed * cos"),
    ("_dot2", "return a0 * b0 + a1 * b1", "return a0 * (b0 + 1e-12) + a1 * b1"),
    ("_act_controlled", "(vehicle.target_speed - vehicle.speed)",  # the ego's
     "(vehicle.target_speed - np.nextafter(vehicle.speed, np.inf))"),  # acceleration
    ("_act_controlled", "-vehicle.MAX_STEERING_ANGLE,", "-vehicle.MAX_STEERING_ANGLE / 2,"),
])
def test_a_changed_formula_of_the_actions_is_caught(monkeypatch, name, old, new):
    """A changed term of the steering, the IDM accelerations or the road's state (one
    rounding, a clip, a speed limit, the min of the two lanes' accelerations, a cos) makes
    the comparison of actions on drawn states fail."""
    from tap_bench.sim import fast_road

    _mutate(monkeypatch, name, old, new)
    if name == "ActState":
        from tap_bench.sim import fast_idm

        monkeypatch.setattr(fast_road, "ActState", fast_idm.ActState)
    assert _act_mismatches(seeds=(0,))["mismatches"] > 0


def _two_road_chain(angle: float) -> tuple[Road, float]:
    """Two 2-lane straight roads, a->b (100 m) then b->c (200 m), turned by ``angle``
    [rad]: the road, and where highway-env's ``after_end`` says the first road's lanes end
    [m along the lane]."""
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    network = RoadNetwork()
    for lane in range(2):
        network.add_lane("a", "b", StraightLane(rotation @ [0, 4 * lane],
                                                rotation @ [100, 4 * lane]))
        network.add_lane("b", "c", StraightLane(rotation @ [100, 4 * lane],
                                                rotation @ [300, 4 * lane]))
    road = Road(network=network, np_random=np.random.RandomState(0))
    return road, 100 - StraightLane.VEHICLE_LENGTH / 2


def _follow_road_outcomes(angle: float) -> tuple[list, list]:
    """Vehicles at, one ulp around and a little before and past the point where
    highway-env's ``after_end`` says a straight lane ends (``length - VEHICLE_LENGTH / 2``)
    on a road turned by ``angle`` [rad], each targeting its own lane: their target lanes
    after fast_idm's ``_follow_road`` (the road's state) and after highway-env's
    ``follow_road`` (which switches to the next road's lane past the end)."""
    from tap_bench.sim import fast_idm

    road, end = _two_road_chain(angle)
    network = road.network
    places = [end, np.nextafter(end, 0), np.nextafter(end, 200), end - 1e-9, end + 1e-9,
              end - 3, end + 3, 101.0, 99.0, -1.0]
    for lane in range(2):
        for s in places:
            lane_index = ("a", "b", lane)
            position = network.get_lane(lane_index).position(s, 0.0)
            vehicle = IDMVehicle(road, position, angle, 20.0, target_lane_index=lane_index)
            vehicle.lane_index, vehicle.lane = lane_index, network.get_lane(lane_index)
            road.vehicles.append(vehicle)
    state = _act_state(road)
    ours, theirs = [], []
    for vehicle in road.vehicles:
        start = vehicle.target_lane_index
        fast_idm._follow_road(vehicle, state)
        ours.append(vehicle.target_lane_index)
        vehicle.target_lane_index = start
        vehicle.follow_road()
        theirs.append(vehicle.target_lane_index)
        vehicle.target_lane_index = start
    return ours, theirs


@pytest.mark.parametrize("angle", [0.0, 0.3, -2.1])
def test_the_end_of_a_lane_is_seen_as_highway_env_sees_it(angle):
    ours, theirs = _follow_road_outcomes(angle)
    assert ours == theirs
    switched = sum(lane[0] == "b" for lane in theirs)
    assert 4 <= switched <= len(theirs) - 4  # both outcomes, near the end


@pytest.mark.parametrize(("old", "new"), [
    ("> lane.length - lane.VEHICLE_LENGTH / 2",
     "> lane.length - lane.VEHICLE_LENGTH / 2 + 1e-12"),
    ("> lane.length - lane.VEHICLE_LENGTH / 2", "> lane.length - lane.VEHICLE_LENGTH / 3"),
    ("projection[2][k]", "np.nextafter(projection[2][k], 0)"),
])
def test_a_changed_end_of_lane_is_caught(monkeypatch, old, new):
    _mutate(monkeypatch, "_follow_road", old, new)
    assert any(ours != theirs for ours, theirs in (_follow_road_outcomes(angle)
                                                  for angle in (0.0, 0.3)))


def test_the_end_of_a_lane_is_highway_envs_when_its_code_is_not_the_one_repeated(monkeypatch):
    """Another highway-env's ``follow_road`` or ``after_end`` source, or a lane whose
    ``after_end`` is its own, and highway-env's ``follow_road`` decides."""
    from tap_bench.sim import fast_idm

    road, vehicles = _straight_road([(100, 0)])
    state = _act_state(road)
    asked = []
    vehicles[0].follow_road = lambda: asked.append(vehicles[0])  # highway-env's, counted

    def ask() -> int:
        asked.clear()
        fast_idm._follow_road(vehicles[0], state)
        return len(asked)

    assert ask() == 0  # read from the road's state
    monkeypatch.setitem(fast_idm._FOLLOW_CODE, "AbstractLane.after_end", "0" * 16)
    fast_idm._follows_as_written.cache_clear()
    try:
        assert ask() == 1  # another highway-env's source
    finally:
        monkeypatch.undo()
        fast_idm._follows_as_written.cache_clear()
    assert ask() == 0
    lane = road.network.get_lane(vehicles[0].target_lane_index)
    lane.after_end = lambda position, longitudinal=None, lateral=None: False
    assert ask() == 1  # the lane's own end
    del lane.after_end
    monkeypatch.setattr(IDMVehicle, "follow_road", lambda self: None)
    assert ask() == 1  # a changed follow_road


def _highway_gap(a, b, dt: float) -> float:
    """The widest gap highway-env's rectangle test finds between ``a`` and ``b`` (moving by
    their velocities times ``dt``): over the normals of both polygons' sides, computed as
    ``utils.are_polygons_intersecting`` computes them, the larger axis's smaller of the
    gap now and over the step (> 0: the test returns "apart")."""
    from highway_env import utils

    pa, pb = a.polygon(), b.polygon()
    moved = a.velocity * dt - b.velocity * dt
    best = -np.inf
    for polygon in (pa, pb):
        for p1, p2 in itertools.pairwise(polygon):
            normal = np.array([-p2[1] + p1[1], p2[0] - p1[0]])
            normal /= np.linalg.norm(normal)
            min_a, max_a = utils.project_polygon(pa, normal)
            min_b, max_b = utils.project_polygon(pb, normal)
            now = utils.interval_distance(min_a, max_a, min_b, max_b)
            projection = normal.dot(moved)
            if projection < 0:
                min_a += projection
            else:
                max_a += projection
            best = max(best, min(now, utils.interval_distance(min_a, max_a, min_b, max_b)))
    return best


def _rectangle_pairs(seed: int) -> list[tuple]:
    """Drawn pairs of rectangles close enough for highway-env's spherical pre-check to let
    them through: vehicles of drawn sizes, headings and speeds (some reversing) up to 10 km
    from the origin, the second one at a drawn offset or side by side with the first at a
    gap near the tolerance; some obstacles."""
    from highway_env.vehicle.kinematics import Vehicle

    rng = np.random.default_rng(seed)
    pairs = []
    for _ in range(300):
        centre = rng.uniform(-9000, 9000, 2) * rng.choice([1e-3, 1.0])
        heading = rng.uniform(-np.pi, np.pi)
        a = Vehicle(None, centre, heading, rng.uniform(-5, 40))
        a.LENGTH, a.WIDTH = rng.uniform(0.5, 12), rng.uniform(0.5, 4)
        dt = float(rng.choice([0.1, 0.2, 1.0]))
        if rng.random() < 0.3:  # side by side, parallel, at a gap near the tolerance
            gap = float(rng.choice([0.0, 1e-12, 1e-9, 1e-7, 9e-7, 1.1e-6, 2e-6, 1e-5, 0.01,
                                    0.3]))
            side = np.array([-np.sin(heading), np.cos(heading)])
            b = Vehicle(None, centre + side * (a.WIDTH + gap), heading, a.speed)
            b.LENGTH, b.WIDTH = a.LENGTH, a.WIDTH
        else:
            offset = rng.uniform(-1, 1, 2) * (a.LENGTH + abs(a.speed) * dt + 6)
            b = (Obstacle(None, centre + offset, rng.uniform(-np.pi, np.pi))
                 if rng.random() < 0.2 else
                 Vehicle(None, centre + offset, rng.uniform(-np.pi, np.pi),
                         rng.uniform(-5, 40)))
            b.LENGTH, b.WIDTH = rng.uniform(0.5, 12), rng.uniform(0.5, 4)
        pairs.append((a, b, dt))
    return pairs


@pytest.mark.parametrize("seed", range(4))
def test_pairs_apart_are_those_highway_envs_rectangle_test_finds_apart(seed):
    """fast_road._apart skips a pair only where highway-env's own test finds it apart by
    more than the rounding of either computation (so its check does nothing), and finds
    nearly all the pairs that are apart by more than the tolerance."""
    from tap_bench.sim.fast_road import _apart

    skipped = apart = 0
    for a, b, dt in _rectangle_pairs(seed):
        gap = _highway_gap(a, b, dt)
        if _apart(a, b, dt):
            skipped += 1
            assert gap > TOLERANCE - 1e-7, (gap, a.position, b.position)
            assert a._is_colliding(b, dt)[:2] == (False, False)
        else:
            assert gap <= TOLERANCE + 1e-7, (gap, a.position, b.position)
        apart += gap > TOLERANCE
    assert skipped == apart or abs(skipped - apart) <= 2  # gaps within rounding of 1e-6
    assert skipped >= 60 and len(_rectangle_pairs(seed)) - skipped >= 60


@pytest.mark.parametrize(("old", "new"), [
    ("if moved < 0:", "if moved > 0:"),  # the step's travel on the wrong side
    ("ra = la * abs(ca * nx + sa * ny) + wa * abs(ca * ny - sa * nx)",
     "ra = wa * abs(ca * nx + sa * ny) + la * abs(ca * ny - sa * nx)"),  # length and width
    ("dx, dy = va * ca - vb * cb, va * sa - vb * sb", "dx, dy = va * ca, va * sa"),
    ("TOLERANCE", "0.0"),  # no margin for the rounding (both gaps)
    ("pa, pb = ax * nx + ay * ny, bx * nx + by * ny",
     "pa, pb = ax * nx + ay * ny, bx * nx + by * nx"),
])
def test_a_changed_rectangle_test_is_caught(monkeypatch, old, new):
    import inspect

    from tap_bench.sim import fast_road

    source = inspect.getsource(fast_road._apart)
    assert old in source  # the mutation applies to the code as it is
    namespace = dict(vars(fast_road))
    exec(compile(source.replace(old, new), fast_road.__file__, "exec"), namespace)
    with pytest.raises(AssertionError):
        for seed in range(4):
            for a, b, dt in _rectangle_pairs(seed):
                gap = _highway_gap(a, b, dt)
                if namespace["_apart"](a, b, dt):
                    assert gap > TOLERANCE - 1e-7
                else:
                    assert gap <= TOLERANCE + 1e-7


def test_rectangles_not_highway_envs_are_checked_by_highway_env(monkeypatch):
    """A vehicle with its own polygon or collision test, another highway-env's collision
    code, a position beyond 10 km or a side under 0.5 m: the pair is never skipped."""
    from highway_env.vehicle.kinematics import Vehicle

    from tap_bench.sim import fast_road

    def pair(**changes):
        a = Vehicle(None, np.array([100.0, 0.0]), 0.0, 20.0)
        b = Vehicle(None, np.array([100.0, 4.0]), 0.0, 20.0)
        for name, value in changes.items():
            setattr(a, name, value)
        return a, b

    assert fast_road._apart(*pair(), 0.2)  # side by side, 2 m apart
    a, b = pair()
    a.polygon = lambda: _own_polygon(a)
    assert not fast_road._apart(a, b, 0.2)
    assert not fast_road._apart(*pair(position=np.array([2e4, 0.0])), 0.2)
    assert not fast_road._apart(*pair(WIDTH=0.4), 0.2)
    assert not fast_road._apart(*pair(heading=np.nan), 0.2)

    class _Round(Vehicle):
        def _is_colliding(self, other, dt):
            return False, False, None

    a, b = pair()
    a.__class__ = _Round
    assert not fast_road._apart(a, b, 0.2)
    monkeypatch.setitem(fast_road._COLLISION_CODE, "RoadObject.polygon", "0" * 16)
    fast_road._collides_as_written.cache_clear()
    try:
        assert not fast_road._apart(*pair(), 0.2)
    finally:
        monkeypatch.undo()
        fast_road._collides_as_written.cache_clear()
    assert fast_road._apart(*pair(), 0.2)


def _own_polygon(obj):
    """highway-env's polygon of ``obj``, as a user's own method would return it."""
    from highway_env.vehicle.objects import RoadObject

    return RoadObject.polygon(obj)


@pytest.mark.parametrize("seed", range(3))
def test_the_near_pairs_are_those_highway_envs_pre_check_lets_through(seed):
    """On drawn roads (vehicles and obstacles close together, NaN positions, none to all of
    them checking collisions, so both the pairs of the few that check and all pairs at
    once are measured): the pairs are in highway-env's order, each with one that checks,
    every pair highway-env's spherical pre-check lets through is among them, and every
    other is farther than its bound by no more than the tolerance."""
    from highway_env.vehicle.kinematics import Vehicle

    from tap_bench.sim.fast_road import _pairs_to_check

    rng = np.random.default_rng(seed)
    kinds = set()
    for _ in range(40):
        n, m = int(rng.integers(2, 25)), int(rng.integers(0, 4))
        vehicles = [Vehicle(None, rng.uniform(0, 60, 2), 0.0, rng.uniform(-5, 30))
                    for _ in range(n)]
        objects = [Obstacle(None, rng.uniform(0, 60, 2)) for _ in range(m)]
        everyone = vehicles + objects
        share = rng.choice([0.0, 0.05, 0.2, 0.5, 1.0])
        for obj in everyone:
            obj.check_collisions = bool(rng.random() < share)
        if rng.random() < 0.2:
            vehicles[int(rng.integers(n))].position = np.array([np.nan, 3.0])
        dt = float(rng.choice([0.1, 0.2]))
        pairs = _pairs_to_check(vehicles, objects, dt)
        assert pairs == sorted(pairs) and len(set(pairs)) == len(pairs)
        checkers = sum(obj.check_collisions for obj in everyone)
        kinds.add(4 * checkers > len(everyone))
        for i, a in enumerate(vehicles):
            for j in range(i + 1, len(everyone)):
                b = everyone[j]
                if not (a.check_collisions or b.check_collisions):
                    assert (i, j) not in pairs
                    continue
                distance = np.linalg.norm(b.position - a.position)
                bound = (a.diagonal + b.diagonal) / 2 + a.speed * dt
                if not distance > bound:  # highway-env's pre-check lets it through
                    assert (i, j) in pairs
                elif (i, j) in pairs:
                    assert distance <= bound + 2 * TOLERANCE
    assert kinds == {True, False}  # both ways of measuring


def test_the_ego_acts_by_highway_envs_code_where_it_is_not_the_one_repeated(monkeypatch):
    """The ego's act (an MDPVehicle's, no new high-level action) is restated only for
    highway-env's own classes and code: a class with its own steering or speed control, an
    instance's own act, or another highway-env's source acts by its own ``act``."""
    from highway_env.vehicle.controller import ControlledVehicle, MDPVehicle

    from tap_bench.sim import fast_idm

    env = make_env("highway", record=False, duration=2)
    env.reset(seed=0)
    ego = env.unwrapped.vehicle
    assert type(ego) is MDPVehicle and fast_idm._controls_as_written(ego)

    class _Gentle(MDPVehicle):
        def speed_control(self, target_speed):
            return 0.5 * super().speed_control(target_speed)

    class _Own(ControlledVehicle):
        def act(self, action=None):
            super().act(action)

    for cls in (_Gentle, _Own):
        ego.__class__ = cls
        assert not fast_idm._controls_as_written(ego)
    ego.__class__ = MDPVehicle
    ego.act = lambda *args: None
    assert not fast_idm._controls_as_written(ego)
    del ego.act
    monkeypatch.setitem(fast_idm._CONTROL_CODE, "ControlledVehicle.act", "0" * 16)
    fast_idm._control_class.cache_clear()
    try:
        assert not fast_idm._controls_as_written(ego)
    finally:
        monkeypatch.undo()
        fast_idm._control_class.cache_clear()
    assert fast_idm._controls_as_written(ego)


def _ego_outcomes(angle: float) -> tuple[list, list]:
    """MDPVehicles around the end of a straight lane (as in :func:`_follow_road_outcomes`)
    on a road turned by ``angle``, at drawn speeds and headings: their target lanes and
    actions (bits) after fast_idm's ``_act_controlled`` and after highway-env's ``act``."""
    from highway_env.vehicle.controller import MDPVehicle

    from tap_bench.sim import fast_idm

    rng = np.random.default_rng(0)
    road, end = _two_road_chain(angle)
    network = road.network
    for lane in range(2):
        for s in (end, np.nextafter(end, 200), end - 3, end + 3, 50.0):
            lane_index = ("a", "b", lane)
            position = network.get_lane(lane_index).position(s, rng.uniform(-2, 2))
            ego = MDPVehicle(road, position, angle + rng.uniform(-0.5, 0.5),
                             float(rng.choice([rng.uniform(-0.01, 0.01), 25.0])),
                             target_lane_index=lane_index)
            ego.lane_index, ego.lane = lane_index, network.get_lane(lane_index)
            road.vehicles.append(ego)
    state = _act_state(road)
    ours, theirs = [], []
    for ego in road.vehicles:
        assert fast_idm._controls_as_written(ego)
        start = ego.target_lane_index
        for act, out in ((lambda e=ego: fast_idm._act_controlled(e, state), ours),
                         (ego.act, theirs)):
            ego.target_lane_index = start
            act()
            out.append((ego.target_lane_index, type(ego.action["steering"]),
                        np.float64(ego.action["steering"]).tobytes(),
                        np.float64(ego.action["acceleration"]).tobytes()))
    return ours, theirs


@pytest.mark.parametrize("angle", [0.0, 0.3, -2.1])
def test_the_ego_acts_as_highway_envs_ego(angle):
    ours, theirs = _ego_outcomes(angle)
    assert ours == theirs
    assert 2 <= sum(target[0] == "b" for target, *_ in theirs) <= len(theirs) - 2


@pytest.mark.parametrize(("old", "new"), [
    ("    _follow_road(vehicle, state)\n", ""),  # the end of the lane not seen
    ("vehicle.target_speed - vehicle.speed", "vehicle.target_speed - vehicle.speed * 1.0"
     " - 1e-12"),
    ("steering = np.float64(", "steering = float("),  # np.clip's type
])
def test_a_changed_act_of_the_ego_is_caught(monkeypatch, old, new):
    _mutate(monkeypatch, "_act_controlled", old, new)
    assert any(ours != theirs for ours, theirs in (_ego_outcomes(a) for a in (0.0, 0.3)))
