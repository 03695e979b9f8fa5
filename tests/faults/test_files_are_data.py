"""Files from others are data: a run folder's ``summary.json`` naming plugins makes ``bench
check`` import nothing (plugins load only when the user names them with ``--plugin``), and
``bench suites`` (a listing) imports no suite's plugins. Each command runs in a child
process from the folder that holds the module, as ``python -m`` puts it on the path."""

from __future__ import annotations

import contextlib
import io
import json
import uuid

from fault_helpers import label_table, run_process

from tap_bench.cli import main

EVIL = '''
import os
import pathlib

pathlib.Path(os.environ["TAP_TEST_MARKER"]).write_text("imported")
'''


def _run_folder(tmp_path):
    a, b = tmp_path / "a.parquet", tmp_path / "b.parquet"
    label_table("a", range(12)).to_parquet(a)
    label_table("b", range(12)).to_parquet(b)
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["compare", str(a), str(b), "-o", str(tmp_path / "run"), "--resamples",
                     "100"]) == 0
        assert main(["bench", "check", str(tmp_path / "run"), "--baseline",
                     str(tmp_path / "baseline.json"), "--update-baseline"]) == 0
    return tmp_path / "run"


def _evil(tmp_path, monkeypatch) -> tuple[str, object]:
    module = f"evilmod_{uuid.uuid4().hex[:8]}"
    (tmp_path / f"{module}.py").write_text(EVIL)
    marker = tmp_path / "imported.txt"
    monkeypatch.setenv("TAP_TEST_MARKER", str(marker))
    return module, marker


def test_bench_check_imports_no_plugin_a_run_folder_names(tmp_path, monkeypatch):
    run = _run_folder(tmp_path)
    module, marker = _evil(tmp_path, monkeypatch)
    summary = json.loads((run / "summary.json").read_text())
    summary["plugins"] = [module]
    (run / "summary.json").write_text(json.dumps(summary))
    result = run_process("bench", "check", run, "--baseline", tmp_path / "baseline.json",
                         cwd=tmp_path)
    assert not marker.exists(), f"bench check imported {module} from summary.json"
    assert result.returncode == 0, result.stderr.decode()
    assert module in result.stderr.decode() and "--plugin" in result.stderr.decode()
    # the JSON verdict and the module named by the user: in this process (about 1.3 CPU s
    # a child), with the working folder on the path as python -m puts it
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = main(["bench", "check", str(run), "--baseline", str(tmp_path / "baseline.json"),
                     "--format", "json"])
    assert not marker.exists(), f"bench check imported {module} from summary.json"
    assert code == 0 and module in err.getvalue() and "--plugin" in err.getvalue()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        code = main(["--plugin", module, "bench", "check", str(run), "--baseline",
                     str(tmp_path / "baseline.json")])
    assert code == 0 and marker.exists()  # named by the user, it is imported


def test_a_run_whose_measure_no_loaded_plugin_registers_says_the_fix(tmp_path, monkeypatch):
    run = _run_folder(tmp_path)
    module, marker = _evil(tmp_path, monkeypatch)
    summary = json.loads((run / "summary.json").read_text())
    summary["plugins"] = [module]
    summary["measures"] = [*summary.get("measures", []), {"name": "their_measure"}]
    (run / "summary.json").write_text(json.dumps(summary))
    result = run_process("bench", "check", run, "--baseline", tmp_path / "baseline.json",
                         cwd=tmp_path)
    err = result.stderr.decode()
    assert result.returncode == 2 and not marker.exists()
    assert "their_measure" in err and "--plugin" in err and "Traceback" not in err


def test_bench_suites_imports_no_suite_plugin(tmp_path, monkeypatch):
    module, marker = _evil(tmp_path, monkeypatch)
    (tmp_path / "cat" / "envs" / "suites").mkdir(parents=True)
    (tmp_path / "cat" / "envs" / "suites" / "theirs.json").write_text(json.dumps({
        "name": "theirs", "envs": ["merge"], "policies": ["idm"], "seeds": "0-3",
        "plugins": [module], "description": "a suite from someone else"}))
    monkeypatch.setenv("TAP_BENCH_PATH", str(tmp_path / "cat"))
    result = run_process("bench", "suites", cwd=tmp_path)
    out = result.stdout.decode()
    assert result.returncode == 0, result.stderr.decode()
    assert not marker.exists(), "bench suites imported a suite's plugin"
    assert "theirs" in out and "default" in out and module in out


def test_the_viewer_of_a_run_folder_imports_no_plugin_its_summary_names(tmp_path, monkeypatch):
    """``tap-bench view RUN`` of a run folder without its map table builds the roads again
    from the run's suite: the suite's plugins in its ``summary.json`` are not imported."""
    module, marker = _evil(tmp_path, monkeypatch)
    suite = tmp_path / "suite.json"
    suite.write_text(json.dumps({"name": "tiny", "envs": ["merge"], "policies": ["idm"],
                                 "seeds": "0", "reference_policy": "idm",
                                 "env_overrides": {"merge": {"duration": 2}},
                                 "bootstrap": {"n_resamples": 100}}))
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["bench", "run", "--suite", str(suite), "-o", str(tmp_path / "run"),
                     "--workers", "1", "--no-progress", "--no-cache"]) == 0
    run = tmp_path / "run"
    (run / "roads.parquet").unlink()
    summary = json.loads((run / "summary.json").read_text())
    summary["suite"]["plugins"] = [module]
    (run / "summary.json").write_text(json.dumps(summary))
    result = run_process("view", run, "--no-open", "--rebuild", cwd=tmp_path)
    assert result.returncode == 0, result.stderr.decode()[-2000:]
    assert not marker.exists(), "tap-bench view imported a plugin the run folder names"
    assert (run / "viewer" / "index.html").is_file()
