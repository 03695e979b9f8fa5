"""TFRecord files, read and written record by record without TensorFlow.

A TFRecord file is a sequence of records, each framed as::

    uint64 length (little-endian) | uint32 masked CRC-32C of those 8 bytes
    data (length bytes)           | uint32 masked CRC-32C of the data

Files may be GZIP-compressed as a whole (TensorFlow's ``compression_type="GZIP"``); the
reader recognises them by their magic bytes, whatever their name.

A record is read whole, so its length is bounded: :data:`MAX_RECORD_BYTES` (64 MiB) by
default, more than 50 times the largest WOMD record seen (about 1.2 MB, a 9 s scenario with
its map). A longer one is an error naming the limit, and the option that raises it; its
bytes are skipped in chunks, never held, so a damaged or hostile file (a small GZIP file
announcing a 2 GiB record) cannot make the reader allocate what it announces.
"""

from __future__ import annotations

import gzip
import os
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from tap_bench.errors import WomdRecordError
from tap_bench.womd.checksum import masked_crc32c

__all__ = ["MAX_RECORD_BYTES", "Record", "TFRecordWriter", "describe_start", "iter_records",
           "looks_like_tfrecord", "read_record"]

MAX_RECORD_BYTES = 64 << 20
"""The longest record read by default [B]; raise it with ``max_record_bytes``
(``--max-record-mb`` on the command line)."""
_SKIP_CHUNK = 1 << 20

_HEADER = struct.Struct("<QI")
_CRC = struct.Struct("<I")
_GZIP_MAGIC = b"\x1f\x8b"
_DAMAGED = ("The file is damaged (an interrupted download or copy?): fetch it again. "
            "`tap-bench ingest --on-error skip` (on_error='skip') keeps its other records; a "
            "rollout reads whole files: leave this one out.")


@dataclass(frozen=True)
class Record:
    """One record of a TFRecord file.

    Attributes:
        path: the file it came from.
        index: 0-based position of the record in the file.
        offset: byte offset of the record's length header (in the decompressed stream of a
            GZIP file).
        data: the record's payload.
    """

    path: str
    index: int
    offset: int
    data: bytes

    def error(self, problem: str, fix: str) -> WomdRecordError:
        """An error about this record, naming file, index and offset."""
        return WomdRecordError(self.path, self.index, self.offset, problem, fix)


def iter_records(
    path: str | os.PathLike,
    *,
    check_crc: bool = True,
    on_error: Callable[[WomdRecordError], None] | None = None,
    max_record_bytes: int = MAX_RECORD_BYTES,
) -> Iterator[Record]:
    """Yield the records of a TFRecord file (plain or GZIP) one at a time.

    Memory holds one record at a time, whatever the size of the file, and never more than
    ``max_record_bytes`` for it.

    Args:
        path: the file.
        check_crc: check both CRC-32C of every record (default). Turning it off saves the
            checksum time on trusted local copies.
        on_error: None (default) raises the first :class:`WomdRecordError`; a callable is
            given each error instead and reading goes on: after a bad data CRC or a record
            over the size limit with the next record, after broken framing (bad length CRC,
            truncation) with the next file, as the start of the next record is then
            unknown.
        max_record_bytes: the longest record read [B] (:data:`MAX_RECORD_BYTES`).

    Raises:
        WomdRecordError: a record with a bad CRC, a truncated record, trailing bytes too
            short for a header or a record longer than ``max_record_bytes``, naming the
            file, record and byte offset.
    """
    if (isinstance(max_record_bytes, bool) or not isinstance(max_record_bytes, int)
            or max_record_bytes < 1):
        raise ValueError(f"max_record_bytes must be a positive integer, got "
                         f"{max_record_bytes!r}.")
    path = str(path)
    raw = open(path, "rb")
    try:
        stream: BinaryIO = raw
        size: int | None = os.fstat(raw.fileno()).st_size
        if raw.peek(2)[:2] == _GZIP_MAGIC:
            stream = gzip.GzipFile(fileobj=raw, mode="rb")
            size = None  # the decompressed size is unknown until the end
        yield from _records(path, stream, check_crc, on_error, max_record_bytes, size)
    finally:
        if stream is not raw:
            stream.close()
        raw.close()


def read_record(path: str | os.PathLike, index: int, offset: int, *,
                check_crc: bool = True, max_record_bytes: int = MAX_RECORD_BYTES) -> Record:
    """The record ``index`` of a TFRecord file whose header starts at byte ``offset`` (as
    :func:`iter_records` gave it): one seek in a plain file, so a scene of a large file is
    read without the records before it; a GZIP file is read from its start (its
    decompressed offsets cannot be sought).

    Raises:
        WomdRecordError: a bad CRC or framing at that place (the file changed since its
            records were listed), naming file, index and offset.
    """
    path = str(path)
    with open(path, "rb") as raw:
        if raw.peek(2)[:2] == _GZIP_MAGIC:
            for record in iter_records(path, check_crc=check_crc,
                                       max_record_bytes=max_record_bytes):
                if record.index == index:
                    return record
        else:
            size = os.fstat(raw.fileno()).st_size
            raw.seek(offset)
            for record in _records(path, raw, check_crc, None, max_record_bytes, size,
                                   start=(index, offset)):
                return record
    raise WomdRecordError(path, index, offset, "no record here: the file is shorter than "
                          "when its records were listed", "List the file's scenes again.")


def looks_like_tfrecord(path: str | os.PathLike) -> bool:
    """Whether a file starts with a TFRecord length header whose CRC matches (plain or
    GZIP); an empty file does not."""
    try:
        with open(path, "rb") as raw:
            stream: BinaryIO = raw
            if raw.peek(2)[:2] == _GZIP_MAGIC:
                stream = gzip.GzipFile(fileobj=raw, mode="rb")
            header = stream.read(_HEADER.size)
    except (OSError, EOFError):
        return False
    if len(header) < _HEADER.size:
        return False
    return masked_crc32c(header[:8]) == _HEADER.unpack(header)[1]


def describe_start(data: bytes) -> str:
    """What the first bytes of a file look like, for a message: text, a known format, or
    the bytes themselves."""
    if not data:
        return "an empty file"
    known = {b"PK\x03\x04": "a ZIP archive", b"PAR1": "a Parquet file",
             b"\x89PNG": "a PNG image", b"%PDF": "a PDF document", b"\x80": "a Python pickle",
             b"{": "JSON text", b"[": "JSON text"}
    for magic, name in known.items():
        if data.startswith(magic):
            return f"{name} (it starts with {data[:12]!r})"
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        return f"binary data starting with {data[:12].hex(' ')}"
    if text.isprintable() or all(c.isprintable() or c.isspace() for c in text):
        return f"text starting with {text[:40]!r}"
    return f"binary data starting with {data[:12].hex(' ')}"


def _skip(stream: BinaryIO, n: int) -> int:
    """Read and drop ``n`` bytes in chunks; the number of bytes dropped."""
    dropped = 0
    while dropped < n:
        chunk = stream.read(min(_SKIP_CHUNK, n - dropped))
        if not chunk:
            break
        dropped += len(chunk)
    return dropped


def _records(path: str, stream: BinaryIO, check_crc: bool,
             on_error: Callable[[WomdRecordError], None] | None, max_record_bytes: int,
             size: int | None, start: tuple[int, int] = (0, 0)) -> Iterator[Record]:
    index, offset = start
    what = "plain file" if size is not None else "GZIP stream"
    while True:
        try:
            header = stream.read(_HEADER.size)
        except (OSError, EOFError) as err:  # a damaged GZIP stream
            _report(on_error, WomdRecordError(
                path, index, offset, f"the GZIP stream cannot be decompressed ({err})",
                _DAMAGED, resumable=False))
            return
        if not header:
            return
        if len(header) < _HEADER.size:
            _report(on_error, WomdRecordError(
                path, index, offset, f"the file ends {len(header)} bytes into a record's "
                f"12-byte length header", _DAMAGED, resumable=False))
            return
        length, length_crc = _HEADER.unpack(header)
        if check_crc and masked_crc32c(header[:8]) != length_crc:
            if index == 0:
                problem = ("the CRC of the first length field does not match: this is not a "
                           f"TFRecord file; found {describe_start(header)}")
                fix = ("Pass only TFRecord files of WOMD Scenario or tf.Example protos (for "
                       "example 'training/*.tfrecord*'), or ScenarioNet *.pkl files.")
            else:
                problem = (f"the CRC of the length field does not match (it reads {length} "
                           "bytes): the file is damaged")
                fix = _DAMAGED
            _report(on_error, WomdRecordError(path, index, offset, problem, fix,
                                              resumable=False))
            return
        left = None if size is None else size - offset - _HEADER.size
        if left is not None and length + _CRC.size > left:
            _report(on_error, WomdRecordError(
                path, index, offset, f"truncated: the length field announces {length} bytes "
                f"of data and a 4-byte CRC, but the {what} ends after {left}", _DAMAGED,
                resumable=False))
            return
        if length > max_record_bytes:
            problem = (f"the record announces {length} bytes, more than the limit of "
                       f"{max_record_bytes} bytes ({max_record_bytes / (1 << 20):g} MiB)")
            fix = ("A WOMD record is about 1 MB: the file is likely damaged. If the record is "
                   "genuine, raise the limit (max_record_bytes, --max-record-mb).")
            if on_error is None:
                raise WomdRecordError(path, index, offset, problem, fix)
            try:
                dropped = _skip(stream, length + _CRC.size)
            except (OSError, EOFError) as err:
                dropped, problem = -1, f"{problem}; the {what} then cannot be read ({err})"
            if dropped != length + _CRC.size:
                on_error(WomdRecordError(path, index, offset, problem
                                         + (f"; the {what} ends inside it" if dropped >= 0
                                            else ""), fix, resumable=False))
                return
            on_error(WomdRecordError(path, index, offset, problem + "; skipped", fix))
            offset += _HEADER.size + length + _CRC.size
            index += 1
            continue
        try:
            body = stream.read(length + _CRC.size)
        except (OSError, EOFError, OverflowError, MemoryError) as err:
            _report(on_error, WomdRecordError(
                path, index, offset, f"the record's {length} bytes cannot be read: the "
                f"{what} is damaged or cut short ({err})",
                _DAMAGED, resumable=False))
            return
        if len(body) < length + _CRC.size:
            _report(on_error, WomdRecordError(
                path, index, offset, f"truncated: the length field announces {length} bytes "
                f"of data and a 4-byte CRC, but the {what} ends after {len(body)}", _DAMAGED,
                resumable=False))
            return
        data = body[:length]
        if check_crc and masked_crc32c(data) != _CRC.unpack_from(body, length)[0]:
            _report(on_error, WomdRecordError(
                path, index, offset, f"the CRC of the {length} data bytes does not match: "
                "the record is corrupt", _DAMAGED))
        else:
            yield Record(path, index, offset, data)
        offset += _HEADER.size + length + _CRC.size
        index += 1


def _report(on_error: Callable[[WomdRecordError], None] | None, err: WomdRecordError) -> None:
    if on_error is None:
        raise err
    on_error(err)


class TFRecordWriter:
    """Write records to a TFRecord file, GZIP-compressed when ``compress`` is true.

    Use it as a context manager; ``write`` frames each record with its two masked CRCs.
    Writing is not atomic by itself: write into ``tap_bench.tableio.atomic_path``.
    """

    def __init__(self, path: str | os.PathLike, *, compress: bool = False):
        self.path = Path(path)
        self._raw = open(self.path, "wb")
        self._stream: BinaryIO = (gzip.GzipFile(fileobj=self._raw, mode="wb")
                                  if compress else self._raw)
        self.records = 0

    def write(self, data: bytes) -> None:
        """Append one record."""
        length = struct.pack("<Q", len(data))
        self._stream.write(length + _CRC.pack(masked_crc32c(length)))
        self._stream.write(data)
        self._stream.write(_CRC.pack(masked_crc32c(data)))
        self.records += 1

    def close(self) -> None:
        if self._stream is not self._raw:
            self._stream.close()
        self._raw.close()

    def __enter__(self) -> TFRecordWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
