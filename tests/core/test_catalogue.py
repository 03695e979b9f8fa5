"""The catalogue: built-in scenarios and policies found, user folders added through
$TAP_BENCH_PATH, and a loud error when the built-in data is missing."""

from __future__ import annotations

import json
import shutil

import pytest

from tap_bench import catalogue
from tap_bench.errors import CatalogueError
from tap_bench.sim.policies import available_policies
from tap_bench.sim.scenario_format import scenario_names


def test_the_built_in_catalogue_lists_scenarios_policies_and_suites():
    assert {"highway", "merge", "roundabout"} <= set(catalogue.files("envs"))
    assert {"idm", "random"} <= set(catalogue.files("policies"))
    assert "default" in catalogue.files("suites")


def test_a_user_folder_adds_and_overrides(tmp_path, monkeypatch):
    mine = tmp_path / "mine"
    (mine / "policies").mkdir(parents=True)
    (mine / "envs" / "suites").mkdir(parents=True)
    idm = json.loads(catalogue.find("policies", "idm").read_text())
    (mine / "policies" / "my-idm.json").write_text(json.dumps({**idm, "name": "my-idm"}))
    shutil.copy(catalogue.find("envs", "merge"), mine / "envs" / "merge.json")
    (mine / "envs" / "suites" / "mine.json").write_text(json.dumps(
        {"name": "mine", "envs": ["merge"], "policies": ["idm", "my-idm"], "seeds": "0-1"}))
    monkeypatch.setenv(catalogue.PATH_VARIABLE, str(mine))
    assert "my-idm" in available_policies() and "idm" in available_policies()
    assert catalogue.find("envs", "merge") == mine / "envs" / "merge.json"
    assert "highway" in scenario_names()  # the built-in ones stay
    from tap_bench.bench.suite import load_suite

    assert load_suite("mine").policies == ("idm", "my-idm")


def test_missing_built_in_data_is_an_error_not_an_empty_list(tmp_path, monkeypatch):
    monkeypatch.setattr(catalogue, "_PACKAGE", tmp_path / "site-packages" / "tap_bench")
    with pytest.raises(CatalogueError, match="built-in scenarios and policies are missing"):
        catalogue.files("envs")
