"""Trajectory tables to WOMD ``Scenario`` TFRecords.

Any trajectory table (WOMD, highway-env rollouts, hand-made fixtures) can be written as a
TFRecord of ``Scenario`` protos, one record per scenario, that WOMD tools read. Reading the
file back with :func:`tap_bench.read_womd` gives the same table:

- ``t``, ``x``, ``y`` and ``z`` are doubles in the proto and come back exactly;
- ``heading``, ``vx``, ``vy``, ``length``, ``width``, ``height`` are floats (float32) in
  the proto and come back rounded to float32 (relative error below 6e-8);
- ``speed`` is not a proto field: it comes back as ``hypot(vx, vy)``. A table without
  ``vx``/``vy`` is written with ``vx = speed cos(heading)``, ``vy = speed sin(heading)``;
- a table without ``length``, ``width`` or ``height`` (or with NaN there on a valid row)
  is written with the typical box of its ``object_type`` (:data:`DEFAULT_BOX`), since a
  valid WOMD state has a positive box and the readers refuse any other;
- invalid rows (``valid=False``) come back with NaN kinematics, and steps missing from a
  track's rows come back as invalid rows;
- ``track_id`` that is not a WOMD int32 id, and columns WOMD has no field for (``source``
  unless it is ``womd``, ``env``, ``policy``, ``seed``, ``crashed`` ...), are kept in two
  tap-bench fields of ``Track`` (:data:`tap_bench.womd.proto.TAP_BENCH_TRACK_ID_FIELD`,
  :data:`~tap_bench.womd.proto.TAP_BENCH_COLUMNS_FIELD`, JSON) that other tools ignore.

States are encoded with numpy as fixed 59-byte messages, the bytes protobuf itself writes
for an ``ObjectState`` with every field set, so writing is fast enough to build benchmark
shards of hundreds of MB.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa

from tap_bench.errors import TrajectoryTableError
from tap_bench.tableio import atomic_path
from tap_bench.trajectories import validate_trajectories
from tap_bench.womd import proto
from tap_bench.womd.tfrecord import TFRecordWriter

__all__ = ["DEFAULT_BOX", "encode_scenarios", "restore_extra_columns", "write_womd"]

DEFAULT_BOX = {
    "vehicle": (4.5, 2.0, 1.6),
    "pedestrian": (0.8, 0.8, 1.7),
    "cyclist": (1.8, 0.8, 1.7),
    "other": (1.0, 1.0, 1.0),
}
"""(length, width, height) [m] written where a table gives no box size, by object type: a
passenger car, a walking person, a bicycle with its rider, a small object."""

_TYPE_NUMBERS = {"vehicle": 1, "pedestrian": 2, "cyclist": 3, "other": 4}
_NATIVE = frozenset({
    "scenario_id", "track_id", "t", "x", "y", "heading", "speed", "valid", "vx", "vy",
    "object_type", "is_ego", "z", "length", "width", "height", "object_of_interest",
    "track_to_predict", "prediction_difficulty",
})
"""Columns with a home in the Scenario proto (``speed`` through vx, vy)."""
_INT32 = (-(2**31), 2**31 - 1)
_TRACKS_FIELD_TAG = bytes([2 << 3 | 2])

# An ObjectState with every field set: tag byte, then value, in field order.
_STATE_FIELDS = (("center_x", "<f8"), ("center_y", "<f8"), ("center_z", "<f8"),
                 ("length", "<f4"), ("width", "<f4"), ("height", "<f4"), ("heading", "<f4"),
                 ("velocity_x", "<f4"), ("velocity_y", "<f4"), ("valid", "u1"))
_STATE_DTYPE = np.dtype([("state_tag", "u1"), ("state_length", "u1")]
                        + [item for (name, kind) in _STATE_FIELDS
                           for item in ((f"{name}_tag", "u1"), (name, kind))])
_STATE_SIZE = _STATE_DTYPE.itemsize - 2  # 59 bytes, the tag and length prefix excluded
_STATE_WIRE = {"<f8": 1, "<f4": 5, "u1": 0}
_STATE_NUMBERS = {name: number for name, number, _ in proto.OBJECT_STATE_FIELDS}


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _encode_states(columns: dict[str, np.ndarray]) -> np.ndarray:
    """(n,) structured array whose bytes are n repeated ``states`` fields of a Track."""
    n = len(columns["valid"])
    states = np.zeros(n, dtype=_STATE_DTYPE)
    states["state_tag"] = 3 << 3 | 2
    states["state_length"] = _STATE_SIZE
    for name, kind in _STATE_FIELDS:
        states[f"{name}_tag"] = _STATE_NUMBERS[name] << 3 | _STATE_WIRE[kind]
        states[name] = columns[name]
    return states


def _track_ids(ids: Sequence[str]) -> tuple[list[int], bool]:
    """WOMD int32 ids when every id is a canonical int32 string, else 0 .. n-1 (and True:
    the string ids must be kept in the tap-bench field)."""
    ints = []
    for s in ids:
        try:
            value = int(s)
        except ValueError:
            break
        if str(value) != s or not _INT32[0] <= value <= _INT32[1]:
            break
        ints.append(value)
    else:
        return ints, False
    return list(range(len(ids))), True


def _json_value(value: object) -> object:
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and np.isnan(value):
        return None
    return value


def _extra_columns(track: pd.DataFrame, slots: np.ndarray, n_steps: int,
                   names: Sequence[str]) -> str:
    """JSON of a track's extra columns: a value when constant, else one per time step."""
    kept = {}
    for name in names:
        values = track[name].tolist()
        if name == "source" and all(v == "womd" for v in values):
            continue
        values = [_json_value(v) for v in values]
        if all(v == values[0] for v in values) and len(slots) == n_steps:
            kept[name] = values[0]
        elif all(v == values[0] for v in values):
            kept[name] = {"value": values[0], "steps": slots.tolist()}
        else:
            series: list[object] = [None] * n_steps
            for slot, v in zip(slots.tolist(), values, strict=True):
                series[slot] = v
            kept[name] = {"series": series}
    return json.dumps(kept, separators=(",", ":")) if kept else ""


def restore_extra_columns(table: pa.Table, extra_json: Sequence[str], n_steps: int) -> pa.Table:
    """Add the columns kept by the writer in the tap-bench Track field to a decoded table.

    Args:
        table: a decoded scenario, ``n_steps`` rows per track, tracks in ``extra_json`` order.
        extra_json: per track, the JSON the writer stored ("" for none).
        n_steps: the scenario's number of time steps.

    Raises:
        ValueError: a track's JSON is malformed or does not have the writer's structure
            (naming the track's position and the column); the decoder makes it a record
            error.
    """
    decoded = []
    for i, text in enumerate(extra_json):
        try:
            doc = json.loads(text) if text else {}
        except ValueError as err:  # also a UnicodeDecodeError of bytes
            raise ValueError(f"track {i}: the tap-bench columns are not valid JSON ({err})"
                             ) from None
        if not isinstance(doc, dict):
            raise ValueError(f"track {i}: the tap-bench columns hold a "
                             f"{type(doc).__name__}, not an object of columns")
        decoded.append(doc)
    names = list(dict.fromkeys(name for d in decoded for name in d))
    for name in names:
        values: list[object] = []
        for i, d in enumerate(decoded):
            values.extend(_extra_values(d.get(name), n_steps, f"track {i}, column {name!r}"))
        if len(values) != table.num_rows:
            raise ValueError(f"column {name!r}: {len(values)} values for {table.num_rows} "
                             "rows")
        try:
            if name in table.column_names:
                fallback = table.column(name).to_pylist()
                column = pa.array([v if v is not None else f
                                   for v, f in zip(values, fallback, strict=True)])
                table = table.set_column(table.column_names.index(name), name, column)
            else:
                table = table.append_column(name, pa.array(values))
        except (pa.ArrowException, TypeError, ValueError) as err:
            raise ValueError(f"column {name!r}: the tap-bench values do not form one column "
                             f"({err})") from None
    return table


def _extra_values(kept: object, n_steps: int, where: str) -> list[object]:
    """The ``n_steps`` values of one track's column as the writer stored it: a constant,
    ``{"value", "steps"}`` or ``{"series"}``."""
    if not isinstance(kept, dict):
        if isinstance(kept, list):
            raise ValueError(f"{where}: a list where a value or an object belongs")
        return [kept] * n_steps
    if "series" in kept:
        series = kept["series"]
        if not isinstance(series, list) or len(series) != n_steps:
            raise ValueError(f"{where}: 'series' must be a list of {n_steps} values, got "
                             f"{type(series).__name__} of length "
                             f"{len(series) if isinstance(series, list) else '-'}")
        return series
    steps = kept.get("steps")
    if "value" not in kept or not isinstance(steps, list) or not all(
            isinstance(s, int) and not isinstance(s, bool) for s in steps):
        raise ValueError(f"{where}: an object needs 'value' and 'steps' (a list of step "
                         "indices), or 'series'")
    chosen = set(steps)
    return [kept["value"] if i in chosen else None for i in range(n_steps)]


def _column(group: pd.DataFrame, name: str, default: float) -> np.ndarray:
    if name in group.columns:
        return group[name].to_numpy(dtype=np.float64, na_value=np.nan)
    return np.full(len(group), default)


def _box_size(group: pd.DataFrame, axis: int, row_types: np.ndarray) -> np.ndarray:
    """(n_rows,) the box's length (axis 0), width (1) or height (2) [m]: the table's, or
    :data:`DEFAULT_BOX` of the row's object type where the table has none (column absent or
    NaN)."""
    name = ("length", "width", "height")[axis]
    default = np.array([DEFAULT_BOX.get(t, DEFAULT_BOX["other"])[axis] for t in row_types],
                       dtype=np.float64)
    values = _column(group, name, np.nan)
    return np.where(np.isnan(values), default, values)


def _scenario_record(scenario_id: str, group: pd.DataFrame, extras: Sequence[str]) -> bytes:
    times = np.unique(group["t"].to_numpy())
    n_steps = len(times)
    track_codes, track_names = pd.factorize(group["track_id"], sort=False)
    ids, keep_strings = _track_ids([str(s) for s in track_names])
    slot = np.searchsorted(times, group["t"].to_numpy())
    n_tracks = len(track_names)
    flat = track_codes * n_steps + slot

    valid = np.zeros(n_tracks * n_steps, dtype=bool)
    valid[flat] = group["valid"].to_numpy(dtype=bool)
    heading = _column(group, "heading", 0.0)
    if {"vx", "vy"} <= set(group.columns):
        vx, vy = _column(group, "vx", 0.0), _column(group, "vy", 0.0)
    else:
        speed = _column(group, "speed", 0.0)
        vx, vy = speed * np.cos(heading), speed * np.sin(heading)
    row_types = (group["object_type"].astype(str).to_numpy() if "object_type" in group.columns
                 else np.full(len(group), "vehicle", dtype=object))
    columns = {"valid": valid}
    for name, values in (("center_x", _column(group, "x", 0.0)),
                         ("center_y", _column(group, "y", 0.0)),
                         ("center_z", _column(group, "z", 0.0)),
                         ("length", _box_size(group, 0, row_types)),
                         ("width", _box_size(group, 1, row_types)),
                         ("height", _box_size(group, 2, row_types)),
                         ("heading", heading), ("velocity_x", vx), ("velocity_y", vy)):
        full = np.zeros(n_tracks * n_steps)
        full[flat] = np.where(np.isnan(values), 0.0, values)
        full[~valid] = 0.0  # WOMD writes invalid states as zeros
        columns[name] = full
    states = _encode_states(columns).reshape(n_tracks, n_steps)

    first_row = np.zeros(n_tracks, dtype=np.int64)
    first_row[track_codes[::-1]] = np.arange(len(group))[::-1]
    otype = (group["object_type"].to_numpy()[first_row] if "object_type" in group.columns
             else np.full(n_tracks, "vehicle", dtype=object))
    scenario = proto.Scenario(scenario_id=scenario_id, timestamps_seconds=times.tolist())
    if "is_ego" in group.columns:
        ego = np.unique(track_codes[group["is_ego"].to_numpy(dtype=bool)])
        if len(ego) > 1:
            raise TrajectoryTableError(
                f"scenario {scenario_id!r} has {len(ego)} tracks with is_ego=True "
                f"({', '.join(map(str, track_names[ego][:5]))}); a WOMD scenario has one "
                "self-driving car. Set is_ego on one track only.", column="is_ego")
        if len(ego) == 1:
            scenario.sdc_track_index = int(ego[0])
    if "object_of_interest" in group.columns:
        interest = np.unique(track_codes[group["object_of_interest"].to_numpy(dtype=bool)])
        scenario.objects_of_interest.extend(ids[i] for i in interest)
    if "track_to_predict" in group.columns:
        chosen = np.unique(track_codes[group["track_to_predict"].to_numpy(dtype=bool)])
        difficulty = (group["prediction_difficulty"].to_numpy()[first_row]
                      if "prediction_difficulty" in group.columns else np.zeros(n_tracks))
        for i in chosen:
            scenario.tracks_to_predict.add(track_index=int(i), difficulty=int(difficulty[i]))
    parts = [scenario.SerializeToString()]
    if extras:
        by_track = np.argsort(track_codes, kind="stable")
        bounds = np.searchsorted(track_codes[by_track], np.arange(n_tracks + 1))
    for i in range(n_tracks):
        track = proto.Track(id=ids[i], object_type=_TYPE_NUMBERS[otype[i]])
        if keep_strings:
            track.tap_bench_track_id = str(track_names[i])
        if extras:
            rows = by_track[bounds[i]:bounds[i + 1]]
            track.tap_bench_columns = _extra_columns(group.iloc[rows], slot[rows], n_steps,
                                                     extras)
        body = track.SerializeToString() + states[i].tobytes()
        parts.append(_TRACKS_FIELD_TAG + _varint(len(body)) + body)
    return b"".join(parts)


def encode_scenarios(table: pd.DataFrame) -> Iterator[tuple[str, bytes]]:
    """Serialize a trajectory table as WOMD ``Scenario`` protos, one per scenario.

    Args:
        table: a trajectory table (SPEC section 1), validated here. Optional WOMD columns
            (``z``, ``length``, ``width``, ``height``, ``object_of_interest``,
            ``track_to_predict``, ``prediction_difficulty``) are written when present.

    Yields:
        (scenario_id, serialized Scenario) in order of first appearance. A scenario's
        ``timestamps_seconds`` are the sorted distinct ``t`` of its rows; a track with no
        row at a step gets an invalid state there.

    Raises:
        TrajectoryTableError: the table breaks the contract, or a scenario has two ego
            tracks.
    """
    clean = validate_trajectories(table)
    extras = [c for c in clean.columns if c not in _NATIVE]
    order = pd.unique(pd.Series(table["scenario_id"]).astype(str))
    codes, names = pd.factorize(clean["scenario_id"], sort=False)
    starts = np.flatnonzero(np.r_[True, codes[1:] != codes[:-1]])
    stops = np.r_[starts[1:], len(codes)]
    spans = {names[codes[a]]: (a, b) for a, b in zip(starts, stops, strict=True)}
    for scenario_id in order:
        a, b = spans[scenario_id]
        group = clean.iloc[a:b].reset_index(drop=True)
        yield str(scenario_id), _scenario_record(str(scenario_id), group, extras)


def write_womd(table: pd.DataFrame, path: str | os.PathLike, *, compress: bool = False) -> Path:
    """Write a trajectory table as a TFRecord of WOMD ``Scenario`` protos, atomically.

    Args:
        table: a trajectory table (SPEC section 1); see :func:`encode_scenarios`.
        path: the file to write (conventionally ``*.tfrecord``; ``*.tfrecord.gz`` with
            ``compress``).
        compress: GZIP the file (TensorFlow's ``compression_type="GZIP"``).

    Returns:
        The path written. An interrupted write leaves no file behind.
    """
    path = Path(path)
    with atomic_path(path) as tmp, TFRecordWriter(tmp, compress=compress) as writer:
        for _, record in encode_scenarios(table):
            writer.write(record)
    return path
