"""Ingest: bad records (stop or skip, with their report), atomic output, workers, the CLI."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from tap_bench.cli import main
from tap_bench.errors import FileFormatError, UnknownNameError, WomdRecordError
from tap_bench.sources.ingest import IngestReport, ingest_womd, iter_womd, read_womd
from tap_bench.womd import proto
from tap_bench.womd.tfrecord import TFRecordWriter, iter_records
from tap_bench.womd.writer import encode_scenarios, write_womd


def many_scenarios(table, n):
    """``n`` copies of a table's first scenario, named s0 .. s{n-1}."""
    first = table[table["scenario_id"] == "s1"]
    return pd.concat([first.assign(scenario_id=f"s{i}") for i in range(n)],
                     ignore_index=True)


def shard(path, records):
    with TFRecordWriter(path) as writer:
        for record in records:
            writer.write(record)
    return path


def scenario_records(table):
    return [record for _, record in encode_scenarios(table)]


def record_with_unknown_type() -> bytes:
    state = proto.ObjectState(center_x=1.0, valid=True).SerializeToString()
    view = proto.ScenarioView(scenario_id="odd", timestamps_seconds=[0.0, 0.1])
    view.tracks.add(id=3, object_type=7, states=[state, state])
    return view.SerializeToString()


@pytest.fixture
def shard_with_bad_records(tmp_path, two_cars_and_a_walker):
    """Five records: scenarios s0, s1, then bytes that are no Scenario, then a track of
    object type 7, then s4; the second and third bad ones are records 2 and 3."""
    good = scenario_records(many_scenarios(two_cars_and_a_walker, 5))
    records = [good[0], good[1], b"\xff\xfe definitely not protobuf", record_with_unknown_type(),
               good[4]]
    return shard(tmp_path / "mixed.tfrecord", records), records


def test_default_stops_at_the_first_bad_record_and_writes_nothing(tmp_path,
                                                                  shard_with_bad_records):
    path, records = shard_with_bad_records
    out = tmp_path / "out" / "table.parquet"
    with pytest.raises(WomdRecordError) as info:
        ingest_womd(path, out)
    err = info.value
    assert (err.record, err.offset) == (2, 16 * 2 + len(records[0]) + len(records[1]))
    assert "not a serialized WOMD Scenario" in str(err) and str(path) in str(err)
    assert list((tmp_path / "out").iterdir()) == []


def test_skip_lists_every_skipped_record_in_the_report(tmp_path, shard_with_bad_records):
    path, _ = shard_with_bad_records
    out = tmp_path / "table.parquet"
    lines = []
    report = ingest_womd(path, out, on_error="skip", log=lines.append)
    assert report.scenarios == 3
    assert [s["record"] for s in report.skipped] == [2, 3]
    assert "unknown object type 7" in report.skipped[1]["problem"]
    assert len(lines) == 2 and "record 3" in lines[1]
    saved = json.loads((tmp_path / "table.parquet.report.json").read_text())
    assert [s["record"] for s in saved["skipped"]] == [2, 3]
    assert sorted(pd.read_parquet(out)["scenario_id"].unique()) == ["s0", "s1", "s4"]


def test_skip_goes_on_after_a_corrupt_crc(tmp_path, two_cars_and_a_walker):
    records = scenario_records(many_scenarios(two_cars_and_a_walker, 3))
    path = shard(tmp_path / "crc.tfrecord", records)
    raw = bytearray(path.read_bytes())
    raw[16 + len(records[0]) + 12 + 40] ^= 0x01  # one bit of record 1's data
    path.write_bytes(bytes(raw))
    report = IngestReport()
    tables = list(iter_womd(path, on_error="skip", report=report))
    assert [t["scenario_id"].iloc[0] for t in tables] == ["s0", "s2"]
    assert report.skipped[0]["record"] == 1 and "CRC" in report.skipped[0]["problem"]


def test_interrupted_ingest_leaves_no_output(tmp_path, two_cars_and_a_walker, monkeypatch):
    path = write_womd(many_scenarios(two_cars_and_a_walker, 4), tmp_path / "in.tfrecord")
    import tap_bench.sources.builtin as builtin

    calls = []
    real = builtin.decode_scenario

    def interrupted(record, **kwargs):
        calls.append(record.index)
        if record.index == 2:
            raise KeyboardInterrupt
        return real(record, **kwargs)

    monkeypatch.setattr(builtin, "decode_scenario", interrupted)
    out_dir = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        ingest_womd(path, out_dir / "t.parquet", batch_bytes=1)
    assert calls == [0, 1, 2]
    assert list(out_dir.iterdir()) == []


def test_two_workers_give_the_same_table_as_one(tmp_path, two_cars_and_a_walker):
    for k in range(3):
        table = many_scenarios(two_cars_and_a_walker, 4).assign(
            scenario_id=lambda d, k=k: d["scenario_id"] + f"-{k}")
        write_womd(table, tmp_path / f"shard-{k}.tfrecord")
    one = ingest_womd(tmp_path / "shard-*.tfrecord", tmp_path / "one.parquet")
    two = ingest_womd(tmp_path / "shard-*.tfrecord", tmp_path / "two.parquet", workers=2,
                      batch_bytes=1)
    assert one.scenarios == two.scenarios == 12
    pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "one.parquet"),
                                  pd.read_parquet(tmp_path / "two.parquet"))


def test_iter_womd_yields_one_table_per_scenario(tmp_path, two_cars_and_a_walker):
    path = write_womd(two_cars_and_a_walker, tmp_path / "f.tfrecord")
    tables = list(iter_womd(path, object_types=["vehicle"]))
    assert [t["scenario_id"].unique().tolist() for t in tables] == [["s1"], ["s2"]]
    assert set(tables[0]["object_type"]) == {"vehicle"}


def test_reading_a_tf_example_file_as_scenarios_says_what_to_do(womd_dir):
    with pytest.raises(WomdRecordError, match="format='tf_example'"):
        read_womd(womd_dir / "motion_data_one_example.tfrecord", format="scenario")


def test_argument_errors_name_the_value_and_the_choices(tmp_path):
    with pytest.raises(UnknownNameError, match="vehicle"):
        read_womd(tmp_path, object_types=["vehicel"])
    with pytest.raises(FileFormatError, match="no file matches"):
        read_womd(tmp_path / "*.tfrecord")
    with pytest.raises(UnknownNameError, match="skip"):
        read_womd(tmp_path, on_error="ignore")


def test_malicious_pickle_is_refused_without_running(tmp_path):
    import pickle

    marker = tmp_path / "ran"

    class Payload:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    path = tmp_path / "sd_evil.pkl"
    path.write_bytes(pickle.dumps({"tracks": {}, "metadata": {"ts": Payload()}}))
    with pytest.raises(WomdRecordError, match="refused to load"):
        read_womd(path)
    assert not marker.exists()


# --- the command line ------------------------------------------------------------------

def test_cli_ingest_then_label(tmp_path, two_cars_and_a_walker, capsys):
    src = write_womd(two_cars_and_a_walker, tmp_path / "in.tfrecord")
    out = tmp_path / "womd.parquet"
    code = main(["ingest", "womd", str(tmp_path / "*.tfrecord"), "-o", str(out),
                 "--object-types", "vehicle", "--no-progress"])
    assert code == 0
    table = pd.read_parquet(out)
    assert set(table["object_type"]) == {"vehicle"}
    assert "wrote" in capsys.readouterr().out
    assert src.exists()
    labels = tmp_path / "labels.parquet"
    assert main(["label", str(out), "-o", str(labels), "--level", "all"]) == 0
    got = pd.read_parquet(labels)
    ego = got[(got["track_id"] == "100") & (got["level"] == "action")]
    assert ego["lateral"].tolist() == ["Straight"]
    assert ego["longitudinal"].tolist() == ["Maintain Slow Speed"]  # 10 m/s <= v_slow 10.214


def test_cli_reports_a_bad_file_and_exits_2(tmp_path, shard_with_bad_records, capsys):
    path, _ = shard_with_bad_records
    code = main(["ingest", "womd", str(path), "-o", str(tmp_path / "o.parquet"),
                 "--no-progress"])
    assert code == 2
    err = capsys.readouterr().err
    assert f"{path}: record 2 at byte" in err
    assert not (tmp_path / "o.parquet").exists()


def test_cli_skip_prints_every_skipped_record(tmp_path, shard_with_bad_records, capsys):
    path, _ = shard_with_bad_records
    code = main(["ingest", "womd", str(path), "-o", str(tmp_path / "o.parquet"),
                 "--on-error", "skip", "--workers", "2", "--no-progress"])
    assert code == 0
    err = capsys.readouterr().err
    assert "record 2 at byte" in err and "record 3 at byte" in err
    assert "skipped 2 record(s)" in err


def test_gzip_shards_are_ingested(tmp_path, two_cars_and_a_walker):
    write_womd(two_cars_and_a_walker, tmp_path / "a.tfrecord.gz", compress=True)
    table = read_womd(tmp_path / "a.tfrecord.gz")
    assert table["scenario_id"].unique().tolist() == ["s1", "s2"]
    assert np.isclose(table.loc[table["track_id"] == "8", "speed"], 1.2).all()


def test_records_keep_their_offsets_across_gzip(tmp_path, two_cars_and_a_walker):
    path = write_womd(two_cars_and_a_walker, tmp_path / "a.tfrecord.gz", compress=True)
    first, second = iter_records(path)
    assert second.offset == 16 + len(first.data)
