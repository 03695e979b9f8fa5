"""Scripts of ``benchmarks/`` that choose agents or reproduce a figure of the docs: they
drive policies as a bench run does."""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd
import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(PROJECT_ROOT / "benchmarks"))

import agents_validation  # noqa: E402
import bench_lane_change_merges  # noqa: E402


@pytest.mark.parametrize("name", ["lane-keeping", "ppo-womd-seed0"])
def test_validation_configures_each_policy_as_a_bench_run_does(monkeypatch, name):
    from tap_bench.sim.policies import load_policy
    from tap_bench.sim.rollout import policy_overrides
    from tap_bench.sim.womd_scene import WomdScenes

    monkeypatch.setattr(agents_validation, "WomdEnv", lambda scenes, record: scenes)
    scenes = WomdScenes(("scenes.tfrecord",))
    policy = load_policy(name)
    driven = agents_validation.policy_env(scenes, policy)
    assert driven.config == scenes.with_overrides(policy_overrides(policy)).config


def test_every_vehicle_counts_each_vehicle_with_a_turn_once():
    # seed 0: the ego keeps its lane; vehicle 2 turns in two of its segments; seed 1: the
    # ego turns once
    labels = pd.DataFrame({
        "scenario_id": ["s0", "s0", "s0", "s0", "s1", "s1"],
        "track_id": ["1", "2", "2", "2", "1", "3"],
        "seed": [0, 0, 0, 0, 1, 1],
        "is_ego": [True, False, False, False, True, False],
        "lateral": ["Straight", "Left Turn", "Straight", "Right Turn",
                    "Straight > Left Turn", "Left Merge"]})
    figures = bench_lane_change_merges.vehicles_with_a_turn(labels)
    assert figures == {"vehicles": 4, "with_a_turn": 2, "egos": 2, "egos_with_a_turn": 1,
                       "which": ["seed 0 vehicle 2", "seed 1 vehicle 1 (ego)"]}
