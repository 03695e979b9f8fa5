"""CRC-32C: the package and the numpy fallback give the same, known checksums."""

from __future__ import annotations

import crc32c as crc32c_package
from hypothesis import given, settings
from hypothesis import strategies as st

from tap_bench.womd.checksum import crc32c, crc32c_numpy, masked_crc32c


def test_check_value_of_both_implementations():
    assert crc32c(b"123456789") == 0xE3069283
    assert crc32c_numpy(b"123456789") == 0xE3069283


def test_masked_crc_of_empty_data_is_the_mask_constant():
    assert masked_crc32c(b"") == 0xA282EAD8


def test_masked_crc_rotates_then_adds():
    crc = 0xE3069283
    rotated = ((crc >> 15) | (crc << 17)) & 0xFFFFFFFF
    assert masked_crc32c(b"123456789") == (rotated + 0xA282EAD8) & 0xFFFFFFFF


@settings(max_examples=40, deadline=None)
@given(st.binary(min_size=0, max_size=20_000), st.integers(0, 20_000))
def test_numpy_fallback_matches_the_package(data, cut):
    assert crc32c_numpy(data) == crc32c_package.crc32c(data)
    cut = min(cut, len(data))
    assert crc32c_numpy(data[cut:], crc32c_numpy(data[:cut])) == crc32c_package.crc32c(data)


def test_numpy_fallback_on_a_megabyte_not_a_multiple_of_its_chunk():
    data = bytes(range(256)) * 4099 + b"tail"
    assert crc32c_numpy(data) == crc32c_package.crc32c(data)
