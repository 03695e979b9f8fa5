"""``bench run``: roll out every policy of a suite in every env over its seeds, label, score,
and write ``results/<run>/``.

What a run folder holds:

======================  ====================================================================
``summary.json``        suite, seeds, thresholds, level, versions, machine, timings, failed
                        episodes, the interval methods, headline figures, the run's
                        measure entries and plugins (what the report, the viewer and
                        ``bench check`` read), and the provenance: each policy's full
                        definition (with the SHA-256 of a model file) and each env's
                        resolved config
``episodes.parquet``    the episode table (:mod:`tap_bench.bench.episodes`), failed
                        episodes included with their error
``labels.parquet``      TAP labels of every track at every level
``trajectories.parquet``  the rollouts (unless ``keep_trajectories`` is False)
``segments.parquet``    the segment table (label timelines) of every track at the suite's
                        level
``roads.parquet``       each env's road network as a map table (:mod:`tap_bench.maps`), for
                        the replay viewer (with the trajectories)
``<table>.parquet``     every table of :class:`tap_bench.bench.scores.scoring.Scores`
                        (``contexts.parquet``: each policy against the reference inside
                        each interaction context, scored as ``tap-bench contexts`` does)
``plots/*.svg``         label distributions, measures, coverage, forest plots, novelty
``report.html``         the static report (no server, images embedded)
``viewer/``             the replay viewer (:mod:`~tap_bench.bench.report.viewer`; with trajectories)
``.tap-bench-folder``   the marker that lets ``--overwrite`` replace the folder
======================  ====================================================================

The folder is built under a temporary name beside the target and renamed into place only
when complete, so an interrupted run leaves nothing that looks finished; an existing run
folder is never replaced unless ``overwrite`` is given, and then only when tap-bench wrote
it (its marker is there): any other folder, a file or a link is refused. Episodes run as
tasks of :mod:`tap_bench.execution` (local worker processes or Ray), the episodes of one
(env, policy) in batches, each batch labelled and measured as one table (the same labels
and measures as each episode alone, at a fraction of the cost); an episode that fails is
recorded with its error and left out of the scores, and the episodes of a batch whose worker
dies are tried again one by one and then recorded as failed: one bad episode never costs
another. A run where every episode
failed is an error (:class:`~tap_bench.errors.EpisodesFailedError`), not an empty result.

With an episode cache (:mod:`tap_bench.bench.cache`), an episode whose inputs did not change
is read instead of simulated, and its labels and measures too when they were made with the
same thresholds, level and code (those episodes are read in this process: no worker
starts for them); the scores, figures and viewer data of unchanged inputs are read too,
and a run whose every input is unchanged is served whole (:mod:`tap_bench.bench.run.
served`). A run with the cache gives the same tables as one without, float for float.
Before the episodes start, the run estimates how long it will take, from the cache's
timings of earlier runs or by timing a first episode of each env.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import time
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from tap_bench.bench.cache import (
    EpisodeCache,
    memoised,
    package_code,
    package_code_holds,
    scenario_fingerprint,
    simulation_fingerprint,
    take_refused,
)
from tap_bench.bench.run.estimate import CACHED_EPISODE_S, RunPlan
from tap_bench.bench.run.folder import (
    _write_json,
    check_output,
    package_versions,
    provenance,
    read_run,
    run_summary,
    run_viewer,
    write_results,
)
from tap_bench.bench.run.plan import SuitePlan, _tasks, plan_suite
from tap_bench.bench.run.scoring import ReferenceSource, read_references, score_run
from tap_bench.bench.run.served import (
    RunResult,
    _check_apart,
    kept_whole,
    store_run,
    try_served,
)
from tap_bench.bench.run.spill import RunSpill, SpilledTable, spills
from tap_bench.bench.run.tasks import (
    CACHED_BATCH,
    RunTables,
    _observed_timings,
    _rollouts,
    result_ok,
)
from tap_bench.bench.suite import Suite
from tap_bench.errors import (
    CacheEntryWarning,
    EpisodesFailedError,
    ParameterError,
    RunExistsError,
)
from tap_bench.execution import Backend, resolve_backend
from tap_bench.sim.scenario_format import Scenario
from tap_bench.sim.womd_scene import WomdScenes

__all__ = ["CACHED_BATCH", "CACHED_EPISODE_S", "RunExistsError", "RunPlan", "RunResult",
           "SuitePlan", "plan_suite",
           "check_output", "package_versions", "provenance", "read_run", "run_suite",
           "run_viewer", "write_results"]


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

    def table(self, envs: Sequence[str]) -> pd.DataFrame:
        """The map tables of ``envs``, one table."""
        return pd.concat([self(env) for env in envs], ignore_index=True)

    def kept(self, envs: Sequence[str], spill: RunSpill | None
             ) -> pd.DataFrame | SpilledTable:
        """The map tables of ``envs`` for the run folder: one table, or (a spilled run)
        written to the spill's parts, a recorded scene's map at a time (the rows
        :meth:`table` gives)."""
        if spill is None:
            return self.table(envs)
        return spill.keep_maps(table for env in envs for table in self._tables(env))

    def _tables(self, env: str) -> Iterator[pd.DataFrame]:
        scenario = self.scenarios[env]
        if isinstance(scenario, WomdScenes) and env not in self.drawn:
            from tap_bench.sources.maps import iter_maps

            yield from iter_maps(scenario.files)
        else:
            yield self(env)


def _table_files(table: pd.DataFrame) -> dict[str, bytes]:
    buffer = io.BytesIO()
    table.to_parquet(buffer, index=True)
    return {"table.parquet": buffer.getvalue()}


def _files_table(files: Mapping[str, bytes]) -> pd.DataFrame:
    return pd.read_parquet(io.BytesIO(files["table.parquet"]))


def run_suite(suite: Suite | str | os.PathLike, output: str | os.PathLike, *,
              workers: int = 2, womd: Sequence[str | os.PathLike] | None = None,
              references: Mapping[str, ReferenceSource] | None = None,
              keep_trajectories: bool = True, overwrite: bool = False,
              progress: bool | None = None, report: bool = True,
              backend: Backend | None = None, seeds: str | Sequence[int] | None = None,
              cache: EpisodeCache | str | os.PathLike | None = None,
              announce: Callable[[str], None] | None = None,
              plugins: Sequence[str] = (), log: str | os.PathLike | None = None,
              realism: Sequence[str | os.PathLike | Mapping[str, Any]] = ()) -> RunResult:
    """Run a benchmark suite and write its run folder.

    Args:
        suite: a :class:`Suite`, a suite name (``default``) or a suite JSON path.
        output: the run folder to create (``results/run-001``).
        workers: rollout processes (1: in this process).
        womd: WOMD files (TFRecord or ScenarioNet pickles): shorthand for
            ``references={"WOMD": womd}``.
        references: more coverage and novelty references, by name: a label table
            (DataFrame, or a .parquet/.csv label file), or driving-data files of any
            registered format (a path or a list of paths), which are labelled with the
            suite's thresholds and also matched scenario by scenario against the episodes.
        keep_trajectories: also write ``trajectories.parquet``.
        overwrite: replace an existing run folder.
        progress: progress bar (None: only on a terminal); recorded scenes: lines.
        log: a file the progress lines of recorded scenes also go to (time-stamped).
        report: write the plots and ``report.html``.
        backend: run the episodes as tasks on this :class:`tap_bench.execution.Backend`
            (a Ray cluster, say) instead of ``workers`` local processes; the tables are the
            same.
        seeds: run these seeds instead of the suite's (``"0-4"``, a list).
        cache: an :class:`~tap_bench.bench.cache.EpisodeCache` or its folder: episodes
            found there are read instead of simulated, new ones are stored, and the cache is
            pruned to its size bound afterwards (None: simulate everything, store nothing).
            The tables are the same either way.
        announce: called with one line saying how many episodes will be simulated and how
            long the run should take, before the episodes start (the CLI prints it); to
            estimate an env no earlier run timed, its first episode runs first. None: no
            estimate.
        plugins: modules that register measures, data formats or policy kinds
            (:mod:`tap_bench.plugins`), imported before the suite is read; with the suite's
            own ``plugins``, every worker imports them before its first task.
        realism: results of ``tap-bench realism`` (their JSON files, or the results) shown
            in the report's realism section and kept in ``summary.json``
            (:mod:`tap_bench.bench.report.realism`).

    Returns:
        :class:`RunResult`.

    Raises:
        RunExistsError: ``output`` exists and ``overwrite`` is False.
        EpisodesFailedError: every episode failed (naming the first errors); nothing is
            written.
    """
    t_start = time.perf_counter()
    output = check_output(output, overwrite)
    plan = plan_suite(suite, plugins=plugins, seeds=seeds)  # the suite, read once
    cache = _open_cache(cache, output)
    sources = _reference_sources(references, womd)
    shown_realism = _realism_entries(realism)  # read (and checked) before the episodes
    # every input as in an earlier run: its folder comes whole from the cache (run.served)
    served, tasks, whole = try_served(plan, cache, output, overwrite, keep_trajectories,
                                      report, bool(sources) or bool(shown_realism), t_start,
                                      announce)
    if served is not None:
        return served
    runner = resolve_backend(backend, workers)
    if cache is not None:  # tap-bench's code as the run's entries are keyed (see the end)
        package_code()
    entries_since = time.time()
    timings: dict[str, float] = {}
    corpora = read_references(sources, plan.level, plan.thresholds, timings)
    with_trajectories = any(traj is not None for traj, _ in corpora.values())
    keep_tables = keep_trajectories or with_trajectories
    if tasks is None:  # not made for the served run's key
        tasks = _tasks(plan, keep_tables, cache)
    roads = _Roads(plan.scenarios, cache)
    # recorded scenes: each episode's tables go to disk as its result arrives (run.spill)
    spill = RunSpill(output) if spills(plan.scenarios) else None
    t0 = time.perf_counter()
    kept = getattr(runner, "kept", None)  # the estimate's first episodes and the rest
    with kept() if kept is not None else contextlib.nullcontext():  # on the same workers
        results, estimate = _rollouts(tasks, plan.name, runner, progress, cache, announce,
                                      roads, None if spill is None else spill.keep, log)
    timings["rollouts_wall"] = time.perf_counter() - t0
    if announce is not None:
        announce(f"episodes done ({timings['rollouts_wall']:.0f} s); scoring ...")
    tables = RunTables.of(results, keep_tables, timings, spill)
    refused = _check_results(results, tables.episodes, plan.name)
    t0 = time.perf_counter()
    scores = score_run(plan, tables, corpora, cache)
    timings["scoring"] = time.perf_counter() - t0
    summary = run_summary(plan, output, sources, tables.episodes, scores, timings, estimate,
                          _cache_summary(cache, results, refused), shown_realism)
    if announce is not None:
        announce(f"scored ({timings['scoring']:.1f} s); writing the tables"
                 + (", plots, report and replay viewer" if report else "") + " ...")
    t0 = time.perf_counter()
    keep = kept_whole(plan, tasks, whole, tables.episodes,
                      keep_trajectories=keep_trajectories, report=report)
    pages: dict[str, bytes] | None = {} if keep else None
    folder = write_results(
        output, overwrite, summary, tables.episodes, tables.labels,
        tables.trajectories if keep_trajectories else None, scores, report,
        segments=tables.segments, cache=cache, pages=pages,
        # the replay viewer draws the roads; highway-env's road is seed-free
        roads=roads.kept(plan.envs, spill) if keep_trajectories else None)
    timings["writing_and_report"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    if spill is not None:
        spill.close()
    _note_refused(summary, refused)  # with the derived entries refused while writing
    _write_json(folder / "summary.json", summary)  # with the final timings
    if keep and cache is not None and pages is not None:
        store_run(cache, whole, folder, summary, pages, tables.episodes, scores)
    if cache is not None:
        _tidy_cache(cache, results, timings["total"], runner.workers, entries_since)
    return RunResult(folder, summary, tables.episodes, scores, folder / "report.html")


def _note_refused(summary: dict[str, Any], refused: list[str]) -> None:
    """The cache entries refused in the run (``refused``: episodes; then the derived
    entries: roads, scores, plots, viewer, run) in ``summary``'s cache part, if any."""
    if summary["cache"] is not None:
        summary["cache"]["refused"] = [*refused, *take_refused()]


def _realism_entries(realism: Sequence[str | os.PathLike | Mapping[str, Any]]
                     ) -> list[dict[str, Any]]:
    """The results of ``tap-bench realism`` the report shows, read and checked
    (:func:`tap_bench.bench.report.realism.realism_entries`; the report is imported here,
    not on the path of a run served from the cache)."""
    from tap_bench.bench.report.realism import realism_entries

    return realism_entries(realism)


def _open_cache(cache: EpisodeCache | str | os.PathLike | None, output: Path
                ) -> EpisodeCache | None:
    """The run's episode cache (None: none), checked to lie apart from ``output``."""
    if cache is not None and not isinstance(cache, EpisodeCache):
        cache = EpisodeCache(Path(cache))
    if cache is not None:
        _check_apart(output, cache.root)
    return cache


def _reference_sources(references: Mapping[str, ReferenceSource] | None,
                       womd: Sequence[str | os.PathLike] | None
                       ) -> dict[str, ReferenceSource]:
    """The run's references by name: ``references`` and ``womd`` as ``"WOMD"``."""
    sources = dict(references or {})
    if womd:
        if "WOMD" in sources:
            raise ParameterError("references", sorted(sources), "names other than 'WOMD' "
                                 "when womd= is given (womd= is references={'WOMD': ...})")
        sources["WOMD"] = list(womd)
    return sources


def _check_results(results: list[dict[str, Any]], episodes: pd.DataFrame, suite_name: str
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
    for note in refused[:5]:
        warnings.warn(f"{note}; its episode was simulated again.", CacheEntryWarning,
                      stacklevel=3)
    if len(refused) > 5:
        warnings.warn(f"{len(refused) - 5} more cache entries refused and simulated again "
                      "(summary.json lists them all).", CacheEntryWarning, stacklevel=3)
    return refused


def _cache_summary(cache: EpisodeCache | None, results: list[dict[str, Any]],
                   refused: list[str]) -> dict[str, Any] | None:
    """The ``cache`` part of ``summary.json`` (None: the run had no cache)."""
    if cache is None:
        return None
    return {"dir": str(cache.root), "cached": sum(r["cached"] for r in results),
            "simulated": sum(not r["cached"] for r in results),
            "labelled_before": sum(bool(r.get("labels_cached")) for r in results),
            "refused": refused}


def _tidy_cache(cache: EpisodeCache, results: list[dict[str, Any]], total: float,
                workers: int, entries_since: float) -> None:
    """After the run: drop what it kept if tap-bench was edited while it ran, record the
    episodes' timings for the next estimate and prune the cache to its size bound."""
    if not package_code_holds():
        # tap-bench edited while the run went on: a worker may have imported the new code
        # (labelling, simulation) after the keys named the old, so what it kept is dropped
        cache.forget_written_since(entries_since)
    simulated, cached = _observed_timings(results)
    work = sum(r["seconds"] for r in results if math.isfinite(r["seconds"]))
    overhead = total - work / max(1, min(workers, len(results)))
    with contextlib.suppress(OSError):  # the run is written; the cache is a convenience
        cache.record_timings(simulated, cached, overhead)
        cache.prune()
