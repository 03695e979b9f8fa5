"""The suite report's realism section: the results of ``tap-bench realism`` a run is given,
read, checked and shown (traffic models floor to ceiling, by manoeuvre)."""

from __future__ import annotations

import json

import pytest

from tap_bench.bench.report.realism import realism_entries, realism_section
from tap_bench.errors import ParameterError


def result(traffic: str, value: float, low: float, high: float, left: float) -> dict:
    block = {"value": value, "low": low, "high": high}
    return {"traffic": traffic, "policy": "log", "rollouts": 8, "scenes": 16, "agents": 458,
            "weights": {"linear_speed": 0.05, "collision_indication": 0.25},
            "overall": {"meta_metric": block, "linear_speed": {"value": 0.5},
                        "collision_indication": {"value": 0.9}},
            "by_manoeuvre": {"Left Turn": {"meta_metric": {"value": left, "low": left - 0.1,
                                                           "high": left + 0.1},
                                           "agents": 12}},
            "by_object_type": {}, "interval": "95 % bootstrap over scenes",
            "definition": "WOSAC 2025", "files": ["x"], "cpu_seconds": 1.0}


def test_results_are_read_and_shown_from_floor_to_ceiling(tmp_path):
    files = []
    for r in (result("log", 0.907, 0.892, 0.922, 0.84),
              result("idm", 0.791, 0.726, 0.850, 0.70),
              result("constant-velocity", 0.623, 0.523, 0.717, 0.52)):
        files.append(tmp_path / f"{r['traffic']}.json")
        files[-1].write_text(json.dumps(r))
    entries = realism_entries(files)
    assert [e["traffic"] for e in entries] == ["constant-velocity", "idm", "log"]
    assert "files" not in entries[0] and "cpu_seconds" not in entries[0]  # what it shows
    page = "".join(realism_section(entries))
    assert "Realism of the simulated traffic" in page
    assert "0.791 [0.726, 0.850]" in page and "0.623 [0.523, 0.717]" in page
    assert page.index("0.623 [0.523") < page.index("0.791 [0.726") < page.index("0.907")
    assert "Left Turn" in page and "0.700 [0.600, 0.800]" in page
    assert realism_section([]) == []


def test_a_file_that_is_not_a_realism_result_is_refused_by_name(tmp_path):
    bad = tmp_path / "episodes.json"
    bad.write_text(json.dumps({"traffic": "idm"}))
    with pytest.raises(ParameterError, match=r"overall, by_manoeuvre missing.*episodes\.json"):
        realism_entries([bad])
    broken = tmp_path / "broken.json"
    broken.write_text("{not json")
    with pytest.raises(ParameterError, match=r"broken\.json"):
        realism_entries([broken])
