"""The real WOMD samples in ../shared/data/womd: counts from their README, field-by-field
agreement with protobuf's own decoding, velocities against positions, and the three
readers against each other."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tap_bench.sources.ingest import read_womd
from tap_bench.trajectories import validate_trajectories
from tap_bench.womd import proto
from tap_bench.womd.scenario import decode_scenario
from tap_bench.womd.tf_example import decode_tf_example
from tap_bench.womd.tfrecord import iter_records

pytestmark = pytest.mark.womd

ONE_SCENARIO = "motion_data_one_scenario.tfrecord"
SCENARIO_INPUT = "womd_scenario_input.tfrecord"
ONE_EXAMPLE = "motion_data_one_example.tfrecord"
PICKLE = "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl"


def tracks_by_type(table):
    return table.groupby("object_type")["track_id"].nunique().to_dict()


def fully_valid(table, kind):
    rows = table[table["object_type"] == kind]
    return int(rows.groupby("track_id")["valid"].all().sum())


def test_one_scenario_counts_match_the_readme(womd_dir):
    table = read_womd(womd_dir / ONE_SCENARIO)
    assert table["scenario_id"].unique().tolist() == ["637f20cafde22ff8"]
    assert table["track_id"].nunique() == 83
    assert tracks_by_type(table) == {"vehicle": 70, "pedestrian": 10, "cyclist": 3}
    assert fully_valid(table, "vehicle") == 21
    assert table.groupby("track_id").size().eq(91).all()
    scenario = proto.Scenario.FromString(next(iter_records(womd_dir / ONE_SCENARIO)).data)
    assert scenario.sdc_track_index == 82
    ego = table.loc[table["is_ego"], "track_id"].unique().tolist()
    assert ego == [str(scenario.tracks[82].id)]
    predicted = table.loc[table["track_to_predict"], "track_id"].unique()
    assert sorted(predicted) == sorted(str(scenario.tracks[r.track_index].id)
                                       for r in scenario.tracks_to_predict)
    assert (table["source"] == "womd").all()


def test_scenario_input_counts_and_time_step(womd_dir):
    table = read_womd(womd_dir / SCENARIO_INPUT)
    assert table["scenario_id"].unique().tolist() == ["ee519cf571686d19"]
    assert tracks_by_type(table) == {"vehicle": 189, "pedestrian": 68}
    assert fully_valid(table, "vehicle") == 9
    t = np.sort(table["t"].unique())
    assert len(t) == 91
    assert np.diff(t).mean() == pytest.approx(0.1002, abs=5e-4)
    interest = table.loc[table["object_of_interest"], "track_id"].unique()
    assert sorted(interest) == ["2694", "625"]


@pytest.mark.parametrize("name", [ONE_SCENARIO, SCENARIO_INPUT])
def test_every_state_matches_protobufs_own_decoding(womd_dir, name):
    record = next(iter_records(womd_dir / name))
    table = decode_scenario(record).to_pandas()
    scenario = proto.Scenario.FromString(record.data)
    states = [s for track in scenario.tracks for s in track.states]
    valid = np.array([s.valid for s in states])
    np.testing.assert_array_equal(table["valid"], valid)
    for column, field in (("x", "center_x"), ("y", "center_y"), ("z", "center_z"),
                          ("vx", "velocity_x"), ("vy", "velocity_y"), ("length", "length")):
        expected = np.array([getattr(s, field) for s in states], dtype=np.float64)
        if field in ("velocity_x", "velocity_y", "length"):
            expected = expected.astype(np.float32).astype(np.float64)
        np.testing.assert_array_equal(table[column].to_numpy()[valid], expected[valid])
        assert np.isnan(table[column].to_numpy()[~valid]).all()
    heading = np.array([s.heading for s in states], dtype=np.float32).astype(np.float64)
    # Same direction; those beyond pi were wrapped into [-pi, pi).
    assert np.allclose(np.cos(table["heading"])[valid], np.cos(heading[valid]), atol=1e-6)
    assert np.allclose(np.sin(table["heading"])[valid], np.sin(heading[valid]), atol=1e-6)
    assert (np.abs(table["heading"][valid]) <= np.pi).all()


@pytest.mark.parametrize("name", [ONE_SCENARIO, SCENARIO_INPUT, ONE_EXAMPLE, PICKLE])
def test_tables_pass_the_trajectory_contract(womd_dir, name):
    table = read_womd(womd_dir / name)
    clean = validate_trajectories(table)
    assert len(clean) == len(table)
    assert table.loc[~table["valid"], ["x", "y", "speed"]].isna().all().all()


def finite_difference_speed(table):
    """(speed from vx, vy; speed from consecutive positions) on pairs of valid steps of
    moving vehicles."""
    out_v, out_fd = [], []
    for _, track in table[table["object_type"] == "vehicle"].groupby(["scenario_id",
                                                                      "track_id"]):
        track = track.sort_values("t")
        ok = track["valid"].to_numpy()
        pair = ok[1:] & ok[:-1]
        dt = np.diff(track["t"].to_numpy())
        fd = np.hypot(np.diff(track["x"].to_numpy()), np.diff(track["y"].to_numpy())) / dt
        v = 0.5 * (track["speed"].to_numpy()[1:] + track["speed"].to_numpy()[:-1])
        moving = pair & (v > 3.0)
        out_v.append(v[moving])
        out_fd.append(fd[moving])
    return np.concatenate(out_v), np.concatenate(out_fd)


@pytest.mark.parametrize("name", [ONE_SCENARIO, SCENARIO_INPUT, ONE_EXAMPLE, PICKLE])
def test_speed_from_velocity_agrees_with_positions(womd_dir, name):
    v, fd = finite_difference_speed(read_womd(womd_dir / name))
    assert len(v) > 200
    error = np.abs(v - fd)
    # WOMD positions carry centimetre noise: a few percent at 10 Hz. Velocities read from
    # the wrong field or the wrong track would be off by metres per second.
    assert np.median(error / v) < 0.03
    assert np.quantile(error, 0.9) < 0.6  # m/s


def test_scenario_and_tf_example_readers_agree_on_the_same_kind_of_data(womd_dir):
    scenario = read_womd(womd_dir / ONE_SCENARIO)
    example = read_womd(womd_dir / ONE_EXAMPLE)
    assert list(scenario.columns) == list(example.columns)
    assert (scenario.dtypes == example.dtypes).all()
    for table in (scenario, example):
        assert table.groupby("track_id").size().eq(91).all()
        t = np.sort(table["t"].unique())
        assert t[0] == 0.0
        assert np.diff(t) == pytest.approx(0.1, abs=2e-3)
        assert table.loc[table["is_ego"], "track_id"].nunique() == 1
        assert set(table["object_type"]) <= {"vehicle", "pedestrian", "cyclist", "other"}


def test_tf_example_layout_matches_a_scenario_laid_out_by_hand(womd_dir):
    """Lay the real Scenario out as a motion tf.Example (10 past, 1 current, 80 future,
    agent-major, padded to 128 slots) and read it back."""
    from tap_bench.womd.tf_example import Example
    from tap_bench.womd.tfrecord import Record

    record = next(iter_records(womd_dir / ONE_SCENARIO))
    table = decode_scenario(record).to_pandas()
    scenario = proto.Scenario.FromString(record.data)
    n_slots, parts = 128, {"past": slice(0, 10), "current": slice(10, 11),
                           "future": slice(11, 91)}
    example = Example()
    features = example.features.feature
    features["scenario/id"].bytes_list.value.append(scenario.scenario_id.encode())
    tracks = list(scenario.tracks)
    pad = n_slots - len(tracks)
    ids = [t.id for t in tracks] + [-1] * pad
    features["state/id"].float_list.value.extend(ids)
    features["state/type"].float_list.value.extend([t.object_type for t in tracks] + [-1] * pad)
    features["state/is_sdc"].int64_list.value.extend(
        [int(i == scenario.sdc_track_index) for i in range(len(tracks))] + [0] * pad)
    times = np.array(scenario.timestamps_seconds)
    for part, steps in parts.items():
        n = steps.stop - steps.start

        def put(key, values, kind="float_list", part=part, n=n):
            getattr(features[f"state/{part}/{key}"], kind).value.extend(values)

        for key, field in (("x", "center_x"), ("y", "center_y"), ("z", "center_z"),
                           ("bbox_yaw", "heading"), ("velocity_x", "velocity_x"),
                           ("velocity_y", "velocity_y"), ("length", "length"),
                           ("width", "width"), ("height", "height")):
            put(key, [getattr(s, field) for t in tracks for s in t.states[steps]]
                + [-1.0] * (pad * n))
        put("valid", [int(s.valid) for t in tracks for s in t.states[steps]] + [0] * (pad * n),
            "int64_list")
        put("timestamp_micros", [round(x * 1e6) for _ in tracks for x in times[steps]]
            + [-1] * (pad * n), "int64_list")
    got = decode_tf_example(Record("made.tfrecord", 0, 0, example.SerializeToString())
                            ).to_pandas()
    assert len(got) == len(table)
    for column in ("scenario_id", "track_id", "object_type", "valid", "is_ego"):
        assert got[column].tolist() == table[column].tolist()
    np.testing.assert_allclose(got["t"], table["t"], atol=1e-6)
    for column in ("x", "y", "heading", "speed", "vx", "vy"):  # float32 in a tf.Example
        np.testing.assert_allclose(got[column], table[column], rtol=1e-6, atol=1e-3)


def test_scenarionet_pickle(womd_dir):
    table = read_womd(womd_dir / PICKLE)
    assert table["scenario_id"].unique().tolist() == ["eb4b91b10ca94ff2"]
    assert tracks_by_type(table) == {"vehicle": 45}
    assert table.groupby("track_id").size().eq(199).all()
    assert table.loc[table["is_ego"], "track_id"].unique().tolist() == ["51"]
    assert sorted(table.loc[table["object_of_interest"], "track_id"].unique()) == ["11", "17"]
    assert (table["source"] == "womd").all()


def test_object_type_filter_keeps_only_those_tracks(womd_dir):
    everything = read_womd(womd_dir / ONE_SCENARIO)
    vehicles = read_womd(womd_dir / ONE_SCENARIO, object_types="vehicle")
    assert set(vehicles["object_type"]) == {"vehicle"}
    expected = everything[everything["object_type"] == "vehicle"].reset_index(drop=True)
    pd.testing.assert_frame_equal(vehicles, expected)


def test_auto_format_reads_all_four_files(womd_dir):
    table = read_womd([womd_dir / "*.tfrecord", womd_dir / "*.pkl"])
    assert table["scenario_id"].nunique() == 4
