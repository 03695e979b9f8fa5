"""Waymo's trajectory-type classifier on hand-made tracks, and TAP's labels of the real WOMD
samples against it (end to end: ingest, label, compare)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tap_bench.sources.ingest import ingest_womd
from tap_bench.womd.trajectory_types import (
    TAP_CATEGORIES,
    agreement_table,
    classify_trajectories,
    confusion_table,
    label_agreement,
)
from tap_bench.womd.validation import validate_womd


def track(track_id, speed, yaw_rate, steps=91, heading0=0.3):
    """A track driven from (100, -50) with constant speed [m/s] and yaw rate [rad/s]."""
    heading = heading0 + np.arange(steps) * 0.1 * yaw_rate
    x = 100 + np.concatenate([[0], np.cumsum(speed * np.cos(heading[:-1]) * 0.1)])
    y = -50 + np.concatenate([[0], np.cumsum(speed * np.sin(heading[:-1]) * 0.1)])
    return pd.DataFrame({"scenario_id": "hand", "track_id": track_id,
                         "t": np.arange(steps) / 10, "x": x, "y": y,
                         "heading": np.angle(np.exp(1j * heading)),
                         "vx": speed * np.cos(heading), "vy": speed * np.sin(heading),
                         "speed": float(speed), "valid": True})


def lane_change(track_id, side):
    """10 m/s along heading 0.3 rad with a 3.5 m sideways shift between 3 s and 6 s."""
    base = track(track_id, 10.0, 0.0)
    shift = side * 3.5 * np.clip((base["t"] - 3) / 3, 0, 1)
    base["x"] -= np.sin(0.3) * shift
    base["y"] += np.cos(0.3) * shift
    return base


def test_hand_made_tracks_get_their_type():
    table = pd.concat([
        track("parked", 0.0, 0.0), track("cruise", 12.0, 0.0),
        track("left", 8.0, (np.pi / 2) / 6.0),  # a quarter turn over 6 s
        track("right", 8.0, -(np.pi / 2) / 6.0),
        track("u-left", 5.0, np.pi / 6.0), track("u-right", 5.0, -np.pi / 6.0),
        lane_change("to-left", +1), lane_change("to-right", -1),
    ])
    types = classify_trajectories(table).set_index("track_id")["trajectory_type"]
    assert types.to_dict() == {
        "parked": "STATIONARY", "cruise": "STRAIGHT", "left": "LEFT_TURN",
        "right": "RIGHT_TURN", "u-left": "LEFT_U_TURN", "u-right": "RIGHT_U_TURN",
        "to-left": "STRAIGHT_LEFT", "to-right": "STRAIGHT_RIGHT"}


def test_tracks_invalid_at_the_start_index_are_not_classified():
    late = track("late", 10.0, 0.0)
    late.loc[late.index[:11], "valid"] = False
    assert classify_trajectories(pd.concat([late, track("on", 10.0, 0.0)]))[
        "track_id"].tolist() == ["on"]


def test_steps_come_from_t_not_from_the_row_count():
    # a track whose first 5 rows are invalid, dropped: its step 10 is still at t = 1 s (the
    # scenario's other track keeps the time stamps), not its 10th row at 1.5 s
    full = pd.concat([track("turn", 8.0, (np.pi / 2) / 6.0), track("cruise", 12.0, 0.0)],
                     ignore_index=True)
    full.loc[(full["track_id"] == "turn") & (full["t"] < 0.45), "valid"] = False
    dropped = full[full["valid"]]
    a, b = classify_trajectories(full), classify_trajectories(dropped)
    pd.testing.assert_frame_equal(a, b)
    assert np.allclose(a["t_start"], 1.0) and np.allclose(a["t_end"], 9.0)


def steps_of(track_id, t, lateral, longitudinal, segment=0):
    n = len(t)
    return pd.DataFrame({"scenario_id": "s", "track_id": track_id, "segment": segment,
                         "t": t, "maneuver_lateral": lateral if isinstance(lateral, list)
                         else [lateral] * n,
                         "maneuver_longitudinal": longitudinal if isinstance(longitudinal, list)
                         else [longitudinal] * n})


def test_strict_agreement_on_hand_written_labels():
    t = np.arange(20) / 10
    types = pd.DataFrame({"scenario_id": "s", "track_id": list("abcdefg"),
                          "trajectory_type": ["LEFT_TURN", "LEFT_TURN", "STRAIGHT", "STATIONARY",
                                              "RIGHT_TURN", "STRAIGHT_LEFT", "RIGHT_U_TURN"],
                          "t_start": 1.0, "t_end": 1.9})
    steps = pd.concat([
        # a: a Left Turn in the window: strict
        steps_of("a", t, ["Straight"] * 12 + ["Left Turn"] * 8, "Maintain Speed"),
        # b: a Left Merge only: the direction agrees, strict does not (a turn is asked for)
        steps_of("b", t, ["Straight"] * 12 + ["Left Merge"] * 8, "Maintain Speed"),
        # c: a Right Turn before 1 s only: outside the window, so Straight
        steps_of("c", t, ["Right Turn"] * 10 + ["Straight"] * 10, "Accelerate"),
        # d: Straight and Stopped: strict and longitudinal
        steps_of("d", t, "Straight", "Stopped"),
        # e: a Right Turn and a Left Merge: both sides, never agrees
        steps_of("e", t, ["Right Turn"] * 15 + ["Left Merge"] * 5, "Maintain Speed"),
        # f: a Left Merge for a lateral move to the left: strict
        steps_of("f", t, ["Straight"] * 14 + ["Left Merge"] * 6, "Maintain Speed"),
        # g: nothing labelled in the window
        steps_of("g", t[:5], "Straight", "Maintain Speed"),
    ])
    got = label_agreement(types, steps).set_index("track_id")
    assert got["lateral"].to_dict() == {
        "a": "Straight > Left Turn", "b": "Straight > Left Merge", "c": "Straight",
        "d": "Straight", "e": "Right Turn > Left Merge", "f": "Straight > Left Merge", "g": ""}
    assert got["tap_category"].to_dict() == {
        "a": "Left Turn", "b": "Left Merge", "c": "Straight", "d": "Straight",
        "e": "Left and Right", "f": "Left Merge", "g": "unlabelled"}
    assert got["strict"].to_dict() == {"a": True, "b": False, "c": True, "d": True, "e": False,
                                       "f": True, "g": False}
    assert got["direction"].to_dict() == {"a": True, "b": True, "c": True, "d": True,
                                          "e": False, "f": True, "g": False}
    assert got["longitudinal_agrees"].to_dict() == {"a": True, "b": True, "c": True, "d": True,
                                                    "e": True, "f": True, "g": False}
    summary = agreement_table(got.reset_index()).set_index("trajectory_type")
    assert summary.loc["all", ["labelled", "strict", "direction"]].tolist() == [6, 4, 5]
    confusion = confusion_table(got.reset_index())
    assert confusion.loc["LEFT_TURN", "Left Turn"] == 1
    assert confusion.loc["LEFT_TURN", "Left Merge"] == 1
    assert confusion.loc["total", "total"] == 7
    assert list(confusion.columns) == [*TAP_CATEGORIES, "total"]


@pytest.mark.womd
def test_tap_labels_of_real_womd_agree_with_waymos_classifier(womd_dir, tmp_path):
    out = tmp_path / "womd.parquet"
    ingest_womd([womd_dir / "*.tfrecord", womd_dir / "*.pkl"], out, object_types="vehicle")
    table = pd.read_parquet(out)
    # the invalid rows dropped (a legal table): the same types
    pd.testing.assert_frame_equal(classify_trajectories(table),
                                  classify_trajectories(table[table["valid"]]))
    result = validate_womd(table)
    s = result.summary
    assert s["labelled"] == 189
    # before issue 12 the strict agreement was 174 of 189 (0.921): never below it
    assert s["strict"] >= 174
    # every turn labelled as a turn that way; no still vehicle with a turn or merge
    assert s["turns"] == 11 and s["turns_labelled_as_that_turn"] == 11
    assert s["still_tracks"] > 100 and s["still_tracks_with_turn_or_merge"] == 0
    summary = result.agreement.set_index("trajectory_type")
    assert summary.loc["STATIONARY", "strict_share"] == 1.0
    # No turn reads as a turn the other way: a flipped axis would do exactly that.
    per_track = result.per_track
    for kind, other in (("LEFT_TURN", "Right"), ("RIGHT_TURN", "Left")):
        rows = per_track[per_track["trajectory_type"] == kind]
        assert not rows["tap_category"].str.startswith(other).any()
    # the named glitchy tracks of issue 12: parked, moving < 1 m, now Straight
    by_key = per_track.set_index(["scenario_id", "track_id"])
    assert by_key.loc[("a3bb37c25ce56418", "37"), "lateral"] == "Straight"
    assert bool(by_key.loc[("a3bb37c25ce56418", "37"), "still"])


@pytest.mark.womd
def test_validate_command_writes_the_tables(womd_dir, tmp_path, capsys):
    from tap_bench.cli import main

    out = tmp_path / "validation"
    assert main(["validate", str(womd_dir / "*.tfrecord"), "-o", str(out)]) == 0
    assert {p.name for p in out.iterdir()} == {"validation.md", "validation.json",
                                               "agreement.csv", "confusion.csv",
                                               "per_track.parquet"}
    text = capsys.readouterr().out
    assert "strict lateral agreement" in text and "Confusion table" in text


def test_agreement_shares_have_intervals_over_scenes():
    from tap_bench.stats.intervals import clustered_wilson_interval, wilson_interval

    # scene a: 10 STRAIGHT tracks that all agree; scene b: 10 that all disagree. Over
    # tracks 10 of 20 would look like 20 independent tracks; over scenes it is 2 scenes
    per_track = pd.DataFrame({
        "scenario_id": np.repeat(["a", "b"], 10), "trajectory_type": "STRAIGHT",
        "labelled": True, "strict": np.repeat([True, False], 10),
        "direction": True, "longitudinal_agrees": np.repeat([True, False], 10)})
    row = agreement_table(per_track).set_index("trajectory_type").loc["all"]
    assert row["scenes"] == 2 and row["strict_share"] == 0.5
    low, high, _ = clustered_wilson_interval([10, 0], [10, 10], 0.95)
    assert (row["strict_low"], row["strict_high"]) == pytest.approx((low, high), abs=5e-4)
    plain = wilson_interval(10, 20, 0.95)
    assert row["strict_high"] - row["strict_low"] > 1.5 * (plain[1] - plain[0])
    assert row["direction_low"] < 1 == row["direction_high"]  # all agree: Wilson's edge
