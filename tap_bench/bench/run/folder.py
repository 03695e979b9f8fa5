"""A run folder: written atomically (tables, ``summary.json``, plots, report, replay
viewer), read back, checked before any work, and the provenance it records (policy
definitions with model hashes, resolved env configs, package versions, machine). The
folder's layout is described in :mod:`tap_bench.bench.run.runner`."""

from __future__ import annotations

import hashlib
import json
import os
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tap_bench.bench.spill import TrajectorySpill
from tap_bench.errors import (
    FileFormatError,
)
from tap_bench.sim.policies import PolicyDefinition
from tap_bench.sim.scenario_format import Scenario
from tap_bench.sim.womd_scene import WomdScenes
from tap_bench.tableio import atomic_folder, atomic_path, check_folder_output

if TYPE_CHECKING:
    import pandas as pd

    from tap_bench.bench.cache import EpisodeCache
    from tap_bench.bench.scores.scoring import Scores


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
                  episodes: pd.DataFrame, labels: pd.DataFrame,
                  trajectories: pd.DataFrame | TrajectorySpill | None, scores: Scores,
                  report: bool = True, *,
                  segments: pd.DataFrame | None = None, roads: pd.DataFrame | None = None,
                  cache: EpisodeCache | None = None,
                  pages: dict[str, bytes] | None = None) -> Path:
    """Write a results folder (tables, ``summary.json``, plots, report, and the replay
    viewer when the trajectories are given) atomically.

    The folder is built under a temporary name beside ``output`` and renamed into place
    when complete (:func:`tap_bench.tableio.atomic_folder`); an existing ``output`` is
    replaced only when ``overwrite`` is True and tap-bench wrote it. With a ``cache``, the
    figures and the viewer's episode data of unchanged inputs are read from it
    (:func:`tap_bench.bench.cache.memoised`): the files are the same.

    Args:
        pages: a dict to fill with the pages that name the run (the report and the viewer's
            index) as templates (:func:`tap_bench.bench.report.pages.page_templates`): the
            run is kept whole in the cache, and a re-run fills them with its own name, time
            and timings. The files written are the same either way.

    Raises:
        RunExistsError: ``output`` exists and ``overwrite`` is False.
        OutputPathError: ``output`` is a file, a link or a folder tap-bench did not write.
    """
    from tap_bench.bench.report.page import write_report
    from tap_bench.bench.report.pages import page_templates
    from tap_bench.bench.report.viewer import write_run_viewer

    with atomic_folder(output, overwrite, kind="run") as tmp:
        episodes.to_parquet(tmp / "episodes.parquet", index=False)
        if len(labels):
            labels.to_parquet(tmp / "labels.parquet", index=False)
        if isinstance(trajectories, TrajectorySpill):  # joined from disk, a part at a time
            trajectories.write(tmp / "trajectories.parquet")
            trajectories = trajectories.table() if report else None  # the viewer's
        elif trajectories is not None and len(trajectories):
            trajectories.to_parquet(tmp / "trajectories.parquet", index=False)
        for name, table in (("segments", segments), ("roads", roads)):
            if table is not None and len(table):
                table.to_parquet(tmp / f"{name}.parquet", index=False)
        for name, table in scores.tables().items():
            if len(table):
                _parquet_safe(table).to_parquet(tmp / f"{name}.parquet", index=False)
        _write_json(tmp / "summary.json", summary)
        with page_templates(tmp, summary, pages) as shown:  # what the pages say of the run
            viewer = report and trajectories is not None and len(trajectories) > 0
            if viewer:
                write_run_viewer(tmp / "viewer", shown, episodes, trajectories,
                                 segments=segments, roads=roads,
                                 novel_labels=scores.novel_labels, cache=cache)
            if report:
                write_report(tmp, shown, episodes, scores, viewer="viewer/index.html"
                             if viewer else None, cache=cache)
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
