"""Exact J and the threshold optimisers."""

from __future__ import annotations

import itertools
import json
import math
from fractions import Fraction

import numpy as np
import pandas as pd
import pytest

import tap_bench as tb
from tap_bench.errors import TapBenchError
from tap_bench.fitting import cem, descent, grid_search
from tap_bench.objective import SortedSamples


def naive_mu(part: np.ndarray) -> float:
    """Mean absolute difference over all pairs, the O(m^2) way, summed exactly."""
    d = np.abs(part[:, None] - part[None, :])[np.triu_indices(len(part), k=1)]
    return math.fsum(d) / len(d)


def naive_j(x: np.ndarray, theta) -> float:
    edges = [-np.inf, *theta, np.inf]
    mus = [naive_mu(x[(x > lo) & (x <= hi)]) for lo, hi in itertools.pairwise(edges)]
    return sum((a - b) ** 2 for i, a in enumerate(mus) for b in mus[i + 1:])


@pytest.mark.parametrize("seed", range(5))
def test_fast_j_equals_the_naive_pairwise_computation(seed):
    rng = np.random.default_rng(seed)
    x = np.concatenate([rng.gamma(2.0, 3.0, 1500), rng.normal(30, 5, 500)])
    thetas = np.sort(rng.uniform(1, 40, size=(6, 3)), axis=1)
    fast = SortedSamples(x).objective(thetas)
    for theta, j in zip(thetas, fast, strict=True):
        assert j == pytest.approx(naive_j(x, theta), rel=1e-9)


def test_mu_stays_exact_at_a_quarter_million_samples():
    # The case where float64 prefix sums lose ~1e-9 .. 1e-5: a small partition far along a
    # large array of values far from zero. Reference: the per-partition sum in fractions.
    rng = np.random.default_rng(7)
    x = rng.gamma(2.0, 5.0, 233_000) + 20.0
    s = SortedSamples(x)
    counts, mu = s.partition_stats(np.array([[25.0, 40.0, 60.0]]))
    b = np.concatenate([[0], np.cumsum(counts[0])])
    for p in (2, 3):
        part = s.x[b[p]:b[p + 1]].tolist()
        m = len(part)
        exact = sum(Fraction(2 * k - m + 1) * Fraction(v) for k, v in enumerate(part))
        exact /= Fraction(m * (m - 1), 2)
        assert abs(mu[0, p] / float(exact) - 1) < 1e-13


def test_infeasible_thresholds_give_infinite_j():
    s = SortedSamples(np.arange(10.0))
    j = s.objective(np.array([[2.5, 1.5], [0.5, 5.5], [3.5, 8.5], [1.5, 5.5]]))
    assert np.isinf(j[:3]).all()  # out of order; one sample below 0.5; one above 8.5
    assert np.isfinite(j[3])


def blocks(edges, n_per_block=3000):
    """Equal-count, evenly spaced blocks of equal width: every partition that is exactly a
    block has the same mu, so J = 0 with the thresholds anywhere in the gaps, and J > 0
    once a threshold cuts into a block."""
    return np.concatenate([np.linspace(lo, hi, n_per_block) for lo, hi in edges])


# distribution: (samples, the gaps the optimal thresholds lie in). Every one of the paper's
# starting guesses has at least one threshold inside a block, so every start must move.
KNOWN = {
    "v": (blocks([(0.5, 8.5), (9.5, 17.5), (18.5, 26.5)]), [(8.5, 9.5), (17.5, 18.5)]),
    "a": (blocks([(-4.2, -1.6), (-1.3, 1.3), (1.6, 4.2)]), [(-1.6, -1.3), (1.3, 1.6)]),
    "w": (blocks([(0.0, 0.03), (0.034, 0.064), (0.112, 0.142), (0.21, 0.24)]),
          [(0.03, 0.034), (0.064, 0.112), (0.142, 0.21)]),
}


def in_gaps(theta, gaps) -> bool:
    return all(lo <= t <= hi for t, (lo, hi) in zip(theta, gaps, strict=True))


@pytest.mark.parametrize("dist", ["v", "a", "w"])
def test_paper_starts_are_not_optimal_on_the_known_distributions(dist):
    x, _ = KNOWN[dist]
    assert (SortedSamples(x).objective(np.array(tb.fitting.PAPER_STARTS[dist])) > 1e-6).all()


@pytest.mark.parametrize("dist", ["v", "a", "w"])
def test_grid_finds_the_known_optimum(dist):
    x, gaps = KNOWN[dist]
    theta, j = grid_search(SortedSamples(x), len(gaps))
    assert j < 1e-20
    assert in_gaps(theta, gaps)


@pytest.mark.parametrize("dist", ["v", "a", "w"])
@pytest.mark.parametrize("method", ["descent", "descent-scaled", "cem"])
def test_optimisers_land_on_the_grid_optimum(dist, method):
    """Stated tolerance: the lowest J over the three paper starts is within 1e-12 of the
    grid optimum's J (here 0; a threshold one sample into a block already costs ~1e-9 for
    w and ~1e-7 for a and v), and its thresholds lie in the gaps."""
    x, gaps = KNOWN[dist]
    s = SortedSamples(x)
    starts = np.array(tb.fitting.PAPER_STARTS[dist])
    eps, eta = tb.fitting.PAPER_HYPERPARAMETERS[dist]
    if method == "cem":
        runs = cem(s, starts, np.random.default_rng(0))
    else:
        runs = descent(s, starts, eps, eta, step="paper" if method == "descent" else "scaled")
    theta, j, hist = min(runs, key=lambda r: r[1])
    _, j_grid = grid_search(s, len(gaps))
    assert j <= j_grid + 1e-12
    assert in_gaps(theta, gaps)
    assert hist[-1] <= hist[0]


def test_scaled_step_converges_where_the_paper_step_stalls():
    """The paper's move is eta * grad: it shrinks with the imbalance it corrects, so with
    eta = 0.01 a hundred epochs cover about one e-fold of it. From the third start on the
    w blocks the paper's step is still short of the optimum after 100 epochs; the scaled
    step (unit direction, adaptive size) reaches it."""
    x, gaps = KNOWN["w"]
    s = SortedSamples(x)
    start = np.array([tb.fitting.PAPER_STARTS["w"][2]])
    (_, j_paper, _), = descent(s, start, 0.005, 0.01, step="paper")
    (theta, j_scaled, _), = descent(s, start, 0.005, 0.01, step="scaled")
    assert j_paper > 1e-8
    assert j_scaled < 1e-20 and in_gaps(theta, gaps)


def test_descent_returns_the_best_point_it_evaluated():
    """The paper's step theta - eta * grad overshoots where eta is large against J's
    curvature: on 600 normal samples of a from (-1, 1) (J = 0.052) it ends at J = 1.1e-3
    after passing 1.0e-3 with the paper's eta = 0.2, and at J = 0.96, above its start, with
    eta = 5. What it returns is the lowest J it evaluated, the start included."""
    s = SortedSamples(np.random.default_rng(0).normal(0.0, 1.0, 600))
    start = np.array([[-1.0, 1.0]])
    for eta in (0.2, 5.0):
        (theta, j, hist), = descent(s, start, 0.05, eta, step="paper")
        assert hist[-1] > min(hist)  # it did overshoot: the last epoch is not the best
        assert j == min(s.objective(start)[0], *hist)
        assert s.objective(theta[None])[0] == j


def test_fit_keeps_the_lowest_j_evaluated_without_a_warning(recwarn):
    """On the sample data the paper's descent ended at 12.9 times the grid optimum's J for w
    and the fit kept it, with a FitWarning. The fit keeps the lowest J any method, start
    or the grid evaluated: nothing to warn about."""
    from tap_bench.errors import FitWarning

    report = tb.fit_report(tb.sample_table(n_random=200, seed=0), dataset="sample")
    for dist, fit in report.fits.items():
        evaluated = [*fit.runs, fit.grid]
        assert fit.chosen.objective == min(r.objective for r in evaluated), dist
        assert fit.chosen.objective <= fit.grid.objective
    assert report.warnings == ()
    assert not [w for w in recwarn if issubclass(w.category, FitWarning)]
    assert report.thresholds.provenance.details["select"] == "best"


def test_a_degenerate_lowest_j_is_passed_over_and_the_fit_says_why():
    from tap_bench.fitting import FitRun, _choose

    s = SortedSamples(np.linspace(0.0, 0.4, 401))  # 1-99 % range 0.392: resolution 0.00392
    degenerate = FitRun("w", "grid", None, (0.1, 0.2, 0.2005), 0.01)
    spread = FitRun("w", "cem", (0.01, 0.05, 0.1), (0.1, 0.2, 0.3), 0.02)
    worse = FitRun("w", "descent", (0.01, 0.05, 0.1), (0.05, 0.2, 0.3), 0.5)
    chosen, notes = _choose("womd.parquet", "w", s, [worse, spread, degenerate])
    assert chosen is spread
    note, = notes
    assert "womd.parquet: w:" in note and "grid, (0.1, 0.2, 0.2005) rad/s, J = 0.01" in note
    assert "cem, (0.1, 0.2, 0.3) rad/s, J = 0.02" in note and "0.0039 rad/s" in note
    # no degenerate run lower: the lowest J, nothing to say
    assert _choose("x", "w", s, [worse, spread]) == (spread, ())
    # every run degenerate: the lowest J is kept (the band warning names it)
    assert _choose("x", "w", s, [degenerate]) == (degenerate, ())
    with pytest.raises(TapBenchError, match="no feasible thresholds"):
        _choose("x", "w", s, [FitRun("w", "cem", None, (0.1, 0.2, 0.3), float("inf"))])


def test_fit_thresholds_from_a_table_with_provenance(tmp_path):
    table = tb.random_trajectories(300, seed=1)
    report = tb.fit_report(table, dataset="synthetic-300")
    th = report.thresholds
    prov = th.provenance
    assert prov.dataset == "synthetic-300"
    samples = tb.one_second_samples(table)
    moving = int((samples["v"] > 0.1).sum())
    assert len(samples["v"]) == 300 * 9
    # stopped windows take no part in D_a, D_w (SPEC 3) nor in J(Theta_v)
    assert prov.n_samples["a"] == prov.n_samples["v"] == moving < 300 * 9
    # nor do windows whose heading is not trusted (a slow crawl) in D_w
    assert prov.n_samples["w"] == len(samples["w"]) <= moving
    assert th.v_stop == 0.1
    for dist in ("w", "a", "v"):
        runs = list(report.fits[dist].runs)
        assert len(runs) == 9  # three methods x three starts, plus the grid apart
        # by default the lowest J evaluated decides: every method, start and the grid
        assert prov.objective[dist] == min(r.objective for r in [*runs, report.fits[dist].grid])
    descent_only = tb.fit_report(table, select="descent").thresholds.provenance
    for dist in ("w", "a", "v"):
        assert descent_only.method[dist] == "descent"
        assert descent_only.objective[dist] == min(
            r.objective for r in report.fits[dist].runs if r.method == "descent")
    table_rows = report.table()
    assert set(table_rows["method"]) == {"descent", "descent-scaled", "cem", "grid"}
    path = tb.save_thresholds(th, tmp_path / "th.json")
    again = tb.load_thresholds(path)
    assert again == th and again.provenance == th.provenance
    assert json.loads(path.read_text())["provenance"]["method"]["w"] in tb.fitting.METHODS


def test_too_few_samples_is_a_clear_error():
    table = tb.behaviour("cruise_slow").iloc[:30]
    with pytest.raises(tb.TapBenchError, match="one-second samples"):
        tb.fit_thresholds(table)


def test_fit_select_one_method():
    table = tb.random_trajectories(100, seed=2)
    th = tb.fit_thresholds(table, methods=("descent", "grid"), select="descent")
    assert th.provenance.method == {"w": "descent", "a": "descent", "v": "descent"}
    with pytest.raises(tb.UnknownNameError, match="Did you mean 'cem'"):
        tb.fit_thresholds(table, methods=("cme",))


def test_infeasible_starts_are_moved_into_the_data():
    # urban speeds: nothing above 15 m/s, so the paper's v starts (med 22..26) are infeasible
    rng = np.random.default_rng(3)
    samples = {"w": rng.gamma(1.0, 0.02, 900), "a": rng.normal(0, 1, 900),
               "v": rng.uniform(0.2, 15.0, 900)}
    report = tb.fit_report(samples, methods=("descent", "grid"))
    runs = report.fits["v"].runs
    assert all(np.isfinite(r.objective) for r in runs)
    assert all(r.start[1] < 15.0 for r in runs)
    moved = report.thresholds.provenance.details["starts_moved_into_data"]["v"]
    assert len(moved) == 1  # the three infeasible starts all became the same quantile start


def test_warning_names_both_figures_far_above_the_grid_and_a_degenerate_band():
    from tap_bench.fitting import FitRun, _fit_warnings
    from tap_bench.objective import SortedSamples

    s = SortedSamples(np.linspace(0.0, 0.4, 401))  # 1-99 % range 0.392: resolution 0.00392
    chosen = FitRun("w", "descent", (0.01, 0.05, 0.1), (0.0126, 0.0502, 0.0509), 0.556)
    grid = FitRun("w", "grid", None, (0.1, 0.2, 0.3), 0.0216)
    notes = _fit_warnings("womd.parquet", "w", s, chosen, grid)
    assert len(notes) == 2
    far, band = notes
    assert "womd.parquet: w:" in far and "J = 0.556" in far and "25.7 times" in far
    assert "J = 0.0216" in far and "(0.1, 0.2, 0.3)" in far
    assert "w_grad = 0.0502 and w_med = 0.0509" in band and "0.0007 rad/s wide" in band
    assert "0.0039 rad/s" in band
    # a fit at the grid optimum with well-spread bands: nothing to report
    assert _fit_warnings("womd.parquet", "w", s, grid, grid) == ()
    # J far above in ratio but both tiny against the data's scale: nothing either
    tiny = FitRun("w", "descent", None, (0.1, 0.2, 0.3), 1e-8)
    assert _fit_warnings("x", "w", s, tiny, FitRun("w", "grid", None, (0.1, 0.2, 0.3), 1e-11)
                         ) == ()


def test_fit_report_raises_fit_warnings(recwarn):
    from tap_bench.errors import FitWarning

    rng = np.random.default_rng(0)
    samples = {"w": rng.uniform(0, 0.4, 500), "a": rng.normal(0, 1, 500),
               "v": rng.uniform(0.5, 30, 500)}
    report = tb.fit_report(samples, methods=("descent", "grid"), epochs=1,
                           dataset="few-epochs")
    raised = [str(w.message) for w in recwarn if issubclass(w.category, FitWarning)]
    assert raised == list(report.warnings)
    assert report.thresholds.provenance.details["warnings"] == list(report.warnings)


def test_fit_on_a_constant_distribution_names_file_distribution_and_fix(tmp_path, capsys):
    from tap_bench.cli import main

    # straight cruises: every one-second |w| is 0. 5 x 9 windows, less the 3 stopped ones
    # of stop_and_go (steps 40-69 mean 0.075, 0 and 0.06 m/s <= v_stop): 42 samples of w.
    table = pd.concat([tb.behaviour(name) for name in ("cruise_slow", "cruise_medium",
                                                       "cruise_fast", "stop_and_go",
                                                       "hard_brake")], ignore_index=True)
    with pytest.raises(TapBenchError, match="cruises.parquet: the 42 one-second samples of w"
                       r" \(rad/s\) take only 1 distinct value"):
        tb.fit_report(table, dataset="cruises.parquet")
    path = tmp_path / "cruises.parquet"
    tb.write_table(table, path)
    assert main(["fit", str(path), "-o", str(tmp_path / "th.json")]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "samples of w" in err and "--thresholds paper" in err
    assert not (tmp_path / "th.json").exists()
