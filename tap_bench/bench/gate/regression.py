"""``bench check``: the regression gate of a run against a stored baseline.

A baseline file (JSON) keeps, for every (env, policy) of a suite, the per-episode values
the gate needs: the seed, the ego's SDL label and the measures
(:func:`~tap_bench.bench.suite.gate_metrics`), and
the provenance of the run (each policy's full definition, with the SHA-256 of a model
file, and each env's resolved config). The gate compares a run's episodes with the
baseline's, per (env, policy) and metric:

- measures: the change of the mean (run - baseline), read the worse way by the measure's
  registered direction (``higher_is_better``); label distribution: the total variation
  distance between the two ego label distributions (``label_tv``, in [0, 1]; no side);
- **one-sided tests** of "no change" against "worse":
  **paired** when the run and the baseline have the same seeds (the simulator is
  deterministic, so an unchanged policy gives the same episode on a seed): a sign-flip
  permutation test on the per-seed differences, over the seeds that differ only (exact
  when 2^k flips are no more than the permutations, else ``n_permutations`` random
  flips), for a rate McNemar's exact test; for ``label_tv`` run and baseline labels
  swapped within the seeds whose labels differ;
  **unpaired** otherwise: episodes exchanged between run and baseline; Fisher's exact
  test for a rate;
- **the weighted Holm correction** over every test of the check (:func:`weighted_holm`):
  each metric has a share of alpha in its cell (:attr:`GateConfig.weights`: crash rate
  0.65, TTC 0.1, headway 0.1, the rest 0.15 shared, the safety family first), and a test
  whose smallest attainable p-value is above its share is left out of the correction
  (Tarone): in a paired check an unchanged cell has no seed that differs and costs
  nothing, so a regression in one cell of a 25-cell suite is tested almost as if alone.
  The choice was made by simulation (``benchmarks/gate_calibration.py``);
- a metric **fails** when it moved the worse way by more than its margin *and* its
  adjusted p-value is below ``alpha``; a move the better way by more than the margin is
  reported as ``better``, never a failure;
- each test's **power** against a worsening of ``detect`` margins
  (:func:`tap_bench.bench.gate.power.rule_power`); a check whose power is below 80 % and below
  that of a check on the baseline's own seeds (fewer or other seeds) is
  **underpowered** and says so.

**A gate that can never fire is refused**: :func:`check` raises
:class:`~tap_bench.errors.ParameterError` (naming the numbers, what would do and the
definitions that changed) when no test could reach its share of alpha even in the most
favourable case, and :func:`write_baseline` refuses a baseline whose seeds could never
let a check fire.

On recorded scenes (episodes with ``crashed_at_fault``) the crash check counts at-fault
collisions (SPEC section 8, :func:`scene_stand_ins`): a policy hit from behind or while
stopped is not a regression; the report shows all collisions beside them.

An (env, policy) of the baseline missing from the run, with failed episodes in the run, or
whose policy or env definition changed since the baseline (named, with what changed),
fails too. A baseline whose metric is missing or not numeric is an error
(:func:`read_baseline`), and a run with no episode, or with more than
:data:`MAX_FAILED_SHARE` of its episodes failed, cannot become one (:func:`write_baseline`).
The baseline file changes only through :func:`write_baseline` (``--update-baseline``).
"""

from __future__ import annotations

import itertools
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tap_bench.bench.gate.power import POWER, rule_power
from tap_bench.bench.gate.statistics import direction, hypergeom_tails, is_rate, tv
from tap_bench.bench.measures import BOUND_TOLERANCE, MEASURES, SCENE_STANDS_IN
from tap_bench.bench.scores.compare import NO_LABEL
from tap_bench.bench.suite import GateConfig, gate_metrics
from tap_bench.errors import (
    BaselineError,
    BaselineMismatchError,
    FileFormatError,
    OutputPathError,
    ParameterError,
    UnknownNameError,
)
from tap_bench.stats.bootstrap import named_rng
from tap_bench.tableio import atomic_path

__all__ = ["BASELINE_FORMAT", "EXACT_FLIPS_MAX_SEEDS", "MAX_FAILED_SHARE", "GateResult",
           "check", "config_of", "definition_changes", "direction", "firing_floor", "holm",
           "read_baseline", "run_config", "smallest_p", "weighted_holm", "write_baseline"]

BASELINE_FORMAT = "tap-bench-baseline"
BASELINE_VERSION = 2
"""The baseline format this code writes and the newest it reads."""


def _episode_fields() -> tuple[str, ...]:
    return ("env", "policy", "seed", "sdl", *MEASURES.names())

_IDENTITY = ("suite", "suite_version", "level", "thresholds")
_GATE_FIELDS = ("alpha", "n_permutations", "seed", "margins", "weights", "detect")
MAX_FAILED_SHARE = 0.05
"""A run with more than this share of failed episodes cannot become a baseline: the
baseline would hold a different set of episodes per (env, policy) than the runs checked
against it, and a failure that is part of the behaviour must be fixed, not frozen."""
EXACT_FLIPS_MAX_SEEDS = 16
"""Up to this many differing paired seeds the sign-flip test may enumerate all 2^n flips
(exact p); it does when 2^n is at most the permutations it would otherwise draw."""


def _exact(k: int, config: GateConfig) -> bool:
    """Enumerate the 2^k flips (else draw ``n_permutations`` of them)."""
    return k <= EXACT_FLIPS_MAX_SEEDS and 2 ** k <= config.n_permutations + 1


@dataclass(frozen=True)
class GateResult:
    """What :func:`check` found.

    Attributes:
        table: one row per (env, policy, metric): env, policy, metric, direction (which
            way is better: higher, lower, none), test (paired/unpaired), n_baseline, n_run,
            baseline, run, change (run - baseline; for label_tv the TV), margin, p_value
            (one-sided, the worse way; the better way on a row whose verdict is better),
            p_min (the smallest p-value the test could give
            on these data), p_adjusted, verdict (worse, changed, better or
            empty), moved (the row fails the check), power (at the ``detect`` worsening),
            underpowered, note.
        moved: True when anything failed (the command then exits 1).
        config: the gate settings used.
    """

    table: pd.DataFrame
    moved: bool
    config: GateConfig

    def moved_rows(self) -> pd.DataFrame:
        """The rows that fail the check."""
        return self.table[self.table["moved"]]

    def better_rows(self) -> pd.DataFrame:
        """The rows that moved the better way (reported, never a failure)."""
        return self.table[self.table["verdict"] == "better"]

    def underpowered_rows(self) -> pd.DataFrame:
        """Rows that did not fail and whose power at the ``detect`` worsening is below
        :data:`tap_bench.bench.gate.power.POWER` and below the baseline's own design's."""
        return self.table[self.table["underpowered"].to_numpy(bool)
                          & ~self.table["moved"].to_numpy(bool)]

    @property
    def underpowered(self) -> bool:
        """Some check cannot catch the worsening it is asked to."""
        return not self.underpowered_rows().empty

    def format(self, *, all_rows: bool = False) -> str:
        """A plain-text verdict: what failed, what improved, what is underpowered (or every
        check)."""
        t = self.table
        kinds = sorted(set(t["test"].dropna()) - {""})
        head = (f"gate: {int(t['moved'].sum())} of {len(t)} checks failed, "
                f"{int((t['verdict'] == 'better').sum())} improved (fails = moved the worse "
                f"way beyond its margin and one-sided p < {self.config.alpha:g} after the "
                f"weighted Holm correction; {', '.join(kinds) or 'no'} tests)")
        cols = ["env", "policy", "metric", "test", "baseline", "run", "change", "margin",
                "p_adjusted", "verdict", "power", "note"]
        fmt = {"float_format": lambda v: f"{v:.4g}", "na_rep": "-", "index": False}
        parts = [head]
        if all_rows:
            parts.append(t[cols].to_string(**fmt))
            return "\n".join(parts)
        for title, rows in (("failed:", self.moved_rows()), ("improved (not a failure):",
                                                              self.better_rows())):
            if not rows.empty:
                parts += [title, rows[cols].to_string(**fmt)]
        low = self.underpowered_rows()
        if not low.empty:
            worst = low.sort_values("power").groupby("metric", sort=False).first()
            lines = [f"  {m}: {int((low['metric'] == m).sum())} cells, weakest "
                     f"{r['env']}/{r['policy']} power {r['power']:.2f} with {int(r['n_run'])} "
                     "run episodes" for m, r in worst.iterrows()]
            parts.append(f"UNDERPOWERED: {len(low)} checks cannot catch a worsening of "
                         f"{self.config.detect:g} margins with {POWER:.0%} probability, as "
                         "a check on the baseline's seeds could:")
            parts += lines
        return "\n".join(parts)

    def to_json(self) -> dict[str, Any]:
        """The machine-readable verdict (``bench check --format json``)."""
        t = self.table
        status = "fail" if self.moved else ("underpowered" if self.underpowered else "pass")
        return {"format": "tap-bench-check", "format_version": 1, "status": status,
                "failed": int(t["moved"].sum()),
                "improved": int((t["verdict"] == "better").sum()),
                "underpowered": len(self.underpowered_rows()), "checks": len(t),
                "gate": self.config.to_dict(),
                "rows": [{k: _json_value(v) for k, v in r.items()}
                         for r in t.to_dict(orient="records")]}


def _json_value(v: Any) -> Any:
    if v is None or v is pd.NA:
        return None
    if isinstance(v, np.bool_ | bool):
        return bool(v)
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, float | np.floating):
        # full precision: a rounded baseline would differ from an identical run by the
        # rounding, which a permutation test on a constant measure calls significant
        return None if not np.isfinite(v) else float(v)
    return str(v)


def scene_stand_ins(episodes: pd.DataFrame) -> pd.DataFrame:
    """The episodes as the gate reads them: on recorded scenes (an episode whose stand-in
    measure is not NA, :data:`~tap_bench.bench.measures.SCENE_STANDS_IN`) the crash check
    counts at-fault collisions (SPEC section 8); a baseline stores them so."""
    out = episodes
    for measure, stand_in in SCENE_STANDS_IN.items():
        if stand_in in episodes.columns and measure in episodes.columns:
            stand = pd.to_numeric(episodes[stand_in], errors="coerce")
            present = stand.notna()
            if present.any():
                if out is episodes:
                    out = episodes.copy()
                out[measure] = out[measure].mask(present, stand > 0.5)
    return out


def _stand_in_notes(table: pd.DataFrame, episodes: pd.DataFrame) -> pd.DataFrame:
    """Say on each check a stand-in decided that it did, with the measure it stood in for
    beside it (``crashed``: at-fault collisions, all collisions in the run)."""
    for measure, stand_in in SCENE_STANDS_IN.items():
        if stand_in not in episodes.columns or measure not in episodes.columns:
            continue
        # the finished episodes on recorded scenes, in table order (none: no table copied)
        present = pd.to_numeric(episodes[stand_in], errors="coerce").notna()
        if not present.any():
            continue
        real = episodes[present & (episodes["status"] == "ok")]
        for (env, policy), group in real.groupby(["env", "policy"], sort=False):
            at = ((table["env"] == env) & (table["policy"] == policy)
                  & (table["metric"] == measure)).to_numpy()
            if at.any():
                every = pd.to_numeric(group[measure], errors="coerce").astype(float).mean()
                text = (f"{stand_in} on recorded scenes (SPEC 8); all {measure} in the run: "
                        f"{every:.3g}")
                table.loc[at, "note"] = [f"{n}; {text}" if isinstance(n, str) and n
                                         else text for n in table.loc[at, "note"]]
    return table


def _identity(summary: dict[str, Any]) -> dict[str, Any]:
    suite = summary.get("suite", {})
    return {"suite": suite.get("name"), "suite_version": suite.get("version"),
            "level": summary.get("level"), "thresholds": summary.get("thresholds")}


def write_baseline(run_summary: dict[str, Any], episodes: pd.DataFrame,
                   path: str | os.PathLike) -> Path:
    """Write the baseline of a run (atomically); the only way a baseline changes.

    Args:
        run_summary: the run's ``summary.json``.
        episodes: the run's episode table.
        path: the baseline JSON to write.

    Raises:
        BaselineError: the run has no episode, or an (env, policy) of it has no episode that
            ran to the end: such a baseline would test nothing there.
        OutputPathError: ``path`` is something other than a tap-bench baseline (a folder,
            a link, a file of notes): only a baseline or a new path is written.
    """
    _check_replaceable(Path(path))
    episodes = scene_stand_ins(episodes)
    ok = episodes[episodes["status"] == "ok"]
    n_failed = int((~episodes["status"].isin(("ok", "skipped"))).sum())
    if ok.empty:
        raise BaselineError(f"run {run_summary.get('run')!r} has no finished episode "
                            f"({len(episodes)} episodes, {n_failed} failed): it cannot become "
                            "a baseline. Fix the failures (summary.json lists them) and run "
                            "again.")
    if n_failed > MAX_FAILED_SHARE * len(episodes):
        raise BaselineError(f"run {run_summary.get('run')!r} has {n_failed} of "
                            f"{len(episodes)} episodes failed ({n_failed / len(episodes):.1%}, "
                            f"more than {MAX_FAILED_SHARE:.0%}): it cannot become a baseline. "
                            "Fix the failures (summary.json lists them) and run again.")
    cells = episodes[["env", "policy"]].drop_duplicates()
    done = set(map(tuple, ok[["env", "policy"]].drop_duplicates().to_numpy()))
    empty = [(e, p) for e, p in cells.to_numpy() if (e, p) not in done]
    if empty:
        listed = ", ".join(f"{e or '-'}/{p}" for e, p in empty[:5])
        raise BaselineError(
            f"run {run_summary.get('run')!r}: every episode of {listed} failed; the baseline "
            "would not test it. Fix those failures, or drop them from the suite, and run "
            "again.")
    gate = run_summary.get("suite", {}).get("gate") or GateConfig().to_dict()
    config = config_of({"gate": gate})
    n_cells = len(cells)
    n_seeds = int(ok.groupby(["env", "policy"]).size().min())
    floor, level = firing_floor(config, cells=n_cells, seeds=n_seeds)
    if floor > level * (1 + 1e-9):
        need = _seeds_needed(config, n_cells, level)
        if need is None:
            raise BaselineError(
                f"run {run_summary.get('run')!r}: gate alpha {config.alpha:g} leaves its most "
                f"favoured test a level of {level:.3g}, which no test of up to 63 seeds can "
                "reach: a gate against this baseline could never fire. Set gate.alpha in the "
                "suite (0.05 by default) and run again.")
        raise BaselineError(
            f"run {run_summary.get('run')!r} has {n_seeds} seeds in its smallest (env, "
            f"policy) cell: no test of a check on them could give a p-value below "
            f"{floor:.3g}, above the {level:.3g} its share of alpha {config.alpha:g} allows, "
            f"so a gate against this baseline could never fire. Run the suite on at least "
            f"{need} seeds and make the baseline from that run.")
    rows = [[_json_value(v) for v in r] for r in ok[list(_episode_fields())].itertuples(
        index=False)]
    gate = config.to_dict()
    doc = {"format": BASELINE_FORMAT, "format_version": BASELINE_VERSION,
           **_identity(run_summary),
           "created": time.strftime("%Y-%m-%d %H:%M:%S"),
           "from_run": run_summary.get("run"), "seeds": run_summary.get("seeds"),
           "versions": run_summary.get("versions", {}), "gate": gate,
           "provenance": run_summary.get("provenance", {}),
           "cells": sorted([str(e), str(p)] for e, p in done),
           "episodes": {"columns": list(_episode_fields()), "rows": rows}}
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(doc, indent=1) + "\n")
    return path


def _check_replaceable(path: Path) -> None:
    """Refuse to write a baseline over anything but a tap-bench baseline (a new path is
    fine): nothing is deleted that tap-bench did not write."""
    if not os.path.lexists(path):
        return
    what = None
    if path.is_symlink():
        what = "a symbolic link"
    elif path.is_dir():
        what = "a folder"
    elif not path.is_file():
        what = "not a regular file"
    else:
        try:
            doc = json.loads(path.read_bytes().decode("utf-8"))
        except (OSError, ValueError, RecursionError):
            doc = None
        if not isinstance(doc, dict) or doc.get("format") != BASELINE_FORMAT:
            what = "not a tap-bench baseline"
    if what is not None:
        raise OutputPathError(f"{path}: {what}; --update-baseline writes only a new file or "
                              "over a tap-bench baseline, so nothing else is replaced. Give "
                              "the baseline another path, or move that file away.")


def read_baseline(path: str | os.PathLike) -> tuple[dict[str, Any], pd.DataFrame]:
    """The baseline's header and its episode rows.

    Raises:
        FileFormatError: missing file (with the command that makes one), not JSON (or not
            text), not a baseline, rows of the wrong shape or type, gate settings that
            :class:`GateConfig` refuses.
        BaselineError: a metric missing, or a measure that is not a number.
    """
    path = Path(path)
    if path.exists() and not path.is_file():
        raise FileFormatError(f"{path}: not a baseline file ("
                              f"{'a folder' if path.is_dir() else 'not a regular file'}); "
                              "give the path of the baseline's JSON file.")
    if not path.is_file():
        raise FileFormatError(f"{path}: no baseline file; make one from a run with "
                              f"'tap-bench bench check RUN --baseline {path} "
                              "--update-baseline'.")
    try:
        doc = json.loads(path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError as err:
        raise FileFormatError(f"{path}: not a text file (byte {err.start} is not UTF-8); a "
                              "baseline is the JSON written by --update-baseline.") from None
    except json.JSONDecodeError as err:
        raise FileFormatError(f"{path}: not valid JSON: {err}") from err
    except (ValueError, RecursionError) as err:  # a 5,000-digit number, deep nesting
        raise FileFormatError(f"{path}: not a baseline's JSON ({type(err).__name__}: "
                              f"{str(err)[:120]}); the file was edited or damaged. Re-make "
                              "it with --update-baseline.") from None
    if not isinstance(doc, dict) or doc.get("format") != BASELINE_FORMAT:
        raise FileFormatError(f"{path}: not a tap-bench baseline (its 'format' is "
                              f"{doc.get('format') if isinstance(doc, dict) else None!r}, "
                              f"expected {BASELINE_FORMAT!r}).")
    version = doc.get("format_version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise FileFormatError(f"{path}: format_version {version!r} is not a baseline format "
                              "version (an integer); the file was edited or damaged. Re-make "
                              "it with --update-baseline.")
    if version > BASELINE_VERSION:
        raise FileFormatError(f"{path}: baseline format version {version} is newer than "
                              f"this tap-bench reads ({BASELINE_VERSION}); update tap-bench, "
                              "or re-make the baseline with --update-baseline.")
    try:
        eps = doc["episodes"]
        rows, columns = eps["rows"], eps["columns"]
        if not isinstance(columns, list) or not isinstance(rows, list) or not all(
                isinstance(r, list) and len(r) == len(columns) for r in rows):
            raise ValueError(f"'rows' must be a list of lists of {len(columns)} values, one "
                             "per column" if isinstance(columns, list) else
                             "'columns' must be a list of names")
        if not rows:
            raise ValueError("it holds no episode; a baseline tests nothing without them")
        table = pd.DataFrame(rows, columns=columns)
    except (KeyError, TypeError, ValueError) as err:
        raise FileFormatError(f"{path}: 'episodes' must hold 'columns' and 'rows': {err}"
                              ) from err
    missing = [c for c in _episode_fields() if c not in table.columns]
    if missing:
        raise BaselineError(f"{path}: baseline episodes lack {', '.join(missing)}; a metric "
                            "the gate checks cannot be missing. Re-make it with "
                            "--update-baseline.")
    for m in MEASURES:
        values = table[m.name]
        what = _impossible(m)
        bad = values.map(lambda v, m=m: v is not None and not _possible(m, v))
        if bad.any():
            row = int(np.flatnonzero(bad.to_numpy())[0])
            raise BaselineError(
                f"{path}: episode row {row} ({table['env'].iloc[row]}, "
                f"{table['policy'].iloc[row]}, seed {table['seed'].iloc[row]}) has "
                f"{m.name} = {str(values.iloc[row])[:80]!r}, not {what}; a baseline holds "
                "what its measures can take (or null where a measure is undefined). The "
                "baseline was edited or damaged; re-make it with --update-baseline.")
        table[m.name] = pd.to_numeric(values, errors="coerce").astype(float)
        infinite = np.isinf(table[m.name].to_numpy())
        if infinite.any():
            row = int(np.flatnonzero(infinite)[0])
            raise BaselineError(
                f"{path}: episode row {row} ({table['env'].iloc[row]}, "
                f"{table['policy'].iloc[row]}, seed {table['seed'].iloc[row]}) has "
                f"{m.name} = {values.iloc[row]!r}, which is infinite (a number too large for "
                "a float); a measure is finite or null. The baseline was edited or damaged; "
                "re-make it with --update-baseline.")
    _check_baseline_rows(table, path)
    _check_baseline_cells(doc, table, path)
    gate = doc.get("gate") or {}
    if not isinstance(gate, dict):
        raise FileFormatError(f"{path}: 'gate' must be an object of gate settings, got "
                              f"{gate!r}.")
    try:
        GateConfig(**{k: v for k, v in gate.items() if k in _GATE_FIELDS})
    except (TypeError, ValueError, UnknownNameError) as err:
        raise FileFormatError(f"{path}: gate settings: {err} Restore them from the suite "
                              "(envs/suites/*.json) or re-make the baseline with "
                              "--update-baseline.") from None
    return doc, table


def _impossible(m: Any) -> str:
    """What a baseline value of measure ``m`` must be, in words."""
    if m.kind == "rate":
        return "true, false, 0 or 1 (an episode's outcome)"
    if m.bounds is not None:
        return f"a number in [{m.bounds[0]:g}, {m.bounds[1]:g}] {m.unit} (the measure's range)"
    return "a number"


def _possible(m: Any, value: Any) -> bool:
    """Whether ``value`` (not None) is a value measure ``m`` can take in one episode: an
    outcome (bool, 0 or 1) for a rate, a number (never a bool) otherwise, within the
    measure's bounds where it has them."""
    if m.kind == "rate":
        return isinstance(value, bool) or (isinstance(value, int | float)
                                           and value in (0, 1))
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    if isinstance(value, int) and abs(value) > 2 ** 63:
        return False
    return m.bounds is None or not value == value or (
        m.bounds[0] - BOUND_TOLERANCE <= value <= m.bounds[1] + BOUND_TOLERANCE)


def _all_possible(m: Any, column: pd.Series) -> bool:
    """Whether every value of ``column``, a numpy bool or number column, is NaN or one
    measure ``m`` can take (:func:`_possible`, at once on the array); False for any other
    column or when some value is not (the caller then reads the column value by value)."""
    dtype = column.dtype
    if not isinstance(dtype, np.dtype) or dtype.kind not in "bif":
        return False
    if dtype.kind == "b":
        return m.kind == "rate"  # an outcome; never a number
    v = column.to_numpy(float)
    with np.errstate(invalid="ignore"):
        if m.kind == "rate":
            return bool(np.all(np.isnan(v) | (v == 0) | (v == 1)))
        if m.bounds is None:
            return True
        return bool(np.all(np.isnan(v) | ((m.bounds[0] - BOUND_TOLERANCE <= v)
                                           & (v <= m.bounds[1] + BOUND_TOLERANCE))))


def _check_run_values(episodes: pd.DataFrame) -> None:
    """Every measure value of the run's finished episodes is one its measure can take, as a
    baseline's must be (:func:`_possible`; null or NaN where a measure is undefined): an
    edited or damaged run folder is an error, never a verdict.

    Raises:
        FileFormatError: naming the row, the column, the value and the fix.
    """
    rows = np.flatnonzero((episodes["status"] == "ok").to_numpy())  # positions in the file
    ok = episodes.iloc[rows]
    for m in MEASURES:
        if m.name not in ok.columns or _all_possible(m, ok[m.name]):
            continue
        for i, value in enumerate(ok[m.name].tolist()):
            if (pd.api.types.is_scalar(value) and pd.isna(value)) or _possible(m, value):
                continue
            row = ok.iloc[i]
            raise FileFormatError(
                f"the run's episodes.parquet: row {rows[i]} ({row['env']}, {row['policy']}, seed "
                f"{row['seed']}) has {m.name} = {str(value)[:80]!r}, not {_impossible(m)}. "
                "The run folder was edited or damaged; run 'tap-bench bench run' again.")


def _check_baseline_cells(doc: dict[str, Any], table: pd.DataFrame, path: Path) -> None:
    """No episode twice, and (for baselines that list their ``cells``) every (env, policy)
    listed holds episodes and no other does: a removed cell would otherwise pass
    unchecked."""
    key = table[["env", "policy", "seed"]].astype(str)
    twice = key.duplicated()
    if twice.any():
        row = int(np.flatnonzero(twice.to_numpy())[0])
        env, policy, seed = key.iloc[row]
        raise FileFormatError(f"{path}: episode row {row} repeats ({env}, {policy}, seed "
                              f"{seed}); each episode is one row. The baseline was edited or "
                              "damaged; re-make it with --update-baseline.")
    cells = doc.get("cells")
    if cells is None:
        return  # written before baselines listed their cells
    if not isinstance(cells, list) or not all(
            isinstance(c, list) and len(c) == 2 and all(isinstance(x, str) for x in c)
            for c in cells):
        raise FileFormatError(f"{path}: 'cells' must be a list of [env, policy] pairs; the "
                              "baseline was edited or damaged. Re-make it with "
                              "--update-baseline.")
    listed = {tuple(c) for c in cells}
    present = set(map(tuple, table[["env", "policy"]].astype(str).drop_duplicates()
                      .to_numpy()))
    for what, names in (("has no episode rows", sorted(listed - present)),
                        ("is not among its cells", sorted(present - listed))):
        if names:
            shown = ", ".join(f"{e}/{p}" for e, p in names[:5])
            raise BaselineError(f"{path}: {shown} {what}; the baseline's cells and "
                                "episodes disagree (edited or damaged). Re-make it with "
                                "--update-baseline.")


def _check_baseline_rows(table: pd.DataFrame, path: Path) -> None:
    """Every identifying value of a baseline's episodes of the type its column holds: text
    for env, policy (and sdl, or null), an integer seed (the measures are checked by
    :func:`read_baseline`)."""
    def bad(col: str, ok) -> None:
        for i, value in enumerate(table[col].tolist()):
            if not ok(value):
                raise FileFormatError(
                    f"{path}: episode row {i}, column {col!r}: {value!r} is not "
                    f"{kinds[col]}. The baseline was edited or damaged; re-make it with "
                    "--update-baseline.")

    text = "text"
    kinds = {"env": text, "policy": text, "seed": "a non-negative integer",
             "sdl": "text or null"}
    bad("env", lambda v: isinstance(v, str))
    bad("policy", lambda v: isinstance(v, str))
    bad("seed", lambda v: (isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 2 ** 63)
        or (isinstance(v, str) and v.isdigit() and len(v) < 19))  # text: before 0.2
    bad("sdl", lambda v: v is None or isinstance(v, str))


def holm(p: np.ndarray) -> np.ndarray:
    """Holm-adjusted p-values (step-down; monotone; capped at 1)."""
    return weighted_holm(p, np.ones(len(p)))


def weighted_holm(p: np.ndarray, weights: np.ndarray, p_min: np.ndarray | None = None,
                  alpha: float = 0.05) -> np.ndarray:
    """Weighted Holm adjusted p-values, restricted to the tests that can reach alpha
    (Tarone's reduction for discrete tests).

    Test i is rejected at family-wise level alpha when its adjusted p-value is below alpha.
    Step k of the weighted Holm procedure rejects the test of smallest p_i / w_i when p_i <=
    alpha w_i / W, W the weight of the tests not yet rejected (Holm 1979; closed testing
    with weighted Bonferroni tests). A test whose smallest attainable p-value ``p_min`` is
    above its share of alpha can never be rejected; it is left out of W, which raises the
    others' shares (Tarone 1990). ``p_min`` depends only on what a permutation test
    conditions on (the seeds that differ, the pooled values), so the family-wise level holds.

    Args:
        p: (m,) p-values.
        weights: (m,) positive weights (their scale does not matter).
        p_min: (m,) smallest attainable p-value of each test; None: every test counts.
        alpha: the level at which a test's share decides whether it can be rejected.

    Returns:
        (m,) adjusted p-values in [0, 1]; 1 for a test left out.
    """
    p = np.asarray(p, float)
    w = np.asarray(weights, float)
    m = len(p)
    if m == 0:
        return p
    keep = _tarone(w, p_min, alpha)
    out = np.ones(m)
    idx = np.flatnonzero(keep)
    if not len(idx):
        return out
    pk, wk = p[idx], w[idx]
    order = np.argsort(pk / wk, kind="stable")
    remaining = wk[order][::-1].cumsum()[::-1]  # weight of the tests not yet rejected
    adjusted = np.minimum(1.0, np.maximum.accumulate(pk[order] / wk[order] * remaining))
    out[idx[order]] = adjusted
    return out


def _tarone(w: np.ndarray, p_min: np.ndarray | None, alpha: float) -> np.ndarray:
    """Which tests stay: starting from those that could reach alpha alone, leave out one at
    a time the test furthest from its share of alpha over the tests kept (largest p_min /
    w) until every test kept can reach its share. (Any set chosen from the p_min alone
    keeps the level; this one leaves out no test that could reach its share.)"""
    keep = np.ones(len(w), bool)
    if p_min is None:
        return keep
    p_min = np.asarray(p_min, float)
    keep &= p_min <= alpha + 1e-15
    ratio = p_min / w
    while keep.any():
        share = alpha * w / w[keep].sum()
        short = keep & (p_min > share + 1e-15)
        if not short.any():
            break
        keep[np.flatnonzero(short)[np.argmax(ratio[short])]] = False
    return keep


def smallest_p(n_permutations: int, *, paired_seeds: int | None = None,
               sizes: tuple[int, int] | None = None) -> float:
    """The smallest one-sided p-value one permutation test can give.

    Args:
        n_permutations: random permutations P (p >= 1 / (P + 1)).
        paired_seeds: for a paired test of a mean, the seeds that differ n (p >= 1 / 2^n;
            a rate's exact test reaches 1 / 2^n whatever P).
        sizes: for an unpaired test, the two sample sizes (p >= 1 / C(n1 + n2, n1)).
    """
    floor = 1.0 / (n_permutations + 1)
    if paired_seeds is not None:
        return max(floor, 1.0 / 2 ** paired_seeds)
    if sizes is not None:
        return max(floor, min(1.0, 1.0 / math.comb(sum(sizes), sizes[0])))
    return floor


@dataclass(frozen=True)
class _Test:
    """One test's outcome: the change (run - baseline; for label_tv the TV), the one-sided
    p-values of a change the worse and the better way, and the smallest attainable p."""

    change: float
    p_worse: float
    p_better: float
    p_min: float


def _binom_tail(k: int, n: int) -> float:
    """P(Bin(n, 1/2) >= k)."""
    if k <= 0:
        return 1.0
    return sum(math.comb(n, i) for i in range(k, n + 1)) / 2.0 ** n


def _sign_flip_test(d: np.ndarray, sign: int, config: GateConfig, key: tuple) -> _Test:
    """Paired one-sided test on per-seed differences ``d`` (run - baseline); ``sign`` -1
    when lower is better. Only the seeds that differ enter (a flip of a 0 changes
    nothing): exact over all 2^K flips of the K non-zero differences up to
    :data:`EXACT_FLIPS_MAX_SEEDS`, exact by the binomial when they are all of one size (a
    rate: McNemar's test), else P random flips from the stream ``("gate", *key)``."""
    change = float(d.mean()) if len(d) else 0.0
    worse = -sign * d[d != 0]  # > 0: worse
    k = len(worse)
    if k == 0:
        return _Test(change, 1.0, 1.0, 1.0)
    size = np.abs(worse)
    if np.allclose(size, size[0], rtol=1e-12, atol=0):
        up = int((worse > 0).sum())
        return _Test(change, _binom_tail(up, k), _binom_tail(k - up, k), 0.5 ** k)
    observed = float(worse.sum())
    if _exact(k, config):
        flips = np.array(list(itertools.product((1.0, -1.0), repeat=k)))
        stats = flips @ worse
        n, extra, p_min = len(stats), 0, 0.5 ** k
    else:
        rng = named_rng(config.seed, "gate", *key)
        stats = rng.choice((1.0, -1.0), size=(config.n_permutations, k)) @ worse
        n, extra, p_min = len(stats) + 1, 1, 1.0 / (config.n_permutations + 1)
    tol = 1e-9 * float(size.sum())
    p_worse = (extra + float((stats >= observed - tol).sum())) / n
    p_better = (extra + float((stats <= observed + tol).sum())) / n
    return _Test(change, p_worse, p_better, p_min)


def _unpaired_test(base: np.ndarray, run: np.ndarray, sign: int, config: GateConfig,
                   key: tuple) -> _Test:
    """One-sided test of the change of the mean with episodes exchanged between run and
    baseline: Fisher's exact test for a rate (values 0 and 1), else P random
    permutations."""
    change = float(run.mean() - base.mean())
    pooled = np.r_[base, run]
    if np.all(pooled == pooled[0]):
        return _Test(change, 1.0, 1.0, 1.0)
    if np.isin(pooled, (0.0, 1.0)).all():
        up, down, p_top, p_bottom = hypergeom_tails(int(run.sum()), len(run), len(base),
                                                     int(pooled.sum()))
        if sign > 0:  # more ones is better: worse is fewer
            return _Test(change, down, up, p_bottom)
        return _Test(change, up, down, p_top)
    rng = named_rng(config.seed, "gate", *key)
    perms = np.argsort(rng.random((config.n_permutations, len(pooled))), axis=1)
    shuffled = pooled[perms]
    n_b = len(base)
    perm = shuffled[:, n_b:].mean(axis=1) - shuffled[:, :n_b].mean(axis=1)
    tol = 1e-9 * max(1.0, float(np.abs(pooled).max()))
    worse_obs, worse_perm = -sign * change, -sign * perm
    n = len(perm) + 1
    return _Test(change, (1 + float((worse_perm >= worse_obs - tol).sum())) / n,
                 (1 + float((worse_perm <= worse_obs + tol).sum())) / n,
                 1.0 / (config.n_permutations + 1))


def _paired_tv_test(base: np.ndarray, run: np.ndarray, config: GateConfig, key: tuple
                    ) -> _Test:
    """TV of the label distributions, p with run and baseline labels swapped per seed
    (only the seeds whose labels differ; exact up to :data:`EXACT_FLIPS_MAX_SEEDS`)."""
    _, codes = np.unique(np.r_[base, run], return_inverse=True)
    k = int(codes.max()) + 1
    cb, cr = codes[:len(base)], codes[len(base):]
    observed = float(tv(cb[None, :], cr[None, :], k)[0])
    differ = np.flatnonzero(cb != cr)
    n_diff = len(differ)
    if n_diff == 0:
        return _Test(observed, 1.0, 1.0, 1.0)
    if _exact(n_diff, config):
        flips = np.array(list(itertools.product((True, False), repeat=n_diff)))
        extra, p_min = 0, 0.5 ** n_diff
    else:
        rng = named_rng(config.seed, "gate", *key)
        flips = rng.random((config.n_permutations, n_diff)) < 0.5
        extra, p_min = 1, 1.0 / (config.n_permutations + 1)
    full = np.ones((len(flips), len(cb)), bool)
    full[:, differ] = flips
    perm = tv(np.where(full, cb, cr), np.where(full, cr, cb), k)
    p = (extra + float((perm >= observed - 1e-12).sum())) / (len(perm) + extra)
    return _Test(observed, p, 1.0, p_min)


def _tv_test(base: np.ndarray, run: np.ndarray, config: GateConfig, key: tuple) -> _Test:
    """(total variation distance of the label distributions, permutation p)."""
    _, codes = np.unique(np.r_[base, run], return_inverse=True)
    k = int(codes.max()) + 1
    n_b = len(base)
    observed = float(tv(codes[None, :n_b], codes[None, n_b:], k)[0])
    if k == 1:
        return _Test(observed, 1.0, 1.0, 1.0)
    rng = named_rng(config.seed, "gate", *key)
    perms = np.argsort(rng.random((config.n_permutations, len(codes))), axis=1)
    shuffled = codes[perms]
    exceed = tv(shuffled[:, :n_b], shuffled[:, n_b:], k) >= observed - 1e-12
    return _Test(observed, float((1 + exceed.sum()) / (1 + len(perms))), 1.0,
                 1.0 / (config.n_permutations + 1))


def definition_changes(run: dict[str, Any] | None, baseline: dict[str, Any] | None
                       ) -> list[tuple[str, str, str]]:
    """What changed in the policies' and envs' definitions since the baseline.

    Args:
        run, baseline: the ``provenance`` of a run summary and of a baseline:
            ``{"policies": {name: definition}, "envs": {name: resolved config}}``.

    Returns:
        (kind, name, what changed) per changed policy or env, e.g. ``("policy", "idm",
        "params.time_wanted: 1.5 -> 3.0")``; names absent on one side are not listed.
    """
    out = []
    for kind, key in (("policy", "policies"), ("env", "envs")):
        here = (run or {}).get(key, {})
        there = (baseline or {}).get(key, {})
        for name in sorted(set(here) & set(there)):
            diffs = _dict_diff(there[name], here[name])
            if diffs:
                out.append((kind, name, "; ".join(diffs)))
    return out


def _dict_diff(old: Any, new: Any, prefix: str = "") -> list[str]:
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for k in sorted(set(old) | set(new), key=str):
            where = f"{prefix}.{k}" if prefix else str(k)
            if k not in old:
                out.append(f"{where}: added {new[k]!r}")
            elif k not in new:
                out.append(f"{where}: removed (was {old[k]!r})")
            else:
                out += _dict_diff(old[k], new[k], where)
        return out
    return [] if old == new else [f"{prefix or 'value'}: {old!r} -> {new!r}"]


def check(run_summary: dict[str, Any], run_episodes: pd.DataFrame,
          baseline: dict[str, Any], baseline_episodes: pd.DataFrame,
          config: GateConfig | None = None, *, power: bool = True) -> GateResult:
    """Check a run against a baseline (see the module docstring).

    Args:
        run_summary, run_episodes: the run's ``summary.json`` and episode table.
        baseline, baseline_episodes: from :func:`read_baseline`.
        config: gate settings; default: those of the run's suite (:func:`run_config`).
        power: also compute each test's power at the ``detect`` worsening (the
            ``underpowered`` verdict); False skips it (calibration studies).

    Raises:
        BaselineMismatchError: suite, level, thresholds or gate settings (margins, alpha,
            weights, permutations, seed, detect) differ: everything that decides the
            verdict comes from the suite (or the caller), never from the baseline file.
        ParameterError: the gate can never fire with these tests, permutations and seeds
            (the message gives the numbers, what would do, and the definitions that
            changed since the baseline).
    """
    here, there = _identity(run_summary), {k: baseline.get(k) for k in _IDENTITY}
    diff = [k for k in _IDENTITY if here[k] != there[k]]
    if diff:
        what = "; ".join(f"{k}: run {here[k]!r}, baseline {there[k]!r}" for k in diff)
        raise BaselineMismatchError(
            f"the run and the baseline differ in {what}. Check against a baseline of the same "
            "suite and settings, or replace it with --update-baseline.")
    if config is None:  # the suite's; a caller's own config is its decision
        config = run_config(run_summary)
        _refuse_other_gate(baseline, config)
    _check_run_values(run_episodes)
    rows: list[dict[str, Any]] = []

    changed = definition_changes(run_summary.get("provenance"), baseline.get("provenance"))
    changed_policy = {name: what for kind, name, what in changed if kind == "policy"}
    changed_env = {name: what for kind, name, what in changed if kind == "env"}
    as_run, run_episodes = run_episodes, scene_stand_ins(run_episodes)
    # (a mask that keeps every row, or none, is not applied: a copy of the table saved)
    ok = run_episodes["status"] == "ok"
    run_ok = (run_episodes if ok.dtype == bool and ok.to_numpy().all()
              else run_episodes[ok])
    # skipped: a recorded scene without a route, not a failure (SPEC section 8)
    failed = ~run_episodes["status"].isin(("ok", "skipped"))
    run_failed = (run_episodes.iloc[:0] if failed.dtype == bool and not failed.to_numpy().any()
                  else run_episodes[failed])
    cells = sorted({cell for t in (baseline_episodes, run_episodes)
                    for cell in zip(t["env"].tolist(), t["policy"].tolist(), strict=True)})
    for kind, name, what in changed:
        rows.append({"env": name if kind == "env" else "", "policy": name if kind == "policy"
                     else "", "metric": "definition", "test": "", "forced": True,
                     "note": f"{kind} {name!r} changed since the baseline: {what}"})
    plans = []  # (key, base, run) of the cells to test
    # each table split by cell once (rows in table order, as a mask per cell selects them)
    base_cells, run_cells = _by_cell(baseline_episodes), _by_cell(run_ok)
    failed_cells = {cell: len(part) for cell, part in _by_cell(run_failed).items()}
    for env, policy in cells:
        base = base_cells.get((env, policy), baseline_episodes.iloc[:0])
        run = run_cells.get((env, policy), run_ok.iloc[:0])
        key = {"env": env, "policy": policy}
        n_failed = failed_cells.get((env, policy), 0)
        if n_failed:
            rows.append({**key, "metric": "failed_episodes", "n_baseline": len(base),
                         "n_run": len(run), "baseline": 0.0, "run": float(n_failed),
                         "change": float(n_failed), "margin": 0.0, "p_value": np.nan,
                         "forced": True, "note": "episodes failed in the run"})
        if base.empty:
            rows.append({**key, "metric": "episodes", "n_baseline": 0, "n_run": len(run),
                         "note": "new in the run (not in the baseline)", "forced": False})
            continue
        if run.empty:
            rows.append({**key, "metric": "episodes", "n_baseline": len(base), "n_run": 0,
                         "note": "in the baseline, missing from the run", "forced": True})
            continue
        plans.append((key, base, run))
    try:
        _refuse_if_it_cannot_fire(plans, config)
    except ParameterError as err:
        if changed:
            listed = "; ".join(f"{kind} {name!r}: {what}" for kind, name, what in changed)
            raise ParameterError(err.parameter, err.value, err.allowed, hint=(
                f"{err.hint} Changed since the baseline: {listed}.")) from None
        raise
    for key, base, run in plans:
        rows += _test_cell(key, base, run, config, _why(key, changed_policy, changed_env))
    table = _stand_in_notes(_decide(pd.DataFrame(rows), config), as_run)
    if power:
        table = _with_power(table, plans, config)
    else:
        table["power"] = np.nan
        table["underpowered"] = False
    # failures first, then improvements, then the rest, each by env and policy (a stable
    # sort: a cell's rows stay in test order)
    verdict, env, policy = (table[c].tolist() for c in ("verdict", "env", "policy"))
    rank = {"worse": 0, "changed": 0, "better": 1}
    order = sorted(range(len(table)), key=lambda i: (rank.get(verdict[i], 2), env[i],
                                                       policy[i]))
    table = table[_COLUMNS].take(order).reset_index(drop=True)
    return GateResult(table, bool(table["moved"].any()), config)


def _by_cell(episodes: pd.DataFrame) -> dict[tuple[Any, Any], pd.DataFrame]:
    """``episodes``' rows by (env, policy), each part in table order with its index."""
    if not len(episodes):
        return {}
    env, policy = episodes["env"].to_numpy(), episodes["policy"].to_numpy()
    if (env == env[0]).all() and (policy == policy[0]).all():  # one cell: the table
        return {(env[0], policy[0]): episodes}
    return {cell: part for cell, part in episodes.groupby(["env", "policy"], sort=False,
                                                          observed=True)}


_COLUMNS = ["env", "policy", "metric", "direction", "test", "n_baseline", "n_run",
            "baseline", "run", "change", "margin", "p_value", "p_min", "p_adjusted",
            "verdict", "moved", "power", "underpowered", "note"]


def config_of(baseline: dict[str, Any]) -> GateConfig:
    """The gate settings a baseline was made with (defaults for fields it predates)."""
    gate = dict(baseline.get("gate") or {})
    return GateConfig(**{k: v for k, v in gate.items() if k in _GATE_FIELDS})


def _refuse_other_gate(baseline: dict[str, Any], config: GateConfig) -> None:
    """Raise when the baseline's gate settings are not ``config``'s (the suite's)."""
    if baseline.get("gate") is None:
        return  # a baseline written before baselines kept their settings
    theirs, ours = config_of(baseline).to_dict(), config.to_dict()
    if theirs != ours:
        what = "; ".join(_dict_diff(ours, theirs)[:5])
        raise BaselineMismatchError(
            f"the baseline's gate settings differ from the run's suite ({what}; suite -> "
            "baseline). The verdict is decided by the suite's settings: check against a "
            "baseline made with them, or replace it with --update-baseline.")


def run_config(run_summary: dict[str, Any]) -> GateConfig:
    """The gate settings of the suite a run was made with (``summary.json``'s
    ``suite.gate``; the defaults for a run without a suite, such as ``tap-bench compare``).

    Raises:
        FileFormatError: the settings are not valid gate settings.
    """
    suite = run_summary.get("suite")
    gate = (suite.get("gate") if isinstance(suite, dict) else None) or {}
    if not isinstance(gate, dict):
        raise FileFormatError(f"run {run_summary.get('run')!r}: summary.json's suite.gate "
                              f"must be an object of gate settings, got {gate!r}.")
    try:
        return config_of({"gate": gate})
    except (TypeError, ValueError, UnknownNameError) as err:
        raise FileFormatError(f"run {run_summary.get('run')!r}: summary.json's suite gate "
                              f"settings: {err}") from None



def _test_cell(key: dict[str, Any], base: pd.DataFrame, run: pd.DataFrame,
               config: GateConfig, why: str) -> list[dict[str, Any]]:
    """The rows of one (env, policy): one test per gate metric."""
    rows = []
    seeds_b = base["seed"].astype(np.int64).to_numpy()
    seeds_r = run["seed"].astype(np.int64).to_numpy()
    paired = len(seeds_b) == len(seeds_r) and set(seeds_b) == set(seeds_r)
    # each side's rows in seed order when paired (in table order else), column by column
    take_b = np.argsort(seeds_b, kind="stable") if paired else slice(None)
    take_r = np.argsort(seeds_r, kind="stable") if paired else slice(None)
    if paired:
        seeds_r = np.sort(seeds_r)
    for metric in gate_metrics():
        name = (key["env"], key["policy"], metric)
        sign = direction(metric)
        row = {**key, "metric": metric, "test": "paired" if paired else "unpaired",
               "direction": {1: "higher", -1: "lower", 0: "none"}[sign],
               "margin": config.margin(metric), "forced": False, "note": why}
        if metric == "label_tv":
            b = base["sdl"].fillna(NO_LABEL).astype(str).to_numpy()[take_b]
            r = run["sdl"].fillna(NO_LABEL).astype(str).to_numpy()[take_r]
            test = (_paired_tv_test(b, r, config, name) if paired
                    else _tv_test(b, r, config, name))
            rows.append({**row, "n_baseline": len(b), "n_run": len(r), "baseline": np.nan,
                         "run": np.nan, **_fields(test)})
            continue
        b, r = _numbers(base[metric])[take_b], _numbers(run[metric])[take_r]
        if paired:
            one_side = np.isfinite(b) != np.isfinite(r)
            if one_side.any():
                rows.append({**row, "n_baseline": int(np.isfinite(b).sum()),
                             "n_run": int(np.isfinite(r).sum()), "forced": True,
                             "note": f"defined on {int(one_side.sum())} seeds in only one "
                             f"of run and baseline (e.g. seed {int(seeds_r[one_side][0])})"})
                continue
            both = np.isfinite(b) & np.isfinite(r)
            b, r = b[both], r[both]
        else:
            b, r = b[np.isfinite(b)], r[np.isfinite(r)]
        if not len(b) and not len(r):
            rows.append({**row, "n_baseline": 0, "n_run": 0, "test": "",
                         "note": "undefined on every episode of both (e.g. no leader "
                         "ever): nothing to compare"})
            continue
        if len(b) < 2 or len(r) < 2:
            rows.append({**row, "n_baseline": len(b), "n_run": len(r), "forced": True,
                         "note": "defined on fewer than 2 episodes of one side only"})
            continue
        test = (_sign_flip_test(r - b, sign, config, name) if paired
                else _unpaired_test(b, r, sign, config, name))
        rows.append({**row, "n_baseline": len(b), "n_run": len(r),
                     "baseline": float(b.mean()), "run": float(r.mean()), **_fields(test)})
    return rows


def _numbers(column: pd.Series) -> np.ndarray:
    """``column`` as floats, NaN where a value is not a number (``pd.to_numeric``'s
    coercion, skipped for a column of numpy bools or numbers: the same floats)."""
    if isinstance(column.dtype, np.dtype) and column.dtype.kind in "biuf":
        return column.to_numpy(float)
    return pd.to_numeric(column, errors="coerce").to_numpy(float)


def _fields(test: _Test) -> dict[str, float]:
    return {"change": test.change, "p_value": test.p_worse, "p_better": test.p_better,
            "p_min": test.p_min}


def _decide(table: pd.DataFrame, config: GateConfig) -> pd.DataFrame:
    """Adjusted p-values and the verdict of every row.

    ``p_adjusted``: the weighted Holm procedure over every test of the check, each metric
    weighted by its share of alpha (:meth:`GateConfig.share`), restricted to the tests that
    can reach alpha (Tarone). ``verdict``: ``worse`` (the metric moved the worse way by
    more than its margin and p_adjusted < alpha: the check fails), ``changed`` (label_tv:
    the label distribution moved), ``better`` (moved the better way beyond the margin,
    the better-side p-value adjusted alike: reported, never a failure), ``untestable``,
    or empty.

    Each column is read once as an array and the result built as one table (a check's
    tables are small: per-column pandas indexing was most of its cost)."""
    n = len(table)
    columns = {c: table[c] for c in table.columns}
    nan = np.full(n, np.nan)
    for col in ("baseline", "run", "change", "margin", "p_value", "p_better", "p_min",
                "n_baseline", "n_run", "test", "direction"):
        if col not in columns:
            columns[col] = pd.Series(nan, index=table.index)

    def floats(col: str) -> np.ndarray:
        return columns[col].to_numpy(float)

    def texts(col: str) -> np.ndarray:  # the column with its NA as ""
        values = columns[col].to_numpy(object)
        return np.where(pd.isna(values), "", values).astype(object)

    p_value, p_better, p_min = floats("p_value"), floats("p_better"), floats("p_min")
    direction = columns["direction"].to_numpy(object)
    tested = ~np.isnan(p_value)
    metrics = set(gate_metrics())
    shares = {m: config.share(m) for m in set(columns["metric"].tolist()) & metrics}
    weights = np.array([shares.get(m, np.nan) for m in columns["metric"].tolist()], float)
    p_adjusted = np.full(n, np.nan)
    p_adjusted[tested] = weighted_holm(p_value[tested], weights[tested], p_min[tested],
                                       config.alpha)
    sided = tested & np.isin(direction, ["higher", "lower"])
    better_adj = np.full(n, np.nan)
    better_adj[sided] = weighted_holm(p_better[sided], weights[sided], p_min[sided],
                                      config.alpha)
    none = direction == "none"
    sign = np.where(direction == "lower", -1.0, np.where(
        (direction == "higher") | none, 1.0, np.nan))
    change, margin = floats("change"), floats("margin")
    worse_by = np.where(none, change, -sign * change)
    with np.errstate(invalid="ignore"):
        fails = (p_adjusted < config.alpha) & (worse_by > margin)
        better = (better_adj < config.alpha) & (-worse_by > margin)
    forced = columns["forced"].fillna(False).to_numpy(bool)
    verdict = np.where(fails | forced, "worse", np.where(better, "better", ""))
    verdict = np.where((verdict == "worse") & none & ~forced, "changed", verdict)
    # an improvement shows the p-values of its side
    improved = verdict == "better"
    p_value = np.where(improved, p_better, p_value)
    p_adjusted = np.where(improved, better_adj, p_adjusted)
    new = {"p_value": p_value, "p_adjusted": p_adjusted, "verdict": verdict,
           "moved": fails | forced, "note": texts("note"), "test": texts("test"),
           "direction": texts("direction")}
    out = {c: new.get(c, s) for c, s in columns.items() if c not in ("forced", "p_better")}
    out.update({c: v for c, v in new.items() if c not in out})
    return pd.DataFrame(out, index=table.index)


def _with_power(table: pd.DataFrame, plans: list, config: GateConfig) -> pd.DataFrame:
    """Each tested row's power at the ``detect`` worsening
    (:func:`tap_bench.bench.gate.power.rule_power`): one changed cell in play when paired,
    every cell when the seeds differ. A row is **underpowered** when that power is below
    :data:`~tap_bench.bench.gate.power.POWER` and below the power of the baseline's own design
    (a paired check on its seeds): the run has fewer seeds, or other ones. (What the
    baseline's design itself cannot catch, ``bench check --power`` and the report show.)"""
    table = table.copy()
    table["power"] = np.nan
    table["underpowered"] = False
    by_key = {(k["env"], k["policy"]): b for k, b, _ in plans}
    for i in np.flatnonzero(table["p_value"].notna().to_numpy()):
        row = table.iloc[i]
        base = by_key[(row["env"], row["policy"])]
        paired = row["test"] == "paired"
        values = (base["sdl"].fillna(NO_LABEL) if row["metric"] == "label_tv"
                  else base[row["metric"]]).to_numpy()
        key = (row["env"], row["policy"])
        power = rule_power(values, row["metric"], config, cells=1 if paired else len(plans),
                           paired=paired, n_run=int(row["n_run"]), seed_key=key)
        table.iloc[i, table.columns.get_loc("power")] = power
        if not np.isfinite(power) or power >= POWER or row["verdict"] == "worse":
            continue
        own = power if paired else rule_power(values, row["metric"], config, cells=1,
                                              paired=True, seed_key=key)
        if power < own - 0.02:
            effect = config.detect * float(row["margin"])
            note = (f"underpowered: a worsening of {effect:g} is caught with probability "
                    f"{power:.2f} at {int(row['n_run'])} {'paired' if paired else 'unpaired'} "
                    f"episodes, {own:.2f} on the baseline's seeds")
            table.iloc[i, table.columns.get_loc("note")] = "; ".join(
                x for x in (row["note"], note) if x)
            table.iloc[i, table.columns.get_loc("underpowered")] = True
    return table


def _why(key: dict[str, Any], policies: dict[str, str], envs: dict[str, str]) -> str:
    bits = []
    if key["policy"] in policies:
        bits.append(f"policy {key['policy']!r} changed (its definition row says how)")
    if key["env"] in envs:
        bits.append(f"env {key['env']!r} changed (its definition row says how)")
    return "; ".join(bits)


def firing_floor(config: GateConfig, *, cells: int, seeds: int | None) -> tuple[float, float]:
    """(the smallest p-value the most favoured test can give, the level it is tested at)
    in the most favourable check: paired on ``seeds`` seeds with one changed cell in play,
    or unpaired (``seeds`` None) with every one of ``cells`` in play. The gate can fire
    only when the first is at most the second."""
    metric = max(gate_metrics(), key=config.share)
    if seeds is None:
        return 1.0 / (config.n_permutations + 1), config.alpha * config.share(metric) / cells
    # a rate's paired test is exact (McNemar): 1 / 2^n; a mean's is floored by P
    best = min(0.5 ** seeds if is_rate(m) else smallest_p(config.n_permutations,
                                                            paired_seeds=seeds)
               for m in gate_metrics() if config.share(m) >= config.share(metric) - 1e-12)
    return best, config.alpha * config.share(metric)


def _seeds_needed(config: GateConfig, cells: int, level: float) -> int | None:
    """The fewest paired seeds (up to 63) whose best test reaches ``level``, or None."""
    return next((k for k in range(1, 64)
                 if firing_floor(config, cells=cells, seeds=k)[0] <= level * (1 + 1e-9)),
                None)


def _refuse_if_it_cannot_fire(plans: list, config: GateConfig) -> None:
    """Raise when no test of the check could ever reach its share of alpha."""
    if not plans:
        return
    cells = len(plans)
    paired = [len(b) == len(r) and set(b["seed"].astype(np.int64))
              == set(r["seed"].astype(np.int64)) for _, b, r in plans]
    n = min(len(b) for _, b, _ in plans)
    floor, level = firing_floor(config, cells=cells, seeds=n if all(paired) else None)
    if floor <= level * (1 + 1e-9):
        return
    if all(paired):
        need = _seeds_needed(config, cells, level)
        if need is None:
            raise ParameterError(
                "gate alpha", config.alpha, f"a level some test can reach (with {n} seeds "
                f"its share is {level:.3g}; no paired test of up to 63 seeds gives a p-value "
                "that small)", hint="Set gate.alpha in the suite (0.05 by default) and "
                "--update-baseline.")
        raise ParameterError(
            "seeds", n, f"at least {need} paired seeds at alpha {config.alpha:g}",
            hint=f"With {n} seeds no test's p-value is below {floor:.3g}, above the "
            f"{level:.3g} its share of alpha allows even when one cell alone changed: the "
            "gate could never fire. Run the suite on more seeds (and --update-baseline).")
    need = math.ceil(1.0 / level - 1 - 1e-9)
    raise ParameterError(
        "gate n_permutations", config.n_permutations,
        f"at least {need} for {cells} cells at alpha {config.alpha:g}",
        hint=f"The run's seeds differ from the baseline's, so every cell is in play: the "
        f"most favoured metric is tested at {level:.3g}, below the smallest p-value "
        f"{floor:.3g} of {config.n_permutations} permutations: the gate could never fire. "
        "Raise gate.n_permutations in the suite (and --update-baseline), or run the "
        "baseline's seeds.")
