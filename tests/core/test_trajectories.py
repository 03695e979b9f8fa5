"""The trajectory-table contract: every bad input gets an error naming column, row and fix."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import tap_bench as tb
from tap_bench.trajectories import validate_and_index


def cruise(n: int = 30, track: str = "7", scenario: str = "001") -> pd.DataFrame:
    return tb.synthetic.from_controls(np.full(n, 10.0), np.zeros(n), scenario_id=scenario,
                                      track_id=track)


def error_of(table: pd.DataFrame) -> tb.TrajectoryTableError:
    with pytest.raises(tb.TrajectoryTableError) as info:
        tb.validate_trajectories(table, source="data/run.csv")
    assert str(info.value).startswith("data/run.csv: ")
    return info.value


def test_empty_table():
    err = error_of(cruise().iloc[:0])
    assert "empty" in str(err)


def test_missing_columns_are_named_with_a_suggestion():
    err = error_of(cruise().rename(columns={"heading": "Heading", "speed": "v"}))
    assert err.column == "heading"
    assert "'heading'" in str(err) and "'speed'" in str(err)
    assert "Did you mean 'Heading'" in str(err)


def test_speed_from_vx_vy_when_absent():
    table = cruise().drop(columns="speed").assign(vx=3.0, vy=-4.0)
    out = tb.validate_trajectories(table)
    assert np.allclose(out["speed"], 5.0)


def test_ids_are_strings_even_when_numeric():
    table = cruise().assign(scenario_id=12, track_id=7.0)
    out = tb.validate_trajectories(table)
    assert out["scenario_id"].iloc[0] == "12" and out["track_id"].iloc[0] == "7"
    assert pd.api.types.is_string_dtype(out["track_id"])


def test_nan_on_a_valid_row_names_row_and_fix():
    table = cruise()
    table.loc[5, "x"] = np.nan
    err = error_of(table)
    assert err.column == "x" and err.row == 5
    assert "valid=False" in str(err)


def test_nan_on_an_invalid_row_splits_the_track():
    table = cruise().assign(valid=True)
    table.loc[12, ["x", "y"]] = np.nan
    table.loc[12, "valid"] = False
    index = validate_and_index(table).index
    assert index.segment_length.tolist() == [12, 17]


def test_infinite_value():
    table = cruise()
    table.loc[3, "speed"] = np.inf
    err = error_of(table)
    assert err.column == "speed" and err.row == 3 and "infinite" in str(err)


def test_non_numeric_value():
    table = cruise().astype({"y": object})
    table.loc[4, "y"] = "north"
    err = error_of(table)
    assert err.column == "y" and err.row == 4 and "'north'" in str(err)


def test_time_going_back_is_an_error_not_sorted():
    table = cruise()
    table = table.iloc[[0, 1, 3, 2, *range(4, 30)]].reset_index(drop=True)
    err = error_of(table)
    assert err.column == "t" and err.row == 3
    assert "not increasing" in str(err) and "does not sort" in str(err)


def test_duplicate_rows():
    table = pd.concat([cruise(), cruise().iloc[[4]]], ignore_index=True)
    err = error_of(table)
    assert "duplicate" in str(err) and err.row == 30 and "row 4" in str(err)
    adjacent = cruise().iloc[[0, 1, 2, 2, *range(3, 30)]].reset_index(drop=True)
    err = error_of(adjacent)
    assert "duplicate" in str(err) and err.row == 3 and "repeats row 2" in str(err)


def test_irregular_step():
    table = cruise()
    table.loc[10:, "t"] += 0.05
    err = error_of(table)
    assert "irregular time step of 0.15 s" in str(err) and err.row == 10


def test_other_sampling_rates_are_refused_with_the_resampling_fix():
    table = cruise(60).iloc[::5].reset_index(drop=True)  # 2 Hz
    err = error_of(table)
    assert "sampled at 2 Hz" in str(err) and "resample_to_10hz" in str(err)
    fast = cruise(60).assign(t=np.arange(60) * 0.04)  # 25 Hz
    assert "sampled at 25 Hz" in str(error_of(fast))


def test_missing_steps_split_the_track():
    table = cruise(40).drop(index=range(15, 18)).reset_index(drop=True)
    index = validate_and_index(table).index
    assert index.segment_length.tolist() == [15, 22]


def test_headings_in_degrees():
    table = cruise().assign(heading=90.0)
    err = error_of(table)
    assert err.column == "heading" and "degrees" in str(err) and "deg2rad" in str(err)


def test_negative_speed():
    table = cruise()
    table.loc[8, "speed"] = -0.5
    err = error_of(table)
    assert err.column == "speed" and err.row == 8 and "negative" in str(err)


def test_unknown_object_type():
    err = error_of(cruise().assign(object_type="truck"))
    assert err.column == "object_type" and "'truck'" in str(err)


def test_bad_valid_column():
    table = cruise().assign(valid="yes")
    err = error_of(table)
    assert err.column == "valid"


def test_interleaved_tracks_are_grouped_and_keep_their_order():
    a, b = cruise(track="a"), cruise(track="b")
    mixed = pd.concat([a, b]).sort_values("t", kind="stable").reset_index(drop=True)
    out = tb.validate_trajectories(mixed)
    assert out["track_id"].tolist() == ["a"] * 30 + ["b"] * 30
    assert np.all(np.diff(out["t"].to_numpy()[:30]) > 0)


def test_time_stamps_of_womd_drift_are_regular():
    table = cruise(91).assign(t=np.arange(91) * 0.1002)
    assert validate_and_index(table).index.segment_length.tolist() == [91]


def test_short_segments_are_reported_not_dropped_silently():
    table = cruise(25).assign(valid=True)
    table.loc[5, "valid"] = False  # leaves a 5-step (0.5 s) segment and a 19-step one
    with pytest.warns(tb.ShortSegmentWarning, match="1 valid segment"):
        labels = tb.label(table)
    assert len(labels) == 1 and labels["segment"].item() == 1
    short = tb.tap(table).short_segments
    assert short[["track_id", "segment", "n_steps"]].values.tolist() == [["7", 0, 5]]
    assert np.isclose(short["t_start"].item(), 0.0) and np.isclose(short["t_end"].item(), 0.5)


def test_identifying_columns_reach_the_label_table():
    table = cruise().assign(source="highway-env", env="highway", policy="idm", seed=3,
                            is_ego=True)
    labels = tb.label(table)
    assert labels[["source", "env", "policy", "seed", "is_ego"]].iloc[0].tolist() == [
        "highway-env", "highway", "idm", 3, True]
