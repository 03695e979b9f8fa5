"""WOMD ``Scenario`` records to the trajectory table (SPEC section 1).

A scenario becomes one row per track per time step, track by track, steps in time order, with
``t`` from ``timestamps_seconds``. Steps a track has no valid state for stay as rows with
``valid=False`` and NaN kinematics, so ``t`` stays regular. WOMD's axes are the contract's;
headings are wrapped into [-pi, pi) where WOMD stores them beyond (a few percent of its
states, up to about 3 pi), as the contract allows at most 2 pi.

Decoding is split for speed: protobuf parses the scenario and its tracks through
:data:`tap_bench.womd.proto.ScenarioView`, which leaves each track's states as raw bytes; the
states of all tracks are then decoded together with numpy (:func:`decode_object_states`),
field by field across every state at once rather than state by state in Python.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

import numpy as np
import pyarrow as pa
from google.protobuf.message import DecodeError

from tap_bench.errors import StateDecodeError, did_you_mean
from tap_bench.trajectories import OBJECT_TYPES
from tap_bench.womd import proto
from tap_bench.womd.tfrecord import Record
from tap_bench.womd.writer import restore_extra_columns

__all__ = ["SCENARIO_COLUMNS", "STATE_COLUMNS", "StateDecodeError", "decode_object_states",
           "decode_scenario", "normalise_object_types", "repeated_strings",
           "trajectory_table", "wrap_heading"]

SCENARIO_COLUMNS = (
    "scenario_id", "track_id", "t", "x", "y", "heading", "speed", "valid", "vx", "vy",
    "object_type", "is_ego", "source", "z", "length", "width", "height",
    "object_of_interest", "track_to_predict", "prediction_difficulty",
)
"""Columns of a table decoded from WOMD, in order.

Beyond the contract: ``z`` [m], ``length``, ``width``, ``height`` [m] (bounding box),
``object_of_interest`` (bool, the track is in ``objects_of_interest``), ``track_to_predict``
(bool, in ``tracks_to_predict``) and ``prediction_difficulty`` (int8: 0 none, 1 level 1,
2 level 2).
"""

_FIXED64 = {2: "x", 3: "y", 4: "z"}
_FIXED32 = {5: "length", 6: "width", 7: "height", 8: "heading", 9: "vx", 10: "vy"}
_VALID_FIELD = 11
_STATES_TAG = 3 << 3 | 2
_PAD = 32  # zero bytes after the buffer, so that reads past a malformed state stay in bounds


def _varint(buf: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read one varint at each position; returns (value uint64, next position, too long)."""
    byte = buf[pos]
    value = (byte & 0x7F).astype(np.uint64)
    pos = pos + 1
    more = np.flatnonzero(byte & 0x80)
    too_long = np.zeros(len(pos), dtype=bool)
    shift = 7
    while more.size:
        if shift > 63:
            too_long[more] = True
            break
        byte = buf[pos[more]]
        value[more] |= (byte & 0x7F).astype(np.uint64) << np.uint64(shift)
        pos[more] += 1
        more = more[(byte & 0x80) != 0]
        shift += 7
    return value, pos, too_long


def _gather(buf: np.ndarray, pos: np.ndarray, size: int, dtype: str) -> np.ndarray:
    """Little-endian values of ``size`` bytes at each position."""
    return buf[pos[:, None] + np.arange(size)].view(dtype).ravel()


def decode_object_states(data: bytes, lengths: np.ndarray) -> dict[str, np.ndarray]:
    """Decode back-to-back serialized ``ObjectState`` messages, all at once.

    Follows protobuf's rules: absent fields take their defaults (0, false), a repeated
    field keeps its last value, unknown fields and fields of an unexpected wire type are
    skipped.

    Args:
        data: the serialized states, one after another.
        lengths: (n,) int, the byte length of each state; they add up to ``len(data)``.

    Returns:
        Arrays of shape (n,): ``x``, ``y``, ``z`` (float64, m), ``length``, ``width``,
        ``height`` (float32, m), ``heading`` (float32, rad), ``vx``, ``vy`` (float32, m/s),
        ``valid`` (bool).

    Raises:
        StateDecodeError: a state whose bytes are not a valid protobuf message.
    """
    lengths = np.asarray(lengths, dtype=np.int64)
    buf = np.frombuffer(bytes(data) + bytes(_PAD), dtype=np.uint8)
    return _decode_states_at(buf, np.cumsum(lengths) - lengths, lengths)


def _decode_states_at(buf: np.ndarray, pos: np.ndarray, lengths: np.ndarray
                      ) -> dict[str, np.ndarray]:
    """:func:`decode_object_states` for states at byte positions ``pos`` of ``buf`` (which
    ends with ``_PAD`` zero bytes)."""
    n = len(lengths)
    ends = pos + lengths
    out: dict[str, np.ndarray] = {name: np.zeros(n, np.float64) for name in _FIXED64.values()}
    out.update({name: np.zeros(n, np.float32) for name in _FIXED32.values()})
    out["valid"] = np.zeros(n, dtype=bool)
    rest = _decode_uniform(buf, pos, lengths, out)
    _decode_generic(buf, pos, ends, rest, out)
    return out


def _state_positions(buf: np.ndarray, first: np.ndarray, n_steps: int
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Positions and lengths of the ``states`` fields of serialized tracks.

    Each track's ``n_steps`` states follow one another from ``first`` (protobuf writes
    fields in number order: id, object_type, then the states). Tracks whose states all
    have the first one's length are placed at once; the others are walked in lockstep.

    Returns:
        (n_tracks, n_steps) int64 payload positions and lengths.

    Raises:
        StateDecodeError: a field other than a state where a state should be.
    """
    n_tracks = len(first)
    first = first.astype(np.int64)
    # Most tracks have states of one length (every field set, or WOMD's short invalid
    # states throughout): their positions follow from the first one. Check them all at once.
    length = buf[first + 1].astype(np.int64)
    stride = np.where(length < 0x80, length + 2, 0)
    grid = np.minimum(first[:, None] + stride[:, None] * np.arange(n_steps), len(buf) - 2)
    regular = ((stride > 0) & (buf[grid] == _STATES_TAG).all(axis=1)
        & (buf[grid + 1] == length[:, None]).all(axis=1))
    pos = grid + 2
    size = np.broadcast_to(length[:, None], (n_tracks, n_steps)).copy()
    others = np.flatnonzero(~regular)
    if others.size:
        pos[others], size[others] = _walk_states(buf, first[others], n_steps, others)
    return pos.ravel(), size.ravel()


def _walk_states(buf: np.ndarray, first: np.ndarray, n_steps: int, tracks: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """State positions and lengths of tracks whose states differ in length, walked in
    lockstep: one state of every track per step. ``tracks`` numbers them for errors."""
    pos = np.empty((n_steps, len(first)), dtype=np.int64)
    size = np.empty((n_steps, len(first)), dtype=np.int64)
    at = first
    for step in range(n_steps):
        tags = buf[at]
        if (tags != _STATES_TAG).any():
            track = int(tracks[np.flatnonzero(tags != _STATES_TAG)[0]])
            raise StateDecodeError("expected a state (field 3) here", track * n_steps + step)
        length = buf[at + 1].astype(np.int64)
        if (length & 0x80).any():  # a state of 128 bytes or more: a longer varint
            value, start, too_long = _varint(buf, at + 1)
            if too_long.any():
                track = int(tracks[np.flatnonzero(too_long)[0]])
                raise StateDecodeError("malformed length of a state", track * n_steps + step)
            length = value.astype(np.int64)
        else:
            start = at + 2
        pos[step] = start
        size[step] = length
        at = start + length
    return pos.T, size.T


def _header_size(track: bytes) -> int:
    """Bytes before the first state of a serialized track: its id and type fields."""
    at = 0
    while at < len(track) and track[at] in (0x08, 0x10):  # id (1) and object_type (2)
        at += 1
        while track[at] & 0x80:
            at += 1
        at += 1
    return at


_UNIFORM_MIN = 32
"""Groups of fewer same-length states go through the generic walk."""


def _layout(buf: np.ndarray, start: int, length: int) -> list[tuple[int, int, int]] | None:
    """The fields of one state as (field, wire type, value offset), when every tag, varint
    and length prefix in it is one byte; None otherwise (or when the bytes are malformed)."""
    layout = []
    at = 0
    while at < length:
        tag = int(buf[start + at])
        if tag & 0x80 or tag >> 3 == 0:
            return None
        wire = tag & 7
        at += 1
        if wire == 0:
            if buf[start + at] & 0x80:
                return None
            size = 1
        elif wire == 1:
            size = 8
        elif wire == 5:
            size = 4
        elif wire == 2:
            if buf[start + at] & 0x80:
                return None
            size = 1 + int(buf[start + at])
        else:
            return None
        layout.append((tag >> 3, wire, at))
        at += size
    return layout if at == length else None


def _decode_uniform(buf: np.ndarray, pos: np.ndarray, lengths: np.ndarray,
                    out: dict[str, np.ndarray]) -> np.ndarray:
    """Decode the states that share their length and layout with many others.

    States of one length whose tag bytes, one-byte varints and length prefixes all match a
    sample state of that length are parsed identically, so their fields sit at fixed
    offsets and are read as columns. Returns the indices of the states left over.
    """
    n = len(lengths)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    if (lengths == lengths[0]).all():
        groups = [(int(lengths[0]), None)]
    else:
        values, counts = np.unique(lengths, return_counts=True)
        groups = [(int(v), np.flatnonzero(lengths == v))
                  for v, c in zip(values, counts, strict=True) if c >= _UNIFORM_MIN]
    done = np.zeros(n, dtype=bool)
    for length, members in groups:
        first = int(pos[0] if members is None else pos[members[0]])
        layout = _layout(buf, first, length)
        if not layout or length == 0:
            continue
        if members is None:
            members = np.arange(n)
        rows = np.lib.stride_tricks.sliding_window_view(buf, length)[pos[members]]
        same = np.ones(len(members), dtype=bool)
        for _field, wire, at in layout:
            same &= rows[:, at - 1] == rows[0, at - 1]  # the tag
            if wire == 2:
                same &= rows[:, at] == rows[0, at]  # the length prefix
            elif wire == 0:
                same &= rows[:, at] < 0x80  # a one-byte varint
        if not same.all():
            members = members[same]
            rows = rows[same]
        # The fields as a structured view of the rows: one strided copy per column.
        names, formats, offsets = [], [], []
        for field, wire, at in layout:  # a repeated field keeps its last occurrence
            name = (_FIXED64.get(field) if wire == 1 else _FIXED32.get(field) if wire == 5
                    else "valid" if wire == 0 and field == _VALID_FIELD else None)
            if name is None:
                continue
            if name in names:
                del formats[names.index(name)], offsets[names.index(name)]
                names.remove(name)
            names.append(name)
            formats.append({1: "<f8", 5: "<f4", 0: "u1"}[wire])
            offsets.append(at)
        view = np.ascontiguousarray(rows).view(np.dtype(
            {"names": names, "formats": formats, "offsets": offsets, "itemsize": length}))
        view = view.ravel()
        everything = len(members) == n
        for name in names:
            values = view[name] != 0 if name == "valid" else view[name]
            if everything:
                out[name][:] = values
            else:
                out[name][members] = values
        done[members] = True
    return np.flatnonzero(~done)


def _column(rows: np.ndarray, at: int, size: int, dtype: str) -> np.ndarray:
    return np.ascontiguousarray(rows[:, at:at + size]).view(dtype).ravel()


def _decode_generic(buf: np.ndarray, pos: np.ndarray, ends: np.ndarray, active: np.ndarray,
                    out: dict[str, np.ndarray]) -> None:
    """Walk the fields of the states ``active``, one field of every state per step."""
    pos = pos.copy()
    active = active[pos[active] < ends[active]]
    while active.size:
        p = pos[active]
        tag, p, bad_tag = _varint(buf, p)
        field = (tag >> np.uint64(3)).astype(np.int64)
        wire = (tag & np.uint64(7)).astype(np.int64)
        nxt = np.full(len(p), -1, dtype=np.int64)
        bad = bad_tag | (field == 0)

        sel = np.flatnonzero(wire == 0)
        if sel.size:
            value, q, too_long = _varint(buf, p[sel])
            nxt[sel] = q
            bad[sel] |= too_long
            is_valid = field[sel] == _VALID_FIELD
            out["valid"][active[sel[is_valid]]] = value[is_valid] != 0
        for wt, size, dtype, names in ((1, 8, "<f8", _FIXED64), (5, 4, "<f4", _FIXED32)):
            sel = np.flatnonzero(wire == wt)
            if not sel.size:
                continue
            nxt[sel] = p[sel] + size
            known = np.isin(field[sel], list(names))
            if known.any():
                sel_known = sel[known]
                values = _gather(buf, p[sel_known], size, dtype)
                fields = field[sel_known]
                for number, name in names.items():
                    hit = fields == number
                    out[name][active[sel_known[hit]]] = values[hit]
        sel = np.flatnonzero(wire == 2)
        if sel.size:
            size, q, too_long = _varint(buf, p[sel])
            bad[sel] |= too_long | (size > np.uint64(1 << 40))
            nxt[sel] = q + np.minimum(size, np.uint64(1 << 40)).astype(np.int64)
        bad |= (nxt < 0) | (nxt > ends[active])  # groups, wire types 6/7, overruns
        if bad.any():
            first = int(active[np.flatnonzero(bad)[0]])
            raise StateDecodeError("malformed ObjectState bytes (bad tag, wire type or a "
                                   "field running past the end of the state)", first)
        pos[active] = nxt
        active = active[nxt < ends[active]]


def normalise_object_types(object_types: Iterable[str] | str | None) -> frozenset[str] | None:
    """Check an ``object_types`` argument: None (all) or names from the contract."""
    if object_types is None:
        return None
    if isinstance(object_types, str):
        object_types = [object_types]
    names = []
    for name in object_types:
        if str(name).lower() not in OBJECT_TYPES:
            raise did_you_mean("object type", name, OBJECT_TYPES)
        names.append(str(name).lower())
    return frozenset(names)


def _kept_states(record: Record, chunks: list[bytes], first: list[int], n_steps: int,
                 track_ids: list[str]) -> dict[str, np.ndarray]:
    """The kept tracks' states, decoded from their serialized ``Track`` messages.

    Args:
        record: the record (names it in errors).
        chunks: each kept track's serialized message, in order.
        first: where each kept track's first state starts in the joined messages [bytes].
        n_steps: states per track.
        track_ids: the kept tracks' ids (name a faulty state's track).

    Returns:
        The state columns, each an array of n_tracks * n_steps values, track by track.

    Raises:
        WomdRecordError: a state is not well formed (its track and step named).
    """
    try:
        buf = np.frombuffer(b"".join(chunks) + bytes(_PAD), dtype=np.uint8)
        from tap_bench.womd.state_wire import decode_track_states

        st = decode_track_states(buf, np.array(first, dtype=np.int64), n_steps,
                                 len(buf) - _PAD)
        if st is None:  # not well formed: the numpy walk finds and names the fault
            pos, lengths = _state_positions(buf, np.array(first, dtype=np.int64), n_steps)
            if (pos + lengths > len(buf) - _PAD).any():
                raise StateDecodeError("a state runs past the end of its track",
                                       int(np.flatnonzero(pos + lengths > len(buf) - _PAD)[0]))
            st = _decode_states_at(buf, pos, lengths)
    except StateDecodeError as err:
        track_pos, step = divmod(err.state, n_steps)
        raise record.error(f"track {track_ids[track_pos]} state {step}: {err}",
                           _NOT_A_SCENARIO) from None
    return st


def decode_scenario(record: Record, *, object_types: frozenset[str] | None = None,
                    source: str = "womd") -> pa.Table:
    """Decode one ``Scenario`` record into a trajectory table (Arrow; ``.to_pandas()``).

    Args:
        record: the record (its path, index and offset name it in errors).
        object_types: keep only tracks of these types (None keeps all).
        source: the value of the ``source`` column.

    Returns:
        The table with :data:`SCENARIO_COLUMNS`, one row per kept track per time step
        (n_tracks * n_steps rows, track by track, steps in time order).

    Raises:
        WomdRecordError: the record is not a Scenario, or is inconsistent (a track whose
            state count differs from the number of timestamps, an unknown object type, an
            SDC index or track to predict out of range).
    """
    try:
        view = proto.ScenarioView.FromString(record.data)
    except DecodeError as err:
        raise record.error(
            f"not a serialized WOMD Scenario proto (protobuf: {err})",
            _NOT_A_SCENARIO) from None
    times = np.array(view.timestamps_seconds, dtype=np.float64)
    n_steps = len(times)
    if not view.scenario_id and (n_steps == 0 or not len(view.tracks)):
        raise record.error("the record has no scenario_id, no timestamps or no tracks: it "
                           "is not a WOMD Scenario", _NOT_A_SCENARIO)
    if not view.scenario_id:
        raise record.error("the scenario has no scenario_id", "Every scenario needs its id: "
                           "without one it would be merged with other scenarios. `tap-bench "
                           "ingest --on-error skip` (on_error='skip') keeps the file's other "
                           "records; a rollout reads whole files: leave this one out.")
    if n_steps == 0:
        raise record.error(f"scenario {view.scenario_id!r} has no timestamps_seconds",
                           "The scenario is incomplete. `tap-bench ingest --on-error skip` "
                           "(on_error='skip') keeps the file's other records; a rollout reads "
                           "whole files: leave this one out.")
    tracks = view.tracks
    n_tracks = len(tracks)
    sdc = view.sdc_track_index if view.HasField("sdc_track_index") else -1
    if sdc >= n_tracks or sdc < -1:
        raise record.error(f"sdc_track_index {sdc} is out of range for {n_tracks} tracks",
                           _INCONSISTENT)
    interest = set(view.objects_of_interest)
    difficulty = np.zeros(n_tracks, dtype=np.int8)
    to_predict = np.zeros(n_tracks, dtype=bool)
    for req in view.tracks_to_predict:
        if not 0 <= req.track_index < n_tracks:
            raise record.error(f"tracks_to_predict names track index {req.track_index}, out "
                               f"of range for {n_tracks} tracks", _INCONSISTENT)
        to_predict[req.track_index] = True
        difficulty[req.track_index] = req.difficulty

    kept: list[int] = []
    type_names: list[str] = []
    track_ids: list[str] = []
    extra_json: list[str] = []
    first: list[int] = []  # where each kept track's first state is, in the joined tracks
    offset = 0
    chunks: list[bytes] = []
    seen: set[str] = set()
    for i, track in enumerate(tracks):
        type_name = proto.OBJECT_TYPE_NAMES.get(track.object_type)
        if type_name is None:
            raise record.error(
                f"track {track.id} (index {i}) has unknown object type {track.object_type}; "
                "WOMD knows 0 UNSET, 1 VEHICLE, 2 PEDESTRIAN, 3 CYCLIST, 4 OTHER",
                "The file may come from a newer WOMD release or be damaged; skip the "
                "record with on_error='skip'.")
        track_id = track.tap_bench_track_id or str(track.id)
        if track_id in seen:
            raise record.error(f"track id {track_id} appears twice in scenario "
                               f"{view.scenario_id!r}", _INCONSISTENT)
        seen.add(track_id)
        if object_types is not None and type_name not in object_types:
            continue
        states = track.states
        if len(states) != n_steps:
            raise record.error(
                f"track {track_id} (index {i}) has {len(states)} states for {n_steps} "
                "timestamps", _INCONSISTENT)
        kept.append(i)
        type_names.append(type_name)
        track_ids.append(track_id)
        extra_json.append(track.tap_bench_columns)
        serialized = track.SerializeToString()
        first.append(offset + _header_size(serialized))
        offset += len(serialized)
        chunks.append(serialized)
    st = _kept_states(record, chunks, first, n_steps, track_ids)
    problem = bad_box_size(track_ids, n_steps, st)
    if problem is not None:
        raise record.error(problem, BOX_SIZE_FIX)
    kept_arr = np.asarray(kept, dtype=np.int64)
    womd_ids = np.array([tracks[i].id for i in kept], dtype=np.int64)
    table = trajectory_table(
        view.scenario_id, times, track_ids, type_names, st, is_ego=kept_arr == sdc,
        object_of_interest=np.isin(womd_ids, list(interest)),
        track_to_predict=to_predict[kept_arr], prediction_difficulty=difficulty[kept_arr],
        source=source)
    if any(extra_json):
        try:
            table = restore_extra_columns(table, extra_json, n_steps)
        except ValueError as err:
            raise record.error(f"the tap-bench columns (Track field 51002) cannot be read: "
                               f"{err}", _INCONSISTENT) from None
    return table


_NOT_A_SCENARIO = ("Is the file a WOMD scenario file (uncompressed/scenario/...)? A file of "
                   "tf.Example records (tf_example/...) is read with format='tf_example'.")
_INCONSISTENT = "The scenario is inconsistent (a damaged file?); skip it with on_error='skip'."


def wrap_heading(heading: np.ndarray) -> np.ndarray:
    """Headings beyond [-pi, pi] (WOMD has some, up to about 3 pi) wrapped into [-pi, pi);
    the others are left bit for bit."""
    out = heading.copy()
    beyond = np.abs(heading) > np.pi
    out[beyond] = np.remainder(heading[beyond] + np.pi, 2 * np.pi) - np.pi
    return out


def repeated_strings(strings: Sequence[str], repeats: int | Sequence[int]) -> pa.Array:
    """An Arrow string array holding ``strings[i]`` ``repeats[i]`` times in a row, built
    without a Python object per row."""
    encoded = [s.encode() for s in strings]
    if isinstance(repeats, int):
        repeats = [repeats] * len(encoded)
    counts = np.asarray(repeats, dtype=np.int64)
    sizes = np.repeat(np.fromiter(map(len, encoded), np.int64, len(encoded)), counts)
    offsets = np.zeros(len(sizes) + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    data = b"".join(e * int(r) for e, r in zip(encoded, counts, strict=True))
    if offsets[-1] < 2**31:
        return pa.StringArray.from_buffers(len(sizes), pa.py_buffer(offsets.astype(np.int32)),
                                           pa.py_buffer(data))
    return pa.LargeStringArray.from_buffers(len(sizes), pa.py_buffer(offsets),
                                            pa.py_buffer(data)).cast(pa.string())


STATE_COLUMNS = ("x", "y", "z", "heading", "vx", "vy", "length", "width", "height")
"""Per-step kinematic columns of :func:`trajectory_table` (NaN on invalid steps)."""


BOX_SIZES = ("length", "width", "height")
"""An agent's box [m]: on a valid step each is a positive, finite length
(:func:`bad_box_size`)."""
BOX_SIZE_FIX = ("A box size on a valid step is a positive length in metres; the record was "
                "damaged or made by a faulty converter. Fix the converter, or leave the "
                "record out (tap-bench ingest --on-error skip keeps the others).")


def bad_box_size(track_ids: Sequence[str], n_steps: int, states: Mapping[str, np.ndarray],
                 sizes: Sequence[str] = BOX_SIZES) -> str | None:
    """The first zero, negative or NaN box size on a valid step, in words (track, step,
    size and value), or None when every one is a positive length.

    Args:
        track_ids: (n_tracks,) ids; ``states``: (n_tracks * n_steps,) arrays, track by
            track, ``valid`` and the sizes.
        sizes: the sizes the record holds (a size it does not hold is not checked).
    """
    valid = np.asarray(states["valid"], dtype=bool)
    for name in sizes:
        values = np.asarray(states[name], dtype=np.float64)
        bad = valid & ~(np.isfinite(values) & (values > 0))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            track, step = divmod(i, n_steps)
            return (f"track {track_ids[track]} step {step}: {name} {values[i]!r} is not a "
                    "box size (a positive length in metres)")
    return None


def trajectory_table(scenario_id: str, times: np.ndarray, track_ids: Sequence[str],
                     object_types: Sequence[str], states: Mapping[str, np.ndarray], *,
                     is_ego: np.ndarray, object_of_interest: np.ndarray,
                     track_to_predict: np.ndarray, prediction_difficulty: np.ndarray,
                     source: str) -> pa.Table:
    """One scenario's tracks as a trajectory table with :data:`SCENARIO_COLUMNS`.

    The common last step of every reader (Scenario, tf.Example, ScenarioNet).

    Args:
        scenario_id: the scenario.
        times: (n_steps,) time of each step [s].
        track_ids, object_types: (n_tracks,) strings.
        states: (n_tracks * n_steps,) arrays, track by track: ``valid`` (bool) and
            :data:`STATE_COLUMNS` (positions and sizes [m], heading [rad], velocity
            [m/s]; any float dtype).
        is_ego, object_of_interest, track_to_predict: (n_tracks,) bool.
        prediction_difficulty: (n_tracks,) int, 0 where not to predict.
        source: the value of the ``source`` column.

    Returns:
        The table; kinematics are NaN on invalid steps, ``speed = hypot(vx, vy)`` and
        headings beyond pi are wrapped (:func:`wrap_heading`).
    """
    n_steps = len(times)
    n = len(track_ids) * n_steps
    valid = np.asarray(states["valid"], dtype=bool)
    kin = {name: np.array(states[name], dtype=np.float64) for name in STATE_COLUMNS}
    kin["heading"] = wrap_heading(kin["heading"])
    kin["speed"] = np.hypot(kin["vx"], kin["vy"])
    for values in kin.values():
        values[~valid] = np.nan

    def per_track(values: np.ndarray, dtype: type) -> np.ndarray:
        return np.repeat(np.asarray(values, dtype=dtype), n_steps)

    return pa.table({
        "scenario_id": repeated_strings([scenario_id], n),
        "track_id": repeated_strings(list(track_ids), n_steps),
        "t": np.tile(np.asarray(times, dtype=np.float64), len(track_ids)),
        "x": kin["x"], "y": kin["y"], "heading": kin["heading"], "speed": kin["speed"],
        "valid": valid, "vx": kin["vx"], "vy": kin["vy"],
        "object_type": repeated_strings(list(object_types), n_steps),
        "is_ego": per_track(is_ego, bool),
        "source": repeated_strings([source], n),
        "z": kin["z"], "length": kin["length"], "width": kin["width"],
        "height": kin["height"],
        "object_of_interest": per_track(object_of_interest, bool),
        "track_to_predict": per_track(track_to_predict, bool),
        "prediction_difficulty": per_track(prediction_difficulty, np.int8),
    })
