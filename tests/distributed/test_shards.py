"""Sharded ingest, labelling and fitting: Ray and local backends give the same tables and
thresholds as the one-machine functions; a corrupt shard is reported and the others land."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from tap_bench.distributed import distributed_fit_report, ingest_shards, label_shards
from tap_bench.execution import LocalBackend

KEYS = ["scenario_id", "track_id", "segment", "level"]


def _sorted(table: pd.DataFrame, keys: list[str]) -> pd.DataFrame:
    return table.sort_values(keys, kind="stable").reset_index(drop=True)


@pytest.fixture(scope="module")
def ingested(ray_cluster, womd_shards, tmp_path_factory):
    """The shards and a corrupt one ingested on Ray: (output dir, report, good inputs)."""
    paths, _ = womd_shards
    folder = tmp_path_factory.mktemp("inputs")
    inputs = []
    for p in paths:
        inputs.append(folder / p.name)
        inputs[-1].write_bytes(p.read_bytes())
    corrupt = folder / "training.tfrecord-corrupt"
    data = bytearray(paths[0].read_bytes())
    data[40:48] = b"\xff" * 8  # inside the first record: its CRC no longer matches
    corrupt.write_bytes(bytes(data))
    out = tmp_path_factory.mktemp("out") / "womd"
    report = ingest_shards(folder, out, ray_cluster.backend, retries=1, progress=False)
    return out, report, inputs


def test_a_corrupt_shard_is_reported_and_the_others_land(ingested):
    out, report, inputs = ingested
    assert len(report.shards) == 4 and len(report.failed) == 1
    failed = report.failed[0]
    assert failed["input"].endswith("training.tfrecord-corrupt")
    assert failed["attempts"] == 2 and failed["output"] is None and "CRC" in failed["error"]
    written = json.loads((out / "_report.json").read_text())
    assert written["failed"] == 1
    assert [s["error"] for s in written["shards"] if not s["ok"]] == [failed["error"]]
    parts = sorted(p.name for p in out.glob("*.parquet"))
    assert parts == [f"{p.name}.parquet" for p in inputs]
    assert not list(out.glob("*.report.json")) and not list(out.glob(".*"))


def test_ray_ingest_gives_the_tables_of_a_local_ingest(ingested):
    from tap_bench.sources import read_womd

    out, _, inputs = ingested
    for src in inputs:
        expected = read_womd(src)
        got = pd.read_parquet(out / f"{src.name}.parquet")
        pd.testing.assert_frame_equal(got, expected)


def test_ray_and_local_labels_of_the_shards_equal_the_labels_of_the_whole_table(
        ingested, ray_backend, tmp_path):
    from tap_bench import label

    out, _, _ = ingested
    ray_report = label_shards(out, tmp_path / "ray", ray_backend, level="all",
                              progress=False)
    local_report = label_shards(out, tmp_path / "local", LocalBackend(1), level="all",
                                progress=False)
    assert not ray_report.failed and not local_report.failed
    ray_labels = _sorted(pd.read_parquet(tmp_path / "ray"), KEYS)
    local_labels = _sorted(pd.read_parquet(tmp_path / "local"), KEYS)
    pd.testing.assert_frame_equal(ray_labels, local_labels)
    whole = _sorted(label(pd.read_parquet(out), level="all"), KEYS)
    assert len(whole) == ray_report.rows > 0
    pd.testing.assert_frame_equal(ray_labels, whole, check_dtype=False)


def test_the_distributed_fit_gives_the_thresholds_of_the_local_fit(ingested, ray_backend):
    from tap_bench.fitting import fit_report
    from tap_bench.kinematics import one_second_samples

    out, _, _ = ingested
    options = {"methods": ("descent", "grid"), "epochs": 30}
    local = fit_report(one_second_samples(pd.read_parquet(out)), **options)
    on_ray, merged = distributed_fit_report(out, ray_backend, **options)
    on_local, _ = distributed_fit_report(out, LocalBackend(1), **options)
    for got in (on_ray, on_local):
        assert got.thresholds.of("w") == local.thresholds.of("w")
        assert got.thresholds.of("a") == local.thresholds.of("a")
        assert got.thresholds.of("v") == local.thresholds.of("v")
        for dist in ("w", "a", "v"):
            assert got.fits[dist].chosen.objective == local.fits[dist].chosen.objective
            assert got.fits[dist].grid.theta == local.fits[dist].grid.theta
    assert all(np.all(np.diff(x) >= 0) for x in merged.samples.values())
    assert len(merged.samples["v"]) == len(one_second_samples(pd.read_parquet(out))["v"])


def test_labels_do_not_depend_on_the_chunk_size_nor_on_scenarios_interleaved(
        ingested, tmp_path):
    from tap_bench import label

    out, _, _ = ingested
    whole = _sorted(label(pd.read_parquet(out), level="all"), KEYS)
    small = label_shards(out, tmp_path / "small", LocalBackend(1), level="all",
                         chunk_rows=3000, progress=False)
    assert not small.failed
    pd.testing.assert_frame_equal(_sorted(pd.read_parquet(tmp_path / "small"), KEYS), whole,
                                  check_dtype=False)
    # rows of two scenarios interleaved step by step: chunks cannot hold whole scenarios,
    # so the part is labelled whole
    table = pd.read_parquet(next(out.glob("*.parquet")))
    first, second = table["scenario_id"].unique()[:2]
    pair = table[table["scenario_id"].isin([first, second])]
    mixed = pair.sort_values("t", kind="stable").reset_index(drop=True)
    assert mixed["scenario_id"].ne(mixed["scenario_id"].shift()).sum() > 2
    (tmp_path / "mixed").mkdir()
    mixed.to_parquet(tmp_path / "mixed" / "mixed.parquet")
    label_shards(tmp_path / "mixed", tmp_path / "mixed-labels", LocalBackend(1),
                 chunk_rows=500, progress=False)
    pd.testing.assert_frame_equal(_sorted(pd.read_parquet(tmp_path / "mixed-labels"), KEYS[:3]),
                                  _sorted(label(pair), KEYS[:3]), check_dtype=False)
