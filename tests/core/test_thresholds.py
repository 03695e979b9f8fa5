"""Thresholds: ordering checks, presets, versioned JSON."""

from __future__ import annotations

import json

import pytest

import tap_bench as tb
from tap_bench.thresholds import PAPER, resolve_thresholds


def test_paper_preset_values():
    assert PAPER.of("w") == (0.0283, 0.0754, 0.1541)
    assert PAPER.of("a") == (-1.3715, 1.5557)
    assert PAPER.of("v") == (0.1, 10.2140, 24.4046)
    assert resolve_thresholds("paper") is PAPER


@pytest.mark.parametrize("bad", [
    dict(w_str=0.1, w_grad=0.05),
    dict(a_dec=1.0, a_acc=0.5),
    dict(v_stop=-0.1),
    dict(v_slow=30.0),
    dict(w_med=float("nan")),
])
def test_out_of_order_thresholds_are_refused(bad):
    kw = {**{f"{d}_{n}": v for d in ("w", "a", "v")
             for n, v in zip(tb.thresholds.NAMES[d], PAPER.of(d), strict=True)}, **bad}
    with pytest.raises(tb.ThresholdsError):
        tb.Thresholds(**kw)


def test_json_round_trip_keeps_values_units_and_provenance(tmp_path):
    path = tb.save_thresholds(PAPER, tmp_path / "paper.json")
    doc = json.loads(path.read_text())
    assert doc["format"] == "tap-bench-thresholds" and doc["version"] == 1
    assert doc["units"] == {"w": "rad/s", "a": "m/s^2", "v": "m/s"}
    back = tb.load_thresholds(path)
    assert back == PAPER and back.provenance == PAPER.provenance
    assert resolve_thresholds(str(path)) == PAPER


def test_bad_files_name_the_problem(tmp_path):
    path = tmp_path / "t.json"
    path.write_text("{not json")
    with pytest.raises(tb.ThresholdsError, match="not valid JSON"):
        tb.load_thresholds(path)
    doc = PAPER.to_dict()
    doc["version"] = 99
    path.write_text(json.dumps(doc))
    with pytest.raises(tb.ThresholdsError, match="version 99 is not supported"):
        tb.load_thresholds(path)
    doc = PAPER.to_dict()
    del doc["thresholds"]["a"]["acc"]
    path.write_text(json.dumps(doc))
    with pytest.raises(tb.ThresholdsError, match=r"thresholds\.a\.acc"):
        tb.load_thresholds(path)
    with pytest.raises(tb.ThresholdsError, match="no such thresholds file"):
        tb.load_thresholds(tmp_path / "missing.json")


def test_unknown_preset_suggests_names():
    with pytest.raises(tb.UnknownNameError, match="Did you mean 'paper'"):
        resolve_thresholds("papr")


def test_labels_follow_the_thresholds():
    table = tb.behaviour("cruise_medium")  # 15 m/s
    strict = PAPER.replace("v", (0.1, 16.0, 30.0))
    assert tb.label(table, strict)["longitudinal"].item() == "Maintain Slow Speed"
    assert tb.label(table, "paper")["longitudinal"].item() == "Maintain Medium Speed"
