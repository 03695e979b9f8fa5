"""Coverage and unique manoeuvres on label sets small enough to check by hand; labels keyed
by (env, label) when pooled."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.bootstrap import BootstrapConfig
from tap_bench.bench.coverage import (
    Reference,
    corpus_reference,
    coverage,
    vocabulary_reference,
)
from tap_bench.bench.novelty import novelty
from tap_bench.bench.scoring import reference_scores
from tap_bench.errors import LabelTableError
from tap_bench.sim.coverage import label_coverage

A = "Straight | Maintain Speed"
B = "Left Merge | Accelerate"
C = "Right Turn | Decelerate > Stopped"


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
    result = coverage(pd.Series([A, C, C]), ref)
    assert result.coverage == pytest.approx(1 / 2)  # A of {A, B}
    assert result.weighted_coverage == pytest.approx(0.75)  # A's weight
    assert result.covered == (A,) and result.missed == (B,)
    assert result.n_distinct == 2
    assert 0 <= result.coverage_low <= result.coverage <= result.coverage_high <= 1


def test_full_coverage_and_nothing_missed():
    ref = corpus_reference(ref_table([A, B]), "maneuver")
    result = coverage(pd.Series([A, B, A, B]), ref)
    assert result.coverage == 1.0 and result.weighted_coverage == 1.0 and result.missed == ()


def test_vocabulary_coverage_counts_single_labels_and_matches_the_training_signal():
    ref = vocabulary_reference("maneuver")
    # maneuver vocabulary: 5 lateral + 5 longitudinal single labels (Reversing, SPEC 4.6)
    assert len(ref) == 10
    labels = [A, B, "Straight > Left Merge | Maintain Speed > Accelerate"]
    result = coverage(pd.Series(labels), ref)
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
        res = coverage(labels, ref, config=BootstrapConfig(n_resamples=500, seed=r))
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
