"""The episodes of a suite run as tasks of :mod:`tap_bench.execution` (local worker processes
or Ray): episodes of one env and policy in batches, each episode rolled out (or read from
the episode cache) and the batch labelled and measured as one table in a worker (part of
:mod:`tap_bench.bench.run.runner`)."""

from __future__ import annotations

import contextlib
import math
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pandas as pd

from tap_bench.bench.cache import (
    EpisodeCache,
    Recalled,
    policy_fingerprint,
    scenario_fingerprint,
)
from tap_bench.bench.episodes import episode_table
from tap_bench.bench.measures import MEASURES, ego_steps
from tap_bench.bench.run.estimate import RunPlan, estimate
from tap_bench.bench.run.plan import _Task
from tap_bench.bench.run.spill import RunSpill, SpilledTable
from tap_bench.bench.scores.contexts import occurrences_from
from tap_bench.errors import (
    CacheEntryWarning,
    EpisodesFailedError,
    RegistrationError,
    warn_caller,
)
from tap_bench.execution import Backend
from tap_bench.labelling import tap
from tap_bench.pathframe import LaneMap
from tap_bench.sim.rollout import EPISODE_COLUMNS, RECORDED_CRASH_COLUMNS, rollout_episode
from tap_bench.sim.womd_scene import WomdScenes
from tap_bench.usercode import loaded_user_code, recording

_ROADS: dict[str, pd.DataFrame] = {}
"""Per process: each scenario's road as a map table (highway-env builds the same road for
every seed, so one per scenario serves all its episodes)."""
_SCENE_LANES: dict[tuple[tuple[str, ...], str], pd.DataFrame] = {}
"""Per process: the lanes of each recorded scene read so far, by (files, WOMD scenario id)
(every policy of a run drives the same scenes; at most :data:`SCENE_LANES_KEPT` kept)."""
SCENE_LANES_KEPT = 256


def _road(task: _Task, trajectories: pd.DataFrame) -> pd.DataFrame | None:
    """The map table the episodes of ``task``'s env are labelled and measured on, so that an
    ego's path goes on along its lane beyond the end of its record (SPEC 7) rather than
    along an arc: for a highway-env scenario the lanes of its road
    (:func:`tap_bench.sim.roads.road_table`) under the ``map_id`` of the episodes' ``env``;
    for recorded scenes the lanes of each scene's own map (:func:`_scene_lanes`). None for
    tables without an ``env`` column (not a rollout)."""
    if "env" not in trajectories.columns:
        return None
    if isinstance(task.scenario, WomdScenes):
        return _scene_lanes(task.scenario, trajectories)
    if task.road is not None:  # drawn once by the run's process
        return task.road.assign(map_id=str(trajectories["env"].iat[0]))
    key = repr(task.scenario)
    if key not in _ROADS:
        from tap_bench.sim.roads import road_table

        _ROADS[key] = road_table(task.scenario)
    return _ROADS[key].assign(map_id=str(trajectories["env"].iat[0]))


def _scene_lanes(scenes: WomdScenes, trajectories: pd.DataFrame) -> pd.DataFrame | None:
    """The lane centre lines of each recorded scene of ``trajectories`` (each scene's record
    read alone with :func:`tap_bench.sources.maps.read_scene_maps`, the map the viewer
    draws), under the ``map_id`` of the episode's ``scenario_id`` in the run (``<WOMD
    id>/<policy>``, :func:`_run_ids`): :func:`tap_bench.pathframe.scene_lanes` then gives
    each episode its scene's lanes. None when the table has no ``womd_scenario_id``."""
    if "womd_scenario_id" not in trajectories.columns:
        return None
    columns = ["womd_scenario_id", "scenario_id"]
    pairs = trajectories[[*columns, *(["seed"] if "seed" in trajectories.columns else [])]
                         ].drop_duplicates(columns)
    womd = pairs["womd_scenario_id"].astype(str).tolist()
    missing = {w for w in womd if (scenes.files, w) not in _SCENE_LANES}
    if missing:
        maps = _missing_maps(scenes, pairs, missing)
        lanes = maps[maps["kind"] == "lane"]
        by_scene = dict(tuple(lanes.groupby("map_id", sort=False)))
        needed = {(scenes.files, w) for w in womd}
        spare = [key for key in _SCENE_LANES if key not in needed]  # oldest first
        for key in spare[:max(0, len(_SCENE_LANES) + len(missing) - SCENE_LANES_KEPT)]:
            del _SCENE_LANES[key]
        for w in missing:
            _SCENE_LANES[(scenes.files, w)] = by_scene.get(w, lanes.iloc[:0])
    return pd.concat([_SCENE_LANES[(scenes.files, w)].assign(map_id=str(sid))
                      for w, sid in zip(womd, pairs["scenario_id"], strict=True)],
                     ignore_index=True)


def _missing_maps(scenes: WomdScenes, pairs: pd.DataFrame, missing: set[str]
                  ) -> pd.DataFrame:
    """The map table of the scenes ``missing`` (WOMD ids): each scene's record read alone,
    found by its episode's seed (its index in the scenes' catalogue, as the env resets on
    it); the files read through when a table has no seeds or a seed's record is another
    scene."""
    from tap_bench.sources.maps import read_maps, read_scene_maps

    if "seed" in pairs.columns:
        catalog = scenes.catalog()
        seeds = sorted({int(seed) % len(catalog) for w, seed in zip(
            pairs["womd_scenario_id"].astype(str), pairs["seed"], strict=True)
            if w in missing})
        maps = read_scene_maps([catalog[seed] for seed in seeds])
        if set(maps["map_id"].astype(str)) == missing:  # else: a seed named another scene
            return maps
    return read_maps(scenes.files, scenario_ids=missing)


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


def _episode(task: _Task, note: str | None = None
             ) -> tuple[pd.DataFrame, dict[str, Any], bool, float, str | None]:
    """One episode of ``task``: (trajectories, its row of the rollout table, whether it was
    read from the cache, seconds it took, why a cache entry of it was refused), read from
    the cache or simulated (in a worker). ``note``: why an entry was refused already."""
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
        if (row["status"] == "ok" and task.cache is not None and task.key
                and _key_holds(task)):
            with contextlib.suppress(OSError):  # a full or read-only cache costs only reuse
                task.cache.put(task.key, task.key_doc or {}, trajectories, row,
                               time.perf_counter() - t0, loaded_user_code(task.run))
    return (_run_ids(task, trajectories).reset_index(drop=True), row, cached is not None,
            time.perf_counter() - t0, note)


def _key_holds(task: _Task) -> bool:
    """Whether the policy's files (its definition, model, module) and the env's (its
    scenario file, the files it names, its user vehicle classes) still hash as when the
    episode's key was made at the start of the run. A model or policy module changed while
    the run went on may have been loaded by the worker after the change: the episode was
    then made by other content than its key names, so neither it nor its labels are kept
    (the next run makes them again under the new content's key). A fingerprint that cannot
    be taken now (a file removed or unreadable) does not hold: it costs only reuse."""
    doc = task.key_doc or {}
    try:
        if "policy" in doc and policy_fingerprint(task.definition) != doc["policy"]:
            return False
        # a synthetic env's files and user vehicle classes (imported by a worker at its
        # first episode); a recorded scene's content is read whole when the key is made
        return ("env" not in doc or isinstance(task.scenario, WomdScenes)
                or scenario_fingerprint(task.scenario, task.env) == doc["env"])
    except Exception:  # files unreadable now: not known to hold; the episode is kept
        return False   # in the results, only not in the cache


LABEL_TABLES = ("episodes", "labels", "segments", "contexts")
"""An episode's tables kept beside it in the cache (:meth:`EpisodeCache.put_labels`): its
row of the episode table (measures included), its labels at every level, its segments at
the suite's level and its interaction-context occurrences
(:func:`~tap_bench.bench.scores.contexts.occurrences_from`)."""


def _store_labels(task: _Task, eps: pd.DataFrame, labels: pd.DataFrame,
                  segments: pd.DataFrame, contexts: pd.DataFrame) -> None:
    """Keep one episode's labels and measures in the cache, so that a re-run only scores."""
    if task.cache is None or not task.label_key or not _key_holds(task):
        return
    with contextlib.suppress(OSError):  # a full or read-only cache costs only reuse
        task.cache.put_labels(task.label_key, task.label_doc or {},
                              dict(zip(LABEL_TABLES, (eps, labels, segments, contexts),
                                       strict=True)), loaded_user_code(task.run))


def _labelled_result(task: _Task, tables: Mapping[str, pd.DataFrame],
                     trajectories: pd.DataFrame | None, seconds: float) -> dict[str, Any]:
    """One episode's result from what the cache held of it whole (its label entry's
    ``tables`` and, when the run keeps them, its ``trajectories``; ``seconds`` the reading
    took): equal to what :func:`_run_task` gives."""
    return {"episodes": tables["episodes"], "labels": tables["labels"],
            "segments": tables["segments"], "contexts": tables["contexts"],
            "trajectories": None if trajectories is None
            else _run_ids(task, trajectories).reset_index(drop=True),
            "timings": {"rollout": seconds}, "cached": True,
            "labels_cached": True, "cache_note": None}


def _run_ids(task: _Task, trajectories: pd.DataFrame) -> pd.DataFrame:
    """A recorded scene's episode under an id of its own in the run: every policy drives the
    same WOMD scenario, so its id becomes ``<WOMD id>/<policy>`` (the WOMD id kept in
    ``womd_scenario_id``); synthetic episodes' ids already name the policy."""
    if not isinstance(task.scenario, WomdScenes) or not len(trajectories):
        return trajectories
    womd = trajectories["scenario_id"].astype(str)
    return trajectories.assign(scenario_id=womd + "/" + task.policy, womd_scenario_id=womd)


def _rows(rows: list[dict[str, Any]]) -> pd.DataFrame:
    # a recorded scene's collision partner and fault go with its row (the report names them)
    extra = [c for c in RECORDED_CRASH_COLUMNS if any(c in row for row in rows)]
    episodes = pd.DataFrame(rows, columns=[*EPISODE_COLUMNS, *extra])
    episodes["seed"] = episodes["seed"].astype(np.int64)
    return episodes


def _label_together(tasks: tuple[_Task, ...],
                    got: list[tuple[pd.DataFrame, dict[str, Any], bool, float, str | None]]
                    ) -> list[dict[str, Any]]:
    """Label and measure the episodes ``got`` of ``tasks`` (one env and policy) as one
    table: one TAP call and one call of the measures for all of them, split back into one
    result per task. TAP and the measures treat each episode (its scenario_id) on its own,
    so each result is the one the episode gives alone (tested), at the cost of about one
    call (``tap`` costs mostly per call on small tables) instead of one per episode."""
    first = tasks[0]
    with_rows = [k for k, (trajectories, *_) in enumerate(got) if len(trajectories)]
    results: list[dict[str, Any]] = [{} for _ in tasks]
    labels = segments = eps = None
    if with_rows:
        t1 = time.perf_counter()
        trajectories = (pd.concat([got[k][0] for k in with_rows], ignore_index=True)
                        if len(with_rows) > 1 else got[with_rows[0]][0])
        road = _road(first, trajectories)
        # one lane map for the batch: the interaction axis and the measures share its lane
        # matches and chains (each path end is searched once, not once a call)
        lanes = None if road is None else LaneMap.of_maps(road)
        source = f"{first.env}/{first.policy} rollout"
        result = tap(trajectories, first.thresholds, interactions="ego", source=source,
                     map_table=lanes)
        labels, segments = result.labels("all"), result.segments(first.level)
        t2 = time.perf_counter()
        steps = ego_steps(trajectories, lanes)  # the measures' and the contexts'
        eps = episode_table(labels=labels if len(labels) else None, trajectories=trajectories,
                            episodes=_rows([got[k][1] for k in with_rows]),
                            level=first.level, policy=first.policy, map_table=lanes,
                            steps=steps)
        contexts = occurrences_from(result.segments("trend"), steps, trajectories,
                                    first.thresholds, source=source)
        t3 = time.perf_counter()
        share = {"labelling": (t2 - t1) / len(with_rows),
                 "measures": (t3 - t2) / len(with_rows)}
        # one episode's rows, in the order its own tap and episode_table calls give them
        by_episode = {name: _split(table, "scenario_id")
                      for name, table in (("labels", labels), ("segments", segments),
                                          ("contexts", contexts))}
        eps_by_seed = _split(eps, "seed")
        for k in with_rows:
            episode_trajectories, row, cached, seconds, note = got[k]
            sid = episode_trajectories["scenario_id"].iat[0]
            mine = {"episodes": eps_by_seed[tasks[k].seed],
                    "labels": by_episode["labels"].get(sid, _empty(labels)),
                    "segments": by_episode["segments"].get(sid, _empty(segments)),
                    "contexts": by_episode["contexts"].get(sid, _empty(contexts))}
            if row["status"] == "ok":
                _store_labels(tasks[k], mine["episodes"], mine["labels"], mine["segments"],
                              mine["contexts"])
            results[k] = {
                **mine,
                "trajectories": episode_trajectories if tasks[k].keep_trajectories else None,
                "timings": {"rollout": seconds, **share}, "cached": cached,
                "cache_note": note}
    for k, (_, row, cached, seconds, note) in enumerate(got):
        if k not in with_rows:  # nothing to label (a failed rollout)
            t2 = time.perf_counter()
            eps = episode_table(episodes=_rows([row]), level=tasks[k].level,
                                policy=tasks[k].policy)
            results[k] = {"episodes": eps, "labels": pd.DataFrame(),
                          "segments": pd.DataFrame(), "contexts": pd.DataFrame(),
                          "trajectories": None,
                          "timings": {"rollout": seconds,
                                      "measures": time.perf_counter() - t2},
                          "cached": cached, "cache_note": note}
    return results


def _empty(table: pd.DataFrame) -> pd.DataFrame:
    return table.iloc[:0].reset_index(drop=True)


def _run_task(task: _Task, note: str | None = None) -> dict[str, Any]:
    """Roll out (or read from the cache), label and measure one episode (in a worker).
    ``note``: why a cache entry of this episode was refused already."""
    _prepare_worker(task)
    with recording(task.run):  # what the policy and measures load (kept with each entry)
        return _label_together((task,), [_episode(task, note)])[0]


def _failed_task(task: _Task, message: str) -> dict[str, Any]:
    eps = pd.DataFrame({"env": [task.env], "policy": [task.policy], "seed": [task.seed],
                        "status": ["error"], "error": [message]})
    return {"episodes": episode_table(episodes=eps, level=task.level),
            "labels": pd.DataFrame(), "segments": pd.DataFrame(), "contexts": pd.DataFrame(),
            "trajectories": None,
            "timings": {}, "cached": False}


CACHED_BATCH = 30
"""Most episodes of one env and policy in one task (:class:`_Batch`). Cached ones are
batched up to this many: reading them costs little beside labelling."""
BATCHES_PER_WORKER = 4
"""Episodes to simulate are batched so that each worker gets about this many tasks (fewer
tasks, fewer TAP calls; enough of them to keep every worker busy to the end)."""
IN_PROCESS_BATCH = 4
"""Fewest episodes to simulate in one task of a run in this process (one worker), where
no other worker is kept busy by smaller tasks: TAP and the measures cost mostly per call
on small tables, so a run of a few seeds labels each env and policy in one call, not one
call per episode, and a long run still reports progress every few episodes."""
RECORDED_BATCH = 4
"""Most episodes of recorded scenes in one task, cached or not: a scene's tables are
thousands of rows (one TAP call costs little beside them), and a batch's results are held
whole in its worker and in the run's process until they are written, so a batch that grew
with the run's scenes would make the run's memory grow with them."""


@dataclass(frozen=True)
class _Batch:
    """Episodes of one env and policy (``tasks``), each read from the cache or simulated
    (or, in ``given``, simulated already: what :func:`_episode` gave, e.g. for the run's
    estimate), then labelled and measured together in one worker call
    (:func:`_label_together`)."""

    tasks: tuple[_Task, ...]
    given: tuple[Any, ...] = ()  # per task: its _episode() value, or None


def _run_batch(batch: _Batch) -> list[dict[str, Any]]:
    """One result per task of ``batch``, equal to what :func:`_run_task` gives for each."""
    _prepare_worker(batch.tasks[0])
    given = batch.given or (None,) * len(batch.tasks)
    with recording(batch.tasks[0].run):
        return _label_together(batch.tasks, [_episode(task) if got is None else got
                                             for task, got in zip(batch.tasks, given,
                                                                  strict=True)])


def _simulate(task: _Task) -> tuple[pd.DataFrame, dict[str, Any], bool, float, str | None]:
    """One episode of ``task`` simulated (or read), not yet labelled: the run's first
    episode of an env, timed for the estimate, is then labelled with its batch."""
    _prepare_worker(task)
    with recording(task.run):
        return _episode(task)


def _split(table: pd.DataFrame, column: str) -> dict[Any, pd.DataFrame]:
    """``table``'s rows by value of ``column``, each in table order with a fresh index."""
    return {key: part.reset_index(drop=True)
            for key, part in table.groupby(column, sort=False, observed=True)}


def _run_item(item: _Task | _Batch) -> list[dict[str, Any]]:
    """A task of the backend: one episode, or a batch of them."""
    return _run_batch(item) if isinstance(item, _Batch) else [_run_task(item)]


def _items(tasks: list[_Task], indices: list[int], cached: list[bool], workers: int = 1,
           given: Mapping[int, Any] | None = None
           ) -> list[tuple[list[int], _Task | _Batch]]:
    """The work items of ``tasks[indices]``: the episodes of one env and policy in batches,
    cached ones up to :data:`CACHED_BATCH` a batch, ones to simulate in batches small
    enough to give each worker about :data:`BATCHES_PER_WORKER` tasks (in this process, at
    least :data:`IN_PROCESS_BATCH` a batch); recorded scenes'
    at most :data:`RECORDED_BATCH` a batch. ``given``: episodes
    simulated already (index -> :func:`_episode`'s value), batched with those to simulate."""
    given = given or {}
    to_simulate = sum(not cached[i] for i in indices)
    per_worker = math.ceil(to_simulate / (BATCHES_PER_WORKER * max(1, workers)))
    fewest = IN_PROCESS_BATCH if workers <= 1 else 1
    size = {True: CACHED_BATCH, False: max(1, min(CACHED_BATCH, max(fewest, per_worker)))}
    groups: dict[tuple[str, str, bool], list[int]] = {}
    for i in indices:
        groups.setdefault((tasks[i].env, tasks[i].policy, cached[i]), []).append(i)
    items: list[tuple[list[int], _Task | _Batch]] = []
    for (_, _, hit), members in groups.items():
        most = (min(size[hit], RECORDED_BATCH)
                if isinstance(tasks[members[0]].scenario, WomdScenes) else size[hit])
        for start in range(0, len(members), most):
            chunk = members[start:start + most]
            got = tuple(given.get(i) for i in chunk) if any(i in given for i in chunk) else ()
            items.append((chunk, _Batch(tuple(tasks[i] for i in chunk), got)
                          if len(chunk) > 1 or got else tasks[chunk[0]]))
    return items


def _run_all(tasks: list[_Task], name: str, backend: Backend, progress: bool | None,
             recalled: Recalled | None, announce: Callable[[str], None] | None,
             road: Callable[[str], pd.DataFrame] | None,
             keep_result: Callable[[int, dict[str, Any]], dict[str, Any]], streamed: bool
             ) -> tuple[list[dict[str, Any]], RunPlan]:
    """The tasks run (:func:`~tap_bench.bench.run.episodes._rollouts` once its progress is set
    up and the cache read): ``streamed``, the results taken one
    by one as they end (``backend.imap``). In steps: what the cache holds taken (earlier
    runs' timings, the labelled episodes as results, which are cached), each env's road
    handed to its tasks, a first episode of each env the cache has no timing of
    simulated for the estimate, the estimate announced, the other episodes run."""
    done = _Done(keep_result)
    known = {} if recalled is None else recalled.timings
    notes = {} if recalled is None else done.take_labelled(tasks, recalled)
    cached = [False] * len(tasks) if recalled is None else recalled.stored
    if road is not None:
        tasks = _with_roads(tasks, done.results, road)
    probes = _probes(tasks, cached, known) if announce is not None else []  # no one to tell
    given, measured = done.timed_first(tasks, probes, backend, announce)
    plan = estimate(tasks, cached, backend.workers, known, measured)
    if announce is not None:
        announce(plan.describe(name))
    done.run_items(tasks, _items(tasks, [i for i in range(len(tasks)) if i not in done.results],
                                 cached, backend.workers, given),
                   backend, progress, f"bench {name} ({backend.name})", streamed)
    out = [done.results[i] for i in range(len(tasks))]
    for i, result in enumerate(out):
        result["seconds"] = done.seconds[i]
        result["env"] = tasks[i].env
        if i in notes and not result.get("cache_note"):
            result["cache_note"] = notes[i]
    return out, plan


def _probes(tasks: list[_Task], cached: list[bool], known: Mapping[str, Any]) -> list[int]:
    """The tasks timed for the estimate: the first episode to simulate of each env that the
    cache's timings (``known``) do not hold."""
    probes, seen = [], set(known.get("simulated", {}))
    for i, (task, hit) in enumerate(zip(tasks, cached, strict=True)):
        if not hit and task.env not in seen:
            probes.append(i)
            seen.add(task.env)
    return probes


def _with_roads(tasks: list[_Task], results: Mapping[int, Any],
                road: Callable[[str], pd.DataFrame]) -> list[_Task]:
    """``tasks``, those of synthetic envs still to run handed their env's road (``road``:
    env -> its map table, drawn once per env); an env whose road cannot be drawn here is
    drawn by its workers, which fail per episode as before."""
    drawn: dict[str, pd.DataFrame | None] = {}
    out = list(tasks)
    for i, task in enumerate(tasks):
        if i not in results and not isinstance(task.scenario, WomdScenes):
            if task.env not in drawn:
                try:
                    drawn[task.env] = road(task.env)
                except Exception:  # the workers draw it, and fail per episode as before
                    drawn[task.env] = None
            out[i] = replace(task, road=drawn[task.env])
    return out


class _Done:
    """The results of a run's tasks as they come in, by task index, each passed through
    ``keep_result`` (:func:`~tap_bench.bench.run.episodes._rollouts`), with the seconds each
    took."""

    def __init__(self, keep_result: Callable[[int, dict[str, Any]], dict[str, Any]]) -> None:
        self.keep_result = keep_result
        self.results: dict[int, dict[str, Any]] = {}
        self.seconds: dict[int, float] = {}

    def take_labelled(self, tasks: list[_Task], recalled: Recalled) -> dict[int, str]:
        """The episodes the cache held whole (``recalled``) taken as results; returns the
        notes of the entries refused, by task index."""
        for i, (tables, trajectories) in recalled.labelled.items():
            self.results[i] = self.keep_result(i, _labelled_result(
                tasks[i], tables, trajectories, recalled.seconds[i]))
            self.seconds[i] = recalled.seconds[i]
        return dict(recalled.notes)

    def timed_first(self, tasks: list[_Task], probes: list[int], backend: Backend,
                    announce: Callable[[str], None] | None
                    ) -> tuple[dict[int, Any], dict[str, float]]:
        """The ``probes`` (a first episode of each env without a timing) simulated, not yet
        labelled: (task index -> the episode, for its batch; env -> its seconds), a failed
        one's result kept."""
        given: dict[int, Any] = {}
        measured: dict[str, float] = {}
        if not probes:
            return given, measured
        if announce is not None:
            announce(f"timing a first episode of {len(probes)} env(s) for the estimate ...")
        # simulated only: each is labelled with the other episodes of its env and policy
        # (one labelling call instead of two; the same labels, as a batch gives each)
        outcomes = backend.map(_simulate, [tasks[i] for i in probes], progress=False)
        for i, outcome in zip(probes, outcomes, strict=True):
            self.seconds[i] = outcome.seconds
            if outcome.ok:
                given[i] = outcome.value
                measured[tasks[i].env] = outcome.seconds
            else:
                self.results[i] = self.keep_result(i, _failed_task(tasks[i], outcome.error))
        return given, measured

    def run_items(self, tasks: list[_Task], items: list[tuple[list[int], _Task | _Batch]],
                  backend: Backend, progress: bool | None, desc: str, streamed: bool
                  ) -> None:
        """The work ``items`` run on ``backend`` (streamed: taken as they end), in rounds:
        the episodes of a batch that failed are the next round's items, one by one (one bad
        episode does not cost the others), and recorded as failed when they fail alone."""
        each = backend.imap if streamed else backend.map
        shown = progress  # the first round's bar; a retry round runs quietly
        while items:
            outcomes = each(_run_item, [item for _, item in items], unit="task",
                            progress=shown, desc=desc)
            alone: list[tuple[list[int], _Task | _Batch]] = []
            for (indices, _), outcome in zip(items, outcomes, strict=True):
                if not outcome.ok and len(indices) > 1:
                    alone += [([i], tasks[i]) for i in indices]
                    continue
                values = outcome.value if outcome.ok else [
                    _failed_task(tasks[i], outcome.error) for i in indices]
                for i, value in zip(indices, values, strict=True):
                    self.results[i] = self.keep_result(i, value)
                    self.seconds[i] = outcome.seconds / len(indices)
            items, shown = alone, False


def result_ok(result: dict[str, Any]) -> bool:
    """Whether the episode of a task result ran: every row of its episode table has status
    ``ok`` (a spilled result says so in ``ok``, its table being on disk)."""
    if "ok" in result:
        return bool(result["ok"])
    return bool((result["episodes"]["status"] == "ok").all())


def observed_timings(results: list[dict[str, Any]], workers: int
                     ) -> tuple[dict[str, float], dict[str, float], float]:
    """What a run of these task results tells the next estimate: the mean wall time per
    episode by env [s], (simulated, cached), successful ones only, and the wall time its
    episodes' work takes on ``workers`` workers [s] (the rest of the run is overhead)."""
    simulated: dict[str, list[float]] = {}
    cached: dict[str, list[float]] = {}
    for r in results:
        if result_ok(r) and math.isfinite(r["seconds"]):
            (cached if r["cached"] else simulated).setdefault(r["env"], []).append(
                r["seconds"])
    work = sum(r["seconds"] for r in results if math.isfinite(r["seconds"]))
    return ({env: float(np.mean(v)) for env, v in simulated.items()},
            {env: float(np.mean(v)) for env, v in cached.items()},
            work / max(1, min(workers, len(results))))


def check_results(results: list[dict[str, Any]], episodes: pd.DataFrame, suite_name: str
                  ) -> list[str]:
    """The notes of the cache entries refused (each warned, the first five by name);
    ``episodes``: the run's episode table.

    Raises:
        EpisodesFailedError: every episode failed.
    """
    if not any(result_ok(r) for r in results):
        errors = [f"{row.env} {row.policy} seed {row.seed}: {row.error}"
                  for row in episodes.itertuples()]
        raise EpisodesFailedError(f"the {len(results)} episode(s) of suite {suite_name}",
                                  errors)
    refused = [r["cache_note"] for r in results if r.get("cache_note")]
    for note in refused[:5]:  # said at the user's call, whatever called this
        warn_caller(f"{note}; its episode was simulated again.", CacheEntryWarning)
    if len(refused) > 5:
        warn_caller(f"{len(refused) - 5} more cache entries refused and simulated again "
                    "(summary.json lists them all).", CacheEntryWarning)
    return refused


def cache_facts(cache: EpisodeCache | None, results: list[dict[str, Any]],
                refused: list[str]) -> dict[str, Any] | None:
    """The ``cache`` part of ``summary.json`` (None: the run had no cache)."""
    if cache is None:
        return None
    return {"dir": str(cache.root), "cached": sum(r["cached"] for r in results),
            "simulated": sum(not r["cached"] for r in results),
            "labelled_before": sum(bool(r.get("labels_cached")) for r in results),
            "refused": refused}


Spilled = pd.DataFrame | SpilledTable
"""A table of the run: in memory, or its parts on disk (:mod:`tap_bench.bench.run.spill`)."""


@dataclass(frozen=True)
class RunTables:
    """The tables of a run's episodes, gathered from the tasks' results: the episode table
    (sorted by env, policy, seed), labels, segments (None: none), the interaction contexts'
    occurrences (None: none) and the trajectories (None: not kept). Labels, segments and
    trajectories of a spilled run stay on disk (:class:`~tap_bench.bench.run.spill.
    SpilledTable`) unless read whole."""

    episodes: pd.DataFrame
    labels: Spilled
    segments: Spilled | None
    occurrences: pd.DataFrame | None
    trajectories: Spilled | None

    @classmethod
    def of(cls, results: list[dict[str, Any]], trajectories: bool,
           timings: dict[str, float], spill: RunSpill | None = None) -> RunTables:
        """Gathered from ``results``; the workers' CPU time per stage goes to ``timings``
        (``<stage>_cpu_in_workers`` [s]). With a ``spill``, the tables are read from its
        parts: the episode table and the occurrences whole (the scores need every row),
        the labels, segments and trajectories left on disk (the matching against a
        reference's scenarios reads them a few episodes at a time)."""
        for key in ("rollout", "labelling", "measures"):
            timings[f"{key}_cpu_in_workers"] = sum(r["timings"].get(key, 0.0)
                                                   for r in results)
        if spill is not None:
            return cls._spilled(spill, trajectories)
        episodes = pd.concat([r["episodes"] for r in results], ignore_index=True)
        episodes = episodes.sort_values(["env", "policy", "seed"], kind="stable")
        return cls(episodes.reset_index(drop=True),
                   _concat([r["labels"] for r in results]) if any(
                       len(r["labels"]) for r in results) else pd.DataFrame(),
                   _concat([r["segments"] for r in results]),
                   _concat([r.get("contexts", ()) for r in results]),
                   _concat([r["trajectories"] for r in results
                            if r["trajectories"] is not None]) if trajectories else None)

    @classmethod
    def _spilled(cls, spill: RunSpill, trajectories: bool) -> RunTables:
        """The tables of a spilled run (:meth:`of`)."""
        episodes = spill.table("episodes").table()
        episodes = episodes.sort_values(["env", "policy", "seed"], kind="stable")

        def kept(name: str) -> Spilled | None:
            part = spill.table(name)
            return part if len(part) else None

        return cls(episodes.reset_index(drop=True), kept("labels") if len(
                   spill.table("labels")) else pd.DataFrame(), kept("segments"),
                   spill.table("contexts").table(),
                   kept("trajectories") if trajectories else None)


def _concat(frames: Sequence[Any]) -> pd.DataFrame | None:
    """The non-empty ``frames`` as one table (None: none)."""
    frames = [f for f in frames if len(f)]
    return pd.concat(frames, ignore_index=True) if frames else None
