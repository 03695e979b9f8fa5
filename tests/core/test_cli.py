"""The ``tap-bench`` command: sample, label, fit, and its errors."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

import tap_bench as tb
from tap_bench.cli import main


@pytest.fixture
def sample(tmp_path):
    path = tmp_path / "sample.parquet"
    assert main(["sample", "-o", str(path), "--random", "30"]) == 0
    return path


def test_label_all_levels_with_segments_and_steps(sample, tmp_path, capsys):
    out, seg, steps = tmp_path / "l.csv", tmp_path / "s.parquet", tmp_path / "st.parquet"
    code = main(["label", str(sample), "-o", str(out), "--level", "all", "--segments", str(seg),
                 "--steps", str(steps)])
    assert code == 0
    labels = tb.read_table(out)
    assert set(labels["level"]) == set(tb.LEVELS)
    n_tracks = len(tb.synthetic.BEHAVIOURS) + 30
    assert len(labels) == 4 * n_tracks
    assert list(labels.columns[:13]) == ["scenario_id", "track_id", "segment", "level",
                                         "lateral", "longitudinal", "sdl", "t_start", "t_end",
                                         "heading_glitches", "speed_glitches",
                                         "reversing_steps", "travel"]
    segments = pd.read_parquet(seg)
    assert {"axis", "label"} <= set(segments.columns)
    assert len(pd.read_parquet(steps)) == len(tb.read_table(sample))
    text = capsys.readouterr().out
    assert f"labelled {n_tracks} segment(s)" in text and "distinct action-level labels" in text
    assert "glitches repaired: 0 heading flips or jumps in 0 track(s)" in text


def test_label_default_level_is_action(sample, tmp_path):
    out = tmp_path / "l.parquet"
    assert main(["label", str(sample), "-o", str(out)]) == 0
    assert set(pd.read_parquet(out)["level"]) == {"action"}


def test_csv_ids_that_look_numeric_stay_strings(tmp_path):
    table = tb.behaviour("cruise_slow", scenario_id="007", track_id="0042")
    path = tmp_path / "t.csv"
    table.to_csv(path, index=False)
    out = tmp_path / "l.csv"
    assert main(["label", str(path), "-o", str(out)]) == 0
    labels = tb.read_table(out)
    assert labels[["scenario_id", "track_id"]].iloc[0].tolist() == ["007", "0042"]


@pytest.mark.parametrize(("row", "encoding"), [(1, "latin-1"), (7, "cp1252"), (40, "utf-16")])
def test_a_csv_that_is_not_utf8_names_its_line_and_the_fix(tmp_path, capsys, row, encoding):
    """A table saved in another encoding (an accented id in Latin-1, a Windows code page,
    a UTF-16 file): the error names the file, the line and byte where UTF-8 breaks, and how
    to convert it, not the decoder's position in an internal chunk."""
    table = tb.behaviour("cruise_slow", scenario_id="s", track_id="t")
    table["track_id"] = table["track_id"].astype(object)
    table.loc[row - 1, "track_id"] = "caf\u00e9"
    path = tmp_path / "t.csv"
    table.to_csv(path, index=False, encoding=encoding)
    assert main(["label", str(path), "-o", str(tmp_path / "l.csv")]) == 2
    err = capsys.readouterr().err
    data = path.read_bytes()
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as bad:
        line = data.count(b"\n", 0, bad.start) + 1
    assert f"{path}: line {line}, byte " in err and "is not UTF-8 text" in err
    assert "Save the file as UTF-8" in err
    if encoding != "utf-16":  # the header is ASCII: the accented id's line (header + row)
        assert line == row + 1
    assert ("iconv -f utf-16" in err) == (encoding == "utf-16")


def test_fit_then_label_with_the_fitted_thresholds(sample, tmp_path, capsys):
    th = tmp_path / "th.json"
    assert main(["fit", str(sample), "-o", str(th), "--methods", "descent", "grid"]) == 0
    text = capsys.readouterr().out
    for dist in ("w:", "a:", "v:"):
        assert dist in text
    assert "dJ_to_grid" in text and "chosen:" in text
    doc = json.loads(th.read_text())
    assert doc["provenance"]["dataset"] == str(sample)
    out = tmp_path / "l.parquet"
    assert main(["label", str(sample), "-o", str(out), "--thresholds", str(th)]) == 0


def test_errors_name_the_file_and_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    table = tb.behaviour("cruise_slow")
    table.loc[3, "speed"] = -1.0
    table.to_csv(bad, index=False)
    out = tmp_path / "l.csv"
    assert main(["label", str(bad), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "row 3" in err and "negative" in err
    assert not out.exists()  # nothing half-written
    assert main(["label", str(tmp_path / "none.parquet"), "-o", str(out)]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["label", str(bad), "-o", str(tmp_path / "l.txt")]) == 2
    assert main(["label", str(bad), "-o", str(out), "--thresholds", "papr"]) == 2
    assert "Did you mean 'paper'" in capsys.readouterr().err


def test_short_segments_report(tmp_path, capsys):
    table = tb.behaviour("cruise_slow").assign(valid=True)
    table.loc[4, "valid"] = False
    path, out, rep = tmp_path / "t.parquet", tmp_path / "l.parquet", tmp_path / "short.csv"
    tb.write_table(table, path)
    assert main(["label", str(path), "-o", str(out), "--report", str(rep)]) == 0
    assert "shorter than 1 s" in capsys.readouterr().err
    report = tb.read_table(rep)  # one row per track
    assert report["segments"].tolist() == [2]
    assert report["short_segments"].tolist() == [1] and report["short_steps"].tolist() == [4]


def test_write_is_atomic(tmp_path, monkeypatch):
    target = tmp_path / "x.parquet"
    tb.write_table(pd.DataFrame({"a": [1]}), target)

    def boom(self, path, **kw):
        with open(path, "wb") as fh:
            fh.write(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(pd.DataFrame, "to_parquet", boom)
    with pytest.raises(OSError):
        tb.write_table(pd.DataFrame({"a": [2]}), target)
    monkeypatch.undo()
    assert pd.read_parquet(target)["a"].tolist() == [1]
    assert [p.name for p in tmp_path.iterdir()] == ["x.parquet"]


def test_resampled_table_labels_like_the_original():
    table = tb.behaviour("aggressive_right_turn")
    two_hz = table.iloc[::5].reset_index(drop=True)
    back = tb.resample_to_10hz(two_hz)
    assert np.allclose(back["t"].diff().dropna(), 0.1)
    assert tb.label(back)["sdl"].item() == tb.label(table)["sdl"].item()


def test_written_files_get_the_usual_permissions(tmp_path):
    import os
    import stat

    target = tb.write_table(pd.DataFrame({"a": [1]}), tmp_path / "p.csv")
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(target.stat().st_mode) == 0o666 & ~umask
