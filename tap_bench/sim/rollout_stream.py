"""Rollouts streamed to disk: memory bounded whatever the number of scenes, resumable.

:func:`stream_rollout` runs the episodes of :func:`tap_bench.sim.rollout.rollout` (same
tasks, same backends) but keeps no episode's trajectory table longer than it takes to write
it. Results arrive in seed order and go, a few scenes at a time, into parts in a folder
beside the output, ``<output>.parts/``:

- ``run.json``: what the run is (scenes, policy, seeds): a resume of another run is refused;
- ``part-<first>.arrow`` and ``part-<first>.episodes.jsonl``: the trajectory rows (an Arrow
  IPC file, its text columns dictionary-encoded, LZ4-compressed: about as small as Parquet,
  written and read back in half the time or less) and the episode rows of consecutive seeds
  from position ``<first>`` in the run's seed list, each pair written atomically (a part is
  whole or absent). Parts of Parquet (``part-<first>.parquet``, as earlier versions wrote
  them) are read as well.

When every seed has its row, the parts are joined into the output (one table, Parquet row
groups of :data:`ROW_GROUP_ROWS` rows whatever the parts were, or CSV) and the episode table,
both written atomically, and the parts folder is removed. A run killed or interrupted
leaves its parts: the same command with ``resume=True`` (``--resume``) keeps them, runs the
seeds without a row and writes the same output, bit for bit, as a run never interrupted.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tap_bench.errors import OutputPathError
from tap_bench.execution import DEFAULT_RETRIES, Backend, resolve_backend
from tap_bench.sim.rollout import (
    EPISODE_COLUMNS,
    Policy,
    PolicyDefinition,
    _failed_row,
    _run_task,
    collect_rollout,
    episode_tasks,
    resolve_policy,
    resolve_scenario,
)
from tap_bench.sim.scenario_format import Scenario, parse_seeds
from tap_bench.sim.womd_scene import WomdScenes

if TYPE_CHECKING:
    import gymnasium as gym
    import pandas as pd
    import pyarrow as pa

__all__ = ["PART_ROWS", "PART_SCENES", "ROW_GROUP_ROWS", "StreamedRollout", "ego_rows",
           "join_parquet", "parts_folder", "stream_rollout"]

ROW_GROUP_ROWS = 1 << 16
"""Rows per Parquet row group of the joined output (fixed, so the file does not depend on
where a run was interrupted)."""
READ_BATCH_ROWS = 1 << 13
"""Rows read from a part at a time while joining."""
PART_SUFFIXES = (".arrow", ".parquet")
"""A part's trajectory file: written as the first (Arrow IPC), read as either."""
PART_SCENES = 16
"""Scenes per part at most: what an interrupted run can lose."""
PART_ROWS = 1 << 16
"""Trajectory rows held before a part is written, at most (plus one scene's)."""
PART_SECONDS = 30.0
"""A part is written at least this often while results come [s]."""



@dataclass(frozen=True)
class StreamedRollout:
    """What :func:`stream_rollout` did.

    Attributes:
        output: the trajectory table written (None when no episode left rows).
        episodes_output: the episode table written.
        episodes: the episode table (:data:`~tap_bench.sim.rollout.EPISODE_COLUMNS`).
        rows: trajectory rows written.
        before: scenes an earlier, interrupted run had done (kept from its parts).
    """

    output: Path | None
    episodes_output: Path
    episodes: pd.DataFrame
    rows: int
    before: int


def parts_folder(output: str | os.PathLike) -> Path:
    """The folder of a run's parts: ``<output>.parts`` beside the output."""
    output = Path(output)
    return output.with_name(output.name + ".parts")


def _identity(scenario: Scenario, spec: Any, seeds: Sequence[int], record: bool,
              ego_only: bool = False) -> dict:
    policy = (repr(spec) if isinstance(spec, PolicyDefinition) else
        f"{type(spec).__module__}.{type(spec).__qualname__}:{getattr(spec, 'name', '')}")
    identity = {"scenario": repr(scenario), "policy": policy,
                "seeds": [int(s) for s in seeds], "record": bool(record)}
    if ego_only:  # absent otherwise: parts of runs before the option still resume
        identity["ego_only"] = True
    return identity


def ego_rows(table: pd.DataFrame) -> pd.DataFrame:
    """Only the ego's rows of a trajectory table (``is_ego`` true), index renumbered; the
    table itself when it has no rows."""
    if not len(table):
        return table
    return table[table["is_ego"].to_numpy(bool)].reset_index(drop=True)


def _json_value(value: Any) -> Any:
    if hasattr(value, "item") and not isinstance(value, str | bytes):
        return value.item()  # numpy scalars
    return value


class _Parts:
    """The parts folder of one run: what is done, and writing the next part."""

    def __init__(self, folder: Path, identity: dict, resume: bool):
        self.folder = folder
        run = folder / "run.json"
        if folder.exists() and not resume:
            raise OutputPathError(
                f"{folder}: an interrupted run left its parts here. Continue it with "
                "--resume (resume=True), or remove the folder to start again.")
        if folder.exists() and run.exists():
            found = json.loads(run.read_text())
            if found != identity:
                changed = [k for k in {**found, **identity}
                           if found.get(k) != identity.get(k)]
                raise OutputPathError(
                    f"{folder}: the parts are of another run ({', '.join(changed)} differ: "
                    f"{found.get(changed[0])!r} there, {identity.get(changed[0])!r} now). "
                    "Give the same command to resume it, or another output.")
        else:
            from tap_bench.tableio import atomic_path

            folder.mkdir(parents=True, exist_ok=True)
            with atomic_path(run) as tmp:
                tmp.write_text(json.dumps(identity))
        self.rows: dict[int, dict] = {}  # seed position -> episode row
        self.trajectory_parts: list[tuple[int, Path]] = []
        for path in sorted(folder.glob("part-*.episodes.jsonl")):
            first = int(path.name.split("-")[1].split(".")[0])
            lines = path.read_text().splitlines()
            for k, line in enumerate(lines):
                self.rows[first + k] = json.loads(line)
            for suffix in PART_SUFFIXES:
                table = folder / f"part-{first:08d}{suffix}"
                if table.exists():
                    self.trajectory_parts.append((first, table))
                    break

    def write(self, first: int, tables: list[pd.DataFrame], rows: list[dict]) -> None:
        """Write the part of seed positions ``first`` .. ``first + len(rows) - 1``."""
        import pandas as pd

        from tap_bench.tableio import atomic_paths

        kept = [t for t in tables if len(t)]
        episodes = self.folder / f"part-{first:08d}.episodes.jsonl"
        paths = [episodes]
        if kept:
            table_path = self.folder / f"part-{first:08d}{PART_SUFFIXES[0]}"
            paths.append(table_path)
        lines = [json.dumps({k: _json_value(v) for k, v in row.items()}) for row in rows]
        with atomic_paths(paths) as temps:
            temps[0].write_text("".join(line + "\n" for line in lines))
            if kept:
                _write_part(pd.concat(kept, ignore_index=True), temps[1])
        if kept:
            self.trajectory_parts.append((first, table_path))
        for k, line in enumerate(lines):  # as a resumed run reads them back
            self.rows[first + k] = json.loads(line)

    def remove(self) -> None:
        """Remove what this run wrote in the folder, and the folder when that empties it."""
        for path in self.folder.glob("part-*"):
            if path.name.endswith((*PART_SUFFIXES, ".episodes.jsonl")):
                path.unlink(missing_ok=True)
        for path in self.folder.glob(".*.tmp"):  # a killed run's unfinished part
            if path.name.startswith((".part-", ".run.json.")):
                path.unlink(missing_ok=True)
        (self.folder / "run.json").unlink(missing_ok=True)
        try:
            self.folder.rmdir()
        except OSError:  # something else is in it: not ours to delete
            pass


def _write_part(frame: pd.DataFrame, path: Path) -> None:
    """A part's trajectory rows as an Arrow IPC file at ``path``: the table pandas' Parquet
    writer would make (its schema and pandas metadata), text columns dictionary-encoded,
    LZ4-compressed (:func:`_part_batches` reads it back as that table)."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.feather as feather

    table = pa.Table.from_pandas(frame, preserve_index=False)
    columns = [pc.dictionary_encode(column) if pa.types.is_large_string(column.type)
               or pa.types.is_string(column.type) else column for column in table.columns]
    feather.write_feather(pa.table(columns, names=table.column_names,
                                   metadata=table.schema.metadata), str(path),
                          compression="lz4")


def _plain(schema: pa.Schema) -> pa.Schema:
    """``schema`` with each dictionary type as its values' type."""
    import pyarrow as pa

    return pa.schema([field.with_type(field.type.value_type)
                      if pa.types.is_dictionary(field.type) else field for field in schema],
                     metadata=schema.metadata)


def _part_schema(path: Path) -> pa.Schema:
    """The schema of a part's trajectory rows (Arrow IPC or Parquet, by its suffix)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    if path.suffix == ".arrow":
        with pa.OSFile(str(path)) as source:
            return _plain(pa.ipc.open_file(source).schema)
    return pq.read_schema(path)


def _part_batches(path: Path) -> Iterator[pa.RecordBatch]:
    """A part's trajectory rows (Arrow IPC or Parquet, by its suffix) in batches of
    :data:`READ_BATCH_ROWS` rows, as pyarrow's Parquet reader gives them (dictionaries
    decoded)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    if path.suffix != ".arrow":
        yield from pq.ParquetFile(path).iter_batches(batch_size=READ_BATCH_ROWS)
        return
    with pa.OSFile(str(path)) as source:  # read into memory, not mapped
        reader = pa.ipc.open_file(source)
        table = reader.read_all().cast(_plain(reader.schema)).combine_chunks()
    yield from table.to_batches(max_chunksize=READ_BATCH_ROWS)


def join_parquet(parts: list[Path], out: Path) -> int:
    """The parts (Parquet, or Arrow IPC files ending ``.arrow``) as one Parquet file at
    ``out``, row groups of :data:`ROW_GROUP_ROWS` rows; one part (and one row group) in
    memory at a time. The rows written."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    schemas = [_part_schema(p) for p in parts]
    schema = pa.unify_schemas(schemas, promote_options="permissive").with_metadata(
        schemas[0].metadata)
    pending: list[pa.Table] = []
    held = rows = 0
    with pq.ParquetWriter(out, schema) as writer:
        def flush(final: bool) -> None:
            nonlocal pending, held
            table = pa.concat_tables(pending)
            start = 0
            while table.num_rows - start >= ROW_GROUP_ROWS or (final and start < table.num_rows):
                chunk = table.slice(start, ROW_GROUP_ROWS)
                writer.write_table(chunk, row_group_size=ROW_GROUP_ROWS)
                start += chunk.num_rows
            pending = [table.slice(start)] if start < table.num_rows else []
            held = table.num_rows - start

        for path in parts:
            for batch in _part_batches(path):
                table = pa.Table.from_batches([batch])
                for field in schema:  # a column some parts lack: nulls there
                    if field.name not in table.column_names:
                        table = table.append_column(field, pa.nulls(table.num_rows,
                                                                     field.type))
                table = table.select(schema.names).cast(schema)
                table = table.replace_schema_metadata(schema.metadata)
                pending.append(table)
                held += table.num_rows
                rows += table.num_rows
                if held >= ROW_GROUP_ROWS:
                    flush(False)
        if pending:
            flush(True)
    return rows


def _join_csv(parts: list[Path], out: Path, gz: bool) -> int:
    import gzip


    rows = 0
    columns: list[str] = []
    for path in parts:
        columns += [c for c in _part_schema(path).names if c not in columns]
    opener = gzip.open if gz else open
    with opener(out, "wt", encoding="utf-8", newline="") as handle:
        for path in parts:
            for batch in _part_batches(path):
                table = batch.to_pandas().reindex(columns=columns)
                table.to_csv(handle, index=False, header=rows == 0)
                rows += len(table)
    return rows


def stream_rollout(env: str | os.PathLike | Scenario | WomdScenes | gym.Env,
                   policy: str | os.PathLike | Policy | PolicyDefinition,
                   seeds: str | int | Sequence[int], output: str | os.PathLike, *,
                   episodes_output: str | os.PathLike | None = None,
                   backend: Backend | None = None, workers: int = 1, resume: bool = False,
                   retries: int = DEFAULT_RETRIES, progress: bool | None = None,
                   log: str | os.PathLike | None = None,
                   config: Mapping[str, Any] | None = None, duration: float | None = None,
                   lane_change: str | None = None, validate: bool = True,
                   ego_only: bool = False) -> StreamedRollout:
    """Run ``policy`` on ``env`` once per seed, as :func:`~tap_bench.sim.rollout.rollout`,
    writing the tables to ``output`` and ``episodes_output`` (module docstring).

    Args:
        env, policy, seeds, backend, workers, retries, config, duration, lane_change: as
            :func:`~tap_bench.sim.rollout.rollout`.
        output: the trajectory table (``.parquet``, ``.csv`` or ``.csv.gz``).
        episodes_output: the episode table (default: ``<name>.episodes.<suffix>``).
        resume: keep the parts an interrupted run of the same command left and run the
            rest (without it, parts found there are an error).
        progress: progress lines on stderr (None or True: yes; False: none).
        log: a file the progress lines are appended to as well.
        validate: check each part against the trajectory contract before it is written.
        ego_only: write only the ego's rows of the trajectory table (``is_ego``), one
            track of a recorded scene's tens to hundreds (the episode table, made from
            every agent, is the same).

    Returns:
        :class:`StreamedRollout`.

    Raises:
        OutputPathError: parts of an interrupted run without ``resume``, or parts of
            another run.
        EpisodesFailedError: every episode failed (the episode table is written first).
    """
    import pandas as pd

    from tap_bench.progress import SceneProgress
    from tap_bench.tableio import _format, check_outputs, episodes_path

    output = Path(output)
    episodes_out = Path(episodes_output) if episodes_output else episodes_path(output)
    check_outputs([output, episodes_out])
    _format(output), _format(episodes_out)  # a bad table name fails before any scene runs
    scenario = resolve_scenario(env, config=config, duration=duration,
                                lane_change=lane_change)
    seed_list = (list(scenario.seeds(seeds)) if isinstance(scenario, WomdScenes)
        else parse_seeds(seeds))
    spec = resolve_policy(policy)
    name = getattr(spec, "name", "policy")
    parts = _Parts(parts_folder(output), _identity(scenario, spec, seed_list, True, ego_only),
                   resume)
    before = len(parts.rows)
    todo = [k for k in range(len(seed_list)) if k not in parts.rows]
    tasks = episode_tasks(scenario, spec, [seed_list[k] for k in todo])
    runner = resolve_backend(backend, workers)
    bar = SceneProgress(len(seed_list), f"{scenario.name} {name}", before=before,
                        show=progress is not False, log=os.fspath(log) if log else None,
                        unit="scene" if isinstance(scenario, WomdScenes) else "episode")
    if before:
        bar.note(f"resuming: {before} of {len(seed_list)} {bar.unit}s were done before, "
                 f"{len(todo)} to run")
    tables: list[pd.DataFrame] = []
    rows: list[dict] = []
    first, held, last_write = 0, 0, time.monotonic()
    try:
        outcomes = runner.imap(_run_task, tasks, retries=retries, progress=False,
                               total=len(tasks))
        for task, k, outcome in zip(tasks, todo, outcomes, strict=True):
            table, row = outcome.value if outcome.ok else (pd.DataFrame(),
                                                           _failed_row(task, outcome.error))
            if ego_only:
                table = ego_rows(table)
            if validate and len(table):
                from tap_bench.trajectories import plainly_valid, validate_and_index

                if not plainly_valid(table):  # else pandas' check decides, names the fault
                    validate_and_index(table,
                                       source=f"{output} (seed {task.seed}, not written)")
            if not rows:
                first = k
            elif k != first + len(rows):  # a gap (seeds done before): the part ends here
                parts.write(first, tables, rows)
                tables, rows, held, first = [], [], 0, k
            tables.append(table)
            rows.append(row)
            held += len(table)
            bar.update(row["status"])
            if (len(rows) >= PART_SCENES or held >= PART_ROWS
                    or time.monotonic() - last_write >= PART_SECONDS):
                parts.write(first, tables, rows)
                tables, rows, held, last_write = [], [], 0, time.monotonic()
        if rows:
            parts.write(first, tables, rows)
            tables, rows = [], []
    except BaseException:
        bar.close()
        if rows:  # what finished is kept for --resume
            parts.write(first, tables, rows)
        raise
    bar.close()
    episodes, written, joined = _join_parts(parts, len(seed_list), output, episodes_out)
    result = collect_rollout([], episodes, stacklevel=3)  # warnings; all failed raises
    return StreamedRollout(output if joined else None, episodes_out, result.episodes,
                           written, before)


def _join_parts(parts: _Parts, n: int, output: Path, episodes_out: Path
                ) -> tuple[pd.DataFrame, int, bool]:
    """The parts of a streamed rollout of ``n`` episodes joined into its outputs, both
    written atomically, and the parts removed: (the episode table, the trajectory rows
    written, whether a trajectory table was written: not when no episode has rows)."""
    import pandas as pd

    from tap_bench.tableio import _format, _write, atomic_paths

    ordered = [parts.rows[k] for k in range(n)]
    extra = [key for row in ordered for key in row if key not in EPISODE_COLUMNS]
    episodes = pd.DataFrame(ordered, columns=[*EPISODE_COLUMNS, *dict.fromkeys(extra)])
    table_parts = [p for _, p in sorted(parts.trajectory_parts)]
    written = 0
    targets = [episodes_out] + ([output] if table_parts else [])
    with atomic_paths(targets) as temps:
        _write(episodes, temps[0], episodes_out)
        if table_parts:
            if _format(output) == "parquet":
                written = join_parquet(table_parts, temps[1])
            else:
                written = _join_csv(table_parts, temps[1],
                                    output.name.lower().endswith(".gz"))
    parts.remove()
    return episodes, written, bool(table_parts)
