"""Rollouts on a backend: batches of seeds per task, the same tables as a local rollout.

Each task runs :func:`tap_bench.sim.rollout.rollout` on a batch of seeds in one worker
process. An episode depends on its seed alone (the env and the policy are reset with it), so
the tables, gathered in the order of the seeds, are those of ``rollout(env, policy, seeds)``
run locally, whichever worker or node ran each batch. A failed episode is reported in the
episode table, as locally; a batch whose worker died on every retry is reported episode by
episode, and the other batches are kept.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import pandas as pd

from tap_bench.distributed.backend import DEFAULT_RETRIES, Backend

__all__ = ["DEFAULT_BATCH", "distributed_rollout"]

DEFAULT_BATCH = 8
"""Seeds per task: a task costs Ray a few ms, an episode about a second, and small batches
keep a cluster's workers evenly busy."""


@dataclass(frozen=True)
class _Batch:
    scenario: Any  # tap_bench.sim.suite.Scenario
    policy: Any  # PolicyDefinition or Policy
    seeds: tuple[int, ...]
    record: bool


def _run_batch(batch: _Batch) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Roll out one batch in this (worker) process; failed episodes stay in the table."""
    from tap_bench.sim.rollout import rollout

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # failed episodes are rows; the driver warns once
        result = rollout(batch.scenario, batch.policy, list(batch.seeds), workers=1,
                         record=batch.record, progress=False)
    return result.trajectories, result.episodes


def distributed_rollout(env: Any, policy: Any, seeds: str | int | Sequence[int],
                        backend: Backend, *, batch: int = DEFAULT_BATCH,
                        config: Mapping[str, Any] | None = None,
                        duration: float | None = None, lane_change: str | None = None,
                        record: bool = True, retries: int = DEFAULT_RETRIES,
                        progress: bool | None = None):
    """:func:`tap_bench.sim.rollout.rollout` with batches of seeds as tasks on ``backend``.

    Args:
        env, policy, seeds, config, duration, lane_change, record: as
            :func:`~tap_bench.sim.rollout.rollout`.
        backend: where the batches run (:class:`~tap_bench.distributed.LocalBackend`,
            :class:`~tap_bench.distributed.RayBackend`).
        batch: seeds per task.
        retries: retries of a batch whose worker died.
        progress: progress bar over batches (None: only on a terminal).

    Returns:
        :class:`~tap_bench.sim.rollout.Rollout`, equal to the local rollout of the same
        seeds.

    Warns:
        EpisodeFailedWarning: some episodes failed; their rows say why.
    """
    import gymnasium as gym

    from tap_bench.sim.policies import Policy, PolicyDefinition, get_definition
    from tap_bench.sim.rollout import EPISODE_COLUMNS, collect_rollout
    from tap_bench.sim.scenario_env import find_scenario_env, get_scenario
    from tap_bench.sim.suite import parse_seeds

    if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
        raise ValueError(f"batch must be a positive integer (seeds per task), got {batch!r}.")
    scenario = find_scenario_env(env).scenario if isinstance(env, gym.Env) else get_scenario(env)
    if config or duration is not None or lane_change is not None:
        scenario = scenario.with_overrides(config, duration=duration, lane_change=lane_change)
    seed_list = parse_seeds(seeds)
    spec = policy if isinstance(policy, Policy | PolicyDefinition) else get_definition(
        os.fspath(policy) if isinstance(policy, os.PathLike) else policy)
    if isinstance(spec, PolicyDefinition):
        spec.build()  # fail here, once, on a bad definition rather than in every task
    name = getattr(spec, "name", "policy")
    batches = [_Batch(scenario, spec, tuple(seed_list[i:i + batch]), record)
               for i in range(0, len(seed_list), batch)]
    outcomes = backend.map(_run_batch, batches, retries=retries, unit="batch",
                           desc=f"{scenario.name} {name} ({backend.name})", progress=progress)
    tables, episode_tables = [], []
    for work, outcome in zip(batches, outcomes, strict=True):
        if outcome.ok:
            trajectories, episodes = outcome.value
            if len(trajectories):
                tables.append(trajectories)
            episode_tables.append(episodes)
        else:
            episode_tables.append(_failed_episodes(work, name, outcome.error, EPISODE_COLUMNS))
    return collect_rollout(tables, pd.concat(episode_tables, ignore_index=True), stacklevel=3)


def _failed_episodes(work: _Batch, name: str, error: str, columns: Sequence[str]
                     ) -> pd.DataFrame:
    rows = [{"env": work.scenario.name, "policy": name, "seed": seed,
             "return": float("nan"), "length": 0, "duration_s": float("nan"),
             "crashed": False, "mean_speed": float("nan"), "terminated": False,
             "truncated": False, "status": "error", "error": error} for seed in work.seeds]
    return pd.DataFrame(rows, columns=list(columns))
