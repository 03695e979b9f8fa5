"""Policies: the registry, the built-ins, and every env with every built-in policy."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

import tap_bench
from tap_bench.errors import FileFormatError, UnknownNameError
from tap_bench.sim import available_policies, load_policy, register_policy, registered_ids
from tap_bench.sim.idm import IDMPolicy
from tap_bench.sim.policies import Policy, RandomPolicy, get_definition
from tap_bench.sim.rollout import rollout
from tap_bench.sim.scenario_format import suite_dir

BUILT_INS = ["idm", "idm-aggressive", "idm-defensive", "random", "lane-keeping"]
SCENARIOS = [i.removeprefix("tap_bench/").rsplit("-v", 1)[0] for i in registered_ids()]


def test_the_built_ins_are_defined_as_data():
    defs = available_policies()
    assert set(BUILT_INS) <= set(defs)
    assert {defs[n].kind for n in BUILT_INS} == {"idm", "random", "lane_keeping"}
    for name in BUILT_INS:
        assert isinstance(load_policy(name), Policy)


def test_an_unknown_policy_suggests_the_closest():
    with pytest.raises(UnknownNameError, match="Did you mean 'idm'"):
        load_policy("imd")


def test_registering_a_taken_name_is_refused():
    with pytest.raises(ValueError, match="already registered"):
        register_policy("idm", lambda: RandomPolicy("idm"))


def test_a_python_policy_is_available_by_name():
    register_policy("test-python-random", lambda: RandomPolicy("test-python-random"),
                    "random, registered in a test")
    assert "test-python-random" in available_policies()
    assert load_policy("test-python-random").name == "test-python-random"


def test_a_bad_idm_parameter_names_the_file(tmp_path):
    path = tmp_path / "idm-bad.json"
    path.write_text(json.dumps({"name": "idm-bad", "kind": "idm",
                                "params": {"time_wantd": 1.0}}))
    with pytest.raises(FileFormatError, match=r"idm-bad\.json.*Did you mean 'time_wanted'"):
        load_policy(path)
    path.write_text(json.dumps({"name": "idm-bad", "kind": "idm",
                                "params": {"comfort_acc_min": 2.0}}))
    with pytest.raises(FileFormatError, match="must be negative"):
        load_policy(path)


def test_a_bad_kind_names_the_file(tmp_path):
    path = tmp_path / "x.json"
    path.write_text(json.dumps({"name": "x", "kind": "idn"}))
    with pytest.raises(FileFormatError, match="Did you mean 'idm'"):
        get_definition(path)


def test_the_parameter_sets_differ_as_documented():
    params = {n: load_policy(n).params for n in ("idm-defensive", "idm", "idm-aggressive")}
    gaps = [p.time_wanted for p in params.values()]
    speeds = [p.target_speed_factor for p in params.values()]
    assert gaps == sorted(gaps, reverse=True) and speeds == sorted(speeds)


def test_idm_takes_over_the_ego_in_the_same_state():
    env = gym.make("tap_bench/highway-v0", duration=2)
    env.reset(seed=2)
    old = env.unwrapped.vehicle
    state = (old.position.copy(), old.heading, old.speed)
    policy = load_policy("idm-aggressive")
    policy.reset(env, seed=2)
    new = env.unwrapped.vehicle
    assert new is not old and new in env.unwrapped.road.vehicles
    assert old not in env.unwrapped.road.vehicles
    np.testing.assert_array_equal(new.position, state[0])
    assert (new.heading, new.speed) == state[1:]
    assert new.TIME_WANTED == 0.8
    assert type(new).TIME_WANTED == 1.5  # the class is untouched
    # the realistic lane-change gains of the scenario carried over
    assert new.KP_HEADING == old.KP_HEADING == 1.0


def test_random_policy_repeats_itself_per_seed():
    env = gym.make("tap_bench/highway-v0", duration=2)
    policy = RandomPolicy()
    draws = []
    for _ in range(2):
        policy.reset(env, seed=11)
        draws.append([policy.act(None) for _ in range(20)])
    policy.reset(env, seed=12)
    assert draws[0] == draws[1] != [policy.act(None) for _ in range(20)]


@pytest.mark.parametrize("scenario", SCENARIOS)
@pytest.mark.parametrize("policy", BUILT_INS)
def test_every_env_with_every_built_in_policy(scenario, policy):
    trajectories, episodes = rollout(scenario, policy, [0, 1], duration=2, progress=False)
    assert episodes["status"].tolist() == ["ok", "ok"], episodes["error"].tolist()
    assert (episodes["length"] >= 1).all()
    clean = tap_bench.validate_trajectories(trajectories)
    assert set(clean["policy"]) == {policy} and set(clean["seed"]) == {0, 1}
    assert clean.groupby("scenario_id")["is_ego"].sum().gt(0).all()


def _sb3_models() -> list[str]:
    return sorted(p.stem for p in suite_dir("policies").glob("*.zip")
                  if (p.with_suffix(".json")).is_file())


@pytest.mark.parametrize("model", _sb3_models())
def test_shipped_sb3_models_drive_their_scenario_without_a_trust_warning(model, request):
    """The shipped models' digests are known (sim/sb3.SHIPPED_MODELS): loading them does
    not warn that their pickles can run code; any other model file does
    (tests/faults/test_definitions_are_code.py). A model trained on real scenes drives
    the first sample scene (skipped where the samples are absent)."""
    import warnings

    from tap_bench.errors import UntrustedModelWarning
    from tap_bench.sim.womd_scene import WomdScenes

    pytest.importorskip("stable_baselines3")
    definition = get_definition(model)
    scenario = definition.params["env"]
    if "womd" in scenario:
        womd_dir = request.getfixturevalue("womd_dir")
        scenario = WomdScenes((str(womd_dir / "motion_data_one_scenario.tfrecord"),),
                              traffic=definition.params.get("traffic", "log"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        trajectories, episodes = rollout(scenario, model, [0], duration=3, progress=False)
    assert not [w for w in caught if issubclass(w.category, UntrustedModelWarning)]
    assert episodes["status"].tolist() == ["ok"], episodes["error"].tolist()
    assert len(trajectories) > 0


def test_an_idm_policy_object_is_accepted_by_rollout():
    policy = IDMPolicy("my-idm", time_wanted=2.0)
    _, episodes = rollout("merge", policy, [3], duration=2, record=False, progress=False)
    assert episodes["policy"].tolist() == ["my-idm"]


def test_policies_lists_held_out_figures_only(capsys):
    """Issue 25: the shipped agents' figures come from held-out seeds, said which; the
    figures of the seeds their weights were selected on are not shown."""
    from tap_bench.cli import main

    assert main(["policies"]) == 0
    out = capsys.readouterr().out
    assert "kept_eval_crash_rate" not in out and "kept_eval_return" not in out
    dqn = out[out.index("dqn-highway"):].split("\n")[:4]
    assert any("held-out seeds 1000-1099 (100 episodes): crash rate 0.16" in line
               for line in dqn)
