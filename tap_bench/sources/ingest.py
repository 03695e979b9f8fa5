"""Driving-data files in, one trajectory table out: streaming, in worker processes, with a
report.

:func:`iter_driving_data` yields one table per scenario and holds one record at a time, so data
sets larger than memory can be processed scenario by scenario; :func:`read_driving_data` gathers
them into one table; :func:`ingest_driving_data` streams them into a Parquet file, written
atomically, decoding batches of records in worker processes.

The input formats are the registered readers (:mod:`tap_bench.sources.registry`), told
apart per file with ``format="auto"``; built in: TFRecords of ``Scenario`` protos
(``uncompressed/scenario/...``), TFRecords of motion ``tf.Example`` protos
(``uncompressed/tf_example/...``), and ScenarioNet scenario pickles (``*.pkl``).
"""

from __future__ import annotations

import glob
import json
import os
import shutil
import sys
import tempfile
import time
import warnings
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from tap_bench.errors import (
    FileFormatError,
    ParameterError,
    RegistrationError,
    TapBenchError,
    TrajectoryTableError,
    WomdRecordError,
    did_you_mean,
)
from tap_bench.execution import Backend, LocalBackend
from tap_bench.sources import builtin  # noqa: F401 (the built-in readers are registered)
from tap_bench.sources.registry import Reader, get_reader, reader_names, readers
from tap_bench.tableio import atomic_paths, check_outputs
from tap_bench.trajectories import validate_and_index, validate_trajectories
from tap_bench.womd.scenario import SCENARIO_COLUMNS, normalise_object_types
from tap_bench.womd.tfrecord import MAX_RECORD_BYTES, Record, iter_records, looks_like_tfrecord

__all__ = ["IngestReport", "check_reader", "expand_paths", "formats", "ingest_driving_data",
           "ingest_womd", "iter_driving_data", "iter_womd", "read_driving_data", "read_womd",
           "record_files"]

ON_ERROR = ("stop", "skip")
BATCH_BYTES = 8 << 20
"""Records are sent to worker processes in batches of about this many bytes."""
ROW_GROUP_ROWS = 1 << 18
"""Rows per Parquet row group: tables are gathered to this size before they are written."""
PARQUET_OPTIONS = {
    "compression": "snappy",
    # Dictionary pages for the repetitive string columns only: on float columns they cost
    # more time than they save space.
    "use_dictionary": ["scenario_id", "track_id", "object_type", "source"],
}
_SCENARIONET_INDEX = {"dataset_summary.pkl", "dataset_mapping.pkl"}


@dataclass
class IngestReport:
    """What an ingest read, wrote and skipped.

    Attributes:
        inputs: the files read.
        output: the table written (None when reading into memory).
        files, records, scenarios, rows: counts read and kept.
        bytes_read: bytes of input files read [B].
        seconds: wall time [s].
        workers: decoding processes.
        decode_cpu_seconds: CPU time spent decoding, in all processes [s].
        skipped: one entry per skipped record (path, record, offset, problem); empty with
            ``on_error="stop"``.
        notes: files left out (not records, empty) and other remarks.
        max_record_bytes: the longest record read [B].
    """

    inputs: list[str] = field(default_factory=list)
    output: str | None = None
    format: str = "auto"
    object_types: list[str] | None = None
    files: int = 0
    records: int = 0
    scenarios: int = 0
    rows: int = 0
    bytes_read: int = 0
    seconds: float = 0.0
    workers: int = 1
    decode_cpu_seconds: float = 0.0
    skipped: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    max_record_bytes: int = MAX_RECORD_BYTES

    @property
    def mb_per_s(self) -> float:
        """Input throughput [MB/s]."""
        return self.bytes_read / 1e6 / self.seconds if self.seconds else float("nan")

    def to_json(self) -> str:
        return json.dumps({**asdict(self), "mb_per_s": round(self.mb_per_s, 2)}, indent=2)


def expand_paths(paths: str | os.PathLike | Iterable[str | os.PathLike]) -> list[Path]:
    """Files named by paths, glob patterns (``data/*.tfrecord*``, ``**`` recursive) or
    directories (every file in them), sorted; ScenarioNet's ``dataset_summary.pkl`` and
    ``dataset_mapping.pkl`` index files are left out. A path that exists is taken as it is,
    even when its name holds ``[`` ``]``, ``*`` or ``?``.

    Raises:
        FileFormatError: a pattern or path that matches no file.
    """
    if isinstance(paths, str | os.PathLike):
        paths = [paths]
    found: list[Path] = []
    for item in paths:
        text = str(item)
        if Path(text).is_dir():
            matches = sorted(p for p in Path(text).iterdir())
        elif Path(text).exists():  # a file named with [ ] * ? is that file, not a pattern
            matches = [Path(text)]
        elif glob.has_magic(text):
            matches = sorted(Path(p) for p in glob.glob(text, recursive=True))
        else:
            matches = []
        matches = [p for p in matches if p.is_file() and p.name not in _SCENARIONET_INDEX]
        if not matches:
            raise FileFormatError(f"{text}: no such file, or no file matches the pattern. "
                                    "Quote glob patterns so the shell does not expand them.")
        found.extend(matches)
    return list(dict.fromkeys(found))


def record_files(paths: str | os.PathLike | Iterable[str | os.PathLike],
                 note: Callable[[str], None] | None = None) -> list[Path]:
    """The WOMD files among ``paths`` (see :func:`expand_paths`).

    Files found in a directory or by a pattern that are neither TFRecords (plain or GZIP,
    sniffed by their first length header) nor ``*.pkl`` pickles, such as a README or an
    empty file, are left out with a note; a file named on its own is kept as it is (and
    reading it says what is wrong), but an empty one gets a note.

    Raises:
        FileFormatError: a path that matches no file, or only files that are not records.
    """
    if isinstance(paths, str | os.PathLike):
        paths = [paths]
    note = note or (lambda text: warnings.warn(text, stacklevel=3))
    kept: list[Path] = []
    for item in paths:
        files = expand_paths([item])
        named = len(files) == 1 and not Path(str(item)).is_dir() and Path(str(item)).exists()
        if named:
            if files[0].stat().st_size == 0:
                note(f"{files[0]}: the file is empty (0 bytes): no records in it.")
            kept.extend(files)
            continue
        good = [p for p in files if _file_reader(p) is not None or looks_like_tfrecord(p)]
        for p in files:
            if p not in good:
                what = ("empty" if p.stat().st_size == 0 else
                        "not a TFRecord nor a file a reader claims by its name")
                note(f"{p}: skipped, {what}.")
        if not good:
            raise FileFormatError(f"{item}: no TFRecord or ScenarioNet (*.pkl) file there; "
                                  f"{len(files)} other file(s) left out. Readers: "
                                  f"{', '.join(reader_names())}.")
        kept.extend(good)
    return list(dict.fromkeys(kept))


def _check_choice(kind: str, value: str, allowed: tuple[str, ...]) -> str:
    if value not in allowed:
        raise did_you_mean(kind, value, allowed)
    return value


def formats() -> tuple[str, ...]:
    """``"auto"`` and the registered formats (:mod:`tap_bench.sources.registry`)."""
    return ("auto", *reader_names())


def _file_format(path: Path, format: str, check_crc: bool,
                 max_record_bytes: int = MAX_RECORD_BYTES) -> Reader:
    """The reader of ``path``: the one asked for, or the one that claims it (``auto``): a
    file reader by its name's ending, else the first TFRecord reader whose ``sniff`` accepts
    the first record, else the TFRecord fallback (``sniff=None``)."""
    if format != "auto":
        return get_reader(format)
    if _file_reader(path) is not None:
        return _file_reader(path)
    tfrecord = [r for r in readers() if r.framing == "tfrecord"]
    fallback = next((r for r in reversed(tfrecord) if r.sniff is None), tfrecord[-1])
    for record in iter_records(path, check_crc=check_crc, on_error=lambda err: None,
                               max_record_bytes=max_record_bytes):
        return next((r for r in tfrecord if r.sniff is not None and r.sniff(record.data)),
                    fallback)
    return fallback


def _file_reader(path: Path) -> Reader | None:
    """The reader of whole files whose name ending ``path`` has (``.pkl``), if any."""
    name = path.name.lower()
    return next((r for r in readers() if r.framing == "file" and name.endswith(r.suffixes)),
                None)


@dataclass
class _Batch:
    """A unit of work: records of one file, or one ScenarioNet pickle."""

    path: str
    reader: Reader
    records: list[Record]
    size: int


@dataclass
class _Decoded:
    """A decoded batch: its tables (or, from a worker, the Arrow IPC file holding them
    concatenated), the records skipped, the CPU time spent [s], and per table kept its
    scenario id with the record's index and offset (``ids``)."""

    tables: list[pa.Table]
    skipped: list[dict]
    cpu_seconds: float
    scenarios: int = 0
    spooled: str | None = None
    ids: list[tuple[str, int, int]] = field(default_factory=list)
    error: WomdRecordError | None = None


def _decode_batch(batch: _Batch, object_types: frozenset[str] | None, skip: bool
                  ) -> _Decoded:
    """Decode a batch; with ``skip`` a bad record is listed and left out, else raised."""
    start = time.process_time()
    tables, skipped, ids = _decode_records(batch, object_types, skip)
    return _Decoded(tables, skipped, time.process_time() - start, len(tables), ids=ids)


@dataclass(frozen=True)
class _SpoolTask:
    """A batch to decode in a worker, and the folder its tables go to."""

    batch: _Batch
    object_types: frozenset[str] | None
    skip: bool
    spool: str


def _decode_to_spool(task: _SpoolTask) -> _Decoded:
    """:func:`_decode_batch` in a worker process. The tables go back through an Arrow IPC
    file in the spool folder (memory-backed where /dev/shm exists) rather than through a
    pipe: pickling them would cost about half the decoding time again. A bad record with
    ``skip`` False comes back as ``error`` (not raised: it is not worth a retry)."""
    start = time.process_time()
    try:
        tables, skipped, ids = _decode_records(task.batch, task.object_types, task.skip)
    except WomdRecordError as err:
        return _Decoded([], [], time.process_time() - start, 0, error=err)
    spool = task.spool
    path = None
    if tables:
        table = pa.concat_tables(tables, promote_options="default")
        fd, path = tempfile.mkstemp(dir=spool, suffix=".arrow")
        os.close(fd)
        with pa.OSFile(path, "wb") as sink, pa.ipc.new_file(sink, table.schema) as writer:
            writer.write_table(table)
    return _Decoded([], skipped, time.process_time() - start, len(tables), path, ids)


def _decode_records(batch: _Batch, object_types: frozenset[str] | None, skip: bool
                    ) -> tuple[list[pa.Table], list[dict], list[tuple[str, int, int]]]:
    """Decode a batch's records: (tables, skipped records, (scenario id, record, offset)
    of each table). Every failure of a decoder becomes a :class:`WomdRecordError` naming
    the record, raised or (``skip``) listed; a scenario id met twice in the batch is one."""
    tables: list[pa.Table] = []
    skipped: list[dict] = []
    ids: list[tuple[str, int, int]] = []
    seen: dict[str, int] = {}
    decode = batch.reader.decode

    def decode_one(index: int, offset: int, source: str | Record) -> None:
        try:
            table = decode(source, object_types)
            sid = _scenario_id(table)
            if sid and sid in seen:
                raise WomdRecordError(batch.path, index, offset, _duplicate(sid, batch.path,
                                                                            seen[sid]), _DUP)
            problem = _contract_problem(table, sid)
            if problem:
                raise WomdRecordError(batch.path, index, offset, problem, _INVALID)
        except WomdRecordError as err:
            if not skip:
                raise
            skipped.append(err.as_dict())
            return
        except Exception as err:  # a decoder's own failure is this record's error
            wrapped = WomdRecordError(batch.path, index, offset, f"cannot be decoded "
                                      f"({type(err).__name__}: {err})", _UNDECODABLE)
            if not skip:
                raise wrapped from err
            skipped.append(wrapped.as_dict())
            return
        seen[sid] = index
        tables.append(table)
        ids.append((sid, index, offset))

    if batch.reader.framing == "file":
        decode_one(0, 0, batch.path)
        return tables, skipped, ids
    for record in batch.records:
        decode_one(record.index, record.offset, record)
    return tables, skipped, ids


_UNDECODABLE = ("The record is damaged or not in the format read; skip it with "
                "on_error='skip' (--on-error skip) to keep the other records.")
_DUP = ("Scenario ids must be unique: two records with one id would be merged into one "
        "scenario. Ingest the files apart, or skip the repeat with on_error='skip'.")


_INVALID = ("tap-bench labels only tables that keep the trajectory contract (SPEC section 1); "
            "skip the record with on_error='skip' (--on-error skip) to keep the others.")


def _contract_problem(table: pa.Table, sid: str) -> str | None:
    """Why a decoded scenario breaks the trajectory contract (NaN, duplicate or reversed
    times, infinite or NaN coordinates on valid rows ...), or None: each scenario is
    checked where it enters, so that one bad record never reaches label, validate or
    export (which would refuse the whole table)."""
    if table.num_rows == 0:
        return None
    return _frame_contract_problem(table.to_pandas(split_blocks=True), sid)


def _frame_contract_problem(frame: pd.DataFrame, sid: str) -> str | None:
    """:func:`_contract_problem` of a scenario already in pandas (not empty)."""
    try:
        validate_and_index(frame, source=f"scenario {sid!r}")
    except TrajectoryTableError as err:
        return f"breaks the trajectory contract: {err}"
    return None


def _scenario_id(table: pa.Table) -> str:
    if table.num_rows == 0:
        return ""  # nothing kept (object_types): nothing to merge
    return str(table.column("scenario_id")[0].as_py())


def _duplicate(sid: str, path: str, record: int) -> str:
    return f"scenario id {sid!r} was already read from {path}, record {record}"


def _batches(files: list[Path], format: str, check_crc: bool, batch_bytes: int,
             on_bad_framing: Callable[[WomdRecordError], None] | None,
             report: IngestReport, max_record_bytes: int) -> Iterator[_Batch]:
    for path in files:
        fmt = _file_format(path, format, check_crc, max_record_bytes)
        report.files += 1
        if fmt.framing == "file":
            size = path.stat().st_size
            if size > max_record_bytes:
                err = WomdRecordError(
                    str(path), 0, 0, f"the file has {size} bytes, more than the limit of "
                    f"{max_record_bytes} bytes", "Raise the limit (max_record_bytes, "
                    "--max-record-mb) if the file is genuine.")
                if on_bad_framing is None:
                    raise err
                on_bad_framing(err)
                continue
            report.records += 1
            report.bytes_read += size
            yield _Batch(str(path), fmt, [], size)
            continue
        records: list[Record] = []
        size = 0
        for record in iter_records(path, check_crc=check_crc, on_error=on_bad_framing,
                                   max_record_bytes=max_record_bytes):
            records.append(record)
            size += len(record.data) + 16
            report.records += 1
            report.bytes_read += len(record.data) + 16
            if size >= batch_bytes:
                yield _Batch(str(path), fmt, records, size)
                records, size = [], 0
        if records:
            yield _Batch(str(path), fmt, records, size)


def _iter_tables(paths, *, format: str, object_types, on_error: str, check_crc: bool,
                 workers: int, report: IngestReport, log: Callable[[str], None] | None,
                 backend: Backend | None = None,
                 batch_bytes: int = BATCH_BYTES,
                 progress: Callable[[int, int], None] | None = None,
                 max_record_bytes: int = MAX_RECORD_BYTES,
                 files: list[Path] | None = None) -> Iterator[pa.Table]:
    """Decoded tables (Arrow) in input order; fills ``report`` as it goes."""
    _check_choice("format", format, formats())
    _check_choice("on_error value", on_error, ON_ERROR)
    types = normalise_object_types(object_types)

    def note(text: str) -> None:
        report.notes.append(text)
        if log is not None:
            log(text)
        else:
            warnings.warn(text, stacklevel=4)

    if files is None:
        files = record_files(paths, note)
    report.inputs = [str(p) for p in files]
    report.format = format
    report.object_types = sorted(types) if types is not None else None
    report.workers = backend.workers if backend is not None else workers
    if backend is not None and getattr(backend, "address", None) is not None:
        raise ParameterError("backend", backend, "a backend on this machine (decoded "
                             "tables come back through its memory)",
                             hint="For a cluster, ingest shards with 'tap-bench ingest ... "
                             "--backend ray -o DIR' (tap_bench.distributed.ingest_shards).")
    skip = on_error == "skip"

    def skipped(entries: list[dict]) -> None:
        for entry in entries:
            report.skipped.append(entry)
            if log is not None:
                log(f"skipped {entry['path']}: record {entry['record']} at byte "
                    f"{entry['offset']}: {entry['problem']}")

    def bad_framing(err: WomdRecordError) -> None:
        skipped([{**err.as_dict(), "problem": err.problem
                  + ("" if err.resumable else "; the rest of the file cannot be read")}])

    seen: dict[str, tuple[str, int]] = {}  # scenario id -> (file, record) it came from

    def finish(batch: _Batch, result: _Decoded) -> list[pa.Table]:
        skipped(result.skipped)
        tables = result.tables
        if result.spooled is not None:
            with pa.memory_map(result.spooled) as source:
                tables = [pa.ipc.open_file(source).read_all()]
            os.unlink(result.spooled)  # the mapping stays readable until released
        repeats = []
        for sid, index, offset in result.ids:
            if sid and sid in seen:
                err = WomdRecordError(batch.path, index, offset, _duplicate(sid, *seen[sid]),
                                      _DUP)
                if not skip:
                    raise err
                skipped([err.as_dict()])
                repeats.append(sid)
            elif sid:
                seen[sid] = (batch.path, index)
        if repeats:  # a batch holds each id once: its rows of a repeated id are the repeat
            drop = pa.array(repeats, pa.string())
            tables = [t.filter(pc.invert(pc.is_in(t.column("scenario_id").cast(pa.string()),
                                                  drop))) for t in tables]
        report.scenarios += result.scenarios - len(repeats)
        report.rows += sum(t.num_rows for t in tables)
        report.decode_cpu_seconds += result.cpu_seconds
        if progress is not None:
            progress(batch.size, result.scenarios)
        return tables

    batches = _batches(files, format, check_crc, batch_bytes, bad_framing if skip else None,
                       report, max_record_bytes)
    if backend is None and workers <= 1:
        for batch in batches:
            yield from finish(batch, _decode_batch(batch, types, skip))
        return
    shm = Path("/dev/shm")
    # the process in the name: a folder left behind says whose it was
    spool = tempfile.mkdtemp(prefix=f"tap-bench-ingest-{os.getpid()}-",
                             dir=shm if shm.is_dir() and os.access(shm, os.W_OK) else None)
    sent: deque[_Batch] = deque()  # outcomes come in order: the batch of each, in turn

    def tasks() -> Iterator[_SpoolTask]:
        for batch in batches:
            sent.append(batch)
            yield _SpoolTask(batch, types, skip, spool)

    try:
        runner = backend if backend is not None else LocalBackend(workers)
        for outcome in runner.imap(_decode_to_spool, tasks(), progress=False):
            batch = sent.popleft()
            if outcome.ok:
                result: _Decoded = outcome.value
                if result.error is not None:
                    raise result.error  # a bad record, with on_error="stop"
                yield from finish(batch, result)
                continue
            # the batch failed on every attempt (its worker died, say): with "skip" its
            # records are listed and the others kept; with "stop" the ingest ends here
            lost = _lost_batch(batch, outcome.error)
            if not skip:
                raise lost
            skipped([lost.as_dict()])
            if progress is not None:
                progress(batch.size, 0)
    finally:
        shutil.rmtree(spool, ignore_errors=True)


def _lost_batch(batch: _Batch, error: str) -> WomdRecordError:
    """The error for a batch whose decoding failed outside any record's own checks."""
    first = batch.records[0] if batch.records else None
    count = len(batch.records) or 1
    return WomdRecordError(
        batch.path, first.index if first else 0, first.offset if first else 0,
        f"decoding {count} record(s) from here failed: {error}",
        "Run again with --workers 1 to see the error in this process; other files and "
        "records are not affected with --on-error skip.")


def iter_driving_data(paths: str | os.PathLike | Iterable[str | os.PathLike], *,
              format: str = "auto", object_types: Iterable[str] | str | None = None,
              on_error: str = "stop", check_crc: bool = True,
              report: IngestReport | None = None,
              max_record_bytes: int = MAX_RECORD_BYTES) -> Iterator[pd.DataFrame]:
    """Yield a trajectory table per scenario, reading one record at a time (any registered
    format; ``iter_womd`` is the same).

    Args:
        paths: files, glob patterns or directories (see :func:`expand_paths`).
        format: ``auto`` (default: ``*.pkl`` are ScenarioNet, TFRecords are sniffed),
            ``scenario``, ``tf_example`` or ``scenarionet``.
        object_types: keep only these object types (``vehicle``, ``pedestrian``,
            ``cyclist``, ``other``); None keeps all.
        on_error: ``stop`` raises the first bad record; ``skip`` leaves it out and lists it
            in ``report.skipped``.
        check_crc: check the CRC-32C of every record.
        report: filled with counts and skipped records as the iteration goes.
        max_record_bytes: the longest record read [B]
            (:data:`tap_bench.womd.tfrecord.MAX_RECORD_BYTES`, 64 MiB); a longer one is a
            bad record, never held in memory.

    Yields:
        pandas DataFrames with :data:`tap_bench.womd.scenario.SCENARIO_COLUMNS` (SPEC
        section 1), one per scenario, rows ordered by track then time.

    Raises:
        WomdRecordError: a bad record with ``on_error="stop"``, naming file, record and
            byte offset.
    """
    report = report if report is not None else IngestReport()
    for table in _iter_tables(paths, format=format, object_types=object_types,
                              on_error=on_error, check_crc=check_crc, workers=1,
                              report=report, log=None, batch_bytes=0,
                              max_record_bytes=max_record_bytes):
        yield table.to_pandas(split_blocks=True)


def read_driving_data(paths: str | os.PathLike | Iterable[str | os.PathLike], *,
              format: str = "auto", object_types: Iterable[str] | str | None = None,
              on_error: str = "stop", check_crc: bool = True, workers: int = 1,
              report: IngestReport | None = None,
              max_record_bytes: int = MAX_RECORD_BYTES) -> pd.DataFrame:
    """Read driving-data files of any registered format (WOMD TFRecords, ScenarioNet
    pickles, a plugin's format) into one trajectory table (``read_womd`` is the same).

    Arguments as :func:`iter_driving_data`, plus ``workers`` decoding processes.

    Returns:
        One pandas DataFrame with :data:`tap_bench.womd.scenario.SCENARIO_COLUMNS`,
        scenarios in input order (an empty table with those columns when nothing is kept).
    """
    report = report if report is not None else IngestReport()
    tables = list(_iter_tables(paths, format=format, object_types=object_types,
                               on_error=on_error, check_crc=check_crc, workers=workers,
                               report=report, log=None, max_record_bytes=max_record_bytes))
    if not tables:
        return pd.DataFrame({name: pd.Series(dtype=object) for name in _columns()})
    return pa.concat_tables(tables, promote_options="default").to_pandas(split_blocks=True)


def _columns() -> tuple[str, ...]:
    return SCENARIO_COLUMNS


def report_path(output: str | os.PathLike) -> Path:
    """Where :func:`ingest_driving_data` writes its report: beside the output, ``.report.json``."""
    output = Path(output)
    return output.with_name(output.name + ".report.json")


def ingest_driving_data(paths: str | os.PathLike | Iterable[str | os.PathLike],
                output: str | os.PathLike, *, format: str = "auto",
                object_types: Iterable[str] | str | None = None, on_error: str = "stop",
                check_crc: bool = True, workers: int = 1, progress: bool | None = False,
                log: Callable[[str], None] | None = None,
                batch_bytes: int = BATCH_BYTES, backend: Backend | None = None,
                max_record_bytes: int = MAX_RECORD_BYTES) -> IngestReport:
    """Stream driving-data files of any registered format into one Parquet trajectory table,
    atomically (``ingest_womd`` is the same).

    The table goes to a temporary file beside ``output``, renamed onto it only when every
    input has been read: an interrupted or failed ingest leaves no output. Memory holds a
    few batches of records and their tables, whatever the size of the inputs. The report
    (:class:`IngestReport`) is written beside the output as ``<output>.report.json``; table
    and report land together.

    Args:
        paths, format, object_types, on_error, check_crc, max_record_bytes: as
            :func:`iter_driving_data`.
        output: the Parquet file to write (not one of the inputs).
        workers: decoding processes (1 decodes in this process).
        backend: decode on this :class:`tap_bench.execution.Backend` instead of
            ``workers`` local processes (it must run on this machine: tables come back
            through shared memory). A batch whose worker dies is tried once more, then
            reported (``on_error="skip"``) or raised.
        progress: show a progress bar (tqdm, on stderr) with scenarios and MB/s; None:
            only when stderr is a terminal.
        log: called with a line for every skipped record (``on_error="skip"``) and every
            file left out (default: a warning).
        batch_bytes: records per work unit [B].

    Returns:
        The report.

    Raises:
        WomdRecordError: a bad record with ``on_error="stop"``; nothing is written.
        OutputPathError: ``output`` is an input or cannot be written.
    """
    output = Path(output)
    if output.suffix not in (".parquet", ".pq"):
        raise FileFormatError(f"{output}: the output of an ingest is a Parquet file; name "
                              "it *.parquet.")
    normalise_object_types(object_types)  # a misspelled type fails before any work
    report = IngestReport(output=str(output), max_record_bytes=max_record_bytes)

    def note(text: str) -> None:
        report.notes.append(text)
        (log or (lambda line: warnings.warn(line, stacklevel=4)))(text)

    files = record_files(paths, note)
    check_outputs([output, report_path(output)], files)
    start = time.perf_counter()
    bar = None
    if progress is None:
        progress = sys.stderr.isatty()
    if progress:
        from tqdm import tqdm

        total = sum(p.stat().st_size for p in files)
        bar = tqdm(total=total, unit="B", unit_scale=True, unit_divisor=1000,
                   desc="ingest", file=sys.stderr, dynamic_ncols=True)

    def advance(size: int, scenarios: int) -> None:
        if bar is not None:
            bar.update(min(size, bar.total - bar.n))
            bar.set_postfix(scenarios=report.scenarios, refresh=False)

    try:
        with atomic_paths([output, report_path(output)]) as (tmp, report_tmp):
            writer = None
            pending: list[pa.Table] = []
            pending_rows = 0

            def flush() -> None:
                nonlocal writer, pending, pending_rows
                if not pending:
                    return
                table = pa.concat_tables(pending, promote_options="default")
                if writer is None:
                    writer = pq.ParquetWriter(tmp, table.schema, **PARQUET_OPTIONS)
                elif table.schema != writer.schema:
                    table = table.cast(writer.schema)
                writer.write_table(table, row_group_size=ROW_GROUP_ROWS)
                pending, pending_rows = [], 0

            try:
                for table in _iter_tables(paths, format=format, object_types=object_types,
                                          on_error=on_error, check_crc=check_crc,
                                          workers=workers, report=report, log=log,
                                          backend=backend, batch_bytes=batch_bytes,
                                          progress=advance,
                                          max_record_bytes=max_record_bytes, files=files):
                    pending.append(table)
                    pending_rows += table.num_rows
                    if pending_rows >= ROW_GROUP_ROWS:
                        flush()
                flush()
                if writer is None:  # nothing kept: an empty table with the columns

                    empty = pa.table({c: pa.array([], pa.string()) for c in SCENARIO_COLUMNS})
                    pq.write_table(empty, tmp)
            finally:
                if writer is not None:
                    writer.close()
            report.seconds = time.perf_counter() - start
            report_tmp.write_text(report.to_json())
    finally:
        if bar is not None:
            bar.close()
    return report


def check_reader(reader: Reader, sample: str | os.PathLike | None = None) -> pd.DataFrame | None:
    """Check a data format's entry, and with ``sample``, that it reads a file of its format
    into a valid trajectory table (Gymnasium's ``check_env`` for readers).

    Args:
        reader: the :class:`Reader` (registered or not).
        sample: a file of the format (None: check the entry only).

    Returns:
        the table read from ``sample`` (None without one).

    Raises:
        RegistrationError: the entry is unusable (its functions are not importable by name,
            so workers could not run them) or its table breaks the contract (naming the
            column and the fix).
    """
    for role, fn in (("decode", reader.decode), ("sniff", reader.sniff)):
        if fn is None:
            continue
        module, name = getattr(fn, "__module__", None), getattr(fn, "__qualname__", "")
        if not module or module == "__main__" or "<" in name or "." in name:
            raise RegistrationError(
                f"format {reader.name!r}: its {role} function {name or fn!r} must be a "
                "module-level function of an importable module (not __main__, not a lambda "
                "or a nested function): ingest runs it in worker processes.")
    if sample is None:
        return None
    path = Path(sample)
    if reader.framing == "file" and not path.name.lower().endswith(reader.suffixes):
        raise RegistrationError(f"format {reader.name!r}: sample {path} does not end with one "
                                f"of its suffixes {reader.suffixes}.")
    table = read_driving_data([path], format=reader.name)
    missing = [c for c in ("scenario_id", "track_id", "t", "x", "y", "heading", "speed")
               if c not in table.columns]
    if missing:
        raise RegistrationError(f"format {reader.name!r}: the table read from {path} lacks "
                                f"{', '.join(missing)}; decode must return the columns of "
                                "tap_bench.womd.scenario.SCENARIO_COLUMNS.")
    if not len(table):
        raise RegistrationError(f"format {reader.name!r}: read no rows from {path}.")
    try:
        validate_trajectories(table, source=f"format {reader.name!r} on {path}")
    except TapBenchError as err:
        raise RegistrationError(f"format {reader.name!r} on {path}: {err}") from err
    return table


# The first names, from when WOMD was the only format: kept, the same functions.
iter_womd = iter_driving_data
read_womd = read_driving_data
ingest_womd = ingest_driving_data
