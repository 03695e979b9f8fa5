"""Suite files: the committed suites load; bad fields are refused with the fix."""

from __future__ import annotations

import json

import pytest

from tap_bench.bench.suite import available_suites, load_suite, suite_from_dict
from tap_bench.errors import FileFormatError, UnknownNameError

GOOD = {"name": "t", "envs": ["highway"], "policies": ["idm", "random"], "seeds": "0-4"}


@pytest.mark.parametrize("name", ["default", "demo", "rl-highway"])
def test_committed_suites_load(name):
    suite = load_suite(name)
    assert suite.name == name and suite.envs and suite.policies and suite.seeds
    assert suite.reference in suite.policies
    for env in suite.envs:
        assert suite.scenario(env).name == env


def test_available_suites():
    assert {"default", "demo"} <= set(available_suites())


def test_defaults():
    suite = suite_from_dict(GOOD)
    assert suite.level == "maneuver" and suite.thresholds == "paper"
    assert suite.reference == "idm" and suite.seeds == (0, 1, 2, 3, 4)
    assert suite.gate.margins["mean_speed"] == 1.0


def test_env_override_applies():
    suite = suite_from_dict({**GOOD, "env_overrides": {"highway": {"duration": 5}}})
    assert suite.scenario("highway").duration == 5


@pytest.mark.parametrize("doc, message", [
    ({**GOOD, "polices": ["idm"]}, "(?i)did you mean 'policies'"),
    ({**GOOD, "envs": ["higway"]}, "(?i)did you mean 'highway'"),
    ({**GOOD, "policies": ["idn"]}, "(?i)did you mean 'idm'"),
    ({**GOOD, "seeds": "4-1"}, "runs backwards"),
    ({**GOOD, "level": "manoeuvre"}, "(?i)did you mean 'maneuver'"),
    ({**GOOD, "reference_policy": "ppo"}, "not one of the suite's policies"),
    ({**GOOD, "env_overrides": {"merge": {"duration": 5}}}, "not in envs"),
    ({**GOOD, "env_overrides": {"highway": {"durations": 5}}}, "(?i)did you mean 'duration'"),
    ({**GOOD, "gate": {"margins": {"speed": 1}}}, "(?i)did you mean"),
    ({**GOOD, "bootstrap": {"level": 95}}, "level must be"),
    ({k: v for k, v in GOOD.items() if k != "seeds"}, "missing field"),
])
def test_bad_suites_are_refused_with_the_fix(doc, message):
    with pytest.raises(FileFormatError, match=message):
        suite_from_dict(doc)


def test_unknown_suite_name_and_bad_json(tmp_path):
    with pytest.raises(UnknownNameError, match=r"(?i)did you mean 'default'"):
        load_suite("defualt")
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    with pytest.raises(FileFormatError, match="not valid JSON"):
        load_suite(bad)
    ok = tmp_path / "ok.json"
    ok.write_text(json.dumps(GOOD))
    assert load_suite(ok).name == "t"
