"""Hostile and damaged WOMD records: every decode failure is a record error naming file,
record and offset, ``on_error="skip"`` keeps every good record, a record over the size
limit is never held in memory, and files that are not records are named for what they are.

The fuzz cases are records with *valid* CRCs: the framing is intact and only the decoders
stand between a damaged payload and a traceback.
"""

from __future__ import annotations

import gzip
import json
import pickle
import resource
import struct
import zlib

import numpy as np
import pandas as pd
import pytest

from tap_bench.errors import WomdRecordError
from tap_bench.execution import LocalBackend
from tap_bench.sources.ingest import IngestReport, ingest_womd, read_womd
from tap_bench.sources.scenarionet import decode_scenarionet
from tap_bench.womd import proto
from tap_bench.womd.tf_example import Example
from tap_bench.womd.tfrecord import MAX_RECORD_BYTES, TFRecordWriter, iter_records
from tap_bench.womd.writer import encode_scenarios

STEPS = 12


def table_with_extras(scenario_id: str = "good") -> pd.DataFrame:
    """One scenario, two tracks with string ids (kept in tap-bench's Track field) and two
    extra columns (``lane`` per step, ``note`` constant): every field the writer adds."""
    t = np.round(np.arange(STEPS) * 0.1, 10)
    rows = []
    for track, y in (("car-a", 0.0), ("car-b", 3.5)):
        for i, tt in enumerate(t):
            rows.append({"scenario_id": scenario_id, "track_id": track, "t": tt,
                         "x": 10 * tt, "y": y, "heading": 0.0, "vx": 10.0, "vy": 0.0,
                         "speed": 10.0, "object_type": "vehicle", "valid": True,
                         "is_ego": track == "car-a", "lane": i // 4, "note": "hand-made"})
    return pd.DataFrame(rows)


def scenario_record(scenario_id: str = "good") -> bytes:
    return next(r for _, r in encode_scenarios(table_with_extras(scenario_id)))


def tf_example_record(scenario_id: bytes = b"tf-good", n_slots: int = 2) -> bytes:
    """A minimal motion tf.Example: ``n_slots`` agents, 1 past, 1 current, 1 future step."""
    ex = Example()
    feature = ex.features.feature
    feature["scenario/id"].bytes_list.value.append(scenario_id)
    feature["state/id"].float_list.value.extend(range(1, n_slots + 1))
    feature["state/type"].float_list.value.extend([1] * n_slots)
    for part, step in (("past", 0), ("current", 1), ("future", 2)):
        for name in ("x", "y", "z", "bbox_yaw", "velocity_x", "velocity_y"):
            feature[f"state/{part}/{name}"].float_list.value.extend([float(step)] * n_slots)
        for name, size in (("length", 4.5), ("width", 2.0), ("height", 1.6)):  # a car's box
            feature[f"state/{part}/{name}"].float_list.value.extend([size] * n_slots)
        feature[f"state/{part}/valid"].int64_list.value.extend([1] * n_slots)
        feature[f"state/{part}/timestamp_micros"].int64_list.value.extend(
            [step * 100_000] * n_slots)
    return ex.SerializeToString()


def scenarionet_doc(scenario_id: str = "sn-good") -> dict:
    n = 5
    state = {"position": np.zeros((n, 3)), "velocity": np.ones((n, 2)),
             "heading": np.zeros(n), "valid": np.ones(n, bool), "length": np.full(n, 4.5)}
    return {"id": scenario_id, "metadata": {"ts": np.arange(n) * 0.1, "scenario_id": scenario_id,
                                            "dataset": "waymo", "sdc_id": "1"},
            "tracks": {"1": {"type": "VEHICLE", "state": state}}}


def shard(path, records) -> str:
    with TFRecordWriter(path) as writer:
        for record in records:
            writer.write(record)
    return str(path)


def mutate(data: bytes, rng: np.random.Generator) -> bytes:
    """One random damage: flipped bits, a cut, inserted or deleted bytes, a spliced copy."""
    b = bytearray(data)
    kind = rng.integers(5)
    if kind == 0:
        for _ in range(rng.integers(1, 8)):
            i = rng.integers(len(b))
            b[i] ^= 1 << rng.integers(8)
    elif kind == 1:
        b = b[: rng.integers(len(b))]
    elif kind == 2:
        i = rng.integers(len(b))
        b[i:i] = rng.bytes(int(rng.integers(1, 16)))
    elif kind == 3:
        i = rng.integers(len(b))
        del b[i: i + int(rng.integers(1, 16))]
    else:
        i, j = sorted(rng.integers(len(b), size=2))
        b[i:i] = b[j: j + 32]
    return bytes(b)


# -- the decoders' own failures -----------------------------------------------------------
def _with_columns(text: str) -> bytes:
    scenario = proto.ScenarioView.FromString(scenario_record())
    scenario.tracks[0].tap_bench_columns = text
    return scenario.SerializeToString()


BAD_COLUMNS = {
    "not JSON": '{"lane": ',
    "a list": "[1, 2]",
    "a list for a value": '{"lane": [1, 2]}',
    "steps not a list": '{"lane": {"value": 1, "steps": 3}}',
    "short series": '{"lane": {"series": [1, 2]}}',
    "series not a list": '{"lane": {"series": "abc"}}',
    "mixed types": '{"lane": {"series": [1, "a", [2], 3, 4, 5, 6, 7, 8, 9, 10, 11]}}',
}


@pytest.mark.parametrize("case", sorted(BAD_COLUMNS))
def test_a_damaged_json_extension_field_is_a_record_error_and_skip_keeps_the_rest(tmp_path,
                                                                                   case):
    path = shard(tmp_path / "s.tfrecord", [scenario_record("first"), _with_columns(
        BAD_COLUMNS[case]), scenario_record("last")])
    with pytest.raises(WomdRecordError, match=r"record 1 at byte \d+: .*tap-bench columns"):
        read_womd(path)
    report = IngestReport()
    table = read_womd(path, on_error="skip", report=report)
    assert sorted(table["scenario_id"].unique()) == ["first", "last"]
    assert [s["record"] for s in report.skipped] == [1]
    assert report.skipped[0]["path"] == path and report.skipped[0]["offset"] > 0


def _scenarionet_cases() -> dict[str, dict]:
    cases = {}
    doc = scenarionet_doc()
    cases["tracks a list"] = {**doc, "tracks": [doc["tracks"]["1"]]}
    cases["metadata a list"] = {**doc, "metadata": [1, 2]}
    cases["a track a list"] = {**doc, "tracks": {"1": [1, 2]}}
    cases["state a list"] = {**doc, "tracks": {"1": {"type": "VEHICLE", "state": [1]}}}
    short = {k: v[:3] for k, v in doc["tracks"]["1"]["state"].items()}
    cases["short arrays"] = {**doc, "tracks": {"1": {"type": "VEHICLE", "state": short}}}
    text = {**doc["tracks"]["1"]["state"], "heading": ["north"] * 5}
    cases["text for numbers"] = {**doc, "tracks": {"1": {"type": "VEHICLE", "state": text}}}
    cases["text time stamps"] = {**doc, "metadata": {**doc["metadata"], "ts": ["a", "b"]}}
    cases["no time steps"] = {**doc, "metadata": {**doc["metadata"], "ts": []}}
    cases["2-d position of 1 column"] = {**doc, "tracks": {"1": {"type": "VEHICLE", "state": {
        **doc["tracks"]["1"]["state"], "position": np.zeros((5, 1))}}}}
    cases["bad difficulty"] = {**doc, "metadata": {**doc["metadata"],
                                                   "tracks_to_predict": {"1": {"difficulty":
                                                                               "hard"}}}}
    cases["empty id"] = {**doc, "metadata": {**doc["metadata"], "scenario_id": ""}}
    return cases


@pytest.mark.parametrize("case", sorted(_scenarionet_cases()))
def test_a_scenarionet_file_of_the_wrong_structure_is_a_record_error(tmp_path, case):
    doc = _scenarionet_cases()[case]
    with pytest.raises(WomdRecordError, match=r"bad\.pkl: record 0 at byte 0: "):
        decode_scenarionet(doc, path=str(tmp_path / "bad.pkl"))
    (tmp_path / "a.pkl").write_bytes(pickle.dumps(scenarionet_doc("sn-a")))
    (tmp_path / "bad.pkl").write_bytes(pickle.dumps(doc))
    (tmp_path / "c.pkl").write_bytes(pickle.dumps(scenarionet_doc("sn-c")))
    report = IngestReport()
    table = read_womd(tmp_path, on_error="skip", report=report)
    assert sorted(table["scenario_id"].unique()) == ["sn-a", "sn-c"]
    assert [s["path"].endswith("bad.pkl") for s in report.skipped] == [True]


def _tf_example_cases() -> dict[str, bytes]:
    def edit(fn) -> bytes:
        ex = Example.FromString(tf_example_record())
        fn(ex.features.feature)
        return ex.SerializeToString()

    return {
        "empty scenario/id list": edit(lambda f: f["scenario/id"].bytes_list.ClearField(
            "value")),
        "scenario/id not UTF-8": edit(lambda f: f["scenario/id"].bytes_list.value.__setitem__(
            0, b"\xff\xfe")),
        "scenario/id empty": edit(lambda f: f["scenario/id"].bytes_list.value.__setitem__(
            0, b"")),
        "scenario/id numbers": edit(lambda f: f["scenario/id"].int64_list.value.append(7)),
        "short state/type": edit(lambda f: f["state/type"].float_list.value.pop()),
        "short is_sdc": edit(lambda f: f["state/is_sdc"].int64_list.value.append(1)),
        "text state/id": edit(lambda f: f["state/id"].bytes_list.value.extend([b"a", b"b"])),
        "short difficulty": edit(lambda f: (
            f["state/tracks_to_predict"].int64_list.value.extend([1, 1]),
            f["state/difficulty_level"].int64_list.value.append(1))),
    }


@pytest.mark.parametrize("case", sorted(_tf_example_cases()))
def test_a_tf_example_with_wrong_sizes_or_text_is_a_record_error(tmp_path, case):
    path = shard(tmp_path / "e.tfrecord", [tf_example_record(b"tf-first"),
                                           _tf_example_cases()[case],
                                           tf_example_record(b"tf-last")])
    with pytest.raises(WomdRecordError, match=r"e\.tfrecord: record 1 at byte \d+: "):
        read_womd(path, format="tf_example")
    report = IngestReport()
    table = read_womd(path, format="tf_example", on_error="skip", report=report)
    assert sorted(table["scenario_id"].unique()) == ["tf-first", "tf-last"]
    assert [s["record"] for s in report.skipped] == [1]


FUZZ = {"scenario": scenario_record, "tf_example": tf_example_record,
        "scenarionet": lambda: pickle.dumps(scenarionet_doc())}


@pytest.mark.parametrize("fmt", sorted(FUZZ))
def test_fuzzed_records_with_valid_crcs_never_end_a_skip_ingest(tmp_path, fmt):
    """200 damaged copies of a valid record, each framed with valid CRCs: ``stop`` raises
    only record errors, ``skip`` lists the bad ones and keeps every good one."""
    rng = np.random.default_rng(13)
    good = FUZZ[fmt]()
    damaged = [mutate(good, rng) for _ in range(200)]
    if fmt == "scenarionet":  # a pickle is one file, one record
        for i, data in enumerate(damaged):
            (tmp_path / f"f{i:03d}.pkl").write_bytes(data)
        (tmp_path / "zz-good.pkl").write_bytes(pickle.dumps(scenarionet_doc("kept")))
        source, fmt_arg, expect = tmp_path, "auto", "kept"
    else:
        last = scenario_record("kept") if fmt == "scenario" else tf_example_record(b"kept")
        source = shard(tmp_path / "fuzz.tfrecord", [*damaged, last])
        fmt_arg, expect = fmt, "kept"
    for i in range(0, 200, 25):  # each damaged record alone, on stop: a record error or OK
        single = tmp_path / "single"
        single.mkdir(exist_ok=True)
        if fmt == "scenarionet":
            one = single / "one.pkl"
            one.write_bytes(damaged[i])
        else:
            one = shard(single / "one.tfrecord", [damaged[i]])
        try:
            read_womd(one, format=fmt_arg)
        except WomdRecordError as err:
            assert err.record == 0 and err.offset == 0 and str(one) in str(err)
    report = IngestReport()
    table = read_womd(source, format=fmt_arg, on_error="skip", report=report)
    assert expect in set(table["scenario_id"])
    assert report.skipped, "no damaged record was caught"
    for entry in report.skipped:
        assert {"path", "record", "offset", "problem"} <= set(entry) and entry["problem"]


def test_a_record_error_from_a_worker_process_names_the_record(tmp_path):
    path = shard(tmp_path / "w.tfrecord", [scenario_record("first"),
                                           _with_columns("[1]"), scenario_record("last")])
    out = tmp_path / "w.parquet"
    backend = LocalBackend(2)
    with backend.kept():  # both ingests on the same two worker processes
        report = ingest_womd(path, out, on_error="skip", backend=backend, batch_bytes=1)
        assert report.scenarios == 2 and [s["record"] for s in report.skipped] == [1]
        assert len(backend._kept[0]) == 2  # the records were read in worker processes
        with pytest.raises(WomdRecordError, match="record 1"):
            ingest_womd(path, tmp_path / "w2.parquet", backend=backend, batch_bytes=1)
    assert not (tmp_path / "w2.parquet").exists()


# -- ids ----------------------------------------------------------------------------------
def test_a_scenario_id_met_twice_is_a_record_error_not_a_merge(tmp_path):
    a = shard(tmp_path / "a.tfrecord", [scenario_record("same"), scenario_record("other")])
    b = shard(tmp_path / "b.tfrecord", [scenario_record("same")])
    with pytest.raises(WomdRecordError, match=r"b\.tfrecord: record 0 .*'same' was already "
                                              r"read from .*a\.tfrecord, record 0"):
        read_womd([a, b])
    report = IngestReport()
    table = read_womd([a, b], on_error="skip", report=report)
    assert len(table) == 2 * len(table_with_extras())  # 'same' once, 'other' once
    assert report.skipped[0]["path"] == b
    inside = shard(tmp_path / "c.tfrecord", [scenario_record("x"), scenario_record("x")])
    with pytest.raises(WomdRecordError, match=r"record 1 .*already read"):
        read_womd(inside)


def test_a_scenario_without_id_is_a_record_error(tmp_path):
    view = proto.ScenarioView.FromString(scenario_record())
    view.scenario_id = ""
    path = shard(tmp_path / "n.tfrecord", [view.SerializeToString()])
    with pytest.raises(WomdRecordError, match="no scenario_id"):
        read_womd(path)


# -- framing: sizes and what was found ----------------------------------------------------
def _header(length: int) -> bytes:
    from tap_bench.womd.checksum import masked_crc32c

    raw = struct.pack("<Q", length)
    return raw + struct.pack("<I", masked_crc32c(raw))


def test_a_gzip_bomb_announcing_2_gib_is_refused_in_bounded_memory(tmp_path):
    """A small GZIP file whose first record announces 2 GiB: refused by the size limit,
    skipped in chunks on ``skip``; the process's peak memory grows by far less than 2 GiB."""
    bomb = tmp_path / "bomb.tfrecord.gz"
    zeros = zlib.compressobj(9, zlib.DEFLATED, 31)
    with open(bomb, "wb") as f:
        f.write(zeros.compress(_header(2 << 30)))
        chunk = bytes(1 << 20)
        for _ in range(96):  # 96 MiB of zeros: about 100 kB compressed
            f.write(zeros.compress(chunk))
        f.write(zeros.flush())
    assert bomb.stat().st_size < 1 << 20
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # [KiB]
    with pytest.raises(WomdRecordError, match=r"announces 2147483648 bytes, more than the "
                                              r"limit of 67108864 bytes .*--max-record-mb"):
        list(iter_records(bomb))
    errors = []
    assert list(iter_records(bomb, on_error=errors.append)) == []
    assert "ends inside it" in errors[0].problem and not errors[0].resumable
    grown = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - peak
    assert grown < 256 * 1024, f"peak memory grew by {grown} KiB"


def test_the_record_size_limit_can_be_raised_and_skip_goes_on_after_a_long_record(tmp_path):
    big, small = bytes(3000), b"a small record"
    path = shard(tmp_path / "big.tfrecord", [big, small])
    errors = []
    kept = list(iter_records(path, on_error=errors.append, max_record_bytes=1000))
    assert [r.index for r in kept] == [1] and errors[0].resumable
    assert [len(r.data) for r in iter_records(path, max_record_bytes=4000)] == [3000, len(small)]
    assert MAX_RECORD_BYTES == 64 << 20
    with pytest.raises(ValueError, match="max_record_bytes"):
        list(iter_records(path, max_record_bytes=0))


def test_the_cli_option_raises_the_limit(tmp_path, cli):
    path = shard(tmp_path / "s.tfrecord", [scenario_record("a")])
    code, _, err = cli("ingest", "womd", path, "-o", tmp_path / "o.parquet",
                       "--max-record-mb", "0.0001")
    assert code == 2 and "--max-record-mb" in err and "Traceback" not in err
    assert not (tmp_path / "o.parquet").exists()
    code, _, _ = cli("ingest", "womd", path, "-o", tmp_path / "o.parquet",
                     "--max-record-mb", "1")
    assert code == 0


def test_a_huge_length_in_a_plain_file_says_truncated_not_gzip(tmp_path):
    path = tmp_path / "plain.tfrecord"
    path.write_bytes(_header(1 << 40) + b"abc")
    with pytest.raises(WomdRecordError) as info:
        list(iter_records(path, max_record_bytes=1 << 41))
    assert "plain file ends after 3" in str(info.value) and "GZIP" not in str(info.value)


@pytest.mark.parametrize("content, found", [
    (b"# A README\nwith text", "text starting with '# A README'"),
    (b"PAR1\x15\x04\x15\x10\x15\x14L\x15\x02", "a Parquet file"),
    (b"PK\x03\x04\x14\x00\x00\x00\x08\x00\x00\x00", "a ZIP archive"),
    (bytes(range(200, 212)), "binary data starting with c8 c9"),
])
def test_a_damaged_first_header_says_what_was_found(tmp_path, content, found):
    path = tmp_path / "x.tfrecord"
    path.write_bytes(content)
    with pytest.raises(WomdRecordError, match="not a TFRecord file; found " + found[:12]):
        list(iter_records(path))


# -- files ------------------------------------------------------------------------------
def test_a_folder_with_a_readme_and_an_empty_file_is_ingested_with_notes(tmp_path, cli):
    folder = tmp_path / "womd"
    folder.mkdir()
    (folder / "README.md").write_text("# my notes\n")
    (folder / "empty.tfrecord").write_bytes(b"")
    shard(folder / "a.tfrecord", [scenario_record("a")])
    gz = folder / "b.tfrecord.gz"
    gz.write_bytes(gzip.compress((tmp_path / "womd" / "a.tfrecord").read_bytes()))
    shard(folder / "c.tfrecord", [scenario_record("c")])
    code, _, err = cli("ingest", "womd", folder, "-o", tmp_path / "o.parquet",
                         "--on-error", "skip")
    assert code == 0, err
    assert "README.md: skipped, not a TFRecord" in err and "empty.tfrecord: skipped, empty" in err
    report = json.loads((tmp_path / "o.parquet.report.json").read_text())
    assert len(report["notes"]) == 2 and len(report["inputs"]) == 3
    assert report["scenarios"] == 2  # b.tfrecord.gz repeats 'a': listed, not merged
    assert "already read" in report["skipped"][0]["problem"]


def test_an_empty_tfrecord_named_alone_gets_a_note(tmp_path, cli):
    empty = tmp_path / "empty.tfrecord"
    empty.write_bytes(b"")
    code, _, err = cli("ingest", "womd", empty, "-o", tmp_path / "o.parquet")
    assert code == 0 and "empty.tfrecord: the file is empty (0 bytes)" in err
    with pytest.warns(UserWarning, match="empty"):
        assert read_womd(empty).empty


def test_a_file_name_with_brackets_is_found(tmp_path, cli):
    name = tmp_path / "my womd [1].tfrecord"
    shard(name, [scenario_record("bracket")])
    code, _, err = cli("ingest", "womd", name, "-o", tmp_path / "o.parquet")
    assert code == 0, err
    assert pd.read_parquet(tmp_path / "o.parquet")["scenario_id"].unique().tolist() == [
        "bracket"]


def test_tracks_sharing_an_empty_value_are_not_one_array_named_twice():
    """``()`` is one object in Python: two tracks that carry it share nothing to copy."""
    doc = scenarionet_doc("sn-empty")
    first = doc["tracks"]["1"]
    first["state"]["extra"] = ()
    second = {"type": "VEHICLE", "state": {k: (v.copy() if hasattr(v, "copy") else v)
                                           for k, v in first["state"].items()}}
    doc["tracks"]["2"] = second
    assert second["state"]["extra"] is first["state"]["extra"]
    table = decode_scenarionet(pickle.loads(pickle.dumps(doc)))
    assert sorted(set(table.column("track_id").to_pylist())) == ["1", "2"]
