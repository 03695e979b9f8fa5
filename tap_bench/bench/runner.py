"""``bench run``: roll out every policy of a suite in every env over its seeds, label, score,
and write ``results/<run>/``.

What a run folder holds:

======================  ====================================================================
``summary.json``        suite, seeds, thresholds, level, versions, machine, timings, failed
                        episodes, the interval methods, headline figures, and the
                        provenance: each policy's full definition (with the SHA-256 of a
                        model file) and each env's resolved config
``episodes.parquet``    the episode table (:mod:`tap_bench.bench.episodes`), failed
                        episodes included with their error
``labels.parquet``      TAP labels of every track at every level
``trajectories.parquet``  the rollouts (unless ``keep_trajectories`` is False)
``segments.parquet``    the segment table (label timelines) of every track at the suite's
                        level
``roads.parquet``       each env's road network as a map table (:mod:`tap_bench.maps`), for
                        the replay viewer (with the trajectories)
``<table>.parquet``     every table of :class:`tap_bench.bench.scoring.Scores`
``plots/*.png``         label distributions, measures, coverage, forest plots, novelty
``report.html``         the static report (no server, images embedded)
``viewer/``             the replay viewer (:mod:`tap_bench.bench.viewer`; with the trajectories)
``.tap-bench-folder``   the marker that lets ``--overwrite`` replace the folder
======================  ====================================================================

The folder is built under a temporary name beside the target and renamed into place only
when complete, so an interrupted run leaves nothing that looks finished; an existing run
folder is never replaced unless ``overwrite`` is given, and then only when tap-bench wrote
it (its marker is there): any other folder, a file or a link is refused. Episodes run as
tasks of :mod:`tap_bench.execution` (local worker processes or Ray), one task per (env,
policy, seed), each labelling its own episode; an episode that fails is recorded with its
error and left out of the scores, and an episode whose worker dies is tried once more and
then recorded as failed: one bad episode never costs another.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tap_bench.bench.episodes import episode_table
from tap_bench.bench.power import power_table
from tap_bench.bench.report import write_report
from tap_bench.bench.scenarios import match_scenarios
from tap_bench.bench.scoring import Scores, score
from tap_bench.bench.suite import Suite, gate_metrics, load_suite
from tap_bench.bench.viewer import write_run_viewer
from tap_bench.errors import FileFormatError, ParameterError, RunExistsError
from tap_bench.execution import Backend, resolve_backend
from tap_bench.labelling import tap
from tap_bench.labels import validate_labels
from tap_bench.sim.policies import PolicyDefinition, get_definition
from tap_bench.sim.roads import road_table
from tap_bench.sim.rollout import resolve_policy, rollout
from tap_bench.sim.suite import Scenario
from tap_bench.sources import read_womd
from tap_bench.tableio import atomic_folder, atomic_path, check_folder_output, read_table
from tap_bench.thresholds import Thresholds, resolve_thresholds

__all__ = ["RunExistsError", "RunResult", "check_output", "package_versions", "provenance",
           "read_run", "run_suite", "run_viewer", "write_results"]

def check_output(output: str | os.PathLike, overwrite: bool) -> Path:
    """``output`` as a Path, checked before any work (:func:`tap_bench.tableio.
    check_folder_output`): a new folder in a writable place, or, with ``overwrite``, a run
    folder tap-bench wrote.

    Raises:
        RunExistsError: naming the folder and the flag that replaces it.
        OutputPathError: the place is not writable, or ``output`` is a file, a link or a
            folder tap-bench did not write.
    """
    return check_folder_output(output, overwrite)


@dataclass(frozen=True)
class RunResult:
    """What :func:`run_suite` returns.

    Attributes:
        folder: the run folder written.
        summary: the content of ``summary.json``.
        episodes: the episode table.
        scores: the scored tables.
        report: path of ``report.html``.
    """

    folder: Path
    summary: dict[str, Any]
    episodes: pd.DataFrame
    scores: Scores
    report: Path


@dataclass(frozen=True)
class _Task:
    """One episode of a suite run: what a worker needs, and nothing more (the scenario is
    resolved once, by the caller)."""

    env: str
    scenario: Scenario
    policy: str  # the policy's name
    definition: PolicyDefinition
    seed: int
    thresholds: Thresholds
    level: str
    keep_trajectories: bool


def _run_task(task: _Task) -> dict[str, Any]:
    """Roll out, label and measure one episode (in a worker process)."""
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        trajectories, episodes = rollout(task.scenario, task.definition, [task.seed],
                                         progress=False)
    t1 = time.perf_counter()
    labels = segments = pd.DataFrame()
    if len(trajectories):
        result = tap(trajectories, task.thresholds,
                     source=f"{task.env}/{task.policy} rollout")
        labels = result.labels("all")
        segments = result.segments(task.level)
    t2 = time.perf_counter()
    eps = episode_table(labels=labels if len(labels) else None,
                        trajectories=trajectories if len(trajectories) else None,
                        episodes=episodes, level=task.level, policy=task.policy)
    t3 = time.perf_counter()
    timings = {"rollout": t1 - t0, "labelling": t2 - t1, "measures": t3 - t2}
    return {"episodes": eps, "labels": labels, "segments": segments,
            "trajectories": trajectories if task.keep_trajectories else None,
            "timings": timings}


def _failed_task(task: _Task, message: str) -> dict[str, Any]:
    eps = pd.DataFrame({"env": [task.env], "policy": [task.policy], "seed": [task.seed],
                        "status": ["error"], "error": [message]})
    return {"episodes": episode_table(episodes=eps, level=task.level),
            "labels": pd.DataFrame(), "segments": pd.DataFrame(), "trajectories": None,
            "timings": {}}


def _tasks(suite: Suite, thresholds: Thresholds, keep: bool) -> list[_Task]:
    scenarios = {env: suite.scenario(env) for env in suite.envs}  # resolved once
    definitions = [resolve_policy(policy) for policy in suite.policies]  # built once here
    return [_Task(env, scenarios[env], d.name, d, seed, thresholds, suite.level, keep)
            for env in suite.envs for d in definitions for seed in suite.seeds]


def _rollouts(suite: Suite, thresholds: Thresholds, backend: Backend, keep: bool,
              progress: bool | None) -> list[dict[str, Any]]:
    """Every episode of the suite as a task on ``backend`` (one recovery rule: an episode
    whose worker died is tried once more, then recorded as failed)."""
    tasks = _tasks(suite, thresholds, keep)
    outcomes = backend.map(_run_task, tasks, unit="episode", progress=progress,
                           desc=f"bench {suite.name} ({backend.name})")
    return [o.value if o.ok else _failed_task(task, o.error)
            for task, o in zip(tasks, outcomes, strict=True)]


def package_versions() -> dict[str, str]:
    """Versions of tap-bench and the packages its results depend on."""
    from importlib import metadata

    out = {}
    for pkg in ("tap-bench", "numpy", "pandas", "pyarrow", "gymnasium", "highway-env",
                "matplotlib", "stable-baselines3", "torch"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            continue
    return out


def _machine() -> dict[str, Any]:
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = []
    return {"cores": os.cpu_count(), "load_avg": load, "python": sys.version.split()[0]}


def run_suite(suite: Suite | str | os.PathLike, output: str | os.PathLike, *,
              workers: int = 2, womd: Sequence[str | os.PathLike] | None = None,
              references: Mapping[str, ReferenceSource] | None = None,
              keep_trajectories: bool = True, overwrite: bool = False,
              progress: bool | None = None, report: bool = True,
              backend: Backend | None = None) -> RunResult:
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

    Returns:
        :class:`RunResult`.

    Raises:
        RunExistsError: ``output`` exists and ``overwrite`` is False.
    """
    suite = suite if isinstance(suite, Suite) else load_suite(suite)
    output = check_output(output, overwrite)
    runner = resolve_backend(backend, workers)
    thresholds = resolve_thresholds(suite.thresholds)
    timings: dict[str, float] = {}
    t_start = time.perf_counter()
    sources = dict(references or {})
    if womd:
        if "WOMD" in sources:
            raise ParameterError("references", sorted(sources), "names other than 'WOMD' "
                                 "when womd= is given (womd= is references={'WOMD': ...})")
        sources["WOMD"] = list(womd)
    t0 = time.perf_counter()
    corpora = {name: _reference(name, source, suite) for name, source in sources.items()}
    if corpora:
        timings["references"] = time.perf_counter() - t0
    with_trajectories = any(traj is not None for traj, _ in corpora.values())

    t0 = time.perf_counter()
    results = _rollouts(suite, thresholds, runner, keep_trajectories or with_trajectories,
                        progress)
    timings["rollouts_wall"] = time.perf_counter() - t0
    for key in ("rollout", "labelling", "measures"):
        timings[f"{key}_cpu_in_workers"] = sum(r["timings"].get(key, 0.0) for r in results)
    episodes = pd.concat([r["episodes"] for r in results], ignore_index=True)
    episodes = episodes.sort_values(["env", "policy", "seed"], kind="stable")
    episodes = episodes.reset_index(drop=True)
    labels = pd.concat([r["labels"] for r in results if len(r["labels"])], ignore_index=True) \
        if any(len(r["labels"]) for r in results) else pd.DataFrame()
    segments = pd.concat([r["segments"] for r in results if len(r["segments"])],
                         ignore_index=True) \
        if any(len(r["segments"]) for r in results) else None
    trajectories = None
    if keep_trajectories or with_trajectories:
        frames = [r["trajectories"] for r in results
                  if r["trajectories"] is not None and len(r["trajectories"])]
        trajectories = pd.concat(frames, ignore_index=True) if frames else None

    t0 = time.perf_counter()
    matches = []
    for name, (ref_traj, ref_labels) in corpora.items():
        if ref_traj is not None and len(labels):
            matches.append(match_scenarios(labels, trajectories, ref_labels, ref_traj,
                                           level=suite.level, top=3).assign(reference=name))
    power = power_table(episodes, suite.gate,
                        n_tests=len(suite.envs) * len(suite.policies) * len(gate_metrics()))
    scores = score(episodes, reference_policy=suite.reference, level=suite.level,
                   config=suite.bootstrap,
                   references={name: lab for name, (_, lab) in corpora.items()} or None,
                   scenario_matches=pd.concat(matches, ignore_index=True) if matches else None,
                   gate_power=power)
    timings["scoring"] = time.perf_counter() - t0

    failed = episodes[episodes["status"] != "ok"]
    summary = {
        "format": "tap-bench-run", "format_version": 1,
        "run": output.name, "created": time.strftime("%Y-%m-%d %H:%M:%S"),
        "suite": suite.to_dict(), "suite_file": str(suite.path) if suite.path else None,
        "level": suite.level, "seeds": list(suite.seeds),
        "thresholds": thresholds.to_dict() if hasattr(thresholds, "to_dict") else
        str(suite.thresholds),
        "reference_policy": suite.reference,
        "references": {name: _describe_source(source) for name, source in sources.items()},
        "versions": package_versions(), "machine": _machine(),
        "n_episodes": len(episodes), "n_failed": len(failed),
        "failed": failed[["env", "policy", "seed", "error"]].to_dict("records"),
        "methods": scores.methods,
        "headline": _headline(scores, episodes),
        "provenance": provenance(suite),
        "timings": timings,
    }
    t0 = time.perf_counter()
    roads = None
    if keep_trajectories:  # the replay viewer draws them; highway-env's road is seed-free
        roads = pd.concat([road_table(suite.scenario(env)) for env in suite.envs],
                          ignore_index=True)
    folder = write_results(output, overwrite, summary, episodes, labels, trajectories
                           if keep_trajectories else None, scores, report,
                           segments=segments, roads=roads)
    timings["writing_and_report"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    _write_json(folder / "summary.json", summary)  # with the final timings
    return RunResult(folder, summary, episodes, scores, folder / "report.html")


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def provenance(suite: Suite) -> dict[str, Any]:
    """What every policy and env of a suite is, in full, so that ``bench check`` can say what
    changed since a baseline.

    Returns:
        ``{"policies": {name: {"kind", "params", "model_sha256"?}}, "envs": {name:
        {"highway_env_id", "version", "duration", "lane_change", "config"}}}``; a model
        file's SHA-256 is taken from the file its definition names.
    """
    policies = {}
    for name in suite.policies:
        definition = get_definition(name)
        entry: dict[str, Any] = {"kind": definition.kind, "params": dict(definition.params)}
        model = definition.params.get("model")
        if isinstance(model, str):
            path = Path(model)
            if not path.is_absolute() and definition.path is not None:
                path = definition.path.parent / path
            entry["model_sha256"] = _sha256(path) if path.is_file() else "(missing file)"
        policies[name] = json.loads(json.dumps(entry, default=str))
    envs = {}
    for env in suite.envs:
        scenario = suite.scenario(env)
        envs[env] = json.loads(json.dumps(
            {"highway_env_id": scenario.highway_env_id, "version": scenario.version,
             "duration": scenario.duration, "lane_change": scenario.lane_change,
             "config": scenario.config}, default=str))
    return {"policies": policies, "envs": envs}


ReferenceSource = pd.DataFrame | str | os.PathLike | Sequence[str | os.PathLike]
"""A coverage reference: a label table, a label file, or driving-data files."""

_LABEL_SUFFIXES = (".parquet", ".pq", ".csv", ".csv.gz")


def _reference(name: str, source: ReferenceSource, suite: Suite
               ) -> tuple[pd.DataFrame | None, pd.DataFrame]:
    """(trajectories or None, label table) of one named reference."""
    if isinstance(source, pd.DataFrame):
        validate_labels(source, suite.level, source=f"reference {name!r}")
        return None, source
    paths = [source] if isinstance(source, str | os.PathLike) else list(source)
    if not paths:
        raise ParameterError(f"references[{name!r}]", source, "a label table or data files")
    if len(paths) == 1 and str(paths[0]).lower().endswith(_LABEL_SUFFIXES):
        table = read_table(paths[0])
        if "sdl" in table.columns:  # a label file
            validate_labels(table, suite.level, source=str(paths[0]))
            return None, table
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        traj = read_womd([str(p) for p in paths])
        labels = tap(traj, suite.thresholds, source=name).labels("all")
    return traj, labels


def _describe_source(source: ReferenceSource) -> Any:
    if isinstance(source, pd.DataFrame):
        return f"a label table of {len(source)} rows"
    if isinstance(source, str | os.PathLike):
        return str(source)
    return [str(p) for p in source]


def _headline(scores: Scores, episodes: pd.DataFrame) -> dict[str, Any]:
    """Per policy, pooled over envs: crash rate, mean speed, coverage of the reference."""
    out: dict[str, Any] = {}
    m = scores.measures
    pooled_env = "all" if (m["env"] == "all").any() else m["env"].iloc[0] if len(m) else ""
    for policy in sorted(episodes["policy"].unique()):
        row: dict[str, Any] = {}
        sub = m[(m["policy"] == policy) & (m["env"] == pooled_env)]
        for r in sub.itertuples():
            row[r.measure] = _round(r.mean)
        cov = scores.coverage
        if len(cov):
            c = cov[(cov["policy"] == policy) & (cov["env"] == pooled_env)]
            for r in c.itertuples():
                row[f"coverage of {r.reference}"] = _round(r.coverage)
        out[policy] = row
    return out


def _round(x: float) -> float | None:
    return None if x is None or not np.isfinite(x) else round(float(x), 4)


def _write_json(path: Path, doc: dict[str, Any]) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(doc, indent=2, default=_json_default) + "\n")


def _json_default(value: Any) -> Any:
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return None if not np.isfinite(value) else float(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, Path):
        return str(value)
    return str(value)


def write_results(output: str | os.PathLike, overwrite: bool, summary: dict[str, Any],
                  episodes: pd.DataFrame, labels: pd.DataFrame,
                  trajectories: pd.DataFrame | None, scores: Scores, report: bool = True, *,
                  segments: pd.DataFrame | None = None, roads: pd.DataFrame | None = None
                  ) -> Path:
    """Write a results folder (tables, ``summary.json``, plots, report, and the replay
    viewer when the trajectories are given) atomically.

    The folder is built under a temporary name beside ``output`` and renamed into place
    when complete (:func:`tap_bench.tableio.atomic_folder`); an existing ``output`` is
    replaced only when ``overwrite`` is True and tap-bench wrote it.

    Raises:
        RunExistsError: ``output`` exists and ``overwrite`` is False.
        OutputPathError: ``output`` is a file, a link or a folder tap-bench did not write.
    """
    with atomic_folder(output, overwrite, kind="run") as tmp:
        episodes.to_parquet(tmp / "episodes.parquet", index=False)
        if len(labels):
            labels.to_parquet(tmp / "labels.parquet", index=False)
        if trajectories is not None and len(trajectories):
            trajectories.to_parquet(tmp / "trajectories.parquet", index=False)
        for name, table in (("segments", segments), ("roads", roads)):
            if table is not None and len(table):
                table.to_parquet(tmp / f"{name}.parquet", index=False)
        for name, table in scores.tables().items():
            if len(table):
                _parquet_safe(table).to_parquet(tmp / f"{name}.parquet", index=False)
        _write_json(tmp / "summary.json", summary)
        viewer = report and trajectories is not None and len(trajectories) > 0
        if viewer:
            write_run_viewer(tmp / "viewer", summary, episodes, trajectories,
                             segments=segments, roads=roads, novel_labels=scores.novel_labels)
        if report:
            write_report(tmp, summary, episodes, scores, viewer="viewer/index.html"
                         if viewer else None)
    return Path(output)


def _parquet_safe(table: pd.DataFrame) -> pd.DataFrame:
    """Object columns holding mixed Python values as strings (Parquet needs one type)."""
    out = table.copy()
    for col in out.columns:
        if out[col].dtype == object:
            kinds = {type(v) for v in out[col].dropna()}
            if len(kinds) > 1:
                out[col] = out[col].astype("string")
    return out


def read_run(folder: str | os.PathLike) -> tuple[dict[str, Any], pd.DataFrame]:
    """``summary.json`` and the episode table of a run folder.

    Raises:
        FileFormatError: the folder is not a finished run (no summary or episode table), or
            one of them is damaged: not JSON, not an object, not Parquet, columns missing.
    """
    folder = Path(folder)
    summary_path = folder / "summary.json"
    episodes_path = folder / "episodes.parquet"
    for path in (summary_path, episodes_path):
        if not path.is_file():
            raise FileFormatError(f"{folder}: not a finished run folder ({path.name} is "
                                  "missing); make one with 'tap-bench bench run'.")
    redo = "The run folder is damaged; run 'tap-bench bench run' again."
    try:
        summary = json.loads(summary_path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise FileFormatError(f"{summary_path}: not valid JSON ({err}). {redo}") from None
    if not isinstance(summary, dict):
        raise FileFormatError(f"{summary_path}: holds a {type(summary).__name__}, not the "
                              f"run's summary object. {redo}")
    for key in ("suite", "thresholds"):
        if summary.get(key) is not None and not isinstance(summary[key], dict | str):
            raise FileFormatError(f"{summary_path}: {key!r} is a "
                                  f"{type(summary[key]).__name__}. {redo}")
    try:
        episodes = pd.read_parquet(episodes_path)
    except Exception as err:  # pyarrow raises several kinds for a damaged file
        raise FileFormatError(f"{episodes_path}: not a readable Parquet table "
                              f"({type(err).__name__}: {err}). {redo}") from None
    missing = [c for c in ("env", "policy", "seed", "status") if c not in episodes.columns]
    if missing:
        raise FileFormatError(f"{episodes_path}: not an episode table (no "
                              f"{', '.join(missing)} column). {redo}")
    return summary, episodes


def run_viewer(folder: str | os.PathLike, output: str | os.PathLike | None = None) -> Path:
    """Write (again) the replay viewer of a finished run folder.

    Reads ``trajectories.parquet`` and, when there, ``segments.parquet``, ``roads.parquet``
    and ``novel_labels.parquet`` (older runs lack the first two: the egos are labelled again
    with the run's thresholds and the roads rebuilt from its suite).

    Args:
        folder: the run folder.
        output: the viewer folder (default ``<folder>/viewer``).

    Returns:
        the path of the viewer's ``index.html``.

    Raises:
        FileFormatError: the folder is not a finished run, or has no trajectories.
    """
    folder = Path(folder)
    summary, episodes = read_run(folder)
    traj_path = folder / "trajectories.parquet"
    if not traj_path.is_file():
        raise FileFormatError(f"{folder}: no trajectories.parquet to replay; run the suite "
                              "again without --no-trajectories.")
    optional = {name: pd.read_parquet(folder / f"{name}.parquet")
                if (folder / f"{name}.parquet").is_file() else None
                for name in ("segments", "roads", "novel_labels")}
    return write_run_viewer(output if output is not None else folder / "viewer", summary,
                            episodes, pd.read_parquet(traj_path), **optional)
