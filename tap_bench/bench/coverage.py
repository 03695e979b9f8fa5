"""Behaviour coverage: how much of a reference label set an agent exhibits (issue 6 part 2).

A **reference** (:class:`Reference`) is a set of items with weights:

- the SDL vocabulary of a level (``vocabulary_reference``): the single labels
  (``Left Merge``, ``Maintain Fast Speed`` ...), equal weights; an episode exhibits the
  single labels its SDL label is made of. This is the reference of the quick training-time
  signal :func:`tap_bench.sim.coverage.label_coverage`, whose value is the point estimate
  here;
- the labels of a reference corpus (``corpus_reference``), e.g. WOMD's vehicles or IDM's
  egos: whole SDL labels, weighted by their frequency in the corpus; an episode exhibits
  its own SDL label.

For an agent's n episodes, :func:`coverage` reports

- ``coverage``: share of the reference's items exhibited at least once;
- ``weighted_coverage``: the reference weight of the items exhibited (the share of the
  reference corpus's trajectories whose label the agent shows);
- ``entropy_bits``: the entropy of the agent's SDL label distribution, Chao-Shen
  coverage-adjusted (Chao & Shen 2003), and ``entropy_observed_bits``, the plug-in value.

**What the intervals are for.** Coverage counts distinct labels, so it grows with n: the
estimand is the expected coverage of an evaluation with the same number of episodes, of
which the observed value is unbiased. A plain bootstrap underestimates its spread (labels
the agent produces but the sample missed never appear in a resample). The intervals
therefore follow Chao et al. (2014, Ecol. Monogr. 84:45, the iNEXT method): the empirical
label distribution is augmented with the undetected labels the Chao1 estimator predicts,
carrying the Good-Turing undetected probability (as many of them as the reference has
unseen items count as reference items, which widens the interval: the conservative
choice); episodes are drawn
from it (multinomially for whole labels, independently per item for vocabulary items) and
the interval is ``estimate +- z * sd`` over those draws, clipped to [0, 1]. The tests measure
the resulting coverage rate on synthetic label distributions (docs/benchmark.md has the
figures).
"""

from __future__ import annotations

from dataclasses import dataclass
from statistics import NormalDist

import numpy as np
import pandas as pd

from tap_bench import sdl
from tap_bench.bench.bootstrap import BootstrapConfig
from tap_bench.errors import LabelTableError, did_you_mean
from tap_bench.sim.coverage import vocabulary_tokens

__all__ = [
    "CoverageResult",
    "Reference",
    "corpus_reference",
    "coverage",
    "entropy_bits",
    "vocabulary_reference",
]


@dataclass(frozen=True)
class Reference:
    """A reference label set.

    Attributes:
        items: (K,) the reference items (single labels or whole SDL labels), sorted.
        weights: (K,) their weights, summing to 1 (corpus frequencies, or 1/K).
        kind: ``"vocabulary"`` (items are single labels) or ``"corpus"`` (whole labels).
        level: the SDL level.
        description: one line for reports (what, how many trajectories).
        n_trajectories: trajectories of the corpus (0 for a vocabulary).
    """

    items: np.ndarray
    weights: np.ndarray
    kind: str
    level: str
    description: str
    n_trajectories: int = 0

    def __len__(self) -> int:
        return len(self.items)

    def contains(self, labels: np.ndarray) -> np.ndarray:
        """(n,) bool: which whole SDL labels the reference shows (corpus references)."""
        return np.isin(np.asarray(labels, dtype=object), self.items)


def vocabulary_reference(level: str = "action") -> Reference:
    """The single labels of ``level``, lateral and longitudinal, equally weighted."""
    sdl.check_level(level)
    items = np.array(sorted(vocabulary_tokens(level)), dtype=object)
    return Reference(items, np.full(len(items), 1.0 / len(items)), "vocabulary", level,
                     f"the {len(items)} single labels of the {level} level")


def corpus_reference(labels: pd.DataFrame, level: str, *, tracks: str = "vehicles",
                     name: str = "reference corpus") -> Reference:
    """The SDL labels of a reference corpus, weighted by their frequency.

    Args:
        labels: a label table (SPEC section 1).
        level: the SDL level to take.
        tracks: ``"vehicles"`` (rows whose ``object_type`` is vehicle, or all rows when the
            column is absent), ``"ego"`` (rows with ``is_ego``), or ``"all"``.
        name: what the corpus is, for reports (``"WOMD"``, ``"idm rollouts"``).
    """
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
    lab = table["sdl"].dropna().to_numpy(str)
    if not len(lab):
        raise LabelTableError(f"{name}: no {tracks} labels at level {level!r}; label it at "
                              f"that level (--level {level} or all).")
    items, counts = np.unique(lab, return_counts=True)
    return Reference(items.astype(object), counts / counts.sum(), "corpus", level,
                     f"{name}: {len(items)} distinct {level} labels of {len(lab)} "
                     f"{tracks} trajectories", n_trajectories=len(lab))


@dataclass(frozen=True)
class CoverageResult:
    """Coverage of one agent (see the module docstring for the estimands and intervals).

    Attributes:
        n: episodes scored.
        coverage, coverage_low, coverage_high: share of reference items exhibited.
        weighted_coverage, weighted_low, weighted_high: reference weight exhibited.
        entropy_bits, entropy_low, entropy_high: Chao-Shen entropy of the agent's labels.
        entropy_observed_bits: plug-in entropy of the observed labels.
        n_distinct: distinct SDL labels of the agent.
        covered: the reference items exhibited.
        missed: the reference items not exhibited, heaviest first.
    """

    n: int
    coverage: float
    coverage_low: float
    coverage_high: float
    weighted_coverage: float
    weighted_low: float
    weighted_high: float
    entropy_bits: float
    entropy_low: float
    entropy_high: float
    entropy_observed_bits: float
    n_distinct: int
    covered: tuple[str, ...]
    missed: tuple[str, ...]

    def row(self) -> dict:
        """The scalar fields as a dict (a row of the coverage table)."""
        return {k: getattr(self, k) for k in (
            "n", "coverage", "coverage_low", "coverage_high", "weighted_coverage",
            "weighted_low", "weighted_high", "entropy_bits", "entropy_low", "entropy_high",
            "entropy_observed_bits", "n_distinct")}


def _items_of(labels: np.ndarray, reference: Reference) -> list[set[str]] | np.ndarray:
    if reference.kind == "corpus":
        return labels
    out = []
    for text in labels:
        items: set[str] = set()
        for side in sdl.parse_sdl(text):
            items.update(side)
        out.append(items)
    return out


def entropy_bits(counts: np.ndarray) -> tuple[float, float]:
    """(Chao-Shen, plug-in) entropy in bits of a label count vector.

    Chao-Shen: with n the total, f1 the labels seen once and C = 1 - f1/n (f1 = n is
    taken as n - 1) the estimated sample coverage, p~ = C * count/n and
    H = -sum p~ log2 p~ / (1 - (1 - p~)^n).
    """
    counts = np.asarray(counts, dtype=float)
    n = counts.sum()
    if n == 0:
        return float("nan"), float("nan")
    p = counts[counts > 0] / n
    return float(_chao_shen(counts[None, :])[0]), float(-(p * np.log2(p)).sum())


def _chao_shen(counts: np.ndarray) -> np.ndarray:
    """(B,) Chao-Shen entropy [bits] of each row of a (B, m) count matrix (equal totals)."""
    n = counts.sum(axis=1, keepdims=True)
    if n[0, 0] <= 1:
        return np.zeros(len(counts))
    f1 = (counts == 1).sum(axis=1, keepdims=True)
    c = 1.0 - np.minimum(f1, n - 1) / n
    pa = c * counts / n
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(counts > 0, -pa * np.log2(pa) / (1.0 - (1.0 - pa) ** n), 0.0)
    return terms.sum(axis=1)


def _undetected(freq: np.ndarray, n: int) -> tuple[int, float, np.ndarray]:
    """Chao1 undetected count, their total probability and the adjusted probabilities of
    the detected items, from detection counts ``freq`` over n units (iNEXT's
    EstiBootComm)."""
    f1, f2 = float((freq == 1).sum()), float((freq == 2).sum())
    if f2 > 0:
        f0 = (n - 1) / n * f1 * f1 / (2 * f2)
    else:
        f0 = (n - 1) / n * f1 * (f1 - 1) / 2
    total = freq.sum()
    share = f1 / total * (n * f0 / (n * f0 + f1)) if f1 > 0 else 0.0  # undetected mass
    p = freq / n
    tail = (p * (1 - p) ** n).sum()
    lam = share / tail if tail > 0 else 0.0
    p_adj = p * (1 - lam * (1 - p) ** n)
    return int(np.ceil(f0)), share * total / n, np.clip(p_adj, 0, 1)


def coverage(labels: pd.Series | np.ndarray, reference: Reference, *,
             config: BootstrapConfig | None = None, stream: int = 0) -> CoverageResult:
    """Coverage of ``reference`` by an agent's ego labels, with intervals.

    Args:
        labels: (n,) the agent's SDL labels, one per episode (NA labels are dropped).
        reference: a :class:`Reference` at the labels' level.
        config: bootstrap resamples, level and seed.
        stream: random stream of the config (one per agent, so agents do not share draws).

    Returns:
        :class:`CoverageResult`.
    """
    config = config or BootstrapConfig()
    lab = pd.Series(labels, dtype="string").dropna().to_numpy(str)
    n = len(lab)
    K = len(reference)
    names, counts = np.unique(lab, return_counts=True)
    h, h_obs = entropy_bits(counts)
    if n == 0:
        nan = float("nan")
        return CoverageResult(0, 0.0, nan, nan, 0.0, nan, nan, nan, nan, nan, nan, 0, (),
                              tuple(reference.items))
    # the items the agent shows (whole labels or single labels) and how many episodes show each
    if reference.kind == "corpus":
        items, freq = names, counts
    else:
        per_label = _items_of(names, reference)
        tally: dict[str, int] = {}
        for item_set, c in zip(per_label, counts, strict=True):
            for item in item_set:
                tally[item] = tally.get(item, 0) + int(c)
        items = np.array(sorted(tally), dtype=object)
        freq = np.array([tally[i] for i in items])
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

    # augmented population: the detected items and the f0 undetected ones Chao1 predicts;
    # up to as many of them as the reference has unseen items count as reference items
    f0, p0, p_adj = _undetected(freq.astype(float), n)
    p_each = p0 / f0 if f0 else 0.0  # detection probability of one undetected item
    n_ref_undetected = min(f0, len(missed_idx))
    w_missed = float(reference.weights[missed_idx].mean()) if len(missed_idx) else 0.0
    rng = config.rng(10_000 + stream)
    B = config.n_resamples
    if reference.kind == "corpus":  # one label per episode: multinomial draws
        in_ref_pop = np.r_[in_ref, np.arange(f0) < n_ref_undetected]
        prob = np.r_[p_adj, np.full(f0, p_each)]
        draws = rng.multinomial(n, prob / prob.sum(), size=B)  # (B, m) episodes per label
    else:  # vocabulary items: the universe is the reference; items shown independently
        in_ref_pop = np.r_[in_ref, np.ones(n_ref_undetected, bool)]
        prob = np.r_[p_adj, np.full(n_ref_undetected, min(p_each, 1.0))]
        draws = rng.binomial(n, prob, size=(B, len(prob)))
    w_pop = np.where(in_ref_pop, np.r_[w_item, np.full(len(prob) - len(w_item), w_missed)],
                     0.0)
    seen = draws > 0
    boot_cov = (seen & in_ref_pop).sum(axis=1) / K
    boot_wcov = (seen * w_pop).sum(axis=1)
    z = NormalDist().inv_cdf(0.5 + config.level / 2)

    def interval(estimate: float, boot: np.ndarray) -> tuple[float, float]:
        sd = float(np.std(boot))
        return max(0.0, estimate - z * sd), min(1.0, estimate + z * sd)

    c_lo, c_hi = interval(cov, boot_cov)
    w_lo, w_hi = interval(wcov, boot_wcov)
    if reference.kind == "corpus":
        label_draws = draws  # the same augmented population of whole labels
    else:
        g0, q0, q_adj = _undetected(counts.astype(float), n)
        q = np.r_[q_adj, np.full(g0, q0 / g0 if g0 else 0.0)]
        label_draws = rng.multinomial(n, q / q.sum(), size=B)
    boot_h = _chao_shen(label_draws)
    sd_h = float(np.std(boot_h))
    return CoverageResult(
        n=n, coverage=cov, coverage_low=c_lo, coverage_high=c_hi, weighted_coverage=wcov,
        weighted_low=w_lo, weighted_high=w_hi, entropy_bits=h,
        entropy_low=max(0.0, h - z * sd_h), entropy_high=h + z * sd_h,
        entropy_observed_bits=h_obs, n_distinct=len(names), covered=tuple(covered),
        missed=tuple(missed))
