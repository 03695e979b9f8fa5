"""Scenario files: the suite's files load, and bad files fail with the fix."""

from __future__ import annotations

import json

import pytest

from tap_bench.errors import FileFormatError, UnknownNameError
from tap_bench.sim.scenario_env import get_scenario
from tap_bench.sim.scenario_format import load_scenario, parse_seeds, scenario_names, suite_dir


def test_the_suite_has_the_five_scenarios_simulated_at_10_hz():
    assert set(scenario_names()) >= {"highway", "merge", "roundabout", "intersection", "exit"}
    for name in scenario_names():
        scenario = load_scenario(suite_dir("envs") / f"{name}.json")
        assert scenario.env_id == f"tap_bench/{name}-v{scenario.version}"
        assert scenario.config["simulation_frequency"] == 10
        assert 10 % scenario.policy_frequency == 0
        assert scenario.max_steps == round(scenario.duration * scenario.policy_frequency)


def test_a_scenarios_env_config_is_highway_envs_defaults_with_its_overrides():
    """env_config: the whole config the env runs with (the cache's key and ``tap-bench envs
    NAME`` read it): every default key of its highway-env id, the scenario's own values
    over them."""
    from tap_bench.sim.schema import default_config

    scenario = load_scenario(suite_dir("envs") / "merge.json")
    full = scenario.env_config
    assert set(full) >= set(default_config(scenario.highway_env_id))
    assert {k: full[k] for k in scenario.config} == scenario.config
    assert full["simulation_frequency"] == 10 and full["duration"] == scenario.duration
    full["duration"] = -1.0  # a fresh dict each time
    assert scenario.env_config["duration"] == scenario.duration


def test_a_misspelled_config_key_names_the_file_and_the_right_key(write_scenario):
    path = write_scenario(config={"vehicle_count": 3})
    with pytest.raises(FileFormatError) as err:
        load_scenario(path)
    message = str(err.value)
    assert str(path) in message and "'vehicle_count'" in message
    assert "Did you mean 'vehicles_count'" in message


def test_a_misspelled_observation_parameter_is_caught_despite_kwargs(write_scenario):
    path = write_scenario(config={"observation": {"type": "Kinematics", "vehicle_count": 5}})
    with pytest.raises(FileFormatError, match="Did you mean 'vehicles_count'"):
        load_scenario(path)


@pytest.mark.parametrize("highway_env_id", ["highway-v0", "intersection-v0", "merge-v0",
                                            "roundabout-v0", "exit-v0", "racetrack-v0"])
def test_an_envs_own_default_observation_and_action_are_accepted(highway_env_id):
    """Each environment's own default observation and action pass the check, keys its class
    takes through **kwargs included (intersection-v0's Kinematics has "flatten": a trained
    model's observation config repeats it, and the learning curve applies it); a misspelled
    key beside them is still caught."""
    from tap_bench.sim.scenario_format import check_config
    from tap_bench.sim.schema import default_config

    defaults = default_config(highway_env_id)
    own = {key: defaults[key] for key in ("observation", "action")}
    check_config(highway_env_id, own)
    with pytest.raises(FileFormatError, match="parameter 'vehicle_count'"):
        check_config(highway_env_id, {"observation": {**defaults["observation"],
                                                      "vehicle_count": 5}})


def test_an_unknown_observation_type_lists_the_known_ones(write_scenario):
    path = write_scenario(config={"observation": {"type": "Kinematic"}})
    with pytest.raises(FileFormatError, match="Did you mean 'Kinematics'"):
        load_scenario(path)


@pytest.mark.parametrize(("fields", "match"), [
    ({"config": {"lanes_count": "3"}}, "expects a number"),
    ({"config": {"simulation_frequency": 15}}, "always 10 Hz"),
    ({"config": {"duration": 5}}, "top-level field"),
    ({"config": {"policy_frequency": 3}}, "whole divisor"),
    ({"duration": -1}, "positive number of seconds"),
    ({"duration": 2.5}, "whole number of decisions"),
    ({"lane_change": "realistc"}, "Did you mean 'realistic'"),
    ({"default_seeds": "5-1"}, "runs backwards"),
    ({"highway_env_id": "highway-v9"}, "Did you mean"),
    ({"durration": 3}, "Did you mean 'duration'"),
    ({"config": {"action": {"type": "MultiAgentAction"}}}, "one ego"),
])
def test_bad_fields_are_refused_with_the_reason(write_scenario, fields, match):
    with pytest.raises((FileFormatError, UnknownNameError), match=match):
        load_scenario(write_scenario(**fields))


def test_the_name_must_match_the_file(write_scenario, tmp_path):
    path = write_scenario(name="tiny")
    doc = json.loads(path.read_text())
    doc["name"] = "other"
    path.write_text(json.dumps(doc))
    with pytest.raises(FileFormatError, match="rename the file"):
        load_scenario(path)


def test_scenarios_are_found_by_name_id_or_path(write_scenario):
    assert get_scenario("highway") == get_scenario("tap_bench/highway-v0")
    path = write_scenario()
    assert get_scenario(path).name == "tiny"
    with pytest.raises(UnknownNameError, match="Did you mean 'highway'"):
        get_scenario("higway")


def test_overrides_are_validated_like_the_file():
    scenario = get_scenario("highway")
    assert scenario.with_overrides({"vehicles_count": 5}).config["vehicles_count"] == 5
    with pytest.raises(FileFormatError, match="Did you mean 'vehicles_count'"):
        scenario.with_overrides({"vehicles_cont": 5})
    partial = scenario.with_overrides({"observation": {"vehicles_count": 7}})
    assert partial.config["observation"] == {"type": "Kinematics", "vehicles_count": 7}


@pytest.mark.parametrize(("spec", "seeds"), [
    ("0-3", [0, 1, 2, 3]), ("5", [5]), ("1,4,7-8", [1, 4, 7, 8]), (3, [3]),
    ([2, 0], [2, 0]), (range(2), [0, 1]),
])
def test_seed_lists(spec, seeds):
    assert parse_seeds(spec) == seeds


@pytest.mark.parametrize("spec", ["a", "1,1", "-1", "", [-2], True])
def test_bad_seed_lists_are_refused(spec):
    with pytest.raises(ValueError):
        parse_seeds(spec)


def test_the_old_module_name_still_gives_the_scenario_format():
    from tap_bench.sim import scenario_format, suite

    assert suite.__all__ == scenario_format.__all__
    assert all(getattr(suite, n) is getattr(scenario_format, n) for n in suite.__all__)
