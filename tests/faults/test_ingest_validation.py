"""Bad records are caught where they enter: ingest checks every scenario against the
trajectory contract (NaN, duplicate or reversed times; infinite or NaN coordinates), stop
mode names the record, skip mode lists it in the report and keeps the others, so what
ingest writes always labels, validates and exports."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest

from tap_bench.errors import WomdRecordError
from tap_bench.sources.ingest import IngestReport, read_womd, report_path

N = 20  # steps (2 s: long enough to label)


def _ts(at: int = 5, value=None, reverse: bool = False) -> np.ndarray:
    ts = np.arange(N) * 0.1
    if reverse:
        return ts[::-1].copy()
    ts[at] = value
    return ts


def scenarionet_doc(scenario_id: str, ts=None, position=None) -> dict:
    n = N
    state = {"position": np.zeros((n, 3)) if position is None else position,
             "velocity": np.ones((n, 2)), "heading": np.zeros(n), "valid": np.ones(n, bool),
             "length": np.full(n, 4.5)}
    state["position"][:, 0] = np.arange(n) * 0.1 if position is None else position[:, 0]
    return {"id": scenario_id, "metadata": {"ts": np.arange(n) * 0.1 if ts is None else ts,
                                            "scenario_id": scenario_id, "dataset": "waymo",
                                            "sdc_id": "1"},
            "tracks": {"1": {"type": "VEHICLE", "state": state}}}


def _position(x=0.0, y=0.0, at=2):
    p = np.zeros((N, 3))
    p[:, 0] = np.arange(N) * 0.1
    p[at, 0] += x
    p[at, 1] = y
    return p


BAD = {
    "NaN timestamp": dict(ts=_ts(value=np.nan)),
    "duplicate timestamp": dict(ts=_ts(value=0.4)),
    "reversed timestamps": dict(ts=_ts(reverse=True)),
    "infinite x": dict(position=_position(x=np.inf)),
    "NaN y": dict(position=_position(y=np.nan)),
    "-infinite y": dict(position=_position(y=-np.inf)),
}


@pytest.fixture
def folder(tmp_path):
    def make(case):
        (tmp_path / "a.pkl").write_bytes(pickle.dumps(scenarionet_doc("sn-a")))
        (tmp_path / "bad.pkl").write_bytes(pickle.dumps(scenarionet_doc("sn-bad",
                                                                       **BAD[case])))
        (tmp_path / "c.pkl").write_bytes(pickle.dumps(scenarionet_doc("sn-c")))
        return tmp_path
    return make


@pytest.mark.parametrize("case", sorted(BAD))
def test_stop_names_the_record_and_skip_lists_it(folder, case):
    path = folder(case)
    with pytest.raises(WomdRecordError, match=r"bad\.pkl: record 0 at byte 0: .*trajectory "
                       "contract"):
        read_womd(path)
    report = IngestReport()
    table = read_womd(path, on_error="skip", report=report)
    assert sorted(table["scenario_id"].unique()) == ["sn-a", "sn-c"]
    assert [s["path"].endswith("bad.pkl") for s in report.skipped] == [True]


@pytest.mark.parametrize("case", sorted(BAD))
def test_ingest_cli_exits_2_or_reports_and_what_it_writes_labels(folder, cli, case):
    path = folder(case)
    out = path / "out.parquet"
    code, _, err = cli("ingest", "womd", path, "-o", out)
    assert code == 2 and "bad.pkl" in err and "Traceback" not in err and not out.exists()
    code, _, err = cli("ingest", "womd", path, "-o", out, "--on-error", "skip")
    assert code == 0, err
    assert "skipped 1 record" in err
    report = json.loads(report_path(out).read_text())
    assert "bad.pkl" in json.dumps(report) and "trajectory contract" in json.dumps(report)
    code, _, err = cli("label", out, "-o", path / "labels.parquet")
    assert code == 0, err
    code, _, err = cli("export", out, "-o", path / "exported")
    assert code == 0, err
