"""``bench run`` on recorded scenes writes each episode's trajectories to disk as it ends
(:mod:`tap_bench.bench.run.spill`) and joins them afterwards: the run folder's tables equal
those of a run that holds every trajectory in memory, and nothing is left beside it."""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import pandas as pd

from tap_bench.bench.run import runner
from tap_bench.bench.run import spill as bench_spill
from tap_bench.bench.suite import suite_from_dict
from tap_bench.cli import main

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "scale"))  # scale_scenes
sys.path.insert(0, str(HERE.parent / "sim"))  # womd_records

from scale_scenes import scene_files  # noqa: E402


def womd_suite(files: list[str]):
    return suite_from_dict(suite_doc(files))


def suite_doc(files: list[str]) -> dict:
    return {
        "name": "womd-stream", "version": 0,
        "envs": [{"womd": files, "traffic": "log", "ego": "sdc", "policy_frequency": 2}],
        "policies": ["log", "idm"], "reference_policy": "log", "seeds": "all",
        "level": "maneuver", "thresholds": "paper",
        "bootstrap": {"n_resamples": 200, "level": 0.95, "seed": 0}}


def _run(suite, out: Path, **options) -> Path:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return runner.run_suite(suite, out, workers=1, progress=False, **options).folder


def _same_folders(a: Path, b: Path) -> None:
    tables = sorted(p.name for p in a.glob("*.parquet"))
    assert tables == sorted(p.name for p in b.glob("*.parquet"))
    assert "trajectories.parquet" in tables
    for name in tables:
        pd.testing.assert_frame_equal(pd.read_parquet(a / name), pd.read_parquet(b / name),
                                      obj=name)
    data = sorted(p.relative_to(a) for p in (a / "viewer").rglob("*")
                  if p.is_file() and p.suffix != ".html")
    assert data == sorted(p.relative_to(b) for p in (b / "viewer").rglob("*")
                          if p.is_file() and p.suffix != ".html")
    for rel in data:  # the index names the run and its time
        if rel.name != "index.js":
            assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    assert len(data) > 2
    sa, sb = (json.loads((f / "summary.json").read_text()) for f in (a, b))
    for key in ("headline", "verdict", "n_episodes", "failed", "methods"):
        assert sa[key] == sb[key], key


def test_a_womd_run_spills_trajectories_and_equals_one_held_in_memory(tmp_path, monkeypatch):
    files = scene_files(tmp_path / "scenes", 5, per_file=2, parked=20)
    suite = womd_suite(files)
    kept = []  # the spills made, to see what each held
    made = bench_spill.TrajectorySpill

    def spill(output):
        kept.append(made(output))
        return kept[-1]

    monkeypatch.setattr(runner, "TrajectorySpill", spill)
    streamed = _run(suite, tmp_path / "streamed")
    assert len(kept) == 1 and len(kept[0].parts) == 10  # an episode a part
    assert not kept[0].folder.exists()  # removed when the run ended
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scenes", "streamed"]
    monkeypatch.setattr(runner, "spills", lambda scenarios: False)
    held = _run(suite, tmp_path / "held")
    assert len(kept) == 1
    _same_folders(streamed, held)
    assert len(pd.read_parquet(streamed / "trajectories.parquet")) == kept[0].rows


def test_without_the_report_the_trajectories_are_never_one_table(tmp_path, monkeypatch,
                                                                   capsys):
    files = scene_files(tmp_path / "scenes", 3, per_file=3)
    suite = tmp_path / "suite.json"
    suite.write_text(json.dumps(suite_doc(files)))
    read_whole = []
    monkeypatch.setattr(bench_spill.TrajectorySpill, "table",
                        lambda self: read_whole.append(1))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["bench", "run", "--suite", str(suite), "-o", str(tmp_path / "run"),
                     "--no-report", "--no-cache", "--workers", "1", "--no-progress"]) == 0
    assert not read_whole
    assert "report: none, --no-report" in capsys.readouterr().out
    folder = tmp_path / "run"
    assert not (folder / "report.html").exists() and not (folder / "viewer").exists()
    table = pd.read_parquet(folder / "trajectories.parquet")
    assert sorted(table["policy"].unique()) == ["idm", "log"]
    assert table.groupby("policy")["seed"].nunique().tolist() == [3, 3]
