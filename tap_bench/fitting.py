"""Learning the thresholds Theta from data (SPEC section 3).

Each distribution (D_w of |w|, D_a, D_v without the Stopped partition) is fitted on its own
by minimising J (:mod:`tap_bench.objective`) with four methods:

``descent``
    The paper's method: finite-difference gradient descent, grad_i = (J(theta + eps e_i) -
    J(theta - eps e_i)) / (2 eps), theta <- theta - eta grad, 100 epochs from each of three
    starting guesses, with Table 1's eps and eta. A step that would leave thresholds out of
    order or a partition with fewer than two samples is halved until it does not.
``descent-scaled``
    The same gradient, but a scale-free step: theta moves along -grad/|grad| by a step
    that starts at 5 % of the data's 1-99 % range, grows by 1.2 after an improvement and
    halves after a rejected move. It does not depend on the units or on the size of J,
    which the paper's eta*grad does (see docs/thresholds.md for how little the paper's
    rates move on some data).
``cem``
    The sampling cross-entropy method (de Boer et al., 2005): Gaussian proposals around
    each start, the best 10 % refit the mean and spread (smoothing 0.7), 60 iterations.
``grid``
    Exhaustive search over a lattice of split ranks (every increasing tuple of 72 ranks
    evenly spaced over the sorted data for three thresholds, 300 for two), then finer
    local lattices around the best down to single samples. It is the reference the
    others are measured against.

The thresholds are the lowest J evaluated by any of them (``select="best"``), passing over a
solution with a degenerate band (:func:`fit_report`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from tap_bench._version import __version__
from tap_bench.errors import FitWarning, TapBenchError, did_you_mean
from tap_bench.kinematics import V_STOP, one_second_samples
from tap_bench.objective import SortedSamples
from tap_bench.thresholds import NAMES, UNITS, Provenance, Thresholds

__all__ = ["FAR_ABOVE_GRID", "J_RESOLUTION", "METHODS", "PAPER_HYPERPARAMETERS", "PAPER_STARTS",
           "RESOLUTION", "DistributionFit", "FitReport", "FitRun", "fit_report",
           "fit_thresholds"]

METHODS = ("descent", "descent-scaled", "cem", "grid")
DISTRIBUTIONS = ("w", "a", "v")
PAPER_HYPERPARAMETERS = {"a": (0.05, 0.05), "v": (0.05, 0.2), "w": (0.005, 0.01)}
"""Table 1 of the paper: (eps, eta) per distribution."""
PAPER_STARTS = {
    "a": ((-0.5, 0.5), (-1.0, 1.0), (-2.0, 2.0)),
    "v": ((7.0, 22.0), (10.0, 24.0), (12.0, 26.0)),
    "w": ((0.01, 0.05, 0.1), (0.02, 0.07, 0.15), (0.05, 0.1, 0.2)),
}
"""The paper's three starting guesses per distribution (Appendix C)."""
FAR_ABOVE_GRID = 2.0
"""A chosen fit whose J is more than this many times the grid optimum's, and above it by
more than :data:`J_RESOLUTION` of the data's scale, is reported."""
J_RESOLUTION = 0.01
"""J's scale is the squared mean absolute difference of all samples (the size of the mu_p);
differences of J below this share of it are too small to report."""
RESOLUTION = 0.01
"""A band narrower than this share of the data's 1-99 % range is degenerate: thresholds
that close split nothing a reader of the labels can tell apart."""


@dataclass(frozen=True)
class FitRun:
    """One optimisation run on one distribution.

    Attributes:
        dist: ``"w"``, ``"a"`` or ``"v"``.
        method: one of :data:`METHODS`.
        start: the starting guess actually used (None for the grid): the paper's guess, or
            the equal-count quantiles where that guess was infeasible on the data.
        theta: the thresholds reached, in increasing order [unit of ``dist``].
        objective: J at ``theta`` [unit^2].
        history: J after each epoch or iteration.
    """

    dist: str
    method: str
    start: tuple[float, ...] | None
    theta: tuple[float, ...]
    objective: float
    history: tuple[float, ...] = field(default=(), repr=False)


@dataclass(frozen=True)
class DistributionFit:
    """All runs on one distribution, the grid optimum and the chosen run."""

    dist: str
    n_samples: int
    runs: tuple[FitRun, ...]
    grid: FitRun | None
    chosen: FitRun
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class FitReport:
    """The fitted thresholds and how every method and start fared."""

    thresholds: Thresholds
    fits: dict[str, DistributionFit]

    @property
    def warnings(self) -> tuple[str, ...]:
        """What to look at in the fit, per distribution (also raised as FitWarning)."""
        return tuple(w for fit in self.fits.values() for w in fit.warnings)

    def table(self) -> pd.DataFrame:
        """One row per distribution, method and start: thresholds, J and the distance to the
        grid optimum (difference in J and largest threshold difference, in the unit)."""
        rows = []
        for dist, fit in self.fits.items():
            for run in (*fit.runs, *([fit.grid] if fit.grid else [])):
                row: dict[str, Any] = {
                    "dist": dist, "unit": UNITS[dist], "method": run.method,
                    "start": "" if run.start is None else
                    "(" + ", ".join(f"{v:g}" for v in run.start) + ")",
                    "theta": "(" + ", ".join(f"{v:.4f}" for v in run.theta) + ")",
                    "J": run.objective, "chosen": run is fit.chosen,
                }
                if fit.grid is not None:
                    row["dJ_to_grid"] = run.objective - fit.grid.objective
                    row["dtheta_to_grid"] = float(np.max(np.abs(
                        np.subtract(run.theta, fit.grid.theta))))
                rows.append(row)
        return pd.DataFrame(rows)


# -- the optimisers ---------------------------------------------------------------------------
def _probe(s: SortedSamples, thetas: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """J and its central finite-difference gradient at each row of (S, d) ``thetas``.

    One batched evaluation of the centres and their 2d probes. Where one side of a probe is
    infeasible the one-sided difference is used; where both are, 0.
    """
    n_starts, d = thetas.shape
    probes = np.concatenate([thetas[:, None, :], thetas[:, None, :] + eps * np.eye(d)[None],
                             thetas[:, None, :] - eps * np.eye(d)[None]], axis=1)
    j = s.objective(probes.reshape(-1, d)).reshape(n_starts, 2 * d + 1)
    j0, jp, jm = j[:, :1], j[:, 1:d + 1], j[:, d + 1:]
    fp, fm = np.isfinite(jp), np.isfinite(jm)
    with np.errstate(invalid="ignore"):
        grad = np.where(fp & fm, (jp - jm) / (2 * eps),
                        np.where(fp, (jp - j0) / eps, np.where(fm, (j0 - jm) / eps, 0.0)))
    return j[:, 0], np.nan_to_num(grad, nan=0.0, posinf=0.0, neginf=0.0)


def _data_scale(s: SortedSamples) -> float:
    lo, hi = np.quantile(s.x, [0.01, 0.99])
    return float(hi - lo) or float(s.x[-1] - s.x[0]) or 1.0


def descent(s: SortedSamples, starts: np.ndarray, eps: float, eta: float, epochs: int = 100,
            step: str = "paper") -> list[tuple[np.ndarray, float, list[float]]]:
    """Finite-difference descent from each start; returns (theta, J, history) per start.

    ``step="paper"``: theta <- theta - eta * grad (halved while infeasible).
    ``step="scaled"``: a move of ``size`` along -grad/|grad|, kept only if J decreases;
    ``size`` starts at 5 % of the data's 1-99 % range, x1.2 on success, x0.5 on failure.
    Each epoch is one batched evaluation of J for all starts. The theta returned is the best
    one evaluated (the start included): the paper's step can overshoot a minimum and end
    above a point it passed. The history is J where each epoch ended.
    """
    theta = np.array(starts, dtype=np.float64)
    j, g = _probe(s, theta, eps)
    best, best_j = theta.copy(), j.copy()
    size = np.full(len(theta), 0.05 * _data_scale(s))
    hist: list[list[float]] = [[] for _ in theta]
    for _ in range(epochs):
        if step == "paper":
            move = -eta * g
            cand = theta + move
            for _ in range(30):  # halve a move that leaves the feasible set
                bad = ~s.feasible(cand)
                if not bad.any():
                    break
                move[bad] *= 0.5
                cand[bad] = theta[bad] + move[bad]
            ok = s.feasible(cand)
            theta[ok] = cand[ok]
            j, g = _probe(s, theta, eps)
        else:
            norm = np.linalg.norm(g, axis=1, keepdims=True)
            direction = np.divide(-g, norm, out=np.zeros_like(g), where=norm > 0)
            cand = theta + size[:, None] * direction
            j_new, g_new = _probe(s, cand, eps)
            better = j_new < j
            theta[better], j[better], g[better] = cand[better], j_new[better], g_new[better]
            size = np.where(better, size * 1.2, size * 0.5)
        improved = j < best_j
        best[improved], best_j[improved] = theta[improved], j[improved]
        for k in range(len(theta)):
            hist[k].append(float(j[k]))
    return [(best[k].copy(), float(best_j[k]), hist[k]) for k in range(len(theta))]


def cem(s: SortedSamples, starts: np.ndarray, rng: np.random.Generator, iterations: int = 60,
        population: int = 100, elite: float = 0.1, smoothing: float = 0.7
        ) -> list[tuple[np.ndarray, float, list[float]]]:
    """Sampling cross-entropy method from each start; (theta, J, history) per start."""
    mean = np.array(starts, dtype=np.float64)
    n_starts, d = mean.shape
    std = np.full_like(mean, 0.1 * _data_scale(s))
    best = mean.copy()
    best_j = s.objective(mean)
    n_elite = max(2, round(elite * population))
    hist = [[] for _ in range(n_starts)]
    for _ in range(iterations):
        draws = np.sort(mean[:, None, :] + std[:, None, :] *
                        rng.standard_normal((n_starts, population, d)), axis=2)
        j = s.objective(draws.reshape(-1, d)).reshape(n_starts, population)
        order = np.argsort(j, axis=1, kind="stable")[:, :n_elite]
        elites = np.take_along_axis(draws, order[:, :, None], axis=1)
        top = np.take_along_axis(j, order[:, :1], axis=1)[:, 0]
        improved = top < best_j
        best[improved] = elites[improved, 0]
        best_j[improved] = top[improved]
        finite = np.isfinite(np.take_along_axis(j, order, axis=1)).all(axis=1)
        new_mean = elites.mean(axis=1)
        new_std = elites.std(axis=1)
        mean = np.where(finite[:, None], smoothing * new_mean + (1 - smoothing) * mean, mean)
        std = np.where(finite[:, None], smoothing * new_std + (1 - smoothing) * std, std * 0.7)
        for k in range(n_starts):
            hist[k].append(float(best_j[k]))
    return [(best[k].copy(), float(best_j[k]), hist[k]) for k in range(n_starts)]


def _increasing_tuples(values: np.ndarray, d: int) -> np.ndarray:
    """Every strictly increasing d-tuple of ``values`` (sorted, distinct): (C(n, d), d)."""
    n = len(values)
    grids = np.meshgrid(*[np.arange(n)] * d, indexing="ij")
    idx = np.stack([g.ravel() for g in grids], axis=1)
    idx = idx[np.all(np.diff(idx, axis=1) > 0, axis=1)]
    return values[idx]


def _argmin(evaluate, candidates: np.ndarray, chunk: int = 20000) -> tuple[int, float]:
    """Row of ``candidates`` with the lowest ``evaluate(rows)`` (first on ties), and its J."""
    best_j, best = np.inf, -1
    for lo in range(0, len(candidates), chunk):
        j = evaluate(candidates[lo:lo + chunk])
        k = int(np.argmin(j))
        if j[k] < best_j:
            best_j, best = float(j[k]), lo + k
    return best, best_j


def grid_search(s: SortedSamples, d: int, size: int | None = None, fine: int = 17,
                seeds: int = 4) -> tuple[np.ndarray, float]:
    """Exhaustive search on a rank lattice, refined down to single samples.

    Thresholds only matter through where they split the sorted samples, so the search runs
    over split ranks r where x[r-1] < x[r] (threshold halfway between them): first every
    increasing d-tuple of ``size`` split ranks evenly spaced over the data (72 for d = 3,
    300 for d = 2), then local lattices of ``fine`` split ranks per threshold around each
    of the ``seeds`` best lattice points, shrinking until neighbouring splits are tried.
    """
    x = s.x
    splits = np.flatnonzero(x[1:] > x[:-1]) + 1  # ranks where a threshold can fall
    m = len(splits)
    if m < d:
        raise TapBenchError("no feasible thresholds on the grid: too few distinct samples")

    def evaluate(idx: np.ndarray) -> np.ndarray:
        return s.objective_at_ranks(splits[idx])

    size = min(size or (72 if d >= 3 else 300), m)
    lattice = np.unique(np.linspace(0, m - 1, size).round().astype(np.int64))
    tuples = _increasing_tuples(lattice, d)
    j_lattice = np.concatenate([evaluate(tuples[lo:lo + 20000])
                                for lo in range(0, len(tuples), 20000)])
    if not np.isfinite(j_lattice).any():
        raise TapBenchError("no feasible thresholds on the grid: too few distinct samples")
    best, best_j = tuples[0], np.inf
    # J has several basins: refine from the `seeds` best lattice points, keep the lowest.
    for k in np.argsort(j_lattice, kind="stable")[:seeds]:
        if not np.isfinite(j_lattice[k]):
            break
        cell, cell_j = tuples[k], float(j_lattice[k])
        step = max(1, int(np.ceil((m - 1) / max(len(lattice) - 1, 1))))
        while True:
            offsets = np.unique(np.linspace(-step, step, fine).round().astype(np.int64))
            axes = [np.clip(b + offsets, 0, m - 1) for b in cell]
            local = np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)
            local = local[np.all(np.diff(local, axis=1) > 0, axis=1)]
            i, j = _argmin(evaluate, local)
            if i >= 0 and j <= cell_j:
                cell, cell_j = local[i], j
            if step == 1:
                break
            step = max(1, step * 2 // (fine - 1))
        if cell_j < best_j:
            best, best_j = cell, cell_j
    ranks = splits[best]
    return 0.5 * (x[ranks - 1] + x[ranks]), best_j


def feasible_starts(s: SortedSamples, starts: np.ndarray) -> np.ndarray:
    """Starting guesses moved into the feasible set where they are not in it.

    A start that leaves a partition with fewer than two samples (say, a 22 m/s threshold on
    urban data with nothing faster) would give J = inf and never move. Such a start is
    replaced by thresholds at the data's (i+1)/(d+1) quantiles, which split the samples
    into d + 1 equal parts; feasible starts are kept as they are.
    """
    starts = np.array(starts, dtype=np.float64)
    bad = ~s.feasible(starts)
    if bad.any():
        d = starts.shape[1]
        ranks = np.round(np.arange(1, d + 1) * len(s) / (d + 1)).astype(np.int64)
        quantile = 0.5 * (s.x[ranks - 1] + s.x[ranks])
        starts[bad] = quantile
    return starts


# -- fitting --------------------------------------------------------------------------------
def _samples(data: pd.DataFrame | dict[str, np.ndarray], v_stop: float
             ) -> dict[str, np.ndarray]:
    samples = data if isinstance(data, dict) else one_second_samples(data, v_stop=v_stop)
    for dist in DISTRIBUTIONS:
        if dist not in samples:
            raise TapBenchError(f"samples lack the distribution {dist!r} (need w, a and v)")
    out = {k: np.asarray(samples[k], dtype=np.float64) for k in DISTRIBUTIONS}
    out["w"] = np.abs(out["w"])
    out["v"] = out["v"][out["v"] > v_stop]  # the Stopped partition takes no part in J
    return out


def fit_report(data: pd.DataFrame | dict[str, np.ndarray], *,
               methods: tuple[str, ...] = METHODS, select: str | None = None,
               dataset: str = "trajectory table", epochs: int = 100, seed: int = 0,
               starts: dict[str, tuple[tuple[float, ...], ...]] | None = None,
               hyperparameters: dict[str, tuple[float, float]] | None = None,
               v_stop: float = V_STOP) -> FitReport:
    """Fit Theta_w, Theta_a and Theta_v with several methods and report them all.

    Args:
        data: a trajectory table, or one-second samples ``{"w", "a", "v"}`` as returned by
            :func:`tap_bench.kinematics.one_second_samples`.
        methods: which of :data:`METHODS` to run (the grid is always run when asked for
            and is the reference for distances).
        select: which run becomes the thresholds. ``"best"`` (the default): the lowest J
            evaluated, over every method and start and the grid; a method name: the
            lowest J of that method's starts. A run with a degenerate band (narrower than
            :data:`RESOLUTION` of the data's 1-99 % range: on real data the global minimum
            of J can be one, docs/thresholds.md) is passed over for the lowest J without
            one, and a FitWarning names both; only when every run has one is it kept.
        dataset: a name for the data, kept in the provenance.
        epochs: descent epochs per start.
        seed: seed of the cross-entropy method's sampling.
        starts: starting guesses per distribution (default: the paper's).
        hyperparameters: (eps, eta) per distribution (default: the paper's Table 1).
        v_stop: the fixed Stopped threshold [m/s].
    """
    for m in methods:
        if m not in METHODS:
            raise did_you_mean("fitting method", m, METHODS)
    if select is None:
        select = "best"
    if select != "best" and select not in methods:
        raise TapBenchError(f"select={select!r} is not among the methods run {methods!r}; "
                            "use 'best' or one of them.")
    starts = {**PAPER_STARTS, **(starts or {})}
    hyper = {**PAPER_HYPERPARAMETERS, **(hyperparameters or {})}
    samples = _samples(data, v_stop)
    rng = np.random.default_rng(seed)
    fits: dict[str, DistributionFit] = {}
    moved: dict[str, list[tuple[float, ...]]] = {}
    for dist in DISTRIBUTIONS:
        x = samples[dist]
        d = len(starts[dist][0])
        if len(x) < 2 * (d + 1):
            raise TapBenchError(
                f"{dataset}: only {len(x)} one-second samples of {dist} ({UNITS[dist]}); "
                f"fitting {d} thresholds needs at least {2 * (d + 1)} (two per partition). "
                "Fit on more data, or label with --thresholds paper.")
        distinct = np.unique(x)
        if len(distinct) < d + 1:
            shown = ", ".join(f"{v:.6g}" for v in distinct[:3])
            raise TapBenchError(
                f"{dataset}: the {len(x)} one-second samples of {dist} ({UNITS[dist]}) take "
                f"only {len(distinct)} distinct value(s) ({shown}); {d} thresholds need "
                f"{d + 1} or more to split them. The data has no {_WHAT[dist]} to learn from: "
                "fit on data that has, or label with --thresholds paper.")
        s = SortedSamples(x)
        start_arr = feasible_starts(s, np.array(starts[dist], dtype=np.float64))
        moved[dist] = sorted({tuple(map(float, a)) for a, b in
                              zip(start_arr, starts[dist], strict=True)
                              if tuple(map(float, a)) != tuple(map(float, b))})
        eps, eta = hyper[dist]
        runs: list[FitRun] = []
        for method in methods:
            if method == "grid":
                continue
            if method == "cem":
                results = cem(s, start_arr, rng)
            else:
                results = descent(s, start_arr, eps, eta, epochs,
                                  step="paper" if method == "descent" else "scaled")
            for st, (theta, j, hist) in zip(start_arr, results, strict=True):
                runs.append(FitRun(dist, method, tuple(map(float, st)),
                                   tuple(map(float, theta)), j, tuple(hist)))
        grid = None
        if "grid" in methods:
            theta, j = grid_search(s, d)
            grid = FitRun(dist, "grid", None, tuple(map(float, theta)), j)
        pool = [*runs, *([grid] if grid else [])]
        if select != "best":
            pool = [r for r in pool if r.method == select]
        chosen, refused = _choose(dataset, dist, s, pool)
        notes = (*refused, *_fit_warnings(dataset, dist, s, chosen, grid))
        for note in notes:
            warnings.warn(note, FitWarning, stacklevel=2)
        fits[dist] = DistributionFit(dist, len(x), tuple(runs), grid, chosen, notes)


    th = Thresholds(
        *fits["w"].chosen.theta, *fits["a"].chosen.theta, v_stop, *fits["v"].chosen.theta,
        provenance=Provenance(
            dataset=dataset,
            n_samples={d: fits[d].n_samples for d in DISTRIBUTIONS},
            objective={d: fits[d].chosen.objective for d in DISTRIBUTIONS},
            method={d: fits[d].chosen.method for d in DISTRIBUTIONS},
            details={
                "select": select, "methods": list(methods), "epochs": epochs, "seed": seed,
                "starts": {d: [list(s) for s in starts[d]] for d in DISTRIBUTIONS},
                "eps_eta": {d: list(hyper[d]) for d in DISTRIBUTIONS},
                "chosen_start": {d: list(fits[d].chosen.start) if fits[d].chosen.start
                                 else None for d in DISTRIBUTIONS},
                "starts_moved_into_data": {d: moved[d] for d in DISTRIBUTIONS},
                "v_stop_fixed": v_stop, "names": {d: list(NAMES[d]) for d in NAMES},
                "warnings": [w for d in DISTRIBUTIONS for w in fits[d].warnings],
                "tap_bench": __version__,
            },
        ))
    return FitReport(thresholds=th, fits=fits)


_WHAT = {"w": "turning", "a": "change of speed", "v": "range of speeds"}


def _resolution(s: SortedSamples) -> float:
    """The narrowest band that is not degenerate: RESOLUTION of the 1-99 % range [unit]."""
    lo, hi = np.quantile(s.x, [0.01, 0.99])
    return RESOLUTION * float(hi - lo)


def _degenerate(s: SortedSamples, run: FitRun) -> bool:
    return bool(np.any(np.diff(run.theta) < _resolution(s)))


def _show(run: FitRun) -> str:
    theta = ", ".join(f"{v:.4g}" for v in run.theta)
    return f"{run.method}, ({theta}) {UNITS[run.dist]}, J = {run.objective:.4g}"


def _choose(dataset: str, dist: str, s: SortedSamples, pool: list[FitRun]
            ) -> tuple[FitRun, tuple[str, ...]]:
    """The run of ``pool`` with the lowest J (the first evaluated on ties) whose bands are
    not degenerate, and a note when a lower J was passed over for a degenerate band. When
    every run is degenerate the lowest J is kept (and :func:`_fit_warnings` reports it)."""
    ranked = sorted((r for r in pool if np.isfinite(r.objective)), key=lambda r: r.objective)
    if not ranked:
        raise TapBenchError(f"{dataset}: no feasible thresholds found for {dist}")
    kept = next((r for r in ranked if not _degenerate(s, r)), ranked[0])
    if kept is ranked[0]:
        return kept, ()
    return kept, (
        f"{dataset}: {dist}: the lowest J evaluated ({_show(ranked[0])}) has a band "
        f"narrower than the data's resolution ({RESOLUTION:.0%} of its 1-99 % range, "
        f"{_resolution(s):.2g} {UNITS[dist]}): a degenerate band, passed over for the lowest J "
        f"without one ({_show(kept)}). Compare both (tap-bench fit prints every run).",)


def _fit_warnings(dataset: str, dist: str, s: SortedSamples, chosen: FitRun,
                  grid: FitRun | None) -> tuple[str, ...]:
    """Warnings for one distribution's chosen fit, each naming both figures. A grid optimum
    with a degenerate band is no reference to be far from (:func:`_choose` says why it was
    passed over)."""
    unit = UNITS[dist]
    out = []
    theta = ", ".join(f"{v:.4g}" for v in chosen.theta)
    n = len(s.x)
    mu_all = float(np.dot(2.0 * np.arange(n) - n + 1, s.x) / (n * (n - 1) / 2))
    if (grid is not None and not _degenerate(s, grid)
            and chosen.objective > FAR_ABOVE_GRID * grid.objective
            and chosen.objective - grid.objective > J_RESOLUTION * mu_all**2):
        ratio = chosen.objective / grid.objective if grid.objective > 0 else float("inf")
        out.append(
            f"{dataset}: {dist}: the chosen fit ({chosen.method}, ({theta}) {unit}) has J = "
            f"{chosen.objective:.4g}, {ratio:.3g} times the grid optimum's J = "
            f"{grid.objective:.4g} at ({', '.join(f'{v:.4g}' for v in grid.theta)}) {unit}. "
            "Compare both (tap-bench fit prints every run); --select best takes the lowest J.")
    resolution = _resolution(s)
    edges = np.asarray(chosen.theta)
    widths = np.diff(edges)
    names = NAMES[dist] if dist != "v" else NAMES[dist][1:]
    for k in np.flatnonzero(widths < resolution):
        out.append(
            f"{dataset}: {dist}: the band between {dist}_{names[k]} = {edges[k]:.4g} and "
            f"{dist}_{names[k + 1]} = {edges[k + 1]:.4g} {unit} is {widths[k]:.2g} {unit} "
            f"wide, narrower than the data's resolution ({RESOLUTION:.0%} of its 1-99 % "
            f"range, {resolution:.2g} {unit}): a degenerate band. Look at the other runs of "
            "tap-bench fit, or label with --thresholds paper.")
    return tuple(out)


def fit_thresholds(data: pd.DataFrame | dict[str, np.ndarray], **kwargs) -> Thresholds:
    """Fitted :class:`Thresholds` with provenance; see :func:`fit_report` for the options."""
    return fit_report(data, **kwargs).thresholds
