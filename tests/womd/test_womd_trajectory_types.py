"""Waymo's trajectory-type classifier on hand-made tracks, and TAP's labels of the real WOMD
samples against it (end to end: ingest, label, compare)."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

import tap_bench
from tap_bench.sources.ingest import ingest_womd
from tap_bench.womd.trajectory_types import (
    agreement_table,
    classify_trajectories,
    label_agreement,
)


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


def test_agreement_rules_on_hand_written_labels():
    types = pd.DataFrame({"scenario_id": "s", "track_id": ["a", "b", "c", "d"],
                          "trajectory_type": ["LEFT_TURN", "STRAIGHT", "STATIONARY",
                                              "RIGHT_TURN"]})
    labels = pd.DataFrame({
        "scenario_id": "s", "track_id": ["a", "b", "b", "c"], "t_start": [0.0, 0.0, 5.0, 0.0],
        "lateral": ["Straight > Left Merge", "Straight", "Right Turn", "Straight"],
        "longitudinal": ["Maintain Speed", "Accelerate", "Maintain Speed",
                         "Decelerate > Stopped"]})
    got = label_agreement(types, labels).set_index("track_id")
    assert got["agrees"].to_dict() == {"a": True, "b": False, "c": True, "d": False}
    assert got["labelled"].to_dict() == {"a": True, "b": True, "c": True, "d": False}
    summary = agreement_table(got.reset_index()).set_index("trajectory_type")
    assert summary.loc["all", "agree"] == 2 and summary.loc["all", "labelled"] == 3


@pytest.mark.womd
def test_tap_labels_of_real_womd_agree_with_waymos_classifier(womd_dir, tmp_path):
    out = tmp_path / "womd.parquet"
    ingest_womd([womd_dir / "*.tfrecord", womd_dir / "*.pkl"], out, object_types="vehicle")
    table = pd.read_parquet(out)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", tap_bench.ShortSegmentWarning)
        labels = tap_bench.label(table, level="maneuver")
    per_track = label_agreement(classify_trajectories(table), labels)
    summary = agreement_table(per_track).set_index("trajectory_type")
    assert summary.loc["all", "labelled"] > 150
    assert summary.loc["all", "agreement"] >= 0.85
    assert summary.loc["STATIONARY", "agreement"] >= 0.9
    for turn in ("LEFT_TURN", "RIGHT_TURN"):
        assert summary.loc[turn, "agreement"] >= 0.75
    # No turn reads as a turn the other way only: a flipped axis would do exactly that.
    for kind, opposite in (("LEFT_TURN", "Right"), ("RIGHT_TURN", "Left")):
        rows = per_track[per_track["trajectory_type"] == kind]
        side = "Left" if opposite == "Right" else "Right"
        flipped = rows["lateral"].str.contains(opposite) & ~rows["lateral"].str.contains(side)
        assert not flipped.any()
