"""Properties of TAP that hold for any valid trajectory table (hypothesis)."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import tap_bench as tb
from tap_bench.synthetic import from_controls

SETTINGS = settings(max_examples=40, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])
LABELLING = settings(SETTINGS, max_examples=20)
"""For the properties that label whole tables: 20 drawn tables of
1-4 tracks, with and without gaps and noise, in the suite's fixed (derandomized) draw."""


@st.composite
def tracks(draw, max_tracks: int = 4):
    """A table of 1..max_tracks tracks built from piecewise-constant controls with noise,
    some rows invalid (gaps), all at 10 Hz."""
    frames = []
    n_tracks = draw(st.integers(1, max_tracks))
    for k in range(n_tracks):
        n = draw(st.integers(1, 120))
        pieces = draw(st.lists(st.tuples(st.integers(1, 40), st.floats(-0.6, 0.6),
                                         st.floats(-4.0, 4.0)), min_size=1, max_size=6))
        yaw = np.concatenate([np.full(d, w) for d, w, _ in pieces])[:n]
        acc = np.concatenate([np.full(d, a) for d, _, a in pieces])[:n]
        if len(yaw) < n:
            yaw = np.pad(yaw, (0, n - len(yaw)))
            acc = np.pad(acc, (0, n - len(acc)))
        v0 = draw(st.floats(0.0, 35.0))
        speed = np.maximum(v0 + np.cumsum(acc) * 0.1, 0.0)
        seed = draw(st.integers(0, 2**16))
        rng = np.random.default_rng(seed)
        yaw = yaw + rng.normal(0, draw(st.sampled_from([0.0, 0.01, 0.05])), n)
        frame = from_controls(speed, yaw, scenario_id=f"s{k % 2}", track_id=str(k),
                              heading0=draw(st.floats(-3.1, 3.1)))
        if draw(st.booleans()):
            frame["valid"] = rng.random(n) > draw(st.sampled_from([0.0, 0.05, 0.3]))
        frames.append(frame)
    table = pd.concat(frames, ignore_index=True)
    if "valid" in table:
        table["valid"] = table["valid"].fillna(True).astype(bool)
    return table


def _label(table: pd.DataFrame, level: str = "all") -> pd.DataFrame:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", tb.ShortSegmentWarning)
        return tb.label(table, "paper", level=level)


def _key(frame: pd.DataFrame) -> pd.DataFrame:
    return frame.sort_values(["scenario_id", "track_id", "segment", "level"]).reset_index(
        drop=True)


@LABELLING
@given(tracks())
def test_any_valid_table_labels_and_every_level_has_one_row_per_segment(table):
    result = tb.tap(table)
    labels = result.labels("all")
    n_seg = len(result.segments_info)
    assert len(labels) == 4 * n_seg
    assert labels["sdl"].str.contains(" | ", regex=False).all()
    # every step of every labelled segment is accounted for
    assert int(result.segments_info["n_steps"].sum()) == len(result.step_t)
    # vocabulary at each level
    for level in tb.LEVELS:
        part = labels[labels["level"] == level]
        for axis in ("lateral", "longitudinal"):
            words = {w for seq in part[axis] for w in seq.split(" > ")}
            assert words <= set(tb.vocabulary(level, axis))


@LABELLING
@given(tracks(), st.randoms(use_true_random=False))
def test_labels_do_not_depend_on_row_order(table, rnd):
    base = _label(table)
    # interleave tracks time-major and shuffle the order of tracks; keep each track's order
    order = list(table.groupby(["scenario_id", "track_id"], sort=False).groups.values())
    rnd.shuffle(order)
    shuffled = pd.concat([table.loc[idx] for idx in order])
    shuffled = shuffled.assign(_k=shuffled.groupby(["scenario_id", "track_id"]).cumcount())
    shuffled = shuffled.sort_values("_k", kind="stable").drop(columns="_k")
    pd.testing.assert_frame_equal(_key(_label(shuffled)), _key(base))


@LABELLING
@given(tracks(max_tracks=3), tracks(max_tracks=3))
def test_labels_of_a_track_do_not_depend_on_other_tracks(table, others):
    others = others.assign(scenario_id="other-" + others["scenario_id"])
    alone = _label(table)
    both = pd.concat([others, table], ignore_index=True)
    if "valid" in both:
        both["valid"] = both["valid"].fillna(True).astype(bool)
    together = _label(both)
    together = together[~together["scenario_id"].str.startswith("other-")]
    pd.testing.assert_frame_equal(_key(together), _key(alone))


@LABELLING
@given(tracks(max_tracks=3), tracks(max_tracks=3), st.integers(1, 12))
def test_labels_of_a_scenario_do_not_depend_on_the_scenario_after_it(table, after, lead):
    """The other direction of the test above: a scenario sorted after this one, whose
    tracks begin with invalid rows (agents that appear later, as in recorded scenes), leaves
    this one's labels (travel included) as they are alone: TAP labels a batch of episodes
    as one table (bench run) and a large file in parts (tap-bench label)."""
    after = after.assign(scenario_id="z-" + after["scenario_id"])
    starts = after.groupby("track_id", sort=False).cumcount() < lead
    after = after.assign(valid=~starts.to_numpy() & after.get("valid", True))
    alone = _label(table)
    both = pd.concat([table, after], ignore_index=True)
    both["valid"] = both["valid"].fillna(True).astype(bool)
    together = _label(both)
    together = together[together["scenario_id"].isin(set(table["scenario_id"]))]
    pd.testing.assert_frame_equal(_key(together), _key(alone), check_exact=True)


def test_a_scenario_labels_as_alone_whatever_scenario_follows_it():
    """Drawn WOMD-like tables: one-second blocks summed across a scenario's end into the
    invalid rows that begin the next scenario's first track gave another travel in the last
    bits than the scenario alone (19 of 40 such pairs)."""
    for seed in range(8):
        table = tb.random_trajectories(6, 57, seed=seed, scenarios=2)
        first, second = sorted(table["scenario_id"].unique())
        later = table["scenario_id"] == second
        table["valid"] = ~(later & (table.groupby("track_id").cumcount() < 3 + seed % 7))
        alone = tb.tap(table[table["scenario_id"] == first]).labels("all")
        together = tb.tap(table).labels("all")
        together = together[together["scenario_id"] == first].reset_index(drop=True)
        pd.testing.assert_frame_equal(together, alone, check_exact=True, obj=f"seed {seed}")


@LABELLING
@given(tracks())
def test_labelling_is_deterministic(table):
    pd.testing.assert_frame_equal(_label(table), _label(table))


@LABELLING
@given(tracks())
def test_no_run_shorter_than_one_second_after_the_trace(table):
    seg = tb.tap(table).segments("all")
    later = seg[seg["level"] != "trace"]
    assert ((later["t_end"] - later["t_start"]) >= 1.0 - 1e-9).all()


def _swap(text: str) -> str:
    return text.replace("Left", "\0").replace("Right", "Left").replace("\0", "Right")


@LABELLING
@given(tracks())
def test_mirrored_trajectories_swap_left_and_right(table):
    mirrored = table.assign(y=-table["y"], heading=-table["heading"])
    a, b = _label(table), _label(mirrored)
    assert b["lateral"].tolist() == [_swap(x) for x in a["lateral"]]
    assert b["longitudinal"].tolist() == a["longitudinal"].tolist()


@SETTINGS
@given(st.lists(st.tuples(st.sampled_from(["a", "b", "c10", "c9", "é", "Z"]),
                          st.sampled_from(["1", "2", "10", "x", "ä", "X", "ß"]),
                          st.integers(1, 4)),
                min_size=1, max_size=25), st.sampled_from(["runs", "time-major"]),
       st.sampled_from(["str", "string[python]", "object", "category"]), st.booleans())
def test_the_track_order_is_the_stable_sort_of_every_row(runs, layout, dtype, encoded):
    """Rows grouped by (scenario_id, track_id), in the order of the sorted ids and stable
    within a track, however the input lays them out (runs in any order, a track split over
    several runs, time-major; one scenario or several; ids beyond ASCII; Arrow, Python,
    object or categorical strings; a small table's ids compared by their codes, a large
    one's as strings): the same order as a stable sort of every row's key."""
    from tap_bench import trajectories
    from tap_bench.trajectories import _track_order

    limit = trajectories._ENCODE_ROWS
    trajectories._ENCODE_ROWS = limit if encoded else 0
    try:
        _check_track_order(_track_order, runs, layout, dtype)
    finally:
        trajectories._ENCODE_ROWS = limit


def _check_track_order(_track_order, runs, layout, dtype) -> None:
    if layout == "runs":
        rows = [(sc, tr) for sc, tr, k in runs for _ in range(k)]
    else:
        ids = list(dict.fromkeys((sc, tr) for sc, tr, _ in runs))
        rows = [i for _ in range(3) for i in ids]
    scenario = pd.Series([r[0] for r in rows], dtype=dtype)
    track = pd.Series([r[1] for r in rows], dtype=dtype)
    order, new_track = _track_order(scenario, track)
    order = np.arange(len(rows)) if order is None else order
    sc_codes, _ = pd.factorize(scenario, sort=True)
    tr_codes, tr_uniques = pd.factorize(track, sort=True)
    key = sc_codes.astype(np.int64) * len(tr_uniques) + tr_codes
    expected = np.argsort(key, kind="stable")
    np.testing.assert_array_equal(order, expected)
    np.testing.assert_array_equal(new_track, np.r_[True, key[expected][1:]
                                                   != key[expected][:-1]])


@SETTINGS
@given(st.lists(st.tuples(st.integers(0, 3), st.integers(0, 12), st.integers(1, 12)),
                min_size=1, max_size=12, unique_by=lambda r: r[:2]),
       st.sampled_from(["runs", "time-major"]),
       st.sampled_from(["int", "str", "object", "category", "category-int"]))
def test_validation_orders_any_id_type_as_its_strings(tracks_, layout, dtype):
    """Integer, string, object and categorical ids (one scenario or several, tracks in
    runs or interleaved): the validated table is the stable sort of the rows by the ids'
    strings, whatever the column's type, with those strings as the ids."""
    from tap_bench.trajectories import validate_and_index

    rows = []
    for sc, tr, n in tracks_:
        rows += [(sc, tr, k) for k in range(n)]
    if layout == "time-major":
        rows.sort(key=lambda r: r[2])
    frame = pd.DataFrame(rows, columns=["scenario_id", "track_id", "step"])
    table = pd.DataFrame({"t": frame["step"] * 0.1, "x": frame["step"] * 1.0, "y": 0.0,
                          "heading": 0.0, "speed": 10.0})
    for col in ("scenario_id", "track_id"):
        ids = frame[col]
        table[col] = {"int": ids, "str": ids.astype(str), "object": ids.astype(str)
                      .astype(object), "category": ids.astype(str).astype("category"),
                      "category-int": ids.astype("category")}[dtype]
    checked = validate_and_index(table)
    key = frame["scenario_id"].astype(str) + "\0" + frame["track_id"].astype(str)
    expected = np.argsort(key.to_numpy(dtype=object), kind="stable")
    got = np.arange(len(table)) if checked.order is None else checked.order
    np.testing.assert_array_equal(got, expected)
    out = checked.frame()  # (a categorical of strings stays one)
    assert out["track_id"].astype(str).tolist() == frame["track_id"].astype(str).to_numpy()[
        expected].tolist()
    starts = np.flatnonzero(np.r_[True, key.to_numpy(dtype=object)[expected][1:]
                                  != key.to_numpy(dtype=object)[expected][:-1]])
    np.testing.assert_array_equal(checked.index.track_start[:-1], starts)


def test_a_scenario_labels_as_alone_before_a_scenario_with_no_valid_row():
    """A scenario sorted after this one with no valid row at all: its rows are no block's."""
    table = tb.random_trajectories(4, 57, seed=0, scenarios=1).assign(valid=True)
    alone = tb.tap(table).labels("all")  # its last blocks 7 rows: summed one by one
    empty = table.assign(scenario_id="z-" + table["scenario_id"], valid=False)
    together = tb.tap(pd.concat([table, empty], ignore_index=True)).labels("all")
    pd.testing.assert_frame_equal(together, alone, check_exact=True)
