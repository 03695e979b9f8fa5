"""The simulation sub-commands: envs, policies (rollout and train have their own tests)."""

from __future__ import annotations

import json

from tap_bench.cli import main


def test_envs_lists_every_scenario_with_its_settings(capsys):
    assert main(["envs"]) == 0
    out = capsys.readouterr().out
    for name in ("highway", "merge", "roundabout", "intersection"):
        assert f"tap_bench/{name}-v0" in out
    assert "tap_bench/exit-v1" in out and "exit-seeded-v0" in out
    assert "realistic" in out and "10 Hz" in out


def test_envs_shows_one_scenarios_full_config(capsys):
    assert main(["envs", "intersection"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["config"]["simulation_frequency"] == 10
    assert doc["config"]["other_vehicles_type"].endswith("IntersectionIDMVehicle")
    assert doc["config"]["spawn_probability"] == 0.6  # highway-env's default, filled in


def test_envs_lists_the_recorded_scene_env(capsys):
    assert main(["envs"]) == 0
    out = capsys.readouterr().out
    assert "tap_bench/womd-v0" in out and "seed % N" in out and "--womd" in out
    assert main(["envs", "--json"]) == 0
    rows = {row["id"]: row for row in json.loads(capsys.readouterr().out)}
    assert "files=[...]" in rows["tap_bench/womd-v0"]["make"]
    assert main(["envs", "womd-v0"]) == 0
    assert json.loads(capsys.readouterr().out)["id"] == "tap_bench/womd-v0"


def test_an_unknown_env_is_an_error_with_a_suggestion(capsys):
    assert main(["envs", "roundabot"]) == 2
    assert "Did you mean 'roundabout'" in capsys.readouterr().err


def test_policies_lists_the_built_ins(capsys):
    assert main(["policies", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert {"idm", "idm-aggressive", "idm-defensive", "random", "lane-keeping"} <= set(doc)
    assert doc["idm-defensive"]["params"]["time_wanted"] == 2.5
