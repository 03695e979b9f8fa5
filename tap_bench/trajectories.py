"""The trajectory table: its contract (SPEC section 1) and its validation on entry.

One row per vehicle per time step::

    scenario_id  str    scenario the track belongs to
    track_id     str    track within the scenario (a string even when it looks like a number)
    t            float  time [s], strictly increasing within a track, 10 Hz
    x, y         float  position [m], WOMD axes: y to the left
    heading      float  [rad], counter-clockwise from +x
    speed        float  [m/s], >= 0 (computed from vx, vy when absent)

Optional: ``valid`` (bool), ``vx``, ``vy`` [m/s], ``object_type`` (vehicle, pedestrian,
cyclist, other), ``is_ego`` (bool), ``source``, ``env``, ``policy``, ``seed``, ``crashed``.

Rows of different tracks may be interleaved (WOMD's time-major layout is fine); rows of one
track must be in increasing ``t`` and are never silently sorted. A step of 0.1 s (10 %
tolerance) is regular; a gap of a whole number of steps (2 or more) marks missing steps and
splits the track into valid segments, as ``valid == False`` rows do. Any other step is
irregular and an error. Data sampled at another rate is refused: resample it first with
:func:`tap_bench.resample_to_10hz`.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from tap_bench.errors import TrajectoryTableError, did_you_mean

if TYPE_CHECKING:
    import numpy as np
    import pandas as pd
    import pyarrow as pa

__all__ = [
    "DT",
    "HZ",
    "IDENTIFYING_COLUMNS",
    "OBJECT_TYPES",
    "OPTIONAL_COLUMNS",
    "REQUIRED_COLUMNS",
    "plainly_valid",
    "validate_trajectories",
]

HZ = 10.0
"""Sampling rate TAP works at [Hz] (WOMD: 91 steps over 9.1 s)."""
DT = 1.0 / HZ
"""Time step [s]."""
DT_TOLERANCE = 0.1
"""Relative tolerance on a step: 0.09 s to 0.11 s is one regular step (WOMD: about 0.1002 s)."""
MAX_SPEED = 100.0
"""No vehicle moves faster [m/s]: a larger speed is an input error (SPEC section 2)."""
MAX_COORDINATE = 1e7
"""Largest |x| or |y| [m] of a position in a local metric frame (SPEC section 2)."""
MAX_GAP_STEPS = 10_000
"""A larger jump in t is taken as a mistake (wrong units), not as missing steps."""

REQUIRED_COLUMNS = ("scenario_id", "track_id", "t", "x", "y", "heading", "speed")
OPTIONAL_COLUMNS = (
    "valid",
    "vx",
    "vy",
    "object_type",
    "is_ego",
    "source",
    "env",
    "policy",
    "seed",
    "crashed",
)
IDENTIFYING_COLUMNS = ("source", "env", "policy", "seed", "object_type", "is_ego")
"""Per-track columns carried from the trajectory table into label and segment tables."""
OBJECT_TYPES = ("vehicle", "pedestrian", "cyclist", "other")

_NUMERIC = ("t", "x", "y", "heading", "speed", "vx", "vy")
_KEYS = ("scenario_id", "track_id")
_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class TrackIndex:
    """Where each track and each valid segment lies in a validated table.

    The validated table is ordered by (scenario_id, track_id) and then by ``t``. Arrays are
    over that order.

    Attributes:
        track: (n_rows,) int64, index of the track (0 .. n_tracks-1) of each row.
        track_start: (n_tracks + 1,) int64, first row of each track, then n_rows.
        segment: (n_rows,) int64, index of the valid segment of each row, -1 on invalid rows.
        segment_start: (n_segments,) int64, first row of each valid segment.
        segment_stop: (n_segments,) int64, one past the last row of each valid segment.
        segment_track: (n_segments,) int64, the track of each segment.
    """

    track: np.ndarray
    track_start: np.ndarray
    segment: np.ndarray
    segment_start: np.ndarray
    segment_stop: np.ndarray
    segment_track: np.ndarray

    @property
    def n_tracks(self) -> int:
        return len(self.track_start) - 1

    @property
    def n_segments(self) -> int:
        return len(self.segment_start)

    @property
    def segment_length(self) -> np.ndarray:
        """(n_segments,) int64, number of steps in each valid segment."""
        return self.segment_stop - self.segment_start


def _where(table: pd.DataFrame, pos: int) -> str:
    """Describe input row ``pos`` by position and keys, for error messages."""
    parts = []
    for col in ("scenario_id", "track_id", "t"):
        if col in table.columns:
            parts.append(f"{col}={_plain(table[col].iloc[pos])!r}")
    return f"row {pos}" + (f" ({', '.join(parts)})" if parts else "")


def _plain(value):
    """A numpy scalar as the Python value it holds (for readable messages)."""
    return value.item() if hasattr(value, "item") else value


def _fail(message: str, source: str, *, column: str | None = None, row: int | None = None,
          rate_hz: float | None = None):
    raise TrajectoryTableError(f"{source}: {message}", column=column, row=row,
                               rate_hz=rate_hz)


def _as_id_strings(col: pd.Series, name: str, source: str) -> pd.Series:
    """Identifiers as strings; integral floats (3.0, from a NaN-holding column) become '3'."""
    import numpy as np
    import pandas as pd

    missing = col.array.isna()  # of the array: a Series of flags costs more than a check
    if missing.any():
        pos = int(np.flatnonzero(missing)[0])
        _fail(f"column {name!r} is empty at row {pos}; every row needs a {name}.", source,
              column=name, row=pos)
    if pd.api.types.is_float_dtype(col):
        values = col.to_numpy()
        if np.all(values == np.round(values)):
            col = pd.Series(values.astype(np.int64), index=col.index)
    if pd.api.types.is_string_dtype(col) and not pd.api.types.is_object_dtype(col):
        return col
    return col.astype(str)


def _contract_types(col: pd.Series) -> pd.Series | None:
    """``col`` itself when it is already what lower-casing it as strings gives and holds
    only the contract's object types (a string column of 'vehicle', 'cyclist' ...: the
    usual case, checked on its few distinct values instead of every row), a categorical
    of such strings as strings; else None."""
    import pandas as pd

    if isinstance(col.dtype, pd.CategoricalDtype):  # of the contract's words, none missing:
        # its strings, as lower-casing them gives (checked on the categories)
        categories = col.dtype.categories
        if (categories.dtype == pd.api.types.pandas_dtype(str) and
                not (col.array.codes < 0).any() and
                all(isinstance(v, str) and v in OBJECT_TYPES for v in categories)):
            # (the categories' Arrow strings taken at the codes: astype(str) goes through
            # a Python string a row)
            import pyarrow as pa

            strings = categories.array.__arrow_array__().take(pa.array(col.array.codes))
            return pd.Series(pd.array(strings, dtype=categories.dtype), index=col.index,
                             name=col.name)
        return None
    if col.dtype != pd.api.types.pandas_dtype(str):
        return None
    values = col.unique()
    return col if all(isinstance(v, str) and v in OBJECT_TYPES for v in values) else None


def _check_columns(table: pd.DataFrame, source: str) -> None:
    present = set(table.columns)
    missing = [c for c in REQUIRED_COLUMNS if c not in present]
    if "speed" in missing and {"vx", "vy"} <= present:
        missing.remove("speed")
    if not missing:
        return
    hints = []
    for col in missing:
        err = did_you_mean("column", col, [c for c in map(str, table.columns)])
        if "Did you mean" in str(err):
            hints.append(f"{col!r}: {str(err).split('. Known')[0].split('. ', 1)[1]}")
    fix = (" Rename the columns, or add them." + (" " + "; ".join(hints) if hints else ""))
    extra = " (speed may instead be given as vx, vy)" if "speed" in missing else ""
    _fail(f"missing required column(s) {', '.join(map(repr, missing))}{extra}; the table has "
          f"{', '.join(map(repr, map(str, table.columns)))}.{fix}", source, column=missing[0])


def _numeric(table: pd.DataFrame, col: str, source: str, columns=None) -> np.ndarray:
    import numpy as np
    import pandas as pd

    series = table[col] if columns is None else columns[col]
    if pd.api.types.is_bool_dtype(series) or not pd.api.types.is_numeric_dtype(series):
        converted = pd.to_numeric(series, errors="coerce")
        bad = converted.isna().to_numpy() & series.notna().to_numpy()
        if pd.api.types.is_bool_dtype(series) or bad.any():
            pos = int(np.flatnonzero(bad)[0]) if bad.any() else 0
            _fail(f"column {col!r} must be numeric; {_where(table, pos)} holds "
                  f"{_plain(series.iloc[pos])!r}. Convert it to a number.", source,
                  column=col, row=pos)
        series = converted
    return series.to_numpy(dtype=np.float64, na_value=np.nan)


def _bool_column(table: pd.DataFrame, col: str, source: str, columns=None) -> np.ndarray:
    import numpy as np
    import pandas as pd

    series = table[col] if columns is None else columns[col]
    if series.dtype == np.bool_:  # numpy's bool holds no missing value
        return series.to_numpy()
    if pd.api.types.is_bool_dtype(series) and not series.isna().any():
        return series.to_numpy(dtype=bool)
    values = series.to_numpy(dtype=object)
    ok = np.array([v in (True, False, 0, 1) and v is not None for v in values], dtype=bool)
    if not ok.all():
        pos = int(np.flatnonzero(~ok)[0])
        _fail(f"column {col!r} must be true/false (or 1/0); {_where(table, pos)} holds "
              f"{_plain(values[pos])!r}.", source, column=col, row=pos)
    return values.astype(bool)


def validate_trajectories(table: pd.DataFrame, *, source: str = "trajectory table") -> pd.DataFrame:
    """Check a trajectory table against the contract and return it normalised.

    The result has string ``scenario_id`` and ``track_id``, float64 kinematic columns, a
    boolean ``valid`` column (all true when the input had none), ``speed`` computed as
    ``hypot(vx, vy)`` when absent, and rows ordered by (scenario_id, track_id, t).

    Args:
        table: the trajectory table (one row per vehicle per step).
        source: a name for the table in error messages, usually its file path.

    Raises:
        TrajectoryTableError: naming the column, the row and the fix, for: an empty table,
            missing columns, non-numeric, NaN or infinite values, a non-increasing or
            irregular ``t``, a sampling rate other than 10 Hz, headings that look like
            degrees, negative speed, a speed above 100 m/s or a coordinate beyond 1e7 m,
            unknown object types, duplicate (scenario_id, track_id, t).
    """
    return validate_and_index(table, source=source).frame()


@dataclass(frozen=True)
class CheckedTable:
    """A validated trajectory table as columns in track order, with its :class:`TrackIndex`.

    Attributes:
        columns: column name -> (n_rows,) numpy array (numeric, bool) or pandas Series
            (strings), rows grouped by (scenario_id, track_id), each track in time order.
            The string and extra columns are put in that order only when first asked for
            (``checked[name]``); :meth:`per_track` reads them without reordering them all.
        index: where tracks and valid segments lie.
        names: every column, in the table's order (the contract's checked columns first).
        raw: the columns not yet in track order, as in the input (None: the input
            column of that name in ``table``, read when first asked for).
        order: input row of each row in track order (None: the input was in that order).
        table: the input's columns by name (or the input table, its index reset), which
            hold the columns not read yet.
    """

    columns: dict[str, np.ndarray | pd.Series]
    index: TrackIndex
    names: tuple[str, ...] = ()
    raw: dict[str, np.ndarray | pd.Series | None] = field(default_factory=dict)
    order: np.ndarray | None = None
    table: pd.DataFrame | dict | None = None

    def __getitem__(self, name: str) -> np.ndarray | pd.Series:
        if name not in self.columns and name in self.raw:
            self.columns[name] = _take(self._raw(name), self.order)
        return self.columns[name]

    def _raw(self, name: str) -> np.ndarray | pd.Series:
        if self.raw[name] is None:
            self.raw[name] = self.table[name]
        return self.raw[name]

    def __contains__(self, name: object) -> bool:
        return name in self.columns or name in self.raw

    def frame(self) -> pd.DataFrame:
        """The columns as a DataFrame (contract columns first)."""
        import pandas as pd

        names = self.names or tuple(self.columns)
        ordered = [c for c in (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS) if c in names]
        ordered += [c for c in names if c not in ordered]
        return pd.DataFrame({c: _values(self[c]) for c in ordered})

    def per_track(self, names: list[str] | tuple[str, ...]) -> pd.DataFrame:
        """One row per track: the given columns at each track's first row."""
        import pandas as pd

        return pd.DataFrame(self.per_track_arrays(names))

    def per_track_arrays(self, names: list[str] | tuple[str, ...]) -> dict:
        """:meth:`per_track` as column name -> (n_tracks,) numpy or pandas extension array
        (no frame: a small table's columns are then taken without pandas' fixed costs)."""
        rows = self.index.track_start[:-1]
        out = {}
        for c in names:  # as arrays: a frame of arrays needs no index alignment
            if c in self.columns:
                out[c] = _take_array(self.columns[c], rows)
            elif c in self.raw:
                out[c] = _take_array(self._raw(c),
                                     rows if self.order is None else self.order[rows])
        return out


def _values(col: np.ndarray | pd.Series):
    import pandas as pd

    return col.reset_index(drop=True) if isinstance(col, pd.Series) else col


def _take(col: np.ndarray | pd.Series, rows: np.ndarray | None):
    import pandas as pd

    if rows is None:
        return col
    if isinstance(col, pd.Series):
        return col.take(rows).reset_index(drop=True)
    return col[rows]


def _take_array(col: np.ndarray | pd.Series, rows: np.ndarray):
    """The values of ``col`` at ``rows`` as an array of its type (:func:`_take` without
    the Series)."""
    import pandas as pd

    return col.array.take(rows) if isinstance(col, pd.Series) else col[rows]


def _track_order(scenario: pd.Series, track: pd.Series) -> tuple[np.ndarray | None, np.ndarray]:
    """Order that groups rows by (scenario_id, track_id), stable within a track.

    Returns:
        (order, new_track): ``order`` is None when the rows are grouped and sorted already
        (the common case, detected without factorising every row); ``new_track`` is a
        (n_rows,) bool mask of the first row of each track in the grouped order.
    """
    import numpy as np
    import pandas as pd

    n = len(scenario)
    # a small table's (an episode's) string ids as codes once: comparing codes costs less
    # than comparing strings, and the sort below reuses them (a large table's runs are
    # compared as strings: encoding every row would cost more)
    small = n <= _ENCODE_ROWS
    sc_encoded = _arrow_codes(scenario) if small else None
    tr_encoded = _arrow_codes(track) if small else None

    def changes(col: pd.Series, encoded) -> np.ndarray:
        out = np.ones(n, dtype=bool)
        if n > 1 and encoded is not None:
            out[1:] = encoded[0][1:] != encoded[0][:-1]  # equal codes: equal strings
        elif n > 1 and isinstance(col.dtype, pd.CategoricalDtype):  # (its codes: no
            # pandas comparison; a missing value, -1, differs from every value, as there)
            codes = col.array.codes
            out[1:] = (codes[1:] != codes[:-1]) | (codes[1:] < 0)
        elif n > 1:
            values = col.array
            out[1:] = np.asarray(values[1:] != values[:-1], dtype=bool)
        return out

    new_scenario = changes(scenario, sc_encoded)
    change = new_scenario | changes(track, tr_encoded)
    starts = np.flatnonzero(change)
    if len(starts) <= n // 2:  # runs of rows (a track's): check the order of the runs
        # few runs (an episode's tracks) of strings: check them in Python (code point
        # order, as Arrow's sort), without pandas' fixed costs
        if len(starts) <= 1000 and _plain_strings(scenario, track):
            keys = list(zip(scenario.array.take(starts).tolist(),
                            track.array.take(starts).tolist(), strict=True))
            if all(a < b for a, b in itertools.pairwise(keys)):
                return None, change
        if sc_encoded is not None and tr_encoded is not None:
            # every value starts a run: the ranks of all values are those of the starts'
            sc_codes = _ranks(sc_encoded[1])[sc_encoded[0][starts]]
            tr_codes = _ranks(tr_encoded[1])[tr_encoded[0][starts]]
            n_values = len(tr_encoded[1])
        else:
            sc_codes, _ = pd.factorize(scenario.take(starts), sort=True)
            tr_codes, tr_uniques = pd.factorize(track.take(starts), sort=True)
            n_values = len(tr_uniques)
        block_key = sc_codes.astype(np.int64) * max(n_values, 1) + tr_codes
        if np.all(block_key[1:] > block_key[:-1]):
            return None, change
        runs = np.argsort(block_key, kind="stable")
        if np.all(block_key[runs][1:] > block_key[runs][:-1]):
            # each track one run, the runs out of order: sorting the runs (rows in input
            # order within each) is the stable sort of every row, without factorising them
            lengths = np.diff(np.append(starts, n))[runs]
            begins = np.cumsum(lengths) - lengths  # where each run starts in the new order
            order = np.repeat(starts[runs] - begins, lengths) + np.arange(n)
            new_track = np.zeros(n, dtype=bool)
            new_track[begins] = True
            return order, new_track
    # interleaved tracks (time-major rows, as simulators write them): sort every row (one
    # scenario, as an episode is, needs no codes of its own)
    one_scenario = not new_scenario[1:].any()
    sc_codes = np.zeros(n, np.int64) if one_scenario else _sorted_codes(scenario,
                                                                        sc_encoded)[0]
    tr_codes, n_tracks = _sorted_codes(track, tr_encoded)
    key = sc_codes.astype(np.int64) * max(n_tracks, 1) + tr_codes
    order = np.argsort(key, kind="stable")
    key = key[order]
    new_track = np.ones(n, dtype=bool)
    new_track[1:] = key[1:] != key[:-1]
    return order, new_track


def _plain_strings(*cols: pd.Series) -> bool:
    """Whether every column is of a string dtype (no categorical with an order of its own):
    then their values sort by code point, in Python as in pandas."""
    import pandas as pd

    return all(isinstance(c.dtype, pd.StringDtype) for c in cols)


_ENCODE_ROWS = 100_000
"""Up to this many rows, :func:`_track_order` compares string ids by their codes."""


def _arrow_codes(col: pd.Series):
    """(codes in order of first appearance, (n,); the distinct values, an Arrow array) of
    a column of Arrow-backed strings, or None for other columns."""
    if not (_plain_strings(col) and col.dtype.storage == "pyarrow"):
        return None
    values = col.array.__arrow_array__()
    values = values.combine_chunks() if values.num_chunks != 1 else values.chunk(0)
    encoded = values.dictionary_encode()
    return encoded.indices.to_numpy(zero_copy_only=False), encoded.dictionary


def _sorted_codes(col: pd.Series, encoded=None) -> tuple[np.ndarray, int]:
    """``pd.factorize(col, sort=True)``'s codes and number of values: for strings,
    factorised in order of appearance, the few values then ranked with the same sort
    (cheaper than sorting while factorising). ``encoded``: :func:`_arrow_codes` of the
    column, when known."""
    import numpy as np
    import pandas as pd

    if not _plain_strings(col):
        codes, uniques = pd.factorize(col, sort=True)
        return codes, len(uniques)
    encoded = encoded if encoded is not None else _arrow_codes(col)
    if encoded is not None:  # Arrow's own encoding: pandas' costs more
        codes, distinct = encoded
        return _ranks(distinct)[codes], len(distinct)
    codes, uniques = pd.factorize(col)
    order = np.asarray(uniques.argsort())
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    return rank[codes], len(order)


def _ranks(distinct) -> np.ndarray:
    """(k,) int64 rank of each of ``distinct`` (an Arrow string array) in Arrow's sort
    (code point order, as ``pd.factorize(sort=True)`` ranks strings)."""
    import numpy as np
    import pyarrow.compute as pc

    order = pc.array_sort_indices(distinct).to_numpy()
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    return rank


_PLAIN_FLOATS = ("t", "x", "y", "heading", "speed", "vx", "vy")
_PLAIN_FLAGS = ("valid", "is_ego", "crashed")
_PLAIN_TEXT = ("scenario_id", "track_id", "object_type")


def plainly_valid(table: pd.DataFrame | pa.Table, *, floats: tuple[str, ...] = ()) -> bool:
    """Whether a one-scenario table (a pandas DataFrame or an Arrow table) keeps the
    contract on sight of its arrays, without :func:`validate_and_index`'s pandas work: its
    columns named once each, ``t``, ``x``, ``y``, ``heading``, ``speed``, ``vx``, ``vy``
    (and ``floats``) float64, ``valid`` (and ``is_ego``, ``crashed`` where present) bool,
    ``scenario_id``, ``track_id`` (and ``object_type`` where present) Arrow-backed strings,
    none missing; one scenario, each track's rows together and of one length; nothing
    infinite, no NaN time, no NaN position, heading or speed on a valid row, speeds,
    positions and headings within the contract's bounds, every step a regular 0.1 s, the
    contract's object types.

    A table that passes keeps the contract (:func:`validate_and_index` accepts it); one that
    does not may keep it still (gaps of whole steps, tracks interleaved, other column
    types ...): :func:`validate_and_index` then decides and names what is wrong."""
    import numpy as np
    import pyarrow as pa
    import pyarrow.compute as pc

    if isinstance(table, pa.Table):
        names = table.schema.names
        rows = table.num_rows
    else:
        names = [str(c) for c in table.columns]
        rows = len(table)
    present = set(names)
    if (not rows or len(present) != len(names)
            or not {*_PLAIN_FLOATS, *floats, "valid", "scenario_id", "track_id"} <= present):
        return False
    arrays: dict[str, np.ndarray] = {}
    text: dict[str, pa.ChunkedArray] = {}
    for name in (*_PLAIN_FLOATS, *floats, *_PLAIN_FLAGS, *_PLAIN_TEXT):
        if name not in present:
            continue
        kind = (np.float64 if name in _PLAIN_FLOATS or name in floats
                else np.bool_ if name in _PLAIN_FLAGS else str)
        if isinstance(table, pa.Table):
            column = table.column(name)
            expected = {np.float64: pa.float64(), np.bool_: pa.bool_(), str: pa.string()}
            if column.type != expected[kind] or column.null_count:
                return False
            if kind is str:
                text[name] = column
            else:
                arrays[name] = column.to_numpy()
            continue
        column = table[name]
        if kind is str:
            if not (_plain_strings(column) and column.dtype.storage == "pyarrow"):
                return False
            values = column.array.__arrow_array__()
            if values.null_count:
                return False
            text[name] = values if isinstance(values, pa.ChunkedArray) else (
                pa.chunked_array([values]))
        elif column.dtype != kind:
            return False
        else:
            arrays[name] = column.to_numpy()
    if pc.count_distinct(text["scenario_id"]).as_py() != 1:
        return False
    if "object_type" in text and not all(
            kind in OBJECT_TYPES for kind in pc.unique(text["object_type"]).to_pylist()):
        return False
    encoded = pc.dictionary_encode(text["track_id"]).combine_chunks()
    n = len(encoded.dictionary)
    if rows % n:
        return False
    steps = rows // n
    codes = encoded.indices.to_numpy()
    if not np.array_equal(codes, np.repeat(np.arange(n, dtype=codes.dtype), steps)):
        return False
    valid = arrays["valid"]
    with np.errstate(invalid="ignore"):
        for name in _PLAIN_FLOATS:
            if np.isinf(arrays[name]).any():
                return False
        if np.isnan(arrays["t"]).any():
            return False
        for name in ("x", "y", "heading", "speed"):
            if (np.isnan(arrays[name]) & valid).any():
                return False
        speed = arrays["speed"]
        if (valid & ((speed < 0) | (speed > MAX_SPEED))).any():
            return False
        if (valid & ((np.abs(arrays["x"]) > MAX_COORDINATE)
                     | (np.abs(arrays["y"]) > MAX_COORDINATE))).any():
            return False
        if (valid & (np.abs(arrays["heading"]) > _TWO_PI + 1e-6)).any():
            return False
        dt = np.diff(arrays["t"].reshape(n, steps), axis=1) / DT
        return bool((np.abs(dt - 1.0) <= DT_TOLERANCE).all())


def validate_and_index(table: pd.DataFrame, *, source: str = "trajectory table") -> CheckedTable:
    """:func:`validate_trajectories` without building a DataFrame: columns and index."""
    import numpy as np
    import pandas as pd

    if not isinstance(table, pd.DataFrame):
        raise TypeError(f"{source}: expected a pandas DataFrame, got {type(table).__name__}")
    if len(table) == 0:
        _fail("the table is empty; a trajectory table needs at least one row per step of "
              "each track.", source)
    table = table.reset_index(drop=True)
    _check_columns(table, source)
    # every column by name at once (each table[name] costs as much as the work on an
    # episode's column); a table with repeated names reads them one by one, as before
    by_name = dict(table.items()) if table.columns.is_unique else table
    cols, valid = _read_columns(table, by_name, source)
    _check_values(table, cols, valid, source)
    _read_flags(table, by_name, cols, source)
    # Group rows by track, keeping each track's rows in input order (never sorting by t).
    order, new_track = _track_order(cols["scenario_id"], cols["track_id"])
    dt, same = _check_time_order(table, cols["t"], order, new_track, source)
    gap = _check_time_steps(table, dt, same, order, source)

    cols["valid"] = valid
    names = (*cols, *(c for c in table.columns if c not in cols))
    # numbers and flags in track order now; strings and extra columns when asked for
    # (the input's other columns read only when asked for: each read of a column costs)
    raw = {c: cols.get(c) for c in names if not isinstance(cols.get(c), np.ndarray)}
    cols = {k: _take(v, order) for k, v in cols.items() if isinstance(v, np.ndarray)}
    index = _track_index(new_track, cols["valid"], gap)
    return CheckedTable(columns=cols, index=index, names=names, raw=raw, order=order,
                        table=by_name)


def _read_columns(table: pd.DataFrame, by_name: dict | pd.DataFrame,
                  source: str) -> tuple[dict, np.ndarray]:
    """The key columns as id strings, the numeric ones as float arrays (``speed`` from
    ``vx``, ``vy`` where absent) and ``valid`` (every row where the table has none);
    infinite values and NaN on valid rows refused."""
    import numpy as np

    cols: dict[str, np.ndarray | pd.Series] = {}
    for key in _KEYS:
        cols[key] = _as_id_strings(by_name[key], key, source)
    for col in _NUMERIC:
        if col in table.columns:
            cols[col] = _numeric(table, col, source, by_name)
    if "speed" not in table.columns:
        cols["speed"] = np.hypot(cols["vx"], cols["vy"])
    valid = (_bool_column(table, "valid", source, by_name) if "valid" in table.columns
        else None)

    # Infinite values are never data; NaN is only allowed on rows marked invalid.
    for col in _NUMERIC:
        if col not in cols:
            continue
        values = cols[col]
        inf = np.isinf(values)
        if inf.any():
            pos = int(np.flatnonzero(inf)[0])
            _fail(f"column {col!r} is infinite at {_where(table, pos)}. Replace it with a "
                  "finite value, or mark the row valid=False and set it to NaN.", source,
                  column=col, row=pos)
        nan = np.isnan(values)
        if col == "t":
            if nan.any():
                pos = int(np.flatnonzero(nan)[0])
                _fail(f"column 't' is NaN at {_where(table, pos)}; every row needs a time.",
                      source, column="t", row=pos)
        elif col in ("x", "y", "heading", "speed") and nan.any():
            bad = nan if valid is None else nan & valid
            if bad.any():
                pos = int(np.flatnonzero(bad)[0])
                _fail(f"column {col!r} is NaN at {_where(table, pos)}, a valid row. Mark the "
                      "row valid=False (a gap that splits the track) or drop it.", source,
                      column=col, row=pos)
    if valid is None:
        valid = np.ones(len(table), dtype=bool)

    return cols, valid


def _check_values(table: pd.DataFrame, cols: dict, valid: np.ndarray, source: str) -> None:
    """Refuse valid rows whose speed is negative or beyond :data:`MAX_SPEED`, whose
    position is beyond :data:`MAX_COORDINATE`, or whose heading looks like degrees."""
    import numpy as np

    speed = cols["speed"]
    neg = valid & (speed < 0)
    if neg.any():
        pos = int(np.flatnonzero(neg)[0])
        name = "speed" if "speed" in table.columns else "hypot(vx, vy)"
        _fail(f"{name} is negative ({float(speed[pos])!r} m/s) at {_where(table, pos)}; speed is a "
              "magnitude. Use abs(), or give vx, vy instead.", source, column="speed", row=pos)
    fast = valid & (speed > MAX_SPEED)
    if fast.any():
        pos = int(np.flatnonzero(fast)[0])
        name = "speed" if "speed" in table.columns else "hypot(vx, vy)"
        _fail(f"{name} is {float(speed[pos])!r} m/s at {_where(table, pos)}; no vehicle moves "
              f"faster than {MAX_SPEED:g} m/s. Check the units (m/s, not km/h or mm/s) or mark "
              "the row valid=False.", source, column="speed", row=pos)
    for col in ("x", "y"):
        far = valid & (np.abs(cols[col]) > MAX_COORDINATE)
        if far.any():
            pos = int(np.flatnonzero(far)[0])
            _fail(f"{col} is {float(cols[col][pos])!r} m at {_where(table, pos)}, beyond "
                  f"{MAX_COORDINATE:g} m from the origin: positions must be metres in a local "
                  "frame. Check the units (m, not mm), convert latitude/longitude to a local "
                  "metric frame, or mark the row valid=False.", source, column=col, row=pos)
    heading = cols["heading"]
    big = valid & (np.abs(heading) > _TWO_PI + 1e-6)
    if big.any():
        pos = int(np.flatnonzero(big)[0])
        _fail(f"heading {float(heading[pos])!r} at {_where(table, pos)} is beyond 2*pi: "
              "headings look like degrees. Convert with numpy.deg2rad (radians, "
              "counter-clockwise from +x); if they are unwrapped radians, wrap them to "
              "(-pi, pi].", source,
              column="heading", row=pos)



def _read_flags(table: pd.DataFrame, by_name: dict | pd.DataFrame, cols: dict,
                source: str) -> None:
    """Add ``object_type`` (checked, lower case), ``is_ego`` and ``crashed`` to ``cols``
    where the table has them."""
    import numpy as np

    if "object_type" in table.columns:
        otype = _contract_types(by_name["object_type"])
        if otype is None:  # other spellings: lower-cased, then checked row by row
            otype = table["object_type"].astype(str).str.lower()
            bad = ~otype.isin(OBJECT_TYPES).to_numpy()
            if bad.any():
                pos = int(np.flatnonzero(bad)[0])
                _fail(f"object_type {table['object_type'].iloc[pos]!r} at "
                      f"{_where(table, pos)} is not one of {', '.join(OBJECT_TYPES)}.",
                      source, column="object_type", row=pos)
        cols["object_type"] = otype
    if "is_ego" in table.columns:
        cols["is_ego"] = _bool_column(table, "is_ego", source, by_name)
    if "crashed" in table.columns:
        cols["crashed"] = _bool_column(table, "crashed", source, by_name)


def _check_time_order(table: pd.DataFrame, t_input: np.ndarray, order: np.ndarray | None,
                      new_track: np.ndarray, source: str) -> tuple[np.ndarray, np.ndarray]:
    """(rows - 1,) time steps [s] in track order and whether each joins two rows of one
    track; duplicate times and times going back within a track refused."""
    import numpy as np

    t = t_input if order is None else t_input[order]
    dt = np.diff(t)
    same = ~new_track[1:]
    back = same & (dt <= 0)
    if back.any():
        i = int(np.flatnonzero(back)[0])
        a, b = (i, i + 1) if order is None else (int(order[i]), int(order[i + 1]))
        track_rows = np.flatnonzero(np.cumsum(new_track) == np.cumsum(new_track)[i + 1])
        same_t = track_rows[(t[track_rows] == t[i + 1]) & (track_rows < i + 1)]
        if len(same_t):  # the same time appears earlier in the track: a duplicate
            a = int(same_t[0]) if order is None else int(order[same_t[0]])
            _fail(f"duplicate (scenario_id, track_id, t): {_where(table, b)} repeats row {a}. "
                  "Drop one of them.", source, column="t", row=b)
        if dt[i] == 0:
            _fail(f"duplicate (scenario_id, track_id, t): {_where(table, b)} repeats row {a}. "
                  "Drop one of them.", source, column="t", row=b)
        _fail(f"t is not increasing within a track: {_where(table, b)} goes back from "
              f"t={float(t[i])!r} at row {a}. Rows of one track must be in time order; "
              "tap-bench does not sort them silently: sort by t yourself if the order is only "
              "a storage accident.", source, column="t", row=b)
    return dt, same


def _check_time_steps(table: pd.DataFrame, dt: np.ndarray, same: np.ndarray,
                      order: np.ndarray | None, source: str) -> np.ndarray:
    """(rows - 1,) whether each step is a gap of whole missing steps; a table at another
    rate than 10 Hz, or an irregular step, refused."""
    import numpy as np

    steps = dt / DT
    whole = np.round(steps)
    regular = np.abs(steps - 1.0) <= DT_TOLERANCE
    gap = (whole >= 2) & (np.abs(steps - whole) <= DT_TOLERANCE) & (whole <= MAX_GAP_STEPS)
    irregular = same & ~regular & ~gap
    n_pairs = int(same.sum())
    if n_pairs and (irregular.any() or int((regular & same).sum()) < 0.5 * n_pairs):
        # Mostly non-0.1 s steps: the table is at another rate, not 10 Hz with gaps.
        same_dt = dt[same]
        median = float(np.median(same_dt))
        if abs(median / DT - 1.0) > DT_TOLERANCE:
            rate = 1.0 / median
            fix = ("tap_bench.tap() and tap-bench label resample input faster than 10 Hz on "
                   "entry (SPEC 4.7); tap_bench.resample_to_10hz(table) does it by hand"
                   if rate > HZ else
                   "input slower than 10 Hz is refused (SPEC 4.7): resampling it up would "
                   "invent the motion between samples. Record at 10 Hz or faster, or, if "
                   "linear interpolation between your samples is acceptable, resample it "
                   "with tap_bench.resample_to_10hz(table)")
            _fail(f"the table is sampled at {rate:.3g} Hz (median step {median:.4g} s); TAP "
                  f"works at 10 Hz: {fix} (linear interpolation of x, y, speed and unwrapped "
                  "heading).", source, column="t", rate_hz=rate)
    if irregular.any():
        i = int(np.flatnonzero(irregular)[0])
        a, b = (i, i + 1) if order is None else (int(order[i]), int(order[i + 1]))
        _fail(f"irregular time step of {dt[i]:.4g} s between row {a} and {_where(table, b)}; "
              "steps must be 0.1 s, or a whole number of steps where rows are missing. "
              "Resample the track with tap_bench.resample_to_10hz(table).", source,
              column="t", row=b)
    return gap


def _track_index(new_track: np.ndarray, valid: np.ndarray, gap: np.ndarray) -> TrackIndex:
    """The tracks and their valid segments of rows in track order: a segment starts at
    every valid row after an invalid row, a gap or the start of its track."""
    import numpy as np

    track_starts = np.flatnonzero(new_track)
    track = np.cumsum(new_track) - 1
    n_rows = len(new_track)
    # A new valid segment starts at every valid row that follows an invalid row, a gap or
    # the start of its track.
    v = valid
    starts_seg = v.copy()
    starts_seg[1:] &= new_track[1:] | ~v[:-1] | gap
    segment = np.cumsum(starts_seg) - 1
    segment[~v] = -1
    seg_start = np.flatnonzero(starts_seg)
    ends_seg = v.copy()
    ends_seg[:-1] &= new_track[1:] | ~v[1:] | gap
    seg_stop = np.flatnonzero(ends_seg) + 1
    index = TrackIndex(
        track=track.astype(np.int64),
        track_start=np.append(track_starts, n_rows).astype(np.int64),
        segment=segment.astype(np.int64),
        segment_start=seg_start.astype(np.int64),
        segment_stop=seg_stop.astype(np.int64),
        segment_track=track[seg_start].astype(np.int64),
    )
    return index

