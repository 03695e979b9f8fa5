"""Rollouts: a policy on a scenario for a list of seeds, in parallel processes.

Each seed is one episode. The env is reset with the seed, so every policy meets the same
initial traffic on a seed; the policy is reset with the same seed, so the episode, and its
trajectory table, depend on the seed alone, whichever worker runs it and whatever ran
before in that worker. Episodes run as tasks of :mod:`tap_bench.execution` (this process,
fresh local worker processes, or Ray), one task per episode: nothing from the parent's
process state, such as highway-env's class attributes, reaches a worker. An episode that
raises is reported in the episode table (``status`` ``"error"``, with the error) and leaves
no rows in the trajectory table; an episode whose worker dies is tried once more and then
reported the same way. The other episodes are kept.
"""

from __future__ import annotations

import os
import traceback
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

from tap_bench.errors import EpisodeFailedWarning, EpisodesFailedError, RegistrationError
from tap_bench.execution import DEFAULT_RETRIES, Backend, resolve_backend
from tap_bench.sim.policies import CHEAP_OBSERVATION, Policy, PolicyDefinition, get_definition
from tap_bench.sim.scenario_format import Scenario, get_scenario, parse_seeds
from tap_bench.sim.womd_scene import WomdScenes
from tap_bench.trajectories import HZ

if TYPE_CHECKING:
    import gymnasium as gym
    import pandas as pd

__all__ = ["EPISODE_COLUMNS", "RECORDED_CRASH_COLUMNS", "EpisodeFailedWarning",
           "EpisodesFailedError", "Rollout", "check_policy", "collect_rollout",
           "episode_tasks", "resolve_policy", "resolve_scenario", "rollout", "rollout_episode",
           "run_episode"]

RECORDED_CRASH_COLUMNS = ("crash_with", "crash_fault")
"""A recorded scene's collision partner (track id) and the fault rule that decided
(:mod:`tap_bench.sim.collisions`): kept beside :data:`EPISODE_COLUMNS` in a run's table."""
EPISODE_COLUMNS = ("env", "policy", "seed", "return", "length", "duration_s", "crashed",
                   "mean_speed", "terminated", "truncated", "status", "error")
"""The episode table: one row per seed.

env, policy: scenario and policy names. seed: int. return: sum of rewards. length: decisions
(``env.step`` calls). duration_s: simulated time [s]. crashed: the ego collided. mean_speed:
the ego's mean speed over its recorded steps [m/s]. terminated, truncated: how the episode
ended. status: ``"ok"`` or ``"error"``; error: the exception of a failed episode, else "".
Recorded scenes (``tap_bench/womd-v0``) add ``scenario_id``, ``traffic``, ``off_road``,
``max_off_road_distance_m``, ``off_road_rule``, ``route_progress``, ``ran_red_light``,
``log_ade``, ``log_fde``, ``crash_with`` (the agent whose box overlaps the ego's most),
``crash_at_fault``, ``crash_fault`` (the rule that decided), ``crash_from_behind_by_log``,
``traffic_collisions``, ``traffic_collisions_with_log``, ``traffic_collided`` (collisions
among idm traffic) and ``map`` (what the road network made of the map, e.g. successors
inferred) (:meth:`tap_bench.sim.womd_env.WomdEnv.episode_info`).
"""


class Rollout(NamedTuple):
    """What :func:`rollout` returns; unpacks as ``trajectories, episodes = rollout(...)``.

    Attributes:
        trajectories: the trajectory table (SPEC section 1) of every successful episode,
            with ``env``, ``policy``, ``seed``, ``episode``, ``is_ego`` and ``crashed``.
        episodes: the episode table (:data:`EPISODE_COLUMNS`), in the order of the seeds.
    """

    trajectories: pd.DataFrame
    episodes: pd.DataFrame


@dataclass(frozen=True)
class _Task:
    scenario: Scenario
    policy: PolicyDefinition | Policy
    seed: int
    record: bool
    scene: int | None = None  # recorded scenes: the scene's index in the task's files


def run_episode(env: gym.Env, policy: Policy, seed: int, *, record: bool = True,
                options: Mapping[str, Any] | None = None
                ) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Run one episode of ``policy`` on a scenario env reset with ``seed`` (and
    ``options``: ``{"scene": i}`` picks a recorded scene apart from the seed).

    Returns:
        the episode's trajectory table (empty when ``record`` is False) and its row of the
        episode table.
    """
    import pandas as pd

    from tap_bench.sim.scenario_env import find_scenario_env

    scenario_env = find_scenario_env(env)
    obs, _ = env.reset(seed=seed, options=dict(options) if options else None)
    missing = getattr(env.unwrapped, "route_missing", "")
    if missing and not getattr(policy, "replays_log", False):
        # a recorded scene without a route: the human replays it, a policy is skipped there
        # (status "skipped", the reason in error), counted apart from failures
        row = {"env": scenario_env.scenario.name, "policy": policy.name, "seed": int(seed),
               "return": float("nan"), "length": 0, "duration_s": float("nan"),
               "crashed": False, "mean_speed": float("nan"), "terminated": False,
               "truncated": False, "status": "skipped", "error": missing,
               **scenario_env.episode_info()}
        return pd.DataFrame(), row
    policy.reset(env, seed=seed)
    total, steps = 0.0, 0
    terminated = truncated = False
    while not (terminated or truncated):
        obs, reward, terminated, truncated, _ = env.step(policy.act(obs))
        total += float(reward)
        steps += 1
    inner = env.unwrapped
    table = scenario_env.trajectories(policy=policy.name) if record else pd.DataFrame()
    mean_speed = ego_mean_speed(table) if record and len(table) else float("nan")
    row = {"env": scenario_env.scenario.name, "policy": policy.name, "seed": int(seed),
           "return": total, "length": steps, "duration_s": inner.steps / HZ,
           "crashed": bool(inner.vehicle.crashed), "mean_speed": mean_speed,
           "terminated": bool(terminated), "truncated": bool(truncated), "status": "ok",
           "error": ""}
    if hasattr(scenario_env, "episode_info"):  # recorded scenes: off road, progress ...
        row.update(scenario_env.episode_info())
    return table, row


def ego_mean_speed(table: pd.DataFrame) -> float:
    """The mean of the ego's ``speed`` rows of a trajectory table [m/s], NaN left out (NaN
    when none is left): pandas' ``table.loc[table["is_ego"], "speed"].mean()``, computed as
    pandas computes it (NaN put to 0, the float64 values summed, divided by their count)
    without the selected Series when the columns are plain float64 and bool."""
    import numpy as np

    speed, ego = table["speed"], table["is_ego"]
    if speed.dtype != np.float64 or ego.dtype != np.bool_:
        return float(table.loc[ego.to_numpy(), "speed"].mean())
    values = speed.to_numpy()[ego.to_numpy()]
    missing = np.isnan(values)
    count = values.size - int(missing.sum())
    if not count:
        return float("nan")
    if count < values.size:
        values = np.where(missing, 0.0, values)
    return float(values.sum() / np.float64(count))


# Per-process caches: a worker builds each env and policy once and reuses them across seeds
# (reset with the seed makes that safe).
_ENVS: dict[str, gym.Env] = {}
_POLICIES: dict[str, Policy] = {}


def _observation_config(policy: Policy) -> Mapping[str, Any]:
    return CHEAP_OBSERVATION if policy.observation is None else policy.observation


def policy_overrides(policy: Policy) -> dict[str, Any]:
    """The env config a policy drives with: its observation (:data:`CHEAP_OBSERVATION`
    for one that reads none) and, for a trained agent whose action config is its own (a
    safety layer: :mod:`tap_bench.sim.womd_safety`), that action config."""
    action = getattr(policy, "action", None)
    return {"observation": dict(_observation_config(policy)),
            **({"action": dict(action)} if action is not None else {})}


def _is_womd(env: gym.Env) -> bool:
    from tap_bench.sim.womd_env import WomdEnv

    return isinstance(env, WomdEnv)


def _run_task(task: _Task) -> tuple[pd.DataFrame, dict[str, Any]]:
    # Definitions are data with a stable repr: build each once per process. A policy object
    # is used as it came (a copy per task in a worker).
    import pandas as pd

    from tap_bench.sim.scenario_env import ScenarioEnv

    policy_key = repr(task.policy) if isinstance(task.policy, PolicyDefinition) else None
    env_key = None
    try:
        policy = _POLICIES.get(policy_key) if policy_key else task.policy
        if policy is None:
            policy = _POLICIES[policy_key] = task.policy.build()
        overrides = policy_overrides(policy)
        env_key = repr((task.scenario, sorted((k, sorted(v.items()))
                                              for k, v in overrides.items()), task.record))
        env = _ENVS.get(env_key)
        if env is None:
            if isinstance(task.scenario, WomdScenes):  # one env per file of a sharded run:
                for key in [k for k, e in _ENVS.items() if _is_womd(e)][:-1]:  # keep two
                    _ENVS.pop(key).close()
            scenario = task.scenario.with_overrides(overrides)
            if isinstance(scenario, WomdScenes):
                from tap_bench.sim.womd_env import WomdEnv

                env = _ENVS[env_key] = WomdEnv(scenario, record=task.record)
            else:
                env = _ENVS[env_key] = ScenarioEnv(scenario, record=task.record)
        if not isinstance(task.scenario, WomdScenes):
            return run_episode(env, policy, task.seed, record=task.record)
        from tap_bench.sim.womd_env import MapWarning

        with warnings.catch_warnings():
            # each scene's map note is in its episode row: collect_rollout warns once
            warnings.simplefilter("ignore", MapWarning)
            options = {"scene": task.scene} if task.scene is not None else None
            return run_episode(env, policy, task.seed, record=task.record, options=options)
    except Exception as err:  # one failing episode must not end the rollout
        # an env or policy left in an unknown state is rebuilt for the next episode
        _ENVS.pop(env_key, None)
        _POLICIES.pop(policy_key, None)
        lines = traceback.format_exception_only(type(err), err)
        where = traceback.extract_tb(err.__traceback__)[-1]
        message = (f"{''.join(lines).strip()} (at {os.path.basename(where.filename)}:"
                   f"{where.lineno})")
        return pd.DataFrame(), _failed_row(task, message)


def rollout_episode(scenario: Scenario, policy: PolicyDefinition | Policy, seed: int, *,
                    record: bool = True) -> tuple[pd.DataFrame, dict[str, Any]]:
    """One episode in this process, reusing this process's env and policy objects (the
    unit of work of :func:`rollout` and of ``bench run``).

    Returns:
        the episode's trajectory table (empty when it failed or ``record`` is False) and its
        row of the episode table; a failed episode is a row with ``status`` "error", never
        an exception.
    """
    return _run_task(_Task(scenario, policy, int(seed), record))


def _failed_row(task: _Task, message: str) -> dict[str, Any]:
    name = getattr(task.policy, "name", str(task.policy))
    return {"env": task.scenario.name, "policy": name, "seed": task.seed,
            "return": float("nan"), "length": 0, "duration_s": float("nan"), "crashed": False,
            "mean_speed": float("nan"), "terminated": False, "truncated": False,
            "status": "error", "error": message}


def rollout(env: str | os.PathLike | Scenario | WomdScenes | gym.Env,
            policy: str | os.PathLike | Policy | PolicyDefinition,
            seeds: str | int | Sequence[int], *, workers: int = 1,
            config: Mapping[str, Any] | None = None, duration: float | None = None,
            lane_change: str | None = None, record: bool = True,
            progress: bool | None = None, backend: Backend | None = None,
            retries: int = DEFAULT_RETRIES) -> Rollout:
    """Run ``policy`` on scenario ``env`` once per seed.

    Args:
        env: scenario name (``"highway"``), Gymnasium id, scenario file, :class:`Scenario`,
            a scenario env (its scenario is used), or recorded WOMD scenes
            (:class:`~tap_bench.sim.womd_scene.WomdScenes`: a seed is a scenario's index
            in the files; ``seeds="all"`` runs every one).
        policy: policy name (``"idm"``), definition or model file, or a policy object
            (pickled to the workers).
        seeds: ``"0-49"``, ``"1,4,7"``, an int or a sequence of ints.
        workers: processes; 1 runs in this process. The tables do not depend on it.
            Ignored when ``backend`` is given.
        config: more highway-env config overrides for the scenario.
        duration: another episode length [s].
        lane_change: another lane-change setting (``"default"``, ``"realistic"``).
        record: build the trajectory table (False: episode table only, faster).
        progress: show a progress bar (None: on a terminal; elsewhere a line on stderr
            every few seconds, tap_bench.progress).
        backend: where the episodes run (:mod:`tap_bench.execution`: local processes or
            a Ray cluster); one task per episode.
        retries: retries of an episode whose worker died (the recovery rule of
            :mod:`tap_bench.execution`).

    Returns:
        :class:`Rollout` (trajectory table, episode table).

    Warns:
        EpisodeFailedWarning: some episodes failed; their rows say why.

    Raises:
        EpisodesFailedError: every episode failed (naming the first errors).
    """
    import pandas as pd

    scenario = resolve_scenario(env, config=config, duration=duration,
                                lane_change=lane_change)
    if isinstance(scenario, WomdScenes):  # "all", or seeds within the files
        seed_list = list(scenario.seeds(seeds))
    else:
        seed_list = parse_seeds(seeds)
    runner = resolve_backend(backend, workers)
    spec = resolve_policy(policy)
    tasks = episode_tasks(scenario, spec, seed_list, record)
    name = getattr(spec, "name", "policy")
    outcomes = runner.map(_run_task, tasks, retries=retries, unit="episode",
                          desc=f"{scenario.name} {name}", progress=progress)
    results = [o.value if o.ok else (pd.DataFrame(), _failed_row(task, o.error))
               for task, o in zip(tasks, outcomes, strict=True)]
    extra = [k for _, row in results for k in row if k not in EPISODE_COLUMNS]
    columns = [*EPISODE_COLUMNS, *dict.fromkeys(extra)]  # recorded scenes add their measures
    episodes = pd.DataFrame([row for _, row in results], columns=columns)
    return collect_rollout([table for table, _ in results], episodes, stacklevel=3)


def episode_tasks(scenario: Scenario, spec: PolicyDefinition | Policy, seeds: Sequence[int],
                  record: bool = True) -> list[_Task]:
    """One task per seed. On recorded scenes each task names only the file its scene is in
    and the scene's index there (the seed stays the run's): a worker lists and reads the
    files of the scenes it runs, not every file of the run, so a run over many files
    shards by file on a cluster, and the tables are the same as one env over all files."""
    if not isinstance(scenario, WomdScenes):
        return [_Task(scenario, spec, int(seed), record) for seed in seeds]
    from tap_bench.sim.womd_scene import scene_catalog

    catalog = scenario.catalog()
    tasks = []
    local: dict[str, tuple[WomdScenes, dict]] = {}
    for seed in seeds:
        ref = catalog[seed]
        if ref.path not in local:
            with warnings.catch_warnings():  # said once already, listing the whole run
                warnings.simplefilter("ignore")
                refs = scene_catalog([ref.path])
            one_file = WomdScenes((ref.path,), scenario.traffic, scenario.ego,
                                  scenario.policy_frequency, scenario.name, scenario.config)
            local[ref.path] = (one_file, {r: i for i, r in enumerate(refs)})
        one_file, index = local[ref.path]
        tasks.append(_Task(one_file, spec, int(seed), record, index[ref]))
    return tasks


def resolve_scenario(env: str | os.PathLike | Scenario | WomdScenes | gym.Env, *,
                     config: Mapping[str, Any] | None = None, duration: float | None = None,
                     lane_change: str | None = None) -> Scenario:
    """The :class:`Scenario` that ``env`` names, with the overrides applied.

    Args:
        env: scenario name, Gymnasium id, scenario file, :class:`Scenario` or scenario env.
        config, duration, lane_change: as :func:`rollout`.
    """
    import gymnasium as gym

    from tap_bench.sim.scenario_env import find_scenario_env

    if isinstance(env, WomdScenes):
        return env.with_overrides(config) if config else env
    if isinstance(env, gym.Env):
        scenario = find_scenario_env(env).scenario
    else:
        scenario = get_scenario(env)
    if config or duration is not None or lane_change is not None:
        scenario = scenario.with_overrides(config, duration=duration, lane_change=lane_change)
    return scenario


def resolve_policy(policy: str | os.PathLike | Policy | PolicyDefinition
                   ) -> Policy | PolicyDefinition:
    """A policy object as given, or the definition a name or file names, built once here
    so that a bad definition fails at once rather than in every worker."""
    if isinstance(policy, Policy | PolicyDefinition):
        spec = policy
    else:
        spec = get_definition(os.fspath(policy) if isinstance(policy, os.PathLike) else policy)
    if isinstance(spec, PolicyDefinition):
        spec.build()
    return spec


def collect_rollout(tables: Sequence[pd.DataFrame], episodes: pd.DataFrame, *,
                    stacklevel: int = 2) -> Rollout:
    """Assemble a :class:`Rollout` from per-episode trajectory tables (empty for failed
    episodes) and the episode table, warning once about the failed episodes.

    For other ways of running episodes (other executors) that must return what
    :func:`rollout` returns.

    Raises:
        EpisodesFailedError: every episode failed: an empty result would only hide why.
    """
    import numpy as np
    import pandas as pd

    episodes = episodes.reset_index(drop=True)
    episodes["seed"] = episodes["seed"].astype(np.int64)
    failed = episodes[~episodes["status"].isin(("ok", "skipped"))]
    skipped = episodes[episodes["status"] == "skipped"]
    if len(skipped):  # recorded scenes without a route: not failures, said apart
        listed = "; ".join(f"seed {r.seed}: {r.error}" for r in skipped.head(3).itertuples())
        warnings.warn(f"{len(skipped)} of {len(episodes)} episodes of "
                      f"{skipped.iloc[0]['policy']} skipped: no route to follow ({listed}).",
                      EpisodeFailedWarning, stacklevel=stacklevel)
    if len(failed) and len(failed) == len(episodes):
        first = failed.iloc[0]
        raise EpisodesFailedError(
            f"{len(episodes)} episode(s) of {first['policy']} on {first['env']}",
            [f"seed {r.seed}: {r.error}" for r in failed.itertuples()])
    if len(failed):
        first = failed.iloc[0]
        listed = "; ".join(f"seed {r.seed}: {r.error}" for r in failed.head(3).itertuples())
        warnings.warn(f"{len(failed)} of {len(episodes)} episodes of {first['policy']} on "
                      f"{first['env']} failed and were left out of the trajectory table "
                      f"({listed}). The episode table lists them.", EpisodeFailedWarning,
                      stacklevel=stacklevel)
    if "map" in episodes.columns:  # recorded scenes: one line for all their maps
        from tap_bench.sim.womd_env import MapWarning, map_summary

        summary = map_summary(episodes["map"].tolist())
        if summary is not None:
            warnings.warn(summary[0].upper() + summary[1:] + ".", MapWarning,
                          stacklevel=stacklevel)
    kept = [t for t in tables if len(t)]
    trajectories = pd.concat(kept, ignore_index=True) if kept else pd.DataFrame()
    return Rollout(trajectories, episodes)


def check_policy(policy: str | os.PathLike | Policy | PolicyDefinition,
                 scenario: str | os.PathLike | Scenario = "highway", *, seed: int = 0,
                 duration: float = 2.0) -> pd.DataFrame:
    """Check a policy as Gymnasium's ``check_env`` checks an env: it builds, has a name,
    drives two short episodes of ``scenario`` on the same seed without an error, and drives
    them the same way (a policy must be seeded by ``reset(env, seed=...)``).

    Args:
        policy: a policy name, definition file, definition or object.
        scenario: the scenario it drives (a short episode of it).
        seed: the seed of both episodes.
        duration: the episodes' length [s].

    Returns:
        the first episode's trajectory table.

    Raises:
        RegistrationError: naming the policy and what is wrong.
    """
    if isinstance(policy, str | os.PathLike | PolicyDefinition):
        spec = resolve_policy(policy)
    else:
        spec = policy  # checked as it is
    built = spec.build() if isinstance(spec, PolicyDefinition) else spec
    name = getattr(built, "name", None)
    if not isinstance(built, Policy) or not isinstance(name, str) or not name:
        raise RegistrationError(f"policy {policy!r} builds {type(built).__name__}, not a Policy: "
                                "it needs a non-empty name, observation (a config or None), "
                                "reset(env, *, seed) and act(observation).")
    short = resolve_scenario(scenario, duration=duration)
    runs = []
    for _ in range(2):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            trajectories, row = rollout_episode(short, spec, seed)
        if row["status"] != "ok":
            raise RegistrationError(f"policy {name!r} failed an episode of {short.name} "
                                    f"(seed {seed}): {row['error']}")
        runs.append(trajectories.reset_index(drop=True))
    if not runs[0].equals(runs[1]):
        raise RegistrationError(f"policy {name!r} drove seed {seed} of {short.name} two "
                                "different ways: seed its randomness in reset(env, seed=...) "
                                "so that a seed gives one episode.")
    return runs[0]
