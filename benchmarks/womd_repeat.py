"""Files of many WOMD scenes for scale tests: the sample and development scenes repeated
under new scenario ids.

Reads the real scenes at run time (``../shared/data/womd/`` and
``../shared/data/womd-dev/dev.tfrecord``, or the sources given) and writes ``N`` scenes to a
folder outside the project (``/tmp`` by default): each copy is a source scene whose
scenario id gets the suffix ``-r<copy>``, nothing else changed (a Scenario record is
rewritten at the wire level, only its field 5; a tf.Example gets a new ``scenario/id``; a
ScenarioNet pickle a new ``metadata.scenario_id`` and ``id``). Scenes go in source order,
copy after copy (copy 0 keeps the source's scenes, under new ids too), until ``N``; Scenario
records fill TFRecord files of at most ``--per-file`` scenes, tf.Example records files of
their own, pickles one file each (their format holds one scene).

Usage::

    python benchmarks/womd_repeat.py 245 -o /tmp/womd-245 [--per-file 49] [SOURCES ...]

Prints the files written, the scenes and the bytes.
"""

from __future__ import annotations

import argparse
import pickle
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SOURCES = (str(ROOT / ".." / "shared" / "data" / "womd"),
                   str(ROOT / ".." / "shared" / "data" / "womd-dev" / "dev.tfrecord"))
"""The sample scenes (four files) and the twelve development scenes."""

SCENARIO_ID_FIELD = 5
"""``Scenario.scenario_id``'s field number in WOMD's scenario.proto."""


def _varint(data: bytes, pos: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = data[pos]
        pos += 1
        value |= (byte & 0x7F) << shift
        if byte < 0x80:
            return value, pos
        shift += 7


def _encode_varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def with_scenario_id(record: bytes, scenario_id: str) -> bytes:
    """A serialised ``Scenario`` with field 5 (scenario_id) replaced by ``scenario_id``
    (put first when the record has none); every other field's bytes are kept as they are.

    Raises:
        ValueError: a wire type protobuf does not use (the record is not a protobuf).
    """
    new_field = (_encode_varint(SCENARIO_ID_FIELD << 3 | 2)
                 + _encode_varint(len(scenario_id.encode())) + scenario_id.encode())
    parts: list[bytes] = []
    pos, replaced = 0, False
    while pos < len(record):
        start = pos
        key, pos = _varint(record, pos)
        number, wire = key >> 3, key & 7
        if wire == 0:
            _, pos = _varint(record, pos)
        elif wire == 1:
            pos += 8
        elif wire == 2:
            length, pos = _varint(record, pos)
            pos += length
        elif wire == 5:
            pos += 4
        else:
            raise ValueError(f"wire type {wire} at byte {start}: not a protobuf record")
        if number == SCENARIO_ID_FIELD and wire == 2:
            if not replaced:
                parts.append(new_field)
                replaced = True
            continue
        parts.append(record[start:pos])
    return b"".join(parts) if replaced else new_field + b"".join(parts)


def _example_with_id(record: bytes, scenario_id: str) -> bytes:
    from tap_bench.womd.tf_example import Example

    example = Example.FromString(record)
    feature = example.features.feature["scenario/id"]
    del feature.bytes_list.value[:]
    feature.bytes_list.value.append(scenario_id.encode())
    return example.SerializeToString()


def _plain(value: object) -> object:
    """A ScenarioNet scenario as plain dicts, lists and numpy arrays (the restricted
    unpickler's array subclass would not load again)."""
    import numpy as np

    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(_plain(v) for v in value)
    if isinstance(value, np.ndarray):
        return np.array(value, dtype=value.dtype, subok=False)
    return value


def _sources(paths: Sequence[str]) -> list[tuple[str, str, object]]:
    """Every source scene as (format, scenario id, payload): the record's bytes, or the
    unpickled ScenarioNet dict."""
    import warnings

    from tap_bench.sim.womd_scene import scene_catalog
    from tap_bench.sources.scenarionet import load_scenarionet
    from tap_bench.womd.tfrecord import iter_records

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # READMEs beside the data
        refs = scene_catalog(paths)
    out = []
    for ref in refs:
        if ref.format == "scenarionet":
            scenario = load_scenarionet(ref.path)
            meta = scenario.get("metadata", {}) or {}
            out.append(("scenarionet", str(meta.get("scenario_id", scenario.get("id"))),
                        scenario))
            continue
        for record in iter_records(ref.path):
            if record.index == ref.record:
                if ref.format == "scenario":
                    from tap_bench.womd.proto import ScenarioView

                    sid = str(ScenarioView.FromString(record.data).scenario_id)
                else:
                    from tap_bench.womd.tf_example import Example

                    value = Example.FromString(record.data).features.feature["scenario/id"]
                    sid = value.bytes_list.value[0].decode()
                out.append((ref.format, sid, record.data))
                break
    return out


def repeated(sources: list[tuple[str, str, object]], n: int
             ) -> Iterator[tuple[str, str, object]]:
    """``n`` scenes: the sources in order, copy after copy, each under id
    ``<source id>-r<copy>``."""
    copy = 0
    made = 0
    while made < n:
        for fmt, sid, payload in sources:
            if made == n:
                return
            new_id = f"{sid}-r{copy}"
            if fmt == "scenario":
                yield fmt, new_id, with_scenario_id(payload, new_id)
            elif fmt == "tf_example":
                yield fmt, new_id, _example_with_id(payload, new_id)
            else:
                scenario = _plain(payload)
                scenario["metadata"] = {**scenario["metadata"], "scenario_id": new_id}
                scenario["id"] = new_id
                yield fmt, new_id, scenario
            made += 1
        copy += 1


def write_repeated(n: int, out: Path, *, per_file: int = 49,
                   sources: Sequence[str] = DEFAULT_SOURCES) -> list[Path]:
    """Write ``n`` scenes to folder ``out`` (created; must not hold files of a previous
    run); the files written, in scene order of their first scene."""
    from tap_bench.womd.tfrecord import TFRecordWriter

    out.mkdir(parents=True, exist_ok=True)
    if any(out.iterdir()):
        raise SystemExit(f"{out} is not empty: give a new folder.")
    src = _sources(sources)
    if not src:
        raise SystemExit(f"no scenes in {', '.join(sources)}")
    writers: dict[str, tuple[TFRecordWriter, int]] = {}
    counters = {"scenario": 0, "tf_example": 0, "scenarionet": 0}
    files: list[Path] = []
    try:
        for fmt, sid, payload in repeated(src, n):
            if fmt == "scenarionet":
                path = out / f"sd_{sid}.pkl"
                path.write_bytes(pickle.dumps(payload, protocol=4))
                files.append(path)
                continue
            writer, count = writers.get(fmt, (None, 0))
            if writer is None or count == per_file:
                if writer is not None:
                    writer.close()
                path = out / f"{fmt}-{counters[fmt]:05d}.tfrecord"
                counters[fmt] += 1
                writer, count = TFRecordWriter(path), 0
                files.append(path)
            writer.write(payload)
            writers[fmt] = (writer, count + 1)
    finally:
        for writer, _ in writers.values():
            writer.close()
    return files


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("n", type=int, help="scenes to write")
    parser.add_argument("-o", "--out", required=True, help="a new folder (under /tmp)")
    parser.add_argument("--per-file", type=int, default=49,
                        help="Scenario or tf.Example records per TFRecord file (default 49)")
    parser.add_argument("sources", nargs="*", default=list(DEFAULT_SOURCES),
                        help="source files or folders (default: the sample and dev scenes)")
    args = parser.parse_args(argv)
    out = Path(args.out).resolve()
    if out.is_relative_to(ROOT):
        raise SystemExit(f"{out} is inside the project: WOMD data is never copied into it.")
    files = write_repeated(args.n, out, per_file=args.per_file, sources=args.sources)
    size = sum(f.stat().st_size for f in files)
    print(f"{args.n} scenes in {len(files)} files, {size / 1e6:.1f} MB -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
