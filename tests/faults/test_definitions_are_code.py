"""Definitions are code: a policy factory or a vehicle type from a suite, scenario or policy
file must name a class of the right kind, checked before anything of it is called (a
module that defines no such class is not even imported); an SB3 model warns in the parent,
once per model, before a ``bench run``."""

from __future__ import annotations

import json
import sys
import uuid
import warnings
from pathlib import Path

import pytest
from fault_helpers import PROJECT_ROOT, RUN_TAG

from tap_bench.bench.run.plan import _tasks, plan_suite
from tap_bench.bench.suite import suite_from_dict
from tap_bench.errors import UntrustedModelWarning
from tap_bench.sim.scenario_env import get_scenario, make_env

MODULE = f"userdefs_{RUN_TAG}"
SOURCE = '''
import pathlib, os
pathlib.Path(os.environ["TAP_TEST_MARKER"] + ".imported").touch()


def make_policy(name, **params):
    pathlib.Path(os.environ["TAP_TEST_MARKER"] + ".called").touch()


class NoAct:
    observation = None

    def __init__(self, name):
        pathlib.Path(os.environ["TAP_TEST_MARKER"] + ".called").touch()

    def reset(self, env, *, seed):
        pass


class NotAVehicle:
    def __init__(self, *args, **kwargs):
        pathlib.Path(os.environ["TAP_TEST_MARKER"] + ".called").touch()
'''


@pytest.fixture
def marker(tmp_path, monkeypatch):
    (tmp_path / f"{MODULE}.py").write_text(SOURCE)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("TAP_TEST_MARKER", str(tmp_path / "marker"))
    sys.modules.pop(MODULE, None)
    return tmp_path / "marker"


def _suite_with_policy(tmp_path, factory: str, name: str) -> str:
    policy = tmp_path / f"{name}.json"
    policy.write_text(json.dumps({"name": name, "kind": "import",
                                  "params": {"factory": factory}}))
    suite = tmp_path / "suite.json"
    suite.write_text(json.dumps({"name": "evil", "envs": ["merge"],
                                 "policies": [str(policy), "idm"], "seeds": "0-1",
                                 "reference_policy": "idm",
                                 "env_overrides": {"merge": {"duration": 2}}}))
    return str(suite)


FACTORIES = {
    "os:system": "defines no class 'system'",
    "subprocess:Popen": "no method reset, act",
    "builtins:eval": "defines no class 'eval'",
    "antigravity:Fly": "defines no class 'Fly'",
    f"{MODULE}:make_policy": "defines no class 'make_policy'",
    f"{MODULE}:NoAct": "no method act",
    f"{MODULE}:Missing": "defines no class 'Missing'",
    "no_such_module_xyz:Policy": "no module 'no_such_module_xyz'",
    "os.system": "'module:Class'",
}


@pytest.mark.parametrize("factory", sorted(FACTORIES))
def test_a_factory_that_is_not_a_policy_class_is_refused_before_any_call(
        tmp_path, cli, marker, monkeypatch, factory):
    monkeypatch.chdir(tmp_path)  # os.system(name) would make the file here
    suite = _suite_with_policy(tmp_path, factory, "touch ran-the-shell")
    code, out, err = cli("bench", "run", "--suite", suite, "-o", tmp_path / "run",
                         "--no-cache", "--workers", "1", "--no-progress")
    assert code == 2, (out, err)
    assert FACTORIES[factory] in err and "Traceback" not in err
    assert not (tmp_path / "ran-the-shell").exists() and not (tmp_path / "run").exists()
    assert not marker.with_suffix(".called").exists()  # nothing of it was called
    if factory == "antigravity:Fly":  # (importing it would open a web browser)
        assert "antigravity" not in sys.modules


def test_a_module_without_the_class_is_never_imported(tmp_path, marker):
    from tap_bench.errors import ParameterError
    from tap_bench.sim.policies import import_policy

    with pytest.raises(ParameterError, match="defines no class 'Missing'"):
        import_policy("x", f"{MODULE}:Missing")
    assert not marker.with_suffix(".imported").exists()
    assert MODULE not in sys.modules


VEHICLE_TYPES = {
    "os.system": "defines no class 'system'",
    "antigravity.Fly": "defines no class 'Fly'",
    f"{MODULE}.NotAVehicle": "not a subclass of highway_env.vehicle.kinematics.Vehicle",
    "json.JSONDecoder": "not a subclass",
}


@pytest.mark.parametrize("vehicle_type", sorted(VEHICLE_TYPES))
def test_a_vehicle_type_must_be_a_highway_env_vehicle_class(tmp_path, marker, vehicle_type):
    from tap_bench.errors import ParameterError

    with pytest.raises(ParameterError, match=VEHICLE_TYPES[vehicle_type]):
        scenario = get_scenario("merge").with_overrides(
            {"other_vehicles_type": vehicle_type})
        make_env(scenario)
    assert not marker.with_suffix(".called").exists()
    if vehicle_type.startswith("antigravity"):
        assert "antigravity" not in sys.modules


def test_a_user_vehicle_class_works(tmp_path, monkeypatch):
    package = f"cars_{uuid.uuid4().hex[:8]}"
    (tmp_path / f"{package}.py").write_text(
        "from highway_env.vehicle.behavior import IDMVehicle\n\n\n"
        "class Calm(IDMVehicle):\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    env = make_env(get_scenario("merge").with_overrides(
        {"other_vehicles_type": f"{package}.Calm"}, duration=2))
    env.reset(seed=0)
    others = env.unwrapped.road.vehicles[1:]
    assert others and all(type(v).__name__ == "Calm" for v in others)
    env.close()


def _model_definitions(tmp_path: Path, edit: bool) -> list[str]:
    """dqn-highway and ppo-highway's definitions and models copied to ``tmp_path``, each
    model's zip comment changed (``edit``: other bytes, the same model) or not."""
    import shutil
    import zipfile

    paths = []
    for name in ("dqn-highway", "ppo-highway"):
        shutil.copy(PROJECT_ROOT / "policies" / f"{name}.zip", tmp_path / f"{name}.zip")
        if edit:
            with zipfile.ZipFile(tmp_path / f"{name}.zip", "a") as archive:
                archive.comment = b"edited"
        doc = json.loads((PROJECT_ROOT / "policies" / f"{name}.json").read_text())
        (tmp_path / f"{name}.json").write_text(json.dumps(doc))
        paths.append(str(tmp_path / f"{name}.json"))
    return paths


@pytest.mark.parametrize("edit", [False, True])
def test_the_parent_warns_once_per_unknown_sb3_model_before_the_run(tmp_path, edit):
    """The shipped models' digests are known: their bytes load without a warning (they
    warned on every load, 16 times in one benchmark); any other bytes, here the same
    zip with a comment added, warn once per model before the run."""
    suite = suite_from_dict({"name": "agents", "envs": ["highway"],
                             "policies": [*_model_definitions(tmp_path, edit), "idm"],
                             "seeds": "0-2", "reference_policy": "idm"})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _tasks(plan_suite(suite), False, None)
    untrusted = [str(w.message) for w in caught if w.category is UntrustedModelWarning]
    if not edit:
        assert untrusted == []
        return
    assert len(untrusted) == 2
    assert any("dqn-highway.zip" in m for m in untrusted)
    assert any("ppo-highway.zip" in m for m in untrusted)


def test_loading_a_shipped_model_does_not_warn_and_an_edited_one_does(tmp_path):
    pytest.importorskip("stable_baselines3")
    from tap_bench.sim.sb3 import load_model

    with warnings.catch_warnings():
        warnings.simplefilter("error", UntrustedModelWarning)
        model = load_model(PROJECT_ROOT / "policies" / "dqn-highway.zip")
    assert type(model).__name__ == "DQN"
    _model_definitions(tmp_path, edit=True)
    with pytest.warns(UntrustedModelWarning, match="dqn-highway.zip"):
        load_model(tmp_path / "dqn-highway.zip")
