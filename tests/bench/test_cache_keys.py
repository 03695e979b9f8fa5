"""The episode key follows every input of an episode: any byte changed in any file an
episode depends on (the scenario file, the policy definition, a model file it names, the
factory's module and every module it loads in the user's package, a user vehicle class,
tap-bench's simulation code) or any version gives another key (property test over
generated edits)."""

from __future__ import annotations

import json
import os
import shutil
import string
import uuid
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from tap_bench.bench import cache as cache_module
from tap_bench.bench.cache import (
    episode_key,
    policy_fingerprint,
    scenario_fingerprint,
    simulation_fingerprint,
)
from tap_bench.sim.policies import _read_definition
from tap_bench.sim.scenario_env import get_scenario
from tap_bench.sim.scenario_format import load_scenario

RUN_TAG = os.environ.get("PYTEST_XDIST_TESTRUNUID", uuid.uuid4().hex)[:8]
"""A tag of this test run for the user modules written here, the same in every
pytest-xdist worker (test ids name them, and the workers must collect the same ids)."""

PACKAGE = f"userpkg_{RUN_TAG}"
SIBLING = f"sibling_{RUN_TAG}"
CARS = f"cars_{RUN_TAG}"

SOURCES = {
    f"{PACKAGE}/__init__.py": "",
    f"{PACKAGE}/policy.py": (f"from . import helper\nimport {SIBLING}\n\n\n"
                             "class MyPolicy:\n    observation = None\n\n"
                             "    def __init__(self, name, gain=1.0):\n"
                             "        self.name, self.gain = name, gain\n\n"
                             "    def reset(self, env, *, seed):\n        pass\n\n"
                             "    def act(self, observation):\n        return helper.ACTION\n"),
    f"{PACKAGE}/helper.py": "ACTION = 1  # IDLE\n",
    f"{PACKAGE}/loaded_by_name.py": "SETTING = 3\n",
    f"{CARS}/__init__.py": "",
    f"{CARS}/vehicles.py": ("from highway_env.vehicle.behavior import IDMVehicle\n\n\n"
                               "class MyVehicle(IDMVehicle):\n    TIME_WANTED = 1.2\n"),
    f"{SIBLING}.py": "SCALE = 2.0\n",
}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A scenario with a user vehicle class and an ``import`` policy of a user package with
    a model file: every file an episode of theirs depends on."""
    root = tmp_path_factory.mktemp("inputs")
    for name, text in SOURCES.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    (root / "weights.bin").write_bytes(bytes(range(64)))
    (root / "mine.json").write_text(json.dumps({
        "name": "mine", "kind": "import", "description": "a user policy",
        "params": {"factory": f"{PACKAGE}.policy:MyPolicy", "gain": 2.5,
                   "weights": "weights.bin"}}, indent=1))
    (root / "scene.json").write_text(json.dumps({
        "name": "scene", "version": 3, "highway_env_id": "highway-v0", "description": "d",
        "duration": 10, "default_seeds": "0-4", "lane_change": "realistic",
        "config": {"lanes_count": 2, "vehicles_count": 5,
                   "other_vehicles_type": f"{CARS}.vehicles.MyVehicle"},
        "script": {"kind": "cut_in", "at": 3.0, "gap": 25.0}}, indent=1))
    sim = root / "sim"
    sim.mkdir()
    for path in cache_module._simulation_modules()[:3]:
        shutil.copy(path, sim / path.name)
    return root


def key_of(root: Path, seed: int = 0) -> str:
    scenario = load_scenario(root / "scene.json")
    policy = _read_definition(root / "mine.json")
    versions = simulation_fingerprint(sorted((root / "sim").glob("*.py")))
    env, pol = scenario_fingerprint(scenario), policy_fingerprint(policy)
    assert env is not None and pol is not None
    return episode_key(env, pol, seed, versions)[0]


FILES = [*SOURCES, "weights.bin", "mine.json", "scene.json", "sim/0", "sim/1", "sim/2"]


def _file(root: Path, name: str) -> Path:
    if name.startswith("sim/"):
        return sorted((root / "sim").glob("*.py"))[int(name[4:])]
    return root / name


_KEY_AS_WRITTEN: dict[Path, str] = {}
"""The key of the module's input files as written, by their folder (the examples' key
before their edit)."""


@settings(max_examples=120, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture,
                                 HealthCheck.filter_too_much])
@given(name=st.sampled_from(FILES), where=st.floats(0, 1, exclude_max=True),
       byte=st.integers(0, 255))
def test_any_byte_changed_in_any_input_changes_the_key(inputs, monkeypatch, name, where,
                                                       byte):
    monkeypatch.syspath_prepend(str(inputs))
    # the key of the files as written, taken at the first example (each example puts its
    # byte back); test_the_key_of_the_files_as_written_is_kept_after_the_edits checks that
    # it is the key the files give after all the examples
    if inputs not in _KEY_AS_WRITTEN:
        _KEY_AS_WRITTEN[inputs] = key_of(inputs)
    before = _KEY_AS_WRITTEN[inputs]
    path = _file(inputs, name)
    original = path.read_bytes()
    data = bytearray(original)
    if not data:  # an empty file: a byte added is the change
        data = bytearray([byte])
    else:
        i = int(where * len(data))
        if name.endswith(".json"):  # a change that keeps the file a valid definition
            assume(chr(data[i]) in string.ascii_letters + string.digits)
            pool = string.digits if chr(data[i]).isdigit() else string.ascii_letters
            byte = ord(pool[byte % len(pool)])
        assume(data[i] != byte)
        data[i] = byte
    path.write_bytes(bytes(data))
    try:
        try:
            after = key_of(inputs)
        except Exception:  # the edit broke the file: not an input any more
            assume(False)
        assert after != before, f"{name}: a changed byte left the key as it was"
    finally:
        path.write_bytes(original)


def test_the_key_of_the_files_as_written_is_kept_after_the_edits(inputs, monkeypatch):
    """The examples above put back each byte they changed, so the key they compare with
    (taken at the first) is still the key of the files."""
    if inputs not in _KEY_AS_WRITTEN:
        pytest.skip("the examples above did not run in this process")
    monkeypatch.syspath_prepend(str(inputs))
    assert key_of(inputs) == _KEY_AS_WRITTEN[inputs]


def test_every_field_of_the_env_and_its_name_are_in_the_key(inputs, monkeypatch):
    monkeypatch.syspath_prepend(str(inputs))
    versions = simulation_fingerprint()
    policy = policy_fingerprint(_read_definition(inputs / "mine.json"))
    scenario = load_scenario(inputs / "scene.json")
    base = episode_key(scenario_fingerprint(scenario), policy, 0, versions)[0]
    script = replace(scenario.script, at=4.0)
    variants = [replace(scenario, version=4), replace(scenario, script=script),
                replace(scenario, script=None), replace(scenario, name="other"),
                replace(scenario, lane_change="default"), replace(scenario, description="e")]
    keys = {episode_key(scenario_fingerprint(v), policy, 0, versions)[0] for v in variants}
    keys.add(episode_key(scenario_fingerprint(scenario, env="renamed"), policy, 0,
                         versions)[0])
    assert base not in keys and len(keys) == len(variants) + 1
    # two envs of one config under two names: two keys
    merge = get_scenario("merge")
    assert scenario_fingerprint(merge, "a") != scenario_fingerprint(merge, "b")


def test_versions_are_in_the_key(monkeypatch):
    env, policy = {"env": "e"}, {"policy": "p"}
    base = episode_key(env, policy, 0, simulation_fingerprint())[0]
    monkeypatch.setattr(cache_module, "_version",
                        lambda package: "99" if package == "highway-env" else "1")
    assert episode_key(env, policy, 0, simulation_fingerprint())[0] != base


def test_code_loaded_from_the_user_package_is_followed(inputs, monkeypatch):
    monkeypatch.syspath_prepend(str(inputs))
    from tap_bench.usercode import code_files

    files = code_files(f"{PACKAGE}.policy")
    assert {f"{PACKAGE}.policy", f"{PACKAGE}.helper", f"{PACKAGE}.loaded_by_name",
            SIBLING} <= set(files)
    assert f"{CARS}.vehicles" not in files
    # third-party and tap-bench modules are keyed by their versions, not file by file
    assert not any(name.split(".")[0] in ("highway_env", "tap_bench", "numpy")
                   for name in files)


def test_the_simulation_code_holds_what_recorded_scenes_are_built_from():
    """An edit to the road map of a recorded scene or to a record decoder re-simulates."""
    package = Path(cache_module.__file__).resolve().parent.parent
    names = {path.relative_to(package).as_posix() for path in cache_module._simulation_modules()}
    assert {"womd/roadmap.py", "womd/scenario.py", "womd/tf_example.py",
            "sources/scenarionet.py", "sim/womd_road.py", "trajectories.py"} <= names


def _closure_without_memo(starts: tuple[str, ...]) -> dict[str, Path]:
    """``_tap_bench_closure`` as it was: each name looked up from the top of the path."""
    from tap_bench.usercode import _source_path, find_module_source

    files: dict[str, Path] = {}
    todo = list(starts)
    while todo:
        name = todo.pop()
        if name in files:
            continue
        path = _source_path(find_module_source(name))
        if path is None:
            continue
        files[name] = path
        named: set[str] = set()
        for base, names, plain in cache_module._IMPORT.findall(path.read_text()):
            if plain:
                named.add(plain)
                continue
            named.add(base)
            for part in names.strip("()").replace("\n", ",").split(","):
                word = part.split("#")[0].split(" as ")[0].strip()
                if word.isidentifier():
                    named.add(f"{base}.{word}")
        todo += [m for m in named if m not in files]
    return dict(sorted(files.items()))


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(order=st.randoms(use_true_random=False), extra=st.lists(st.sampled_from([
    "tap_bench.nothing", "tap_bench.bench.measures.MEASURES", "tap_bench.bench.nothing.deeper",
    "tap_bench..x", "tap_bench.1x", "numpy", "numpy.linalg", "no_such_top", "json.decoder",
    "tap_bench.sim", "tap_bench.sim.scenario_env.get_scenario", "tap_bench.bench"]),
    max_size=6))
def test_a_module_is_found_as_without_the_memo(inputs, monkeypatch, order, extra):
    """The label code's closure looks each package up once (a memo of specs): every name
    gets the spec it gets when looked up alone, whatever was looked up before; the closure
    is the one looked up name by name."""
    from tap_bench.usercode import find_module_source

    monkeypatch.syspath_prepend(str(inputs))
    package = Path(cache_module.__file__).resolve().parent.parent
    names = [".".join(("tap_bench", *p.relative_to(package).with_suffix("").parts))
             .removesuffix(".__init__") for p in package.rglob("*.py")][:60]
    names += [*extra, f"{PACKAGE}.policy", f"{PACKAGE}.helper.ACTION", SIBLING,
              f"{CARS}.vehicles.MyVehicle"]
    order.shuffle(names)
    memo: dict = {}
    for name in names:
        alone, memoised = find_module_source(name), find_module_source(name, memo)
        assert (alone is None) == (memoised is None), name
        if alone is not None:
            assert (alone.name, alone.origin, alone.submodule_search_locations) == (
                memoised.name, memoised.origin, memoised.submodule_search_locations), name
    starts = tuple(order.sample(names, 3))
    assert cache_module._tap_bench_closure(starts) == _closure_without_memo(starts)


def test_the_label_codes_closure_is_the_one_looked_up_name_by_name():
    """The label code's closure (what the label key hashes) is the one looked up name by
    name. It draws nothing, so it runs once, not in each example above."""
    assert cache_module._tap_bench_closure(cache_module.LABEL_CODE) \
        == _closure_without_memo(cache_module.LABEL_CODE)


def test_an_envs_key_is_the_same_in_the_process_that_first_reads_highway_envs_defaults(
        tmp_path, monkeypatch):
    """highway-env's defaults are read once per installation and kept in a file; the process
    that reads them (a new highway-env, an edited scenario kind) answers them as every later
    process, which reads the file, does: same values, same key order (``tap-bench envs NAME``
    prints them in that order). The episode keys hash the fingerprint with its keys sorted,
    so they are the same in both either way."""
    from tap_bench.sim import schema
    from tap_bench.sim.scenario_format import load_scenario, suite_dir

    monkeypatch.setenv("TAP_BENCH_CACHE", str(tmp_path))
    monkeypatch.setattr(schema, "_MEMORY", {})
    scenario = load_scenario(suite_dir("envs") / "merge.json")
    first = scenario_fingerprint(scenario)  # highway-env's defaults read and kept
    schema._MEMORY.clear()  # a later process: the defaults come from the file
    later = scenario_fingerprint(scenario)
    assert json.dumps(first) == json.dumps(later)
    assert cache_module._canonical(first) == cache_module._canonical(later)
