"""What docs/contributing.md tells a new contributor to write works everywhere: the measure
and the data format, copied from the docs as written, named as plugins, go through a
2-worker ``bench run`` (and the same on Ray), ``bench check`` in a fresh process, the report
and the replay viewer, and show up in each."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import pandas as pd
import pytest

SUITE = {"name": "ext", "envs": ["merge"], "policies": ["idm", "idm-aggressive"],
         "seeds": "0-5", "reference_policy": "idm",
         "env_overrides": {"merge": {"duration": 3}},
         "bootstrap": {"n_resamples": 200, "level": 0.9},
         "gate": {"alpha": 0.5}}  # few seeds: a gate that can fire with 6 of them


def _suite(tmp_path: Path, **extra) -> Path:
    path = tmp_path / "ext.json"
    path.write_text(json.dumps({**SUITE, **extra}))
    return path


def _assert_everywhere(folder: Path, ext: dict) -> None:
    """The measure and the format show up in every table, the summary, the report (at the
    suite's 90 % level, never 95 %) and the viewer."""
    name = ext["measure"]
    episodes = pd.read_parquet(folder / "episodes.parquet")
    ok = episodes[episodes["status"] == "ok"]
    assert len(ok) == 12 and ok[name].notna().all(), "every episode measured by every worker"
    assert (ok[name] <= 0.5).all()  # the smallest acceleration of a 3 s drive
    measures = pd.read_parquet(folder / "measures.parquet")
    assert set(measures.loc[measures["measure"] == name, "policy"]) == {"idm", "idm-aggressive"}
    paired = pd.read_parquet(folder / "paired_measures.parquet")
    assert (paired["measure"] == name).any()
    power = pd.read_parquet(folder / "gate_power.parquet")
    assert (power["metric"] == name).any()
    coverage = pd.read_parquet(folder / "coverage.parquet")
    assert "my drives" in set(coverage["reference"]), "the format's files were read"
    summary = json.loads((folder / "summary.json").read_text())
    assert name in [m["name"] for m in summary["measures"]]
    assert set(ext["modules"]) <= set(summary["plugins"])
    assert summary["suite"]["gate"]["margins"][name] == 0.5
    html = (folder / "report.html").read_text()
    assert html.count("max decel") >= 4  # summary, per-env, paired and power tables
    assert "90 %" in html and "95 %" not in html
    index = (folder / "viewer" / "data" / "index.js").read_text()
    assert f'"name":"{name}"' in index and f'"{name}":' in index


def _check_in_a_fresh_process(folder: Path, tmp_path: Path) -> str:
    """``bench check`` with the run's plugins named (a run folder is data: the plugins it
    names are imported only when the user names them), in a fresh process; the gate checks
    the measure. The baseline it checks against is written in this process (the same
    command with ``--update-baseline``)."""
    from tap_bench.cli import main

    baseline = tmp_path / "baseline.json"
    args = ["--plugin", "tapext.measures", "--plugin", "tapext.my_formats", "bench", "check",
            str(folder), "--baseline", str(baseline)]
    assert main([*args, "--update-baseline"]) == 0
    assert baseline.is_file()
    checked = subprocess.run([sys.executable, "-m", "tap_bench", *args, "--all"],
                             capture_output=True, text=True, timeout=300)
    assert checked.returncode == 0, checked.stderr
    assert "max_decel" in checked.stdout
    return checked.stdout


def test_docs_examples_run_through_bench_run_check_report_and_viewer(extension, tmp_path):
    from tap_bench.cli import main

    suite = _suite(tmp_path)
    folder = tmp_path / "run"
    args = [a for m in extension["modules"] for a in ("--plugin", m)]
    code = main([*args, "bench", "run", "--suite", str(suite), "-o", str(folder),
                 "--workers", "2", "--no-cache", "--reference",
                 "my drives=" + ",".join(map(str, extension["drives"]))])
    assert code == 0
    _assert_everywhere(folder, extension)
    _check_in_a_fresh_process(folder, tmp_path)
    # the format is a --format choice of the command line once its plugin is named
    out = tmp_path / "drives.parquet"
    assert main(["ingest", "womd", *map(str, extension["drives"]), "-o", str(out),
                 "--format", "my-csv", "--plugin", "tapext.my_formats"]) == 0
    assert set(pd.read_parquet(out)["scenario_id"]) == {"a", "b"}


def test_a_suite_names_its_plugins_and_a_measure_without_one_is_refused(extension, tmp_path,
                                                                        capsys):
    """The plugins a suite names are loaded as those named with ``--plugin`` are: one
    worker, two seeds and no report here (a run's workers import the plugins their parent
    loaded, however named: the 2-worker run with its report is the test above)."""
    from tap_bench.cli import main

    folder = tmp_path / "run"
    suite = _suite(tmp_path, plugins=extension["modules"], seeds="0-1",
                   gate={"alpha": 0.5, "margins": {"max_decel": 0.25}})
    code = main(["bench", "run", "--suite", str(suite), "-o", str(folder), "--workers", "1",
                 "--no-cache", "--no-report"])
    assert code == 0
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["suite"]["gate"]["margins"]["max_decel"] == 0.25
    assert set(summary["plugins"]) >= set(extension["modules"])
    measured = pd.read_parquet(folder / "episodes.parquet")["max_decel"]
    assert len(measured) == 4 and measured.notna().all()
    bad = _suite(tmp_path, plugins=["tapext.no_such_module"])
    assert main(["bench", "run", "--suite", str(bad), "-o", str(tmp_path / "x")]) == 2
    assert "tapext.no_such_module" in capsys.readouterr().err


def test_docs_examples_on_the_ray_backend(extension, ray_backend, tmp_path):
    from tap_bench.bench.run.runner import run_suite

    folder = tmp_path / "run"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_suite(_suite(tmp_path), folder, backend=ray_backend, progress=False,
                  plugins=extension["modules"],
                  references={"my drives": [str(p) for p in extension["drives"]]})
    # the measure and the format in every table, as a local run writes them; bench check of
    # a run folder in a fresh process (two more processes) is the local test's, the folder
    # being the same files whatever backend made it
    _assert_everywhere(folder, extension)


@pytest.mark.parametrize("where", ["cli", "suite"])
def test_a_plugin_that_cannot_be_imported_is_a_clear_error(where, tmp_path, capsys):
    from tap_bench.cli import main

    if where == "cli":
        code = main(["--plugin", "no_such_plugin_module", "envs"])
    else:
        code = main(["bench", "run", "--suite", str(_suite(tmp_path,
                     plugins=["no_such_plugin_module"])), "-o", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code == 2 and "no_such_plugin_module" in err and "PYTHONPATH" in err
