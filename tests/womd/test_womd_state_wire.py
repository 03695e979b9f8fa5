"""Tracks' states decoded in one compiled pass (:func:`tap_bench.womd.state_wire.
decode_track_states`) equal the numpy decoder's (:func:`tap_bench.womd.scenario.
decode_object_states`), bit for bit, for any subset of fields, repeated and unknown fields,
states of any length; bytes that are not well formed are left to the numpy decoder."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tap_bench.womd import proto
from tap_bench.womd.scenario import _PAD, decode_object_states
from tap_bench.womd.state_wire import decode_track_states

F32 = st.floats(width=32, allow_nan=True)
STATE = st.fixed_dictionaries({}, optional={
    "center_x": st.floats(), "center_y": st.floats(), "center_z": st.floats(),
    "length": F32, "width": F32, "height": F32, "heading": F32, "velocity_x": F32,
    "velocity_y": F32, "valid": st.booleans()})


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte, value = value & 0x7F, value >> 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def _field(number: int, wire: int, payload: bytes) -> bytes:
    return _varint(number << 3 | wire) + (_varint(len(payload)) if wire == 2 else b"") + payload


def _tracks(blobs: list[bytes], n_steps: int, header: bytes = b"\x08\x07\x10\x01"):
    """Tracks of ``n_steps`` states each (a header, then the states as field 3), joined,
    padded as decode_scenario pads them: (buffer, first state of each track, end)."""
    chunks, first, at = [], [], 0
    for k in range(0, len(blobs), n_steps):
        track = header + b"".join(_field(3, 2, b) for b in blobs[k:k + n_steps])
        first.append(at + len(header))
        at += len(track)
        chunks.append(track)
    data = b"".join(chunks)
    return np.frombuffer(data + bytes(_PAD), np.uint8), np.array(first, np.int64), len(data)


def _assert_equal(got: dict, want: dict) -> None:
    assert set(got) == set(want)
    for name in want:
        assert got[name].dtype == want[name].dtype, name
        assert np.array_equal(got[name].view(np.uint8), want[name].view(np.uint8)), name


@settings(max_examples=80, deadline=None)
@given(states=st.lists(st.lists(STATE, min_size=1, max_size=3), min_size=1, max_size=60),
       n_steps=st.integers(1, 4),
       unknown=st.lists(st.tuples(st.integers(12, 3000), st.sampled_from([0, 1, 2, 5]),
                                  st.binary(max_size=150)), max_size=3))
def test_states_equal_the_numpy_decoders(states, n_steps, unknown):
    blobs = []
    for parts in states:
        blob = b"".join(proto.ObjectState(**p).SerializeToString() for p in parts)
        for number, wire, payload in unknown:
            blob += (_field(number, 2, payload) if wire == 2 else _field(number, 0, b"\x05")
                     if wire == 0 else _field(number, wire, bytes(8 if wire == 1 else 4)))
        blobs.append(blob)
    blobs = blobs[:len(blobs) // n_steps * n_steps] or blobs[:1] * n_steps
    buf, first, end = _tracks(blobs, n_steps)
    got = decode_track_states(buf, first, n_steps, end)
    assert got is not None
    _assert_equal(got, decode_object_states(b"".join(blobs), np.array([len(b) for b in blobs])))


def test_a_known_field_of_another_wire_type_is_skipped_as_protobuf_does():
    blob = (proto.ObjectState(center_x=2.5, valid=True).SerializeToString()
            + _field(3, 0, b"\x09") + _field(5, 1, bytes(8)) + _field(11, 5, bytes(4)))
    buf, first, end = _tracks([blob], 1)
    got = decode_track_states(buf, first, 1, end)
    assert got["x"][0] == 2.5 and got["y"][0] == 0.0 and got["valid"][0]
    _assert_equal(got, decode_object_states(blob, np.array([len(blob)])))


@pytest.mark.parametrize("case", ["not a state", "a double cut short", "past the end",
                                  "a group", "field 0"])
def test_bytes_not_well_formed_are_left_to_the_numpy_decoder(case):
    good = proto.ObjectState(center_x=1.0, valid=True).SerializeToString()
    blobs = {"a double cut short": [good, b"\x11\x00\x00"],
             "a group": [good, b"\x13\x14"], "field 0": [good, b"\x00\x01"]}.get(case,
                                                                               [good, good])
    buf, first, end = _tracks(blobs, 2)
    if case == "not a state":
        buf = buf.copy()
        buf[first[0] + len(good) + 2] = 0x22  # the second state as field 4
    if case == "past the end":
        end -= 1
    assert decode_track_states(buf, first, 2, end) is None
