"""Training: a few hundred steps give a model that loads by name and drives; the coverage
callback logs to SB3's logger."""

from __future__ import annotations

import csv
import json

import pytest

from tap_bench.sim.policies import get_definition, load_policy
from tap_bench.sim.rollout import rollout

pytest.importorskip("stable_baselines3")


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["ppo", "dqn"])
def test_a_short_training_gives_a_loadable_model_and_logs_coverage(tmp_path, algo):
    from tap_bench.sim.training import train

    output = tmp_path / f"{algo}-tiny.zip"
    small = {"ppo": {"n_steps": 64, "batch_size": 32, "n_epochs": 2},
             "dqn": {"learning_starts": 50}}[algo]
    result = train(algo, "highway", timesteps=200, seed=3, output=output,
                   hyperparameters=small, log_dir=tmp_path / "log", coverage_window=10)
    assert result.model_path.is_file() and result.definition_path.is_file()
    doc = json.loads(result.definition_path.read_text())
    assert doc["params"]["timesteps"] == 200 and doc["params"]["seed"] == 3
    assert doc["params"]["observation"] == {"type": "Kinematics"}
    assert result.episodes >= 1 and 0.0 < result.coverage <= 1.0

    with open(tmp_path / "log" / "progress.csv") as handle:
        rows = list(csv.DictReader(handle))
    logged = [float(r["tap/coverage"]) for r in rows if r.get("tap/coverage")]
    # SB3 writes the logger's values at its own interval: the last value may come later
    assert logged and all(0.0 < c <= 1.0 for c in logged)

    definition = get_definition(result.definition_path)
    assert definition.kind == "sb3" and definition.name == f"{algo}-tiny"
    with pytest.warns(UserWarning, match="pickles"):
        _, episodes = rollout("highway", result.definition_path, [0, 1], duration=3,
                              progress=False)
    assert episodes["status"].tolist() == ["ok", "ok"], episodes["error"].tolist()
    assert episodes["policy"].tolist() == [f"{algo}-tiny"] * 2


def test_a_model_for_another_action_space_is_refused_clearly(tmp_path):
    import gymnasium as gym

    from tap_bench.errors import TapBenchError
    from tap_bench.sim.sb3 import algorithm_class

    env = gym.make("tap_bench/highway-v0", record=False)
    model = algorithm_class("ppo")("MlpPolicy", env, n_steps=16, batch_size=16, seed=0,
                                   device="cpu")
    path = tmp_path / "ppo-highway-untrained.zip"
    model.save(path)
    policy = load_policy(path)
    intersection = gym.make("tap_bench/intersection-v0", config={"observation": {
        "type": "Kinematics"}})
    with pytest.warns(UserWarning, match="pickles"), \
            pytest.raises(TapBenchError, match="action space"):
        policy.reset(intersection, seed=0)
