"""The writer and the Scenario reader: lossless round trips of the contract's columns, and
the numpy state codecs against protobuf's own."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tap_bench.errors import TrajectoryTableError
from tap_bench.sources.ingest import read_womd
from tap_bench.womd import proto
from tap_bench.womd.scenario import StateDecodeError, decode_object_states
from tap_bench.womd.tfrecord import iter_records
from tap_bench.womd.writer import DEFAULT_BOX, encode_scenarios, write_womd

F32 = st.floats(-1e4, 1e4, allow_nan=False, width=32)
VELOCITY = st.floats(-70.0, 70.0, allow_nan=False, width=32)
"""A velocity component [m/s]: hypot of two stays under the contract's 100 m/s."""


@st.composite
def trajectory_tables(draw):
    """Tables of 1-3 scenarios, 1-4 tracks, 1-25 steps at 10 Hz with invalid steps, ids that
    are WOMD ints or free strings, float32-exact heading and velocity, extra columns."""
    rows = []
    for s in range(draw(st.integers(1, 3))):
        n_steps = draw(st.integers(1, 25))
        t0 = draw(st.sampled_from([0.0, 1.5, 100.0]))
        t = t0 + np.arange(n_steps) / 10
        n_tracks = draw(st.integers(1, 4))
        if draw(st.booleans()):
            ids = [str(i) for i in draw(st.lists(st.integers(-2**31, 2**31 - 1),
                                                 min_size=n_tracks, max_size=n_tracks,
                                                 unique=True))]
        else:
            ids = draw(st.lists(st.text("abcXYZ-_ é0123456789", min_size=1, max_size=6),
                                min_size=n_tracks, max_size=n_tracks, unique=True))
        ego = draw(st.integers(-1, n_tracks - 1))
        for k, track_id in enumerate(ids):
            kind = draw(st.sampled_from(["vehicle", "pedestrian", "cyclist", "other"]))
            policy = draw(st.sampled_from(["idm", "ppo"]))
            for i in range(n_steps):
                valid = draw(st.booleans()) if i % 3 == 0 else True
                x = draw(st.floats(-1e5, 1e5, allow_nan=False))
                rows.append({
                    "scenario_id": f"scenario-{s}", "track_id": track_id, "t": t[i],
                    "x": x if valid else np.nan, "y": draw(st.floats(-1e5, 1e5)) if valid
                    else np.nan,
                    "heading": draw(st.floats(-3.0, 3.0, width=32)),
                    "vx": draw(VELOCITY), "vy": draw(VELOCITY), "valid": valid,
                    "object_type": kind,
                    "is_ego": k == ego, "source": "highway-env", "policy": policy,
                    "seed": s, "crashed": i == n_steps - 1 and k == 0,
                })
    table = pd.DataFrame(rows)
    table["speed"] = np.hypot(table["vx"], table["vy"])
    return table


def expected(table):
    out = table.copy()
    for column in ("x", "y", "heading", "vx", "vy", "speed"):
        out.loc[~out["valid"], column] = np.nan
    return out


def compare(written, read, columns):
    key = ["scenario_id", "track_id", "t"]
    a = expected(written).sort_values(key).reset_index(drop=True)
    b = read.sort_values(key).reset_index(drop=True)
    assert len(a) == len(b)
    for column in columns:
        left, right = a[column].to_numpy(), b[column].to_numpy()
        if left.dtype.kind == "f":
            np.testing.assert_array_equal(left, right.astype(np.float64), err_msg=column)
        else:
            assert left.tolist() == right.tolist(), column


CONTRACT = ("scenario_id", "track_id", "t", "x", "y", "heading", "speed", "valid", "vx",
            "vy", "object_type", "is_ego", "source", "policy", "seed", "crashed")


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(table=trajectory_tables(), compress=st.booleans())
def test_round_trip_is_lossless_for_the_contract_columns(tmp_path, table, compress):
    path = write_womd(table, tmp_path / "rt.tfrecord", compress=compress)
    compare(table, read_womd(path), CONTRACT)


def test_round_trip_of_a_hand_made_table(tmp_path, two_cars_and_a_walker):
    table = two_cars_and_a_walker
    path = write_womd(table, tmp_path / "fixture.tfrecord")
    back = read_womd(path)
    compare(table, back, ("scenario_id", "track_id", "t", "x", "y", "valid", "is_ego",
                          "object_type"))
    assert back.loc[back["is_ego"], "track_id"].unique().tolist() == ["100"]
    assert back.groupby("scenario_id")["track_id"].nunique().to_dict() == {"s1": 3, "s2": 1}


def test_missing_steps_come_back_as_invalid_rows(tmp_path, two_cars_and_a_walker):
    table = two_cars_and_a_walker
    gappy = table[~((table["track_id"] == "7") & ~table["valid"])]  # drop the gap rows
    back = read_womd(write_womd(gappy, tmp_path / "gap.tfrecord"))
    car = back[back["track_id"] == "7"].sort_values("t")
    assert len(car) == 20
    assert car["valid"].tolist() == [not 5 <= i < 10 for i in range(20)]
    assert car.loc[~car["valid"], "x"].isna().all()


def test_table_without_velocity_is_written_from_speed_and_heading(tmp_path,
                                                                  two_cars_and_a_walker):
    table = two_cars_and_a_walker.drop(columns=["vx", "vy"])
    back = read_womd(write_womd(table, tmp_path / "v.tfrecord"))
    back = back.sort_values(["scenario_id", "track_id", "t"]).reset_index(drop=True)
    ref = expected(two_cars_and_a_walker).sort_values(["scenario_id", "track_id", "t"]
                                                      ).reset_index(drop=True)
    np.testing.assert_allclose(back["speed"], ref["speed"], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(back["vy"], ref["vy"], rtol=1e-6, atol=1e-6)


def test_writer_bytes_are_what_protobuf_reads(two_cars_and_a_walker):
    _, record = next(encode_scenarios(two_cars_and_a_walker))
    scenario = proto.Scenario.FromString(record)
    assert scenario.scenario_id == "s1"
    assert [t.id for t in scenario.tracks] == [100, 7, 8]
    assert scenario.sdc_track_index == 0
    walker = scenario.tracks[2]
    assert walker.object_type == proto.Track.TYPE_PEDESTRIAN
    assert len(walker.states) == 20
    assert walker.states[10].center_y == pytest.approx(2.2)
    assert walker.states[10].velocity_y == pytest.approx(1.2)
    gap = scenario.tracks[1].states[6]
    assert not gap.valid and gap.center_x == 0.0
    # Re-serialised by protobuf, the same scenario reads back the same.
    again = proto.Scenario.FromString(scenario.SerializeToString()).SerializeToString()
    assert again == scenario.SerializeToString()


def test_two_ego_tracks_are_refused_and_nothing_is_written(tmp_path, two_cars_and_a_walker):
    table = two_cars_and_a_walker.copy()
    table.loc[table["track_id"] == "8", "is_ego"] = True
    target = tmp_path / "bad.tfrecord"
    with pytest.raises(TrajectoryTableError, match="2 tracks with is_ego=True"):
        write_womd(table, target)
    assert list(tmp_path.iterdir()) == []


def test_records_from_the_writer_frame_one_scenario_each(tmp_path, two_cars_and_a_walker):
    path = write_womd(two_cars_and_a_walker, tmp_path / "f.tfrecord.gz", compress=True)
    assert [proto.Scenario.FromString(r.data).scenario_id
            for r in iter_records(path)] == ["s1", "s2"]


# --- the numpy ObjectState decoder against protobuf ------------------------------------

STATE = st.fixed_dictionaries({}, optional={
    "center_x": st.floats(allow_nan=False), "center_y": st.floats(allow_nan=False),
    "center_z": st.floats(allow_nan=False), "length": F32, "width": F32, "height": F32,
    "heading": F32, "velocity_x": F32, "velocity_y": F32, "valid": st.booleans()})


@settings(max_examples=60, deadline=None)
@given(states=st.lists(st.lists(STATE, min_size=1, max_size=3), min_size=1, max_size=80),
       unknown=st.lists(st.tuples(st.integers(12, 3000), st.binary(max_size=200)),
                        max_size=3))
def test_state_decoder_agrees_with_protobuf(states, unknown):
    """Any subset of fields, fields repeated by concatenating messages (the last wins),
    unknown fields of any length."""
    blobs = []
    for parts in states:
        blob = b"".join(proto.ObjectState(**p).SerializeToString() for p in parts)
        for number, payload in unknown:
            blob += _field(number, payload)
        blobs.append(blob)
    got = decode_object_states(b"".join(blobs), np.array([len(b) for b in blobs]))
    for i, blob in enumerate(blobs):
        ref = proto.ObjectState.FromString(blob)
        for name, field in (("x", "center_x"), ("y", "center_y"), ("z", "center_z")):
            assert got[name][i] == getattr(ref, field), (name, i)
        for name, field in (("length", "length"), ("width", "width"), ("height", "height"),
                            ("heading", "heading"), ("vx", "velocity_x"),
                            ("vy", "velocity_y")):  # float fields: protobuf hands out doubles
            assert float(got[name][i]) == getattr(ref, field), (name, i)
        assert got["valid"][i] == ref.valid


def test_uniform_and_generic_paths_agree():
    full = proto.ObjectState(center_x=1.5, center_y=-2.0, center_z=0.25, length=4.0,
                             width=2.0, height=1.5, heading=0.5, velocity_x=3.0,
                             velocity_y=-1.0, valid=True).SerializeToString()
    odd = proto.ObjectState(center_x=9.0, valid=True).SerializeToString() + \
        proto.ObjectState(center_x=7.0).SerializeToString()  # x repeated: the last wins
    blobs = [full] * 40 + [odd] + [full] * 40  # 80 uniform states and a stray one
    got = decode_object_states(b"".join(blobs), np.array([len(b) for b in blobs]))
    assert got["x"][40] == 7.0 and got["valid"][40] and got["vx"][40] == 0
    assert (got["x"][:40] == 1.5).all() and (got["vy"][41:] == -1.0).all()


def test_malformed_state_bytes_name_the_state():
    good = proto.ObjectState(center_x=1.0, valid=True).SerializeToString()
    bad = b"\x11\x00\x00"  # a double announced, three bytes given
    with pytest.raises(StateDecodeError) as info:
        decode_object_states(good + bad + good, np.array([len(good), len(bad), len(good)]))
    assert info.value.state == 1


def _field(number: int, payload: bytes) -> bytes:
    def varint(value):
        out = bytearray()
        while True:
            byte, value = value & 0x7F, value >> 7
            out.append(byte | (0x80 if value else 0))
            if not value:
                return bytes(out)

    return varint(number << 3 | 2) + varint(len(payload)) + payload


def test_a_table_without_box_sizes_reads_back_with_each_types_typical_box(
        tmp_path, two_cars_and_a_walker):
    # the readers refuse a valid state without a positive box: the writer gives one
    table = two_cars_and_a_walker.drop(columns=[c for c in ("length", "width", "height")
                                                if c in two_cars_and_a_walker.columns])
    back = read_womd(write_womd(table, tmp_path / "boxes.tfrecord"))
    valid = back[back["valid"]]
    for kind, group in valid.groupby("object_type"):
        length, width, height = DEFAULT_BOX[kind]
        np.testing.assert_allclose(group["length"], length, rtol=1e-6)
        np.testing.assert_allclose(group["width"], width, rtol=1e-6)
        np.testing.assert_allclose(group["height"], height, rtol=1e-6)
    assert set(valid["object_type"]) >= {"vehicle", "pedestrian"}
