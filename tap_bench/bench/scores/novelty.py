"""Unique manoeuvres: labels an agent produces that the reference corpus never shows
(SPEC section 6).

The **novelty rate** is the share of the agent's episodes whose ego SDL label is absent
from the reference corpus (:func:`tap_bench.bench.scores.coverage.corpus_reference`), with a
Wilson score interval (0 novel of 30 episodes: [0, 0.114], never [0, 0]). Pooled over envs
it is the episode-weighted mean of the per-env rates, each env's episodes held against that
env's reference (:mod:`tap_bench.bench.scores.scoring`). "Never shows" is relative to a finite
corpus: a label absent from a small reference may only be rare; the report states the
reference's size beside the rate.

**Windows.** Episodes cut into windows (scored against a corpus of short tracks:
:func:`tap_bench.bench.scores.windows.window_episodes`) are not independent: the windows of one
episode share its policy's state and traffic. With ``windowed`` the Wilson interval is
taken at the effective sample size ``n / deff`` (Rao and Scott's design effect), ``deff``
the variance of the rate under a cluster bootstrap (whole episodes with their windows,
:func:`tap_bench.stats.bootstrap.cluster_weights`) over the binomial ``p (1 - p) / n``,
kept within [1, windows per episode]; with no novel window, or all novel, where no
variance can be seen, ``deff`` is the windows per episode (the episodes are the sample).

Against the manoeuvres of a corpus (a ``"segments"`` reference: the labels of segments,
:func:`tap_bench.bench.scores.coverage.corpus_reference` with ``unit="segments"``), an episode is
novel when one of its segments carries a label the reference's segments never show, and
the novel labels listed are those segment labels (count: the episodes showing them).

This differs from SPEC section 5's *unique* label (no other trajectory of one data set has
it, :mod:`tap_bench.similarity`): here the agent is held against another corpus.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from tap_bench.bench.scores.coverage import Reference, unit_items
from tap_bench.bench.scores.windows import CUT_FROM
from tap_bench.errors import LabelTableError
from tap_bench.labels import label_text
from tap_bench.stats.bootstrap import BootstrapConfig, cluster_weights
from tap_bench.stats.intervals import wilson_interval

__all__ = ["NoveltyResult", "novelty", "pooled_novelty"]


@dataclass(frozen=True)
class NoveltyResult:
    """Novel labels of one agent.

    Attributes:
        n: episodes with a label.
        n_novel: episodes whose label the reference never shows.
        rate, rate_low, rate_high: ``n_novel / n`` and its interval.
        labels: one row per novel label: label, count, share (of the agent's episodes),
            example_scenario (the first episode showing it), sorted by count.
    """

    n: int
    n_novel: int
    rate: float
    rate_low: float
    rate_high: float
    labels: pd.DataFrame

    def row(self) -> dict:
        """The scalar fields as a dict (a row of the novelty table)."""
        return {"n": self.n, "n_novel": self.n_novel, "novel_rate": self.rate,
                "novel_low": self.rate_low, "novel_high": self.rate_high,
                "n_novel_labels": len(self.labels)}


def novelty(episodes: pd.DataFrame, reference: Reference, *,
            config: BootstrapConfig | None = None, axes=None, windowed: bool = False
            ) -> NoveltyResult:
    """The agent's labels that ``reference`` never shows, as a rate and examples.

    Args:
        episodes: the agent's rows of the episode table (``sdl``; ``env`` and
            ``scenario_id`` when present); failed episodes and NA labels are left out.
        reference: a corpus reference (whole SDL labels) at the labels' level.
        config: the interval level.
        axes: the axes a label is made of (as the reference's; default the ``sdl`` label).
        windowed: the rows are windows cut from episodes, each one's episode in the
            :data:`~tap_bench.bench.scores.windows.CUT_FROM` column: the interval counts
            whole episodes' worth of information (the design effect of a cluster bootstrap
            by episode; module docstring).

    Raises:
        LabelTableError: ``reference`` is a vocabulary, or ``windowed`` and ``episodes``
            without the ``CUT_FROM`` column.
    """
    if reference.kind == "vocabulary":
        raise LabelTableError("novelty needs a reference corpus (its whole SDL labels); a "
                              "vocabulary holds every single label, so nothing is novel.")
    if windowed and CUT_FROM not in episodes.columns:
        raise LabelTableError(
            f"novelty(windowed=True) needs the {CUT_FROM!r} column of a table of windows "
            f"(the episode each window was cut from); window_episodes adds it, or add it "
            f"as window_episode(table['scenario_id']).")
    config = config or BootstrapConfig()
    ok = episodes
    if "status" in ok.columns:
        ok = ok[ok["status"] == "ok"]
    text = label_text(ok, axes)
    ok = ok[text.notna().to_numpy()]
    lab = text.dropna().to_numpy(str)
    novel = ~reference.contains(lab)
    n = len(lab)
    if n == 0:
        empty = pd.DataFrame(columns=["label", "count", "share", "example_scenario"])
        return NoveltyResult(0, 0, float("nan"), float("nan"), float("nan"), empty)
    deff = _design_effect(novel, ok[CUT_FROM], config) if windowed else 1.0
    lo, hi = wilson_interval(novel.sum() / deff, n / deff, config.level)
    example = (ok["scenario_id"].to_numpy() if "scenario_id" in ok.columns else
        np.arange(n).astype(str))
    if reference.kind == "segments":  # the novel segment labels, once per episode
        known = set(reference.items)
        pairs = [(item, j) for j, items in enumerate(unit_items(lab, reference.axes))
                 for item in dict.fromkeys(items) if item not in known]
        shown = np.array([p[0] for p in pairs], dtype=object)
        where = np.array([p[1] for p in pairs], dtype=np.int64)
    else:
        shown, where = lab[novel], np.flatnonzero(novel)
    names, first, counts = np.unique(shown.astype(str), return_index=True,
                                     return_counts=True)
    order = np.lexsort((names, -counts))
    labels = pd.DataFrame({"label": names[order], "count": counts[order],
                           "share": counts[order] / n,
                           "example_scenario": example[where[first[order]]] if len(names)
                           else np.zeros(0, object)})
    return NoveltyResult(n, int(novel.sum()), float(novel.mean()), float(lo), float(hi), labels)


def _design_effect(novel: np.ndarray, cut_from: pd.Series, config: BootstrapConfig
                   ) -> float:
    """The variance of the novel share under a cluster bootstrap by episode (``cut_from``:
    (n,) each window's episode) over the binomial variance, within [1, windows per
    episode] (module docstring)."""
    episodes = cut_from.to_numpy(object)
    n, size = len(novel), len(novel) / len(set(episodes))
    p = float(novel.mean())
    if p in (0.0, 1.0):
        return max(1.0, size)
    w = cluster_weights(config.rng("novelty", "clusters", n), episodes, config.n_resamples)
    rates = (w @ novel.astype(float)) / np.maximum(w.sum(axis=1), 1)
    return float(np.clip(rates.var() / (p * (1 - p) / n), 1.0, max(1.0, size)))


def pooled_novelty(results: dict[str, NoveltyResult], level: float) -> NoveltyResult:
    """Pool per-env novelty: the episode-weighted mean of the per-env rates (each env's
    episodes held against its own reference), a Wilson interval on the pooled counts, and
    the per-env novel labels with an ``env`` column (a label is (env, label))."""
    n = sum(r.n for r in results.values())
    k = sum(r.n_novel for r in results.values())
    frames = [r.labels.assign(env=env) for env, r in results.items() if len(r.labels)]
    labels = (pd.concat(frames, ignore_index=True) if frames else
        pd.DataFrame(columns=["label", "count", "share", "example_scenario", "env"]))
    if len(labels):
        labels["share"] = labels["count"] / n
        labels = labels.sort_values(["count", "env", "label"], ascending=[False, True, True],
                                    kind="stable").reset_index(drop=True)
    if n == 0:
        return NoveltyResult(0, 0, float("nan"), float("nan"), float("nan"), labels)
    lo, hi = wilson_interval(k, n, level)
    return NoveltyResult(n, k, k / n, float(lo), float(hi), labels)
