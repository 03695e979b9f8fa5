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
when complete, so an interrupted run leaves nothing that looks finished (the temporary
folder of a run killed outright names its process, and the next run into the same output
removes it once that process is gone, saying so: :func:`tap_bench.tableio.
remove_abandoned`); an existing run
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

:func:`run_suite` reads as its steps, each in its own module and given the plain values it
needs: the suite resolved once into a plan (:func:`~tap_bench.bench.run.plan.plan_suite`),
the references read (:func:`~tap_bench.bench.run.references.read_references`), the episodes'
tasks made (:func:`~tap_bench.bench.run.plan._tasks`, keyed for the cache), the run served
whole when nothing changed (:func:`~tap_bench.bench.run.served.try_served`), the episodes
run (:func:`~tap_bench.bench.run.episodes.run_episodes`), scored
(:func:`~tap_bench.bench.run.scoring.score_run`, a pure function of the run's tables; the
scores of unchanged inputs read back from the cache, :func:`~tap_bench.bench.cache.
memoised`) and written
(:func:`~tap_bench.bench.run.folder.write_results`), then the cache's part: the run kept
whole (:func:`~tap_bench.bench.run.served.keep_run`) and the cache closed
(:meth:`~tap_bench.bench.cache.EpisodeCache.close_run`).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from tap_bench.bench.cache import EpisodeCache, memoised, package_code, table_digest
from tap_bench.bench.run.episodes import run_episodes
from tap_bench.bench.run.estimate import CACHED_EPISODE_S, RunPlan
from tap_bench.bench.run.folder import (
    RunResult,
    check_output,
    finish_summary,
    package_versions,
    provenance,
    read_run,
    run_summary,
    run_viewer,
    write_results,
)
from tap_bench.bench.run.plan import SuitePlan, _tasks, plan_suite
from tap_bench.bench.run.references import ReferenceSource, read_references
from tap_bench.bench.run.scoring import score_run
from tap_bench.bench.run.served import _check_apart, keep_run, try_served
from tap_bench.bench.run.tasks import CACHED_BATCH
from tap_bench.bench.scores.scoring import scores_from_files, scores_to_files
from tap_bench.bench.suite import Suite
from tap_bench.errors import ParameterError, RunExistsError
from tap_bench.execution import Backend, resolve_backend

__all__ = ["CACHED_BATCH", "CACHED_EPISODE_S", "RunExistsError", "RunPlan", "RunResult",
           "SuitePlan", "plan_suite",
           "check_output", "package_versions", "provenance", "read_run", "run_suite",
           "run_viewer", "write_results"]


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
    output = check_output(output, overwrite, announce)
    plan = plan_suite(suite, plugins=plugins, seeds=seeds)  # the suite, read once
    cache = _open_cache(cache, output)
    sources = _reference_sources(references, womd)
    shown_realism = _realism_entries(realism)  # read (and checked) before the episodes
    timings: dict[str, float] = {}
    corpora = read_references(sources, plan.level, plan.thresholds, timings)
    keep_tables = keep_trajectories or any(traj is not None for traj, _ in corpora.values())
    tasks = _tasks(plan, keep_tables, cache)  # keyed for the cache when there is one
    # every input as in an earlier run: its folder comes whole from the cache (run.served)
    served, whole = try_served(plan, tasks, cache, output, overwrite, keep_trajectories,
                               report, bool(sources) or bool(shown_realism), t_start,
                               announce)
    if served is not None:
        return served
    backend = resolve_backend(backend, workers)
    if cache is not None:  # tap-bench's code as the run's entries are keyed (see the end)
        package_code()
    entries_since = time.time()
    done = run_episodes(tasks, plan.name, plan.scenarios, output, backend=backend,
                        cache=cache, recorded=plan.recorded, keep_tables=keep_tables,
                        keep_maps=keep_trajectories,
                        progress=progress, announce=announce, log=log, timings=timings)
    tables = done.tables
    if announce is not None:
        announce(f"episodes done ({timings['rollouts_wall']:.0f} s); scoring ...")
    t0 = time.perf_counter()
    # the scores of unchanged episodes, suite, contexts, gate metrics and measures are read
    # back from the cache; runs with reference corpora or plug-ins are scored every time
    key = None if corpora or plan.plugins else {
        "episodes": table_digest(tables.episodes), "suite": plan.document,
        "contexts": None if tables.occurrences is None else table_digest(tables.occurrences),
        "gate_metrics": list(plan.gate_metrics),
        "measures": [m.to_dict() for m in plan.measures]}
    scores = memoised(cache, "scores", key, lambda: score_run(plan, tables, corpora),
                      scores_to_files, scores_from_files)
    timings["scoring"] = time.perf_counter() - t0
    summary = run_summary(plan, output, sources, tables.episodes, scores, timings,
                          done.estimate, done.cache, shown_realism)
    if announce is not None:
        announce(f"scored ({timings['scoring']:.1f} s); writing the tables"
                 + (", plots, report and replay viewer" if report else "") + " ...")
    t0 = time.perf_counter()
    # the pages that name the run as templates when it may be kept whole (run.served)
    pages: dict[str, bytes] | None = {} if whole is not None else None
    folder = write_results(
        output, overwrite, summary, tables.episodes, tables.labels,
        tables.trajectories if keep_trajectories else None, scores, report,
        segments=tables.segments, cache=cache, pages=pages, roads=done.roads)
    timings["writing_and_report"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    # with the final timings and the derived cache entries refused while writing
    finish_summary(folder, summary, done.refused)
    if done.spill is not None:
        done.spill.close()
    result = RunResult(folder, summary, tables.episodes, scores, folder / "report.html")
    if cache is not None:
        keep_run(cache, plan, tasks, whole, result, pages)
        simulated, cached, work = done.observed
        cache.close_run(entries_since, simulated, cached, timings["total"] - work)
    return result


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
