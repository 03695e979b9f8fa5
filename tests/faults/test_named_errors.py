"""Tracebacks found by the attack on every promise, each now a named error or handled: a
policy name that is invalid matplotlib math, scenario ids over 255 bytes or called
``index`` in the viewer and export, a full disk under ``-o``, ``contexts`` without an ego,
``gap`` on an empty table, a malformed ``%`` in the viewer's URL, ``-o X --cache X``."""

from __future__ import annotations

import errno
import json
import re
import shutil
import subprocess
import warnings

import numpy as np
import pandas as pd
import pytest
from fault_helpers import PROJECT_ROOT

from tap_bench.bench.run.runner import run_suite
from tap_bench.bench.suite import suite_from_dict
from tap_bench.sim.policies import get_definition


def test_a_policy_name_that_is_invalid_matplotlib_math_gets_its_report(tmp_path):
    folder = tmp_path / "policies"
    folder.mkdir()
    doc = json.loads(get_definition("idm").path.read_text())
    paths = []
    for name in ("idm$^{", "cost $\\frac$ x"):
        path = folder / f"{name}.json"
        path.write_text(json.dumps({**doc, "name": name}))
        paths.append(str(path))
    suite = suite_from_dict({"name": "math", "envs": ["merge"], "policies": paths,
                             "seeds": "0-1", "reference_policy": paths[0],
                             "env_overrides": {"merge": {"duration": 2}},
                             "bootstrap": {"n_resamples": 100}}, check_names=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_suite(suite, tmp_path / "run", workers=1, progress=False)
    html = result.report.read_text()
    figures = list((tmp_path / "run" / "plots").glob("*.svg"))
    assert "idm$^{" in html and figures
    assert any("cost $\\frac$ x" in path.read_text() for path in figures)  # drawn as text
    plots = tmp_path / "run" / "plots"
    for path in (plots / "tradeoff.svg", *plots.glob("forest_*.svg")):  # and the views
        assert "idm$^{" in path.read_text() and "cost $\\frac$ x" in path.read_text()


def _womd(path, scenario_id: str):
    from tap_bench.womd.writer import write_womd

    t = np.round(np.arange(30) * 0.1, 10)
    rows = [{"scenario_id": scenario_id, "track_id": track, "t": tt, "x": 10 * tt, "y": y,
             "heading": 0.0, "vx": 10.0, "vy": 0.0, "speed": 10.0, "object_type": "vehicle",
             "valid": True, "is_ego": track == "1"}
            for track, y in (("1", 0.0), ("2", 3.5)) for tt in t]
    write_womd(pd.DataFrame(rows), path)
    return path


@pytest.mark.parametrize("scenario_id", ["x" * 300, "é" * 200, "index", "INDEX", ".hidden"])
def test_scenario_ids_over_255_bytes_or_reserved_make_a_whole_viewer(tmp_path, cli,
                                                                    scenario_id):
    shard = _womd(tmp_path / "s.tfrecord", scenario_id)
    other = _womd(tmp_path / "t.tfrecord", "plain")
    code, _, err = cli("view", shard, other, "-o", tmp_path / "viewer", "--no-open")
    assert code == 0, err
    data = tmp_path / "viewer" / "data"
    assert all(len(p.name.encode()) <= 255 for p in data.iterdir())
    index = (data / "index.js").read_text()
    assert index.startswith("TAPVIEW.index(")  # not overwritten by a scenario's chunk
    entries = json.loads(index[len("TAPVIEW.index("):index.rindex(")")])["episodes"]
    chunks = {e["id"]: e["chunk"] for e in entries}
    assert set(chunks) == {scenario_id, "plain"}
    assert all((data / f"{c}.js").is_file() for c in chunks.values())
    table = tmp_path / "t.parquet"
    assert cli("ingest", "womd", shard, "-o", table)[0] == 0
    code, _, err = cli("export", table, "-o", tmp_path / "exported")
    assert code == 0, err


def test_a_full_disk_under_o_is_a_message_and_leaves_nothing(tmp_path, cli, monkeypatch):
    table = tmp_path / "t.parquet"
    assert cli("sample", "-o", table)[0] == 0
    real = pd.DataFrame.to_parquet

    def full(self, path, *args, **kwargs):
        if "labels" in str(path):
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(self, path, *args, **kwargs)

    monkeypatch.setattr(pd.DataFrame, "to_parquet", full)
    code, _, err = cli("label", table, "-o", tmp_path / "labels.parquet")
    assert code == 2 and "no space left on device" in err and "Traceback" not in err
    assert "-o" in err and not (tmp_path / "labels.parquet").exists()


@pytest.fixture(scope="module")
def rollouts(tmp_path_factory):
    from tap_bench.cli import main

    folder = tmp_path_factory.mktemp("rollouts")
    for policy in ("idm", "lane-keeping"):
        assert main(["rollout", "--env", "merge", "--policy", policy, "--seeds", "0-1",
                     "--duration", "3", "-o", str(folder / f"{policy}.parquet"),
                     "--no-progress"]) == 0
    return folder


def test_contexts_without_an_ego_is_a_named_error(tmp_path, cli, rollouts):
    paths = []
    for policy in ("idm", "lane-keeping"):
        table = pd.read_parquet(rollouts / f"{policy}.parquet").assign(is_ego=False)
        paths.append(tmp_path / f"{policy}.parquet")
        table.to_parquet(paths[-1])
    code, _, err = cli("contexts", *paths, "--a", "idm", "--b", "lane-keeping",
                       "-o", tmp_path / "ctx.csv")
    assert code == 2 and "no ego" in err and "Traceback" not in err
    dropped = pd.read_parquet(paths[0]).drop(columns=["is_ego"])
    dropped.to_parquet(paths[0])
    code, _, err = cli("contexts", paths[0], "--a", "idm", "--b", "lane-keeping")
    assert code == 2 and "no ego" in err


def test_gap_on_an_empty_table_is_a_named_error(tmp_path, cli, rollouts):
    empty = tmp_path / "empty.parquet"
    pd.read_parquet(rollouts / "idm.parquet").iloc[0:0].to_parquet(empty)
    code, _, err = cli("gap", empty, "--reference", rollouts / "lane-keeping.parquet",
                       "-o", tmp_path / "gap.csv")
    assert code == 2 and "empty" in err and "Traceback" not in err
    nameless = tmp_path / "nameless.parquet"
    pd.read_parquet(rollouts / "idm.parquet").assign(policy=None).to_parquet(nameless)
    code, _, err = cli("gap", nameless, "--reference", rollouts / "lane-keeping.parquet")
    assert code == 2 and "policy" in err and "Traceback" not in err


@pytest.mark.parametrize("same", ["equal", "cache inside", "run inside"])
def test_a_run_folder_and_its_cache_must_be_apart(tmp_path, cli, same):
    out = tmp_path / "X"
    cache = {"equal": out, "cache inside": out / "cache", "run inside": tmp_path}[same]
    code, _, err = cli("bench", "run", "--suite", "demo", "-o", out, "--cache", cache,
                       "--seeds", "0", "--workers", "1", "--no-progress")
    assert code == 2 and "overlap" in err and "Traceback" not in err
    assert not out.exists()


def _function(source: str, name: str) -> str:
    start = source.index(f"function {name}(")
    depth, i = 0, source.index("{", start)
    while True:
        depth += {"{": 1, "}": -1}.get(source[i], 0)
        if depth == 0:
            return source[start:i + 1]
        i += 1


@pytest.mark.skipif(shutil.which("node") is None, reason="needs node")
def test_a_malformed_percent_in_the_viewer_url_is_ignored():
    js = (PROJECT_ROOT / "tap_bench" / "bench" / "report" / "viewer" / "static"
          / "viewer.js").read_text()
    code = (_function(js, "decodePart") + "\n" + _function(js, "parseHash") + "\n"
            "const location = {hash: '#ep=highway%2Fidm&x=%zz&%=1&seed=%E0%A4%A&env=a%20b'};\n"
            "console.log(JSON.stringify(parseHash()));")
    out = subprocess.run(["node", "-e", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    parsed = json.loads(out.stdout)
    assert parsed == {"ep": "highway/idm", "env": "a b"}
    assert re.search(r"decodeURIComponent\(", js.replace(_function(js, "decodePart"), "")) \
        is None
