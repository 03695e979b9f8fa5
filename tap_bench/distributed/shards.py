"""Shard sets on a backend: WOMD ingestion and TAP labelling, one task per shard.

Both write partitioned Parquet: a directory with one part file per input shard, written
atomically by the task that made it, and ``_report.json`` listing every shard with its
rows, attempts, time and, for a shard that failed on every retry, the error. A failed shard
leaves no part; the others land. Parquet readers (pandas, pyarrow, Ray Data) read the
directory as one table and skip the ``_report.json``.

Memory per worker is bounded whatever the size of the data set or of a shard: ingestion
streams a file's records in batches of 8 MB (:func:`tap_bench.sources.ingest.ingest_womd`), and
labelling reads a part in chunks of whole scenarios of about a million rows
(:data:`LABEL_CHUNK_ROWS`). A scenario must lie in a single shard, as it does in WOMD's files
and in parts written here, so that labels do not depend on how the data was cut.

On a multi-node cluster every path must be on a file system all nodes see (NFS, a mounted
bucket): tasks read their shard and write their part themselves; only counts travel back.
"""

from __future__ import annotations

import json
import os
import re
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow.compute as pc

from tap_bench import sdl
from tap_bench.errors import FileFormatError, ParameterError, TapBenchError
from tap_bench.execution import DEFAULT_RETRIES, Backend, Outcome
from tap_bench.labelling import tap
from tap_bench.sources.ingest import (
    ON_ERROR,
    _check_choice,
    expand_paths,
    formats,
    ingest_womd,
    record_files,
    report_path,
)
from tap_bench.stages import StageConfig
from tap_bench.tableio import atomic_path, read_table
from tap_bench.thresholds import resolve_thresholds
from tap_bench.womd.scenario import normalise_object_types
from tap_bench.womd.tfrecord import MAX_RECORD_BYTES

__all__ = ["LABEL_CHUNK_ROWS", "REPORT_NAME", "ShardReport", "ingest_shards", "label_shards",
           "parquet_shards"]

REPORT_NAME = "_report.json"
"""The report of a sharded run, inside its output directory (ignored by Parquet readers)."""


@dataclass
class ShardReport:
    """What a sharded run read, wrote and failed on.

    Attributes:
        kind: ``"ingest"`` or ``"label"``.
        output: the output directory.
        backend, workers: where it ran.
        seconds: wall time [s].
        shards: one dict per input shard: ``input``, ``output`` (the part, None when it
            failed), ``ok``, ``attempts``, ``seconds`` and ``cpu_seconds`` (wall and CPU
            time in the worker [s]), ``rows`` (written), ``bytes`` (input size [B]),
            ``error`` ("" when ok) and per-kind counts.
    """

    kind: str
    output: str
    backend: str
    workers: int
    seconds: float = 0.0
    shards: list[dict[str, Any]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def failed(self) -> list[dict[str, Any]]:
        """The shards that failed on every attempt."""
        return [s for s in self.shards if not s["ok"]]

    @property
    def rows(self) -> int:
        return sum(s.get("rows", 0) for s in self.shards)

    @property
    def bytes_read(self) -> int:
        """Bytes of the inputs read in this run [B] (not those of resumed parts)."""
        return sum(s["bytes"] for s in self.shards if s["ok"] and not s.get("resumed"))

    def to_json(self) -> str:
        return json.dumps({**asdict(self), "failed": len(self.failed), "rows": self.rows,
                           "bytes_read": self.bytes_read}, indent=2)

    def write(self) -> Path:
        """Write the report to ``<output>/_report.json``, atomically."""
        path = Path(self.output) / REPORT_NAME
        with atomic_path(path) as tmp:
            tmp.write_text(self.to_json())
        return path


def parquet_shards(paths: str | os.PathLike | Iterable[str | os.PathLike]) -> list[Path]:
    """The Parquet shards named by files, glob patterns or directories, sorted.

    In a directory, only ``*.parquet`` / ``*.pq`` files are shards; names starting with
    ``_`` or ``.`` (reports, temporary files) are left out.

    Raises:
        FileFormatError: a path or pattern that gives no Parquet shard.
    """
    shards = [p for p in expand_paths(paths)
              if p.suffix in (".parquet", ".pq") and not p.name.startswith(("_", "."))]
    if not shards:
        raise FileFormatError(f"{paths}: no Parquet shard (*.parquet) there. Label or fit a "
                              "directory written by 'tap-bench ingest ... --backend ray', or "
                              "give the files.")
    return shards


def _prepare_output(output: str | os.PathLike, resume: bool) -> Path:
    out = Path(output)
    if out.exists() and not out.is_dir():
        raise FileFormatError(f"{out}: exists and is not a directory; a sharded run writes a "
                              "directory of Parquet parts. Choose another --output.")
    if out.is_dir() and any(out.iterdir()) and not resume:
        raise FileFormatError(f"{out}: the output directory is not empty. Choose a new one, "
                              "remove it, or pass resume=True (--resume) to keep the parts "
                              "already written and do the rest.")
    out.mkdir(parents=True, exist_ok=True)
    return out


def _whole_part(path: Path) -> bool:
    """Whether a part file is a readable Parquet file (its footer and schema read)."""
    import pyarrow.parquet as pq

    try:
        pq.read_metadata(path)
    except Exception:  # pyarrow raises several kinds for a damaged file
        return False
    return True


def _part_names(inputs: Sequence[Path]) -> list[str]:
    """One part name per input: its file name made Parquet, numbered when names clash."""
    stems = [re.sub(r"\.(parquet|pq)$", "", p.name) for p in inputs]
    clash = len(set(stems)) < len(stems)
    return [f"part-{i:05d}-{s}.parquet" if clash else f"{s}.parquet"
            for i, s in enumerate(stems)]


def _run(kind: str, fn, jobs: list[Any], inputs: list[Path], parts: list[Path],
         out: Path, backend: Backend, retries: int, resume: bool,
         progress: bool | None) -> ShardReport:
    start = time.perf_counter()
    report = ShardReport(kind, str(out), backend.name, backend.workers)
    damaged = {i for i, part in enumerate(parts) if resume and part.exists()
               and not _whole_part(part)}
    for i in sorted(damaged):  # an earlier run's part that cannot be read is done again
        aside = parts[i].with_name(f".{parts[i].name}.damaged")  # hidden from readers, kept
        os.replace(parts[i], aside)
        report.notes.append(f"{parts[i]}: the part an earlier run left cannot be read as "
                            f"Parquet; it is made again (the damaged file is kept as "
                            f"{aside.name}).")
    todo = [i for i, part in enumerate(parts)
            if not (resume and part.exists()) or i in damaged]
    outcomes: dict[int, Outcome] = dict(zip(todo, backend.map(
        fn, [jobs[i] for i in todo], retries=retries, desc=f"{kind} ({backend.name})",
        unit="shard", progress=progress), strict=True))
    for i, (src, part) in enumerate(zip(inputs, parts, strict=True)):
        entry: dict[str, Any] = {"input": str(src), "output": str(part),
                                 "bytes": src.stat().st_size if src.exists() else 0}
        outcome = outcomes.get(i)
        if i in damaged:
            entry["redone"] = "the earlier part could not be read"
        if outcome is None:
            entry.update(ok=True, attempts=0, seconds=0.0, cpu_seconds=0.0, error="",
                         resumed=True)
        elif outcome.ok:
            entry.update(ok=True, attempts=outcome.attempts, seconds=outcome.seconds,
                         cpu_seconds=outcome.cpu_seconds, error="", **outcome.value)
        else:
            entry.update(output=None, ok=False, attempts=outcome.attempts,
                         seconds=float("nan"), error=outcome.error)
        report.shards.append(entry)
    report.seconds = time.perf_counter() - start
    report.write()
    return report


# -- ingestion ----------------------------------------------------------------------------
@dataclass(frozen=True)
class _IngestJob:
    input: str
    output: str
    format: str
    object_types: tuple[str, ...] | None
    on_error: str
    check_crc: bool
    max_record_bytes: int


def _ingest_shard(job: _IngestJob) -> dict[str, Any]:
    """Ingest one WOMD file into one part; its report goes back to the driver."""
    report = ingest_womd([job.input], job.output, format=job.format,
                         object_types=job.object_types, on_error=job.on_error,
                         check_crc=job.check_crc, workers=1,
                         max_record_bytes=job.max_record_bytes)
    report_path(job.output).unlink(missing_ok=True)  # gathered into _report.json instead
    return {"rows": report.rows, "records": report.records, "scenarios": report.scenarios,
            "skipped": report.skipped}


def ingest_shards(paths: str | os.PathLike | Iterable[str | os.PathLike],
                  output: str | os.PathLike, backend: Backend, *, format: str = "auto",
                  object_types: Iterable[str] | str | None = None, on_error: str = "stop",
                  check_crc: bool = True, retries: int = DEFAULT_RETRIES,
                  resume: bool = False, progress: bool | None = None,
                  max_record_bytes: int | None = None,
                  log: Callable[[str], None] | None = None) -> ShardReport:
    """Ingest WOMD files into a directory of Parquet parts, one task and one part per file.

    Args:
        paths: files, glob patterns or directories (:func:`tap_bench.womd.expand_paths`).
        output: the directory to write (``womd/``): ``<input name>.parquet`` per input and
            ``_report.json``.
        backend: where the tasks run.
        format, object_types, check_crc, max_record_bytes: as
            :func:`tap_bench.sources.ingest_womd` (None: its default).
        on_error: ``stop`` (default): a bad record fails its shard, which is retried and
            then reported, the other shards kept; ``skip``: bad records are left out and
            listed under the shard's ``skipped``.
        retries: retries of a failed shard.
        resume: keep the parts an earlier run wrote and ingest only the missing ones.
        progress: progress bar over shards (None: only on a terminal).
        log: told of every file left out (not a record file; default: a warning).

    Returns:
        The :class:`ShardReport`, also written to ``<output>/_report.json``.
    """
    _check_choice("format", format, formats())
    _check_choice("on_error value", on_error, ON_ERROR)
    types = normalise_object_types(object_types)
    inputs = record_files(paths, log)
    out = _prepare_output(output, resume)
    parts = [out / name for name in _part_names(inputs)]
    jobs = [_IngestJob(str(src.resolve()), str(part.resolve()), format,
                       tuple(sorted(types)) if types is not None else None, on_error,
                       check_crc, max_record_bytes or MAX_RECORD_BYTES)
            for src, part in zip(inputs, parts, strict=True)]
    return _run("ingest", _ingest_shard, jobs, inputs, parts, out, backend, retries, resume,
                progress)


# -- labelling ----------------------------------------------------------------------------
LABEL_CHUNK_ROWS = 1 << 20
"""Trajectory rows a label task holds at once: whole scenarios, about this many rows."""


class _NotContiguous(Exception):
    """A part whose scenarios are not each in one run of rows."""


def _scenario_chunks(path: str, rows: int) -> Iterator[pd.DataFrame]:
    """A Parquet part as tables of whole scenarios of about ``rows`` rows each.

    Raises:
        _NotContiguous: a scenario met again after another one (the part is not grouped
            by scenario, as ingested parts are).
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    seen: set[str] = set()

    def emit(table: pa.Table) -> pd.DataFrame:
        ids = set(pc.unique(table.column("scenario_id").cast(pa.string())).to_pylist())
        if seen & ids:
            raise _NotContiguous(path)
        seen.update(ids)
        return table.to_pandas()

    pending: list[pa.RecordBatch] = []
    size = 0
    for batch in pq.ParquetFile(path).iter_batches(batch_size=min(rows, 1 << 16)):
        pending.append(batch)
        size += batch.num_rows
        if size < rows:
            continue
        table = pa.Table.from_batches(pending)
        ids = np.asarray(table.column("scenario_id").cast(pa.string()).to_numpy(
            zero_copy_only=False))
        other = np.flatnonzero(ids != ids[-1])
        if len(other) == 0:  # one scenario so far: it may go on in the next batch
            continue
        cut = int(other[-1]) + 1  # the last scenario may go on in the next batch
        yield emit(table.slice(0, cut))
        pending = table.slice(cut).to_batches()
        size = table.num_rows - cut
    if size:
        yield emit(pa.Table.from_batches(pending))


@dataclass(frozen=True)
class _LabelJob:
    input: str
    output: str
    thresholds: Any  # Thresholds
    config: Any  # StageConfig
    level: str
    chunk_rows: int
    interactions: str | None = None


def _label_shard(job: _LabelJob) -> dict[str, Any]:
    """Label one Parquet part, whole scenarios at a time, and write its label table."""
    try:
        return _label_chunks(job, _scenario_chunks(job.input, job.chunk_rows))
    except _NotContiguous:  # a part not grouped by scenario: label it whole

        return _label_chunks(job, iter([read_table(job.input)]))


def _label_chunks(job: _LabelJob, tables: Iterator[pd.DataFrame]) -> dict[str, Any]:
    import pyarrow as pa
    import pyarrow.parquet as pq


    counts = {"rows": 0, "trajectory_rows": 0, "segments": 0, "short_segments": 0}
    with atomic_path(job.output) as tmp:
        writer = None
        try:
            for table in tables:
                result = tap(table, job.thresholds, job.config, source=job.input,
                             interactions=job.interactions)
                labels = pa.Table.from_pandas(result.labels(job.level), preserve_index=False)
                if writer is None:
                    writer = pq.ParquetWriter(tmp, labels.schema)
                writer.write_table(labels.cast(writer.schema))
                counts["rows"] += labels.num_rows
                counts["trajectory_rows"] += len(table)
                counts["segments"] += len(result.segments_info)
                counts["short_segments"] += len(result.short_segments)
        finally:
            if writer is not None:
                writer.close()
        if writer is None:
            raise FileFormatError(f"{job.input}: the part has no rows; remove it or ingest "
                                  "its source again.")
    return counts


def label_shards(paths: str | os.PathLike | Iterable[str | os.PathLike],
                 output: str | os.PathLike, backend: Backend, *,
                 thresholds: Any = "paper", level: str = "action", config: Any = None,
                 retries: int = DEFAULT_RETRIES, resume: bool = False,
                 chunk_rows: int = LABEL_CHUNK_ROWS, progress: bool | None = None,
                 interactions: str | None = None) -> ShardReport:
    """Label every Parquet shard of a trajectory data set, one task and one part per shard.

    Args:
        paths: a directory of Parquet shards (an ingest's output), files or glob patterns.
        output: the directory of label parts to write (same file names as the shards).
        backend: where the tasks run.
        thresholds: a :class:`~tap_bench.Thresholds`, a preset or a thresholds JSON path,
            resolved once here.
        level: SDL level or ``"all"``.
        config: :class:`~tap_bench.stages.StageConfig` (default: 1 s runs, 4 s merge gap).
        retries: retries of a failed shard.
        resume: keep the parts an earlier run wrote and label only the missing ones.
        chunk_rows: trajectory rows a task labels at once (whole scenarios; a part whose
            scenarios are not each one run of rows is labelled whole).
        progress: progress bar over shards (None: only on a terminal).
        interactions: also label the interaction axis (:func:`tap_bench.labelling.tap`).

    Returns:
        The :class:`ShardReport` (also ``<output>/_report.json``); each shard lists its
        label ``rows``, ``segments`` and ``short_segments`` (too short to label).
    """
    sdl.levels(level)  # a bad level fails here, not in every task
    th = resolve_thresholds(thresholds)
    config = config or StageConfig()
    inputs = parquet_shards(paths)
    out = _prepare_output(output, resume)
    if any(src.resolve().parent == out.resolve() for src in inputs):
        raise TapBenchError(f"{out}: the output directory holds the input shards; write the "
                            "labels to another directory.")
    parts = [out / name for name in _part_names(inputs)]
    if isinstance(chunk_rows, bool) or not isinstance(chunk_rows, int) or chunk_rows < 1:
        raise ParameterError("chunk_rows", chunk_rows, "",
            message=f"chunk_rows must be a positive integer, got {chunk_rows!r}.")
    jobs = [_LabelJob(str(src.resolve()), str(part.resolve()), th, config, level, chunk_rows,
                      interactions) for src, part in zip(inputs, parts, strict=True)]
    return _run("label", _label_shard, jobs, inputs, parts, out, backend, retries, resume,
                progress)
