"""``bench check``: the regression gate of a run against a stored baseline.

A baseline file (JSON) keeps, for every (env, policy) of a suite, the per-episode values
the gate needs: the ego's SDL label and the measures (:data:`GATE_METRICS`). The gate
compares a run's episodes with the baseline's, per (env, policy) and metric:

- measures: the change of the mean (run - baseline); label distribution: the total
  variation distance between the two ego label distributions (``label_tv``, in [0, 1]);
- a **permutation test** of "no change" (episodes exchanged between run and baseline,
  ``n_permutations`` times, seeded): runs with other seeds are exchangeable with the
  baseline's under no change, so seed noise alone rarely fires the gate;
- **Holm's correction** over every test of the check, so ``alpha`` bounds the chance that a
  check of an unchanged suite fires anywhere;
- a metric **moved** when its change exceeds its margin *and* the Holm-adjusted p-value is
  below ``alpha``: a change must be both practically and statistically real.

An (env, policy) of the baseline missing from the run, or with failed episodes in the run,
moves too. The baseline file changes only through :func:`write_baseline`
(``--update-baseline``).
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tap_bench.bench.compare import NO_LABEL
from tap_bench.bench.measures import MEASURES
from tap_bench.bench.suite import GATE_METRICS, GateConfig
from tap_bench.errors import (
    BaselineError,
    BaselineMismatchError,
    FileFormatError,
    UnknownNameError,
)
from tap_bench.tableio import atomic_path

__all__ = ["BASELINE_FORMAT", "GateResult", "check", "holm", "read_baseline", "write_baseline"]

BASELINE_FORMAT = "tap-bench-baseline"
_EPISODE_FIELDS = ("env", "policy", "seed", "sdl", *(m.name for m in MEASURES))
_IDENTITY = ("suite", "suite_version", "level", "thresholds")


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
        head = (f"gate: {int(self.table['moved'].sum())} of {len(self.table)} checks moved "
                f"(moved = |change| > margin and Holm-adjusted permutation p < "
                f"{self.config.alpha:g}, {self.config.n_permutations} permutations)")
        if shown.empty:
            return head
        cols = ["env", "policy", "metric", "baseline", "run", "change", "margin", "p_holm",
                "moved", "note"]
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
    run = run_summary.get("run")
    if ok.empty:
        raise BaselineError(
            f"run {run!r} has {len(episodes)} episode(s) and none ran to the end; a baseline "
            "from it would let every later check pass. Fix the failures (bench run lists "
            "them) and make the baseline from a run whose episodes succeed.")
    cells = episodes[["env", "policy"]].drop_duplicates()
    done = set(map(tuple, ok[["env", "policy"]].drop_duplicates().to_numpy()))
    empty = [(e, p) for e, p in cells.to_numpy() if (e, p) not in done]
    if empty:
        listed = ", ".join(f"{e or '-'}/{p}" for e, p in empty[:5])
        raise BaselineError(
            f"run {run!r}: every episode of {listed} failed; the baseline would not test "
            "it. Fix those failures, or drop them from the suite, and run again.")
    rows = [[_json_value(v) for v in r] for r in ok[list(_EPISODE_FIELDS)].itertuples(
        index=False)]
    gate = run_summary.get("suite", {}).get("gate") or GateConfig().to_dict()
    doc = {"format": BASELINE_FORMAT, "format_version": 1,
           **_identity(run_summary),
           "created": time.strftime("%Y-%m-%d %H:%M:%S"),
           "from_run": run_summary.get("run"), "seeds": run_summary.get("seeds"),
           "versions": run_summary.get("versions", {}), "gate": gate,
           "episodes": {"columns": list(_EPISODE_FIELDS), "rows": rows}}
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(doc, indent=1) + "\n")
    return path


def read_baseline(path: str | os.PathLike) -> tuple[dict[str, Any], pd.DataFrame]:
    """The baseline's header and its episode rows.

    Raises:
        FileFormatError: missing file (with the command that makes one), not JSON, or not
            a baseline.
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
    missing = [c for c in _EPISODE_FIELDS if c not in table.columns]
    if missing:
        raise FileFormatError(f"{path}: baseline episodes lack {', '.join(missing)}; "
                              "re-make it with --update-baseline.")
    _check_baseline_rows(table, path)
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


def _check_baseline_rows(table: pd.DataFrame, path: Path) -> None:
    """Every value of a baseline's episodes of the type its column holds: text for env,
    policy (and sdl, or null), an integer seed, a number (or null, true/false for
    ``crashed``) for each measure."""
    def bad(col: str, ok) -> None:
        for i, value in enumerate(table[col].tolist()):
            if not ok(value):
                raise FileFormatError(
                    f"{path}: episode row {i}, column {col!r}: {value!r} is not "
                    f"{kinds[col]}. The baseline was edited or damaged; re-make it with "
                    "--update-baseline.")

    text = "text"
    kinds = {"env": text, "policy": text, "seed": "a non-negative integer", "sdl": "text or null",
             **{m.name: "a number or null" for m in MEASURES}}
    bad("env", lambda v: isinstance(v, str))
    bad("policy", lambda v: isinstance(v, str))
    bad("seed", lambda v: (isinstance(v, int) and not isinstance(v, bool))
        or (isinstance(v, str) and v.isdigit()))  # baselines before 0.2 wrote it as text
    bad("sdl", lambda v: v is None or isinstance(v, str))
    for m in MEASURES:
        bad(m.name, lambda v, flag=m.name == "crashed": v is None or (
            isinstance(v, int | float) and (flag or not isinstance(v, bool))))


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


def _permutations(n: int, config: GateConfig, stream: int) -> np.ndarray:
    rng = np.random.default_rng([config.seed, stream])
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
    k = codes.max() + 1
    n_b, n_r = len(base), len(run)

    def tv(groups: np.ndarray) -> np.ndarray:
        P = groups.shape[0]
        offsets = (np.arange(P) * k)[:, None]
        cb = np.bincount((offsets + groups[:, :n_b]).ravel(), minlength=P * k).reshape(P, k)
        cr = np.bincount((offsets + groups[:, n_b:]).ravel(), minlength=P * k).reshape(P, k)
        return 0.5 * np.abs(cb / n_b - cr / n_r).sum(axis=1)

    observed = float(tv(codes[None, :])[0])
    exceed = tv(codes[perms]) >= observed - 1e-12
    return observed, float((1 + exceed.sum()) / (1 + len(perms)))


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
    run_ok = run_episodes[run_episodes["status"] == "ok"]
    run_failed = run_episodes[run_episodes["status"] != "ok"]
    cells = sorted(set(map(tuple, baseline_episodes[["env", "policy"]].drop_duplicates()
                           .to_numpy())) | set(map(tuple, run_episodes[["env", "policy"]]
                                                   .drop_duplicates().to_numpy())))
    stream = 0
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
        stream += 1
        for metric in GATE_METRICS:
            margin = float(config.margins.get(metric, np.inf))
            if metric == "label_tv":
                b = base["sdl"].fillna(NO_LABEL).astype(str).to_numpy()
                r = run["sdl"].fillna(NO_LABEL).astype(str).to_numpy()
                perms = _permutations(len(b) + len(r), config, stream)
                change, p = _tv_test(b, r, perms)
                b_val = r_val = np.nan  # a distance between the two: see 'change'
            else:
                b = pd.to_numeric(base[metric], errors="coerce").to_numpy(float)
                r = pd.to_numeric(run[metric], errors="coerce").to_numpy(float)
                b, r = b[np.isfinite(b)], r[np.isfinite(r)]
                if len(b) < 2 and len(r) >= 2:  # null or text in the baseline: never silent
                    rows.append({**key, "metric": metric, "n_baseline": len(b),
                                 "n_run": len(r), "margin": margin, "forced": True,
                                 "note": "the baseline holds fewer than 2 numbers for it; "
                                         "re-make the baseline"})
                    continue
                if len(b) < 2 or len(r) < 2:
                    rows.append({**key, "metric": metric, "n_baseline": len(b),
                                 "n_run": len(r), "margin": margin, "forced": False,
                                 "note": "fewer than 2 values on a side: not tested"})
                    continue
                perms = _permutations(len(b) + len(r), config, stream)
                change, p = _mean_test(b, r, perms)
                b_val, r_val = float(b.mean()), float(r.mean())
            rows.append({**key, "metric": metric, "n_baseline": len(b), "n_run": len(r),
                         "baseline": b_val, "run": r_val, "change": change, "margin": margin,
                         "p_value": p, "forced": False, "note": ""})
    table = pd.DataFrame(rows)
    for col in ("baseline", "run", "change", "margin", "p_value"):
        if col not in table.columns:
            table[col] = np.nan
    tested = table["p_value"].notna().to_numpy()
    table["p_holm"] = np.nan
    table.loc[tested, "p_holm"] = holm(table.loc[tested, "p_value"].to_numpy(float))
    significant = table["p_holm"].to_numpy(float) < config.alpha
    beyond = np.abs(table["change"].to_numpy(float)) > table["margin"].to_numpy(float)
    table["moved"] = (significant & beyond) | table["forced"].fillna(False).to_numpy(bool)
    table["note"] = table["note"].fillna("")
    table = table.drop(columns="forced")
    table = table[["env", "policy", "metric", "n_baseline", "n_run", "baseline", "run",
                   "change", "margin", "p_value", "p_holm", "moved", "note"]]
    table = table.sort_values(["moved", "env", "policy"], ascending=[False, True, True],
                              kind="stable").reset_index(drop=True)
    return GateResult(table, bool(table["moved"].any()), config)
