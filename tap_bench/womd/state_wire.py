"""WOMD tracks' ``ObjectState`` messages decoded in one compiled pass: what
:func:`tap_bench.womd.scenario.decode_object_states` and the track walk before it do with
numpy, field by field across every state, for records whose bytes are well formed.

``ObjectState`` (WOMD's scenario.proto): center_x 2, center_y 3, center_z 4 (double),
length 5, width 6, height 7, heading 8, velocity_x 9, velocity_y 10 (float), valid 11
(bool); a track's states are its field 3, one after another. As protobuf reads them: absent
fields are 0 (false), a field met twice keeps its last value, unknown fields and fields of
another wire type are skipped. Bytes the numpy decoder would refuse (a field other than a
state where a state belongs, a bad tag or length, a state running past the end, a group)
are left to it, and it names the fault.
"""

from __future__ import annotations

import numba
import numpy as np

from tap_bench.womd.map_wire import _as_float, _double, _varint

__all__ = ["decode_track_states"]

_STATES_TAG = 3 << 3 | 2


def decode_track_states(buf: np.ndarray, first: np.ndarray, n_steps: int, end: int
                        ) -> dict[str, np.ndarray] | None:
    """Every track's ``n_steps`` states, decoded at once.

    Args:
        buf: the serialized tracks (uint8), any padding after ``end``.
        first: (n_tracks,) where each track's first state field starts in ``buf``.
        n_steps: states a track holds.
        end: where the tracks' bytes end.

    Returns:
        (n_tracks * n_steps,) arrays, track by track, as
        :func:`~tap_bench.womd.scenario.decode_object_states` gives them, or None where the
        bytes are not well formed (the numpy decoder then says why).
    """
    ok, x, y, z, sizes, valid = _decode(buf, np.asarray(first, np.int64), n_steps, end)
    if not ok:
        return None
    names = ("length", "width", "height", "heading", "vx", "vy")
    return {"x": x, "y": y, "z": z, **{name: sizes[:, k].copy()
                                       for k, name in enumerate(names)}, "valid": valid}


@numba.njit(cache=True, nogil=True)
def _decode(buf, first, n_steps, end):  # pragma: no cover - compiled
    """(ok, x, y, z, the six float32 fields as (n, 6), valid) of the states of tracks
    starting at ``first`` (module docstring); ok False where the bytes are malformed."""
    n = len(first) * n_steps
    x = np.zeros(n)
    y = np.zeros(n)
    z = np.zeros(n)
    sizes = np.zeros((n, 6), np.float32)
    valid = np.zeros(n, np.bool_)
    for track in range(len(first)):
        at = first[track]
        for step in range(n_steps):
            i = track * n_steps + step
            if at >= end or buf[at] != _STATES_TAG:
                return False, x, y, z, sizes, valid
            size, pos = _varint(buf, at + 1, end)
            if pos < 0 or size > np.uint64(end - pos):
                return False, x, y, z, sizes, valid
            stop = pos + np.int64(size)
            at = stop
            while pos < stop:
                tag, pos = _varint(buf, pos, stop)
                if pos < 0:
                    return False, x, y, z, sizes, valid
                field = np.int64(tag >> np.uint64(3))
                wire = np.int64(tag & np.uint64(7))
                if field == 0:
                    return False, x, y, z, sizes, valid
                if wire == 0:
                    value, pos = _varint(buf, pos, stop)
                    if pos < 0:
                        return False, x, y, z, sizes, valid
                    if field == 11:
                        valid[i] = value != 0
                elif wire == 1:
                    if pos + 8 > stop:
                        return False, x, y, z, sizes, valid
                    if field == 2:
                        x[i] = _double(buf, pos)
                    elif field == 3:
                        y[i] = _double(buf, pos)
                    elif field == 4:
                        z[i] = _double(buf, pos)
                    pos += 8
                elif wire == 5:
                    if pos + 4 > stop:
                        return False, x, y, z, sizes, valid
                    if 5 <= field <= 10:
                        bits32 = np.uint32(0)
                        for k in range(4):
                            bits32 |= np.uint32(buf[pos + k]) << np.uint32(8 * k)
                        sizes[i, field - 5] = _as_float(bits32, np.float32)
                    pos += 4
                elif wire == 2:
                    length, pos = _varint(buf, pos, stop)
                    if pos < 0 or length > np.uint64(stop - pos):
                        return False, x, y, z, sizes, valid
                    pos += np.int64(length)
                else:
                    return False, x, y, z, sizes, valid
    return True, x, y, z, sizes, valid
