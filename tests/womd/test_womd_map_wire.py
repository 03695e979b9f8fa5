"""The road map read from a Scenario's wire format in one compiled pass
(:mod:`tap_bench.womd.map_wire`) is the road map protobuf's message objects give
(``roadmap._scenario_road_map``): on the real records, on maps with every kind of feature, on
the wire's freedoms (fields in any order, packed ids, a scalar twice, negative numbers,
unknown fields); what it does not mirror (merged messages, malformed bytes) goes to
protobuf, with protobuf's errors."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from tap_bench.errors import FileFormatError
from tap_bench.womd import proto, roadmap
from tap_bench.womd.map_wire import read_map_wire
from tap_bench.womd.tfrecord import iter_records


def _by_protobuf(data: bytes) -> roadmap.RoadMap:
    return roadmap._scenario_road_map(proto.ScenarioMapPointsView.FromString(data), "<r>")


def _assert_same(a: roadmap.RoadMap, b: roadmap.RoadMap) -> None:
    assert a.scenario_id == b.scenario_id and a.topology == b.topology
    assert a.inferred_links == b.inferred_links
    assert list(a.lanes) == list(b.lanes)
    for lane_id, lane in a.lanes.items():
        other = b.lanes[lane_id]
        assert np.array_equal(lane.centre, other.centre), lane_id
        assert lane.centre.dtype == other.centre.dtype == np.float64
        for name in ("id", "type", "entry", "exit", "left", "right", "width",
                     "width_measured"):
            assert getattr(lane, name) == getattr(other, name), (lane_id, name)
        assert (lane.speed_limit == other.speed_limit
                or (np.isnan(lane.speed_limit) and np.isnan(other.speed_limit)))
    for mine, theirs in ((a.road_edges, b.road_edges), (a.crosswalks, b.crosswalks)):
        assert len(mine) == len(theirs)
        assert all(np.array_equal(p, q) for p, q in zip(mine, theirs, strict=True))
    assert len(a.stop_signs) == len(b.stop_signs)
    for p, q in zip(a.stop_signs, b.stop_signs, strict=True):
        assert p.id == q.id and p.lanes == q.lanes
        assert np.array_equal(p.position, q.position)
    for name in ("lane", "state", "stop_point"):
        mine, theirs = getattr(a.signals, name), getattr(b.signals, name)
        assert mine.dtype == theirs.dtype and np.array_equal(mine, theirs), name


def _real_records() -> list[bytes]:
    root = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
    files = [root / "womd" / "motion_data_one_scenario.tfrecord",
             root / "womd" / "womd_scenario_input.tfrecord",
             root / "womd-dev" / "dev.tfrecord"]
    if not all(f.is_file() for f in files):
        pytest.skip("real WOMD samples not found")
    return [r.data for f in files for r in iter_records(f)]


@pytest.mark.womd
def test_every_real_record_reads_as_protobuf_reads_it():
    records = _real_records()
    assert len(records) >= 10
    for data in records:
        assert read_map_wire(data) is not None  # the compiled reader read it
        _assert_same(roadmap.scenario_road_map(data, source="<r>"), _by_protobuf(data))


# --------------------------------------------------------------- the wire, by hand

def _varint(value: int) -> bytes:
    value &= (1 << 64) - 1
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def _f(number: int, value: int | float | bytes, wire: int | None = None) -> bytes:
    """One field: an int as a varint, a float as a double, bytes length-delimited."""
    if isinstance(value, bytes):
        return _varint(number << 3 | 2) + _varint(len(value)) + value
    if isinstance(value, float) or wire == 1:
        return _varint(number << 3 | 1) + struct.pack("<d", value)
    return _varint(number << 3 | 0) + _varint(value)


def _pt(x: float, y: float, z: float = 0.5, order: str = "xyz") -> bytes:
    values = {"x": (1, x), "y": (2, y), "z": (3, z)}
    return b"".join(_f(values[a][0], float(values[a][1])) for a in order)


def _line(points: list[tuple[float, float]], field: int = 2, order: str = "xyz") -> bytes:
    return b"".join(_f(field, _pt(x, y, order=order)) for x, y in points)


def _scenario(*features: bytes, states: tuple[bytes, ...] = (), sid: str = "s",
              times: int = 5) -> bytes:
    return (b"".join(_f(1, 0.1 * k) for k in range(times)) + _f(5, sid.encode())
            + _f(2, b"\x08\x01")  # a track: not the map's, skipped
            + b"".join(_f(7, s) for s in states) + b"".join(_f(8, f) for f in features))


def _lane_feature(fid: int, pts, *, extra: bytes = b"", speed: float | None = 25.0) -> bytes:
    body = (_f(1, speed) if speed is not None else b"") + _f(2, 2) + _f(3, 0)
    return _f(1, fid) + _f(3, body + _line(pts, field=8) + extra)


def _neighbour(fid: int, a: int, b: int, c: int, d: int) -> bytes:
    return _f(1, fid) + _f(2, a) + _f(3, b) + _f(4, c) + _f(5, d)


def _boundary(a: int, b: int, fid: int, kind: int = 6) -> bytes:
    return _f(1, a) + _f(2, b) + _f(3, fid) + _f(4, kind)


def _lane_state(lane: int, state: int, stop: tuple[float, float] | None = (3.0, 4.0)) -> bytes:
    return _f(1, lane) + _f(2, state) + (_f(3, _pt(*stop)) if stop else b"")


STRAIGHT = [(float(x), 0.0) for x in range(12)]
BESIDE = [(float(x), 3.6) for x in range(12)]
LINE = [(float(x) + 0.5, 1.8) for x in range(12)]


def _full_map(**changes: bytes) -> bytes:
    lane_a = _lane_feature(
        10, STRAIGHT,
        extra=(_f(9, 7) + _f(9, 8) + _f(10, 11) + _f(11, _neighbour(11, 0, 11, 0, 11))
               + _f(13, _boundary(0, 11, 30)) + _f(14, _boundary(2, 9, 31))))
    lane_b = _lane_feature(11, BESIDE, speed=None,
                           extra=_f(9, 10) + _f(12, _neighbour(10, 0, 11, 0, 11)))
    features = {
        "lane_a": lane_a, "lane_b": lane_b,
        "line": _f(1, 30) + _f(4, _f(1, 6) + _line(LINE)),
        "line2": _f(1, 31) + _f(4, _line([(x, -1.9) for x, _ in LINE])),
        "edge": _f(1, 40) + _f(5, _f(1, 1) + _line([(x, -6.0) for x, _ in STRAIGHT])),
        "short_edge": _f(1, 41) + _f(5, _line([(0.0, 9.0)])),
        "crosswalk": _f(1, 50) + _f(8, _line([(3.0, -3.0), (5.0, -3.0), (5.0, 6.0),
                                              (3.0, 6.0)], field=1)),
        "stop": _f(1, 60) + _f(7, _f(1, 10) + _f(1, 11) + _f(2, _pt(11.0, 0.0))),
        "speed_bump": _f(1, 70) + _f(9, _line([(1.0, 1.0)] * 4, field=1)),
    }
    features.update(changes)
    states = tuple(_f(1, _lane_state(10, 4 if k < 3 else 6)) + _f(1, _lane_state(11, k % 9))
                   for k in range(5))
    return _scenario(*[f for f in features.values() if f], states=states)


CASES = {
    "every kind": {},
    "fields in another order": {
        "lane_a": _f(3, _line(STRAIGHT, field=8, order="zyx") + _f(10, 11) + _f(9, 7)
                     + _f(9, 8) + _f(2, 1) + _f(1, 30.0)) + _f(1, 10)},
    "packed ids, a negative type and index": {
        "lane_a": _f(1, 10) + _f(3, _f(2, -1) + _line(STRAIGHT, field=8)
                                 + _f(9, _varint(7) + _varint(8) + _varint(2**40))
                                 + _f(11, _neighbour(11, -5, 11, 0, 11)))},
    "a scalar twice keeps the last": {
        "lane_b": _f(1, 99) + _f(3, _f(2, 1) + _f(2, 3) + _line(BESIDE, field=8)) + _f(1, 11)},
    "negative and large ids": {
        "line": _f(1, -30) + _f(4, _line(LINE)),
        "lane_b": _f(1, 2**62) + _f(3, _line(BESIDE, field=8) + _f(9, -4))},
    "points with fields missing or twice": {
        "line": _f(1, 30) + _f(4, _line(LINE, order="yx") + _f(2, _pt(1, 2, order="xyxz"))
                                + _f(2, b""))},
    "unknown fields everywhere": {
        "lane_a": _f(1, 10) + _f(3, _line(STRAIGHT, field=8) + _f(20, 5) + _f(21, b"xx")
                                 + _f(13, _boundary(0, 11, 30) + _f(9, 1)))
                  + _f(15, 3.5) + _f(16, b"abc")},
    "no map": {name: b"" for name in ("lane_a", "lane_b", "line", "line2", "edge",
                                      "short_edge", "crosswalk", "stop", "speed_bump")},
    "an empty lane": {"lane_b": _f(1, 11) + _f(3, b"")},
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_map_reads_as_protobuf_reads_it(case):
    data = _full_map(**CASES[case])
    assert read_map_wire(data) is not None
    _assert_same(roadmap.scenario_road_map(data, source="<r>"), _by_protobuf(data))


def test_the_signals_keep_first_stop_points_and_a_steps_last_state():
    states = (_f(1, _lane_state(5, 4)) + _f(1, _lane_state(9, 12, None))
              + _f(1, _lane_state(5, 6, (7.0, 8.0))),
              _f(2, b"\x01") + _f(1, _lane_state(9, 3)) + _f(1, _lane_state(-2, 1)))
    data = _scenario(_lane_feature(1, STRAIGHT), states=states, times=1)
    road = roadmap.scenario_road_map(data, source="<r>")
    _assert_same(road, _by_protobuf(data))
    assert road.signals.lane.tolist() == [5, 9, -2]
    assert road.signals.state.tolist() == [[6, 0, 0], [0, 3, 1]]
    assert road.signals.stop_point.tolist() == [[3.0, 4.0], [0.0, 0.0], [3.0, 4.0]]


LEFT_TO_PROTOBUF = {
    "a lane twice (merged)": _f(1, 1) + _f(3, _line(STRAIGHT, field=8)) + _f(3, _f(2, 2)),
    "a lane and a line": _f(1, 1) + _f(3, _line(STRAIGHT, field=8)) + _f(4, _line(LINE)),
    "entry lanes split by exit lanes": _f(1, 1) + _f(3, _line(STRAIGHT, field=8) + _f(9, 2)
                                                  + _f(10, 3) + _f(9, 4)),
    "a type as a double": _f(1, 1) + _f(3, _f(2, 1.0, wire=1) + _line(STRAIGHT, field=8)),
    "left neighbours split by a right one": _f(1, 1) + _f(3, _line(STRAIGHT, field=8)
                                                       + _f(11, _neighbour(2, 0, 11, 0, 11))
                                                       + _f(12, _neighbour(2, 0, 11, 0, 11))
                                                       + _f(11, _neighbour(2, 0, 11, 0, 11))),
    "left boundaries split by a right one": _f(1, 1) + _f(3, _line(STRAIGHT, field=8)
                                                       + _f(13, _boundary(0, 5, 30))
                                                       + _f(14, _boundary(0, 11, 31))
                                                       + _f(13, _boundary(5, 11, 32))),
}


@pytest.mark.parametrize("case", sorted(LEFT_TO_PROTOBUF))
def test_what_the_reader_does_not_mirror_is_read_by_protobuf(case):
    data = _scenario(LEFT_TO_PROTOBUF[case], _lane_feature(2, BESIDE))
    assert read_map_wire(data) is None
    _assert_same(roadmap.scenario_road_map(data, source="<r>"), _by_protobuf(data))


@pytest.mark.parametrize("cut", [1, 7, 40, -3, -1])
def test_malformed_bytes_get_protobufs_error(cut):
    data = _full_map()[:cut]
    assert read_map_wire(data) is None
    with pytest.raises(FileFormatError, match="not a serialized WOMD Scenario proto"):
        roadmap.scenario_road_map(data, source="<r>")
