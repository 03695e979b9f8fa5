"""A large Parquet file read with its strings encoded (tableio.read_table_encoded) and
labelled in parts (tap_in_parts): every table equal to tap() of the file as read_table
reads it, column for column and dtype for dtype, and the same errors (the command line
labels large files this way)."""

from __future__ import annotations

import tempfile
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st
from pandas.testing import assert_frame_equal

from tap_bench.errors import ResampledWarning, TapBenchError, TrajectoryTableError
from tap_bench.labelling import tap, tap_in_parts
from tap_bench.synthetic import random_trajectories
from tap_bench.tableio import EncodedTable, read_table, read_table_encoded

from .test_tap_in_parts import _assert_same, every_branch, note_branches, scenes, uncut_table

SETTINGS = settings(max_examples=6, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])
"""6 examples (each writes, reads and labels its table twice, about 1.1 CPU s): the suite's
fixed (derandomized) draw holds every branch of ``scenes`` and every ``interactions``, and
the explicit example (one table of every branch, ``every_branch``) the kinds of track id
and extra column it leaves out (hypothesis events; ``--hypothesis-show-statistics``)."""


def _write(table: pd.DataFrame, folder: Path, how: str = "pandas") -> Path:
    path = folder / "table.parquet"
    if how == "pandas":
        table.to_parquet(path)
    else:  # pyarrow's own string type, no pandas metadata, small row groups
        arrow = pa.Table.from_pandas(table, preserve_index=False)
        arrow = arrow.cast(pa.schema([(f.name, pa.string() if pa.types.is_large_string(f.type)
                                       else f.type) for f in arrow.schema]))
        pq.write_table(arrow.replace_schema_metadata(None), path, row_group_size=97)
    return path


def _labelled_alike(path: Path, part_rows: int, interactions=None) -> EncodedTable:
    encoded = read_table_encoded(path, 0)
    assert isinstance(encoded, EncodedTable)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        whole = tap(read_table(path), interactions=interactions)
    _assert_same(tap_in_parts(encoded, part_rows=part_rows, interactions=interactions), whole)
    return encoded


@SETTINGS
@given(table=scenes(), part_rows=st.integers(1, 400),
       interactions=st.sampled_from([None, "ego", "all"]),
       tracks=st.sampled_from(["str", "non-ascii", "int", "categorical"]),
       extra=st.sampled_from(["none", "source", "source with gaps", "env"]),
       how=st.sampled_from(["pandas", "arrow"]))
@example(table=every_branch(), part_rows=40, interactions="all", tracks="non-ascii",
         extra="env", how="arrow")
def test_an_encoded_file_gives_the_tables_of_one_call(table, part_rows, interactions, tracks,
                                                      extra, how):
    note_branches(table, part_rows, interactions)
    event(f"track ids {tracks}")
    event(f"extra column {extra}")
    if tracks == "non-ascii":  # code point order: 'B' < 'b' < 'é' < 'ü'
        prefixes = np.array(["ü", "B", "b", "é", "1"], dtype=object)
        codes = pd.factorize(table["track_id"])[0]
        table["track_id"] = prefixes[codes % 5] + table["track_id"].astype(str)
    elif tracks == "int":
        table["track_id"] = pd.factorize(table["track_id"])[0] * 7 % 11
    elif tracks == "categorical":
        table["track_id"] = table["track_id"].astype("category")
    if extra.startswith("source"):
        table["source"] = np.where(np.arange(len(table)) % 3 == 0, "womd", "sim")
        table["source"] = table.groupby("track_id", observed=True)["source"].transform("first")
        if extra == "source with gaps":
            table["source"] = table["source"].where(table["track_id"] != table["track_id"].iloc[0])
    elif extra == "env":
        table["env"] = "highway"
        table["object_type"] = np.where(table["is_ego"], "vehicle", "cyclist")
    if how == "arrow" and tracks == "categorical":
        how = "pandas"
    event(f"written by {how}")
    with tempfile.TemporaryDirectory() as folder:
        _labelled_alike(_write(table, Path(folder), how), part_rows, interactions)


def test_the_codes_rank_the_strings_and_decode_to_them(tmp_path):
    table = random_trajectories(30, 40, seed=7, scenarios=5)
    table["track_id"] = np.where(np.arange(len(table)) % 2 == 0, "é", "E") + \
        table["track_id"].astype(str)
    table["track_id"] = table.groupby("track_id")["track_id"].transform("first")
    path = _write(table, tmp_path)
    encoded = read_table_encoded(path, 0)
    frame = read_table(path)
    assert_frame_equal(encoded.frame(), frame, check_exact=True)
    for name in ("scenario_id", "track_id", "object_type", "source"):
        values = encoded.values[name].to_pylist()
        assert values == sorted(set(frame[name]))  # Python sorts by code point too
        codes = encoded.codes[name]
        assert np.array_equal(np.asarray(values, dtype=object)[codes], frame[name].to_numpy())
        decoded = pd.Series(encoded.decoded(name, codes), name=name)
        assert_frame_equal(decoded.to_frame(), frame[[name]], check_exact=True)
        part = encoded.part(10, 50)
        assert list(part.columns) == list(frame.columns)
        assert part[name].astype(str).tolist() == frame[name].iloc[10:50].tolist()
        assert isinstance(part[name].dtype, pd.CategoricalDtype)


def test_the_label_table_is_cut_in_parts(tmp_path):
    table = random_trajectories(60, 40, seed=1, scenarios=12)
    encoded = read_table_encoded(_write(table, tmp_path), 0)
    parts = tap_in_parts(encoded, part_rows=200)
    assert len(parts.parts) > 1
    _assert_same(parts, tap(table))


@pytest.mark.parametrize("case", ["small", "unsorted", "split", "categorical", "int", "csv"])
def test_files_that_are_not_cut_are_read_as_read_table_reads_them(tmp_path, case):
    table = uncut_table(case)
    min_rows = len(table) if case == "small" else 0
    path = _write(table, tmp_path)
    if case == "csv":
        path = tmp_path / "table.csv"
        table.to_csv(path, index=False)
    encoded = read_table_encoded(path, min_rows)
    if case in ("unsorted", "split"):  # encoded, but labelled whole
        assert isinstance(encoded, EncodedTable)
        parts = tap_in_parts(encoded, part_rows=100)
        assert len(parts.parts) == 1
        _assert_same(parts, tap(read_table(path)))
    else:
        assert_frame_equal(encoded, read_table(path), check_exact=True)


def _message(call) -> str:
    with pytest.raises(TrajectoryTableError) as err:
        call()
    return str(err.value)


@pytest.mark.parametrize("fault", ["nan", "speed", "duplicate", "back", "type", "no track",
                                   "no type"])
def test_errors_are_those_of_the_file_as_read(tmp_path, fault):
    """A fault in a later part is reported as tap() of read_table's frame reports it."""
    table = random_trajectories(40, 40, seed=3, scenarios=8)
    table["object_type"] = "vehicle"
    row = len(table) - 40
    if fault == "nan":
        table.loc[row, "x"] = np.nan
    elif fault == "speed":
        table.loc[row, "speed"] = -1.0
    elif fault == "duplicate":
        table = pd.concat([table.iloc[:row + 1], table.iloc[[row]], table.iloc[row + 1:]],
                          ignore_index=True)
    elif fault == "back":  # (within the last track)
        table.loc[row + 5, "t"] -= 0.2
    elif fault == "type":
        table.loc[row, "object_type"] = "truck"
    elif fault == "no track":
        table["track_id"] = table["track_id"].where(table.index != row)
    else:
        table["object_type"] = table["object_type"].where(table.index != row)
    path = _write(table, tmp_path)
    encoded = read_table_encoded(path, 0)
    assert isinstance(encoded, EncodedTable)
    assert _message(lambda: tap_in_parts(encoded, part_rows=100)) == \
        _message(lambda: tap(read_table(path)))


def test_a_file_faster_than_10_hz_is_resampled_whole(tmp_path):
    table = random_trajectories(30, 40, seed=4, scenarios=6)
    table["t"] = table["t"] / 2  # 20 Hz
    path = _write(table, tmp_path)
    with pytest.warns(ResampledWarning) as whole_warned:
        whole = tap(read_table(path))
    with pytest.warns(ResampledWarning) as parts_warned:
        parts = tap_in_parts(read_table_encoded(path, 0), part_rows=100)
    assert [str(w.message) for w in parts_warned] == [str(w.message) for w in whole_warned]
    _assert_same(parts, whole)


@pytest.mark.parametrize("types", [["vehicle", "cyclist"], ["Vehicle", "cyclist"],
                                   ["vehicle", None]])
def test_categorical_object_types_label_as_their_strings(types):
    """tap() of a table whose object_type is a categorical: the tables of its strings (a
    categorical of the contract's words is taken as strings without lower-casing a row)."""
    table = random_trajectories(20, 40, seed=8, scenarios=3)
    kinds = np.asarray(types, dtype=object)[pd.factorize(table["track_id"])[0] % 2]
    table["object_type"] = pd.array(kinds, dtype="str")
    categorical = table.assign(object_type=table["object_type"].astype("category"))
    if types[1] is None:
        assert _message(lambda: tap(categorical)) == _message(lambda: tap(table))
        return
    whole = tap(table, interactions="all")
    _assert_same(tap_in_parts(categorical, interactions="all"), whole)


@pytest.mark.parametrize("encoded", [False, True])
def test_parts_without_per_step_tables_give_the_labels_and_glitches(tmp_path, encoded):
    """per_step=False (the command line without --segments and --steps): the label tables,
    glitches and segment lists of one call; the two tables that read the per-step times
    and rows raise instead of giving wrong ones."""
    table = random_trajectories(60, 40, seed=9, scenarios=12)
    table.loc[table.groupby("track_id").cumcount() == 7, "valid"] = False
    table["valid"] = table["valid"].fillna(True).astype(bool)
    path = _write(table, tmp_path)
    source = read_table_encoded(path, 0) if encoded else read_table(path)
    whole = tap(read_table(path))
    parts = tap_in_parts(source, part_rows=200, per_step=False)
    assert len(parts.parts) > 1
    for level in ("trace", "trend", "maneuver", "action", "all"):
        assert_frame_equal(parts.labels(level), whole.labels(level), check_exact=True)
    assert_frame_equal(parts.glitches(), whole.glitches(), check_exact=True)
    assert_frame_equal(parts.segments_info, whole.segments_info, check_exact=True)
    assert_frame_equal(parts.short_segments, whole.short_segments, check_exact=True)
    for table_of in (lambda: parts.segments("all"), parts.steps):
        with pytest.raises(TapBenchError, match="per_step=True"):
            table_of()


@pytest.mark.parametrize("index", ["strings", "named strings", "scenario_id",
                                   "scenario_id and track_id", "object_type", "filtered"])
def test_a_file_with_its_index_stored_is_read_as_read_table_reads_it(tmp_path, index):
    """A frame written with its index (pandas stores it as the last columns and makes them
    the index again): a string index was looked up among the frame's columns and the
    reading raised KeyError, for any size of file; an index of the id columns must give
    read_table's error naming the missing column (review5)."""
    table = random_trajectories(30, 40, seed=5, scenarios=6)
    if index == "strings":
        table.index = [f"r{i}" for i in range(len(table))]
    elif index == "named strings":
        table.index = pd.Index([f"r{i}" for i in range(len(table))], name="row")
    elif index == "scenario_id":
        table = table.set_index("scenario_id")
    elif index == "scenario_id and track_id":
        table = table.set_index(["scenario_id", "track_id"])
    elif index == "object_type":
        table = table.set_index("object_type")
    else:
        table = table[table.index % 7 != 3]
    path = tmp_path / "table.parquet"
    table.to_parquet(path)
    for min_rows in (0, len(table)):
        if index.startswith("scenario_id"):
            assert _message(lambda m=min_rows: tap_in_parts(read_table_encoded(path, m),
                                                            part_rows=100)) \
                == _message(lambda: tap(read_table(path)))
            continue
        encoded = read_table_encoded(path, min_rows)
        if min_rows:
            assert_frame_equal(encoded, read_table(path), check_exact=True)
            continue
        assert isinstance(encoded, EncodedTable)
        assert set(encoded.codes) <= set(read_table(path).columns)  # not the index
        parts = tap_in_parts(encoded, part_rows=100)
        assert len(parts.parts) > 1
        _assert_same(parts, tap(read_table(path)))
