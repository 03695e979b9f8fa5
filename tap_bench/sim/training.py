"""Training Stable-Baselines3 agents on a scenario, on the CPU: ``tap-bench train``.

The model is written atomically to the ``.zip`` given, and beside it a policy definition
(``.json``, kind ``sb3``) that records the scenario, the observation config, the algorithm,
its hyper-parameters, the seed, the number of timesteps and the command, so that the model
loads by name (``tap-bench rollout --policy dqn-highway``) and can be rebuilt.
"""

from __future__ import annotations

import json
import os
import shlex
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tap_bench.errors import ParameterError
from tap_bench.sim.sb3 import algorithm_class
from tap_bench.sim.scenario_env import get_scenario, make_env
from tap_bench.sim.wrappers import EpisodeLabels
from tap_bench.tableio import atomic_path

__all__ = ["HYPERPARAMETERS", "TrainingResult", "train"]

HYPERPARAMETERS: dict[str, dict[str, Any]] = {
    # highway-env's published Stable-Baselines3 settings for its highway tasks.
    "dqn": {"policy_kwargs": {"net_arch": [256, 256]}, "learning_rate": 5e-4,
            "buffer_size": 15000, "learning_starts": 200, "batch_size": 32, "gamma": 0.8,
            "train_freq": 1, "gradient_steps": 1, "target_update_interval": 50,
            "exploration_fraction": 0.7},
    "ppo": {"policy_kwargs": {"net_arch": {"pi": [256, 256], "vf": [256, 256]}},
            "n_steps": 256, "batch_size": 64, "n_epochs": 10, "learning_rate": 5e-4,
            "gamma": 0.8},
    "a2c": {"policy_kwargs": {"net_arch": [256, 256]}, "learning_rate": 7e-4, "gamma": 0.8},
}
"""Default hyper-parameters per algorithm; ``train(..., hyperparameters=...)`` overrides."""


@dataclass(frozen=True)
class TrainingResult:
    """What :func:`train` wrote.

    Attributes:
        model_path: the ``.zip``.
        definition_path: the policy definition ``.json`` beside it.
        seconds: wall time of the training [s].
        episodes: episodes finished during training.
        coverage: last logged behaviour coverage (None without the coverage callback).
    """

    model_path: Path
    definition_path: Path
    seconds: float
    episodes: int
    coverage: float | None


def train(algo: str, env: str, *, timesteps: int, seed: int, output: str | os.PathLike,
          hyperparameters: Mapping[str, Any] | None = None, coverage: bool = True,
          coverage_window: int = 50, log_dir: str | os.PathLike | None = None,
          verbose: int = 0, command: str | None = None) -> TrainingResult:
    """Train ``algo`` on scenario ``env`` for ``timesteps`` decisions and save it.

    Args:
        algo: ``"dqn"``, ``"ppo"`` or ``"a2c"``.
        env: scenario name, id or file.
        timesteps: decisions (env steps) to train for.
        seed: seeds SB3 (torch, numpy) and the env's first reset.
        output: the ``.zip`` to write; the definition goes to the same name with ``.json``.
        hyperparameters: overrides of :data:`HYPERPARAMETERS`.
        coverage: label episodes and log behaviour coverage (:mod:`tap_bench.sim.callbacks`).
        coverage_window: episodes the coverage is computed over.
        log_dir: write SB3's log, with the ``tap/*`` coverage keys, there as CSV.
        verbose: SB3's verbosity; 1 also prints the log.
        command: the command line to record (default: this process's).

    Raises:
        ValueError: ``timesteps`` or ``output`` is not usable.
    """
    output = Path(output)
    if output.suffix != ".zip":
        raise ParameterError("output", str(output), "a .zip file (a Stable-Baselines3 model)",
                             hint=f"Name it {output.with_suffix('.zip').name}.")
    if isinstance(timesteps, bool) or not isinstance(timesteps, int) or timesteps < 1:
        raise ParameterError("timesteps", timesteps, "an integer >= 1")
    cls = algorithm_class(algo)
    algo = algo.lower()
    import torch
    from stable_baselines3.common.logger import Logger, make_output_format
    from stable_baselines3.common.monitor import Monitor

    torch.set_num_threads(1)  # a shared CPU; also makes runs repeatable
    scenario = get_scenario(env)
    params = {**HYPERPARAMETERS[algo], **(hyperparameters or {})}
    gym_env = make_env(scenario, record=coverage)
    callbacks = []
    if coverage:
        gym_env = EpisodeLabels(gym_env, tracks="ego")
        # callbacks.py subclasses SB3's BaseCallback: imported only where SB3 is installed
        from tap_bench.sim.callbacks import CoverageCallback

        callbacks.append(CoverageCallback(window=coverage_window))
    gym_env = Monitor(gym_env)
    model = cls("MlpPolicy", gym_env, seed=seed, verbose=verbose, device="cpu", **params)
    outputs = [make_output_format("stdout", "")] if verbose else []
    if log_dir:
        Path(log_dir).mkdir(parents=True, exist_ok=True)
        outputs.append(make_output_format("csv", str(log_dir)))
    model.set_logger(Logger(str(log_dir) if log_dir else None, outputs))
    start = time.perf_counter()
    model.learn(total_timesteps=timesteps, callback=callbacks or None, progress_bar=False)
    seconds = time.perf_counter() - start

    output.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(output) as tmp, open(tmp, "wb") as handle:
        model.save(handle)
    definition = output.with_suffix(".json")
    inner = gym_env.unwrapped
    doc = {
        "name": output.stem,
        "kind": "sb3",
        "description": f"{algo.upper()} trained on {scenario.env_id} for {timesteps} steps "
                       f"(seed {seed}) by tap-bench train.",
        "params": {
            "model": output.name,
            "algo": algo,
            "env": scenario.env_id,
            "observation": inner.config["observation"],
            "timesteps": timesteps,
            "seed": seed,
            "hyperparameters": params,
            "train_seconds": round(seconds, 1),
            "command": command or " ".join(shlex.quote(a) for a in sys.argv),
        },
    }
    with atomic_path(definition) as tmp:
        tmp.write_text(json.dumps(doc, indent=2) + "\n")
    episodes = len(gym_env.get_episode_rewards())
    return TrainingResult(model_path=output, definition_path=definition, seconds=seconds,
                          episodes=episodes,
                          coverage=callbacks[0].coverage if callbacks else None)
