"""tap_in_parts: a large table labelled scenario by scenario gives every table one tap()
call gives (the command line labels large tables this way), and the same errors and
warnings."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st
from pandas.testing import assert_frame_equal

from tap_bench.errors import ResampledWarning, TrajectoryTableError
from tap_bench.labelling import TapParts, _scenario_parts, tap, tap_in_parts
from tap_bench.synthetic import random_trajectories

SETTINGS = settings(max_examples=6, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])
"""6 examples (each labels its table twice, about 0.9 CPU s): the suite's fixed
(derandomized) draw holds every branch of ``scenes`` and every ``interactions``
(``note_branches``; see them with ``--hypothesis-show-statistics``); the explicit example
(``every_branch``) holds them all in one table."""


def _tables(result) -> dict[str, pd.DataFrame]:
    out = {"info": result.segments_info, "short": result.short_segments,
           "glitches": result.glitches(), "steps": result.steps()}
    for level in ("trace", "trend", "maneuver", "action", "all"):
        out[f"labels {level}"] = result.labels(level)
        out[f"segments {level}"] = result.segments(level)
    return out


def _assert_same(parts: TapParts, whole) -> None:
    expected = _tables(whole)
    for name, frame in _tables(parts).items():
        assert_frame_equal(frame, expected[name], check_exact=True, obj=name)
    assert np.array_equal(parts.interaction_segments, whole.interaction_segments)


@st.composite
def scenes(draw):
    """Several scenarios of random tracks (some with gaps and short stretches, some
    marked ego), each scenario's rows time-major or track-major, scenarios in order."""
    n_scenarios = draw(st.integers(2, 6))
    frames = []
    for k in range(n_scenarios):
        n_tracks = draw(st.integers(1, 4))
        steps = draw(st.integers(31, 70))
        frame = random_trajectories(n_tracks, steps, seed=draw(st.integers(0, 2**16)),
                                    scenarios=1)
        if draw(st.booleans()):  # a track too short to label (< 1 s)
            first = frame["track_id"] == frame["track_id"].iloc[-1]
            keep = draw(st.integers(1, 12))
            frame = frame[~first | (first.cumsum() <= keep)].reset_index(drop=True)
        frame["scenario_id"] = draw(st.sampled_from(["s", "scène", "S", "10"])) + f"{k:03d}"
        frame["is_ego"] = frame["track_id"] == frame["track_id"].iloc[0]
        if draw(st.booleans()):  # a gap: invalid rows split a track
            rows = draw(st.lists(st.integers(0, len(frame) - 1), max_size=6))
            frame["valid"] = ~frame.index.isin(rows)
        if draw(st.booleans()):  # time-major, as simulators write
            frame = frame.sort_values("t", kind="stable")
        frames.append(frame)
    frames.sort(key=lambda f: f["scenario_id"].iloc[0])
    table = pd.concat(frames, ignore_index=True)
    if "valid" in table.columns:
        table["valid"] = table["valid"].fillna(True).astype(bool)
    return table


def every_branch() -> pd.DataFrame:
    """One table of ``scenes``' every branch at once (an explicit example): three scenarios,
    a track too short to label, a gap, time-major rows, ids of several spellings."""
    frames = []
    for k, (name, n_tracks, steps) in enumerate([("scène", 3, 45), ("S", 2, 62),
                                                 ("s", 4, 33)]):
        frame = random_trajectories(n_tracks, steps, seed=100 + k, scenarios=1)
        frame["scenario_id"] = f"{name}{k:03d}"
        frame["is_ego"] = frame["track_id"] == frame["track_id"].iloc[0]
        frames.append(frame)
    short = frames[0]["track_id"] == frames[0]["track_id"].iloc[-1]
    frames[0] = frames[0][~short | (short.cumsum() <= 6)].reset_index(drop=True)
    frames[1]["valid"] = ~frames[1].index.isin([3, 40, 41, 90])
    frames[2] = frames[2].sort_values("t", kind="stable")
    table = pd.concat(sorted(frames, key=lambda f: f["scenario_id"].iloc[0]),
                      ignore_index=True)
    table["valid"] = table["valid"].fillna(True).astype(bool)
    return table


def note_branches(table: pd.DataFrame, part_rows: int, interactions) -> None:
    """Name the branches of ``scenes`` an example holds, as hypothesis events."""
    event(f"interactions {interactions}")
    event("parts within a scenario" if part_rows < table.groupby("scenario_id").size().min()
          else "parts of whole scenarios")
    rows = table.groupby(["scenario_id", "track_id"], sort=False).size()
    if (rows < 10).any():
        event("a track too short to label")
    if "valid" in table.columns and not table["valid"].all():
        event("a gap")
    changes = (table["track_id"] != table["track_id"].shift()).sum()
    if changes > len(rows):
        event("time-major rows")


@SETTINGS
@given(table=scenes(), part_rows=st.integers(1, 400),
       interactions=st.sampled_from([None, "ego", "all"]))
@example(table=every_branch(), part_rows=40, interactions="all")
def test_parts_give_the_tables_of_one_call(table, part_rows, interactions):
    note_branches(table, part_rows, interactions)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        whole = tap(table, interactions=interactions)
    parts = tap_in_parts(table, part_rows=part_rows, interactions=interactions)
    _assert_same(parts, whole)
    assert parts.timings.keys() == whole.timings.keys()


def test_a_large_table_is_cut_between_scenarios_only():
    table = random_trajectories(60, 40, seed=1, scenarios=12)
    bounds = _scenario_parts(table, 200)
    assert bounds is not None and bounds[0] == 0 and bounds[-1] == len(table)
    sid = table["scenario_id"].to_numpy()
    for b in bounds[1:-1]:
        assert sid[b] != sid[b - 1]
    parts = tap_in_parts(table, part_rows=200)
    assert len(parts.parts) == len(bounds) - 1 > 1
    _assert_same(parts, tap(table))


def uncut_table(case: str) -> pd.DataFrame:
    """A table of 8 scenarios that parts cannot cut (``case``: "unsorted", scenarios out
    of the validated order; "split", one scenario in two runs of rows; "categorical" ids;
    "int" ids), or as drawn (any other case)."""
    table = random_trajectories(40, 40, seed=2, scenarios=8)
    if case == "unsorted":
        table = pd.concat([table[table["scenario_id"] == s]
                           for s in sorted(table["scenario_id"].unique())[::-1]],
                          ignore_index=True)
    elif case == "split":
        first = table["scenario_id"] == table["scenario_id"].iloc[0]
        table = pd.concat([table[first].iloc[:30], table[~first], table[first].iloc[30:]],
                          ignore_index=True)
    elif case == "categorical":
        table["scenario_id"] = table["scenario_id"].astype("category")
    elif case == "int":
        table["scenario_id"] = pd.factorize(table["scenario_id"])[0]
    return table


@pytest.mark.parametrize("case", ["unsorted", "split", "categorical", "small"])
def test_tables_that_cannot_be_cut_are_labelled_whole(case):
    table = uncut_table(case)
    part_rows = len(table) + 1 if case == "small" else 100
    assert _scenario_parts(table, part_rows) is None
    parts = tap_in_parts(table, part_rows=part_rows)
    assert len(parts.parts) == 1
    _assert_same(parts, tap(table))


def _message(call) -> str:
    with pytest.raises(TrajectoryTableError) as err:
        call()
    return str(err.value)


@pytest.mark.parametrize("fault", ["nan", "speed", "duplicate", "irregular", "type"])
def test_errors_are_those_of_the_whole_table(fault):
    """A fault in a later part is reported as tap() reports it: the row of the whole
    table, and the first fault of the whole table's checks."""
    table = random_trajectories(40, 40, seed=3, scenarios=8)
    table["object_type"] = "vehicle"
    row = len(table) - 40
    if fault == "nan":
        table.loc[row, "x"] = np.nan
    elif fault == "speed":
        table.loc[row, "speed"] = -1.0
        table.loc[5, "heading"] = 40.0  # checked after the speed: a later check, earlier row
    elif fault == "duplicate":
        table = pd.concat([table.iloc[:row + 1], table.iloc[[row]], table.iloc[row + 1:]],
                          ignore_index=True)
    elif fault == "irregular":
        table.loc[row:row + 20, "t"] += 0.03
    else:
        table.loc[row, "object_type"] = "truck"
    assert _scenario_parts(table, 100) is not None
    assert _message(lambda: tap_in_parts(table, part_rows=100)) == _message(lambda: tap(table))


def test_a_table_faster_than_10_hz_is_resampled_whole():
    table = random_trajectories(30, 40, seed=4, scenarios=6)
    fast = table.copy()
    fast["t"] = fast["t"] / 2  # 20 Hz
    with pytest.warns(ResampledWarning) as whole_warned:
        whole = tap(fast)
    with pytest.warns(ResampledWarning) as parts_warned:
        parts = tap_in_parts(fast, part_rows=100)
    assert [str(w.message) for w in parts_warned] == [str(w.message) for w in whole_warned]
    assert len(parts.parts) == 1
    _assert_same(parts, whole)


def test_a_table_with_invalid_rows_is_cut_too():
    """Invalid rows where scenarios meet (a block's position mean sums its own scenario's
    rows only, so a part sums what the whole table sums)."""
    table = random_trajectories(40, 40, seed=6, scenarios=8)
    first_rows = table.groupby("track_id").cumcount() < 3
    table["valid"] = ~(first_rows & (np.arange(len(table)) % 2 == 0))
    assert _scenario_parts(table, 100) is not None
    for interactions in (None, "all"):
        _assert_same(tap_in_parts(table, part_rows=100, interactions=interactions),
                     tap(table, interactions=interactions))


def test_a_part_without_labels_adds_no_rows():
    """A part whose scenario has only tracks too short to label: its empty tables (whose
    columns may have other dtypes) leave the joined tables as one call's."""
    table = random_trajectories(30, 40, seed=5, scenarios=6)
    middle = table["scenario_id"] == table["scenario_id"].iloc[len(table) // 2]
    table = table[~middle | (table.groupby("track_id").cumcount() < 5)].reset_index(drop=True)
    for interactions in (None, "all"):
        parts = tap_in_parts(table, part_rows=1, interactions=interactions)
        assert len(parts.parts) == 6
        assert any(len(p.segments_info) == 0 for p in parts.parts)
        _assert_same(parts, tap(table, interactions=interactions))


def test_interactions_of_a_table_with_nothing_long_enough_to_label():
    """Every track shorter than 1 s: no segment, no relation (it raised an IndexError)."""
    table = random_trajectories(3, 40, seed=5, scenarios=1)
    table = table[table.groupby("track_id").cumcount() < 5].reset_index(drop=True)
    result = tap(table, interactions="all")
    assert len(result.segments_info) == 0 and len(result.short_segments) == 3
    assert len(result.labels("all")) == 0 and len(result.steps()) == 0
    assert (result.segments("all")["axis"] == "interaction").sum() == 0
