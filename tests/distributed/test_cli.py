"""The command line with --backend ray: ingest to a directory, label it, fit on it."""

from __future__ import annotations

import json

import pandas as pd

from tap_bench.cli import main


def test_ingest_label_and_fit_a_shard_directory_with_the_ray_backend(
        ray_backend, womd_shards, tmp_path, capsys):
    from tap_bench import label
    from tap_bench.fitting import fit_report
    from tap_bench.thresholds import load_thresholds

    paths, _ = womd_shards
    womd, labels, th = tmp_path / "womd", tmp_path / "labels", tmp_path / "th.json"
    assert main(["ingest", "womd", str(paths[0].parent), "-o", str(womd), "--backend", "ray",
                 "--no-progress"]) == 0
    assert len(list(womd.glob("*.parquet"))) == 3
    assert main(["label", str(womd), "-o", str(labels), "--backend", "ray"]) == 0
    assert json.loads((labels / "_report.json").read_text())["failed"] == 0
    assert main(["fit", str(womd), "-o", str(th), "--backend", "ray", "--methods", "descent",
                 "--epochs", "20"]) == 0
    assert "3 of 3 shard(s) on ray" in capsys.readouterr().out

    whole = pd.read_parquet(womd)
    keys = ["scenario_id", "track_id", "segment"]
    got = pd.read_parquet(labels).sort_values(keys).reset_index(drop=True)
    pd.testing.assert_frame_equal(got, label(whole).sort_values(keys).reset_index(drop=True),
                                  check_dtype=False)
    local = fit_report(whole, methods=("descent",), epochs=20).thresholds
    fitted = load_thresholds(th)
    assert [fitted.of(d) for d in "wav"] == [local.of(d) for d in "wav"]
