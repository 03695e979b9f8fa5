"""Matched comparison on the hand-worked pairs of conftest.hand_pairs."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.scores.compare import NO_LABEL, matched_by_label, paired_comparison
from tap_bench.errors import LabelTableError, UnknownNameError
from tap_bench.stats.bootstrap import BootstrapConfig

from .conftest import make_episodes


def test_agreement_and_label_differences_by_hand(hand_pairs):
    pc = paired_comparison(hand_pairs, "A", "B")
    row = pc.summary.iloc[0]
    assert row["n_pairs"] == 4 and row["n_dropped"] == 0
    assert row["agreement"] == pytest.approx(0.75)  # seeds 0, 2, 3 agree
    diffs = pc.labels.set_index("label")["diff"].to_dict()
    assert diffs == pytest.approx({"x | s": 0.25, "y | s": -0.25, "z | s": 0.0})
    freq = pc.labels.set_index("label")[["freq_a", "freq_b"]].loc["x | s"].to_list()
    assert freq == pytest.approx([0.5, 0.25])
    assert (pc.labels["diff_low"] <= pc.labels["diff"]).all()
    assert (pc.labels["band_low"] <= pc.labels["diff"]).all()
    assert (pc.labels["diff"] <= pc.labels["band_high"]).all()


def test_measure_differences_and_probability_of_improvement_by_hand(hand_pairs):
    m = paired_comparison(hand_pairs, "A", "B").measures.set_index("measure")
    speed = m.loc["mean_speed"]
    assert speed["mean_a"] == pytest.approx(11.25) and speed["mean_b"] == pytest.approx(10.25)
    assert speed["diff"] == pytest.approx(1.0)
    # A faster on seeds 0, 3; tie on 1; slower on 2 -> (2 + 0.5) / 4
    assert speed["p_improvement"] == pytest.approx(0.625)
    crash = m.loc["crashed"]
    # lower is better: A better on seed 1, worse on 3, ties on 0, 2 -> (1 + 1) / 4
    assert crash["p_improvement"] == pytest.approx(0.5)
    assert crash["diff"] == pytest.approx(0.0)


def test_failed_episode_drops_its_pair(hand_pairs):
    eps = hand_pairs.copy()
    eps.loc[(eps["policy"] == "B") & (eps["seed"] == 1), "status"] = "error"
    row = paired_comparison(eps, "A", "B").summary.iloc[0]
    assert row["n_pairs"] == 3 and row["n_dropped"] == 1
    assert row["agreement"] == pytest.approx(1.0)


def test_missing_label_is_its_own_label(hand_pairs):
    eps = hand_pairs.copy()
    eps.loc[(eps["policy"] == "A") & (eps["seed"] == 0), "sdl"] = pd.NA
    labels = paired_comparison(eps, "A", "B").labels
    assert NO_LABEL in set(labels["label"])


def test_pooled_over_envs_is_added(hand_pairs):
    other = hand_pairs.assign(env="f")
    pc = paired_comparison(pd.concat([hand_pairs, other], ignore_index=True), "A", "B")
    assert list(pc.summary["env"]) == ["e", "f", "all"]
    assert pc.summary.set_index("env").loc["all", "n_pairs"] == 8


def test_intervals_depend_on_the_seed_only(hand_pairs):
    one = paired_comparison(hand_pairs, "A", "B", config=BootstrapConfig(seed=3))
    two = paired_comparison(hand_pairs, "A", "B", config=BootstrapConfig(seed=3))
    pd.testing.assert_frame_equal(one.measures, two.measures)


def test_unknown_policy_and_no_common_seed_are_clear(hand_pairs):
    with pytest.raises(LabelTableError, match="no episodes of policy 'C'"):
        paired_comparison(hand_pairs, "A", "C")
    shifted = hand_pairs.copy()
    shifted.loc[shifted["policy"] == "B", "seed"] += 10
    with pytest.raises(LabelTableError, match="share no"):
        paired_comparison(shifted, "A", "B")


def test_matched_by_label_groups_equal_labels():
    rows = []
    # label m: A at 10, 12 m/s; B at 7, 9 m/s. label k: only A. label j: A once, B twice.
    for seed, (pol, lab, v) in enumerate([("A", "m", 10), ("A", "m", 12), ("B", "m", 7),
                                          ("B", "m", 9), ("A", "k", 20), ("A", "k", 21),
                                          ("A", "j", 5), ("B", "j", 6), ("B", "j", 6)]):
        rows.append({"policy": pol, "seed": seed, "sdl": f"Straight | {lab}",
                     "mean_speed": v})
    eps = make_episodes(rows)
    eps["sdl"] = eps["sdl"].str.replace("| m", "| Maintain Speed").str.replace(
        "| k", "| Accelerate").str.replace("| j", "| Decelerate")
    out = matched_by_label(eps, "A", "B", min_group=2)
    speed = out[out["measure"] == "mean_speed"]
    assert list(speed["label"]) == ["Straight | Maintain Speed"]  # k: no B; j: one A
    assert speed.iloc[0][["n_a", "n_b", "mean_a", "mean_b", "diff"]].tolist() == [2, 2, 11.0,
                                                                                  8.0, 3.0]
    # within one token edit, Decelerate and Maintain Speed join the anchors' groups
    near = matched_by_label(eps, "A", "B", metric="levenshtein", d_sim=1, min_group=2)
    near = near[near["measure"] == "mean_speed"].set_index("label")
    assert near.loc["Straight | Maintain Speed", "n_a"] == 5  # m, k, j of A
    assert near.loc["Straight | Maintain Speed", "n_b"] == 4


def test_matched_metric_is_checked(hand_pairs):
    with pytest.raises(UnknownNameError, match="levenshtein"):
        matched_by_label(hand_pairs, "A", "B", metric="levenstein")
    with pytest.raises(ValueError, match="d_sim"):
        matched_by_label(hand_pairs, "A", "B", d_sim=1)


def test_no_nan_in_interval_when_measure_absent(hand_pairs):
    m = paired_comparison(hand_pairs, "A", "B").measures
    assert set(m["measure"]) == {"mean_speed", "crashed"}
    assert np.isfinite(m[["diff_low", "diff_high"]].to_numpy()).all()


def test_small_label_groups_are_listed_not_tested():
    rows = []
    # issue 11: a 3 vs 2 group must not print a "significant" difference
    for seed, (pol, v) in enumerate([("A", 1.0), ("A", 1.2), ("A", 0.9), ("B", 3.0),
                                     ("B", 3.1)]):
        rows.append({"policy": pol, "seed": seed, "sdl": "Straight | Maintain Speed",
                     "min_headway_s": v})
    out = matched_by_label(make_episodes(rows), "A", "B")
    assert len(out) == 1 and not out.iloc[0]["tested"]
    assert (out.iloc[0]["n_a"], out.iloc[0]["n_b"]) == (3, 2)
    assert "fewer than 5" in out.iloc[0]["note"] and pd.isna(out.iloc[0]["diff_low"])


def test_no_zero_width_interval_on_estimated_paired_quantities(hand_pairs):
    eps = hand_pairs.assign(crashed=False)
    pc = paired_comparison(eps, "A", "B")
    crash = pc.measures.set_index("measure").loc["crashed"]
    assert crash["diff"] == 0 and crash["diff_low"] < 0 < crash["diff_high"]
    assert crash["p_low"] < 0.5 < crash["p_high"]
    assert (pc.labels["band_high"] > pc.labels["band_low"]).all()


def test_on_real_scenes_the_comparison_shows_at_fault_collisions_beside_all():
    from tap_bench.bench.scores.compare import paired_comparison

    rows = []
    for seed in range(6):
        for policy, crashed, fault in (("idm", seed < 4, seed < 1), ("log", False, False)):
            rows.append({"env": "womd", "policy": policy, "seed": seed, "sdl": "x | s",
                         "crashed": crashed, "crashed_at_fault": float(fault),
                         "off_road": 0.0, "route_progress": 1.0})
    measures = paired_comparison(make_episodes(rows), "idm", "log").measures.set_index(
        "measure")
    assert measures.loc["crashed", "mean_a"] == pytest.approx(4 / 6)
    assert measures.loc["crashed_at_fault", "mean_a"] == pytest.approx(1 / 6)
    assert {"off_road", "route_progress"} <= set(measures.index)


def test_compare_policies_stacks_every_pair_and_lists_a_pair_with_nothing_to_pair(hand_pairs):
    """The run's comparison tables: A vs B as paired_comparison gives it, with the pair's
    names; C (every episode failed) is skipped with the reason, and has no rows."""
    from tap_bench.bench.scores.compare import compare_policies

    failed = hand_pairs[hand_pairs["policy"] == "B"].assign(policy="C", status="error")
    eps = pd.concat([hand_pairs, failed], ignore_index=True)
    config = BootstrapConfig()
    out = compare_policies(eps, [("A", "B"), ("C", "B")], config)
    alone = paired_comparison(eps, "A", "B", config=config)
    pd.testing.assert_frame_equal(out.paired, alone.summary)
    assert set(out.measures["policy_a"]) == {"A"} and set(out.labels["policy_b"]) == {"B"}
    assert out.method == alone.method
    assert len(out.skipped) == 1 and out.skipped[0].startswith("C vs B: ")


def test_scores_list_the_methods_in_report_order_the_comparisons_text_in_its_place(hand_pairs):
    """The methods come in the report's order whichever step makes them: the paired
    comparisons' text second (theirs, "" when nothing was compared), skipped pairs and the
    carried tables' methods after score's own."""
    from tap_bench.bench.scores.scoring import score

    config = BootstrapConfig(n_resamples=100)
    failed = hand_pairs[hand_pairs["policy"] == "B"].assign(policy="C", status="error")
    eps = pd.concat([hand_pairs, failed], ignore_index=True)
    both = score(eps, reference_policy="B", level="maneuver", config=config,
                 methods={"contexts": "carried"})
    alone = score(hand_pairs[hand_pairs["policy"] == "B"], reference_policy="B",
                  level="maneuver", config=config)
    order = ["measures", "paired", "matched", "coverage", "novelty", "same-policy null",
             "unit", "diversity"]
    assert list(both.methods) == [*order, "skipped comparisons", "contexts"]
    assert both.methods["paired"] == paired_comparison(eps, "A", "B", config=config).method
    assert list(alone.methods) == order and alone.methods["paired"] == ""
