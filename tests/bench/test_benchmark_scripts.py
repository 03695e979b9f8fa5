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


def _validation_episodes(fault_b: dict[int, list[int]]) -> pd.DataFrame:
    """Two drivers in each of 4 scenes: agent ``a`` (two seeds) never at fault, progress 0.8;
    ``b`` (one run) at fault on the drivers ``fault_b`` names per scene, progress 0.4."""
    rows = []
    for scene in range(4):
        for track in ("1", "2"):
            for policy, progress in (("a0", 0.8), ("a1", 0.8), ("b", 0.4)):
                fault = policy == "b" and int(track) in fault_b.get(scene, [])
                rows.append({"policy": policy, "scene": scene, "track": track,
                             "status": "ok", "route_progress": progress,
                             "crash_at_fault": fault, "off_road": False})
    return pd.DataFrame(rows)


def test_scene_intervals_separate_only_what_more_than_one_scene_shows():
    groups = {"a": ["a0", "a1"], "b": ["b"]}
    everywhere = agents_validation.scene_intervals(
        _validation_episodes({s: [1, 2] for s in range(4)}), groups, "a", n_resamples=200)
    b = everywhere.set_index("policy").loc["b"]
    assert b["d_at_fault"] == -1.0 and b["d_at_fault_high"] == -1.0
    assert b["d_iqm"] == pytest.approx(0.4) and b["d_iqm_low"] == pytest.approx(0.4)
    # b at fault in one scene only: a draw without that scene ties, so 0 stays inside
    one_scene = agents_validation.scene_intervals(
        _validation_episodes({0: [1, 2]}), groups, "a", n_resamples=200)
    b = one_scene.set_index("policy").loc["b"]
    assert b["d_at_fault"] == pytest.approx(-0.25)
    assert b["d_at_fault_low"] < -0.25 and b["d_at_fault_high"] == pytest.approx(0.0, abs=0.1)
    assert b["at_fault_low"] <= 0.0 + 0.1 and b["at_fault_high"] > 0.25


def test_seed_intervals_pool_the_seeds_over_the_drivers_each_seed_drove():
    eps = _validation_episodes({})
    eps.loc[eps["policy"] == "a1", "route_progress"] = 0.6
    out = agents_validation.seed_intervals(eps, ["a0", "a1"], n_resamples=200)
    assert out["iqm"] == pytest.approx(0.7) and out["at_fault"] == 0.0
    assert out["iqm_low_run"] < 0.7 < out["iqm_high_run"]
    assert out["iqm_low_task"] < 0.7 < out["iqm_high_task"]


def test_scene_intervals_of_an_at_fault_rate_stay_within_0_and_1():
    """The draws widened by sqrt(G / (G - 1)) about a small rate go below 0 (one scene of 4
    at fault: -0.019 before); a rate's interval is cut at 0 and 1, a difference's is not."""
    groups = {"a": ["a0", "a1"], "b": ["b"]}
    table = agents_validation.scene_intervals(
        _validation_episodes({0: [1]}), groups, "a", n_resamples=200).set_index("policy")
    assert (table["at_fault_low"] >= 0.0).all() and (table["at_fault_high"] <= 1.0).all()
    assert table.loc["b", "at_fault_high"] > 0.125 > table.loc["b", "at_fault_low"]
    assert table.loc["b", "d_at_fault_low"] < -0.125 < table.loc["b", "d_at_fault_high"]
