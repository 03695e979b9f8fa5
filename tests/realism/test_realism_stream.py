"""``tap-bench realism`` scores scenes one at a time: the score equals the one of all the
scenes' rows in one table, it keeps a few values per scene whatever the number of agents,
and its peak memory does not grow with the number of scenes (measured in a subprocess)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from tap_bench.cli import main
from tap_bench.errors import ParameterError
from tap_bench.realism import summary as realism_summary
from tap_bench.realism.score import BERNOULLI_FEATURES, FEATURES
from tap_bench.realism.summary import SceneScores, _block, scene_values
from tap_bench.stats.bootstrap import BootstrapConfig

PROJECT_ROOT = Path(__file__).resolve().parents[2]
DEV = PROJECT_ROOT / ".." / "shared" / "data" / "womd-dev" / "dev.tfrecord"
THREE = ("tfrecord-00004-of-00150_246.json", "tfrecord-00012-of-00150_204.json",
         "tfrecord-00001-of-01000_49.json")  # 3, 17 and 5 tracks


def one_table_summary(agents: pd.DataFrame, config: BootstrapConfig) -> dict[str, Any]:
    """The realism summary computed from every scene's rows in one table, as tap-bench did
    before it scored scenes one at a time: the oracle of the streamed score."""
    per_scene = scene_values(agents)
    index = pd.Index(per_scene["scenario_id"])
    n = len(index)
    weights = config.rng("realism", "scenes").multinomial(
        n, np.full(n, 1 / n), size=config.n_resamples).astype(float)
    out: dict[str, Any] = {"scenes": n,
                           "agents": int((agents["feature"] == FEATURES[0]).sum()),
                           "overall": _block(per_scene, weights, config, index)}
    for key, column in (("by_object_type", "object_type"), ("by_manoeuvre", "manoeuvre")):
        groups = {}
        for value, rows in agents.groupby(column, sort=True):
            block = _block(scene_values(rows), weights, config, index)
            block["agents"] = int((rows["feature"] == FEATURES[0]).sum())
            groups[str(value)] = block
        out[key] = groups
    out["per_scene"] = per_scene.to_dict(orient="records")
    return out


def agent_rows(scene: str, agents: int, rng: np.random.Generator) -> pd.DataFrame:
    """Rows of one scene as score_scene gives them: ``agents`` agents of drawn types and
    manoeuvres, every feature, drawn log-probabilities, terms and rates."""
    types = rng.choice(["vehicle", "pedestrian", "cyclist"], agents, p=[0.7, 0.2, 0.1])
    labels = rng.choice(["Left Turn", "Straight", "Stopped", "unlabelled"], agents)
    rows = []
    for feature in FEATURES:
        bernoulli = feature in BERNOULLI_FEATURES
        rows.append(pd.DataFrame({
            "scenario_id": scene, "track_id": [str(k) for k in range(agents)],
            "object_type": types, "manoeuvre": labels, "feature": feature,
            "log_prob_sum": -rng.exponential(0.2 if bernoulli else 20.0, agents),
            "terms": np.ones(agents, np.int64) if bernoulli else rng.integers(1, 80, agents),
            "simulated_rate": rng.uniform(0, 1, agents) if bernoulli else np.nan}))
    return pd.concat(rows, ignore_index=True)


def _comparable(result: dict[str, Any]) -> str:
    keys = ("scenes", "agents", "overall", "by_object_type", "by_manoeuvre", "per_scene")
    return json.dumps({k: result[k] for k in keys}, sort_keys=True)


def test_scene_by_scene_equals_one_table(monkeypatch):
    rng = np.random.default_rng(5)
    scenes = [agent_rows(f"scene-{k}", int(rng.integers(1, 30)), rng) for k in range(12)]
    scenes.append(agent_rows("no-walkers", 4, rng).assign(object_type="vehicle"))
    config = BootstrapConfig(n_resamples=100, seed=3)
    monkeypatch.setattr(realism_summary, "KEPT_ROWS", 7)  # tables joined on the way
    streamed = SceneScores()
    for table in scenes:
        streamed.add(table)
    expected = one_table_summary(pd.concat(scenes, ignore_index=True), config)
    assert _comparable(streamed.summary(config)) == _comparable(expected)  # float for float
    assert expected["by_object_type"]["cyclist"]["scenes"] < 13  # groups missing somewhere


def test_a_scene_keeps_its_values_not_its_agents():
    rng = np.random.default_rng(6)
    few, many = SceneScores(), SceneScores()
    for k in range(3):
        one = agent_rows(f"s{k}", 4, rng).assign(object_type="vehicle", manoeuvre="Straight")
        few.add(one)
        many.add(agent_rows(f"s{k}", 400, rng).assign(object_type="vehicle",
                                                      manoeuvre="Straight"))
    kept = {name: sum(len(t) for t in [*s._tables.values(), *s._pending.values()]
                      for t in t) for name, s in (("few", few), ("many", many))}
    assert kept["few"] == kept["many"] == 3 * 3  # a row per scene and group, no agent's
    assert many.summary(BootstrapConfig(n_resamples=100))["agents"] == 1200


def test_a_scenario_met_twice_is_refused_by_name():
    rng = np.random.default_rng(7)
    scores = SceneScores()
    scores.add(agent_rows("same", 3, rng))
    with pytest.raises(ParameterError, match=r"added once.*scenario same"):
        scores.add(agent_rows("same", 3, rng))


@pytest.fixture(scope="module")
def dev_file() -> str:
    if not DEV.is_file():
        pytest.skip(f"the development scenes are not in {DEV}")
    return str(DEV.resolve())


def test_the_command_scores_as_one_table_of_its_scenes(tmp_path, dev_file):
    from tap_bench.realism.rollouts import agent_manoeuvres, scene_rollouts, score_scene
    from tap_bench.sim.policies import load_policy
    from tap_bench.sim.womd_env import make_womd_env

    out = tmp_path / "r.json"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["realism", "--womd", dev_file, "--scenario", *THREE, "--traffic",
                     "idm", "--rollouts", "2", "--resamples", "200", "--no-progress",
                     "-o", str(out)]) == 0
        env = make_womd_env([dev_file], traffic="idm")
        policy = load_policy("log")
        tables = []
        for index in range(len(env.catalog)):
            if env.scene_at(index).scenario_id in THREE:
                states = scene_rollouts(env, index, policy, 2)
                tables.append(score_scene(env.scene, states,
                                          manoeuvres=agent_manoeuvres(env.scene)))
    result = json.loads(out.read_text())
    expected = json.loads(json.dumps(one_table_summary(
        pd.concat(tables, ignore_index=True), BootstrapConfig(n_resamples=200)),
        default=float))
    assert result["scenes"] == 3
    assert _comparable(result) == _comparable(expected)


# a child that runs the command line and reports its peak resident memory (VmHWM: this
# process's own high-water mark, reset at exec)
CHILD = """
import json, sys
from tap_bench.cli import main
from tap_bench.errors import ParameterError
code = main(sys.argv[2:])
peak = [int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM')][0]
json.dump({"code": code, "peak_kb": peak}, open(sys.argv[1], "w"))
"""


def _peak_kb(files: list[str], report: Path, out: Path) -> int:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(PROJECT_ROOT), os.environ.get("PYTHONPATH", "")]), "OMP_WAIT_POLICY": "PASSIVE"}
    proc = subprocess.run([sys.executable, "-c", CHILD, str(report), "realism", "--womd",
                           *files, "--traffic", "log", "--rollouts", "8", "--resamples",
                           "100", "--no-progress", "-o", str(out)],
                          env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(report.read_text())["peak_kb"]


@pytest.mark.slow
def test_peak_memory_does_not_grow_with_the_scenes(tmp_path):
    sys.path.insert(0, str(PROJECT_ROOT / "tests" / "scale"))
    sys.path.insert(0, str(PROJECT_ROOT / "tests" / "sim"))
    from scale_scenes import scene_files

    peaks = {}
    for n in (3, 18):
        files = scene_files(tmp_path / f"s{n}", n, per_file=6, parked=120)
        peaks[n] = _peak_kb(files, tmp_path / f"m{n}.json", tmp_path / f"o{n}.json")
        assert json.loads((tmp_path / f"o{n}.json").read_text())["scenes"] == n
    assert peaks[18] <= 1.2 * peaks[3], peaks
