"""The numpy Kinematics observation returns highway-env's arrays bit for bit; the fast
training variant of a scenario simulates at 5 Hz and checks only the ego's collisions."""

from __future__ import annotations

import numpy as np
import pytest
from highway_env.envs.common.observation import KinematicObservation

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
