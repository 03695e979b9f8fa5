"""A scene's objects are freed by reference counting when the next one replaces them, not
left in reference cycles for the garbage collector's full passes (issue 37: the collector
was 8 % of a whole file's CPU, and raising its thresholds let the cycles' memory grow)."""

from __future__ import annotations

import gc
import weakref

import pytest

from tap_bench.sim.womd_env import make_womd_env
from tap_bench.sources.scenarionet import load_scenarionet


@pytest.fixture
def no_collector():
    """The garbage collector off for the test's body (what is freed is freed by reference
    counting), on again after it."""
    gc.collect()
    gc.disable()
    try:
        yield
    finally:
        gc.enable()


def test_a_scenarionet_pickles_arrays_are_freed_with_the_scenario(womd_dir, no_collector):
    scenario = load_scenarionet(womd_dir / "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl")
    track = next(iter(scenario["tracks"].values()))
    position = weakref.ref(track["state"]["position"])
    assert not hasattr(track["state"]["position"], "unpickler")
    del scenario, track
    assert position() is None  # the unpickler's memo no longer holds it


def test_a_reset_frees_the_last_episodes_road_and_vehicles(womd_dir, no_collector):
    env = make_womd_env(womd_dir / "motion_data_one_scenario.tfrecord")
    env.reset(seed=0)
    road = env.unwrapped.road
    old_road = weakref.ref(road)
    old_vehicles = [weakref.ref(v) for v in road.vehicles]
    for _ in range(3):
        env.step(env.action_space.sample())
    assert len(road.vehicles) > 1
    del road
    env.reset(seed=0)
    assert old_road() is None
    assert all(v() is None for v in old_vehicles)
    assert len(env.unwrapped.road.vehicles) == len(old_vehicles)
    env.close()


def test_a_closed_env_lets_go_of_its_scenes_road_and_vehicles(womd_dir, no_collector):
    env = make_womd_env(womd_dir / "motion_data_one_scenario.tfrecord")
    env.reset(seed=0)
    env.step(env.action_space.sample())
    inner = env.unwrapped
    held = [weakref.ref(o) for o in (inner.road, inner.scene, inner.road.network,
                                     *inner.road.vehicles)]
    env.close()  # the env itself is still referenced here (and points at itself)
    assert all(o() is None for o in held)
    assert inner.road is None and inner.render() is None
    env.reset(seed=0)  # a closed env starts again from its files
    assert len(inner.road.vehicles) == len(held) - 3
