"""Map points read in bulk (:func:`tap_bench.womd.roadmap.map_point_lists`): the same x, y
as protobuf reads point by point, whatever the fields' order or presence."""

from __future__ import annotations

import numpy as np
import pytest
from google.protobuf.message import DecodeError

from tap_bench.womd import proto
from tap_bench.womd.roadmap import map_point_lists, map_points, scenario_road_map, split_rows


def _point(x: float, y: float, z: float, order: str = "xyz") -> bytes:
    """A MapPoint serialized with one field per letter of ``order``, in that order (a
    letter twice: the field twice; a letter left out: the field absent)."""
    values = {"x": x, "y": y, "z": z}
    return b"".join(proto.MapPointView(**{axis: values[axis]}).SerializeToString()
                    for axis in order)


def _protobuf(points: list[bytes]) -> np.ndarray:
    return np.array([(p.x, p.y) for p in map(proto.MapPointView.FromString, points)],
                    dtype=float).reshape(-1, 2)


@pytest.mark.parametrize("order", ["xyz", "zyx", "yx", "xy", "x", "z", "xyzx", "yxz"])
def test_points_equal_protobufs_in_every_field_order(order):
    rng = np.random.default_rng(len(order))
    points = [_point(*rng.normal(0, 1e4, 3), order=order) for _ in range(30)]
    assert np.array_equal(map_points(points), _protobuf(points))


def test_lists_of_mixed_layouts_are_each_read_as_protobuf_reads_them():
    rng = np.random.default_rng(5)
    lists = [[_point(*rng.normal(0, 100, 3), order=order) for _ in range(n)]
             for order, n in (("xyz", 4), ("zyx", 3), ("xy", 0), ("xyz", 6), ("yxzy", 2))]
    lists[3][2] = _point(1.5, -2.5, 0.0, order="xy")  # one point unlike the others
    got = map_point_lists(lists)
    assert [len(g) for g in got] == [4, 3, 0, 6, 2]
    for points, xy in zip(lists, got, strict=True):
        assert np.array_equal(xy, _protobuf(points))
    assert got[3][2].tolist() == [1.5, -2.5]


def test_a_damaged_point_is_a_decode_error():
    with pytest.raises(DecodeError):
        map_points([b"\x09\x00\x00"])  # a double cut short


def test_a_road_map_reads_its_lanes_lines_and_edges_in_bulk():
    view = proto.ScenarioMapView(scenario_id="s")
    lane = view.map_features.add(id=7)
    for x in range(5):
        lane.lane.polyline.add(x=float(x), y=2.0 * x, z=1.0)
    lane.lane.right_boundaries.add(lane_start_index=0, lane_end_index=4,
                                   boundary_feature_id=8)
    line = view.map_features.add(id=8)
    for x in range(5):
        line.road_line.polyline.add(y=2.0 * x - 1.5, x=float(x) + 0.5)
    edge = view.map_features.add(id=9)
    for x in range(3):
        edge.road_edge.polyline.add(x=float(x), y=-9.0)
    road = scenario_road_map(view.SerializeToString())
    assert road.lanes[7].centre.tolist() == [[float(x), 2.0 * x] for x in range(5)]
    assert len(road.road_edges) == 1 and road.road_edges[0][:, 1].tolist() == [-9.0] * 3
    assert road.lanes[7].width_measured


@pytest.mark.parametrize("counts", [[], [0], [3], [2, 0, 5, 1], [0, 0], list(range(40))])
def test_split_rows_is_numpys_split_at_the_counts(counts):
    values = np.arange(2 * sum(counts), dtype=float).reshape(-1, 2)
    got = split_rows(values, counts)
    want = np.split(values, np.cumsum(counts)[:-1]) if counts else []
    assert len(got) == len(want) == len(counts)
    for g, w, n in zip(got, want, counts, strict=True):
        assert g.shape == w.shape == (n, 2) and np.array_equal(g, w)
        assert g.base is values or g.base is values.base  # views, as numpy's


def test_lane_centres_lose_their_non_finite_points_as_each_alone():
    from tap_bench.womd.roadmap import _finite_rows

    rng = np.random.default_rng(5)
    lines = []
    for k in range(30):
        line = rng.normal(0, 10, (int(rng.integers(0, 9)), 2))
        if k % 3 == 0 and len(line):
            line[rng.integers(0, len(line), 2), rng.integers(0, 2, 2)] = \
                [np.nan, np.inf][k % 2]
        lines.append(line.tolist() if k % 4 == 0 else line)
    lines.append(np.full((3, 2), np.nan))
    got = _finite_rows(lines)
    for line, cleaned in zip(lines, got, strict=True):
        alone = np.asarray(line, dtype=float).reshape(-1, 2)
        alone = alone[np.isfinite(alone).all(axis=1)]
        assert cleaned.shape == alone.shape and np.array_equal(cleaned, alone)
    assert _finite_rows([]) == [] and got[-1].shape == (0, 2)
