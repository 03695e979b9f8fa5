"""Every kind of input a run reads, edited one byte at a time, makes the re-run fresh: the
episode key, the label key or the whole-run key moves (files the key hashes), or an entry
made before the edit is not served after it (a module a policy or a measure loaded by name
as it ran, which only the entry records). Property test over generated edits; the kinds
are those docs/benchmark.md's cache section lists."""

from __future__ import annotations

import importlib
import importlib.util
import json
import pickle
import shutil
import string
import sys
from pathlib import Path

import pandas as pd
import pytest
from fault_helpers import RUN_TAG
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from tap_bench.bench import cache as cache_module
from tap_bench.bench.cache import (
    EpisodeCache,
    episode_key,
    label_code,
    label_key,
    policy_fingerprint,
    scenario_fingerprint,
    simulation_fingerprint,
)
from tap_bench.bench.measures import MEASURES, SCENE_MEASURES
from tap_bench.sim.policies import POLICY_KINDS, _read_definition
from tap_bench.sim.rollout import EPISODE_COLUMNS
from tap_bench.sim.scenario_env import get_scenario
from tap_bench.sim.scenario_format import load_scenario
from tap_bench.sim.schema import SCENARIO_KINDS
from tap_bench.sim.womd_scene import SceneRef, WomdScenes
from tap_bench.thresholds import PRESETS, load_thresholds
from tap_bench.usercode import loaded_user_code, recording

TAG = RUN_TAG
PKG, CARS, KINDS, MEAS = f"pkg_{TAG}", f"cars_{TAG}", f"kinds_{TAG}", f"meas_{TAG}"
SMEAS = f"smeas_{TAG}"
BYNAME, MBYNAME, BYPATH = f"byname_{TAG}", f"mbyname_{TAG}", f"bypath_{TAG}"

SOURCES = {
    f"{PKG}/__init__.py": "",
    f"{PKG}/policy.py": ("import importlib\n\nfrom . import helper\n\n\nclass Mine:\n"
                         "    observation = None\n\n    def __init__(self, name):\n"
                         "        self.name = name\n\n    def reset(self, env, *, seed):\n"
                         "        pass\n\n    def act(self, observation):\n"
                         f"        return importlib.import_module('{BYNAME}').A + helper.B\n"),
    f"{PKG}/helper.py": "B = 0\n",
    f"{BYNAME}.py": "A = 1\n",
    f"{CARS}.py": ("from highway_env.vehicle.behavior import IDMVehicle\n\n\n"
                   "class Car(IDMVehicle):\n    TIME_WANTED = 1.2\n"),
    f"{KINDS}.py": ("from highway_env.envs.merge_env import MergeEnv\n\n\n"
                    "def build(name, **params):\n    raise NotImplementedError\n\n\n"
                    "class Env(MergeEnv):\n    SPEED = 20.0\n"),
    f"{MEAS}.py": ("import importlib\n\nimport numpy as np\n\n\ndef value(steps):\n"
                   f"    return np.full(len(steps.starts), importlib.import_module("
                   f"'{MBYNAME}').V)\n"),
    f"{MBYNAME}.py": "V = 2.5\n",
    f"{BYPATH}.py": "C = 7\n",
    f"{SMEAS}.py": ("import numpy as np\n\n\ndef value(steps):\n"
                    "    return np.zeros(len(steps.starts))\n"),
}
ALL, MINE, CONST, LABELS = (0, 1, 2, 3), (0, 1), (2, 3), (1, 3)  # keys of _keys that move
INPUTS = {  # kind -> (file, the keys its edit moves; None: only the entries know it)
    "scenario file": ("scene.json", ALL), "scenario kind's module": (f"{KINDS}.py", ALL),
    "vehicle class module": (f"{CARS}.py", ALL), "policy file": ("mine.json", MINE),
    "file a policy parameter names": ("weights.bin", MINE),
    "factory module": (f"{PKG}/policy.py", MINE),
    "module the factory imports": (f"{PKG}/helper.py", MINE),
    "policy kind builder": (f"{KINDS}.py", ALL), "plugin policy's file": ("const.json", CONST),
    "measure plugin module": (f"{MEAS}.py", LABELS),
    "thresholds file": ("thresholds.json", LABELS), "simulation code": ("sim/0", ALL),
    "module the policy loads by name": (f"{BYNAME}.py", None),
    "module a measure loads by name": (f"{MBYNAME}.py", None),
    "module a policy runs from its path": (f"{BYPATH}.py", None),
    "recorded scene file": ("sd_scene.pkl", (4,)),
    "scene measure plugin module": (f"{SMEAS}.py", LABELS),
}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    root = tmp_path_factory.mktemp("inputs")
    for name, text in SOURCES.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    (root / "weights.bin").write_bytes(bytes(range(64)))
    t = [0.1 * i for i in range(20)]  # a ScenarioNet scene (its key hashes its bytes)
    (root / "sd_scene.pkl").write_bytes(pickle.dumps({
        "id": "s", "metadata": {"ts": t, "scenario_id": "s", "sdc_id": "1"},
        "tracks": {"1": {"type": "VEHICLE", "state": {
            "position": [[10.0 * x, 0.0, 0.0] for x in t], "heading": [0.0] * 20,
            "velocity": [[10.0, 0.0]] * 20, "valid": [True] * 20}}}}))
    (root / "mine.json").write_text(json.dumps({
        "name": "mine", "kind": "import", "params": {"factory": f"{PKG}.policy:Mine",
                                                     "weights": "weights.bin"}}))
    (root / "const.json").write_text(json.dumps({"name": "const", "kind": f"k{TAG}",
                                                 "params": {"gain": 2}}))
    doc = json.loads(get_scenario("merge").path.read_text())
    doc.update(highway_env_id=f"kind-{TAG}-v0", name="scene")
    doc["config"]["other_vehicles_type"] = f"{CARS}.Car"
    (root / "scene.json").write_text(json.dumps(doc))
    (root / "thresholds.json").write_text(json.dumps(PRESETS["paper"].to_dict()))
    (root / "sim").mkdir()
    for path in cache_module._simulation_modules()[:2]:
        shutil.copy(path, root / "sim" / path.name)
    sys.path.insert(0, str(root))
    from tap_bench.bench.measures import Measure
    from tap_bench.sim.policies import PolicyKind
    from tap_bench.sim.schema import ScenarioKind

    POLICY_KINDS.register(PolicyKind(f"k{TAG}", f"{KINDS}:build"))
    SCENARIO_KINDS.register(ScenarioKind(f"kind-{TAG}-v0", f"{KINDS}:Env"))
    MEASURES.register(Measure(f"m{TAG}", "m", True, "a plug-in's measure", 1.0,
                              importlib.import_module(MEAS).value))
    SCENE_MEASURES.register(Measure(f"sm{TAG}", "m", True, "a plug-in's scene measure", 1.0,
                                    importlib.import_module(SMEAS).value))
    run = f"run-{TAG}"
    with recording(run):  # what the policy and the measure load as they run
        importlib.import_module(BYNAME)
        importlib.import_module(MBYNAME)
        spec = importlib.util.spec_from_file_location(BYPATH, root / f"{BYPATH}.py")
        spec.loader.exec_module(importlib.util.module_from_spec(spec))  # no import
    # the keys of the files as written: each example edits one byte and puts it back, so
    # these are every example's keys before its edit (taken once, where each example took
    # them again: about 40 ms a time, 160 times)
    yield root, run, _keys(root)
    MEASURES.unregister(f"m{TAG}")
    SCENE_MEASURES.unregister(f"sm{TAG}")
    POLICY_KINDS.unregister(f"k{TAG}")
    SCENARIO_KINDS.unregister(f"kind-{TAG}-v0")
    sys.path.remove(str(root))


def _file(root: Path, name: str) -> Path:
    if name.startswith("sim/"):
        return sorted((root / "sim").glob("*.py"))[int(name[4:])]
    return root / name


def _keys(root: Path) -> tuple:
    """What decides whether a re-run is served: (mine's episode key, its label key,
    const's episode key, its label key, mine's episode key in the recorded scene)."""
    scenario = load_scenario(root / "scene.json")
    versions = simulation_fingerprint(sorted((root / "sim").glob("*.py")))
    thresholds = load_thresholds(root / "thresholds.json").to_dict()
    code = label_code([m for m in MEASURES if m.name == f"m{TAG}"])
    env = scenario_fingerprint(scenario)
    out = []
    for policy in ("mine.json", "const.json"):
        pol = policy_fingerprint(_read_definition(root / policy))
        assert env is not None and pol is not None
        key = episode_key(env, pol, 0, versions)[0]
        out += [key, label_key(key, thresholds, "maneuver", code)[0]]
    scene = WomdScenes((str(root / "sd_scene.pkl"),))
    recorded = {"env": "womd", **scene.fingerprint(SceneRef(str(root / "sd_scene.pkl"), 0,
                                                             "scenarionet"))}
    out.append(episode_key(recorded, policy_fingerprint(_read_definition(root / "mine.json")),
                           0, versions)[0])
    return tuple(out)


def _entry(cache: EpisodeCache, run: str) -> str:
    """An episode and its labels stored with what the run loaded by name; their key."""
    key, doc = episode_key({"env": "e"}, {"policy": "p"}, 0, {})
    row = {c: None for c in EPISODE_COLUMNS} | {"status": "ok", "seed": 0}
    table = pd.DataFrame({"scenario_id": ["a"], "t": [0.0]})
    cache.put(key, doc, table, row, 1.0, loaded_user_code(run))
    lkey, ldoc = label_key(key, {}, "maneuver", {})
    cache.put_labels(lkey, ldoc, {"episodes": table}, loaded_user_code(run))
    return key


def test_the_docs_list_every_kind_of_input_tested():
    text = " ".join((Path(__file__).resolve().parents[2] / "docs" / "benchmark.md")
                    .read_text().split())
    for phrase in ("loaded by name", "policy kind", "scenario kind", "vehicle class",
                   "thresholds", "measure", "run from its path", "Not in the key"):
        assert phrase in text


@pytest.mark.parametrize("kind", sorted(INPUTS))
@settings(max_examples=4, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture,
                                 HealthCheck.filter_too_much])
@given(where=st.floats(0, 1, exclude_max=True), byte=st.integers(0, 255))
def test_every_input_edited_makes_the_rerun_fresh(inputs, tmp_path_factory, kind, where,
                                                  byte):
    """Each kind of input, 4 drawn one-byte edits (68 in all, every kind edited; drawn over
    all kinds at once, as 140 edits were, each kind's share was left to chance)."""
    root, run, before = inputs
    name, moves = INPUTS[kind]
    path = _file(root, name)
    original = path.read_bytes()
    data = bytearray(original)
    i = int(where * len(data))
    if name.endswith(".json"):  # a change that keeps the file a valid definition
        assume(chr(data[i]) in string.ascii_letters + string.digits)
        pool = string.digits if chr(data[i]).isdigit() else string.ascii_letters
        byte = ord(pool[byte % len(pool)])
    assume(data[i] != byte)  # the edits drawn and refused before any work
    cache = EpisodeCache(tmp_path_factory.mktemp("cache"))
    key = _entry(cache, run)
    lkey = label_key(key, {}, "maneuver", {})[0]
    assert cache.read(key)[0] is not None and cache.read_labels(lkey)[0] is not None
    read = load_thresholds(root / "thresholds.json").to_dict()
    data[i] = byte
    path.write_bytes(bytes(data))
    try:
        if moves is None:  # only the entries know it: neither is served
            assert cache.read(key) == (None, None), f"{kind}: the old episode was served"
            assert cache.read_labels(lkey) == (None, None), f"{kind}: old labels served"
            return
        try:
            after = _keys(root)
        except Exception:  # the edit broke the file: not an input any more
            assume(False)
        if kind == "thresholds file":  # the run reads the values, not the file's bytes
            assume(load_thresholds(root / "thresholds.json").to_dict() != read)
        moved = tuple(i for i in range(len(before)) if before[i] != after[i])
        assert set(moves) <= set(moved), f"{kind}: a changed byte left a key as it was"
    finally:
        path.write_bytes(original)


def test_the_keys_of_the_files_as_written_are_kept_after_the_edits(inputs):
    """The examples above put back each byte they changed, so the keys they compare with
    (taken once, before them) are still the keys of the files."""
    root, _, before = inputs
    assert _keys(root) == before
