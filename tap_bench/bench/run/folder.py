"""A run folder: written atomically (tables, ``summary.json``, plots, report, replay
viewer), read back, checked before any work, and the provenance it records (policy
definitions with model hashes, resolved env configs, package versions, machine). The
folder's layout is described in :mod:`tap_bench.bench.run.runner`."""

from __future__ import annotations

import copy
import hashlib
import json
import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tap_bench.bench.run.spill import SpilledEpisodes, SpilledTable
from tap_bench.errors import (
    FileFormatError,
)
from tap_bench.sim.policies import PolicyDefinition
from tap_bench.sim.scenario_format import Scenario
from tap_bench.sim.womd_scene import WomdScenes
from tap_bench.tableio import (
    atomic_folder,
    atomic_path,
    check_folder_output,
    remove_abandoned,
)

if TYPE_CHECKING:
    import pandas as pd

    from tap_bench.bench.cache import EpisodeCache
    from tap_bench.bench.run.estimate import RunPlan
    from tap_bench.bench.run.plan import SuitePlan
    from tap_bench.bench.scores.scoring import Scores


class RunResult:
    """What :func:`~tap_bench.bench.run.runner.run_suite` returns.

    Attributes:
        folder: the run folder written.
        summary: the content of ``summary.json``.
        episodes: the episode table.
        scores: the scored tables.
        report: path of ``report.html``.

    A run served from the cache (:func:`~tap_bench.bench.run.served.serve_run`) reads its
    episode table and scores from the cache entry when first asked for them.
    """

    __slots__ = ("_episodes", "_scores", "folder", "report", "summary")

    def __init__(self, folder: Path, summary: dict[str, Any],
                 episodes: pd.DataFrame | Callable[[], pd.DataFrame],
                 scores: Scores | Callable[[], Scores], report: Path) -> None:
        self.folder, self.summary, self.report = folder, summary, report
        self._episodes, self._scores = episodes, scores

    @property
    def episodes(self) -> pd.DataFrame:
        if callable(self._episodes):
            self._episodes = self._episodes()
        return self._episodes

    @property
    def scores(self) -> Scores:
        if callable(self._scores):
            self._scores = self._scores()
        return self._scores

    def __repr__(self) -> str:
        return f"RunResult(folder={str(self.folder)!r}, report={str(self.report)!r})"


def check_output(output: str | os.PathLike, overwrite: bool,
                 announce: Callable[[str], None] | None = None) -> Path:
    """``output`` as a Path, checked before any work (:func:`tap_bench.tableio.
    check_folder_output`): a new folder in a writable place, or, with ``overwrite``, a run
    folder tap-bench wrote. The temporary folders that runs into ``output`` killed while
    writing it left beside it are removed (:func:`tap_bench.tableio.remove_abandoned`: only
    those whose owner process is provably gone), and ``announce`` told so in one line.

    Raises:
        RunExistsError: naming the folder and the flag that replaces it.
        OutputPathError: the place is not writable, or ``output`` is a file, a link or a
            folder tap-bench did not write.
    """
    path = check_folder_output(output, overwrite)
    removed = remove_abandoned(path)
    if removed and announce is not None:
        announce(f"removed {len(removed)} folder(s) that killed runs left beside {path}: "
                 + ", ".join(folder.name for folder in removed))
    return path


def package_versions() -> dict[str, str]:
    """Versions of tap-bench and the packages its results depend on (those installed; each
    read once a process)."""
    from tap_bench.bench.cache import _version

    versions = {pkg: _version(pkg) for pkg in (
        "tap-bench", "numpy", "pandas", "pyarrow", "gymnasium", "highway-env", "matplotlib",
        "stable-baselines3", "torch")}
    return {pkg: version for pkg, version in versions.items() if version != "absent"}


def _machine() -> dict[str, Any]:
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = []
    return {"cores": os.cpu_count(), "load_avg": load, "python": sys.version.split()[0]}


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def provenance(definitions: Sequence[PolicyDefinition],
               scenarios: Mapping[str, Scenario | WomdScenes]) -> dict[str, Any]:
    """What every policy and env of a run is, in full, so that ``bench check`` can say what
    changed since a baseline.

    Args:
        definitions: the run's policy definitions (a run plan's ``definitions``).
        scenarios: env -> its scenario or recorded scenes (a run plan's ``scenarios``).

    Returns:
        ``{"policies": {name: {"kind", "params", "model_sha256"?, "code_sha256"?}},
        "envs": {name: {"highway_env_id", "version", "duration", "lane_change", "config",
        "script"?, "vehicle_code_sha256"?}}}``; a model file's SHA-256 is taken from the
        file its definition names; ``code_sha256`` (kind ``import``) and
        ``vehicle_code_sha256`` (a user class as ``other_vehicles_type``) hash the code they
        load in the user's package (:func:`tap_bench.usercode.code_digest`); ``script`` is
        the scenario's scripted event, so that ``bench check`` names an env whose cut-in
        or braking changed.
    """
    from tap_bench.sim.scenario_format import VEHICLE_TYPE_KEYS
    from tap_bench.usercode import TRUSTED_PACKAGES, code_digest

    policies = {}
    for definition in definitions:
        name = definition.name
        entry: dict[str, Any] = {"kind": definition.kind, "params": dict(definition.params)}
        model = definition.params.get("model")
        if isinstance(model, str):
            path = Path(model)
            if not path.is_absolute() and definition.path is not None:
                path = definition.path.parent / path
            entry["model_sha256"] = _sha256(path) if path.is_file() else "(missing file)"
        factory = definition.params.get("factory")
        if definition.kind == "import" and isinstance(factory, str):
            code = code_digest(factory.partition(":")[0])
            entry["code_sha256"] = code["sha256"] if code else "(no Python source)"
        policies[name] = json.loads(json.dumps(entry, default=str))
    envs = {}
    for env, scenario in scenarios.items():
        if isinstance(scenario, WomdScenes):  # recorded scenes: files, each scene's hash
            envs[env] = {"womd": list(scenario.files), "traffic": scenario.traffic,
                         "ego": scenario.ego, "policy_frequency": scenario.policy_frequency,
                         "scenarios": {str(ref): ref.digest() for ref in scenario.catalog()}}
            continue
        entry = {"highway_env_id": scenario.highway_env_id, "version": scenario.version,
                 "duration": scenario.duration, "lane_change": scenario.lane_change,
                 "config": scenario.config}
        if scenario.script is not None:
            entry["script"] = scenario.script.to_dict()
        for key in VEHICLE_TYPE_KEYS:
            module = str(scenario.config.get(key, "")).rpartition(".")[0]
            if module and module.split(".")[0] not in TRUSTED_PACKAGES:
                code = code_digest(module)
                entry.setdefault("vehicle_code_sha256", {})[key] = (
                    code["sha256"] if code else "(no Python source)")
        envs[env] = json.loads(json.dumps(entry, default=str))
    return {"policies": policies, "envs": envs}


def fresh_facts(plan: SuitePlan, output: Path) -> dict[str, Any]:
    """The summary fields that name and describe one run: its folder's name, its time, the
    suite file, the package versions, the machine, and (for a run served from the cache)
    the estimate."""
    return {"run": Path(output).name, "created": time.strftime("%Y-%m-%d %H:%M:%S"),
            "suite_file": plan.suite_file,
            "versions": package_versions(), "machine": _machine(),
            "estimate": {"seconds": None, "overhead": None,
                         "basis": "served whole from the cache"}}


def run_summary(plan: SuitePlan, output: Path, sources: Mapping[str, Any],
                episodes: pd.DataFrame, scores: Scores, timings: dict[str, float],
                estimate: RunPlan, cache: dict[str, Any] | None,
                realism: list[dict[str, Any]]) -> dict[str, Any]:
    """``summary.json``: what ran (the suite, seeds, thresholds, references by name: a label
    table, a path or a list of paths), on what, how it scored, and how long it took
    (``timings`` [s], ``estimate``); ``cache``: its part (None: no cache)."""
    from tap_bench.bench.scores.verdict import one_outcome_cells, verdict_table

    failed = episodes[~episodes["status"].isin(("ok", "skipped"))]  # skipped: no route
    skipped = episodes[episodes["status"] == "skipped"]
    facts = fresh_facts(plan, output)
    described = provenance(plan.definitions, plan.scenarios)
    # what the scores say: the cells with one outcome, the verdict, the headline figures
    one_outcome = one_outcome_cells(episodes).to_dict("records")
    verdict = verdict_table(scores.paired_measures, scores.paired,
                            scores.paired_labels).to_dict("records")
    headline = _headline(scores, episodes)
    thresholds = plan.thresholds
    return {
        "format": "tap-bench-run", "format_version": 1,
        "run": facts["run"], "created": facts["created"],
        "suite": copy.deepcopy(dict(plan.document)), "suite_file": facts["suite_file"],
        "level": plan.level,
        "seeds": copy.deepcopy(plan.document["seeds"]),
        "thresholds": thresholds.to_dict() if hasattr(thresholds, "to_dict") else
        str(plan.document["thresholds"]),
        "reference_policy": plan.reference,
        "references": {name: _describe_source(source) for name, source in sources.items()},
        "versions": facts["versions"], "machine": facts["machine"],
        "n_episodes": len(episodes), "n_failed": len(failed),
        "failed": failed[["env", "policy", "seed", "error"]].to_dict("records"),
        "n_skipped": len(skipped),
        "skipped": skipped[["env", "policy", "seed", "error"]].to_dict("records"),
        "methods": scores.methods,
        "headline": headline,
        "one_outcome_cells": one_outcome,
        "verdict": verdict,
        "provenance": described,
        "measures": [m.to_dict() for m in plan.measures],
        "plugins": list(plan.plugins),
        "realism": realism,
        "timings": timings,
        "estimate": {"seconds": _round(estimate.seconds),
                     "overhead": _round(estimate.overhead_seconds), "basis": estimate.basis},
        "cache": cache,
    }


def _describe_source(source: Any) -> Any:
    import pandas as pd

    if isinstance(source, pd.DataFrame):
        return f"a label table of {len(source)} rows"
    if isinstance(source, str | os.PathLike):
        return str(source)
    return [str(p) for p in source]


def _headline(scores: Scores, episodes: pd.DataFrame) -> dict[str, Any]:
    """Per policy, pooled over envs: each measure's mean with its interval (``<measure>``,
    ``<measure>_low``, ``<measure>_high``), coverage of the reference and, where the
    same-policy null was computed, the figures at half sizes it compares (``<coverage
    key>: same-policy figure``, ``: policy at halves``, ``: difference`` = policy at halves
    minus same-policy figure, with ``_low`` / ``_high``)."""
    import numpy as np

    out: dict[str, Any] = {}
    m = scores.measures
    pooled_env = "all" if (m["env"] == "all").any() else m["env"].iloc[0] if len(m) else ""
    for policy in sorted(episodes["policy"].unique()):
        row: dict[str, Any] = {}
        sub = m[(m["policy"] == policy) & (m["env"] == pooled_env)]
        for r in sub.itertuples():
            row[r.measure] = _round(r.mean)
            row[f"{r.measure}_low"] = _round(r.low)
            row[f"{r.measure}_high"] = _round(r.high)
        cov = scores.coverage
        if len(cov):
            c = cov[(cov["policy"] == policy) & (cov["env"] == pooled_env)]
            for r in c.to_dict("records"):
                seg = str(r.get("unit", "")).endswith("segments")
                key = f"{'segment ' if seg else ''}coverage of {r['reference']}"
                row[key] = _round(r["coverage"])
                if np.isfinite(r.get("coverage_diff", np.nan)):  # the same-policy null
                    row[f"{key}: same-policy figure"] = _round(r["null_coverage"])
                    row[f"{key}: policy at halves"] = _round(r["half_coverage"])
                    row[f"{key}: difference"] = _round(r["coverage_diff"])
                    row[f"{key}: difference_low"] = _round(r["coverage_diff_low"])
                    row[f"{key}: difference_high"] = _round(r["coverage_diff_high"])
        out[policy] = row
    return out


def _round(x: float) -> float | None:
    import numpy as np

    return None if x is None or not np.isfinite(x) else round(float(x), 4)


def _write_json(path: Path, doc: dict[str, Any]) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(doc, indent=2, default=_json_default) + "\n")


def _json_default(value: Any) -> Any:
    import numpy as np

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
                  episodes: pd.DataFrame, labels: pd.DataFrame | SpilledTable,
                  trajectories: pd.DataFrame | SpilledTable | None, scores: Scores,
                  report: bool = True, *,
                  segments: pd.DataFrame | SpilledTable | None = None,
                  roads: pd.DataFrame | SpilledTable | None = None,
                  cache: EpisodeCache | None = None,
                  pages: dict[str, bytes] | None = None) -> Path:
    """Write a results folder (tables, ``summary.json``, plots, report, and the replay
    viewer when the trajectories are given) atomically.

    The folder is built under a temporary name beside ``output`` and renamed into place
    when complete (:func:`tap_bench.tableio.atomic_folder`); an existing ``output`` is
    replaced only when ``overwrite`` is True and tap-bench wrote it. With a ``cache``, the
    figures and the viewer's episode data of unchanged inputs are read from it
    (:func:`tap_bench.bench.cache.memoised`): the files are the same. Tables of a spilled
    run (:class:`~tap_bench.bench.run.spill.SpilledTable`) are joined from their parts a
    row group at a time.

    Args:
        pages: a dict to fill with the pages that name the run (the report and the viewer's
            index) as templates (:func:`tap_bench.bench.report.pages.page_templates`): the
            run is kept whole in the cache, and a re-run fills them with its own name, time
            and timings. The files written are the same either way.

    Raises:
        RunExistsError: ``output`` exists and ``overwrite`` is False.
        OutputPathError: ``output`` is a file, a link or a folder tap-bench did not write.
    """
    from tap_bench.bench.report.pages import page_templates
    from tap_bench.bench.scores.scoring import write_score_tables

    with atomic_folder(output, overwrite, kind="run") as tmp:
        episodes.to_parquet(tmp / "episodes.parquet", index=False)
        for name, table in (("labels", labels), ("trajectories", trajectories),
                            ("segments", segments), ("roads", roads)):
            _write_table(tmp / f"{name}.parquet", table)
        _write_json(tmp / "summary.json", summary)
        write_score_tables(scores, tmp)
        viewer = report and trajectories is not None and len(trajectories) > 0
        spilled = next((t.spill for t in (trajectories, roads)
                        if isinstance(t, SpilledTable)), None)
        if viewer and spilled is not None:  # the viewer reads a chunk at a time
            trajectories = SpilledEpisodes(spilled)
        with page_templates(tmp, summary, pages) as shown:  # what the pages say of the run
            if viewer:  # the viewer's imports (the map readers, numba) only when it is made
                from tap_bench.bench.report.viewer import write_run_viewer

                write_run_viewer(tmp / "viewer", shown, episodes, trajectories,
                                 segments=segments, roads=roads,
                                 novel_labels=scores.novel_labels, cache=cache)
            if report:
                from tap_bench.bench.report.page import write_report

                write_report(tmp, shown, episodes, scores, viewer="viewer/index.html"
                             if viewer else None, cache=cache)
    return Path(output)


def finish_summary(folder: Path, summary: dict[str, Any], refused: list[str]) -> None:
    """Write ``summary.json`` of the run folder ``folder`` again, as ``summary`` is at the
    end of the run (its final timings), with every cache entry refused in its ``cache``
    part: ``refused`` (the episodes') and the derived entries (roads, scores, plots,
    viewer, run) refused since (:func:`tap_bench.bench.cache.take_refused`)."""
    from tap_bench.bench.cache import take_refused

    if summary["cache"] is not None:
        summary["cache"]["refused"] = [*refused, *take_refused()]
    _write_json(folder / "summary.json", summary)


def _write_table(path: Path, table: pd.DataFrame | SpilledTable | None) -> None:
    """``table`` as Parquet at ``path`` (a spilled one joined from its parts); nothing for
    no rows."""
    if table is None or not len(table):
        return
    if isinstance(table, SpilledTable):
        table.write(path)
    else:
        table.to_parquet(path, index=False)


def read_run(folder: str | os.PathLike) -> tuple[dict[str, Any], pd.DataFrame]:
    """``summary.json`` and the episode table of a run folder.

    Raises:
        FileFormatError: the folder is not a finished run (no summary or episode table), or
            one of them is damaged: not JSON, not an object, not Parquet, columns missing.
    """
    import pandas as pd

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
    import pandas as pd

    from tap_bench.bench.report.viewer import write_run_viewer

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
