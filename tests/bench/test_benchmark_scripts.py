"""Scripts of ``benchmarks/`` that choose agents or reproduce a figure of the docs: they
drive policies as a bench run does."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(PROJECT_ROOT / "benchmarks"))

import agents_validation  # noqa: E402


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
