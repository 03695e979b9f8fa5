"""The episodes of a suite run as tasks of :mod:`tap_bench.execution` (local worker processes
or Ray): roll out (or read from the episode cache), label and measure each episode in a
worker; cached episodes of one env and policy in batches (part of
:mod:`tap_bench.bench.runner`)."""

from __future__ import annotations

import contextlib
import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from tap_bench.bench.cache import (
    EpisodeCache,
)
from tap_bench.bench.episodes import episode_table
from tap_bench.bench.measures import MEASURES
from tap_bench.bench.run_plan import RunPlan, SuitePlan, _plan, _Task, _tasks
from tap_bench.errors import RegistrationError
from tap_bench.execution import Backend
from tap_bench.labelling import tap
from tap_bench.sim.rollout import EPISODE_COLUMNS, rollout_episode
from tap_bench.sim.womd_scene import WomdScenes


def _prepare_worker(task: _Task) -> None:
    """Check that this worker has every measure the run fixed, so that no episode table
    lacks one (the execution layer has imported the run's plugins before this task).

    Raises:
        RegistrationError: a measure of the run is not registered here (naming it and the fix).
    """
    missing = [name for name in task.measures if name not in MEASURES]
    if missing:
        raise RegistrationError(
            f"measure(s) {', '.join(missing)} are registered in the process that started the "
            "run but not in this worker: register them in a module (not in __main__) and name "
            "it as a plugin (--plugin MODULE, or \"plugins\" in the suite) so that every "
            "worker imports it.")


def _run_task(task: _Task, note: str | None = None) -> dict[str, Any]:
    """Roll out (or read from the cache), label and measure one episode (in a worker).
    ``note``: why a cache entry of this episode was refused already (in a batch)."""
    _prepare_worker(task)
    t0 = time.perf_counter()
    cached = None
    if task.cache is not None and task.key:
        cached, refused = task.cache.read(task.key)
        note = note or refused
    if cached is not None:
        trajectories, row = cached.trajectories, cached.row
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            trajectories, row = rollout_episode(task.scenario, task.definition, task.seed)
        if row["status"] == "ok" and task.cache is not None and task.key:
            with contextlib.suppress(OSError):  # a full or read-only cache costs only reuse
                task.cache.put(task.key, task.key_doc or {}, trajectories, row,
                               time.perf_counter() - t0)
    trajectories = _run_ids(task, trajectories).reset_index(drop=True)
    episodes = pd.DataFrame([row], columns=list(EPISODE_COLUMNS))
    episodes["seed"] = episodes["seed"].astype(np.int64)
    t1 = time.perf_counter()
    labels = segments = pd.DataFrame()
    if len(trajectories):
        result = tap(trajectories, task.thresholds, interactions="ego",
                     source=f"{task.env}/{task.policy} rollout")
        labels = result.labels("all")
        segments = result.segments(task.level)
    t2 = time.perf_counter()
    eps = episode_table(labels=labels if len(labels) else None,
                        trajectories=trajectories if len(trajectories) else None,
                        episodes=episodes, level=task.level, policy=task.policy)
    t3 = time.perf_counter()
    if row["status"] == "ok":
        _store_labels(task, eps, labels, segments)
    timings = {"rollout": t1 - t0, "labelling": t2 - t1, "measures": t3 - t2}
    return {"episodes": eps, "labels": labels, "segments": segments,
            "trajectories": trajectories if task.keep_trajectories else None,
            "timings": timings, "cached": cached is not None, "cache_note": note}


LABEL_TABLES = ("episodes", "labels", "segments")
"""An episode's tables kept beside it in the cache (:meth:`EpisodeCache.put_labels`): its
row of the episode table (measures included), its labels at every level and its segments
at the suite's level."""


def _store_labels(task: _Task, eps: pd.DataFrame, labels: pd.DataFrame,
                  segments: pd.DataFrame) -> None:
    """Keep one episode's labels and measures in the cache, so that a re-run only scores."""
    if task.cache is None or not task.label_key:
        return
    with contextlib.suppress(OSError):  # a full or read-only cache costs only reuse
        task.cache.put_labels(task.label_key, task.label_doc or {},
                              dict(zip(LABEL_TABLES, (eps, labels, segments), strict=True)))


def _from_label_cache(task: _Task) -> dict[str, Any] | None:
    """One episode's result read whole from the cache: its labels and measures and, when the
    run keeps them, its trajectories; None when any part is missing or refused (then the
    episode goes the usual way). Equal to what :func:`_run_task` gives."""
    if task.cache is None or not task.label_key:
        return None
    t0 = time.perf_counter()
    tables, note = task.cache.read_labels(task.label_key)
    if tables is None or set(tables) != set(LABEL_TABLES):
        return None if note is None else {"cache_note": note}
    trajectories = None
    if task.keep_trajectories:
        entry, note = task.cache.read(task.key)
        if entry is None:
            return None if note is None else {"cache_note": note}
        trajectories = _run_ids(task, entry.trajectories).reset_index(drop=True)
    return {"episodes": tables["episodes"], "labels": tables["labels"],
            "segments": tables["segments"], "trajectories": trajectories,
            "timings": {"rollout": time.perf_counter() - t0}, "cached": True,
            "labels_cached": True, "cache_note": None}


def _run_ids(task: _Task, trajectories: pd.DataFrame) -> pd.DataFrame:
    """A recorded scene's episode under an id of its own in the run: every policy drives the
    same WOMD scenario, so its id becomes ``<WOMD id>/<policy>`` (the WOMD id kept in
    ``womd_scenario_id``); synthetic episodes' ids already name the policy."""
    if not isinstance(task.scenario, WomdScenes) or not len(trajectories):
        return trajectories
    womd = trajectories["scenario_id"].astype(str)
    return trajectories.assign(scenario_id=womd + "/" + task.policy, womd_scenario_id=womd)


def _failed_task(task: _Task, message: str) -> dict[str, Any]:
    eps = pd.DataFrame({"env": [task.env], "policy": [task.policy], "seed": [task.seed],
                        "status": ["error"], "error": [message]})
    return {"episodes": episode_table(episodes=eps, level=task.level),
            "labels": pd.DataFrame(), "segments": pd.DataFrame(), "trajectories": None,
            "timings": {}, "cached": False}


CACHED_BATCH = 30
"""Cached episodes of one env and policy labelled and measured together, in one task: TAP
and the measures cost mostly per call on tables of one episode (about 0.1 s each), so a
batch of 30 costs about what three single episodes do. The tables are the same."""


@dataclass(frozen=True)
class _CachedBatch:
    """Cached episodes of one env and policy (``tasks``), read, labelled and measured in
    one worker call; an entry that fails its checks is simulated there instead."""

    tasks: tuple[_Task, ...]


def _run_batch(batch: _CachedBatch) -> list[dict[str, Any]]:
    """One result per task of ``batch``, equal to what :func:`_run_task` gives for each."""
    _prepare_worker(batch.tasks[0])
    t0 = time.perf_counter()
    first = batch.tasks[0]
    read = [task.cache.read(task.key) if task.cache is not None and task.key else (None, None)
            for task in batch.tasks]
    notes = {task.seed: note for task, (_, note) in zip(batch.tasks, read, strict=True)}
    found = [(task, entry) for task, (entry, _) in zip(batch.tasks, read, strict=True)
             if entry is not None]
    results: dict[int, dict[str, Any]] = {}
    if found:
        tables = [_run_ids(task, e.trajectories) for task, e in found]
        trajectories = pd.concat(tables, ignore_index=True)
        rows = pd.DataFrame([e.row for _, e in found], columns=list(EPISODE_COLUMNS))
        rows["seed"] = rows["seed"].astype(np.int64)
        t1 = time.perf_counter()
        result = tap(trajectories, first.thresholds, interactions="ego",
                     source=f"{first.env}/{first.policy} rollout")
        labels, segments = result.labels("all"), result.segments(first.level)
        t2 = time.perf_counter()
        eps = episode_table(labels=labels, trajectories=trajectories, episodes=rows,
                            level=first.level, policy=first.policy)
        t3 = time.perf_counter()
        share = {"rollout": (t1 - t0) / len(found), "labelling": (t2 - t1) / len(found),
                 "measures": (t3 - t2) / len(found)}
        # one episode's rows, in the order its own tap and episode_table calls give them
        by_episode = {name: _split(table, "scenario_id")
                      for name, table in (("labels", labels), ("segments", segments),
                                          ("trajectories", trajectories))}
        eps_by_seed = _split(eps, "seed")
        for (task, _), table in zip(found, tables, strict=True):
            sid = table["scenario_id"].iat[0]
            mine = {"episodes": eps_by_seed[task.seed],
                    "labels": by_episode["labels"].get(sid, pd.DataFrame()),
                    "segments": by_episode["segments"].get(sid, pd.DataFrame())}
            _store_labels(task, mine["episodes"], mine["labels"], mine["segments"])
            results[task.seed] = {
                **mine,
                "trajectories": by_episode["trajectories"][sid]
                if task.keep_trajectories else None,
                "timings": dict(share), "cached": True, "cache_note": None}
    return [results.get(task.seed) or _run_task(task, notes[task.seed])
            for task in batch.tasks]


def _split(table: pd.DataFrame, column: str) -> dict[Any, pd.DataFrame]:
    """``table``'s rows by value of ``column``, each in table order with a fresh index."""
    return {key: part.reset_index(drop=True)
            for key, part in table.groupby(column, sort=False, observed=True)}


def _run_item(item: _Task | _CachedBatch) -> list[dict[str, Any]]:
    """A task of the backend: one episode, or a batch of cached ones."""
    return _run_batch(item) if isinstance(item, _CachedBatch) else [_run_task(item)]


def _items(tasks: list[_Task], indices: list[int], cached: list[bool]
           ) -> list[tuple[list[int], _Task | _CachedBatch]]:
    """The work items of ``tasks[indices]``: each episode to simulate alone, cached ones
    of one env and policy in batches of up to :data:`CACHED_BATCH`."""
    items: list[tuple[list[int], _Task | _CachedBatch]] = []
    groups: dict[tuple[str, str], list[int]] = {}
    for i in indices:
        if cached[i]:
            groups.setdefault((tasks[i].env, tasks[i].policy), []).append(i)
        else:
            items.append(([i], tasks[i]))
    for members in groups.values():
        for start in range(0, len(members), CACHED_BATCH):
            chunk = members[start:start + CACHED_BATCH]
            items.append((chunk, _CachedBatch(tuple(tasks[i] for i in chunk))))
    return items


def _rollouts(suite_plan: SuitePlan, backend: Backend, keep: bool,
              progress: bool | None, cache: EpisodeCache | None,
              announce: Callable[[str], None] | None
              ) -> tuple[list[dict[str, Any]], RunPlan]:
    """Every episode of the suite as a task on ``backend`` (one recovery rule: an episode
    whose worker died is tried once more, then recorded as failed), cached episodes read
    rather than simulated. Before the tasks start, ``announce`` gets the run's estimate,
    from the cache's timings or from a first episode of each env without one."""
    tasks = _tasks(suite_plan, keep, cache)
    suite = suite_plan.suite
    results: dict[int, dict[str, Any]] = {}
    seconds: dict[int, float] = {}
    notes: dict[int, str] = {}
    for i, task in enumerate(tasks):  # labelled before: read here, no worker needed
        t0 = time.perf_counter()
        hit = _from_label_cache(task)
        if hit is not None and "episodes" in hit:
            results[i] = hit
            seconds[i] = time.perf_counter() - t0
        elif hit is not None:
            notes[i] = hit["cache_note"]
    cached = [i in results or (cache is not None and t.key is not None
                               and cache.contains(t.key)) for i, t in enumerate(tasks)]
    known = cache.timings() if cache is not None else {}
    probes, seen = [], set(known.get("simulated", {}))
    for i, (task, hit) in enumerate(zip(tasks, cached, strict=True)):
        if announce is not None and not hit and task.env not in seen:  # no one to tell: no probe
            probes.append(i)
            seen.add(task.env)
    measured: dict[str, float] = {}
    if probes:
        if announce is not None:
            announce(f"timing a first episode of {len(probes)} env(s) for the estimate ...")
        outcomes = backend.map(_run_task, [tasks[i] for i in probes], progress=False)
        for i, outcome in zip(probes, outcomes, strict=True):
            results[i] = outcome.value if outcome.ok else _failed_task(tasks[i], outcome.error)
            seconds[i] = outcome.seconds
            if outcome.ok:
                measured[tasks[i].env] = outcome.seconds
    plan = _plan(tasks, cached, backend.workers, known, measured)
    if announce is not None:
        announce(plan.describe(suite.name))
    items = _items(tasks, [i for i in range(len(tasks)) if i not in results], cached)
    outcomes = backend.map(_run_item, [item for _, item in items], unit="task",
                           progress=progress, desc=f"bench {suite.name} ({backend.name})"
                           ) if items else []
    for (indices, _), outcome in zip(items, outcomes, strict=True):
        values = outcome.value if outcome.ok else [
            _failed_task(tasks[i], outcome.error) for i in indices]
        for i, value in zip(indices, values, strict=True):
            results[i] = value
            seconds[i] = outcome.seconds / len(indices)
    out = [results[i] for i in range(len(tasks))]
    for i, result in enumerate(out):
        result["seconds"] = seconds[i]
        result["env"] = tasks[i].env
        if i in notes and not result.get("cache_note"):
            result["cache_note"] = notes[i]
    return out, plan


def _observed_timings(results: list[dict[str, Any]]) -> tuple[dict[str, float],
                                                              dict[str, float]]:
    """Mean wall time per episode by env [s]: (simulated, cached), successful ones only."""
    simulated: dict[str, list[float]] = {}
    cached: dict[str, list[float]] = {}
    for r in results:
        if (r["episodes"]["status"] == "ok").all() and math.isfinite(r["seconds"]):
            (cached if r["cached"] else simulated).setdefault(r["env"], []).append(
                r["seconds"])
    return ({env: float(np.mean(v)) for env, v in simulated.items()},
            {env: float(np.mean(v)) for env, v in cached.items()})
