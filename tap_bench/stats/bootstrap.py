"""How intervals are computed: their level, the bootstrap's resamples, and random streams
named by what they draw.

:class:`BootstrapConfig` is the one place that says how every interval of
:mod:`tap_bench.bench` is computed: its two-sided ``level``, the number of resamples of the
bootstrap that the diversity and coverage intervals use (:mod:`tap_bench.bench.scores.diversity`),
and the ``seed`` of every random draw.

**Random streams are named, not numbered.** ``config.rng("coverage", env, policy,
reference)`` is a generator seeded by a :class:`numpy.random.SeedSequence` built from the
config's seed and a SHA-256 digest of the name. The same name gives the same numbers
whichever command asks and whatever else was drawn before it (``tap-bench coverage`` and
``bench run`` give the same interval for the same episodes), and two names never share
numbers by accident. The gate's permutations draw from the same kind of stream
(:func:`named_rng`) under the gate's own seed.

**The unit of resampling is the independent unit, not the row.** The vehicles of one WOMD
scene share its place, its traffic and its signals; the windows cut from one episode share
its policy's state. A bootstrap that draws such rows one by one sees far less spread than
the data has, and its intervals are far too narrow (docs/benchmark.md, "Intervals over
scenes", measures by how much). :func:`scene_clusters` names each row's independent unit (the scene,
``scenario_id``; a rollout's episode, whose ``scenario_id`` names env, policy and seed; a
window's episode), :func:`cluster_weights` and :func:`cluster_indices` draw whole units,
each side of a comparison on its own (stratified by side), and :func:`cluster_factor`
corrects the bootstrap's spread for the number of units drawn.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from typing import TYPE_CHECKING

from tap_bench.errors import ParameterError

if TYPE_CHECKING:
    import numpy as np

__all__ = ["FEW_CLUSTERS", "MAX_RESAMPLES", "BootstrapConfig", "add_bootstrap_arguments",
           "bootstrap_from_args", "cluster_factor", "cluster_indices", "cluster_weights",
           "few_clusters_note", "named_rng", "scene_clusters", "stream_key"]

MAX_RESAMPLES = 100_000
"""The most bootstrap resamples an interval may ask for: 50 times the default 2000, past
which a percentile interval's Monte Carlo error no longer moves at the printed digits,
while memory grows with it (1e9 resamples reached 15.8 GB in 100 s)."""


def stream_key(*name: object) -> list[int]:
    """Eight 32-bit words of the SHA-256 digest of ``name`` (its parts as JSON text).

    Args:
        name: the stream's name, e.g. ``("coverage", "highway", "random", "idm rollouts")``;
            strings, integers and floats (anything JSON can write).
    """
    text = json.dumps([str(p) if not isinstance(p, int | float | str) else p for p in name],
                      ensure_ascii=True)
    digest = hashlib.sha256(text.encode("utf-8")).digest()
    return [int.from_bytes(digest[i:i + 4], "little") for i in range(0, 32, 4)]


def named_rng(seed: int, *name: object) -> np.random.Generator:
    """A generator for the stream ``name`` under ``seed`` (see the module docstring)."""
    import numpy as np

    return np.random.default_rng(np.random.SeedSequence([int(seed), *stream_key(*name)]))


@dataclass(frozen=True)
class BootstrapConfig:
    """How intervals are computed.

    Attributes:
        n_resamples: bootstrap resamples B of the diversity and coverage intervals (>= 100).
        level: two-sided confidence level of every interval, in [0.5, 1), e.g. 0.95.
        seed: root seed of every random stream; the same seed gives the same intervals.
    """

    n_resamples: int = 2000
    level: float = 0.95
    seed: int = 0

    def __post_init__(self) -> None:
        if (isinstance(self.n_resamples, bool) or not isinstance(self.n_resamples, int)
                or self.n_resamples < 100):
            raise ParameterError("n_resamples", self.n_resamples, "an integer >= 100")
        if self.n_resamples > MAX_RESAMPLES:
            raise ParameterError(
                "n_resamples", self.n_resamples, f"at most {MAX_RESAMPLES:,}", message=(
                    f"n_resamples {self.n_resamples:,} is more than the limit of "
                    f"{MAX_RESAMPLES:,} (tap_bench.stats.bootstrap.MAX_RESAMPLES): the "
                    "intervals would not change at the printed digits, and memory grows "
                    "with the resamples."))
        if (isinstance(self.level, bool) or not isinstance(self.level, float | int)
                or not 0.5 <= float(self.level) < 1):
            raise ParameterError("level", self.level, "in [0.5, 1), e.g. 0.95")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ParameterError("seed", self.seed, "a non-negative integer")

    def rng(self, *name: object) -> np.random.Generator:
        """The generator of the stream ``name`` (``"coverage", env, policy, reference``)."""
        if not name:
            raise ParameterError("name", name, "a non-empty stream name, e.g. "
                                 "('coverage', env, policy, reference)")
        return named_rng(self.seed, *name)

    def describe(self, what: str) -> str:
        """One line for reports: the bootstrap's resamples, what it draws, and the seed."""
        return (f"{self.level:.0%} intervals from {self.n_resamples} bootstrap draws of "
                f"{what}, seed {self.seed} (streams named by env, policy and reference)")


# -- resampling by cluster ----------------------------------------------------------------
FEW_CLUSTERS = 10
"""Fewer independent units (scenes, episodes) than this on one side of a comparison and its
bootstrap interval is flagged: the bootstrap sees the spread between units only through
the units drawn, and with a handful of them an interval covers less than its level even
with :func:`cluster_factor` (docs/benchmark.md, "Intervals over scenes")."""


def scene_clusters(table, column: str | None = "scenario_id") -> np.ndarray:
    """(n,) the independent unit each row of ``table`` belongs to (the cluster a bootstrap
    draws whole).

    With ``column="scenario_id"`` (the default): the row's scene (WOMD), its episode
    (rollouts: ``env/policy/s<seed>``), or, for a window cut from an episode
    (``<scenario_id>#<k>``, :func:`tap_bench.bench.scores.windows.windows`), that episode. Another
    column names the units as they are. ``None``, or a table without the column: every row
    its own unit (the ordinary bootstrap).

    Args:
        table: a DataFrame (label table rows).
        column: the column naming each row's unit.
    """
    import numpy as np

    if column is None or column not in table.columns:
        return np.arange(len(table)).astype(str).astype(object)
    values = table[column].astype("string").fillna("<no id>")
    if column == "scenario_id":
        values = values.str.replace(r"#\d+$", "", regex=True)
    return np.asarray(values.astype(object), dtype=object)


def cluster_factor(n_clusters: int) -> float:
    """``sqrt(G / (G - 1))`` for G clusters: the bootstrap's spread of a mean over G drawn
    units is ``sqrt((G - 1) / G)`` of the sampling spread (it draws from the G units seen,
    whose spread is the plug-in variance); draws are scaled about the estimate by this
    factor so their variance is the unbiased one (the small-sample correction of the
    cluster-robust variance, CR1). NaN for fewer than 2 clusters (no spread to see)."""
    g = int(n_clusters)
    return (g / (g - 1)) ** 0.5 if g >= 2 else float("nan")


def few_clusters_note(what: str, sizes: dict[str, int]) -> str | None:
    """A warning's text when a side has fewer than :data:`FEW_CLUSTERS` units, else None.

    Args:
        what: the statistic, e.g. ``"gap of idm from womd"``.
        sizes: units per side, e.g. ``{"policy episodes": 30, "reference scenes": 8}``.
    """
    small = {k: v for k, v in sizes.items() if v < FEW_CLUSTERS}
    if not small:
        return None
    return (f"{what}: the interval rests on " + ", ".join(f"{v} {k}" for k, v in
                                                          sizes.items())
            + f"; with fewer than {FEW_CLUSTERS} independent units on a side a bootstrap "
            "interval covers less than its level (its draws can only mix the units seen). "
            "Read it as rough, and add scenes or seeds.")
def _cluster_codes(clusters) -> tuple[np.ndarray, int]:
    """(n,) cluster number of each unit and the number of clusters."""
    import numpy as np

    _, inverse = np.unique(np.asarray(clusters).astype(str), return_inverse=True)
    return inverse.ravel(), int(inverse.max()) + 1 if len(inverse) else 0


def cluster_weights(rng: np.random.Generator, clusters, draws: int) -> np.ndarray:
    """(draws, n) how often each of n units is drawn when whole clusters are resampled.

    The cluster bootstrap: units of one cluster (the windows cut from one episode, which
    are not independent) are drawn together, as many clusters as there are, with
    replacement. With every unit its own cluster this is the ordinary bootstrap (the
    multinomial draw of n units).

    Args:
        rng: the random stream.
        clusters: (n,) the cluster of each unit (any values; equal values, one cluster).
        draws: the number of resamples B.
    """
    import numpy as np

    inverse, c = _cluster_codes(clusters)
    if not c:
        return np.zeros((draws, 0), int)
    return rng.multinomial(c, np.full(c, 1 / c), size=draws)[:, inverse]


def cluster_indices(rng: np.random.Generator, clusters, draws: int, m: int) -> np.ndarray:
    """(draws, m) indices of m units per resample, drawn by whole clusters with
    replacement (:func:`cluster_weights`' draw for statistics that need indices): clusters
    are drawn until m units are reached, the last one cut at m.

    Args:
        rng: the random stream.
        clusters: (n,) the cluster of each unit.
        draws: the number of resamples B.
        m: units per resample (> 0).
    """
    import numpy as np

    inverse, c = _cluster_codes(clusters)
    if c == 0 or m <= 0:
        raise ParameterError("clusters", len(inverse), "at least one unit and m > 0")
    order = np.argsort(inverse, kind="stable")  # the members of cluster 0, then 1, ...
    sizes = np.bincount(inverse, minlength=c)
    starts = np.cumsum(sizes) - sizes
    if (sizes == sizes[0]).all():  # equal clusters (episodes of one length): at once
        pick = rng.integers(0, c, (draws, -(-m // int(sizes[0]))))
        return order.reshape(c, -1)[pick].reshape(draws, -1)[:, :m]
    out = np.empty((draws, m), int)
    per = -(-m // int(sizes.min()))
    for d in range(draws):
        pick = rng.integers(0, c, per)
        pick = pick[:int(np.searchsorted(np.cumsum(sizes[pick]), m)) + 1]  # enough for m
        lens = sizes[pick]
        within = np.arange(lens.sum()) - np.repeat(np.cumsum(lens) - lens, lens)
        out[d] = order[np.repeat(starts[pick], lens) + within][:m]
    return out


# -- command line -------------------------------------------------------------------------
def add_bootstrap_arguments(parser, *, what: str = "bootstrap resamples") -> None:
    """Add ``--resamples``, ``--ci`` and ``--seed`` (the :class:`BootstrapConfig` of a
    sub-command) to an argparse parser."""
    parser.add_argument("--resamples", type=int, default=2000, help=f"{what} (2000)")
    parser.add_argument("--ci", type=float, default=0.95, help="interval level (0.95)")
    parser.add_argument("--seed", type=int, default=0, help="bootstrap seed (0)")


def bootstrap_from_args(args) -> BootstrapConfig:
    """The :class:`BootstrapConfig` that ``--resamples``, ``--ci`` and ``--seed`` ask for."""
    try:
        return BootstrapConfig(n_resamples=args.resamples, level=args.ci, seed=args.seed)
    except ParameterError as err:  # named as the user typed it
        option = {"n_resamples": "--resamples", "level": "--ci", "seed": "--seed"}.get(
            err.parameter, err.parameter)
        raise ParameterError(option, err.value, err.allowed, message=str(err).replace(
            err.parameter, option, 1)) from None
