"""The numpy Kinematics observation returns highway-env's arrays bit for bit; the fast
training variant of a scenario simulates at 5 Hz and checks only the ego's collisions."""

from __future__ import annotations

import numpy as np
import pytest
from highway_env.envs.common.observation import KinematicObservation
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.kinematics import Vehicle
from highway_env.vehicle.objects import Obstacle

from tap_bench.sim import make_env
from tap_bench.sim.observation import FastKinematicObservation, use_fast_observation

KINEMATICS = {"type": "Kinematics"}
EVERY_OPTION = {"type": "Kinematics", "vehicles_count": 8, "absolute": True,
                "order": "shuffled", "see_behind": True, "clip": False,
                "features": ["presence", "x", "y", "vx", "vy", "cos_h", "sin_h", "heading"]}


def observations_of_both(name: str, config: dict | None, seeds=(0, 1, 2)):
    """(fast, highway-env's) observation pairs over episodes of random and idle actions."""
    env = make_env(name, config=config and {"observation": config}, record=False, duration=8)
    pairs = []
    for seed in seeds:
        env.reset(seed=seed)
        fast = env.unwrapped.observation_type
        assert type(fast) is FastKinematicObservation
        reference = KinematicObservation(env.unwrapped, **env.unwrapped.config["observation"])
        rng = np.random.default_rng(seed)
        done = False
        while not done:
            state = env.unwrapped.np_random.bit_generator.state  # "shuffled" draws from it
            a = fast.observe()
            env.unwrapped.np_random.bit_generator.state = state
            pairs.append((a, reference.observe()))
            action = int(rng.integers(env.action_space.n)) if rng.random() < 0.3 else 1
            _, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
    return pairs


@pytest.mark.parametrize(("name", "config"), [
    ("highway", None), ("merge", None), ("roundabout", None),
    ("intersection", None),  # its own Kinematics settings: absolute, heading features
    ("highway", EVERY_OPTION)])
def test_the_fast_observation_is_highway_envs_bit_for_bit(name, config):
    pairs = observations_of_both(name, config)
    assert len(pairs) > 10
    for fast, reference in pairs:
        assert fast.dtype == reference.dtype == np.float32
        np.testing.assert_array_equal(fast, reference)
    # the test sees traffic: rows of other vehicles, not only the ego and padding
    assert any(a[1:, 0].sum() > 0 for a, _ in pairs)


def test_the_env_returns_the_fast_observation_and_keeps_other_observation_types():
    env = make_env("highway", record=False, duration=2)
    obs, _ = env.reset(seed=3)
    assert type(env.unwrapped.observation_type) is FastKinematicObservation
    np.testing.assert_array_equal(obs, env.unwrapped.observation_type.observe())
    exit_env = make_env("exit", record=False, duration=2)  # ExitObservation adds features
    exit_env.reset(seed=0)
    assert type(exit_env.unwrapped.observation_type).__name__ == "ExitObservation"
    assert not use_fast_observation(exit_env)


def test_the_fast_variant_simulates_at_5_hz_and_checks_only_the_egos_collisions():
    exact = make_env("highway", record=False)
    fast = make_env("highway", record=False, fast=True)
    assert fast.observation_space == exact.observation_space
    assert fast.action_space == exact.action_space
    fast.reset(seed=0)
    exact.reset(seed=0)
    fast.step(1)
    exact.step(1)
    assert (fast.unwrapped.steps, exact.unwrapped.steps) == (5, 10)  # simulated steps
    inner = fast.unwrapped
    others = [v for v in inner.road.vehicles if v is not inner.vehicle]
    assert others and not any(v.check_collisions for v in others)
    assert inner.vehicle.check_collisions
    assert all(v.check_collisions for v in exact.unwrapped.road.vehicles)
    # an episode still ends at the time limit, counted in decisions
    fast.reset(seed=1)
    steps, done = 0, False
    while not done:
        _, _, terminated, truncated, _ = fast.step(1)
        steps += 1
        done = terminated or truncated
    assert terminated or steps == fast.max_steps == 30


def test_the_fast_variant_refuses_recording_and_rates_it_cannot_simulate():
    with pytest.raises(ValueError, match="cannot record"):
        make_env("highway", fast=True)
    with pytest.raises(ValueError, match="policy_frequency 2"):
        make_env("highway", config={"policy_frequency": 2}, record=False, fast=True)


def test_a_reset_observes_with_the_numpy_observation_from_its_first_observation(monkeypatch):
    """highway-env observes once inside reset: with the numpy observation, not pandas."""
    env = make_env("highway", record=False, duration=2)
    env.reset(seed=0)
    calls = []
    original = KinematicObservation.observe

    def counted(self):
        calls.append(type(self))
        return original(self)

    monkeypatch.setattr(KinematicObservation, "observe", counted)
    obs, _ = env.reset(seed=1)
    assert KinematicObservation not in calls
    np.testing.assert_array_equal(obs, original(env.unwrapped.observation_type))


# Drawn scenes: the numpy observation against highway-env's own, bit for bit, over every
# option of the Kinematics observation, vehicles of user classes, obstacles and objects on
# the perception limit; each formula's mutation is caught.

FEATURE_LISTS = [
    ["presence", "x", "y", "vx", "vy"],  # highway-env's default (highway, merge ...)
    ["presence", "x", "y", "vx", "vy", "cos_h", "sin_h"],  # intersection, exit
    ["presence", "x", "y", "vx", "vy", "cos_h", "sin_h", "heading"],
    ["x", "vy", "presence"],  # another order
    ["presence", "x", "y", "vx", "long_off", "lat_off", "ang_off", "cos_d", "sin_d"],
]


def _shifted_to_dict(self, origin_vehicle=None, observe_intentions=True):
    """A user's ``to_dict``: highway-env's, every position one metre on."""
    d = Vehicle.to_dict(self, origin_vehicle, observe_intentions)
    d["x"] += 1.0
    return d


class _OwnDict(IDMVehicle):
    """A user vehicle class with its own ``to_dict``."""

    to_dict = _shifted_to_dict


class _OwnVelocity(IDMVehicle):
    """A user vehicle class with its own ``velocity`` (a slip angle)."""

    @property
    def velocity(self):
        return self.speed * np.array([np.cos(self.heading + 0.1), np.sin(self.heading + 0.1)])


def _drawn_scene(rng: np.random.Generator, envs: dict):
    """A highway road with drawn traffic around the ego: drawn positions (some beyond the
    perception distance, some exactly on it, behind and ahead), headings of every kind,
    speeds (negative too), user classes and obstacles."""
    lanes = int(rng.integers(1, 5))
    if lanes not in envs:
        envs[lanes] = make_env("highway", config={"lanes_count": lanes}, record=False,
                               duration=2)
    env = envs[lanes]
    env.reset(seed=int(rng.integers(10_000)))
    inner = env.unwrapped
    road, ego = inner.road, inner.vehicle
    keep = [v for v in road.vehicles[1:] if rng.random() < 0.8][:int(rng.integers(0, 25))]
    limit = inner.PERCEPTION_DISTANCE
    for v in keep:
        kind = rng.random()
        if kind < 0.1:  # exactly on the perception limit, or just beyond
            sign = rng.choice([-1.0, 1.0])
            v.position = ego.position + np.array([sign * limit, 0.0])
            if rng.random() < 0.5:
                v.position[0] = np.nextafter(v.position[0], sign * np.inf)
        else:
            v.position = ego.position + rng.uniform([-260, -12], [260, 12])
        v.heading = float(rng.choice([0.0, np.pi, rng.uniform(-np.pi, np.pi)]))
        v.speed = float(rng.uniform(-5, 40))
        if rng.random() < 0.15:
            v.__class__ = _OwnDict if rng.random() < 0.5 else _OwnVelocity
        v.on_state_update()
    road.vehicles[:] = [ego, *keep]
    road.objects[:] = [Obstacle(road, ego.position + rng.uniform([-80, -8], [80, 8]))
                       for _ in range(int(rng.integers(0, 3)))]
    if rng.random() < 0.1:  # an ego of a user class
        ego.__class__ = type("UserEgo", (type(ego),), {"to_dict": _shifted_to_dict})
    return env


def _drawn_config(rng: np.random.Generator) -> dict:
    config = {"vehicles_count": int(rng.integers(1, 13)),
              "features": list(FEATURE_LISTS[int(rng.integers(len(FEATURE_LISTS)))]),
              "absolute": bool(rng.random() < 0.3),
              "order": "shuffled" if rng.random() < 0.2 else "sorted",
              "normalize": bool(rng.random() < 0.8), "clip": bool(rng.random() < 0.7),
              "see_behind": bool(rng.random() < 0.3),
              "observe_intentions": bool(rng.random() < 0.3),
              "include_obstacles": bool(rng.random() < 0.8)}
    if rng.random() < 0.3:  # ranges of the config: integers, presence included
        config["features_range"] = {"x": [-100, 100], "y": [-12, 12], "vx": [-30.0, 30.0],
                                    "presence": [0, 2]}
    return config


def _both(env, config: dict, fast_class=FastKinematicObservation):
    """(numpy, highway-env's) observation of the current scene with ``config``."""
    inner = env.unwrapped
    state = inner.np_random.bit_generator.state  # "shuffled" draws from it
    ours = fast_class(inner, **config).observe()
    inner.np_random.bit_generator.state = state
    theirs = KinematicObservation(inner, **config).observe()
    return ours, theirs


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def _drawn_cases(seed: int, n: int):
    rng = np.random.default_rng(seed)
    envs: dict = {}
    for _ in range(n):
        env = _drawn_scene(rng, envs)
        for _ in range(3):
            yield env, _drawn_config(rng)


def test_the_fast_observation_is_highway_envs_on_drawn_scenes(monkeypatch):
    from tap_bench.sim import observation

    paths = {"direct": 0, "dict": 0}
    for name, key in (("_direct_rows", "direct"), ("_dict_rows", "dict")):
        original = getattr(FastKinematicObservation, name)

        def counted(self, *args, _original=original, _key=key):
            paths[_key] += 1
            return _original(self, *args)

        monkeypatch.setattr(FastKinematicObservation, name, counted)
    seen = {"rows": set(), "limit": 0, "shuffled": 0, "beyond count": 0}
    for env, config in _drawn_cases(0, 120):
        ours, theirs = _both(env, config)
        # highway-env's, row for row; with vehicles_count 1 it returns every vehicle near
        # (outside its own space), ours the ego's row alone
        seen["beyond count"] += theirs.shape[0] > config["vehicles_count"]
        assert _same_bits(ours, theirs[:config["vehicles_count"]]), config
        seen["rows"].add(int((theirs[:, config["features"].index("presence")] != 0).sum()))
        seen["shuffled"] += config["order"] == "shuffled"
        ego = env.unwrapped.vehicle
        seen["limit"] += any(np.linalg.norm(v.position - ego.position)
                             == env.unwrapped.PERCEPTION_DISTANCE
                             for v in env.unwrapped.road.vehicles)
    # the draws reach every case: empty and full observations, both row paths, the limit
    assert {1, 2}.issubset(seen["rows"]) and max(seen["rows"]) >= 10, seen
    assert paths["direct"] >= 100 and paths["dict"] >= 50, paths
    assert seen["limit"] >= 20 and seen["shuffled"] >= 20, seen
    assert seen["beyond count"] >= 3, seen
    assert observation._highway_env_observes_as_written()


@pytest.mark.parametrize(("old", "new"), [
    ("vehicle.speed * np.cos(heading)", "abs(vehicle.speed) * np.cos(heading)"),  # vx
    ("out[feature] = np.sin(heading)", "out[feature] = np.cos(heading)"),  # sin_h
    ("row[key] -= value", "row[key] -= 0 * value"),  # not relative to the ego
    ("-2 * ego.LENGTH < lane_distance(v)", "-1 * ego.LENGTH < lane_distance(v)"),
    ("key=lambda o: abs(lane_distance(o))", "key=lambda o: lane_distance(o)"),
    ("close = close[-self.vehicles_count + 1:]", "close = close[-self.vehicles_count:]"),
    ("near[k] = bool(np.linalg.norm(objects[k].position - position) < distance)",
     "near[k] = True"),  # no re-check on the perception limit
    ("np.clip(columns[feature], -1, 1)", "np.clip(columns[feature], -1, 0.999)"),
    ("self.env.np_random.shuffle(obs[1:])", "self.env.np_random.shuffle(obs)"),
    ("if self.absolute:\n            return rows", "if False:\n            return rows"),
])
def test_a_changed_formula_of_the_observation_is_caught(old, new):
    import inspect

    from tap_bench.sim import observation

    source = inspect.getsource(observation)
    assert old in source  # the mutation applies to the code as it is
    namespace: dict = {"__name__": "mutated_observation"}
    exec(compile(source.replace(old, new, 1), observation.__file__, "exec"), namespace)
    mutated = namespace["FastKinematicObservation"]
    assert any(not _same_bits(*_both(env, config, mutated))
               for env, config in _drawn_cases(1, 60))


def test_another_highway_env_observes_with_its_own_code(monkeypatch):
    """Where highway-env's code is not the one repeated here (a digest that does not
    match), the observation is highway-env's own (kept to ``vehicles_count`` rows)."""
    from tap_bench.sim import observation

    env = make_env("highway", record=False, duration=2)
    env.reset(seed=0)
    inner = env.unwrapped
    calls = []
    original = KinematicObservation.observe
    monkeypatch.setattr(KinematicObservation, "observe",
                        lambda self: calls.append(self) or original(self))
    monkeypatch.setitem(observation._OBSERVE_CODE, "Vehicle.to_dict", "0" * 16)
    observation._highway_env_observes_as_written.cache_clear()
    try:
        fast = FastKinematicObservation(inner, **inner.config["observation"])
        np.testing.assert_array_equal(fast.observe(), original(fast))
        assert calls == [fast]
        env.reset(seed=1)
        assert type(inner.observation_type) is FastKinematicObservation
        calls.clear()
        inner.observation_type.observe()
        assert calls == [inner.observation_type]  # by highway-env's own code
    finally:
        monkeypatch.undo()
        observation._highway_env_observes_as_written.cache_clear()
    assert observation._highway_env_observes_as_written()


def test_a_feature_no_vehicle_has_fails_as_in_highway_env():
    env = make_env("highway", record=False, duration=2)
    env.reset(seed=0)
    config = {"features": ["presence", "x", "speed"]}
    with pytest.raises(KeyError):
        KinematicObservation(env.unwrapped, **config).observe()
    with pytest.raises(KeyError):
        FastKinematicObservation(env.unwrapped, **config).observe()
