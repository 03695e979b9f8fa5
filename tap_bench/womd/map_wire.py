"""A serialized WOMD ``Scenario``'s map read straight from its wire format, in one compiled
pass: what :func:`tap_bench.womd.roadmap.scenario_road_map` reads through protobuf's
message objects (:data:`tap_bench.womd.proto.ScenarioMapPointsView`), as flat arrays.

The field numbers are those of WOMD's ``scenario.proto`` and ``map.proto`` (proto2), the
same as :mod:`tap_bench.womd.proto` declares:

- ``Scenario``: timestamps_seconds 1 (repeated double), scenario_id 5 (string),
  dynamic_map_states 7, map_features 8;
- ``MapFeature``: id 1 (int64), lane 3, road_line 4, road_edge 5, stop_sign 7, crosswalk 8;
- ``LaneCenter``: speed_limit_mph 1 (double), type 2 (enum), interpolating 3 (bool),
  polyline 8, entry_lanes 9, exit_lanes 10 (repeated int64), left_neighbors 11,
  right_neighbors 12, left_boundaries 13, right_boundaries 14;
- ``LaneNeighbor``: feature_id 1 (int64), self_start_index 2, self_end_index 3,
  neighbor_start_index 4, neighbor_end_index 5 (int32);
- ``BoundarySegment``: lane_start_index 1, lane_end_index 2 (int32), boundary_feature_id 3
  (int64), boundary_type 4 (enum);
- ``RoadLine`` / ``RoadEdge``: type 1, polyline 2; ``Crosswalk``: polygon 1;
  ``StopSign``: lane 1 (repeated int64), position 2;
- ``MapPoint``: x 1, y 2, z 3 (double);
- ``DynamicMapState``: lane_states 1; ``TrafficSignalLaneState``: lane 1 (int64), state 2
  (enum), stop_point 3.

The reader follows protobuf's rules where a well-formed file can differ from another
(fields in any order, a scalar met twice keeps its last value, absent fields are 0, repeated
integers packed or not, unknown fields skipped, int32 values truncated to 32 bits). What it
does not mirror it refuses, and the caller reads the record with protobuf instead: bytes
that are not well formed (protobuf then names the error), a known field of another wire
type, a message field met twice in one message (protobuf merges them), a feature with more
than one kind, a list of points or ids split by another field, groups.
"""

from __future__ import annotations

import numba
import numpy as np
from numba.core import types
from numba.extending import intrinsic

__all__ = ["FEATURE_KINDS", "MapWire", "read_map_wire"]

FEATURE_KINDS = ("none", "lane", "road_line", "road_edge", "crosswalk", "stop_sign")
"""The kind numbers of :attr:`MapWire.kind`: a feature's first present field among lane,
road_line, road_edge, crosswalk, stop_sign (none: a feature of another kind)."""

_LANE, _ROAD_LINE, _ROAD_EDGE, _CROSSWALK, _STOP_SIGN = 1, 2, 3, 4, 5

# the columns of the per-feature integer table
(_F_ID, _F_KIND, _F_PTS0, _F_PTS1, _F_TYPE, _F_HAS_SPEED, _F_ENTRY0, _F_ENTRY1, _F_EXIT0,
 _F_EXIT1, _F_LEFT0, _F_LEFT1, _F_RIGHT0, _F_RIGHT1, _F_LB0, _F_LB1, _F_RB0, _F_RB1,
 _F_STOP0, _F_STOP1) = range(20)
_F_COLUMNS = 20
_BAD = -1


class MapWire:
    """The map of one serialized Scenario as arrays (:func:`read_map_wire`).

    Attributes:
        scenario_id: the scenario's id.
        n_timestamps: entries of ``timestamps_seconds``.
        n_map_states: entries of ``dynamic_map_states``.
        features: (n_features, 20) int64 per map feature, in the record's order: id, kind
            (:data:`FEATURE_KINDS`), points [start, end) in ``points``, the lane's type and
            whether it has a speed limit, then [start, end) of its entry lanes, exit lanes
            (in ``ids``), left and right neighbours (in ``neighbours``), left and right
            boundaries (in ``boundaries``), and a stop sign's lanes (in ``ids``).
        speed_limit_mph: (n_features,) a lane's speed limit [mph] (0 where absent).
        stop_position: (n_features, 2) a stop sign's position [m] (0 where absent).
        points: (n_points, 2) x, y [m] of every list of points.
        ids: (n_ids,) int64 lane ids of the entry, exit and stop-sign lists.
        neighbours: (n, 5) int64 feature_id, self_start_index, self_end_index,
            neighbor_start_index, neighbor_end_index.
        boundaries: (n, 3) int64 lane_start_index, lane_end_index, boundary_feature_id.
        signal_step, signal_lane, signal_state: (n_states,) int64 the step (the entry of
            ``dynamic_map_states``), the lane and the state of each lane state.
        signal_stop: (n_states, 2) its stop point [m] (0 where absent).
    """

    __slots__ = ("boundaries", "features", "ids", "n_map_states", "n_timestamps",
                 "neighbours", "points", "scenario_id", "signal_lane", "signal_state",
                 "signal_step", "signal_stop", "speed_limit_mph", "stop_position")

    def __init__(self, **fields) -> None:
        for name, value in fields.items():
            setattr(self, name, value)


def read_map_wire(data: bytes) -> MapWire | None:
    """The map of one serialized ``Scenario`` (module docstring), or None where the bytes
    hold something this reader leaves to protobuf (malformed bytes among them)."""
    buf = np.frombuffer(data, dtype=np.uint8)
    out = _read(buf)
    status, sid0, sid1, n_times, n_states = (int(v) for v in out[0])
    if status != 0:
        return None
    try:
        scenario_id = bytes(buf[sid0:sid1]).decode("utf-8")
    except UnicodeDecodeError:
        return None
    (_, features, speed, stop, points, ids, neighbours, boundaries, s_step, s_lane,
     s_state, s_stop) = out
    return MapWire(scenario_id=scenario_id, n_timestamps=n_times, n_map_states=n_states,
                   features=features, speed_limit_mph=speed, stop_position=stop,
                   points=points, ids=ids, neighbours=neighbours, boundaries=boundaries,
                   signal_step=s_step, signal_lane=s_lane, signal_state=s_state,
                   signal_stop=s_stop)


# ------------------------------------------------------------------ compiled


@numba.njit(cache=True, nogil=True)
def _varint(buf, pos, end):  # pragma: no cover - compiled
    """(value as uint64, next position), or (0, -1) for a varint running past ``end`` or
    longer than ten bytes."""
    value = np.uint64(0)
    shift = np.uint64(0)
    while pos < end and shift < 64:
        byte = buf[pos]
        pos += 1
        value |= np.uint64(byte & 0x7F) << shift
        if byte < 0x80:
            return value, pos
        shift += np.uint64(7)
    return np.uint64(0), -1


@numba.njit(cache=True, nogil=True)
def _int64(value):  # pragma: no cover - compiled
    """A varint's value as int64 (two's complement, as protobuf reads int64)."""
    if value >= np.uint64(1) << np.uint64(63):
        return np.int64(value - (np.uint64(1) << np.uint64(63))) + np.int64(-(1 << 63))
    return np.int64(value)


@numba.njit(cache=True, nogil=True)
def _int32(value):  # pragma: no cover - compiled
    """A varint's value as int32 (its low 32 bits, signed, as protobuf reads int32)."""
    low = np.int64(value & np.uint64(0xFFFFFFFF))
    return low - (np.int64(1) << 32) if low >= (np.int64(1) << 31) else low


_BITS_OF_FLOAT = {types.float64: types.uint64, types.float32: types.uint32}
"""The unsigned integer type as wide as each IEEE 754 float type (:func:`_as_float`)."""


@intrinsic
def _as_float(typingctx, bits, kind):  # pragma: no cover - compiled
    """The float of type ``kind`` (``np.float64`` or ``np.float32``) whose IEEE 754 bits are
    ``bits`` (an integer, taken as the unsigned integer as wide as ``kind``)."""
    result = getattr(kind, "instance_type", None)
    if result not in _BITS_OF_FLOAT:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(result))

    return result(_BITS_OF_FLOAT[result], kind), codegen


@numba.njit(cache=True, nogil=True)
def _double(buf, pos):  # pragma: no cover - compiled
    """The little-endian double at ``pos``."""
    bits = np.uint64(0)
    for k in range(8):
        bits |= np.uint64(buf[pos + k]) << np.uint64(8 * k)
    return _as_float(bits, np.float64)


@numba.njit(cache=True, nogil=True)
def _tag(buf, pos, end):  # pragma: no cover - compiled
    """(field number, wire type, position after the tag), or field -1 for a bad tag."""
    tag, pos = _varint(buf, pos, end)
    if pos < 0 or tag >= np.uint64(1) << np.uint64(32) or (tag >> np.uint64(3)) == 0 or (
            tag >> np.uint64(3)) >= np.uint64(1) << np.uint64(29):
        return -1, 0, -1
    return np.int64(tag >> np.uint64(3)), np.int64(tag & np.uint64(7)), pos


@numba.njit(cache=True, nogil=True)
def _skip(buf, pos, end, wire):  # pragma: no cover - compiled
    """The position after a field's value of wire type ``wire`` at ``pos`` (-1: malformed
    or a group)."""
    if wire == 0:
        return _varint(buf, pos, end)[1]
    if wire == 1:
        return pos + 8 if pos + 8 <= end else -1
    if wire == 5:
        return pos + 4 if pos + 4 <= end else -1
    if wire == 2:
        size, pos = _varint(buf, pos, end)
        if pos < 0 or size > np.uint64(end - pos):
            return -1
        return pos + np.int64(size)
    return -1


@numba.njit(cache=True, nogil=True)
def _length(buf, pos, end):  # pragma: no cover - compiled
    """(start, end) of a length-delimited value at ``pos`` ((-1, -1): malformed)."""
    size, pos = _varint(buf, pos, end)
    if pos < 0 or size > np.uint64(end - pos):
        return -1, -1
    return pos, pos + np.int64(size)


@numba.njit(cache=True, nogil=True)
def _point(buf, pos, end):  # pragma: no cover - compiled
    """(ok, x, y) of the MapPoint in buf[pos:end]."""
    x = 0.0
    y = 0.0
    while pos < end:
        field, wire, pos = _tag(buf, pos, end)
        if field < 0:
            return False, x, y
        if field <= 3:
            if wire != 1 or pos + 8 > end:
                return False, x, y
            if field == 1:
                x = _double(buf, pos)
            elif field == 2:
                y = _double(buf, pos)
            pos += 8
            continue
        pos = _skip(buf, pos, end, wire)
        if pos < 0:
            return False, x, y
    return True, x, y


@numba.njit(cache=True, nogil=True)
def _append_ids(buf, pos, end, wire, ids, n_ids):  # pragma: no cover - compiled
    """Append a repeated int64 field's value (one varint, or packed ones) at ``pos`` to
    ``ids``; (next position, new count), position -1 when malformed."""
    if wire == 0:
        value, pos = _varint(buf, pos, end)
        if pos < 0:
            return -1, n_ids
        ids[n_ids] = _int64(value)
        return pos, n_ids + 1
    if wire != 2:
        return -1, n_ids
    a, b = _length(buf, pos, end)
    if a < 0:
        return -1, n_ids
    while a < b:
        value, a = _varint(buf, a, b)
        if a < 0:
            return -1, n_ids
        ids[n_ids] = _int64(value)
        n_ids += 1
    return b, n_ids


@numba.njit(cache=True, nogil=True)
def _ints(buf, pos, end, numbers64, row, table, k):  # pragma: no cover - compiled
    """Read a message of varint fields 1..len(row) into ``row`` (last value kept, absent
    fields 0; field i is int64 where ``numbers64[i - 1]``, else int32) and store it as
    ``table[k]``; False when malformed or a known field has another wire type."""
    for i in range(len(row)):
        row[i] = 0
    while pos < end:
        field, wire, pos = _tag(buf, pos, end)
        if field < 0:
            return False
        if field <= len(row):
            if wire != 0:
                return False
            value, pos = _varint(buf, pos, end)
            if pos < 0:
                return False
            row[field - 1] = _int64(value) if numbers64[field - 1] else _int32(value)
            continue
        pos = _skip(buf, pos, end, wire)
        if pos < 0:
            return False
    for i in range(len(row)):
        table[k, i] = row[i]
    return True


@numba.njit(cache=True, nogil=True)
def _append_message(buf, pos, end, wire, lists, col, numbers64, row, table, n
                    ):  # pragma: no cover - compiled
    """Append the message of varint fields at ``pos`` (wire type ``wire``; read by
    :func:`_ints` with ``numbers64`` and ``row``) as row ``n`` of ``table``, extending the
    feature's list [``lists[col]``, ``lists[col + 1]``) over it; (position after it, the
    table, made larger where needed, the new count), position -1 when malformed or when
    the list was split by another field."""
    if lists[col + 1] == 0 and lists[col] == 0:
        lists[col] = lists[col + 1] = n
    a, b = _length(buf, pos, end) if wire == 2 else (-1, -1)
    if a < 0 or lists[col + 1] != n:
        return -1, table, n
    table = _room2(table, n + 1)
    if not _ints(buf, a, b, numbers64, row, table, n):
        return -1, table, n
    lists[col + 1] = n + 1
    return b, table, n + 1


@numba.njit(cache=True, nogil=True)
def _room1(a, n):  # pragma: no cover - compiled
    """``a`` (1-d), or a copy twice as long (at least ``n`` items), when it has fewer than
    ``n`` items."""
    if n <= a.shape[0]:
        return a
    b = np.empty(max(2 * a.shape[0], n), a.dtype)
    b[:a.shape[0]] = a
    return b


@numba.njit(cache=True, nogil=True)
def _room2(a, n):  # pragma: no cover - compiled
    """:func:`_room1` of a 2-d array (its rows)."""
    if n <= a.shape[0]:
        return a
    b = np.empty((max(2 * a.shape[0], n), a.shape[1]), a.dtype)
    b[:a.shape[0]] = a
    return b


@numba.njit(cache=True, nogil=True)
def _sizes(buf):  # pragma: no cover - compiled
    """(map features, their bytes, the bytes of the signal states) of the Scenario in
    ``buf``; features -1 where its top level is malformed or a map field is not
    length-delimited."""
    n = len(buf)
    pos = 0
    n_features = feature_bytes = state_bytes = 0
    while pos < n:
        field, wire, pos = _tag(buf, pos, n)
        if field < 0:
            return -1, 0, 0
        if (field == 7 or field == 8) and wire == 2:
            a, b = _length(buf, pos, n)
            if a < 0:
                return -1, 0, 0
            if field == 8:
                n_features += 1
                feature_bytes += b - a
            else:
                state_bytes += b - a
            pos = b
        elif field == 7 or field == 8:
            return -1, 0, 0
        else:
            pos = _skip(buf, pos, n, wire)
            if pos < 0:
                return -1, 0, 0
    return n_features, feature_bytes, state_bytes


@numba.njit(cache=True, nogil=True)
def _point_run(buf, pos, end, key, points, n_points):  # pragma: no cover - compiled
    """Read a run of MapPoints (length-delimited values at ``pos``, each after the one-byte
    tag ``key`` but the first, whose tag is read) into ``points`` from row ``n_points``;
    (position after the run, new count, the points' array, made larger where needed),
    position -1 when malformed."""
    points = _room2(points, n_points + (end - pos) // 2 + 1)  # a point takes 2 bytes or more
    while True:
        size = np.int64(buf[pos]) if pos < end else -1
        if 0 <= size < 0x80 and pos + 1 + size <= end:
            a, b = pos + 1, pos + 1 + size
        else:
            a, b = _length(buf, pos, end)
            if a < 0:
                return -1, n_points, points
        if (b - a == 27 and buf[a] == 0x09 and buf[a + 9] == 0x11
                and buf[a + 18] == 0x19):  # x, y, z in order, as WOMD writes them
            points[n_points, 0] = _double(buf, a + 1)
            points[n_points, 1] = _double(buf, a + 10)
        else:
            ok, x, y = _point(buf, a, b)
            if not ok:
                return -1, n_points, points
            points[n_points, 0] = x
            points[n_points, 1] = y
        n_points += 1
        pos = b
        if pos < end and buf[pos] == key:
            pos += 1
        else:
            return pos, n_points, points


@numba.njit(cache=True, nogil=True)
def _point_message(buf, pos, end, wire, seen):  # pragma: no cover - compiled
    """(position after it, x, y) of the MapPoint field at ``buf[pos:end]`` sent with wire
    type ``wire``; the position is -1 where protobuf must read it (not a message, a point
    ``seen`` already, a bad length or point)."""
    if wire != 2 or seen:
        return -1, 0.0, 0.0
    a, b = _length(buf, pos, end)
    if a < 0:
        return -1, 0.0, 0.0
    ok, x, y = _point(buf, a, b)
    return (b if ok else -1), x, y


@numba.njit(cache=True, nogil=True)
def _signal_step(buf, a, b, step, row3, ls_64, s_step, s_lane, s_state, s_stop,
                 n_ls):  # pragma: no cover - compiled
    """Append the lane states of one step's signal message ``buf[a:b]`` (step ``step``) to
    the state lists: (bad, n_ls, s_step, s_lane, s_state, s_stop), bad where protobuf must
    read it."""
    bad = False
    while not bad and a < b:
        f2, w2, a = _tag(buf, a, b)
        if f2 < 0:
            bad = True
        elif f2 == 1:  # a lane state
            if w2 != 2:
                bad = True
                break
            c, d = _length(buf, a, b)
            if c < 0:
                bad = True
                break
            a = d
            row3[0] = row3[1] = 0
            has_stop = False
            x = y = 0.0
            while c < d:
                f3, w3, c = _tag(buf, c, d)
                if f3 < 0:
                    bad = True
                    break
                if f3 == 1 or f3 == 2:
                    if w3 != 0:
                        bad = True
                        break
                    value, c = _varint(buf, c, d)
                    if c < 0:
                        bad = True
                        break
                    row3[f3 - 1] = (_int64(value) if ls_64[f3 - 1]
                                    else _int32(value))
                elif f3 == 3:
                    c, x, y = _point_message(buf, c, d, w3, has_stop)
                    has_stop = True
                    if c < 0:
                        bad = True
                        break
                else:
                    c = _skip(buf, c, d, w3)
                    if c < 0:
                        bad = True
                        break
            s_step = _room1(s_step, n_ls + 1)
            s_lane = _room1(s_lane, n_ls + 1)
            s_state = _room1(s_state, n_ls + 1)
            s_stop = _room2(s_stop, n_ls + 1)
            s_step[n_ls] = step
            s_lane[n_ls] = row3[0]
            s_state[n_ls] = row3[1]
            s_stop[n_ls, 0] = x
            s_stop[n_ls, 1] = y
            n_ls += 1
        else:
            a = _skip(buf, a, b, w2)
            bad = a < 0
    return bad, n_ls, s_step, s_lane, s_state, s_stop


@numba.njit(cache=True, nogil=True)
def _feature(buf, a, b, feature, speed, stop, row5, row4, nb_64, bd_64, points, ids,
             neighbours, boundaries, n_pts, n_ids, n_nb,
             n_bd):  # pragma: no cover - compiled
    """Read one map feature's message ``buf[a:b]`` into its row ``feature`` (columns
    ``_F_*``), its speed limit (``speed[0]``), its stop position (``stop``) and the lists
    it adds to: (bad, points, ids, neighbours, boundaries, n_pts, n_ids, n_nb, n_bd), bad
    where protobuf must read it."""
    bad = False
    kinds = 0
    while not bad and a < b:
        f2, w2, a = _tag(buf, a, b)
        if f2 < 0:
            bad = True
            break
        if f2 == 1:
            if w2 != 0:
                bad = True
                break
            value, a = _varint(buf, a, b)
            bad = a < 0
            feature[_F_ID] = _int64(value)
            continue
        kind = (_LANE if f2 == 3 else _ROAD_LINE if f2 == 4 else _ROAD_EDGE
                if f2 == 5 else _STOP_SIGN if f2 == 7 else _CROSSWALK if f2 == 8
                else 0)
        if kind == 0:
            a = _skip(buf, a, b, w2)
            bad = a < 0
            continue
        if w2 != 2 or kinds:  # a second kind, or one kind twice: protobuf
            bad = True
            break
        kinds += 1
        feature[_F_KIND] = kind
        c, d = _length(buf, a, b)
        if c < 0:
            bad = True
            break
        a = d
        feature[_F_PTS0] = feature[_F_PTS1] = n_pts
        # each list's [start, end) column, its items at the end of its array
        points_field = (8 if kind == _LANE else 2 if kind <= _ROAD_EDGE
                        else 1 if kind == _CROSSWALK else -1)
        seen_position = False
        while c < d:
            f3, w3, c = _tag(buf, c, d)
            if f3 < 0:
                bad = True
                break
            if f3 == points_field:
                if w3 != 2 or feature[_F_PTS1] != n_pts:
                    bad = True
                    break
                c, n_pts, points = _point_run(buf, c, d, points_field << 3 | 2,
                                              points, n_pts)
                feature[_F_PTS1] = n_pts
            elif kind == _LANE and f3 == 1:
                if w3 != 1 or c + 8 > d:
                    bad = True
                    break
                speed[0] = _double(buf, c)
                feature[_F_HAS_SPEED] = 1
                c += 8
            elif kind == _LANE and (f3 == 2 or f3 == 3):
                if w3 != 0:
                    bad = True
                    break
                value, c = _varint(buf, c, d)
                if f3 == 2 and c >= 0:
                    feature[_F_TYPE] = _int32(value)
            elif (kind == _LANE and (f3 == 9 or f3 == 10)) or (
                    kind == _STOP_SIGN and f3 == 1):
                col = _F_ENTRY0 if f3 == 9 else _F_EXIT0 if f3 == 10 else _F_STOP0
                if feature[col + 1] == 0 and feature[col] == 0:
                    feature[col] = feature[col + 1] = n_ids
                if feature[col + 1] != n_ids:
                    bad = True
                    break
                ids = _room1(ids, n_ids + d - c)  # an id takes a byte or more
                c, n_ids = _append_ids(buf, c, d, w3, ids, n_ids)
                feature[col + 1] = n_ids
            elif kind == _LANE and (f3 == 11 or f3 == 12):
                c, neighbours, n_nb = _append_message(
                    buf, c, d, w3, feature,
                    _F_LEFT0 if f3 == 11 else _F_RIGHT0, nb_64, row5,
                    neighbours, n_nb)
            elif kind == _LANE and (f3 == 13 or f3 == 14):
                # (start, end, feature id): the type is read, not kept
                c, boundaries, n_bd = _append_message(
                    buf, c, d, w3, feature, _F_LB0 if f3 == 13 else _F_RB0,
                    bd_64, row4, boundaries, n_bd)
            elif kind == _STOP_SIGN and f3 == 2:
                c, x, y = _point_message(buf, c, d, w3, seen_position)
                seen_position = True
                if c < 0:
                    bad = True
                    break
                stop[0] = x
                stop[1] = y
            elif (kind <= _ROAD_EDGE and kind != _LANE and f3 == 1):
                if w3 != 0:
                    bad = True
                    break
                c = _varint(buf, c, d)[1]
            else:
                c = _skip(buf, c, d, w3)
            if c < 0:
                bad = True
                break
    return bad, points, ids, neighbours, boundaries, n_pts, n_ids, n_nb, n_bd


@numba.njit(cache=True, nogil=True)
def _read(buf):  # pragma: no cover - compiled
    """Read the map of the Scenario in ``buf`` (see :class:`MapWire`): (head, features,
    speed limits, stop positions, points, ids, neighbours, boundaries, signal steps, lanes,
    states, stop points), head = (status, scenario_id start, end, timestamps, map states);
    status -1 where the caller must read with protobuf."""
    n = len(buf)
    head = np.zeros(5, np.int64)
    n_features, feature_bytes, state_bytes = _sizes(buf)
    if n_features < 0:
        head[0] = _BAD
        n_features = feature_bytes = state_bytes = 0
    # the lists' arrays sized as WOMD's maps need (a point takes about 29 bytes), made
    # larger when a map needs more
    features = np.zeros((n_features, _F_COLUMNS), np.int64)
    speed = np.zeros(n_features)
    stop = np.zeros((n_features, 2))
    points = np.empty((feature_bytes // 24 + 16, 2))  # grown by _point_run
    ids = np.empty(feature_bytes // 512 + 16, np.int64)
    neighbours = np.empty((feature_bytes // 512 + 16, 5), np.int64)
    boundaries = np.empty((feature_bytes // 512 + 16, 4), np.int64)
    s_cap = state_bytes // 24 + 16
    s_step = np.empty(s_cap, np.int64)
    s_lane = np.empty(s_cap, np.int64)
    s_state = np.empty(s_cap, np.int64)
    s_stop = np.zeros((s_cap, 2))
    row5 = np.zeros(5, np.int64)
    row4 = np.zeros(4, np.int64)
    row3 = np.zeros(3, np.int64)
    nb_64 = np.array([True, False, False, False, False])
    bd_64 = np.array([False, False, True, False])
    ls_64 = np.array([True, False])
    n_f = n_pts = n_ids = n_nb = n_bd = n_ls = 0
    n_times = n_states = 0
    sid0 = sid1 = 0
    pos = n if head[0] == _BAD else 0
    while pos < n:
        field, wire, pos = _tag(buf, pos, n)
        if field < 0:
            head[0] = _BAD
            break
        bad = False
        if field == 1:  # timestamps_seconds
            if wire == 1:
                if pos + 8 > n:
                    bad = True
                else:
                    n_times += 1
                    pos += 8
            elif wire == 2:
                a, b = _length(buf, pos, n)
                if a < 0 or (b - a) % 8:
                    bad = True
                else:
                    n_times += (b - a) // 8
                    pos = b
            else:
                bad = True
        elif field == 5:  # scenario_id
            if wire != 2:
                bad = True
            else:
                sid0, sid1 = _length(buf, pos, n)
                bad = sid0 < 0
                pos = sid1
        elif field == 7:  # one step's signal states
            if wire != 2:
                bad = True
            else:
                a, b = _length(buf, pos, n)
                bad = a < 0
                pos = b
                if not bad:
                    bad, n_ls, s_step, s_lane, s_state, s_stop = _signal_step(
                        buf, a, b, n_states, row3, ls_64, s_step, s_lane, s_state,
                        s_stop, n_ls)
                n_states += 1
        elif field == 8:  # a map feature
            if wire != 2:
                bad = True
            else:
                a, b = _length(buf, pos, n)
                bad = a < 0
                pos = b
                k = n_f
                n_f += 1
                if not bad:
                    (bad, points, ids, neighbours, boundaries, n_pts, n_ids, n_nb,
                     n_bd) = _feature(buf, a, b, features[k], speed[k:k + 1], stop[k],
                                      row5, row4, nb_64, bd_64, points, ids,
                                      neighbours, boundaries, n_pts, n_ids, n_nb, n_bd)
        else:
            pos = _skip(buf, pos, n, wire)
            bad = pos < 0
        if bad:
            head[0] = _BAD
            break
    if head[0] == _BAD:
        n_f = n_pts = n_ids = n_nb = n_bd = n_ls = 0
    head[1] = sid0
    head[2] = sid1
    head[3] = n_times
    head[4] = n_states
    return (head, features[:n_f].copy(), speed[:n_f].copy(), stop[:n_f].copy(),
            points[:n_pts].copy(), ids[:n_ids].copy(), neighbours[:n_nb].copy(),
            boundaries[:n_bd, :3].copy(), s_step[:n_ls].copy(), s_lane[:n_ls].copy(),
            s_state[:n_ls].copy(), s_stop[:n_ls].copy())
