"""TFRecord framing: round trips, GZIP, and corrupted copies that give the documented errors."""

from __future__ import annotations

import gzip
import struct

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tap_bench.errors import WomdRecordError
from tap_bench.womd.tfrecord import TFRecordWriter, iter_records

PAYLOADS = [b"first record", b"", b"x" * 5000, b"last"]


def write(path, payloads, compress=False):
    with TFRecordWriter(path, compress=compress) as writer:
        for p in payloads:
            writer.write(p)
    return path


def offsets(payloads):
    out, at = [], 0
    for p in payloads:
        out.append(at)
        at += 16 + len(p)
    return out


@settings(max_examples=30, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(payloads=st.lists(st.binary(max_size=3000), max_size=6), compress=st.booleans())
def test_records_round_trip_with_their_index_and_offset(tmp_path, payloads, compress):
    path = write(tmp_path / "r.tfrecord", payloads, compress)
    records = list(iter_records(path))
    assert [r.data for r in records] == payloads
    assert [r.index for r in records] == list(range(len(payloads)))
    assert [r.offset for r in records] == offsets(payloads)


def test_gzip_file_is_recognised_by_content_not_name(tmp_path):
    path = write(tmp_path / "no_suffix", PAYLOADS, compress=True)
    assert path.read_bytes()[:2] == b"\x1f\x8b"
    assert [r.data for r in iter_records(path)] == PAYLOADS


def test_framing_matches_the_tfrecord_layout(tmp_path):
    path = write(tmp_path / "r.tfrecord", [b"123456789"])
    raw = path.read_bytes()
    assert struct.unpack("<Q", raw[:8])[0] == 9
    assert raw[12:21] == b"123456789"
    assert len(raw) == 8 + 4 + 9 + 4


def corrupt(tmp_path, position, value=None, truncate=None, payloads=PAYLOADS):
    path = write(tmp_path / "r.tfrecord", payloads)
    raw = bytearray(path.read_bytes())
    if truncate is not None:
        raw = raw[:truncate]
    else:
        raw[position] = value if value is not None else raw[position] ^ 0xFF
    path.write_bytes(bytes(raw))
    return path


def test_flipped_data_byte_names_file_record_offset_and_crc(tmp_path):
    third = offsets(PAYLOADS)[2]
    path = corrupt(tmp_path, third + 12 + 100)
    with pytest.raises(WomdRecordError) as info:
        list(iter_records(path))
    err = info.value
    assert (err.path, err.record, err.offset) == (str(path), 2, third)
    assert "CRC of the 5000 data bytes" in str(err)
    assert f"record 2 at byte {third}" in str(err)
    assert err.resumable


def test_bad_data_crc_can_be_skipped_and_reading_goes_on(tmp_path):
    path = corrupt(tmp_path, offsets(PAYLOADS)[2] + 12 + 100)
    errors = []
    data = [r.data for r in iter_records(path, on_error=errors.append)]
    assert data == [PAYLOADS[0], PAYLOADS[1], PAYLOADS[3]]
    assert [e.record for e in errors] == [2]


def test_unchecked_crc_reads_the_damaged_bytes(tmp_path):
    path = corrupt(tmp_path, offsets(PAYLOADS)[2] + 12 + 100)
    assert len(list(iter_records(path, check_crc=False))) == 4


def test_wrong_length_field_is_caught_by_its_crc_and_stops_the_file(tmp_path):
    second = offsets(PAYLOADS)[1]
    path = corrupt(tmp_path, second, value=200)  # record 1 is empty: say 200 bytes
    errors = []
    data = [r.data for r in iter_records(path, on_error=errors.append)]
    assert data == [PAYLOADS[0]]
    assert len(errors) == 1
    assert (errors[0].record, errors[0].offset) == (1, second)
    assert "length field" in errors[0].problem
    assert not errors[0].resumable


def test_truncated_record(tmp_path):
    third = offsets(PAYLOADS)[2]
    path = corrupt(tmp_path, None, truncate=third + 12 + 4000)
    with pytest.raises(WomdRecordError, match=r"record 2 at byte \d+: truncated") as info:
        list(iter_records(path))
    assert info.value.offset == third


def test_file_ending_inside_a_header(tmp_path):
    last = offsets(PAYLOADS)[3]
    path = corrupt(tmp_path, None, truncate=last + 5)
    with pytest.raises(WomdRecordError, match="ends 5 bytes into a record's 12-byte length"):
        list(iter_records(path))


def test_a_file_that_is_not_a_tfrecord(tmp_path):
    path = tmp_path / "notes.txt"
    path.write_text("these are not the records you are looking for")
    with pytest.raises(WomdRecordError, match=r"record 0 at byte 0: .*not a TFRecord file"):
        list(iter_records(path))


def test_damaged_gzip_stream(tmp_path):
    path = tmp_path / "r.tfrecord.gz"
    data = gzip.compress(write(tmp_path / "plain", PAYLOADS).read_bytes())
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(WomdRecordError, match="GZIP stream is damaged or cut short"):
        list(iter_records(path))
