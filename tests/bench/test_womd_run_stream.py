"""``bench run`` on recorded scenes writes each episode's trajectories to disk as it ends
(:mod:`tap_bench.bench.run.spill`) and joins them afterwards: the run folder's tables equal
those of a run that holds every trajectory in memory, and nothing is left beside it."""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
import warnings
from pathlib import Path

import pandas as pd
import pytest

from tap_bench.bench.run import episodes, runner, scoring
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


def _script(path: Path) -> object:
    """The JSON a viewer data file hands to the page."""
    text = path.read_text(encoding="utf-8")
    found = re.fullmatch(r'TAPVIEW\.(?:chunk\("[^"]*",|index\()(.*)\);\n', text, re.S)
    assert found, path
    return json.loads(found[1])


def _same_folders(a: Path, b: Path) -> None:
    """``a`` (streamed) holds the tables, summary and viewer data of ``b`` (held in memory);
    ``a``'s viewer carries each recorded scene's map with its episodes, ``b``'s in its
    index."""
    tables = sorted(p.name for p in a.glob("*.parquet"))
    assert tables == sorted(p.name for p in b.glob("*.parquet"))
    assert {"trajectories.parquet", "labels.parquet", "segments.parquet",
            "roads.parquet"} <= set(tables)
    for name in tables:
        pd.testing.assert_frame_equal(pd.read_parquet(a / name), pd.read_parquet(b / name),
                                      obj=name)
    data = sorted(p.relative_to(a) for p in (a / "viewer").rglob("*")
                  if p.is_file() and p.suffix != ".html")
    assert data == sorted(p.relative_to(b) for p in (b / "viewer").rglob("*")
                          if p.is_file() and p.suffix != ".html")
    index_a, index_b = (_script(f / "viewer" / "data" / "index.js") for f in (a, b))
    map_of = {e["id"]: e["map"] for e in index_b["episodes"]}
    assert all(e.pop("map") is None for e in index_a["episodes"])
    for entry in index_b["episodes"]:
        entry.pop("map")
    assert index_a["episodes"] == index_b["episodes"]
    assert index_a["maps"] == {}  # recorded scenes only: their maps go with the episodes
    chunks = [rel for rel in data if rel.suffix == ".js" and rel.parent.name == "data"
              and rel.name != "index.js"]
    for rel in chunks:
        docs_a, docs_b = _script(a / rel), _script(b / rel)
        for doc in docs_b:
            doc["map"] = index_b["maps"][map_of[doc["id"]]]
        assert docs_a == docs_b, rel
        assert all(doc["map"] for doc in docs_a)
    assert len(chunks) > 1
    sa, sb = (json.loads((f / "summary.json").read_text()) for f in (a, b))
    for key in ("headline", "verdict", "n_episodes", "failed", "methods"):
        assert sa[key] == sb[key], key


def _whole_reads(monkeypatch) -> list[str]:
    """The spilled tables of every track and step (trajectories, labels, segments) read
    back as one table, named as it happens."""
    read_whole = []
    whole = bench_spill.SpilledTable.table

    def table(self, indices=None):
        if indices is None and self.name in ("trajectories", "labels", "segments"):
            read_whole.append(self.name)
        return whole(self, indices)

    monkeypatch.setattr(bench_spill.SpilledTable, "table", table)
    return read_whole


def test_a_womd_run_spills_its_tables_and_equals_one_held_in_memory(tmp_path, monkeypatch):
    files = scene_files(tmp_path / "scenes", 5, per_file=2, parked=20)
    suite = womd_suite(files)
    kept = []  # the spills made, to see what each held
    made = bench_spill.RunSpill

    def spill(output):
        kept.append(made(output))
        return kept[-1]

    monkeypatch.setattr(episodes, "RunSpill", spill)
    read_whole = _whole_reads(monkeypatch)
    gathered = []  # the task results as the run holds them until the scores
    tables_of = episodes.RunTables.of.__func__

    def of(cls, results, *args, **kwargs):
        gathered.extend(results)
        return tables_of(cls, results, *args, **kwargs)

    monkeypatch.setattr(episodes.RunTables, "of", classmethod(of))
    streamed = _run(suite, tmp_path / "streamed")
    # no table of an episode is held after it arrived, nor read back whole: the viewer
    # reads a chunk (one scene, every policy) at a time
    assert len(gathered) == 10 and not read_whole
    assert not [k for r in gathered for k, v in r.items() if isinstance(v, pd.DataFrame)]
    assert len(list((tmp_path / "streamed" / "viewer" / "data").glob("*.js"))) == 6
    monkeypatch.undo()
    monkeypatch.setattr(episodes, "RunSpill", spill)
    assert len(kept) == 1
    for name in ("trajectories", "labels", "segments", "episodes"):  # an episode a part
        assert len(kept[0].parts[name]) == 10, name
    assert not kept[0].folder.exists()  # removed when the run ended
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scenes", "streamed"]
    monkeypatch.setattr(episodes, "RunSpill", lambda output: None)  # held in memory
    held = _run(suite, tmp_path / "held")
    assert len(kept) == 1
    _same_folders(streamed, held)
    for name in ("trajectories", "labels", "segments"):
        assert len(pd.read_parquet(streamed / f"{name}.parquet")) == kept[0].rows[name]


def test_without_the_report_no_table_is_read_whole_and_progress_is_logged(
        tmp_path, monkeypatch, capsys):
    files = scene_files(tmp_path / "scenes", 3, per_file=3)
    suite = tmp_path / "suite.json"
    suite.write_text(json.dumps(suite_doc(files)))
    read_whole = _whole_reads(monkeypatch)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["bench", "run", "--suite", str(suite), "-o", str(tmp_path / "run"),
                     "--no-report", "--no-cache", "--workers", "1", "--no-progress",
                     "--log", str(tmp_path / "run.log")]) == 0
    assert not read_whole
    captured = capsys.readouterr()
    assert "report: none, --no-report" in captured.out
    assert "episodes" not in captured.err  # --no-progress: no lines on stderr
    last = (tmp_path / "run.log").read_text().splitlines()[-1]  # but in the log
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d bench womd-stream: 6/6 episodes, "
                        r"0 failed, 0 skipped, [\d.]+ episodes/s, .*", last), last
    folder = tmp_path / "run"
    assert not (folder / "report.html").exists() and not (folder / "viewer").exists()
    table = pd.read_parquet(folder / "trajectories.parquet")
    assert sorted(table["policy"].unique()) == ["idm", "log"]
    assert table.groupby("policy")["seed"].nunique().tolist() == [3, 3]


PROJECT_ROOT = HERE.parents[1]

# runs the command line and reports its peak resident memory (VmHWM: this process's own
# high-water mark, reset at exec)
CHILD = """
import json, sys
from tap_bench.cli import main
code = main(sys.argv[2:])
peak = [int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM')][0]
json.dump({"code": code, "peak_kb": peak}, open(sys.argv[1], "w"))
"""


@pytest.mark.slow
def test_peak_memory_does_not_grow_with_the_scenes(tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(PROJECT_ROOT), os.environ.get("PYTHONPATH", "")]), "OMP_WAIT_POLICY": "PASSIVE"}
    peaks = {}
    for n in (3, 15):
        files = scene_files(tmp_path / f"s{n}", n, per_file=5, parked=150)
        suite = tmp_path / f"suite{n}.json"
        suite.write_text(json.dumps(suite_doc(files)))
        report = tmp_path / f"m{n}.json"
        # in this process (one worker): the labelling and the report are the run's own
        proc = subprocess.run(
            [sys.executable, "-c", CHILD, str(report), "bench", "run", "--suite", str(suite),
             "-o", str(tmp_path / f"run{n}"), "--no-cache", "--workers", "1",
             "--no-progress"], env=env, capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr[-3000:]
        result = json.loads(report.read_text())
        assert result["code"] == 0, proc.stderr[-3000:]
        peaks[n] = result["peak_kb"]
        assert len(pd.read_parquet(tmp_path / f"run{n}" / "episodes.parquet")) == 2 * n
        assert (tmp_path / f"run{n}" / "viewer" / "index.html").is_file()
    # 12 more scenes of 13,832 rows and two policies: a run that held them would hold
    # their trajectories, labels of every track and viewer data (tens of MB more)
    assert peaks[15] <= 1.2 * peaks[3], peaks


def test_the_parts_of_a_killed_run_go_with_the_next_run_into_its_output(tmp_path):
    # the owner line a spill of a process now gone wrote (with its start: were its id given
    # to a new process meanwhile, that one started later)
    dead = subprocess.run([sys.executable, "-c", "import os; from tap_bench.bench.run.spill "
                           "import _owner; print(_owner(os.getpid()))"],
                          capture_output=True, text=True, check=True,
                          env={**os.environ, "PYTHONPATH": str(PROJECT_ROOT)})
    folders = {}
    for name, owner in (("dead", dead.stdout), ("live", f"{os.getppid()}\n"),
                        ("live-started", bench_spill._owner(os.getppid())),
                        ("unnamed", None)):
        folders[name] = tmp_path / f".run.episodes-{name}"
        folders[name].mkdir()
        (folders[name] / "part-00000000.parquet").write_bytes(b"")
        if owner is not None:
            (folders[name] / "owner").write_text(owner)
    other = tmp_path / ".other.episodes-dead"  # another output's
    other.mkdir()
    (other / "owner").write_text(dead.stdout)
    far = tmp_path / ".run.episodes-far"  # a run of another host on a shared file system
    far.mkdir()
    (far / "owner").write_text(f"{dead.stdout.split()[0]} {socket.gethostname()}-other\n")
    # a live process's id with another start: the id was given to it after the run's end
    reused = tmp_path / ".run.episodes-reused"
    reused.mkdir()
    (reused / "owner").write_text(f"{os.getppid()} {socket.gethostname()} 1\n")
    spill = bench_spill.RunSpill(tmp_path / "run")
    assert not folders["dead"].exists()  # its process is gone: a run killed outright
    assert folders["live"].exists() and folders["unnamed"].exists() and other.exists()
    assert folders["live-started"].exists() and far.exists()
    assert not reused.exists()
    started = bench_spill._started(os.getpid())
    assert started is not None  # Linux: /proc names each process's start
    assert (spill.folder / "owner").read_text() == \
        f"{os.getpid()} {socket.gethostname()} {started}\n"
    spill.close()
    assert not spill.folder.exists()


def test_a_run_matched_against_a_reference_reads_a_few_episodes_at_a_time(tmp_path,
                                                                          monkeypatch):
    files = scene_files(tmp_path / "scenes", 3, per_file=3)
    read_whole = _whole_reads(monkeypatch)
    monkeypatch.setattr(scoring, "EPISODES_AT_ONCE", 4)  # 6 episodes: two groups
    streamed = _run(womd_suite(files), tmp_path / "streamed", womd=files)
    assert not read_whole
    assert len(pd.read_parquet(streamed / "scenario_matches.parquet")) == 6 * 3
    assert (streamed / "gap.parquet").is_file()
    docs = [_script(p) for p in (streamed / "viewer" / "data").glob("*.js")
            if p.name != "index.js"]
    assert len(docs) == 3 and all(doc["map"] for chunk in docs for doc in chunk)
    monkeypatch.setattr(episodes, "RunSpill", lambda output: None)  # held in memory
    held = _run(womd_suite(files), tmp_path / "held", womd=files)
    _same_folders(streamed, held)


def test_an_episode_whose_estimate_probe_failed_stays_in_the_spilled_tables(tmp_path,
                                                                            monkeypatch):
    from tap_bench.bench.run import tasks as run_tasks

    files = scene_files(tmp_path / "scenes", 2, per_file=2)

    def broken(task):
        raise RuntimeError("the probe's simulation broke")

    monkeypatch.setattr(run_tasks, "_simulate", broken)  # the first episode, for the estimate
    said = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = runner.run_suite(womd_suite(files), tmp_path / "run", workers=1,
                                  progress=False, announce=said.append)
    assert any("timing a first episode" in line for line in said)
    episodes = pd.read_parquet(result.folder / "episodes.parquet")
    assert len(episodes) == 4
    failed = episodes[episodes["status"] != "ok"]
    assert len(failed) == 1 and "probe's simulation broke" in failed["error"].iat[0]


def test_a_log_asked_of_a_run_that_writes_none_is_said(tmp_path, monkeypatch):
    """A suite of synthetic scenarios shows a bar, not log lines: --log is not ignored
    silently."""
    from tap_bench.bench.run import episodes as run_episodes

    monkeypatch.setattr(run_episodes, "_run_all", lambda *args: ([], None))
    with pytest.warns(UserWarning, match="run.log: not written"):
        run_episodes._rollouts([], "highway-suite", None, False, None, None,
                               log=tmp_path / "run.log")
    assert not (tmp_path / "run.log").exists()


def test_the_index_of_a_run_of_some_scenes_holds_no_map_of_the_others(tmp_path):
    """Seeds 0-1 of a file of 3 scenes: the scene no episode drove has no map in the
    viewer's index (nor does any recorded scene: their maps go with their episodes)."""
    files = scene_files(tmp_path / "scenes", 3, per_file=3)
    doc = suite_doc(files)
    doc["seeds"] = "0-1"
    doc["policies"] = ["log"]
    folder = _run(suite_from_dict(doc, source="suite"), tmp_path / "run")
    index = _script(folder / "viewer" / "data" / "index.js")
    assert index["maps"] == {}
    assert len(index["episodes"]) == 2
