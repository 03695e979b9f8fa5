"""Reading and writing tables (Parquet or CSV) at the edges of the pipeline.

Writes are atomic: the table goes to a temporary file beside the target, which is renamed
over it only once complete, so an interrupted run never leaves half a file behind.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pandas as pd

from tap_bench.errors import FileFormatError

__all__ = ["atomic_path", "read_table", "write_table"]

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
    path = Path(path)
    fmt = _format(path)
    if not path.is_file():
        raise FileFormatError(f"{path}: no such file.")
    try:
        if fmt == "parquet":
            return pd.read_parquet(path)
        return pd.read_csv(path, dtype={c: str for c in _ID_COLUMNS}, keep_default_na=True)
    except (OSError, ValueError) as err:
        raise FileFormatError(f"{path}: cannot read it as {fmt}: {err}") from err


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success only."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the file the usual mode
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def write_table(table: pd.DataFrame, path: str | os.PathLike) -> Path:
    """Write ``table`` atomically as Parquet or CSV, chosen by the suffix of ``path``."""
    path = Path(path)
    fmt = _format(path)
    with atomic_path(path) as tmp:
        if fmt == "parquet":
            table.to_parquet(tmp, index=False)
        else:
            table.to_csv(tmp, index=False, compression="gzip" if path.name.endswith(".gz")
                         else None)
    return path
