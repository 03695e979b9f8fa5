"""The episode cache follows the user's code an episode or a label entry is made with: the
builder of a plugin's policy kind, a plugin's environment class (scenario kind), and a module
that an ``import`` policy or a measure plugin loads by name as it runs
(``importlib.import_module("helper")`` beside a top-level module). Edit one, and the re-run
is made fresh (the old entries are not served); edit nothing, and it is read from the cache.
Each run is a ``tap-bench bench run`` in a child process, as a user runs it, so that the
edited module is imported afresh."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
from fault_helpers import RUN_TAG, command_server, run_process

from tap_bench.sim.scenario_env import get_scenario

TAG = RUN_TAG


def _suite(folder: Path, policy: str, env: str = "merge", seeds: str = "0") -> Path:
    path = folder / "suite.json"
    path.write_text(json.dumps({
        "name": "usercode", "envs": [env], "policies": [policy], "seeds": seeds,
        "reference_policy": policy, "env_overrides": {env: {"duration": 3}},
        "bootstrap": {"n_resamples": 100}}))
    return path


def _run(folder: Path, name: str, *plugins: str, server=None) -> tuple[dict, pd.DataFrame]:
    """``bench run`` of ``folder``'s suite into ``folder/name`` with ``folder/cache``: (the
    summary, the episode table). Without the report (its plots and pages: about 0.5 CPU s
    of a child run's 3.5), which no test here reads. ``server``: a
    :func:`fault_helpers.command_server`'s ``run``, where each run is forked from a process
    that has imported tap-bench (and none of the user's modules); else a fresh child."""
    args = ["bench", "run", "--suite", folder / "suite.json", "-o", folder / name,
            "--cache", folder / "cache", "--workers", "1", "--no-progress", "--no-report"]
    for plugin in plugins:
        args += ["--plugin", plugin]
    result = (server or run_process)(*args, cwd=folder)
    assert result.returncode == 0, result.stderr.decode()[-3000:]
    summary = json.loads((folder / name / "summary.json").read_text())
    return summary, pd.read_parquet(folder / name / "episodes.parquet")


def _counts(summary: dict) -> tuple[int, int]:
    return summary["cache"]["cached"], summary["cache"]["simulated"]


CONST = '''
from tap_bench.sim.policies import register_policy_kind

ACTION = 3  # FASTER


class Const:
    observation = None

    def __init__(self, name):
        self.name = name

    def reset(self, env, *, seed):
        pass

    def act(self, observation):
        return ACTION


def build(name, **params):
    return Const(name)


register_policy_kind("const_{tag}", "constplug_{tag}:build")
'''


SCENE = '''
from highway_env.envs.merge_env import MergeEnv

from tap_bench.sim.schema import SCENARIO_KINDS, ScenarioKind

SPEED = 30.0


class SlowStart(MergeEnv):
    def _make_vehicles(self):
        super()._make_vehicles()
        self.vehicle.speed = SPEED


SCENARIO_KINDS.register(ScenarioKind("slowstart-{tag}-v0", "sceneplug_{tag}:SlowStart",
                                     "a test's own merge"))
'''


@pytest.mark.slow  # 5 CPU s of child runs. Fast: test_cache_inputs.py::
# test_every_input_edited_makes_the_rerun_fresh[scenario kind's module] (the key), and a
# plugin's kind edited end to end:
# test_edited_user_code_is_made_afresh_and_unchanged_code_is_read
def test_an_edited_scenario_kind_is_simulated_again(tmp_path, monkeypatch):
    module = f"sceneplug_{TAG}"
    (tmp_path / f"{module}.py").write_text(SCENE.format(tag=TAG))
    doc = json.loads(get_scenario("merge").path.read_text())
    doc.update(name="slowstart", highway_env_id=f"slowstart-{TAG}-v0")
    doc.pop("script", None)
    (tmp_path / "envs").mkdir()
    (tmp_path / "envs" / "slowstart.json").write_text(json.dumps(doc))
    monkeypatch.setenv("TAP_BENCH_PATH", str(tmp_path))  # the catalogue: envs/slowstart
    _suite(tmp_path, "lane-keeping", env="slowstart")
    first, eps1 = _run(tmp_path, "first", module)
    assert _counts(first) == (0, 1)
    source = tmp_path / f"{module}.py"
    source.write_text(source.read_text().replace("SPEED = 30.0", "SPEED = 15.0"))
    edited, eps2 = _run(tmp_path, "edited", module)
    assert _counts(edited) == (0, 1)
    assert eps2["mean_speed"].mean() < eps1["mean_speed"].mean()


BY_NAME = '''
import importlib


class ByName:
    observation = None

    def __init__(self, name):
        self.name = name

    def reset(self, env, *, seed):
        pass

    def act(self, observation):
        return importlib.import_module("helper_{tag}").ACTION
'''


def _an_edited_helper_is_simulated_again(tmp_path, policy: str, source: str,
                                         helper_name: str) -> None:
    """The policy module ``policy`` (``source``, a factory ``module:Class``) reads its
    action from ``helper_name``: a first run simulates, the same run again is served, and
    after the helper's ``ACTION`` 3 -> 4 the episode is simulated again, slower."""
    module, _, _ = policy.partition(":")
    (tmp_path / f"{module}.py").write_text(source.format(tag=TAG))
    helper = tmp_path / f"{helper_name}.py"
    helper.write_text("ACTION = 3\n")
    (tmp_path / "mine.json").write_text(json.dumps({
        "name": "mine", "kind": "import", "params": {"factory": policy}}))
    _suite(tmp_path, str(tmp_path / "mine.json"))
    first, eps1 = _run(tmp_path, "first")
    again, _ = _run(tmp_path, "again")
    assert _counts(first) == (0, 1) and _counts(again) == (1, 0)
    helper.write_text("ACTION = 4\n")
    edited, eps2 = _run(tmp_path, "edited")
    assert _counts(edited) == (0, 1)
    assert eps2["mean_speed"].mean() < eps1["mean_speed"].mean()


MEASURE = '''
import importlib

import numpy as np

from tap_bench.bench.measures import register_measure


@register_measure("offset_{tag}", unit="m", higher_is_better=True, margin=1.0,
                  description="a value a helper module holds")
def offset(steps):
    return np.full(len(steps.starts), importlib.import_module("mhelper_{tag}").OFFSET)
'''


def test_edited_user_code_is_made_afresh_and_unchanged_code_is_read(tmp_path):
    """Three kinds of the user's code in one suite, edited one after the other (each edit a
    run): a plugin's policy kind builder (``ACTION`` 3 -> 4), a module an ``import`` policy
    loads by name as it drives (its ``ACTION`` 3 -> 4), and a module a measure plugin loads
    by name (its ``OFFSET`` -3.07 -> 96.93). The first run simulates both policies' episodes,
    the same run again reads both; each edit makes fresh exactly what follows that code
    (the episodes of the policy edited, slower; the labels and measures after the measure's
    helper), and the rest is read. Five child runs, where a test of each kind took eight."""
    const, byname, measure = f"constplug_{TAG}", f"byname_{TAG}", f"measplug_{TAG}"
    (tmp_path / f"{const}.py").write_text(CONST.format(tag=TAG))
    (tmp_path / "const.json").write_text(json.dumps({"name": "const", "kind": f"const_{TAG}",
                                                     "params": {}}))
    (tmp_path / f"{byname}.py").write_text(BY_NAME.format(tag=TAG))
    helper = tmp_path / f"helper_{TAG}.py"
    helper.write_text("ACTION = 3\n")
    (tmp_path / "mine.json").write_text(json.dumps({
        "name": "mine", "kind": "import", "params": {"factory": f"{byname}:ByName"}}))
    (tmp_path / f"{measure}.py").write_text(MEASURE.format(tag=TAG))
    mhelper = tmp_path / f"mhelper_{TAG}.py"
    mhelper.write_text("OFFSET = -3.07\n")
    suite = _suite(tmp_path, str(tmp_path / "const.json"))
    doc = json.loads(suite.read_text())
    doc["policies"].append(str(tmp_path / "mine.json"))
    suite.write_text(json.dumps(doc))

    def speeds(episodes: pd.DataFrame) -> pd.Series:
        return episodes.set_index("policy")["mean_speed"]

    outputs = tmp_path / "outputs"
    outputs.mkdir()
    with command_server(outputs) as server:
        first, eps1 = _run(tmp_path, "first", const, measure, server=server)
        assert _counts(first) == (0, 2)
        assert (eps1[f"offset_{TAG}"] == -3.07).all()
        again, _ = _run(tmp_path, "again", const, measure, server=server)
        assert _counts(again) == (2, 0)  # unchanged: read
        source = tmp_path / f"{const}.py"
        source.write_text(source.read_text().replace("ACTION = 3", "ACTION = 4"))  # SLOWER
        edited, eps2 = _run(tmp_path, "edited-kind", const, measure, server=server)
        assert _counts(edited) == (1, 1)  # the plugin kind's policy simulated again, mine read
        assert speeds(eps2)["const"] < speeds(eps1)["const"]
        assert speeds(eps2)["mine"] == speeds(eps1)["mine"]
        helper.write_text("ACTION = 4\n")
        edited, eps3 = _run(tmp_path, "edited-helper", const, measure, server=server)
        assert _counts(edited) == (1, 1)  # mine simulated again, the edited kind's now read
        assert speeds(eps3)["mine"] < speeds(eps1)["mine"]
        assert speeds(eps3)["const"] == speeds(eps2)["const"]
        mhelper.write_text("OFFSET = 96.93\n")
        edited, eps4 = _run(tmp_path, "edited-measure", const, measure, server=server)
        assert (eps4[f"offset_{TAG}"] == 96.93).all()
        assert edited["cache"]["labelled_before"] == 0


BY_FILE = '''
import importlib.util
from pathlib import Path


class ByFile:
    observation = None

    def __init__(self, name):
        self.name = name

    def reset(self, env, *, seed):
        where = Path(__file__).with_name("fhelper_{tag}.py")
        spec = importlib.util.spec_from_file_location("fhelper_{tag}", where)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)  # run from its path: no import, no sys.modules
        self.action = module.ACTION

    def act(self, observation):
        return self.action
'''


@pytest.mark.slow  # 7 CPU s of child runs. Fast: test_cache_inputs.py::
# test_every_input_edited_makes_the_rerun_fresh[module a policy runs from its path] (the
# entry), and the same three runs end to end for a helper loaded by name:
# test_edited_user_code_is_made_afresh_and_unchanged_code_is_read
def test_a_module_a_policy_runs_from_its_path_is_followed(tmp_path):
    """A policy that runs a module from its file (``spec_from_file_location`` and
    ``exec_module``: no import statement, no finder, no ``sys.modules``) is followed as a
    module loaded by name is."""
    _an_edited_helper_is_simulated_again(tmp_path, f"byfile_{TAG}:ByFile", BY_FILE,
                                         f"fhelper_{TAG}")
