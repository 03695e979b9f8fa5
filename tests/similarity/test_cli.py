"""``tap-bench search``, ``unique`` and ``evaluate``."""

from __future__ import annotations

import json

import pandas as pd
from similarity_helpers import LEFT_MERGE, label_rows, triples

from tap_bench.cli import main


def test_search_like_and_sdl(small_labels, tmp_path, capsys):
    path = tmp_path / "labels.csv"
    small_labels.to_csv(path, index=False)
    assert main(["search", str(path), "--like", "s1:2"]) == 0
    out = capsys.readouterr().out
    assert f"reference (action level): {LEFT_MERGE}" in out
    assert "1 of 6 trajectories within exact distance 0" in out
    matches = tmp_path / "m.parquet"
    assert main(["search", str(path), "--sdl", "Straight > Gradual Left Turn > Straight | "
                 "Maintain Medium Speed", "--metric", "levenshtein", "--d-sim", "2", "-o",
                 str(matches)]) == 0
    out = capsys.readouterr().out
    assert "5 of 6 trajectories within levenshtein distance 2" in out
    assert pd.read_parquet(matches)["distance"].tolist() == [1, 1, 2, 2, 2]


def test_search_ids_with_colons_and_segments(tmp_path, capsys):
    labels = label_rows([("a:b", "1", LEFT_MERGE), ("a:b", "1", LEFT_MERGE),
                         ("c", "2", LEFT_MERGE)])
    labels.loc[1, "segment"] = 1
    path = tmp_path / "labels.parquet"
    labels.to_parquet(path)
    assert main(["search", str(path), "--like", "a:b:1:1"]) == 0
    assert "2 of 3 trajectories" in capsys.readouterr().out
    assert main(["search", str(path), "--like", "a:b:1"]) == 2
    assert "pick one as a:b:1:SEGMENT" in capsys.readouterr().err


def test_search_errors_exit_2(small_labels, tmp_path, capsys):
    path = tmp_path / "labels.csv"
    small_labels.to_csv(path, index=False)
    assert main(["search", str(path), "--sdl", "Straight | Maintain Medum Speed"]) == 2
    err = capsys.readouterr().err
    assert "Did you mean 'Maintain Medium Speed'" in err
    assert main(["search", str(tmp_path / "nope.csv"), "--like", "s1:1"]) == 2
    assert "no such file" in capsys.readouterr().err


def test_search_scenarios(tmp_path, capsys):
    labels = label_rows([("s1", "1", LEFT_MERGE), ("s2", "1", LEFT_MERGE),
                         ("s3", "1", "Straight | Stopped")])
    path = tmp_path / "labels.csv"
    labels.to_csv(path, index=False)
    out_path = tmp_path / "ranked.csv"
    assert main(["search", str(path), "--scenario", "s1", "-o", str(out_path)]) == 0
    out = capsys.readouterr().out
    assert "vehicle: Left Merge" in out
    ranked = pd.read_csv(out_path)
    assert ranked["scenario_id"].tolist() == ["s2", "s3"]
    assert ranked["distance"].iloc[0] == 0


def test_unique(small_labels, tmp_path, capsys):
    path = tmp_path / "labels.csv"
    small_labels.to_csv(path, index=False)
    out, counts = tmp_path / "unique.parquet", tmp_path / "counts.csv"
    assert main(["unique", str(path), "--level", "action", "-o", str(out), "--counts",
                 str(counts)]) == 0
    text = capsys.readouterr().out
    assert "action: 1 of 6 trajectories (16.67 %) have a unique label; 3 distinct" in text
    assert pd.read_parquet(out)["track_id"].tolist() == ["2"]
    assert pd.read_csv(counts)["count"].tolist() == [3, 2, 1]


def test_evaluate(tmp_path, capsys):
    table, labels = triples()
    traj, lab = tmp_path / "t.parquet", tmp_path / "l.parquet"
    table.to_parquet(traj)
    labels.to_parquet(lab)
    out = tmp_path / "eval"
    assert main(["evaluate", str(traj), "--labels", str(lab), "-o", str(out),
                 "--object-types", "all", "--no-figures", "--workers", "1"]) == 0
    text = capsys.readouterr().out
    assert "nearest by ADE: 4 of 12 have a different SDL label (33.33 %)" in text
    assert "nearest by DTW: 8 of 12 have a different SDL label (66.67 %)" in text
    summary = json.loads((out / "evaluation.json").read_text())
    assert summary["data"]["trajectories"] == 12
    assert not (out / "fig5_similarity.png").exists()
