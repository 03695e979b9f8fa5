"""The episodes step of a suite run: every task run on the backend
(:mod:`tap_bench.bench.run.tasks`; each env's road drawn once, for its tasks, what the
episode cache holds read first, a run of recorded scenes counted in one progress line as
its results arrive), the results
gathered into the run's tables (on disk for recorded scenes: :mod:`tap_bench.bench.run.
spill`) and checked, then each env's map kept for the run folder (part of
:mod:`tap_bench.bench.run.runner`)."""

from __future__ import annotations

import contextlib
import io
import os
import time
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from tap_bench.bench.cache import (
    EpisodeCache,
    memoised,
    scenario_fingerprint,
    simulation_fingerprint,
)
from tap_bench.bench.run.estimate import RunPlan
from tap_bench.bench.run.plan import _Task
from tap_bench.bench.run.spill import RunSpill, SpilledTable
from tap_bench.bench.run.tasks import (
    LABEL_TABLES,
    RunTables,
    _run_all,
    cache_facts,
    check_results,
    observed_timings,
)
from tap_bench.execution import Backend
from tap_bench.sim.scenario_format import Scenario
from tap_bench.sim.womd_scene import WomdScenes

__all__ = ["RunEpisodes", "run_episodes"]


class _Roads:
    """Each env's map table, drawn (or read from the cache) once in this run: the workers
    label on it and the run folder keeps it. A highway-env road is kept in the cache, keyed
    by the scenario and the simulation code, so that a re-run does not import highway-env
    to draw it again; recorded scenes' maps are read from their files."""

    def __init__(self, scenarios: Mapping[str, Scenario | WomdScenes],
                 cache: EpisodeCache | None) -> None:
        self.scenarios = scenarios
        self.cache = cache
        self.drawn: dict[str, pd.DataFrame] = {}
        self.simulation: dict[str, Any] | None = None  # the code's fingerprint, once

    def __call__(self, env: str) -> pd.DataFrame:
        if env not in self.drawn:
            self.drawn[env] = self._draw(env)
        return self.drawn[env]

    def _draw(self, env: str) -> pd.DataFrame:
        scenario = self.scenarios[env]
        if isinstance(scenario, WomdScenes):
            from tap_bench.sources.maps import read_maps

            return read_maps(scenario.files)
        from tap_bench.sim.roads import road_table

        fingerprint = None if self.cache is None else scenario_fingerprint(scenario, env)
        if fingerprint is None:
            return road_table(scenario)
        if self.simulation is None:
            self.simulation = simulation_fingerprint()
        return memoised(self.cache, "roads", {"env": fingerprint,
                                              "simulation": self.simulation},
                        lambda: road_table(scenario), _table_files, _files_table)

    def kept(self, envs: Sequence[str], spill: RunSpill | None
             ) -> pd.DataFrame | SpilledTable:
        """The map tables of ``envs`` for the run folder: one table, or (a spilled run)
        written to the spill's parts, a recorded scene's map at a time (the same rows). A
        highway-env road that cannot be drawn is left out: its env's episodes failed on it
        and name the error (:func:`~tap_bench.bench.run.tasks._with_roads`)."""
        tables = (table for env in envs for table in self._tables(env))  # one at a time
        if spill is None:
            return pd.concat(list(tables), ignore_index=True)
        return spill.keep_maps(tables)

    def _tables(self, env: str) -> Iterator[pd.DataFrame]:
        scenario = self.scenarios[env]
        if isinstance(scenario, WomdScenes) and env not in self.drawn:
            from tap_bench.sources.maps import iter_maps

            yield from iter_maps(scenario.files)
            return
        try:
            table = self(env)
        except Exception:  # the episodes failed on it and say why
            return
        yield table


def _rollouts(tasks: list[_Task], name: str, backend: Backend, progress: bool | None,
              cache: EpisodeCache | None, announce: Callable[[str], None] | None,
              road: Callable[[str], pd.DataFrame] | None = None,
              keep_result: Callable[[int, dict[str, Any]], dict[str, Any]] | None = None,
              log: str | os.PathLike | None = None) -> tuple[list[dict[str, Any]], RunPlan]:
    """Every episode of ``tasks`` (the suite ``name``'s, :func:`~tap_bench.bench.run.plan.
    _tasks`) as a task on ``backend`` (one recovery rule: an episode whose worker died is
    tried once more, then recorded as failed), cached episodes read rather than simulated.
    Before the tasks start, ``announce`` gets the run's estimate, from the cache's timings
    or from a first episode of each env without one. ``road``: env -> its highway-env road
    as a map table, drawn here once for the envs with episodes to label and handed to their
    tasks (None: each worker draws it). ``keep_result``: (task index, result) -> the result
    kept, called on each result as it arrives (a :class:`~tap_bench.bench.run.spill.
    RunSpill` writes its tables to disk and keeps the rest), the tasks' results then taken
    one by one as they end rather than all at once, and counted in one progress line
    (episodes done, failed, skipped, rate, time left: :class:`~tap_bench.progress.
    SceneProgress`) on stderr unless ``progress`` is False and in the file ``log``."""
    streamed = keep_result is not None
    lines = None
    if streamed:
        from tap_bench.progress import SceneProgress

        lines = SceneProgress(len(tasks), f"bench {name}", show=progress is not False,
                              log=log, unit="episode")
        keep_result = _counted(keep_result, lines)
        progress = False  # the lines instead of a bar of tasks
    else:
        if log:
            warnings.warn(f"{log}: not written: the progress lines of a log are those of a "
                          "suite of recorded scenes; this suite's run shows a progress bar "
                          "instead", stacklevel=2)
        keep_result = lambda _, result: result  # noqa: E731
    try:
        # what the cache holds, in one pass: earlier runs' timings (for the estimate), the
        # episodes labelled before (read here, no worker needed), those stored
        recalled = None if cache is None else cache.recall(
            [(t.label_key, t.key, t.keep_trajectories) for t in tasks], LABEL_TABLES)
        return _run_all(tasks, name, backend, progress, recalled, announce, road, keep_result,
                        streamed)
    finally:
        if lines is not None:
            lines.close()


def _counted(keep: Callable[[int, dict[str, Any]], dict[str, Any]], lines: Any
             ) -> Callable[[int, dict[str, Any]], dict[str, Any]]:
    """``keep`` that also counts each result's episode in ``lines`` by its status."""
    def kept(index: int, result: dict[str, Any]) -> dict[str, Any]:
        episodes = result.get("episodes")
        lines.update(str(episodes["status"].iat[0]) if episodes is not None
                     and len(episodes) else "error")
        return keep(index, result)

    return kept


def _table_files(table: pd.DataFrame) -> dict[str, bytes]:
    buffer = io.BytesIO()
    table.to_parquet(buffer, index=True)
    return {"table.parquet": buffer.getvalue()}


def _files_table(files: Mapping[str, bytes]) -> pd.DataFrame:
    return pd.read_parquet(io.BytesIO(files["table.parquet"]))


@dataclass
class RunEpisodes:
    """What the episodes step of a run made.

    Attributes:
        tables: the run's tables (:class:`~tap_bench.bench.run.tasks.RunTables`).
        roads: each env's map table for the run folder (None: not kept).
        estimate: the estimate made before the episodes started.
        refused: the notes of the episode cache entries refused.
        cache: the ``cache`` part of ``summary.json`` (None: the run had no cache).
        spill: the parts on disk of a run of recorded scenes (None: held in memory).
        observed: what the run tells the next estimate (:func:`~tap_bench.bench.run.
            tasks.observed_timings`): mean seconds per episode by env, simulated and
            cached, and the wall time of the episodes' work [s].
    """

    tables: RunTables
    roads: pd.DataFrame | SpilledTable | None
    estimate: RunPlan
    refused: list[str]
    cache: dict[str, Any] | None
    spill: RunSpill | None
    observed: tuple[dict[str, float], dict[str, float], float]


def run_episodes(tasks: list[_Task], name: str, scenarios: Mapping[str, Scenario | WomdScenes],
                 output: Path, *, backend: Backend, cache: EpisodeCache | None,
                 recorded: bool, keep_tables: bool, keep_maps: bool, progress: bool | None,
                 announce: Callable[[str], None] | None, log: Any,
                 timings: dict[str, float]) -> RunEpisodes:
    """Run every task of the suite ``name`` on ``backend`` and gather their tables.

    Args:
        tasks: the run's tasks (:func:`tap_bench.bench.run.plan._tasks`).
        name: the suite's name (progress, errors).
        scenarios: env -> its scenario or recorded scenes, in the suite's order.
        output: the run folder (a run of recorded scenes spills its tables beside it).
        recorded: some env is recorded scenes (the plan's :attr:`~tap_bench.bench.run.
            plan.SuitePlan.recorded`): each episode's tables go to disk as its result
            arrives (:mod:`tap_bench.bench.run.spill`).
        backend: runs the tasks.
        cache: the episode cache (None: none).
        keep_tables: keep each episode's trajectories.
        keep_maps: keep each env's map table for the run folder's replay viewer.
        progress, announce, log: as :func:`~tap_bench.bench.run.runner.run_suite`.
        timings: the wall time of the rollouts [s] goes to ``timings["rollouts_wall"]``,
            the workers' CPU per stage beside it.

    Raises:
        EpisodesFailedError: every episode failed.
    """
    roads = _Roads(scenarios, cache)
    spill = RunSpill(output) if recorded else None
    t0 = time.perf_counter()
    kept = getattr(backend, "kept", None)  # the estimate's first episodes and the rest
    with kept() if kept is not None else contextlib.nullcontext():  # on the same workers
        results, estimate = _rollouts(tasks, name, backend, progress, cache, announce,
                                      roads, None if spill is None else spill.keep, log)
    timings["rollouts_wall"] = time.perf_counter() - t0
    tables = RunTables.of(results, keep_tables, timings, spill)
    refused = check_results(results, tables.episodes, name)
    facts = cache_facts(cache, results, refused)
    observed = observed_timings(results, backend.workers)
    # the maps for the run folder (the replay viewer draws them, tap-bench label reads
    # them), every env's, once some episode ran: a road the rollouts drew is not drawn
    # again (highway-env's road is seed-free); recorded scenes' are read from their files
    maps = roads.kept(list(scenarios), spill) if keep_maps else None
    return RunEpisodes(tables, maps, estimate, refused, facts, spill, observed)
