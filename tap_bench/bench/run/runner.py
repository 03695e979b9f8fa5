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
and a run whose every input is unchanged is served whole (:mod:`tap_bench.bench.
run_cache`). A run with the cache gives the same tables as one without, float for float.
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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
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
    table_digest,
    take_refused,
)
from tap_bench.bench.episodes import one_outcome_cells
from tap_bench.bench.gate.power import power_table
from tap_bench.bench.run.folder import (
    _write_json,
    check_output,
    package_versions,
    provenance,
    read_run,
    run_viewer,
    write_results,
)
from tap_bench.bench.run.plan import CACHED_EPISODE_S, RunPlan, SuitePlan, plan_suite
from tap_bench.bench.run.served import (
    RunResult,
    _check_apart,
    fresh_facts,
    run_inputs,
    store_run,
    try_served,
)
from tap_bench.bench.run.summary import (
    ReferenceSource,
    _describe_source,
    _headline,
    _reference,
    _round,
    _with_gaps,
)
from tap_bench.bench.run.tasks import CACHED_BATCH, _observed_timings, _rollouts
from tap_bench.bench.scores.contexts import context_scores
from tap_bench.bench.scores.gap import window_episodes, window_seconds
from tap_bench.bench.scores.scenarios import match_scenarios
from tap_bench.bench.scores.scoring import Scores, score, scores_from_files, scores_to_files
from tap_bench.bench.scores.verdict import verdict_table
from tap_bench.bench.spill import TrajectorySpill, spills
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
from tap_bench.thresholds import Thresholds

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


def _inputs_hold(plan: SuitePlan, tasks: Sequence[Any], whole: Mapping[str, Any], *,
                 keep_trajectories: bool, report: bool) -> bool:
    """Whether the run's inputs are still ``whole``, those it started with (then the run may
    be kept whole): False too when they cannot be read now (a policy or scenario file
    removed or unreadable), which costs only reuse, never the run's results."""
    try:
        return run_inputs(plan, tasks, keep_trajectories=keep_trajectories,
                          report=report) == whole
    except Exception:  # any failure to fingerprint: not kept whole, the results written
        return False


def _kept_whole(plan: SuitePlan, tasks: Sequence[Any] | None,
                whole: Mapping[str, Any] | None, episodes: pd.DataFrame, *,
                keep_trajectories: bool, report: bool) -> bool:
    """Whether the run folder is kept whole in the cache for an unchanged re-run: every
    episode made (a failed one is tried again) and the run's inputs as at the start (a
    policy's model or module changed while it went on would be kept under the old
    content's key)."""
    if whole is None or tasks is None or not (episodes["status"] == "ok").all():
        return False
    return _inputs_hold(plan, tasks, whole, keep_trajectories=keep_trajectories,
                        report=report)


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
              plugins: Sequence[str] = (),
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
        progress: progress bar (None: only on a terminal).
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
    from tap_bench.bench.report.realism import realism_entries  # not on the served path

    shown_realism = realism_entries(realism)  # read (and checked) before the episodes
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
    corpora = _read_references(sources, plan.suite.level, plan.thresholds, timings)
    with_trajectories = any(traj is not None for traj, _ in corpora.values())
    roads = _Roads(plan.scenarios, cache)
    # recorded scenes: each episode's trajectories go to disk as it ends (bench.spill)
    spill = TrajectorySpill(output) if spills(plan.scenarios) and (
        keep_trajectories or with_trajectories) else None
    t0 = time.perf_counter()
    kept = getattr(runner, "kept", None)  # the estimate's first episodes and the rest
    with kept() if kept is not None else contextlib.nullcontext():  # on the same workers
        results, estimate = _rollouts(plan, runner, keep_trajectories or with_trajectories,
                                      progress, cache, announce, roads, tasks,
                                      keep_result=None if spill is None else spill.keep)
    timings["rollouts_wall"] = time.perf_counter() - t0
    if announce is not None:
        announce(f"episodes done ({timings['rollouts_wall']:.0f} s); scoring ...")
    refused = _check_results(results, plan.suite.name)
    tables = _RunTables.of(results, keep_trajectories or with_trajectories, timings,
                           spill, whole=with_trajectories)
    t0 = time.perf_counter()
    scores = _scores(plan, tables, corpora, cache)
    timings["scoring"] = time.perf_counter() - t0
    summary = _summary(plan, output, sources, tables, scores, timings, estimate,
                       _cache_summary(cache, results, refused), shown_realism)
    if announce is not None:
        announce(f"scored ({timings['scoring']:.1f} s); writing the tables"
                 + (", plots, report and replay viewer" if report else "") + " ...")
    t0 = time.perf_counter()
    keep = _kept_whole(plan, tasks, whole, tables.episodes,
                       keep_trajectories=keep_trajectories, report=report)
    pages: dict[str, bytes] | None = {} if keep else None
    folder = write_results(
        output, overwrite, summary, tables.episodes, tables.labels,
        tables.trajectories if keep_trajectories else None, scores, report,
        segments=tables.segments, cache=cache, pages=pages,
        # the replay viewer draws the roads; highway-env's road is seed-free
        roads=roads.table(plan.suite.envs) if keep_trajectories else None)
    timings["writing_and_report"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    if spill is not None:
        spill.close()
    if summary["cache"] is not None:  # derived entries (roads, scores, plots, viewer, run)
        summary["cache"]["refused"] = [*refused, *take_refused()]
    _write_json(folder / "summary.json", summary)  # with the final timings
    if keep and cache is not None and pages is not None:
        store_run(cache, whole, folder, summary, pages, tables.episodes, scores)
    if cache is not None:
        _tidy_cache(cache, results, timings["total"], runner.workers, entries_since)
    return RunResult(folder, summary, tables.episodes, scores, folder / "report.html")


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


def _read_references(sources: Mapping[str, ReferenceSource], level: str,
                     thresholds: Thresholds, timings: dict[str, float]
                     ) -> dict[str, tuple[pd.DataFrame | None, pd.DataFrame]]:
    """name -> (trajectories or None, label table) of every reference; the time it took
    goes to ``timings["references"]`` [s]."""
    t0 = time.perf_counter()
    corpora = {name: _reference(name, source, level, thresholds)
               for name, source in sources.items()}
    if corpora:
        timings["references"] = time.perf_counter() - t0
    return corpora


def _check_results(results: list[dict[str, Any]], suite_name: str) -> list[str]:
    """The notes of the cache entries refused (each warned, the first five by name).

    Raises:
        EpisodesFailedError: every episode failed.
    """
    if not any((r["episodes"]["status"] == "ok").all() for r in results):
        errors = [f"{row.env} {row.policy} seed {row.seed}: {row.error}"
                  for r in results for row in r["episodes"].itertuples()]
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


@dataclass(frozen=True)
class _RunTables:
    """The tables of a run's episodes, gathered from the tasks' results: the episode table
    (sorted by env, policy, seed), labels, segments (None: none), the interaction contexts'
    occurrences (None: none) and the trajectories (None: not kept)."""

    episodes: pd.DataFrame
    labels: pd.DataFrame
    segments: pd.DataFrame | None
    occurrences: pd.DataFrame | None
    trajectories: pd.DataFrame | TrajectorySpill | None

    @classmethod
    def of(cls, results: list[dict[str, Any]], trajectories: bool,
           timings: dict[str, float], spill: TrajectorySpill | None = None, *,
           whole: bool = False) -> _RunTables:
        """Gathered from ``results``; the workers' CPU time per stage goes to ``timings``
        (``<stage>_cpu_in_workers`` [s]). With a ``spill``, the trajectories are its parts
        (read back into one table when ``whole``: the reference matching needs them)."""
        for key in ("rollout", "labelling", "measures"):
            timings[f"{key}_cpu_in_workers"] = sum(r["timings"].get(key, 0.0)
                                                   for r in results)
        episodes = pd.concat([r["episodes"] for r in results], ignore_index=True)
        episodes = episodes.sort_values(["env", "policy", "seed"], kind="stable")
        return cls(episodes.reset_index(drop=True),
                   _concat([r["labels"] for r in results]) if any(
                       len(r["labels"]) for r in results) else pd.DataFrame(),
                   _concat([r["segments"] for r in results]),
                   _concat([r.get("contexts", ()) for r in results]),
                   _trajectories(results, spill, whole) if trajectories else None)


def _trajectories(results: list[dict[str, Any]], spill: TrajectorySpill | None, whole: bool
                  ) -> pd.DataFrame | TrajectorySpill | None:
    """The run's trajectories: the results' tables as one, or the spill's parts (as one
    table when ``whole``); None: no rows."""
    if spill is None:
        return _concat([r["trajectories"] for r in results if r["trajectories"] is not None])
    if whole:
        return spill.table()
    return spill if len(spill) else None


def _concat(frames: Sequence[Any]) -> pd.DataFrame | None:
    """The non-empty ``frames`` as one table (None: none)."""
    frames = [f for f in frames if len(f)]
    return pd.concat(frames, ignore_index=True) if frames else None


def _scores(plan: SuitePlan, tables: _RunTables,
            corpora: Mapping[str, tuple[pd.DataFrame | None, pd.DataFrame]],
            cache: EpisodeCache | None) -> Scores:
    """The run's scores. An unchanged run reads them back (keyed by the episode table's
    content and the suite); runs with reference corpora or plug-ins are scored every
    time."""
    return memoised(cache, "scores", None if corpora or plan.plugins else {
        "episodes": table_digest(tables.episodes), "suite": plan.suite.to_dict(),
        "contexts": None if tables.occurrences is None
        else table_digest(tables.occurrences),
        "gate_metrics": list(plan.gate_metrics),
        "measures": [m.to_dict() for m in plan.measures]},
        lambda: _score(plan, tables, corpora), scores_to_files, scores_from_files)


def _score(plan: SuitePlan, tables: _RunTables,
           corpora: Mapping[str, tuple[pd.DataFrame | None, pd.DataFrame]]) -> Scores:
    """Every score of the run (:func:`~tap_bench.bench.scores.scoring.score`), with the
    scenarios matched to each reference, windows of its tracks' length, the gate's power,
    the interaction contexts and the sim-to-real gaps."""
    suite, episodes = plan.suite, tables.episodes
    matches, unmatched = _scenario_matches(corpora, tables, suite.level)
    power = power_table(episodes, suite.gate,
                        n_tests=len(suite.envs) * len(suite.policies)
                        * len(plan.gate_metrics))
    scores = score(episodes, reference_policy=suite.reference, level=suite.level,
                   config=suite.bootstrap,
                   references={name: lab for name, (_, lab) in corpora.items()} or None,
                   scenario_matches=matches, gate_power=power,
                   windows=_windows(corpora, tables.trajectories, suite.level,
                                    plan.thresholds) or None)
    # the interaction contexts, scored as `tap-bench contexts` scores them
    scores = replace(scores, contexts=context_scores(
        tables.occurrences, list(pd.unique(episodes["policy"])), suite.reference,
        config=suite.bootstrap))
    if len(scores.contexts):
        scores.methods["contexts"] = (
            "each policy against the reference inside each interaction context (trend "
            "level): per episode the context's measures reduced over its occurrences, "
            "then paired by seed (t; Tango for a share) where both meet the context, "
            "else unpaired (Welch; Newcombe), as tap-bench contexts")
    if unmatched:
        scores.methods["scenario matching skipped"] = (
            f"{', '.join(unmatched)}: the data marks no ego vehicle (is_ego), so its "
            "scenarios cannot be matched by what happens around the ego; coverage and "
            "novelty use all its vehicles")
    return _with_gaps(scores, corpora, tables.labels, episodes, suite.level,
                      plan.thresholds, suite.bootstrap)


def _scenario_matches(corpora: Mapping[str, tuple[pd.DataFrame | None, pd.DataFrame]],
                      tables: _RunTables, level: str
                      ) -> tuple[pd.DataFrame | None, list[str]]:
    """Each episode's best-matching scenarios of every reference with trajectories (None:
    none), and the references that could not be matched (their data mark no ego)."""
    matches, unmatched = [], []
    for name, (ref_traj, ref_labels) in corpora.items():
        if ref_traj is not None and len(tables.labels):
            if "is_ego" not in ref_labels.columns:  # a format without an ego
                unmatched.append(name)
                continue
            matches.append(match_scenarios(tables.labels, tables.trajectories, ref_labels,
                                           ref_traj, level=level, top=3).assign(reference=name))
    return (pd.concat(matches, ignore_index=True) if matches else None), unmatched


def _windows(corpora: Mapping[str, tuple[pd.DataFrame | None, pd.DataFrame]],
             trajectories: pd.DataFrame | None, level: str, thresholds: Thresholds
             ) -> dict[str, tuple[pd.DataFrame, str]]:
    """Coverage and novelty against real driving: the episodes cut in windows of the
    length of each reference's tracks, by reference name."""
    cut = {}
    for name, (ref_traj, _) in corpora.items():
        if ref_traj is not None and trajectories is not None:
            seconds = window_seconds("auto", ref_traj, trajectories)
            if seconds is not None:
                cut[name] = (window_episodes(trajectories, seconds, level,
                                             thresholds=thresholds, source=name),
                             f"{seconds:.1f} s windows")
    return cut


def _cache_summary(cache: EpisodeCache | None, results: list[dict[str, Any]],
                   refused: list[str]) -> dict[str, Any] | None:
    """The ``cache`` part of ``summary.json`` (None: the run had no cache)."""
    if cache is None:
        return None
    return {"dir": str(cache.root), "cached": sum(r["cached"] for r in results),
            "simulated": sum(not r["cached"] for r in results),
            "labelled_before": sum(bool(r.get("labels_cached")) for r in results),
            "refused": refused}


def _summary(plan: SuitePlan, output: Path, sources: Mapping[str, ReferenceSource],
             tables: _RunTables, scores: Scores, timings: dict[str, float],
             estimate: RunPlan, cache: dict[str, Any] | None,
             realism: list[dict[str, Any]]) -> dict[str, Any]:
    """``summary.json``: what ran, on what, how it scored, and how long it took."""
    suite, episodes, thresholds = plan.suite, tables.episodes, plan.thresholds
    failed = episodes[~episodes["status"].isin(("ok", "skipped"))]  # skipped: no route
    skipped = episodes[episodes["status"] == "skipped"]
    facts = fresh_facts(plan, output)
    return {
        "format": "tap-bench-run", "format_version": 1,
        "run": facts["run"], "created": facts["created"],
        "suite": suite.to_dict(), "suite_file": facts["suite_file"],
        "level": suite.level,
        "seeds": "all" if suite.all_seeds else list(suite.seeds),
        "thresholds": thresholds.to_dict() if hasattr(thresholds, "to_dict") else
        str(suite.thresholds),
        "reference_policy": suite.reference,
        "references": {name: _describe_source(source) for name, source in sources.items()},
        "versions": facts["versions"], "machine": facts["machine"],
        "n_episodes": len(episodes), "n_failed": len(failed),
        "failed": failed[["env", "policy", "seed", "error"]].to_dict("records"),
        "n_skipped": len(skipped),
        "skipped": skipped[["env", "policy", "seed", "error"]].to_dict("records"),
        "methods": scores.methods,
        "headline": _headline(scores, episodes),
        "one_outcome_cells": one_outcome_cells(episodes).to_dict("records"),
        "verdict": verdict_table(scores.paired_measures, scores.paired,
                                 scores.paired_labels).to_dict("records"),
        "provenance": provenance(plan.definitions, plan.scenarios),
        "measures": [m.to_dict() for m in plan.measures],
        "plugins": list(plan.plugins),
        "realism": realism,
        "timings": timings,
        "estimate": {"seconds": _round(estimate.seconds),
                     "overhead": _round(estimate.overhead_seconds), "basis": estimate.basis},
        "cache": cache,
    }


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
