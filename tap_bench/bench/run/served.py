"""A run served whole from the episode cache: when every input of a ``bench run`` is the same
as an earlier run's, its run folder is written from what that run wrote, with no episode
read, nothing scored, drawn or rendered, and without importing the scoring, the report or
the replay viewer (part of :mod:`tap_bench.bench.run.runner`).

**The key** is a :func:`~tap_bench.bench.cache.derived_key` of kind ``runs`` (so it holds
the code of the whole package and the versions of NumPy, pandas, PyArrow and SciPy) over
:func:`run_inputs`:

- every episode of the run, in order, as (env, policy, seed, its label key): the label key
  (:func:`~tap_bench.bench.cache.label_key`) holds the episode key (the env's scenario
  fingerprint with its files and vehicle code, the policy's fingerprint with its files,
  model and code, the seed, the simulation code and versions), the thresholds, the level,
  the code of labelling and measures with the run's measure entries, and the map the ego is
  labelled along: the run entry is at least as strict as the episode and label entries;
- each env's scenario fingerprint (the roads the viewer draws) and each policy's;
- the suite as resolved (every field, seeds given on the command line included; its gate
  and bootstrap settings), the gate's metrics, the run's measure entries, the thresholds;
- the outputs asked for (trajectories, report);
- the versions of every package the run records or computes with, and Python's;
- the package's files that are not Python (the viewer's page, script and style, copied into
  every run folder).

A run is never served from, nor kept in, the cache when it has reference corpora (their
files are read and labelled each run), plug-ins or a measure, scene measure, policy kind or
scenario kind registered by code outside tap-bench and highway-env (a user's script:
:func:`registered_outside`; code the key cannot hold), a policy, policy kind, scenario kind
or vehicle class of the user's code (it may load modules by name as it runs, which only its
episode and label entries record: :func:`tap_bench.usercode.loaded_user_code`), recorded
scenes (their maps and
signals are read from the scenes' files), an episode that cannot be cached (a policy
registered in Python, code without source), or a failed episode (it is tried again next
run).

**The entry** (``<cache>/derived/runs/``, verified whole like every derived entry: header
checksum, key, each file's SHA-256; a damaged one is deleted and the run made in full)
holds every file of the run folder but ``summary.json`` and the folder's marker; the two
pages that name the run, ``report.html`` and the viewer's ``data/index.js``, as templates
with placeholders for the run's name, its time and its timings (:func:`page_templates`,
:func:`fill_page`); ``summary.json`` without those; the episode table (Arrow IPC) and the
scores (:func:`~tap_bench.bench.scores.scoring.scores_to_files`), which :class:`RunResult` reads
when asked.

**Serving** (:func:`serve_run`) writes a fresh run folder atomically
(:func:`tap_bench.tableio.atomic_folder`: an existing folder is replaced only with
``overwrite``), with the run's own name, time, suite file, versions, machine, timings and
cache facts in ``summary.json`` (``cache.run``: ``"served whole"``), the report and viewer
filled with them. Every other file is byte for byte the earlier run's, which is byte for
byte what this run would have written (``tests/bench/test_run_cache.py``).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import re
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tap_bench.bench.cache import (
    EpisodeCache,
    _arrow_bytes,
    _arrow_table,
    _version,
    derived_key,
    note_refused,
    package_code_holds,
    policy_fingerprint,
    scenario_fingerprint,
)
from tap_bench.bench.report.pages import PAGES, fill_page, page_templates, timings_html
from tap_bench.bench.run.folder import RunResult

if TYPE_CHECKING:
    import pandas as pd

    from tap_bench.bench.run.plan import SuitePlan, _Task
    from tap_bench.bench.scores.scoring import Scores

__all__ = ["RUN_FORMAT", "fill_page", "page_templates",
           "keep_run", "run_files", "run_inputs", "serve_run", "serve_unchanged",
           "timings_html", "try_served"]

RUN_FORMAT = 1
"""Layout of a run entry's files; raised when it changes (old entries then miss)."""
VERSIONED = ("tap-bench", "numpy", "pandas", "pyarrow", "scipy", "numba", "gymnasium",
             "highway-env", "matplotlib", "stable-baselines3", "torch", "protobuf")
"""Packages whose versions key a run entry (those ``summary.json`` records among them)."""
FRESH = ("run", "created", "suite_file", "versions", "machine", "timings", "estimate", "cache")
"""The summary fields a served run writes afresh: what names and describes this run."""
_FOLDER_FILES = ("summary.json", ".tap-bench-folder")
_PACKAGE_DATA: list[str] = []


def package_data() -> str:
    """The SHA-256 of every file of the tap-bench package that is not Python source (names
    and bytes; caches and a wheel's copied catalogue, which the fingerprints hash, left
    out), once a process."""
    if not _PACKAGE_DATA:
        _PACKAGE_DATA.append(_package_data_digest())
    return _PACKAGE_DATA[0]


def package_data_holds() -> bool:
    """Whether the package's data files (the viewer's page, script and style, the report's
    templates) still hash as :func:`package_data` found them: a run whose viewer was made
    from files edited while it went on is not kept under the key of the files it started
    with (as :func:`tap_bench.bench.cache.package_code_holds` for the modules)."""
    return not _PACKAGE_DATA or _package_data_digest() == _PACKAGE_DATA[0]


def _package_data_digest() -> str:
    """SHA-256 of the names and bytes of tap-bench's files that are not Python source."""
    package = Path(__file__).resolve().parent.parent
    digest = hashlib.sha256()
    for path in sorted(package.rglob("*")):
        rel = path.relative_to(package)
        if (path.suffix in (".py", ".pyc") or not path.is_file()
                or rel.parts[0] == "_catalogue" or "__pycache__" in rel.parts):
            continue
        digest.update(rel.as_posix().encode() + b"\0")
        digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()


_ENTRY_POINT = re.compile(r"^([A-Za-z_][\w.]*):[\w.]+$")


def registered_outside() -> list[str]:
    """The entries of the registries a run reads (policy kinds, scenario kinds, measures,
    scene measures) whose code is not tap-bench's or highway-env's (registered by a
    plug-in or by the user's own script): what the key of a whole run cannot hold."""
    import dataclasses

    from tap_bench.bench.measures import MEASURES, SCENE_MEASURES
    from tap_bench.sim.policies import POLICY_KINDS
    from tap_bench.sim.schema import SCENARIO_KINDS
    from tap_bench.usercode import TRUSTED_PACKAGES

    out = []
    for registry in (POLICY_KINDS, SCENARIO_KINDS, MEASURES, SCENE_MEASURES):
        for name, entry in list(registry._entries.items()):
            values = [type(entry), *(getattr(entry, f.name) for f in dataclasses.fields(entry))]
            for value in values:
                if isinstance(value, str):
                    match = _ENTRY_POINT.match(value)
                    module = match.group(1) if match else None
                else:
                    module = getattr(value, "__module__", None) if callable(value) else None
                if module is not None and module.split(".")[0] not in TRUSTED_PACKAGES:
                    out.append(f"{registry.what} {name} ({module})")
    return out


def run_inputs(plan: SuitePlan, tasks: Sequence[_Task], *, keep_trajectories: bool,
               report: bool, corpora: bool = False) -> dict[str, Any] | None:
    """What the outputs of a run depend on besides the code (module docstring), or None for
    a run that is never kept whole.

    Args:
        plan: the resolved suite.
        tasks: the run's episodes, keyed (:func:`tap_bench.bench.run.plan._tasks` with a
            cache).
        keep_trajectories, report: the outputs asked for.
        corpora: whether the run has reference corpora.
    """
    if (corpora or plan.plugins or plan.recorded or not tasks
            or any(t.key is None or t.label_key is None for t in tasks)
            or registered_outside()):
        return None
    # every task is keyed: its key's document holds both fingerprints
    envs = {t.env: (t.key_doc or {})["env"] for t in tasks}
    policies = {t.policy: (t.key_doc or {})["policy"] for t in tasks}
    if any(v is None for v in (*envs.values(), *policies.values())):
        return None
    if (any(p.get("code") or p.get("builder") for p in policies.values())
            or any(e.get("kind") or any(e.get("vehicle_code", {}).values())
                   for e in envs.values())):
        return None  # the user's code may load modules by name: only its entries know them
    thresholds = plan.thresholds
    return {"format": RUN_FORMAT, "suite": dict(plan.document), "level": plan.level,
            "thresholds": thresholds.to_dict() if hasattr(thresholds, "to_dict")
            else str(thresholds),
            "measures": [m.to_dict() for m in plan.measures],
            "gate_metrics": list(plan.gate_metrics), "envs": envs, "policies": policies,
            "episodes": [[t.env, t.policy, int(t.seed), t.label_key] for t in tasks],
            "outputs": {"trajectories": bool(keep_trajectories), "report": bool(report)},
            "versions": {**{pkg: _version(pkg) for pkg in VERSIONED},
                         "python": sys.version}, "package_data": package_data()}


def _inputs_hold(plan: SuitePlan, whole: Mapping[str, Any]) -> bool:
    """Whether the run's scenarios and policies are still as its inputs ``whole`` (those it
    started with, :func:`run_inputs`) hold them, their fingerprints taken again: a policy's
    model or module changed while the run went on would be kept under the old content's
    key. False too when they cannot be read now (a policy or scenario file removed or
    unreadable), which costs only reuse, never the run's results. The other inputs are read
    once a process (the versions, the package's data files) or checked as the run is kept
    (what is registered outside tap-bench, tap-bench's code: :func:`run_files`)."""
    try:
        envs = {env: scenario_fingerprint(plan.scenarios[env], env) for env in plan.envs}
        policies = {d.name: policy_fingerprint(d) for d in plan.definitions}
    except Exception:  # any failure to fingerprint: not kept whole, the results written
        return False
    return envs == whole["envs"] and policies == whole["policies"]


# -- keeping and serving a run -----------------------------------------------------------

def keep_run(cache: EpisodeCache, plan: SuitePlan, tasks: Sequence[_Task] | None,
             whole: Mapping[str, Any] | None, result: RunResult,
             pages: Mapping[str, bytes] | None) -> None:
    """The cache's part of the end of a run whose folder is written: ``result`` kept whole
    for an unchanged re-run when it may be (``whole``: its :func:`run_inputs` at the start,
    None: never kept), its page templates were made (``pages``), every episode was made (a
    failed one is tried again) and its inputs still hold (:func:`_inputs_hold`); its files
    (:func:`run_files`) are stored atomically under ``whole``'s key, nothing when they
    cannot be (a full disk: the run is written, the cache is a convenience)."""
    if (pages is None or whole is None or tasks is None
            or not (result.episodes["status"] == "ok").all()):
        return
    files = run_files(result.folder, result.summary, pages, result.episodes, result.scores)
    if files is None or not _inputs_hold(plan, whole):
        return
    key, doc = derived_key("runs", whole)
    with contextlib.suppress(OSError, ValueError):
        cache.put_derived("runs", key, doc, files)


def _plain_json(doc: Any) -> bytes:
    from tap_bench.bench.run.folder import _json_default

    return json.dumps(doc, default=_json_default).encode()


def run_files(folder: Path, summary: Mapping[str, Any], pages: Mapping[str, bytes],
              episodes: pd.DataFrame, scores: Scores) -> dict[str, bytes] | None:
    """What keeps the run written to ``folder`` whole in the cache (name -> bytes, the
    entry's files: module docstring); ``pages``: its page templates
    (:func:`page_templates`). None when it cannot be kept: something was registered
    outside tap-bench or tap-bench's code or data files were edited while the run went on,
    or a page that names the run has no template."""
    from tap_bench.bench.scores.scoring import scores_to_files

    if registered_outside():  # registered while the run went on (a policy's own import)
        return None
    if not package_code_holds() or not package_data_holds():  # edited while the run went on
        return None
    files: dict[str, bytes] = {}
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder).as_posix()
        if path.is_symlink() or not path.is_file() or rel in _FOLDER_FILES:
            continue
        files[f"run/{rel}"] = pages.get(rel, b"") if rel in PAGES else path.read_bytes()
    if "nonce" not in pages or any(f"run/{name}" in files and name not in pages
                                   for name in PAGES):
        return None
    files["pages.json"] = json.dumps({"nonce": pages["nonce"].decode()}).encode()
    files["summary.json"] = _plain_json({k: None if k in FRESH else v  # in order
                                         for k, v in summary.items()})
    files["episodes.arrow"] = _arrow_bytes(episodes)
    files.update({f"scores/{name}": data for name, data in scores_to_files(scores).items()})
    return files


def serve_run(cache: EpisodeCache, inputs: Mapping[str, Any], output: Path, overwrite: bool,
              fresh: Mapping[str, Any], started: float,
              announce: Callable[[str], None] | None = None) -> RunResult | None:
    """The run of ``inputs`` written to ``output`` from the cache, or None when the cache
    does not hold it whole (then the run is made in full and kept).

    Args:
        cache: the episode cache.
        inputs: :func:`run_inputs` of this run.
        output: the run folder (checked: :func:`tap_bench.tableio.check_folder_output`).
        overwrite: replace an earlier run folder there.
        fresh: this run's own summary fields (:func:`~tap_bench.bench.run.folder.
            fresh_facts`; ``timings`` and ``cache`` are filled here).
        started: :func:`time.perf_counter` at the start of the run [s].
        announce: told that the run is served, and from which entry.
    """
    from tap_bench.bench.run.folder import _write_json
    from tap_bench.tableio import atomic_folder

    t0 = time.perf_counter()
    key, _ = derived_key("runs", inputs)
    files, note = cache.read_derived("runs", key)
    if note is not None:
        note_refused(note)
    if files is None:
        return None
    try:
        nonce = json.loads(files["pages.json"])["nonce"]
        kept = json.loads(files["summary.json"])
        if (not isinstance(kept, dict) or not isinstance(nonce, str)
                or "n_episodes" not in kept or "episodes.arrow" not in files):
            raise ValueError("not a run entry")
    except (KeyError, ValueError, UnicodeDecodeError) as err:
        with contextlib.suppress(OSError):  # whatever is wrong with it, the run is made
            cache.derived_path("runs", key).unlink()
        note_refused(f"derived entry {cache.derived_path('runs', key).name} refused and "
                     f"deleted: not a run entry ({type(err).__name__})")
        return None
    if announce is not None:
        announce(f"suite {kept.get('suite', {}).get('name', '')}: every input as in an "
                 f"earlier run; its {kept['n_episodes']} episodes, scores, report and viewer "
                 f"are served from the cache (run entry {key[:12]})")
    n = int(kept["n_episodes"])
    summary = {**kept, **fresh}  # in the order a made run writes them
    summary["timings"] = {"reading_the_run_entry": time.perf_counter() - t0}
    summary["cache"] = {"dir": str(cache.root), "cached": n, "simulated": 0,
                        "labelled_before": n, "refused": [], "run": "served whole",
                        "run_entry": key}
    with atomic_folder(output, overwrite, kind="run") as tmp:
        for name, data in files.items():
            if not name.startswith("run/"):
                continue
            rel = name[len("run/"):]
            if rel in PAGES:
                data = fill_page(rel, data, nonce, summary)
            target = tmp / rel
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(data)
        summary["timings"]["total"] = time.perf_counter() - started
        _write_json(tmp / "summary.json", summary)
    episodes = files["episodes.arrow"]
    scored = {name[len("scores/"):]: data for name, data in files.items()
              if name.startswith("scores/")}

    def scores() -> Scores:
        from tap_bench.bench.scores.scoring import scores_from_files

        return scores_from_files(scored)

    return RunResult(Path(output), summary, lambda: _arrow_table(episodes), scores,
                     Path(output) / "report.html")


def _check_apart(output: Path, cache_root: Path) -> None:
    """The run folder and the episode cache must not hold one another: ``--overwrite``
    would delete the cache with the run, or the cache's files would fill the run folder.

    Raises:
        OutputPathError: naming both folders.
    """
    from tap_bench.errors import OutputPathError

    out, root = Path(output).resolve(), Path(cache_root).expanduser().resolve()
    if out == root or root in out.parents or out in root.parents:
        raise OutputPathError(f"{output}: the run folder and the episode cache ({cache_root}) "
                              "overlap; give the run folder (-o) and the cache (--cache) "
                              "separate places.")


def try_served(plan: SuitePlan, tasks: Sequence[_Task], cache: EpisodeCache | None,
               output: Path, overwrite: bool, keep_trajectories: bool, report: bool,
               corpora: bool, started: float, announce: Callable[[str], None] | None = None
               ) -> tuple[RunResult | None, dict[str, Any] | None]:
    """(the run served whole from ``cache`` or None, its :func:`run_inputs` when it may be
    kept whole): the step of :func:`~tap_bench.bench.run.runner.run_suite` after its tasks
    are made (``tasks``, :func:`tap_bench.bench.run.plan._tasks`), which goes on with them
    when nothing was served, and keeps the run under these inputs when it is done."""
    if cache is None or corpora or plan.plugins or plan.recorded:
        return None, None
    from tap_bench.bench.run.folder import fresh_facts

    inputs = run_inputs(plan, tasks, keep_trajectories=keep_trajectories, report=report)
    if inputs is None:
        return None, None
    return (serve_run(cache, inputs, output, overwrite, fresh_facts(plan, output), started,
                      announce), inputs)


def serve_unchanged(suite: Any, output: str | Path, *, cache: EpisodeCache | None,
                    keep_trajectories: bool = True, overwrite: bool = False,
                    report: bool = True, seeds: Any = None, corpora: bool = False,
                    plugins: Sequence[str] = (),
                    announce: Callable[[str], None] | None = None) -> RunResult | None:
    """The run :func:`~tap_bench.bench.run.runner.run_suite` would write with these arguments,
    when it can be served whole from ``cache``; else None, having imported only what
    resolving the suite needs (the command line tries this first; ``run_suite`` then does
    the rest). Same checks and errors as ``run_suite`` (the output folder first)."""
    import warnings

    from tap_bench.bench.run.folder import check_output
    from tap_bench.bench.run.plan import _tasks, plan_suite
    from tap_bench.errors import CacheEntryWarning

    if cache is None or corpora or plugins:
        return None
    started = time.perf_counter()
    output = check_output(output, overwrite, announce)
    with warnings.catch_warnings(record=True) as said:  # run_suite says them if it runs
        warnings.simplefilter("always")
        plan = plan_suite(suite, plugins=plugins, seeds=seeds)
        _check_apart(output, cache.root)
        if plan.plugins or plan.recorded:  # never served: no tasks made for it
            return None
        served, _ = try_served(plan, _tasks(plan, keep_trajectories, cache), cache, output,
                               overwrite, keep_trajectories, report, corpora, started,
                               announce)
    for warning in said:  # a refused entry is said either way (run_suite lists it)
        if served is not None or issubclass(warning.category, CacheEntryWarning):
            warnings.warn_explicit(warning.message, warning.category, warning.filename,
                                   warning.lineno)
    return served
