"""``bench check``: the regression gate of a run against a stored baseline.

A baseline file (JSON) keeps, for every (env, policy) of a suite, the per-episode values
the gate needs: the seed, the ego's SDL label and the measures
(:func:`~tap_bench.bench.suite.gate_metrics`), and
the provenance of the run (each policy's full definition, with the SHA-256 of a model
file, and each env's resolved config). The gate compares a run's episodes with the
baseline's, per (env, policy) and metric:

- measures: the change of the mean (run - baseline); label distribution: the total
  variation distance between the two ego label distributions (``label_tv``, in [0, 1]);
- **paired** when the run and the baseline have the same seeds (the simulator is
  deterministic, so an unchanged policy gives the same episode on a seed): a sign-flip
  permutation test on the per-seed differences (for ``label_tv``, run and baseline labels
  swapped within seeds), exact over all 2^n flips up to :data:`EXACT_FLIPS_MAX_SEEDS` seeds;
- **unpaired** otherwise: episodes exchanged between run and baseline;
- **Holm's correction** over every test of the check, so ``alpha`` bounds the chance that a
  check of an unchanged suite fires anywhere;
- a metric **moved** when its change exceeds its margin *and* the Holm-adjusted p-value is
  below ``alpha``: a change must be both practically and statistically real.

**A gate that can never fire is refused.** With m tests and P permutations no p-value is
below 1 / (P + 1), and no Holm-adjusted one below m / (P + 1); with n paired seeds no
sign-flip p-value is below 2 / 2^n. :func:`check` raises :class:`~tap_bench.errors.
ParameterError` (naming the numbers and what would do) when the smallest attainable
Holm-adjusted p-value is not below alpha.

An (env, policy) of the baseline missing from the run, with failed episodes in the run, or
whose policy or env definition changed since the baseline (named, with what changed),
moves too. A baseline whose metric is missing or not numeric is an error
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

from tap_bench.bench.bootstrap import named_rng
from tap_bench.bench.compare import NO_LABEL
from tap_bench.bench.measures import MEASURES
from tap_bench.bench.suite import GateConfig, gate_metrics
from tap_bench.errors import (
    BaselineError,
    BaselineMismatchError,
    FileFormatError,
    ParameterError,
    UnknownNameError,
)
from tap_bench.tableio import atomic_path

__all__ = ["BASELINE_FORMAT", "EXACT_FLIPS_MAX_SEEDS", "MAX_FAILED_SHARE", "GateResult",
           "check", "definition_changes", "holm", "read_baseline", "smallest_p",
           "write_baseline"]

BASELINE_FORMAT = "tap-bench-baseline"
BASELINE_VERSION = 2
"""The baseline format this code writes and the newest it reads."""


def _episode_fields() -> tuple[str, ...]:
    return ("env", "policy", "seed", "sdl", *MEASURES.names())

_IDENTITY = ("suite", "suite_version", "level", "thresholds")
MAX_FAILED_SHARE = 0.05
"""A run with more than this share of failed episodes cannot become a baseline: the
baseline would hold a different set of episodes per (env, policy) than the runs checked
against it, and a failure that is part of the behaviour must be fixed, not frozen."""
EXACT_FLIPS_MAX_SEEDS = 16
"""Up to this many paired seeds the sign-flip test enumerates all 2^n flips (exact p)."""


@dataclass(frozen=True)
class GateResult:
    """What :func:`check` found.

    Attributes:
        table: one row per (env, policy, metric): env, policy, metric, n_baseline, n_run,
            baseline, run, change, margin, p_value, p_holm, moved, note.
        moved: True when anything moved (the command then exits 1).
        config: the gate settings used.
    """

    table: pd.DataFrame
    moved: bool
    config: GateConfig

    def moved_rows(self) -> pd.DataFrame:
        """The rows that moved."""
        return self.table[self.table["moved"]]

    def format(self, *, all_rows: bool = False) -> str:
        """A plain-text table of what moved (or of every check)."""
        shown = self.table if all_rows else self.moved_rows()
        kinds = sorted(set(self.table.get("test", pd.Series(dtype=str)).dropna()) - {""})
        head = (f"gate: {int(self.table['moved'].sum())} of {len(self.table)} checks moved "
                f"(moved = |change| > margin and Holm-adjusted permutation p < "
                f"{self.config.alpha:g}; {', '.join(kinds) or 'no'} tests, "
                f"{self.config.n_permutations} permutations)")
        if shown.empty:
            return head
        cols = ["env", "policy", "metric", "test", "baseline", "run", "change", "margin",
                "p_holm", "moved", "note"]
        text = shown[cols].to_string(index=False, float_format=lambda v: f"{v:.4g}",
                                     na_rep="-")
        return f"{head}\n{text}"


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
    """
    ok = episodes[episodes["status"] == "ok"]
    n_failed = len(episodes) - len(ok)
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
    rows = [[_json_value(v) for v in r] for r in ok[list(_episode_fields())].itertuples(
        index=False)]
    gate = run_summary.get("suite", {}).get("gate") or GateConfig().to_dict()
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


def read_baseline(path: str | os.PathLike) -> tuple[dict[str, Any], pd.DataFrame]:
    """The baseline's header and its episode rows.

    Raises:
        FileFormatError: missing file (with the command that makes one), not JSON (or not
            text), not a baseline, rows of the wrong shape or type, gate settings that
            :class:`GateConfig` refuses.
        BaselineError: a metric missing, or a measure that is not a number.
    """
    path = Path(path)
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
        bad = values.map(lambda v: v is not None and not isinstance(v, bool | int | float))
        if bad.any():
            row = int(np.flatnonzero(bad.to_numpy())[0])
            raise BaselineError(
                f"{path}: episode row {row} ({table['env'].iloc[row]}, "
                f"{table['policy'].iloc[row]}, seed {table['seed'].iloc[row]}) has "
                f"{m.name} = {values.iloc[row]!r}, not a number; a baseline holds numbers "
                "(or null where a measure is undefined). Re-make it with --update-baseline.")
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
        GateConfig(**{k: v for k, v in gate.items()
                      if k in ("alpha", "n_permutations", "seed", "margins")})
    except (TypeError, ValueError, UnknownNameError) as err:
        raise FileFormatError(f"{path}: gate settings: {err} Restore them from the suite "
                              "(envs/suites/*.json) or re-make the baseline with "
                              "--update-baseline.") from None
    return doc, table


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
    bad("seed", lambda v: (isinstance(v, int) and not isinstance(v, bool))
        or (isinstance(v, str) and v.isdigit()))  # baselines before 0.2 wrote it as text
    bad("sdl", lambda v: v is None or isinstance(v, str))


def holm(p: np.ndarray) -> np.ndarray:
    """Holm-adjusted p-values (step-down; monotone; capped at 1)."""
    p = np.asarray(p, float)
    m = len(p)
    if m == 0:
        return p
    order = np.argsort(p, kind="stable")
    adjusted = np.minimum(1.0, np.maximum.accumulate((m - np.arange(m)) * p[order]))
    out = np.empty(m)
    out[order] = adjusted
    return out


def smallest_p(n_permutations: int, *, paired_seeds: int | None = None,
               sizes: tuple[int, int] | None = None) -> float:
    """The smallest p-value one permutation test can give.

    Args:
        n_permutations: random permutations P (p >= 1 / (P + 1)).
        paired_seeds: for a paired test, the seeds n (exact sign flips: p >= 2 / 2^n).
        sizes: for an unpaired test, the two sample sizes (p >= 2 / C(n1 + n2, n1)).
    """
    floor = 1.0 / (n_permutations + 1)
    if paired_seeds is not None:
        if paired_seeds <= EXACT_FLIPS_MAX_SEEDS:
            return 2.0 / 2 ** paired_seeds if paired_seeds > 0 else 1.0
        return max(floor, 2.0 / 2 ** paired_seeds)
    if sizes is not None:
        return max(floor, min(1.0, 2.0 / math.comb(sum(sizes), sizes[0])))
    return floor


def _flips(n: int, config: GateConfig, key: tuple) -> np.ndarray:
    """(F, n) of +-1: all 2^n sign patterns (n <= EXACT_FLIPS_MAX_SEEDS), else the identity
    and P random ones from the stream ``("gate", *key)``."""
    if n <= EXACT_FLIPS_MAX_SEEDS:
        return np.array(list(itertools.product((1.0, -1.0), repeat=n))).reshape(-1, n)
    rng = named_rng(config.seed, "gate", *key)
    random = rng.choice((1.0, -1.0), size=(config.n_permutations, n))
    return np.vstack([np.ones((1, n)), random])


def _p_from(perm_stats: np.ndarray, observed: float) -> float:
    """Share of the flips (the identity among them) whose statistic reaches the observed."""
    return float((perm_stats >= observed - 1e-12).sum()) / len(perm_stats)


def _paired_mean_test(base: np.ndarray, run: np.ndarray, config: GateConfig, key: tuple
                      ) -> tuple[float, float]:
    """(mean per-seed change, sign-flip p of |mean change|)."""
    d = run - base
    flips = _flips(len(d), config, key)
    perm = np.abs(flips @ d) / len(d)
    return float(d.mean()), _p_from(perm, abs(float(d.mean())))


def _tv(codes_b: np.ndarray, codes_r: np.ndarray, k: int) -> np.ndarray:
    """(F,) total variation distance between rows of two (F, n) code matrices."""
    F, nb = codes_b.shape
    nr = codes_r.shape[1]
    offsets = (np.arange(F) * k)[:, None]
    cb = np.bincount((offsets + codes_b).ravel(), minlength=F * k).reshape(F, k)
    cr = np.bincount((offsets + codes_r).ravel(), minlength=F * k).reshape(F, k)
    return 0.5 * np.abs(cb / nb - cr / nr).sum(axis=1)


def _paired_tv_test(base: np.ndarray, run: np.ndarray, config: GateConfig, key: tuple
                    ) -> tuple[float, float]:
    """(TV of the label distributions, p with run and baseline labels swapped per seed)."""
    _, codes = np.unique(np.r_[base, run], return_inverse=True)
    k = int(codes.max()) + 1
    cb, cr = codes[:len(base)], codes[len(base):]
    flips = _flips(len(base), config, key) > 0
    perm = _tv(np.where(flips, cb, cr), np.where(flips, cr, cb), k)
    observed = float(_tv(cb[None, :], cr[None, :], k)[0])
    return observed, _p_from(perm, observed)


def _permutations(n: int, config: GateConfig, key: tuple) -> np.ndarray:
    rng = named_rng(config.seed, "gate", *key)
    return np.argsort(rng.random((config.n_permutations, n)), axis=1)


def _mean_test(base: np.ndarray, run: np.ndarray, perms: np.ndarray) -> tuple[float, float]:
    """(change of the mean, permutation p of |change|)."""
    pooled = np.r_[base, run]
    n_b = len(base)
    change = run.mean() - base.mean()
    shuffled = pooled[perms]
    perm_change = shuffled[:, n_b:].mean(axis=1) - shuffled[:, :n_b].mean(axis=1)
    exceed = np.abs(perm_change) >= abs(change) - 1e-12
    return float(change), float((1 + exceed.sum()) / (1 + len(perms)))


def _tv_test(base: np.ndarray, run: np.ndarray, perms: np.ndarray) -> tuple[float, float]:
    """(total variation distance of the label distributions, permutation p)."""
    _, codes = np.unique(np.r_[base, run], return_inverse=True)
    k = int(codes.max()) + 1
    n_b = len(base)
    observed = float(_tv(codes[None, :n_b], codes[None, n_b:], k)[0])
    shuffled = codes[perms]
    exceed = _tv(shuffled[:, :n_b], shuffled[:, n_b:], k) >= observed - 1e-12
    return observed, float((1 + exceed.sum()) / (1 + len(perms)))


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
          config: GateConfig | None = None) -> GateResult:
    """Check a run against a baseline (see the module docstring).

    Args:
        run_summary, run_episodes: the run's ``summary.json`` and episode table.
        baseline, baseline_episodes: from :func:`read_baseline`.
        config: gate settings; default: the baseline's.

    Raises:
        BaselineMismatchError: suite, level or thresholds differ.
        ParameterError: the gate can never fire with these tests, permutations and seeds
            (the message gives the numbers and what would do).
    """
    here, there = _identity(run_summary), {k: baseline.get(k) for k in _IDENTITY}
    diff = [k for k in _IDENTITY if here[k] != there[k]]
    if diff:
        what = "; ".join(f"{k}: run {here[k]!r}, baseline {there[k]!r}" for k in diff)
        raise BaselineMismatchError(
            f"the run and the baseline differ in {what}. Check against a baseline of the same "
            "suite and settings, or replace it with --update-baseline.")
    if config is None:
        gate = dict(baseline.get("gate") or {})
        config = GateConfig(**{k: v for k, v in gate.items()
                               if k in ("alpha", "n_permutations", "seed", "margins")})
    rows: list[dict[str, Any]] = []
    changed = definition_changes(run_summary.get("provenance"), baseline.get("provenance"))
    changed_policy = {name: what for kind, name, what in changed if kind == "policy"}
    changed_env = {name: what for kind, name, what in changed if kind == "env"}
    run_ok = run_episodes[run_episodes["status"] == "ok"]
    run_failed = run_episodes[run_episodes["status"] != "ok"]
    cells = sorted(set(map(tuple, baseline_episodes[["env", "policy"]].drop_duplicates()
                           .to_numpy())) | set(map(tuple, run_episodes[["env", "policy"]]
                                                   .drop_duplicates().to_numpy())))
    for kind, name, what in changed:
        rows.append({"env": name if kind == "env" else "", "policy": name if kind == "policy"
                     else "", "metric": "definition", "test": "", "forced": True,
                     "note": f"{kind} {name!r} changed since the baseline: {what}"})
    plans = []  # (key, base, run) of the cells to test
    for env, policy in cells:
        base = baseline_episodes[(baseline_episodes["env"] == env)
                                 & (baseline_episodes["policy"] == policy)]
        run = run_ok[(run_ok["env"] == env) & (run_ok["policy"] == policy)]
        key = {"env": env, "policy": policy}
        n_failed = int(((run_failed["env"] == env) & (run_failed["policy"] == policy)).sum())
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
    _refuse_if_it_cannot_fire(plans, config)
    for key, base, run in plans:
        seeds_b = base["seed"].astype(np.int64).to_numpy()
        seeds_r = run["seed"].astype(np.int64).to_numpy()
        paired = len(seeds_b) == len(seeds_r) and set(seeds_b) == set(seeds_r)
        if paired:
            base = base.iloc[np.argsort(seeds_b, kind="stable")]
            run = run.iloc[np.argsort(seeds_r, kind="stable")]
        why = _why(key, changed_policy, changed_env)
        for metric in gate_metrics():
            margin = config.margin(metric)
            name = (key["env"], key["policy"], metric)
            row = {**key, "metric": metric, "test": "paired" if paired else "unpaired",
                   "margin": margin, "forced": False, "note": why}
            if metric == "label_tv":
                b = base["sdl"].fillna(NO_LABEL).astype(str).to_numpy()
                r = run["sdl"].fillna(NO_LABEL).astype(str).to_numpy()
                if paired:
                    change, p = _paired_tv_test(b, r, config, name)
                else:
                    change, p = _tv_test(b, r, _permutations(len(b) + len(r), config, name))
                rows.append({**row, "n_baseline": len(b), "n_run": len(r), "baseline": np.nan,
                             "run": np.nan, "change": change, "p_value": p})
                continue
            b = pd.to_numeric(base[metric], errors="coerce").to_numpy(float)
            r = pd.to_numeric(run[metric], errors="coerce").to_numpy(float)
            if paired:
                one_side = np.isfinite(b) != np.isfinite(r)
                if one_side.any():
                    rows.append({**row, "n_baseline": int(np.isfinite(b).sum()),
                                 "n_run": int(np.isfinite(r).sum()), "forced": True,
                                 "note": f"defined on {int(one_side.sum())} seeds in only one "
                                 "of run and baseline (e.g. seed "
                                 f"{int(seeds_r[np.argsort(seeds_r)][one_side][0])})"})
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
            if paired:
                change, p = _paired_mean_test(b, r, config, name)
            else:
                change, p = _mean_test(b, r, _permutations(len(b) + len(r), config, name))
            rows.append({**row, "n_baseline": len(b), "n_run": len(r),
                         "baseline": float(b.mean()), "run": float(r.mean()),
                         "change": change, "p_value": p})
    table = pd.DataFrame(rows)
    for col in ("baseline", "run", "change", "margin", "p_value", "n_baseline", "n_run",
                "test"):
        if col not in table.columns:
            table[col] = np.nan
    tested = table["p_value"].notna().to_numpy()
    table["p_holm"] = np.nan
    table.loc[tested, "p_holm"] = holm(table.loc[tested, "p_value"].to_numpy(float))
    significant = table["p_holm"].to_numpy(float) < config.alpha
    beyond = np.abs(table["change"].to_numpy(float)) > table["margin"].to_numpy(float)
    table["moved"] = (significant & beyond) | table["forced"].fillna(False).to_numpy(bool)
    table["note"] = table["note"].fillna("")
    table["test"] = table["test"].fillna("")
    table = table.drop(columns="forced")
    table = table[["env", "policy", "metric", "test", "n_baseline", "n_run", "baseline", "run",
                   "change", "margin", "p_value", "p_holm", "moved", "note"]]
    table = table.sort_values(["moved", "env", "policy"], ascending=[False, True, True],
                              kind="stable").reset_index(drop=True)
    return GateResult(table, bool(table["moved"].any()), config)


def _why(key: dict[str, Any], policies: dict[str, str], envs: dict[str, str]) -> str:
    bits = []
    if key["policy"] in policies:
        bits.append(f"policy {key['policy']!r} changed: {policies[key['policy']]}")
    if key["env"] in envs:
        bits.append(f"env {key['env']!r} changed: {envs[key['env']]}")
    return "; ".join(bits)


def _refuse_if_it_cannot_fire(plans: list, config: GateConfig) -> None:
    """Raise when the smallest attainable Holm-adjusted p-value is not below alpha."""
    m = len(plans) * len(gate_metrics())
    if not m:
        return
    floor = m / (config.n_permutations + 1)
    if floor >= config.alpha:
        need = math.floor(m / config.alpha + 1e-9)  # P + 1 > m / alpha
        raise ParameterError(
            "gate n_permutations", config.n_permutations,
            f"at least {need} for {m} tests at alpha {config.alpha:g}",
            hint=f"With {config.n_permutations} permutations no p-value is below "
            f"1/{config.n_permutations + 1}, so the smallest Holm-adjusted p-value is "
            f"{m}/{config.n_permutations + 1} = {floor:.3g} >= alpha {config.alpha:g}: the "
            "gate could never fire. Raise gate.n_permutations in the suite (and "
            "--update-baseline) or check fewer envs and policies.")
    best = []
    for _, base, run in plans:
        sb, sr = set(base["seed"].astype(np.int64)), set(run["seed"].astype(np.int64))
        if len(base) == len(run) and sb == sr:
            best.append(smallest_p(config.n_permutations, paired_seeds=len(sb)))
        else:
            best.append(smallest_p(config.n_permutations, sizes=(len(base), len(run))))
    if min(best) * m >= config.alpha:
        n = min(len(b) for _, b, _ in plans)
        need = next(k for k in range(1, 64) if 2.0 / 2 ** k * m < config.alpha)
        raise ParameterError(
            "seeds", n, f"at least {need} paired seeds for {m} tests at alpha "
            f"{config.alpha:g}",
            hint=f"With {n} seeds the smallest p-value of a test is {min(best):.3g}, so the "
            f"smallest Holm-adjusted one is {min(best) * m:.3g} >= alpha: the gate could "
            "never fire. Run the suite on more seeds (and --update-baseline).")
