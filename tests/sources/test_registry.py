"""The reader registry: a new format is one module plus one registry entry; duplicates are
refused; an ingest with a worker that dies on one file keeps every other file."""

from __future__ import annotations

import importlib
import sys
import textwrap

import pytest

import tap_bench
from tap_bench.errors import ParameterError, TapBenchError
from tap_bench.sources import Reader, ingest_womd, read_womd, reader_names, register_reader
from tap_bench.sources.registry import READERS

PLUGIN = '''
import os
import pandas as pd
import pyarrow as pa

from tap_bench.trajectories import HZ

def read_one_csv(path, object_types):
    """One scenario per CSV file: columns track_id, t, x, y, heading, speed."""
    table = pd.read_csv(path, dtype={"track_id": str})
    if "die" in os.path.basename(path):
        os._exit(7)  # a reader that kills its worker process
    table.insert(0, "scenario_id", os.path.basename(path).split(".")[0])
    table["valid"] = True
    table["object_type"] = "vehicle"
    table["source"] = "csv"
    return pa.Table.from_pandas(table, preserve_index=False)
'''


@pytest.fixture
def csv_reader(tmp_path, monkeypatch):
    (tmp_path / "my_csv_reader.py").write_text(textwrap.dedent(PLUGIN))
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("my_csv_reader")
    reader = register_reader(Reader("one-csv", "file", module.read_one_csv,
                                    suffixes=(".scn.csv",), description="test format"))
    yield reader
    if "one-csv" in READERS:
        READERS.unregister("one-csv")
    sys.modules.pop("my_csv_reader", None)


def _write(tmp_path, name: str) -> None:
    t = [i / 10 for i in range(20)]
    lines = ["track_id,t,x,y,heading,speed"] + [f"7,{x},{x * 10},0,0,10" for x in t]
    (tmp_path / f"{name}.scn.csv").write_text("\n".join(lines) + "\n")


def test_a_registered_format_is_sniffed_by_its_suffix_and_read(csv_reader, tmp_path):
    assert "one-csv" in reader_names()
    _write(tmp_path, "a")
    table = read_womd(tmp_path / "a.scn.csv")
    assert set(table["scenario_id"]) == {"a"} and len(table) == 20
    labels = tap_bench.label(table, level="maneuver")
    assert labels["sdl"].iloc[0] == "Straight | Maintain Speed"


def test_duplicates_and_bad_readers_are_refused(csv_reader):
    with pytest.raises(TapBenchError, match="already registered"):
        register_reader(csv_reader)
    with pytest.raises(ParameterError, match="framing"):
        Reader("x", "zip", print)


def test_a_worker_that_dies_on_one_file_costs_only_that_file(csv_reader, tmp_path):
    for name in ("a", "die", "b"):
        _write(tmp_path, name)
    out = tmp_path / "out.parquet"
    report = ingest_womd(sorted(tmp_path.glob("*.scn.csv")), out, workers=2,
                         on_error="skip")
    table = tap_bench.read_table(out)
    assert set(table["scenario_id"]) == {"a", "b"}
    assert len(report.skipped) == 1 and "die.scn.csv" in report.skipped[0]["path"]
    assert "died" in report.skipped[0]["problem"]
    with pytest.raises(tap_bench.WomdRecordError, match="died"):
        ingest_womd(sorted(tmp_path.glob("*.scn.csv")), tmp_path / "o2.parquet", workers=2)
    assert not (tmp_path / "o2.parquet").exists()
