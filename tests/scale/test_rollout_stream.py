"""``tap-bench rollout`` streams each scene's rows to disk: the tables equal an in-memory
rollout's, a killed run resumes to the same files bit for bit and says how many scenes it
had done, and peak memory does not grow with the number of scenes (measured in a fresh
subprocess)."""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys
import warnings
from pathlib import Path

import pandas as pd
import pytest
from kill_points import run_killed
from scale_scenes import scene_files

from tap_bench.cli import main
from tap_bench.errors import OutputPathError
from tap_bench.sim import rollout_stream
from tap_bench.sim.rollout import rollout
from tap_bench.sim.womd_scene import WomdScenes

PROJECT_ROOT = Path(__file__).resolve().parents[2]

# a child that runs the command line with parts of one scene each and reports its peak
# resident memory (VmHWM: this process's own high-water mark, reset at exec)
CHILD = """
import json, sys
from tap_bench.sim import rollout_stream
rollout_stream.PART_SCENES = int(sys.argv[2])
from tap_bench.cli import main
code = main(sys.argv[3:])
peak = [int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM')][0]
json.dump({"code": code, "peak_kb": peak}, open(sys.argv[1], "w"))
"""


def child(args: list[str], report: Path, part_scenes: int = 1) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(PROJECT_ROOT), os.environ.get("PYTHONPATH", "")]), "OMP_WAIT_POLICY": "PASSIVE"}
    return subprocess.Popen([sys.executable, "-c", CHILD, str(report), str(part_scenes),
                             *args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def rollout_args(files: list[str], out: Path, *more: str) -> list[str]:
    return ["rollout", "--womd", *files, "--policy", "idm", "-o", str(out), "--no-progress",
            *more]


def test_the_streamed_tables_equal_an_in_memory_rollout(tmp_path, monkeypatch):
    files = scene_files(tmp_path / "scenes", 7, per_file=3)
    monkeypatch.setattr(rollout_stream, "PART_SCENES", 2)
    monkeypatch.setattr(rollout_stream, "ROW_GROUP_ROWS", 1000)  # several row groups
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(rollout_args(files, tmp_path / "out.parquet")) == 0
        trajectories, episodes = rollout(WomdScenes(tuple(files)), "idm", "all",
                                         progress=False)
    from tap_bench.tableio import write_tables

    write_tables({tmp_path / "mem.parquet": trajectories,
                  tmp_path / "mem.episodes.parquet": episodes})
    for name in ("out.parquet", "out.episodes.parquet"):
        pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / name),
                                      pd.read_parquet(tmp_path / name.replace("out", "mem")))
    import pyarrow.parquet as pq

    assert pq.ParquetFile(tmp_path / "out.parquet").metadata.num_row_groups > 1
    assert not rollout_stream.parts_folder(tmp_path / "out.parquet").exists()
    assert set(pd.read_parquet(tmp_path / "out.parquet")["seed"]) == set(range(7))


def _scenes_in(parts: Path) -> int:
    return sum(len(p.read_text().splitlines()) for p in parts.glob("part-*.episodes.jsonl"))


def test_a_killed_run_resumes_to_the_same_files(tmp_path, monkeypatch, capsys):
    """Killed (SIGKILL) at a point of every state a run leaves on disk: in its start-up
    (run.json half written), after a drawn number of scenes' parts with the next part half
    written, and while the output is written. Each resumed run says how many scenes were
    done and writes the files of a run never interrupted, bit for bit (the same code). The
    kills come by progress (kill_points), so every run is killed mid-way on any machine;
    the uninterrupted run and the resumed ones run in this process."""
    files = scene_files(tmp_path / "scenes", 8, per_file=3)
    whole = tmp_path / "whole.parquet"
    monkeypatch.setattr(rollout_stream, "PART_SCENES", 1)  # as the killed children have it
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(rollout_args(files, whole)) == 0
    expected = [whole.read_bytes(), whole.with_name("whole.episodes.parquet").read_bytes()]
    torn = random.Random(37).randint(1, 7)
    # (killed before this call of tableio._commit, the scenes done then): a run commits
    # run.json, then one part per scene (PART_SCENES = 1), then the output
    points = [(1, 0), (2 + torn, torn), (10, 8)]
    setup = "from tap_bench.sim import rollout_stream; rollout_stream.PART_SCENES = 1"
    for trial, (n, done) in enumerate(points):
        out = tmp_path / f"t{trial}" / "out.parquet"
        parts = rollout_stream.parts_folder(out)
        run_killed(rollout_args(files, out), "tap_bench.tableio:_commit", "before", n, setup)
        assert not out.exists() and _scenes_in(parts) == done, (trial, _scenes_in(parts))
        capsys.readouterr()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            assert main(rollout_args(files, out, "--resume")) == 0
        stdout = capsys.readouterr().out
        if done:
            assert f"resumed: {done} of 8 scenes were done before" in stdout
        else:
            assert "resumed" not in stdout
        assert out.read_bytes() == expected[0]
        assert out.with_name("out.episodes.parquet").read_bytes() == expected[1]
        assert not parts.exists()


def test_parts_are_arrow_files_and_parquet_parts_of_earlier_versions_resume(tmp_path,
                                                                            monkeypatch):
    """A part's rows are an Arrow IPC file (text dictionary-encoded) that reads back as the
    table pandas' Parquet writer made; a run resumed from Parquet parts (as earlier
    versions wrote them) joins them into the same files, bit for bit."""
    import pyarrow as pa
    import pyarrow.feather as feather

    files = scene_files(tmp_path / "scenes", 3, per_file=3)
    monkeypatch.setattr(rollout_stream, "PART_SCENES", 1)
    whole, out = tmp_path / "whole.parquet", tmp_path / "out.parquet"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(rollout_args(files, whole)) == 0
        monkeypatch.setattr(rollout_stream._Parts, "remove", lambda self: None)
        assert main(rollout_args(files, out)) == 0  # its parts left behind
        monkeypatch.undo()
        monkeypatch.setattr(rollout_stream, "PART_SCENES", 1)
        parts = rollout_stream.parts_folder(out)
        arrows = sorted(parts.glob("part-*.arrow"))
        assert len(arrows) == 3 and not list(parts.glob("part-*.parquet"))
        dtypes = pd.read_parquet(whole).dtypes
        for path in arrows:
            assert pa.types.is_dictionary(feather.read_table(path).schema.field(
                "scenario_id").type)
            frame = pa.Table.from_batches(list(rollout_stream._part_batches(path))).to_pandas()
            assert frame.dtypes.equals(dtypes)
            frame.to_parquet(path.with_suffix(".parquet"), index=False)  # as before
            path.unlink()
        out.unlink()
        out.with_name("out.episodes.parquet").unlink()
        assert main(rollout_args(files, out, "--resume")) == 0
    assert out.read_bytes() == whole.read_bytes()
    assert not parts.exists()


def test_parts_are_refused_without_resume_and_from_another_run(tmp_path):
    files = scene_files(tmp_path / "scenes", 3, per_file=3)
    out = tmp_path / "out.parquet"
    parts = rollout_stream.parts_folder(out)
    parts.mkdir()
    (parts / "run.json").write_text(json.dumps({"scenario": "another", "policy": "",
                                                "seeds": [], "record": True}))
    with pytest.raises(OutputPathError, match="--resume"):
        rollout_stream.stream_rollout(WomdScenes(tuple(files)), "idm", "all", out,
                                      progress=False)
    with pytest.raises(OutputPathError, match="another run"):
        rollout_stream.stream_rollout(WomdScenes(tuple(files)), "idm", "all", out,
                                      progress=False, resume=True)
    assert not out.exists()


def test_an_output_without_a_table_suffix_is_refused_before_any_scene_runs(tmp_path,
                                                                             monkeypatch):
    from tap_bench.errors import FileFormatError

    files = scene_files(tmp_path / "scenes", 1, per_file=2)
    ran = []
    monkeypatch.setattr(rollout_stream, "episode_tasks",
                        lambda *a, **k: ran.append(1) or [])
    for out, episodes in ((tmp_path / "out", None), (tmp_path / "out.parquet",
                                                     tmp_path / "episodes.txt")):
        with pytest.raises(FileFormatError, match="unknown table format"):
            rollout_stream.stream_rollout(WomdScenes(tuple(files)), "idm", "all", out,
                                          episodes_output=episodes, progress=False)
    assert not ran and not list(tmp_path.glob("out*"))


def test_ego_only_keeps_the_egos_rows_of_the_full_table(tmp_path, monkeypatch):
    files = scene_files(tmp_path / "scenes", 5, per_file=3)
    monkeypatch.setattr(rollout_stream, "PART_SCENES", 2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(rollout_args(files, tmp_path / "all.parquet")) == 0
        assert main(rollout_args(files, tmp_path / "ego.parquet", "--ego-only")) == 0
    every = pd.read_parquet(tmp_path / "all.parquet")
    ego = pd.read_parquet(tmp_path / "ego.parquet")
    assert ego["is_ego"].all() and len(ego) < len(every)
    pd.testing.assert_frame_equal(ego, every[every["is_ego"]].reset_index(drop=True))
    assert sorted(ego["seed"].unique()) == list(range(5))  # one ego per scene
    assert ego.groupby("seed")["track_id"].nunique().eq(1).all()
    pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "ego.episodes.parquet"),
                                  pd.read_parquet(tmp_path / "all.episodes.parquet"))
    # the parts of a run of every agent are not resumed as an ego-only run
    out = tmp_path / "mixed.parquet"
    parts = rollout_stream.parts_folder(out)
    parts.mkdir()
    (parts / "run.json").write_text(json.dumps(rollout_stream._identity(
        WomdScenes(tuple(files)), rollout_stream.resolve_policy("idm"), list(range(5)),
        True)))
    with pytest.raises(OutputPathError, match="ego_only"):
        rollout_stream.stream_rollout(WomdScenes(tuple(files)), "idm", "all", out,
                                      progress=False, resume=True, ego_only=True)


def test_progress_lines_count_scenes_and_go_to_the_log(tmp_path, capsys, monkeypatch):
    from tap_bench import progress

    files = scene_files(tmp_path / "scenes", 3, per_file=3)
    monkeypatch.setattr(progress, "LINE_EVERY", 0.01)
    log = tmp_path / "run.log"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["rollout", "--womd", *files, "--policy", "idm", "-o",
                     str(tmp_path / "o.parquet"), "--log", str(log)]) == 0
    err = capsys.readouterr().err
    last = log.read_text().splitlines()[-1]
    assert last.endswith(err.strip().splitlines()[-1])  # the same lines, time-stamped
    assert "womd idm: 3/3 scenes, 0 failed, 0 skipped" in last
    assert len(log.read_text().splitlines()) >= 2  # lines while it ran, then the last


@pytest.mark.slow
def test_peak_memory_does_not_grow_with_the_scenes(tmp_path):
    # measured from 40 scenes: the process's resident memory grows for its first ~50
    # scenes whatever the rows kept (4, 8, 16, 40, 80 scenes: 303, 312, 330, 371, 387 MB),
    # as the allocator keeps freed blocks (malloc_trim returns ~100 MB at the end) and the
    # cyclic garbage of each scene's road waits for a full collection; 4 -> 40 gave 1.22x
    peaks = {}
    for n in (40, 80):
        files = scene_files(tmp_path / f"s{n}", n, per_file=8, parked=150)
        report = tmp_path / f"m{n}.json"
        proc = child([*rollout_args(files, tmp_path / f"o{n}.parquet"), "--policy", "log"],
                     report, part_scenes=4)
        assert proc.wait() == 0, proc.stderr.read()
        peaks[n] = json.loads(report.read_text())["peak_kb"]
        assert len(pd.read_parquet(tmp_path / f"o{n}.episodes.parquet")) == n
    # 40 more scenes of 13,832 rows: an in-memory run holds ~2.5 MB more each
    assert peaks[80] <= 1.2 * peaks[40], peaks


def test_a_progress_line_counts_this_runs_scenes_for_the_rate(tmp_path):
    import re

    from tap_bench.progress import SceneProgress

    log = tmp_path / "p.log"
    bar = SceneProgress(10, "womd idm", before=4, show=False, log=str(log), every=1000)
    bar._start -= 2.0  # two seconds into the run
    for status in ("ok", "error", "skipped"):
        bar.update(status)
    line = bar.line()
    found = re.fullmatch(r"womd idm: 7/10 scenes \(4 before\), 1 failed, 1 skipped, "
                         r"([\d.]+) scenes/s, about (\d+) s left", line)
    assert found, line
    assert 1.4 <= float(found[1]) <= 1.5  # 3 scenes in 2 s, not 7
    assert 1 <= int(found[2]) <= 3  # 3 scenes left at that rate
    bar.close()
    last = log.read_text().splitlines()[-1]  # time-stamped in the log
    assert re.match(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d womd idm: 7/10 scenes \(4 before\)", last)
