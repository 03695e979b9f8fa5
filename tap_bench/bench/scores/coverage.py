"""Behaviour coverage: how much of a reference label set an agent exhibits.

A **reference** (:class:`Reference`) is a set of items with weights:

- the SDL vocabulary of a level (``vocabulary_reference``): the single labels
  (``Left Merge``, ``Maintain Fast Speed`` ...), equal weights; an episode exhibits the
  single labels its SDL label is made of. This is the reference of the quick training-time
  signal :func:`tap_bench.sim.coverage.label_coverage`, whose value is the point estimate
  here;
- the labels of a reference corpus (``corpus_reference``), e.g. WOMD's vehicles or IDM's
  egos: whole SDL labels, weighted by their frequency in the corpus; an episode exhibits
  its own SDL label;
- the **manoeuvres** of a reference corpus (``corpus_reference(..., unit="segments")``):
  the labels of its segments (the runs of one label on one axis, the rows of TAP's segment
  table: ``lateral: Left Merge``, ``longitudinal: Accelerate``), weighted by how many
  segments carry each; an episode exhibits the labels of its segments. Whole-episode
  labels are near-unique (idm-aggressive: 12 distinct labels in 12 episodes), so their
  coverage mostly counts coincidences; segments repeat.

For an agent's n episodes, :func:`coverage` reports

- ``coverage``: share of the reference's items exhibited at least once;
- ``weighted_coverage``: the reference weight of the items exhibited (the share of the
  reference corpus's trajectories whose label the agent shows);
- ``n_distinct``, the items covered and those missed.

The diversity of the agent's own labels (Hill numbers, completeness) is
:mod:`tap_bench.bench.scores.diversity`'s.

**Labels belong to an env.** A reference made of rollouts in one env is held against the
agent's episodes in that env only; pooled over envs (:func:`pooled_coverage`) the coverage
is the share of all the envs' (env, label) reference items shown, that is the per-env
coverages averaged with weights K_env (each env's number of reference items), and the
weighted coverage the per-env weighted coverages averaged with the envs' shares of the
reference corpus. A reference without envs (a WOMD corpus, the vocabulary) is one set for
every env, and its pooled coverage is that of all the agent's episodes together.

**What the intervals are for.** Coverage counts distinct labels, so it grows with n: the
estimand is the expected coverage of an evaluation with the same number of episodes, of
which the observed value is unbiased. A plain bootstrap underestimates its spread (labels
the agent produces but the sample missed never appear in a resample). The intervals
therefore follow Chao et al. (2014, Ecol. Monogr. 84:45, the iNEXT method): the empirical
distribution is augmented with the undetected items the Chao1 (Chao2 for incidence)
estimator predicts, carrying the Good-Turing undetected mass
(:func:`tap_bench.bench.scores.diversity.estimated_population`, whose undetected mass is
singletons over sampling units, as iNEXT's); as many of them as the reference has unseen
items count as reference items, which widens the interval: the conservative choice.
Episodes are drawn from it (multinomially for whole labels, independently per item for
vocabulary items) and the interval is the **studentized bootstrap** of
:mod:`~tap_bench.bench.scores.diversity`
(:func:`~tap_bench.stats.intervals.studentized_interval`):
each draw's coverage minus the population's own expected coverage, over the draw's own
standard error (:func:`~tap_bench.bench.scores.diversity.distinct_variance`: the variance of the
count of reference items shown under that draw's population, its undetected items counted
up to the reference items the draw has not shown; floored at estimate / n), gives t*, and
the interval is ``estimate - t*_hi se .. estimate - t*_lo se``, clipped to [0, 1]. iNEXT's
``estimate +- z sd`` covers less than its level; why, and the measured coverage of both,
are in docs/benchmark.md. When the population has nothing undetected to draw
(a handful of episodes with no singleton), the draws cannot move and the interval is
``estimate +- n u / K`` instead, with u the Wilson upper limit of 0 of n: at most that
share of episodes could show an item not yet seen (never a zero-width interval on an
estimate).

**Windows are drawn with their episode.** Episodes cut into windows of the reference's
track length (:func:`tap_bench.bench.scores.windows.window_episodes`) give several labels per
episode that share its policy's state; drawn as independent episodes they make the
interval far too narrow (copies of one label count as repeated evidence). With
``clusters`` (the episode of each window, :func:`tap_bench.bench.scores.windows.window_episode`) the
sampling unit is the episode: it shows the items of all its windows (incidence data over
G episodes, Chao2), the detected items are drawn by resampling whole episodes
(:func:`tap_bench.stats.bootstrap.cluster_weights`) and the undetected ones each per
episode with its Chao2 probability, as vocabulary items are; the studentizing standard
errors and the fallback count G episodes. Episodes whose windows all copy one label give
the interval of one window per episode.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from tap_bench import sdl
from tap_bench.bench.scores.diversity import distinct_variance, estimated_population
from tap_bench.errors import LabelTableError, did_you_mean
from tap_bench.labels import label_text
from tap_bench.sim.coverage import vocabulary_tokens
from tap_bench.stats.bootstrap import BootstrapConfig, cluster_weights, scene_clusters
from tap_bench.stats.intervals import studentized_interval, wilson_interval, z_value

__all__ = [
    "UNITS",
    "CoverageResult",
    "Reference",
    "corpus_reference",
    "coverage",
    "pooled_coverage",
    "unit_items",
    "vocabulary_reference",
]

UNITS = ("episodes", "segments")
"""What coverage and novelty are scored on: each episode's whole label, or the labels of
its segments (the manoeuvres it contains)."""


@dataclass(frozen=True)
class Reference:
    """A reference label set.

    Attributes:
        items: (K,) the reference items (single labels or whole SDL labels), sorted.
        weights: (K,) their weights, summing to 1 (corpus frequencies, or 1/K).
        kind: ``"vocabulary"`` (items are single labels), ``"corpus"`` (whole labels) or
            ``"segments"`` (the labels of segments, ``axis: label``).
        level: the SDL level.
        description: one line for reports (what, how many trajectories).
        n_trajectories: trajectories of the corpus (0 for a vocabulary).
        units: (n_trajectories,) each trajectory's label on ``axes`` (corpora: what the
            same-policy null splits in halves, :mod:`tap_bench.bench.scores.null`).
        seeds: (n_trajectories,) each trajectory's seed when the corpus is rollouts (the
            null then pairs a policy's episodes with the reference's by seed), else None.
        axes: the axes a label is made of.
        scenes: (n_trajectories,) each trajectory's scene (its independent unit,
            :func:`tap_bench.stats.bootstrap.scene_clusters`) when some scene holds more
            than one (WOMD vehicles): the null splits and resamples whole scenes. None:
            every trajectory its own.
    """

    items: np.ndarray
    weights: np.ndarray
    kind: str
    level: str
    description: str
    n_trajectories: int = 0
    units: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, object))
    seeds: np.ndarray | None = field(repr=False, default=None)
    axes: tuple[str, ...] = sdl.AXES
    scenes: np.ndarray | None = field(repr=False, default=None)

    def __len__(self) -> int:
        return len(self.items)

    @property
    def unit(self) -> str:
        """``"segments"`` for a reference of segment labels, else ``"episodes"``."""
        return "segments" if self.kind == "segments" else "episodes"

    def contains(self, labels: np.ndarray) -> np.ndarray:
        """(n,) bool: which labels the reference shows: whole SDL labels (corpus references)
        or, for segment references, labels all of whose segments it shows."""
        labels = np.asarray(labels, dtype=object)
        if self.kind != "segments":
            return np.isin(labels, self.items)
        known = set(self.items)
        return np.array([set(items) <= known for items in unit_items(labels, self.axes)],
                        bool)


def unit_items(labels, axes=sdl.AXES) -> list[tuple[str, ...]]:
    """The segment labels of each label: ``"Straight > Left Merge > Straight | Accelerate"``
    on the lateral and longitudinal axes gives ``("lateral: Straight", "lateral: Left
    Merge", "lateral: Straight", "longitudinal: Accelerate")`` (one per segment, in order).

    Args:
        labels: (n,) label texts on ``axes`` (:func:`tap_bench.labels.label_text`).
        axes: the axes the texts are made of.
    """
    out = []
    for text in labels:
        sides = str(text).split(sdl.SDL_SEPARATOR)
        if len(sides) != len(axes):
            raise LabelTableError(f"label {text!r} has {len(sides)} axes, not the "
                                  f"{len(axes)} of {', '.join(axes)}.")
        out.append(tuple(f"{axis}: {tok}" for axis, side in zip(axes, sides, strict=True)
                         for tok in sdl.split(side)))
    return out


def vocabulary_reference(level: str = "action", *, axes=None) -> Reference:
    """The single labels of ``level`` on ``axes`` (default lateral and longitudinal; the
    interaction axis adds its relations), equally weighted."""
    sdl.check_level(level)
    axes = sdl.check_axes(axes)
    tokens = ({t for axis in axes for t in sdl.vocabulary(level, axis)} if axes != sdl.AXES
        else vocabulary_tokens(level))
    items = np.array(sorted(tokens), dtype=object)
    return Reference(items, np.full(len(items), 1.0 / len(items)), "vocabulary", level,
                     f"the {len(items)} single labels of the {level} level")


def corpus_reference(labels: pd.DataFrame, level: str, *, tracks: str = "vehicles",
                     name: str = "reference corpus", axes=None,
                     unit: str = "episodes") -> Reference:
    """The SDL labels of a reference corpus, weighted by their frequency.

    Args:
        labels: a label table (SPEC section 1).
        level: the SDL level to take.
        tracks: ``"vehicles"`` (rows whose ``object_type`` is vehicle, or all rows when the
            column is absent), ``"ego"`` (rows with ``is_ego``), or ``"all"``.
        name: what the corpus is, for reports (``"WOMD"``, ``"idm rollouts"``).
        axes: the axes a label is made of (default lateral and longitudinal: the ``sdl``
            label; :func:`tap_bench.labels.label_text`). Rows without a
            label on an axis (not labelled with interactions) are left out.
        unit: ``"episodes"`` (whole labels) or ``"segments"`` (the labels of their segments,
            weighted by how many segments carry each: a ``"segments"`` reference).
    """

    if unit not in UNITS:
        raise did_you_mean("coverage unit", unit, UNITS)
    if tracks not in ("vehicles", "ego", "all"):
        raise did_you_mean("reference tracks", tracks, ("vehicles", "ego", "all"))
    table = labels
    if "sdl" not in table.columns:
        raise LabelTableError(f"{name}: no 'sdl' column; give a label table "
                              "(tap-bench label ... --level all).")
    if "level" in table.columns:
        table = table[table["level"].to_numpy() == level]
    if tracks == "vehicles" and "object_type" in table.columns:
        table = table[table["object_type"].to_numpy() == "vehicle"]
    elif tracks == "ego":
        if "is_ego" not in table.columns:
            raise LabelTableError(f"{name}: tracks='ego' needs an is_ego column.")
        table = table[table["is_ego"].fillna(False).to_numpy(bool)]
    axes = sdl.check_axes(axes)
    text = label_text(table, axes)
    has = text.notna().to_numpy()
    lab = text[has].to_numpy(str)
    if not len(lab):
        raise LabelTableError(f"{name}: no {tracks} labels at level {level!r}; label it at "
                              f"that level (--level {level} or all).")
    seeds = table["seed"].to_numpy()[has] if "seed" in table.columns else None
    scenes = scene_clusters(table)[has]
    scenes = scenes if len(set(scenes)) < len(scenes) else None  # one scene, many tracks
    whose = {"all": "trajectories (every track)", "ego": "ego trajectories",
             "vehicles": "vehicle trajectories"}[tracks]
    if unit == "segments":
        segs = np.array([i for items in unit_items(lab, axes) for i in items], dtype=object)
        items, counts = np.unique(segs, return_counts=True)
        return Reference(items.astype(object), counts / counts.sum(), "segments", level,
                         f"{name}: {len(items)} distinct {level} segment labels of "
                         f"{len(segs)} segments of {len(lab)} {whose}",
                         n_trajectories=len(lab), units=lab.astype(object), seeds=seeds,
                         axes=axes, scenes=scenes)
    items, counts = np.unique(lab, return_counts=True)
    return Reference(items.astype(object), counts / counts.sum(), "corpus", level,
                     f"{name}: {len(items)} distinct {level} labels of {len(lab)} {whose}",
                     n_trajectories=len(lab), units=lab.astype(object), seeds=seeds,
                     axes=axes, scenes=scenes)


@dataclass(frozen=True)
class CoverageResult:
    """Coverage of one agent (see the module docstring for the estimands and intervals).

    Attributes:
        n: episodes scored.
        coverage, coverage_low, coverage_high: share of reference items exhibited.
        weighted_coverage, weighted_low, weighted_high: reference weight exhibited.
        n_distinct: distinct SDL labels of the agent.
        n_reference: items of the reference (K).
        covered: the reference items exhibited.
        missed: the reference items not exhibited, heaviest first.
        draws: (B, 2) bootstrap draws of (coverage, weighted coverage), for pooling.
    """

    n: int
    coverage: float
    coverage_low: float
    coverage_high: float
    weighted_coverage: float
    weighted_low: float
    weighted_high: float
    n_distinct: int
    n_reference: int
    covered: tuple[str, ...]
    missed: tuple[str, ...]
    draws: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 2)))

    def row(self) -> dict:
        """The scalar fields as a dict (a row of the coverage table)."""
        return {k: getattr(self, k) for k in (
            "n", "coverage", "coverage_low", "coverage_high", "weighted_coverage",
            "weighted_low", "weighted_high", "n_distinct", "n_reference")}


def _items_of(labels: np.ndarray, reference: Reference) -> list[set[str]] | np.ndarray:
    if reference.kind == "corpus":
        return labels
    if reference.kind == "segments":
        return [set(items) for items in unit_items(labels, reference.axes)]
    out = []
    for text in labels:
        items: set[str] = set()
        for side in sdl.parse_sdl(text):
            items.update(side)
        out.append(items)
    return out


def coverage(labels: pd.Series | np.ndarray, reference: Reference, *,
             rng: np.random.Generator | None = None,
             config: BootstrapConfig | None = None,
             clusters: np.ndarray | pd.Series | None = None) -> CoverageResult:
    """Coverage of ``reference`` by an agent's ego labels, with intervals.

    Args:
        labels: (n,) the agent's SDL labels, one per episode (NA labels are dropped), all
            from the env(s) the reference stands for.
        reference: a :class:`Reference` at the labels' level.
        config: bootstrap resamples and level (and the seed of the default stream).
        rng: the random stream the draws come from, named by the caller
            (``config.rng("coverage", env, policy, reference)``);
            default ``config.rng("coverage", reference.description)``.
        clusters: (n,) the independent unit of each label, e.g. the episode each window
            was cut from (:func:`tap_bench.bench.scores.windows.window_episode`). Given, the draws
            resample whole units (:func:`tap_bench.stats.bootstrap.cluster_weights`) and a
            unit shows the items of all its labels (incidence over units; module
            docstring). None: every label its own unit.

    Returns:
        :class:`CoverageResult`.
    """
    config = config or BootstrapConfig()
    rng = config.rng("coverage", reference.description) if rng is None else rng
    text = pd.Series(labels, dtype="string")
    keep = text.notna().to_numpy()
    lab = text[keep].to_numpy(str)
    if clusters is not None:
        clusters = np.asarray(clusters, dtype=object)
        if len(clusters) != len(keep):
            raise LabelTableError(f"coverage: {len(clusters)} clusters for {len(keep)} "
                                  "labels; give the unit (episode) of every label.")
        clusters = clusters[keep].astype(str)
    n = len(lab)
    K = len(reference)
    if n == 0:
        nan = float("nan")
        return CoverageResult(0, 0.0, nan, nan, 0.0, nan, nan, 0, K, (),
                              tuple(reference.items), np.zeros((0, 2)))
    names, counts = np.unique(lab, return_counts=True)
    items, freq = _shown_items(names, counts, reference)
    pos = {item: j for j, item in enumerate(reference.items)}
    ref_index = np.array([pos.get(i, -1) for i in items])
    in_ref = ref_index >= 0
    w_item = np.where(in_ref, reference.weights[np.maximum(ref_index, 0)], 0.0)
    cov = float(in_ref.sum()) / K
    wcov = float(w_item.sum())
    covered = reference.items[np.sort(ref_index[in_ref])]
    missed_mask = np.ones(K, bool)
    missed_mask[ref_index[in_ref]] = False
    missed_idx = np.flatnonzero(missed_mask)
    missed = reference.items[missed_idx[np.argsort(-reference.weights[missed_idx],
                                                   kind="stable")]]

    units = None
    if clusters is not None:  # incidence over units: which items each unit shows
        units, first = _unit_incidence(lab, clusters, items, reference)
        freq = units.sum(axis=0)
        n = len(units)  # the sampling units from here on
    # augmented population: the detected items and the f0 undetected ones Chao1 (Chao2)
    # predicts; up to as many of them as the reference has unseen items count as its items
    p_adj, p_undetected = estimated_population(freq.astype(float), n)
    f0 = len(p_undetected)
    n_ref_undetected = min(f0, len(missed_idx))
    w_missed = float(reference.weights[missed_idx].mean()) if len(missed_idx) else 0.0
    in_ref_pop, prob, draws = _draw_population(
        rng, config.n_resamples, n, freq, in_ref, p_adj, p_undetected, n_ref_undetected,
        reference.kind, None if units is None else (units, clusters, first))
    w_pop = np.where(in_ref_pop, np.r_[w_item, np.full(len(prob) - len(w_item), w_missed)],
                     0.0)
    seen = draws > 0
    boot = np.column_stack([(seen & in_ref_pop).sum(axis=1) / K, (seen * w_pop).sum(axis=1)])
    shown_p = 1 - (1 - np.clip(prob, 0.0, 1.0)) ** n  # each item's chance to be shown
    centre = np.array([float((shown_p * in_ref_pop).sum()) / K, float((shown_p * w_pop).sum())])
    # standard errors that studentize the draws: the variance of the (weighted) count of
    # reference items shown under each sample's own population, its undetected items
    # counted up to the reference items that sample has not shown
    unseen = K - (seen & in_ref_pop).sum(axis=1)
    # (floored at one episode's worth, estimate / n, as the Hill numbers' are)
    se = np.sqrt([distinct_variance(freq, n, weights=w, undetected_weight=u,
                                    max_undetected=np.array([len(missed_idx)]))
                  for w, u in ((in_ref / K, 1.0 / K), (w_item, w_missed))])
    se = np.maximum(se, np.array([cov, wcov]) / n)
    draws_se = np.sqrt(np.column_stack([
        distinct_variance(draws, n, weights=w, undetected_weight=u, max_undetected=unseen)
        for w, u in ((in_ref_pop / K, 1.0 / K), (w_pop, w_missed))]))
    draws_se = np.maximum(draws_se, boot / n)
    (c_lo, c_hi), (w_lo, w_hi) = _intervals(np.array([cov, wcov]), se, boot, draws_se,
                                            centre, config.level)
    if np.std(boot[:, 0]) == 0:  # nothing undetected to draw: bound what n episodes can add
        _, u = wilson_interval(0, n, config.level)
        c_lo, c_hi = max(0.0, cov - n * u / K), min(1.0, cov + n * u / K)
        step = n * u * float(reference.weights.max())
        w_lo, w_hi = max(0.0, wcov - step), min(1.0, wcov + step)
    # a studentized interval can miss its own estimate when the draws pile up at 1
    c_lo, c_hi = min(c_lo, cov), max(c_hi, cov)
    w_lo, w_hi = min(w_lo, wcov), max(w_hi, wcov)
    return CoverageResult(
        n=len(lab), coverage=cov, coverage_low=c_lo, coverage_high=c_hi,
        weighted_coverage=wcov, weighted_low=w_lo, weighted_high=w_hi,
        n_distinct=len(names), n_reference=K,
        covered=tuple(covered), missed=tuple(missed), draws=boot)


def _shown_items(names: np.ndarray, counts: np.ndarray, reference: Reference
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The items an agent shows, and how many of its episodes show each: its distinct
    labels for a corpus reference, the single labels they contain for a vocabulary one.

    Args:
        names, counts: (m,) the agent's distinct labels and their episode counts.
        reference: the reference whose items are counted.
    """
    if reference.kind == "corpus":
        return names, counts
    tally: dict[str, int] = {}
    for item_set, c in zip(_items_of(names, reference), counts, strict=True):
        for item in item_set:
            tally[item] = tally.get(item, 0) + int(c)
    items = np.array(sorted(tally), dtype=object)
    return items, np.array([tally[i] for i in items])


def _draw_population(rng: np.random.Generator, B: int, n: int, freq: np.ndarray,
                     in_ref: np.ndarray, p_adj: np.ndarray, p_undetected: np.ndarray,
                     n_ref_undetected: int, kind: str,
                     units: tuple[np.ndarray, np.ndarray, np.ndarray] | None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``B`` samples of ``n`` units from the augmented population (the detected items and
    the undetected ones Chao1/Chao2 predicts).

    Args:
        rng: the random stream.
        B: resamples; n: the sampling units (episodes, or clusters when ``units``).
        freq: (m,) how many units show each detected item.
        in_ref: (m,) whether each detected item is a reference item.
        p_adj, p_undetected: the detected items' adjusted and the undetected items'
            estimated probabilities (:func:`estimated_population`).
        n_ref_undetected: how many undetected items count as reference items.
        kind: the reference's kind (``corpus``: one label per episode, multinomial draws;
            else vocabulary items shown independently, binomial draws).
        units: (incidence (G, m), the unit of each label (n_labels,), the index of each
            unit's first label (G,)) when whole units are drawn with their items (a cluster
            bootstrap, :func:`tap_bench.stats.bootstrap.cluster_weights`: the stream's first
            draws); None: labels are units.

    Returns:
        (in_ref_pop, prob, draws): whether each population item is a reference item, its
        probability, and the (B, items) counts of units showing it.
    """
    if units is not None:  # whole units drawn with their items, undetected ones per unit
        incidence, clusters, first = units
        whole = cluster_weights(rng, clusters, B)[:, first]  # (B, G) draws of each unit
        prob = np.r_[freq / n, p_undetected[:n_ref_undetected]]
        draws = np.hstack([whole @ incidence.astype(np.int64),
                           rng.binomial(n, np.clip(prob[len(freq):], 0.0, 1.0),
                                        size=(B, n_ref_undetected))])
        return np.r_[in_ref, np.ones(n_ref_undetected, bool)], prob, draws
    if kind == "corpus":  # one label per episode: multinomial draws
        prob = np.r_[p_adj, p_undetected]
        prob = prob / prob.sum()
        draws = rng.multinomial(n, prob, size=B)  # (B, m) episodes per label
        return np.r_[in_ref, np.arange(len(p_undetected)) < n_ref_undetected], prob, draws
    # vocabulary items: the universe is the reference; items shown independently
    prob = np.r_[p_adj, p_undetected[:n_ref_undetected]]
    draws = rng.binomial(n, np.clip(prob, 0.0, 1.0), size=(B, len(prob)))
    return np.r_[in_ref, np.ones(n_ref_undetected, bool)], prob, draws


def _unit_incidence(lab: np.ndarray, clusters: np.ndarray, items: np.ndarray,
                    reference: Reference) -> tuple[np.ndarray, np.ndarray]:
    """(G, k) bool: which of the k ``items`` each of G units shows (the items of all its
    labels), and the index of each unit's first label (G,)."""
    names, which = np.unique(lab, return_inverse=True)
    pos = {item: j for j, item in enumerate(items)}
    per_label = _items_of(names, reference)
    if reference.kind == "corpus":
        per_label = [(label,) for label in per_label]
    _, first, unit_of = np.unique(clusters, return_index=True, return_inverse=True)
    out = np.zeros((len(first), len(items)), bool)
    for j, item_set in enumerate(per_label):
        cols = [pos[i] for i in item_set]
        if cols:
            out[np.ix_(np.unique(unit_of.ravel()[which.ravel() == j]), cols)] = True
    return out, first


def _intervals(estimate: np.ndarray, se: np.ndarray, boot: np.ndarray, draws_se: np.ndarray,
               centre: np.ndarray, level: float) -> list[tuple[float, float]]:
    """The studentized bootstrap interval of each share (:func:`tap_bench.stats.intervals.
    studentized_interval`), clipped to [0, 1]; where a standard error is 0 (nothing seen
    once: no undetected item), the draws' percentile interval widened to hold the
    estimate."""
    low, high = studentized_interval(estimate, se, boot, draws_se, centre, level)
    alpha = 1 - level
    pct_lo, pct_hi = np.quantile(boot, [alpha / 2, 1 - alpha / 2], axis=0)
    out = []
    for e, lo, hi, plo, phi in zip(estimate, low, high, pct_lo, pct_hi, strict=True):
        if not np.isfinite(lo):
            lo, hi = min(plo, e), max(phi, e)
        out.append((max(0.0, float(lo)), min(1.0, float(hi))))
    return out


def pooled_coverage(results: list[CoverageResult], corpus_sizes: list[int], level: float
                    ) -> CoverageResult:
    """The coverage of the union of per-env references keyed by (env, label).

    Args:
        results: per-env coverages, each of that env's agent episodes against that env's
            reference.
        corpus_sizes: each env's reference corpus size (trajectories), the weights of the
            weighted coverage.
        level: interval level.

    Returns:
        coverage = sum covered / sum K (the K-weighted mean of the per-env coverages),
        weighted coverage = the corpus-size-weighted mean of the per-env ones; intervals
        ``estimate +- z sd`` with the sd of that weighted sum of independent envs.
    """
    results = [r for r in results]
    K = np.array([r.n_reference for r in results], float)
    N = np.array(corpus_sizes, float)
    if not len(results) or K.sum() == 0:
        nan = float("nan")
        return CoverageResult(0, 0.0, nan, nan, 0.0, nan, nan, 0, 0, (), ())
    ck, wk = K / K.sum(), N / N.sum()
    cov = float(sum(c * r.coverage for c, r in zip(ck, results, strict=True)))
    wcov = float(sum(w * r.weighted_coverage for w, r in zip(wk, results, strict=True)))
    # envs are independent: the pooled sd is the root of the weighted sum of squared sds;
    # an env whose draws could not move contributes its fallback half-width / z
    z = z_value(level)

    def sd_of(r: CoverageResult, j: int) -> float:
        lo, hi = ((r.coverage_low, r.coverage_high) if j == 0 else
                  (r.weighted_low, r.weighted_high))
        spread = float(np.std(r.draws[:, j])) if len(r.draws) else 0.0
        return max(spread, (hi - lo) / (2 * z)) if np.isfinite(hi - lo) else spread

    sd_c = float(np.sqrt(sum((c * sd_of(r, 0)) ** 2 for c, r in zip(ck, results,
                                                                     strict=True))))
    sd_w = float(np.sqrt(sum((w * sd_of(r, 1)) ** 2 for w, r in zip(wk, results,
                                                                     strict=True))))
    c_lo, c_hi = max(0.0, cov - z * sd_c), min(1.0, cov + z * sd_c)
    w_lo, w_hi = max(0.0, wcov - z * sd_w), min(1.0, wcov + z * sd_w)
    draws = np.zeros((0, 2))
    return CoverageResult(
        n=sum(r.n for r in results), coverage=cov, coverage_low=c_lo, coverage_high=c_hi,
        weighted_coverage=wcov, weighted_low=w_lo, weighted_high=w_hi,
        n_distinct=sum(r.n_distinct for r in results), n_reference=int(K.sum()),
        covered=tuple(c for r in results for c in r.covered),
        missed=tuple(c for r in results for c in r.missed), draws=draws)
