"""The scoring of a suite run beyond :func:`tap_bench.bench.scores.scoring.score`: coverage
references read or labelled, the sim-to-real gap of every policy, and the headline figures
of ``summary.json`` (part of :mod:`tap_bench.bench.run.runner`)."""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from tap_bench.bench.scores.gap import behaviour_gap, labelled_with_speed
from tap_bench.bench.scores.scoring import Scores
from tap_bench.errors import (
    LabelTableError,
    ParameterError,
)
from tap_bench.labelling import tap
from tap_bench.labels import validate_labels
from tap_bench.sources import read_womd
from tap_bench.stats.bootstrap import BootstrapConfig
from tap_bench.tableio import read_table
from tap_bench.thresholds import Thresholds

ReferenceSource = pd.DataFrame | str | os.PathLike | Sequence[str | os.PathLike]
"""A coverage reference: a label table, a label file, or driving-data files."""

_LABEL_SUFFIXES = (".parquet", ".pq", ".csv", ".csv.gz")


def _reference(name: str, source: ReferenceSource, level: str, thresholds: Thresholds
               ) -> tuple[pd.DataFrame | None, pd.DataFrame]:
    """(trajectories or None, label table) of one named reference."""
    if isinstance(source, pd.DataFrame):
        validate_labels(source, level, source=f"reference {name!r}")
        return None, source
    paths = [source] if isinstance(source, str | os.PathLike) else list(source)
    if not paths:
        raise ParameterError(f"references[{name!r}]", source, "a label table or data files")
    if len(paths) == 1 and str(paths[0]).lower().endswith(_LABEL_SUFFIXES):
        table = read_table(paths[0])
        if "sdl" in table.columns:  # a label file
            validate_labels(table, level, source=str(paths[0]))
            return None, table
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        traj = read_womd([str(p) for p in paths])
        labels = tap(traj, thresholds, source=name).labels("all")
    return traj, labels


def _with_gaps(scores: Scores, corpora: Mapping[str, tuple[pd.DataFrame | None, pd.DataFrame]],
               labels: pd.DataFrame, episodes: pd.DataFrame, level: str,
               thresholds: Thresholds, config: BootstrapConfig) -> Scores:
    """``scores`` with the sim-to-real gap of every policy from each reference given as
    driving-data files (:mod:`tap_bench.bench.scores.gap`): the egos' labels at the suite's level,
    lateral, longitudinal and interaction, against the reference's vehicles at the speeds
    the policy drives."""
    real = {name: traj for name, (traj, _) in corpora.items() if traj is not None}
    if not real or not len(labels) or "is_ego" not in labels.columns:
        return scores
    egos = labels[(labels["level"] == level) & labels["is_ego"].fillna(False)]
    speeds = episodes[["env", "policy", "seed", "mean_speed"]]
    egos = egos.drop(columns=["mean_speed"], errors="ignore").merge(
        speeds, on=["env", "policy", "seed"], how="left")
    axes = tuple(a for a in ("lateral", "longitudinal", "interaction") if a in egos.columns)
    rows, per_label = [], []
    for name, traj in real.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            reference = labelled_with_speed(traj, level, interactions="all",
                                            thresholds=thresholds, source=name)
        for policy, mine in egos.groupby("policy", sort=True):
            try:
                gap = behaviour_gap(mine, reference, name=str(policy), axes=axes,
                                    config=config, reference_name=name)
            except LabelTableError as err:  # nothing comparable: said, not scored
                scores.methods.setdefault("gap skipped", "")
                scores.methods["gap skipped"] += f"{policy} vs {name}: {err} "
                continue
            rows.append({"reference": name, **gap.row()})
            per_label.append(gap.labels.assign(reference=name, policy=str(policy)))
    if not rows:
        return scores
    scores.methods["gap"] = (
        "total variation distance between the shares of single labels ("
        + ", ".join(axes) + f") of the policy's egos and of the reference's vehicles at the "
        f"policy's speeds; {config.level:.0%} bootstrap of whole episodes of the policy and "
        f"whole scenes of the reference, each side on its own ({config.n_resamples} "
        "resamples; the debiased gap with its basic interval); floor: two samples of one "
        "behaviour with these episodes and scenes")
    return dataclasses.replace(scores, gap=pd.DataFrame(rows),
                               gap_labels=pd.concat(per_label, ignore_index=True))


def _describe_source(source: ReferenceSource) -> Any:
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
    return None if x is None or not np.isfinite(x) else round(float(x), 4)
