"""Nothing lost, nothing deleted: outputs replace only what tap-bench wrote, never an input,
fail before the work when their place is not writable, and land together or not at all."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from fault_helpers import label_table

from tap_bench import tableio
from tap_bench.bench.run.runner import RunExistsError, check_output
from tap_bench.errors import OutputPathError
from tap_bench.tableio import (
    FOLDER_MARKER,
    atomic_folder,
    atomic_paths,
    check_outputs,
    write_tables,
)

IS_ROOT = os.geteuid() == 0


@pytest.fixture
def two_policies(tmp_path):
    a = tmp_path / "a.parquet"
    b = tmp_path / "b.parquet"
    label_table("a", range(6)).to_parquet(a)
    label_table("b", range(6), lambda s: "Straight | Accelerate" if s % 2 else
                "Straight | Maintain Speed").to_parquet(b)
    return a, b


def snapshot(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*")
            if p.is_file()}


# -- folders: only what tap-bench wrote is replaced ----------------------------------------
def test_demo_and_compare_never_delete_a_folder_tap_bench_did_not_write(tmp_path, cli,
                                                                       two_policies):
    """`tap-bench demo -o my_thesis` once deleted my_thesis/chapter1.tex."""
    thesis = tmp_path / "my_thesis"
    thesis.mkdir()
    (thesis / "chapter1.tex").write_text("\\chapter{One}")
    before = snapshot(thesis)
    code, _, err = cli("demo", "-o", thesis, "--workers", "1")
    assert code == 2 and "was not written by tap-bench" in err and str(thesis) in err
    assert "Traceback" not in err
    a, b = two_policies
    code, _, err = cli("compare", a, b, "-o", thesis, "--overwrite", "--resamples", "100")
    assert code == 2 and "never replaced" in err and "remove it yourself" in err
    code, _, err = cli("bench", "run", "-o", thesis, "--overwrite", "--workers", "1")
    assert code == 2 and f"{FOLDER_MARKER}" in err
    assert snapshot(thesis) == before


def test_overwrite_replaces_a_folder_tap_bench_wrote_and_only_with_the_flag(tmp_path, cli,
                                                                           two_policies):
    a, b = two_policies
    out = tmp_path / "cmp"
    assert cli("compare", a, b, "-o", out, "--resamples", "100")[0] == 0
    assert (out / FOLDER_MARKER).is_file()
    first = (out / "summary.json").read_bytes()
    code, _, err = cli("compare", a, b, "-o", out, "--resamples", "100")
    assert code == 2 and "--overwrite" in err
    assert (out / "summary.json").read_bytes() == first
    (out / "summary.json").write_text("{}")  # tell the new one from the old
    assert cli("compare", a, b, "-o", out, "--resamples", "100", "--overwrite")[0] == 0
    assert (out / "summary.json").read_text() != "{}"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize("kind", ["file", "symlink to a run", "symlink to nothing"])
def test_overwrite_onto_a_file_or_a_symlink_is_a_message_not_a_traceback(tmp_path, cli,
                                                                        two_policies, kind):
    a, b = two_policies
    run = tmp_path / "run"
    assert cli("compare", a, b, "-o", run, "--resamples", "100")[0] == 0
    target = tmp_path / "target"
    if kind == "file":
        target.write_text("precious")
    elif kind == "symlink to a run":
        target.symlink_to(run)
    else:
        target.symlink_to(tmp_path / "nowhere")
    code, _, err = cli("compare", a, b, "-o", target, "--overwrite", "--resamples", "100")
    assert code == 2 and "Traceback" not in err and str(target) in err
    assert ("is a file" in err) if kind == "file" else ("symbolic link" in err)
    assert target.is_symlink() == (kind != "file")
    if kind == "file":
        assert target.read_text() == "precious"
    assert (run / FOLDER_MARKER).is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["a.parquet", "b.parquet", "run", "target"])  # no .old, no .tmp


def test_run_folders_have_the_usual_modes(tmp_path, cli, two_policies):
    """Folders were 0700 (from mkdtemp) while their files were 0644."""
    a, b = two_policies
    old = os.umask(0o022)
    try:
        assert cli("compare", a, b, "-o", tmp_path / "run", "--resamples", "100")[0] == 0
    finally:
        os.umask(old)
    mode = stat.S_IMODE((tmp_path / "run").stat().st_mode)
    assert mode == 0o755
    assert stat.S_IMODE((tmp_path / "run" / "plots").stat().st_mode) == 0o755
    assert stat.S_IMODE((tmp_path / "run" / "summary.json").stat().st_mode) == 0o644


def test_a_failure_inside_the_folder_leaves_the_old_run_and_no_debris(tmp_path):
    out = tmp_path / "run"
    with atomic_folder(out) as tmp:
        (tmp / "x.txt").write_text("first")
    with pytest.raises(RuntimeError, match="disk full"), atomic_folder(out, True) as tmp:
        (tmp / "x.txt").write_text("second")
        raise RuntimeError("disk full")
    assert (out / "x.txt").read_text() == "first"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    with pytest.raises(RunExistsError):
        check_output(out, overwrite=False)


def test_a_run_removes_the_folders_killed_runs_left_and_nothing_else(tmp_path):
    from tap_bench.bench.run.runner import run_suite
    from tap_bench.bench.suite import suite_from_dict

    out = tmp_path / "run"
    # a run killed while it wrote its folder (the process ends inside atomic_folder)
    killed = subprocess.run(
        [sys.executable, "-c", "import os, sys; from tap_bench.tableio import atomic_folder\n"
         "with atomic_folder(sys.argv[1], kind='run') as tmp:\n"
         "    (tmp / 'episodes.parquet').write_bytes(b'half')\n    os._exit(9)", str(out)],
        cwd=Path(tableio.__file__).parents[1])
    assert killed.returncode == 9
    (dead,) = tmp_path.glob(".run.*.tmp")
    live = tmp_path / ".run.live.tmp"  # a run writing it now
    live.mkdir()
    (live / tableio.OWNER_FILE).write_text(tableio.owner_line(os.getpid()) + "\n")
    foreign = tmp_path / ".run.mine.tmp"  # tap-bench's naming, but not its folder
    foreign.mkdir()
    (foreign / "notes.txt").write_text("precious\n")
    said = []
    suite = suite_from_dict({"name": "tiny", "envs": ["merge"], "policies": ["idm"],
                             "seeds": "0", "env_overrides": {"merge": {"duration": 1}}},
                            check_names=False)
    run_suite(suite, out, workers=1, progress=False, report=False,
              keep_trajectories=False, announce=said.append)
    assert not dead.exists()
    assert live.is_dir() and (foreign / "notes.txt").read_text() == "precious\n"
    assert [line for line in said if "killed runs" in line] == [
        f"removed 1 folder(s) that killed runs left beside {out}: {dead.name}"]
    assert not list(out.rglob(tableio.OWNER_FILE))  # the finished folder does not name it
    for folder in (live, foreign):  # this test's own, not debris of the run
        shutil.rmtree(folder)


# -- outputs that are inputs ------------------------------------------------------------
@pytest.fixture
def trajectories(tmp_path, cli):
    path = tmp_path / "same.parquet"
    assert cli("sample", "-o", path)[0] == 0
    return path


@pytest.mark.parametrize("flag", ["-o", "--segments", "--steps", "--report"])
def test_label_refuses_to_write_over_its_input(tmp_path, cli, trajectories, flag):
    before = trajectories.read_bytes()
    other = {"-o": [], "--segments": ["-o", tmp_path / "l.csv"],
             "--steps": ["-o", tmp_path / "l.csv"], "--report": ["-o", tmp_path / "l.csv"]}
    code, _, err = cli("label", trajectories, *other[flag], flag,
                       tmp_path / "." / "same.parquet")
    assert code == 2 and "is also an input" in err
    assert trajectories.read_bytes() == before
    assert not (tmp_path / "l.csv").exists()


def test_an_input_reached_through_a_link_is_still_the_input(tmp_path, cli, trajectories):
    link = tmp_path / "link.parquet"
    link.symlink_to(trajectories)
    code, _, err = cli("label", trajectories, "-o", link)
    assert code == 2 and "is also an input" in err
    code, _, err = cli("fit", trajectories, "-o", link)
    assert code == 2 and "is also an input" in err


def test_two_outputs_on_one_path_are_refused(tmp_path, cli, trajectories):
    code, _, err = cli("label", trajectories, "-o", tmp_path / "x.csv", "--segments",
                       tmp_path / "x.csv")
    assert code == 2 and "two outputs" in err


def test_ingest_refuses_an_output_that_is_an_input(tmp_path):
    from tap_bench.sources.ingest import ingest_womd

    path = tmp_path / "odd.parquet"
    path.write_bytes(b"\x00" * 20)
    with pytest.raises(OutputPathError, match="is also an input"):
        ingest_womd(path, path)
    assert path.read_bytes() == b"\x00" * 20


# -- unwritable places fail first; several outputs land together ------------------------
def test_an_output_under_a_file_fails_before_the_work(tmp_path, cli, trajectories,
                                                      monkeypatch):
    (tmp_path / "afile").write_text("x")
    calls = []
    import tap_bench.cli.label as label_cli

    monkeypatch.setattr(label_cli, "tap_in_parts", lambda *a, **k: calls.append(1))
    code, _, err = cli("label", trajectories, "-o", tmp_path / "ok.csv", "--segments",
                       tmp_path / "afile" / "s.csv")
    assert code == 2 and "afile is a file" in err and not calls
    assert not (tmp_path / "ok.csv").exists()


def test_bench_run_into_an_unwritable_place_fails_before_any_rollout(tmp_path, cli,
                                                                    monkeypatch):
    """`bench run -o ro/run` once failed with a traceback after 9 s of rollouts."""
    import tap_bench.bench.run.episodes as episodes

    monkeypatch.setattr(episodes, "_rollouts", lambda *a, **k: pytest.fail("rolled out"))
    (tmp_path / "afile").write_text("x")
    code, _, err = cli("bench", "run", "--suite", "demo", "-o", tmp_path / "afile" / "run",
                       "--workers", "1")
    assert code == 2 and "is a file, not a folder" in err


@pytest.mark.skipif(IS_ROOT, reason="root writes into read-only folders")
def test_a_read_only_folder_fails_before_the_work(tmp_path, cli, trajectories):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        code, _, err = cli("label", trajectories, "-o", tmp_path / "ok.csv", "--segments",
                           ro / "s.csv")
        assert code == 2 and "permission denied" in err
        assert not (tmp_path / "ok.csv").exists()
    finally:
        ro.chmod(0o755)


def test_several_outputs_land_together_or_not_at_all(tmp_path, monkeypatch):
    """A failure while writing the second output (a full disk) leaves the first as it
    was; a failure while renaming the second puts the first back."""
    first, second = tmp_path / "a.csv", tmp_path / "b.csv"
    first.write_text("old a\n")
    table = pd.DataFrame({"x": [1, 2]})
    calls = {"n": 0}
    real = tableio._write

    def full_disk(t, tmp, path):
        calls["n"] += 1
        if calls["n"] == 2:
            raise OSError(28, "No space left on device")
        real(t, tmp, path)

    monkeypatch.setattr(tableio, "_write", full_disk)
    with pytest.raises(OSError, match="No space"):
        write_tables({first: table, second: table})
    assert first.read_text() == "old a\n" and not second.exists()
    monkeypatch.setattr(tableio, "_write", real)

    real_replace = os.replace

    def second_rename_fails(src, dst):
        if str(dst) == str(second):
            raise OSError(5, "Input/output error")
        return real_replace(src, dst)

    monkeypatch.setattr(tableio.os, "replace", second_rename_fails)
    with pytest.raises(OSError, match="Input/output"):
        write_tables({first: table, second: table})
    monkeypatch.setattr(tableio.os, "replace", real_replace)
    assert first.read_text() == "old a\n" and not second.exists()
    write_tables({first: table, second: table})
    assert pd.read_csv(first)["x"].tolist() == [1, 2] == pd.read_csv(second)["x"].tolist()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "b.csv"]


def test_atomic_paths_make_their_files_before_the_work(tmp_path):
    (tmp_path / "afile").write_text("x")
    with pytest.raises(OutputPathError, match="in the way"), \
            atomic_paths([tmp_path / "ok.txt", tmp_path / "afile" / "no.txt"]):
        pytest.fail("the work ran")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]
    assert check_outputs([None, tmp_path / "new" / "deep" / "x.csv"]) == [
        tmp_path / "new" / "deep" / "x.csv"]
    assert not (tmp_path / "new").exists()  # checking creates nothing


def test_rollout_outputs_are_checked_before_the_rollouts(tmp_path, cli, monkeypatch):
    import importlib

    rollout_module = importlib.import_module("tap_bench.sim.rollout")
    monkeypatch.setattr(rollout_module, "rollout", lambda *a, **k: pytest.fail("rolled"))
    (tmp_path / "afile").write_text("x")
    code, _, err = cli("rollout", "--env", "highway", "--policy", "idm", "--seeds", "0",
                       "-o", tmp_path / "t.parquet", "--episodes", tmp_path / "afile" / "e.csv")
    assert code == 2 and "afile is a file" in err


def test_coverage_and_unique_outputs_land_together(tmp_path, cli, two_policies):
    a, b = two_policies
    code, _, err = cli("unique", a, "-o", tmp_path / "u.csv", "--counts", a)
    assert code == 2 and "is also an input" in err
    code, _, _ = cli("unique", a, "--level", "maneuver", "-o", tmp_path / "u.csv", "--counts",
                     tmp_path / "c.csv")
    assert code == 0 and (tmp_path / "u.csv").is_file() and (tmp_path / "c.csv").is_file()
    code, _, err = cli("coverage", a, "--reference", b, "-o", b, "--resamples", "100")
    assert code == 2 and "is also an input" in err
    assert np.array_equal(pd.read_parquet(b)["seed"], np.arange(6))


def test_the_viewer_never_deletes_a_folder_it_did_not_write(tmp_path):
    """`tap-bench view … -o FOLDER` removed FOLDER/data before writing."""
    from tap_bench.bench.report.viewer import write_viewer

    mine = tmp_path / "project"
    (mine / "data").mkdir(parents=True)
    (mine / "data" / "results.csv").write_text("precious\n")
    with pytest.raises(OutputPathError, match="was not written by tap-bench"):
        write_viewer(mine, {"episodes": [], "maps": {}, "run": {}}, {})
    assert (mine / "data" / "results.csv").read_text() == "precious\n"
    viewer = tmp_path / "viewer"
    for _ in range(2):  # a viewer tap-bench wrote is replaced
        page = write_viewer(viewer, {"episodes": [], "maps": {}, "run": {}}, {"c0": []})
        assert page.is_file() and (viewer / "data" / "c0.js").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["project", "viewer"]
