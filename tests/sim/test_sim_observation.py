"""The numpy Kinematics observation equals highway-env's own within 1e-9; the fast
training variant of a scenario simulates at 5 Hz and checks only the ego's collisions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from gymnasium import spaces
from highway_env.envs.common.observation import KinematicObservation
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.kinematics import Vehicle
from highway_env.vehicle.objects import Obstacle

from tap_bench.sim import make_env
from tap_bench.sim.observation import FastKinematicObservation, use_fast_observation


class _Wide(KinematicObservation):
    """highway-env's observation returned in float64 (no float32 rounding to compare)."""

    def space(self):
        return spaces.Box(-np.inf, np.inf, (self.vehicles_count, len(self.features)),
                          np.float64)


class _WideFast(FastKinematicObservation):
    """Ours returned in float64."""

    space = _Wide.space


def _both(env, config: dict, fast_class=_WideFast):
    """(ours, highway-env's) float64 observation of the current scene with ``config``;
    highway-env's cut to ``vehicles_count`` rows (with 1 it returns every vehicle near)."""
    inner = env.unwrapped
    state = inner.np_random.bit_generator.state  # "shuffled" draws from it
    ours = fast_class(inner, **config).observe()
    inner.np_random.bit_generator.state = state
    theirs = _Wide(inner, **config).observe()
    return ours, theirs[:config.get("vehicles_count", 5)]


def _close(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and np.allclose(a, b, rtol=0, atol=ATOL, equal_nan=True)


ATOL = 1e-9
SCENARIOS = sorted(p.stem for p in (Path(__file__).parents[2] / "envs").glob("*.json"))
VARIANTS = [{"vehicles_count": n, "absolute": absolute, "normalize": normalize}
            for n in (0, 1, 5, 15) for absolute in (False, True) for normalize in (True, False)]


@pytest.mark.parametrize("name", SCENARIOS)
def test_the_observation_is_highway_envs_on_every_scenario(name):
    """Every shipped scenario, its own observation settings and 16 variants (vehicles_count
    0/1/5/15, absolute or relative, normalised or not), over short episodes."""
    env = make_env(name, record=False, duration=4)
    own = dict(env.unwrapped.config["observation"])
    own.pop("type", None)
    compared, traffic = 0, 0
    for seed in (0, 1):
        env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        done, step = False, 0
        while not done:
            for extra in [{}, *VARIANTS[step % 4::4]]:
                config = {**own, **extra}
                ours, theirs = _both(env, config)
                assert _close(ours, theirs), (name, config, ours, theirs)
                compared += 1
                traffic += config.get("vehicles_count", 5) > 1 and ours[1:, 0].any()
            action = int(rng.integers(env.action_space.n)) if rng.random() < 0.3 else 1
            _, _, terminated, truncated, _ = env.step(action)
            done, step = terminated or truncated, step + 1
    assert compared > 10 and traffic > 0  # rows of other vehicles, not only the ego


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
    np.testing.assert_allclose(obs, original(env.unwrapped.observation_type), rtol=0, atol=1e-6)


# Drawn scenes: the numpy observation against highway-env's own, within 1e-9, over every
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
    config = {"vehicles_count": int(rng.choice([0, 1, 2, 5, 8, 15])),
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


def _drawn_cases(seed: int, n: int):
    rng = np.random.default_rng(seed)
    envs: dict = {}
    for _ in range(n):
        env = _drawn_scene(rng, envs)
        for _ in range(3):
            yield env, _drawn_config(rng)


def test_the_observation_is_highway_envs_on_drawn_scenes():
    seen = {"rows": set(), "limit": 0, "shuffled": 0, "counts": set(), "own": 0}
    for env, config in _drawn_cases(0, 120):
        ours, theirs = _both(env, config)
        assert _close(ours, theirs), config
        if config["vehicles_count"]:
            seen["rows"].add(int((ours[:, config["features"].index("presence")] != 0).sum()))
        seen["counts"].add(config["vehicles_count"])
        seen["shuffled"] += config["order"] == "shuffled"
        road = env.unwrapped.road
        seen["own"] += any(type(v) in (_OwnDict, _OwnVelocity) for v in road.vehicles)
        ego = env.unwrapped.vehicle
        seen["limit"] += any(np.linalg.norm(v.position - ego.position)
                             == env.unwrapped.PERCEPTION_DISTANCE for v in road.vehicles)
    # the draws reach every case: empty and full observations, every count, the limit
    assert {1, 2}.issubset(seen["rows"]) and max(seen["rows"]) >= 10, seen
    assert seen["counts"] >= {0, 1, 5, 15}, seen
    assert seen["limit"] >= 20 and seen["shuffled"] >= 20 and seen["own"] >= 20, seen


def test_the_env_observation_is_float32_in_its_space():
    env = make_env("highway", record=False, duration=2)
    obs, _ = env.reset(seed=0)
    assert obs.dtype == np.float32 and env.observation_space.contains(obs)
    inner = env.unwrapped
    theirs = KinematicObservation(inner, **inner.config["observation"]).observe()
    np.testing.assert_allclose(obs, theirs, rtol=0, atol=1e-6)


@pytest.mark.parametrize(("old", "new"), [
    ('"vx": velocity[:, 0]', '"vx": np.abs(velocity[:, 0])'),
    ('"sin_h": np.sin(heading)', '"sin_h": np.cos(heading)'),
    ("-= table[0, offset]", "-= 0 * table[0, offset]"),  # not relative to the ego
    ("behind = -2 * ego.LENGTH", "behind = -1 * ego.LENGTH"),
    ("along.append(abs(d))", "along.append(d)"),
    ("return kept[:wanted]", "return kept[1:wanted + 1]"),  # the nearest left out
    ("np.clip(table[:, j], -1.0, 1.0,", "np.clip(table[:, j], -1.0, 0.999,"),
    ("self.env.np_random.shuffle(out[1:])", "self.env.np_random.shuffle(out)"),
    ("record = ego.to_dict()", "record = Vehicle.to_dict(ego)"),
    ("< self.env.PERCEPTION_DISTANCE", "<= self.env.PERCEPTION_DISTANCE"),
])
def test_a_changed_formula_of_the_observation_is_caught(old, new):
    import inspect

    from tap_bench.sim import observation

    source = inspect.getsource(observation)
    assert old in source  # the mutation applies to the code as it is
    namespace: dict = {"__name__": "mutated_observation"}
    exec(compile(source.replace(old, new, 1), observation.__file__, "exec"), namespace)

    class Mutated(namespace["FastKinematicObservation"]):
        space = _Wide.space

    assert any(not _close(*_both(env, config, Mutated)) for env, config in _drawn_cases(1, 60))


def test_a_feature_no_vehicle_has_fails_as_in_highway_env():
    env = make_env("highway", record=False, duration=2)
    env.reset(seed=0)
    config = {"features": ["presence", "x", "speed"]}
    with pytest.raises(KeyError):
        KinematicObservation(env.unwrapped, **config).observe()
    with pytest.raises(KeyError):
        FastKinematicObservation(env.unwrapped, **config).observe()
