"""Coverage and unique manoeuvres on label sets small enough to check by hand; labels keyed
by (env, label) when pooled."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.scores.coverage import (
    Reference,
    corpus_reference,
    coverage,
    vocabulary_reference,
)
from tap_bench.bench.scores.novelty import novelty
from tap_bench.bench.scores.scoring import reference_scores
from tap_bench.errors import LabelTableError
from tap_bench.sim.coverage import label_coverage
from tap_bench.stats.bootstrap import BootstrapConfig

A = "Straight | Maintain Speed"
B = "Left Merge | Accelerate"
C = "Right Turn | Decelerate > Stopped"


def _coverage_stream(reference, config=None):
    """coverage()'s stream in these tests: ("coverage", the reference's description)."""
    return (config or BootstrapConfig()).rng("coverage", reference.description)


def ref_table(labels: list[str]) -> pd.DataFrame:
    return pd.DataFrame({"scenario_id": [f"s{i}" for i in range(len(labels))],
                         "track_id": "1", "sdl": labels, "object_type": "vehicle"})


def test_corpus_reference_weights_are_frequencies():
    ref = corpus_reference(ref_table([A, A, A, B]), "maneuver")
    assert list(ref.items) == sorted([A, B])
    assert dict(zip(ref.items, ref.weights, strict=True)) == {A: 0.75, B: 0.25}
    assert ref.n_trajectories == 4


def test_corpus_reference_keeps_vehicles_only():
    table = ref_table([A, B, C])
    table.loc[2, "object_type"] = "pedestrian"
    assert set(corpus_reference(table, "maneuver").items) == {A, B}


def test_coverage_by_hand():
    # reference A x3, B x1; the agent shows A once and C twice
    ref = corpus_reference(ref_table([A, A, A, B]), "maneuver")
    result = coverage(pd.Series([A, C, C]), ref, rng=_coverage_stream(ref))
    assert result.coverage == pytest.approx(1 / 2)  # A of {A, B}
    assert result.weighted_coverage == pytest.approx(0.75)  # A's weight
    assert result.covered == (A,) and result.missed == (B,)
    assert result.n_distinct == 2
    assert 0 <= result.coverage_low <= result.coverage <= result.coverage_high <= 1


def test_full_coverage_and_nothing_missed():
    ref = corpus_reference(ref_table([A, B]), "maneuver")
    result = coverage(pd.Series([A, B, A, B]), ref, rng=_coverage_stream(ref))
    assert result.coverage == 1.0 and result.weighted_coverage == 1.0 and result.missed == ()


def test_vocabulary_coverage_counts_single_labels_and_matches_the_training_signal():
    ref = vocabulary_reference("maneuver")
    # maneuver vocabulary: 5 lateral + 5 longitudinal single labels (Reversing, SPEC 4.6)
    assert len(ref) == 10
    labels = [A, B, "Straight > Left Merge | Maintain Speed > Accelerate"]
    result = coverage(pd.Series(labels), ref, rng=_coverage_stream(ref))
    # Straight, Left Merge, Maintain Speed, Accelerate: 4 of 10
    assert result.coverage == pytest.approx(4 / 10)
    assert result.coverage == pytest.approx(label_coverage(labels, level="maneuver"))


def test_pooled_coverage_matches_labels_within_their_env_only():
    # issue 11: random's highway label must not cover IDM's roundabout label
    eps = pd.DataFrame({"env": ["highway", "roundabout"] * 2, "policy": ["idm"] * 2 +
                        ["random"] * 2, "seed": [0, 0, 0, 0], "status": "ok",
                        "scenario_id": ["a", "b", "c", "d"], "sdl": [A, B, B, C]})
    per_env = {env: corpus_reference(eps[(eps["policy"] == "idm") & (eps["env"] == env)]
                                     .assign(level="maneuver"), "maneuver", tracks="all")
               for env in ("highway", "roundabout")}
    cov, nov, labels = reference_scores(eps, per_env, "idm rollouts", config=BootstrapConfig(),
                                        policies=["random"])
    row = cov.set_index("env")
    assert row.loc["highway", "coverage"] == 0 and row.loc["roundabout", "coverage"] == 0
    assert row.loc["all", "coverage"] == 0  # B on highway is not roundabout's B
    assert row.loc["all", "coverage_high"] > 0  # estimated, not known: not [0, 0]
    novel = nov.set_index("env")
    assert novel.loc["all", "n_novel"] == 2 and novel.loc["all", "novel_low"] > 0
    assert set(zip(labels["env"], labels["label"], strict=True)) >= {("highway", B),
                                                                   ("roundabout", C)}


def test_same_scores_from_the_same_named_streams():
    eps = pd.DataFrame({"env": "h", "policy": "p", "seed": range(6), "status": "ok",
                        "scenario_id": [f"s{i}" for i in range(6)],
                        "sdl": [A, A, B, C, C, C]})
    ref = corpus_reference(ref_table([A, B]), "maneuver")
    one = reference_scores(eps, ref, "r", config=BootstrapConfig(seed=3))[0]
    two = reference_scores(pd.concat([eps.assign(policy="q"), eps]), ref, "r",
                           config=BootstrapConfig(seed=3))[0]
    pd.testing.assert_frame_equal(one, two[two["policy"] == "p"].reset_index(drop=True))


def test_novelty_by_hand():
    ref = corpus_reference(ref_table([A, A, B]), "maneuver")
    episodes = pd.DataFrame({"scenario_id": ["e0", "e1", "e2", "e3"], "env": "h",
                             "status": ["ok", "ok", "ok", "error"], "sdl": [A, C, C, C]})
    result = novelty(episodes, ref)
    assert (result.n, result.n_novel) == (3, 2)  # the failed episode is left out
    assert result.rate == pytest.approx(2 / 3)
    assert result.labels.to_dict("records") == [
        {"label": C, "count": 2, "share": pytest.approx(2 / 3), "example_scenario": "e1"}]
    assert 0 <= result.rate_low <= result.rate <= result.rate_high <= 1


def test_novelty_needs_a_corpus():
    with pytest.raises(LabelTableError, match="corpus"):
        novelty(pd.DataFrame({"sdl": [A]}), vocabulary_reference("maneuver"))


def test_no_labels_at_the_level_is_a_clear_error():
    table = ref_table([A]).assign(level="action")
    with pytest.raises(LabelTableError, match="level 'maneuver'"):
        corpus_reference(table, "maneuver")


def test_coverage_interval_rate_on_a_zipf_label_distribution():
    """The estimand is the expected coverage of n episodes; its true value is known for a
    synthetic label distribution: mean over reference labels of 1 - (1 - p)^n."""
    K, n = 30, 60
    p = 1 / np.arange(1, K + 1) ** 1.2
    p /= p.sum()
    items = np.array([f"L{i:02d}" for i in range(K)], dtype=object)
    ref = Reference(items, np.full(K, 1 / K), "corpus", "maneuver", "synthetic")
    truth = np.mean(1 - (1 - p) ** n)
    hits = 0
    reps = 200
    for r in range(reps):
        rng = np.random.default_rng(r)
        labels = items[rng.choice(K, n, p=p)]
        res = coverage(labels, ref, config=BootstrapConfig(n_resamples=500, seed=r),
                       rng=_coverage_stream(ref, BootstrapConfig(seed=r)))
        hits += res.coverage_low <= truth <= res.coverage_high
    print(f"coverage interval (augmented bootstrap), K={K}, n={n}: {hits / reps:.3f} "
          "(nominal 0.95)")
    assert 0.90 <= hits / reps <= 0.99


@pytest.mark.parametrize("keyed", [True, False])
def test_novel_labels_are_listed_once_under_their_env(keyed):
    """Issue 25: the pooled novel-label rows came back under each env's name (every novel
    label listed twice in the report); each (env, label) is one row, its count the env's."""
    eps = pd.DataFrame({"env": ["highway"] * 3 + ["merge"] * 3, "policy": "p",
                        "seed": [0, 1, 2] * 2, "status": "ok",
                        "scenario_id": [f"s{i}" for i in range(6)],
                        "sdl": [C, C, A, C, B, B]})
    ref_rows = pd.DataFrame({"env": ["highway", "merge"], "policy": "r", "sdl": [A, A],
                             "scenario_id": ["r0", "r1"], "track_id": "1"})
    reference = ({env: corpus_reference(ref_rows[ref_rows["env"] == env].assign(
        level="maneuver"), "maneuver", tracks="all") for env in ("highway", "merge")}
        if keyed else corpus_reference(ref_rows.assign(object_type="vehicle"), "maneuver"))
    _, nov, labels = reference_scores(eps, reference, "ref", config=BootstrapConfig())
    assert not labels.duplicated(["env", "policy", "reference", "label"]).any()
    assert "all" not in set(labels["env"])
    got = {(r.env, r.label): r.count for r in labels.itertuples()}
    assert got == {("highway", C): 2, ("merge", C): 1, ("merge", B): 2}
    pooled = nov.set_index("env").loc["all"]
    assert pooled["n_novel"] == labels["count"].sum() == 5
    # distinct novel labels: (env, label) pairs against per-env references, labels else
    assert pooled["n_novel_labels"] == (3 if keyed else 2)


def _zipf_episodes(G: int, K: int = 30, seed: int = 0):
    p = 1 / np.arange(1, K + 1) ** 1.2
    items = np.array([f"L{i:02d}" for i in range(K)], dtype=object)
    ref = Reference(items, p / p.sum(), "corpus", "maneuver", "synthetic")
    return ref, items[np.random.default_rng(seed).choice(K, G, p=p / p.sum())]


def test_windows_that_copy_their_episode_give_the_episodes_interval():
    """Issue 38: windows cut from one episode are not independent. When every episode's
    windows are copies of one label they carry one episode's information: resampled by
    episode, the interval is the one of one window per episode (each draw holds whole
    episodes), where drawing the windows as independent gives a narrower one."""
    G, k = 40, 4
    ref, one = _zipf_episodes(G)
    episodes = np.array([f"e{g}" for g in range(G)], dtype=object)
    copies, of = np.repeat(one, k), np.repeat(episodes, k)
    config = BootstrapConfig(n_resamples=1000, seed=3)
    base = coverage(one, ref, config=config, clusters=episodes, rng=_coverage_stream(ref, config))
    windows = coverage(copies, ref, config=config, clusters=of, rng=_coverage_stream(ref, config))
    assert windows.n == G * k and base.n == G
    assert (windows.coverage, windows.weighted_coverage) == (base.coverage,
                                                            base.weighted_coverage)
    for a, b in (("coverage_low", "coverage_high"), ("weighted_low", "weighted_high")):
        assert (getattr(windows, a), getattr(windows, b)) == (getattr(base, a),
                                                              getattr(base, b))
    np.testing.assert_array_equal(windows.draws, base.draws)
    # as wide as the interval of the G episodes drawn as independent labels (within 25 %)
    iid = coverage(one, ref, config=config, rng=_coverage_stream(ref, config))
    width = base.coverage_high - base.coverage_low
    assert width >= 0.75 * (iid.coverage_high - iid.coverage_low)
    # the windows drawn as independent episodes: too narrow (the old interval)
    naive = coverage(copies, ref, config=config, rng=_coverage_stream(ref, config))
    assert naive.coverage_high - naive.coverage_low < 0.75 * width


def test_windows_of_one_episode_are_drawn_together():
    """An episode whose two windows show the labels X_g and Y_g: in every draw as many
    X labels as Y labels are shown (the windows come with their episode)."""
    G = 30
    xs = [f"X{g:02d}" for g in range(G)]
    ys = [f"Y{g:02d}" for g in range(G)]
    items = np.array(sorted(xs + ys), dtype=object)
    x_only = Reference(items, np.where(np.char.startswith(items.astype(str), "X"), 1 / G, 0),
                       "corpus", "maneuver", "x")
    labels = np.array([v for pair in zip(xs, ys, strict=True) for v in pair], dtype=object)
    of = np.repeat([f"e{g}" for g in range(G)], 2).astype(object)
    res = coverage(labels, x_only, config=BootstrapConfig(n_resamples=500), clusters=of,
                   rng=_coverage_stream(x_only))
    # the coverage draw counts X and Y (1/K each); the weighted one X only (1/G each)
    shown = res.draws[:, 0] * len(items)
    x_shown = res.draws[:, 1] * G
    assert np.allclose(shown, 2 * x_shown)
    with pytest.raises(LabelTableError, match="clusters"):
        coverage(labels, x_only, clusters=of[:-1], rng=_coverage_stream(x_only))


def test_scoring_windows_resamples_their_episodes():
    """reference_scores(windowed=True) passes the windows' episodes to the coverage."""
    G, k = 30, 3
    ref, one = _zipf_episodes(G, seed=1)
    eps = pd.DataFrame({"env": "highway", "policy": "p", "status": "ok",
                        "seed": np.arange(G * k),
                        "scenario_id": [f"highway/p/s{g}#{j}" for g in range(G)
                                        for j in range(k)],
                        "sdl": np.repeat(one, k),
                        "cut_from": [f"highway/p/s{g}" for g in range(G) for j in range(k)]})
    config = BootstrapConfig(n_resamples=500)
    cov, _, _ = reference_scores(eps, ref, "syn", config=config, windowed=True)
    row = cov.set_index("env").loc["highway"]
    want = coverage(eps["sdl"], ref, config=config, rng=config.rng(
        "coverage", "highway", "p", "syn"), clusters=np.repeat(
        [f"highway/p/s{g}" for g in range(G)], k))
    assert (row["coverage_low"], row["coverage_high"]) == pytest.approx(
        (want.coverage_low, want.coverage_high))
    flat, _, _ = reference_scores(eps, ref, "syn", config=config, windowed=False)
    flat_row = flat.set_index("env").loc["highway"]
    assert flat_row["coverage_high"] - flat_row["coverage_low"] < \
        row["coverage_high"] - row["coverage_low"]


@pytest.mark.parametrize("scorer", ["reference_scores", "novelty"])
def test_windowed_scoring_names_the_missing_cut_from_column(scorer):
    """A windows table without the column naming each window's episode is refused with
    the column's name and where it comes from, not a bare KeyError."""
    ref = corpus_reference(ref_table([A, B]), "maneuver")
    eps = pd.DataFrame({"env": "highway", "policy": "p", "status": "ok", "seed": [0, 1],
                        "scenario_id": ["highway/p/s0#0", "highway/p/s0#1"],
                        "sdl": [A, C]})
    with pytest.raises(LabelTableError, match=r"'cut_from'.*window_episodes"):
        if scorer == "novelty":
            novelty(eps, ref, windowed=True)
        else:
            reference_scores(eps, ref, "syn", config=BootstrapConfig(n_resamples=100),
                             windowed=True)


def test_coverage_diversity_and_the_null_draw_from_the_stream_they_are_given():
    """A given stream is the one drawn from (the run names each by env, policy and
    reference); without one, each draws from its documented default stream, so a user's
    call ``coverage(labels, reference)`` is reproducible and needs no stream."""
    from tap_bench.bench.scores.diversity import diversity
    from tap_bench.bench.scores.null import same_policy_null

    config = BootstrapConfig(n_resamples=100)
    ref = corpus_reference(ref_table([A, A, B, C, C, C, A, B]), "maneuver")
    labels = np.array([A, B, B, C, A, A, C, B, A, C], dtype=object)
    cases = [
        (lambda **kw: coverage(labels, ref, config=config, **kw).draws,
         config.rng("coverage", ref.description)),
        (lambda **kw: diversity(labels, config=config, **kw).draws, config.rng("diversity")),
        (lambda **kw: same_policy_null(labels, ref, config=config, **kw).draws,
         config.rng("null", ref.description)),
    ]
    for draws_of, default_stream in cases:
        default = draws_of()
        np.testing.assert_array_equal(default, draws_of(rng=default_stream))
        other = draws_of(rng=config.rng("coverage", "syn", "idm", ref.description))
        assert default.shape == other.shape and not np.array_equal(default, other)
