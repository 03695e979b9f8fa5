"""Unique behaviours and label counts."""

from __future__ import annotations

import pandas as pd
from similarity_helpers import CRUISE, LEFT_MERGE, STOP_AND_GO, label_rows

from tap_bench.similarity import label_counts, unique_labels


def test_counts_with_shares_sizes_and_first_example(small_labels):
    counts = label_counts(small_labels)
    assert counts["sdl"].tolist() == [CRUISE, LEFT_MERGE, STOP_AND_GO]
    assert counts["count"].tolist() == [3, 2, 1]
    assert counts["share"].tolist() == [0.5, 2 / 6, 1 / 6]
    assert counts["n_actions"].tolist() == [2, 4, 4]
    assert counts[["scenario_id", "track_id"]].values.tolist() == [
        ["s1", "1"], ["s1", "2"], ["s2", "2"]]


def test_unique_rows_most_actions_first(small_labels):
    extra = label_rows([("s3", "1", "Straight > Gradual Left Turn > Straight > Medium Right "
                         "Turn > Straight | Accelerate Slow Speed > Maintain Medium Speed")])
    table = pd.concat([small_labels, extra], ignore_index=True)
    unique = unique_labels(table)
    assert unique[["scenario_id", "track_id"]].values.tolist() == [["s3", "1"], ["s2", "2"]]
    assert unique["n_actions"].tolist() == [7, 4]
    assert unique["n_lateral"].tolist() == [5, 1]


def test_uniqueness_depends_on_the_level():
    # Two different action-level turns collapse to the same maneuver-level label.
    action = label_rows([
        ("s", "1", "Straight > Gradual Left Turn > Straight | Maintain Medium Speed"),
        ("s", "2", "Straight > Medium Left Turn > Straight | Maintain Medium Speed")])
    maneuver = label_rows([
        ("s", "1", "Straight > Left Turn > Straight | Maintain Speed"),
        ("s", "2", "Straight > Left Turn > Straight | Maintain Speed")], level="maneuver")
    table = pd.concat([action, maneuver], ignore_index=True)
    both = unique_labels(table, "all")
    assert both["level"].tolist() == ["action", "action"]
    assert unique_labels(table, "maneuver").empty
    counts = label_counts(table, "all")
    assert counts.groupby("level")["count"].sum().to_dict() == {"action": 2, "maneuver": 2}
