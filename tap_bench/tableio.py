"""Reading and writing tables (Parquet or CSV) at the edges of the pipeline, and the rules
every output of tap-bench follows.

- Writes are atomic: a file goes to a temporary file beside the target, renamed over it
  only once complete (:func:`atomic_path`), so an interrupted run never leaves half a file
  behind. Several outputs of one command land together or not at all
  (:func:`atomic_paths`): their temporary files are made before the work starts, so an
  unwritable place fails at once, and they are renamed into place only when all are done.
- An output is never one of the inputs (:func:`check_outputs`).
- A folder is replaced only when tap-bench wrote it: :func:`atomic_folder` leaves a marker
  file (:data:`FOLDER_MARKER`, listing every file it wrote) in every folder it builds and
  refuses to replace a folder without one, a folder holding anything it did not write
  (a file added by hand), a file or a symbolic link.
- A file that exists is replaced only when asked (``--overwrite``,
  :func:`check_replace`).
- Files and folders get the usual modes (``0o666`` / ``0o777`` less the umask), not the
  ``0o600`` / ``0o700`` of temporary files.
"""

from __future__ import annotations

import contextlib
import gzip
import json
import os
import shutil
import socket
import tempfile
import zlib
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from tap_bench.errors import FileFormatError, OutputPathError, RunExistsError

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["FOLDER_MARKER", "OWNER_FILE", "atomic_folder", "atomic_path", "atomic_paths", "beside",
           "check_folder_output", "check_outputs", "check_replace", "check_writable",
           "EncodedTable", "episodes_path", "owner_gone", "owner_line", "read_table",
           "read_table_encoded", "remove_abandoned", "write_table", "write_tables"]

FOLDER_MARKER = ".tap-bench-folder"
"""The file tap-bench leaves in every results folder it writes; only a folder holding it may
be replaced (``--overwrite``)."""

OWNER_FILE = ".tap-bench-owner"
"""The file naming the process that is building a folder under its temporary name
(:func:`owner_line`), so that a later run can tell the folder of a process that was killed
from one still being written (:func:`remove_abandoned`); removed before the folder is renamed
into place."""

_ID_COLUMNS = ("scenario_id", "track_id")
_SUFFIXES = {".parquet": "parquet", ".pq": "parquet", ".csv": "csv", ".csv.gz": "csv"}


def _format(path: Path) -> str:
    name = path.name.lower()
    for suffix, fmt in _SUFFIXES.items():
        if name.endswith(suffix):
            return fmt
    raise FileFormatError(
        f"{path}: unknown table format; use a .parquet or .csv (.csv.gz) file name."
    )


def read_table(path: str | os.PathLike) -> pd.DataFrame:
    """Read a Parquet or CSV table; ``scenario_id`` and ``track_id`` stay strings.

    Raises:
        FileFormatError: the file is missing, has an unknown suffix or cannot be parsed.
    """
    import pandas as pd

    path = Path(path)
    fmt = _format(path)
    if not path.is_file():
        raise FileFormatError(f"{path}: no such file." if not path.exists() else
                              f"{path}: not a regular file (a folder or a device); give the "
                              "table's file.")
    if fmt == "csv":  # plain text, or gzip's bytes decompressed as they are scanned
        try:
            _check_csv_text(path)
        except (OSError, EOFError, zlib.error) as err:  # a damaged or truncated .gz
            raise FileFormatError(f"{path}: cannot read it as csv ({type(err).__name__}: "
                                  f"{err}); the file is damaged or cut short.") from None
    try:
        if fmt == "parquet":
            # columns handed over from Arrow one by one, each freed once converted: half
            # the peak memory and page faults of a whole-table conversion, the same table
            return pd.read_parquet(path, memory_map=True, to_pandas_kwargs={
                "split_blocks": True, "self_destruct": True})
        return pd.read_csv(path, dtype={c: str for c in _ID_COLUMNS}, keep_default_na=True)
    except UnicodeDecodeError as err:
        raise FileFormatError(_not_utf8(path) or f"{path}: cannot read it as {fmt}: {err}"
                              ) from err
    except (OSError, ValueError) as err:
        raise FileFormatError(f"{path}: cannot read it as {fmt}: {err}") from err


_SCAN_BYTES = 1 << 20  # a CSV file is scanned for NUL bytes this much at a time [B]


def _check_csv_text(path: Path) -> None:
    """Refuse, before the parser reads it whole into memory, a CSV file that holds a NUL
    byte: it is not text (a binary file; a sparse or preallocated file, whose holes read as
    zeros; such zeros gzipped, a few MB for GBs). The scan reads the file once, a block at
    a time (a ``.gz`` file decompressed as it goes).

    Raises:
        FileFormatError: naming the file, the line and byte of the first NUL, and the fix.
    """
    line, offset = 1, 0
    opener = gzip.open if path.name.lower().endswith(".gz") else open
    with opener(path, "rb") as stream:
        if stream.read(2) in (b"\xff\xfe", b"\xfe\xff"):
            return  # UTF-16 text (every other byte NUL): the UTF-8 check names it and the fix
        stream.seek(0)
        for block in iter(lambda: stream.read(_SCAN_BYTES), b""):
            at = block.find(b"\0")
            if at < 0:
                line += block.count(b"\n")
                offset = (len(block) - block.rfind(b"\n") - 1 if b"\n" in block
                    else offset + len(block))
                continue
            line += block.count(b"\n", 0, at)
            start = block.rfind(b"\n", 0, at)
            column = at - start if start >= 0 else offset + at + 1
            raise FileFormatError(
                f"{path}: line {line}, byte {column} is a NUL byte: a CSV table is text, and "
                "this is a binary file (or one never written: a sparse or preallocated file "
                "reads as zeros). Give the CSV table itself, or a Parquet file (.parquet).")


def _not_utf8(path: Path) -> str | None:
    """Where CSV file ``path`` stops being UTF-8 text, as a message with the fix (None
    where it cannot be found: the decoder's own message is shown then)."""
    try:
        data = path.read_bytes()
        data.decode("utf-8")
    except UnicodeDecodeError as err:
        line = data.count(b"\n", 0, err.start) + 1
        column = err.start - (data.rfind(b"\n", 0, err.start) + 1) + 1
        source = ("utf-16" if data[:2] in (b"\xff\xfe", b"\xfe\xff")  # its byte-order mark
                  else "latin1")
        return (f"{path}: line {line}, byte {column} is not UTF-8 text (0x{data[err.start]:02x}"
                f"): tap-bench reads CSV tables as UTF-8. Save the file as UTF-8, e.g. "
                f"iconv -f {source} -t utf-8 {path.name} > utf8-{path.name}"
                + (" (it starts as UTF-16 does)." if source == "utf-16"
                   else " for a Latin-1 file."))
    except OSError:
        return None
    return None


def _str_dtype():
    """The dtype pandas reads a Parquet string column as (``str``)."""
    import pandas as pd

    return pd.StringDtype("pyarrow", na_value=float("nan"))


class EncodedTable:
    """A large Parquet table read with its string columns dictionary-encoded: each
    distinct string once and a code a row (the 25,900-track sample's four string columns:
    4 x 9 MB of codes instead of 146 MB of strings, and a third of the reading time).

    Each encoded column's codes rank its values by code point (as Arrow and
    ``pd.factorize(sort=True)`` sort strings), -1 where missing. :meth:`part` gives rows
    as a frame in which those columns are categoricals of those sorted values;
    :meth:`decoded` gives back the strings of some codes; :meth:`frame` is
    :func:`read_table`'s frame of the whole file.

    Attributes:
        path: the Parquet file.
        num_rows: its number of rows.
        codes: encoded column -> (num_rows,) codes (the smallest signed integer type).
        values: encoded column -> its distinct values, sorted (an Arrow string array).
    """

    def __init__(self, path: Path, arrow, encoded: list[str]):
        import numpy as np
        import pandas as pd
        import pyarrow as pa
        import pyarrow.compute as pc

        self.path = path
        self.num_rows = arrow.num_rows
        self.codes: dict[str, np.ndarray] = {}
        self.values: dict[str, pa.Array] = {}
        self._dtypes: dict[str, pd.CategoricalDtype] = {}
        self._names = list(arrow.column_names)
        for name in encoded:
            column = arrow.column(name)
            dictionary = column.chunk(0).dictionary  # one a column (unified)
            order = pc.array_sort_indices(dictionary).to_numpy()
            # codes of the type pandas keeps them in (int8 below 127 values ...): no copy
            code_type = next(t for t in (np.int8, np.int16, np.int32, np.int64)
                             if len(order) < np.iinfo(t).max)
            rank = np.empty(len(order) + 1, code_type)
            rank[order] = np.arange(len(order))
            rank[-1] = -1  # a missing value's code
            codes = np.empty(len(column), code_type)
            start = 0
            for chunk in column.chunks:  # each chunk's ranks in place (no joined copy)
                indices = chunk.indices.fill_null(-1) if chunk.null_count else chunk.indices
                stop = start + len(indices)
                np.take(rank, indices.to_numpy(zero_copy_only=False), out=codes[start:stop])
                start = stop
            self.codes[name] = codes
            self.values[name] = dictionary.take(pa.array(order)).cast(pa.large_string())
            self._dtypes[name] = pd.CategoricalDtype(
                pd.Index(pd.array(self.values[name], dtype=_str_dtype())), ordered=False)
        self._rest = arrow.drop_columns(encoded)
        self._frame = None

    @property
    def columns(self) -> list[str]:
        """The column names, in the file's order."""
        return list(self._names)

    def frame(self) -> pd.DataFrame:
        """:func:`read_table`'s frame of the whole file (read again, once)."""
        if self._frame is None:
            self._frame = read_table(self.path)
        return self._frame

    def part(self, start: int, stop: int) -> pd.DataFrame:
        """Rows ``start:stop`` as a frame, each encoded column a categorical of its sorted
        values (the other columns as :func:`read_table` gives them)."""
        import pandas as pd

        # (one thread: the CPU time counts every thread's, and a part is small)
        out = self._rest.slice(start, stop - start).to_pandas(
            split_blocks=True, use_threads=False)
        for position, name in enumerate(self._names):
            if name in self.codes:
                out.insert(position, name, pd.Categorical.from_codes(
                    self.codes[name][start:stop], dtype=self._dtypes[name], validate=False))
        return out

    def decoded(self, name: str, codes) -> pd.api.extensions.ExtensionArray:
        """The strings of ``codes`` (-1: missing) of encoded column ``name``, as
        :func:`read_table`'s column holds them."""
        import numpy as np
        import pandas as pd
        import pyarrow as pa

        codes = np.asarray(codes)
        return pd.array(self.values[name].take(pa.array(codes, mask=codes < 0)),
                        dtype=_str_dtype())


def read_table_encoded(path: str | os.PathLike, min_rows: int,
                       by: str = "scenario_id") -> pd.DataFrame | EncodedTable:
    """:func:`read_table`, or for a Parquet file of more than ``min_rows`` rows whose column
    ``by`` (the one a table is cut by, :func:`tap_bench.labelling.tap_in_parts`) is read
    as strings, an :class:`EncodedTable` (the string columns dictionary-encoded).

    Raises:
        FileFormatError: as :func:`read_table`.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = Path(path)
    if _format(path) != "parquet" or not path.is_file():
        return read_table(path)
    try:
        schema = pq.read_schema(path, memory_map=True)
        num_rows = pq.read_metadata(path, memory_map=True).num_rows
    except (OSError, ValueError):
        return read_table(path)  # its error
    names = schema.names
    if num_rows <= min_rows:  # not to be cut: as read
        return read_table(path)
    empty = schema.empty_table().to_pandas()
    columns = list(empty.columns)
    if names[:len(columns)] != columns:  # (the file's pandas metadata makes other columns,
        return read_table(path)  # or an index of columns before the last): as read
    # only the frame's columns (not those of an index that the file's pandas metadata
    # makes, which come last) that pandas reads as `str` (not those the metadata makes
    # something else), each name once
    strings = [f.name for f in schema
               if (pa.types.is_string(f.type) or pa.types.is_large_string(f.type))
               and names.count(f.name) == 1 and f.name in columns
               and empty[f.name].dtype == _str_dtype()]
    if by not in strings:  # not to be cut: as read
        return read_table(path)
    try:
        # (a ParquetFile reads without loading pyarrow.dataset)
        arrow = pq.ParquetFile(path, memory_map=True, read_dictionary=strings).read(
            use_threads=False)  # (the CPU time counts every thread's; reading is 0.06 s)
        arrow = arrow.unify_dictionaries()
    except (OSError, ValueError) as err:
        raise FileFormatError(f"{path}: cannot read it as parquet: {err}") from err
    if arrow.column_names != names or arrow.num_rows != num_rows or any(
            len(arrow.column(n).chunk(0).dictionary.unique())
            != len(arrow.column(n).chunk(0).dictionary) for n in strings):
        return read_table(path)
    return EncodedTable(path, arrow, strings)


def _umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask


def check_writable(path: str | os.PathLike) -> Path:
    """Check, before any work, that a file can be written at ``path``.

    The nearest existing folder on the way to ``path`` must be a writable folder, and
    ``path`` itself must not be a folder. Nothing is created.

    Raises:
        OutputPathError: naming the path, what is in the way and the fix.
    """
    path = Path(path)
    if path.is_dir():
        raise OutputPathError(f"{path}: is a folder; give a file name for this output.")
    parent = path.parent
    while not parent.exists():
        if parent == parent.parent:
            break
        parent = parent.parent
    if parent.exists() and not parent.is_dir():
        raise OutputPathError(f"{path}: {parent} is a file, not a folder; choose another "
                              "output path.")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputPathError(f"{path}: cannot write in {parent} (permission denied); choose "
                              "a folder you can write to.")
    return path


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and a.samefile(b))
    except OSError:
        return False


def beside(path: str | os.PathLike, part: str) -> Path:
    """The companion file of an output: ``run.csv`` and ``"labels"`` give ``run.labels.csv``
    (same folder and format)."""
    path = Path(path)
    return path.with_name(f"{path.stem}.{part}{path.suffix}")


def check_outputs(outputs: Iterable[str | os.PathLike | None],
                  inputs: Iterable[str | os.PathLike | None] = ()) -> list[Path]:
    """Check the outputs of one command before any work: none is an input, none is given
    twice, each is writable (:func:`check_writable`). ``None`` entries are ignored.

    Returns:
        the outputs as Paths.

    Raises:
        OutputPathError: naming the path and the fix.
    """
    outs = [Path(p) for p in outputs if p is not None]
    ins = [Path(p) for p in inputs if p is not None]
    for out in outs:
        for src in ins:
            if _same_file(out, src):
                raise OutputPathError(f"{out}: is also an input ({src}); writing it would "
                                      "replace the input. Choose another output path.")
    for i, out in enumerate(outs):
        for other in outs[:i]:
            if _same_file(out, other):
                raise OutputPathError(f"{out}: is given for two outputs; give each its own "
                                      "path.")
        check_writable(out)
    return outs


def _temp_beside(path: Path) -> Path:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except PermissionError as err:
        raise OutputPathError(f"{path}: cannot write in {path.parent} ({err.strerror}); "
                              "choose a folder you can write to.") from err
    except (FileExistsError, NotADirectoryError) as err:
        raise OutputPathError(f"{path}: {err.filename} is in the way ({err.strerror}); "
                              "choose another output path.") from err
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file the usual mode
    return Path(tmp)


@contextlib.contextmanager
def atomic_paths(paths: Sequence[str | os.PathLike]) -> Iterator[list[Path]]:
    """Yield temporary paths beside ``paths``; on success rename them all into place.

    The temporary files are created on entry, before the caller's work, so an output in an
    unwritable place fails at once. On an exception nothing is renamed and the temporary
    files are removed. When a rename fails midway (a full or vanished file system), the
    outputs already renamed are put back as they were: the outputs land together or not
    at all.

    Raises:
        OutputPathError: an output's folder cannot be written.
    """
    targets = [Path(p) for p in paths]
    temps: list[Path] = []
    try:
        for target in targets:
            temps.append(_temp_beside(target))
        yield list(temps)
        _commit(targets, temps)
    finally:
        for tmp in temps:
            tmp.unlink(missing_ok=True)


def _commit(targets: list[Path], temps: list[Path]) -> None:
    """Rename ``temps`` onto ``targets``; undo the renames done when one fails."""
    if len(targets) == 1:
        os.replace(temps[0], targets[0])
        return
    backups: list[Path | None] = []
    try:
        for target in targets:  # hard links keep the old versions at no cost
            backup = None
            if target.is_file():
                backup = target.with_name(f".{target.name}.{os.getpid()}.bak")
                backup.unlink(missing_ok=True)
                try:
                    os.link(target, backup)
                except OSError:
                    shutil.copy2(target, backup)
            backups.append(backup)
        done = 0
        try:
            for tmp, target in zip(temps, targets, strict=True):
                os.replace(tmp, target)
                done += 1
        except BaseException:
            for target, backup in list(zip(targets, backups, strict=True))[:done]:
                if backup is not None:
                    os.replace(backup, target)
                else:
                    target.unlink(missing_ok=True)
            raise
    finally:
        for backup in backups:
            if backup is not None:
                backup.unlink(missing_ok=True)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success only."""
    with atomic_paths([path]) as (tmp,):
        yield tmp


def check_folder_output(path: str | os.PathLike, overwrite: bool) -> Path:
    """Check, before any work, that a results folder may be written at ``path``.

    A new path is fine when its place is writable. An existing one is replaced only with
    ``overwrite`` and only when it is a folder tap-bench wrote (it holds
    :data:`FOLDER_MARKER`); a file, a symbolic link or any other folder is refused.

    Raises:
        OutputPathError: naming the path, why it is refused and the fix.
    """
    path = Path(path)
    if path.is_symlink():
        raise OutputPathError(f"{path}: is a symbolic link; tap-bench does not replace "
                              "links. Give the folder itself or another name.")
    if path.exists():
        if not path.is_dir():
            raise OutputPathError(f"{path}: is a file, not a results folder; choose another "
                                  "name or remove the file yourself.")
        if not (path / FOLDER_MARKER).is_file():
            raise OutputPathError(
                f"{path}: exists and was not written by tap-bench (it has no "
                f"{FOLDER_MARKER}); it is never replaced. Choose another folder, or remove "
                "it yourself.")
        if not overwrite:
            raise RunExistsError(f"{path} exists; choose another folder or pass "
                                    "--overwrite to replace it.")
        foreign = _not_written_by_tap_bench(path)
        if foreign:
            shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more"
                                              if len(foreign) > 5 else "")
            raise OutputPathError(
                f"{path}: holds {shown}, which tap-bench did not write there; --overwrite "
                "replaces only what tap-bench wrote. Move them out of the folder, or choose "
                "another folder.")
        if not os.access(path.parent, os.W_OK | os.X_OK):
            raise OutputPathError(f"{path}: cannot replace it, {path.parent} is not "
                                  "writable.")
        return path
    return check_writable(path)


def _contents(folder: Path) -> list[str]:
    """Every file and folder under ``folder``, as sorted relative POSIX paths."""
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


def _not_written_by_tap_bench(folder: Path, prefix: str = "") -> list[str]:
    """What ``folder`` holds that its marker does not list; a sub-folder with a marker of
    its own (a viewer written again) is checked against that one. A folder written before
    markers listed their files: nothing can be told, nothing is listed."""
    try:
        marker = json.loads((folder / FOLDER_MARKER).read_text())
    except (OSError, ValueError):
        return [prefix + FOLDER_MARKER + " (damaged)"]
    listed = marker.get("files") if isinstance(marker, dict) else None
    if not isinstance(listed, list):
        return []
    listed_set = set(map(str, listed))
    out: list[str] = []
    for root, dirs, files in os.walk(folder):
        here = Path(root)
        for name in list(dirs):
            sub = here / name
            rel = sub.relative_to(folder).as_posix()
            if (sub / FOLDER_MARKER).is_file() and not sub.is_symlink():
                dirs.remove(name)  # its own marker speaks for it
                out += _not_written_by_tap_bench(sub, f"{prefix}{rel}/")
            elif rel not in listed_set:
                out.append(prefix + rel)
        for name in files:
            rel = (here / name).relative_to(folder).as_posix()
            if rel not in listed_set and rel != FOLDER_MARKER:
                out.append(prefix + rel)
    return sorted(out)


def check_replace(paths: Iterable[str | os.PathLike], overwrite: bool, *,
                  ours: Callable[[Path], bool] | None = None) -> list[Path]:
    """Check, before any work, that the files ``paths`` may be written: a path that exists
    is replaced only with ``overwrite``, and, when ``ours`` is given, only when ``ours(path)``
    says tap-bench wrote it.

    Raises:
        RunExistsError: a path exists and ``overwrite`` is False (naming every one).
        OutputPathError: a path exists that tap-bench did not write, or is a folder or link.
    """
    targets = [Path(p) for p in paths]
    existing = [p for p in targets if p.exists() or p.is_symlink()]
    for path in existing:
        if path.is_symlink() or not path.is_file():
            raise OutputPathError(f"{path}: is a folder or a link, not a file tap-bench "
                                  "wrote; choose another output path.")
    if existing and not overwrite:
        raise RunExistsError(f"{', '.join(map(str, existing))} exist(s); choose another "
                             "output path or pass --overwrite to replace them.")
    if ours is not None:
        for path in existing:
            if not ours(path):
                raise OutputPathError(f"{path}: exists and was not written by tap-bench; it "
                                      "is never replaced. Choose another output path, or "
                                      "move the file yourself.")
    return targets


def process_started(pid: int) -> str | None:
    """When process ``pid`` started (clock ticks since boot, from ``/proc/<pid>/stat``), or
    None where that cannot be read (no such process, no ``/proc``)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as stat:
            fields = stat.read().rpartition(")")[2].split()
        return fields[19]  # field 22 of the line, the 20th after the command's name
    except (OSError, IndexError):
        return None


def owner_line(pid: int) -> str:
    """The line naming process ``pid`` of this host as the owner of a folder it is writing:
    its id, the host and, where it can be read, when the process started (so that another
    process given the same id later is not taken for it)."""
    started = process_started(pid)
    return f"{pid} {socket.gethostname()}" + ("" if started is None else f" {started}")


def owner_gone(line: str) -> bool:
    """Whether the process an :func:`owner_line` names is provably gone: a process of this
    host whose id names no process, or names one that started at another time. False for
    anything else (a live process, another host's, a line that is not an owner line)."""
    fields = line.split()
    try:
        pid = int(fields[0])
    except (ValueError, IndexError):
        return False
    host, started = [*fields[1:], "", ""][:2]
    if host and host != socket.gethostname():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # another user's live process: its start tells
        pass
    except OSError:
        return False
    now = process_started(pid)
    return bool(started) and now is not None and now != started


def remove_abandoned(path: str | os.PathLike) -> list[Path]:
    """Remove the temporary folders :func:`atomic_folder` left beside ``path`` when its
    process was killed (``.<name>.*.tmp`` holding an :data:`OWNER_FILE` whose process is
    gone, :func:`owner_gone`); the folders removed. Anything else is left alone: a folder
    of a live process or of another host, one without an owner file (an older tap-bench's,
    or not tap-bench's at all), a file."""
    path = Path(path)
    removed = []
    try:
        candidates = sorted(path.parent.glob(f".{path.name}.*.tmp"))
    except OSError:
        return []
    for folder in candidates:
        if folder.is_symlink() or not folder.is_dir():
            continue
        try:
            owner = (folder / OWNER_FILE).read_text()
        except (OSError, UnicodeDecodeError):
            continue
        if owner_gone(owner):
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder)
    return removed


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike, overwrite: bool = False,
                  kind: str = "results") -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; move it onto ``path`` on success only.

    The folder gets :data:`FOLDER_MARKER` and the usual mode; while it is written it holds
    :data:`OWNER_FILE`, so that the folder of a process killed meanwhile can be told and
    removed later (:func:`remove_abandoned`). An existing ``path`` is
    replaced only as :func:`check_folder_output` allows; it is checked again at the end,
    as something may have appeared meanwhile.

    Args:
        path: the folder to write.
        overwrite: replace an earlier folder tap-bench wrote there.
        kind: what the folder holds, recorded in the marker.

    Raises:
        OutputPathError, RunExistsError: see :func:`check_folder_output`.
    """
    path = check_folder_output(path, overwrite)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    except PermissionError as err:
        raise OutputPathError(f"{path}: cannot write in {path.parent} ({err.strerror}); "
                              "choose a folder you can write to.") from err
    old: Path | None = None
    try:
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes 0700
        (tmp / OWNER_FILE).write_text(owner_line(os.getpid()) + "\n")
        yield tmp
        (tmp / OWNER_FILE).unlink(missing_ok=True)
        (tmp / FOLDER_MARKER).write_text(json.dumps({"written_by": "tap-bench",
                                                     "kind": kind,
                                                     "files": _contents(tmp)}) + "\n")
        check_folder_output(path, overwrite)
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old",
                                        dir=path.parent))
            os.replace(path, old / path.name)
            try:
                os.replace(tmp, path)
            except BaseException:
                os.replace(old / path.name, path)
                raise
        else:
            os.replace(tmp, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)


def _write(table: pd.DataFrame, tmp: Path, path: Path) -> None:
    """Write ``table`` to ``tmp`` in the format the name of ``path`` asks for."""
    if _format(path) == "parquet":
        table.to_parquet(tmp, index=False)
    else:
        table.to_csv(tmp, index=False,
                     compression="gzip" if path.name.lower().endswith(".gz") else None)


def write_table(table: pd.DataFrame, path: str | os.PathLike) -> Path:
    """Write ``table`` atomically as Parquet or CSV, chosen by the suffix of ``path``."""
    path = Path(path)
    _format(path)
    with atomic_path(path) as tmp:
        _write(table, tmp, path)
    return path


def write_tables(tables: Mapping[str | os.PathLike, pd.DataFrame]) -> list[Path]:
    """Write several tables (path -> table) so that they land together or not at all.

    Call :func:`check_outputs` on the paths before the work that makes the tables, so an
    unwritable place fails before it.

    Returns:
        the paths written, in the order given.
    """
    paths = [Path(p) for p in tables]
    for path in paths:
        _format(path)
    with atomic_paths(paths) as temps:
        for tmp, path, table in zip(temps, paths, tables.values(), strict=True):
            _write(table, tmp, path)
    return paths


def episodes_path(output: Path) -> Path:
    """``idm.parquet`` -> ``idm.episodes.parquet`` (``.csv.gz`` kept whole)."""
    name = output.name
    for suffix in (".csv.gz", ".parquet", ".pq", ".csv"):
        if name.lower().endswith(suffix):
            return output.with_name(name[: -len(suffix)] + ".episodes" + name[-len(suffix):])
    return output.with_name(name + ".episodes.parquet")
