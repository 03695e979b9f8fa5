"""The split of ``tap_bench/bench/`` into sub-packages: old module paths are refused with the
new path, the package's own names and the former modules' names still resolve."""

from __future__ import annotations

import importlib
import re
import subprocess
import sys

import pytest

import tap_bench.bench as bench


@pytest.mark.parametrize("old", sorted(bench.MOVED))
def test_every_moved_path_is_refused_with_its_new_path(old: str) -> None:
    new = bench.MOVED[old]
    importlib.import_module(new)  # the new path exists
    with pytest.raises(ModuleNotFoundError, match=re.escape(f"{old} moved to {new}")):
        importlib.import_module(old)


def test_a_module_under_a_moved_package_is_refused_with_the_package_s_new_path() -> None:
    with pytest.raises(ModuleNotFoundError,
                       match=re.escape("tap_bench.bench.viewer moved to "
                                       "tap_bench.bench.report.viewer")):
        importlib.import_module("tap_bench.bench.viewer.build")


def test_from_import_of_a_moved_module_names_the_new_path() -> None:
    code = "from tap_bench.bench.runner import run_suite"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode != 0
    assert "tap_bench.bench.run.runner" in done.stderr


def test_the_package_names_are_the_functions_not_modules() -> None:
    from tap_bench.bench import check, coverage, novelty, run_suite
    from tap_bench.bench.gate.regression import check as gate_check
    from tap_bench.bench.run.runner import run_suite as runner_run_suite
    from tap_bench.bench.scores.coverage import coverage as coverage_function
    from tap_bench.bench.scores.novelty import novelty as novelty_function
    assert check is gate_check and run_suite is runner_run_suite
    assert coverage is coverage_function and novelty is novelty_function


def test_the_former_gate_and_report_modules_names_still_resolve() -> None:
    from tap_bench.bench.gate import GateResult, check, regression, write_baseline
    from tap_bench.bench.report import page, write_report
    assert (GateResult, check, write_baseline) == (
        regression.GateResult, regression.check, regression.write_baseline)
    assert write_report is page.write_report
    with pytest.raises(ImportError):
        from tap_bench.bench.gate import no_such_name  # noqa: F401


def test_a_name_moved_between_modules_is_refused_with_its_new_module() -> None:
    from tap_bench.bench.report import figures, page
    with pytest.raises(ImportError, match=re.escape(
            "write_plots moved from tap_bench.bench.report.figures to "
            "tap_bench.bench.report.page")):
        from tap_bench.bench.report.figures import write_plots  # noqa: F401
    assert callable(page.write_plots) and "write_plots" in figures.MOVED_NAMES
    with pytest.raises(AttributeError):
        figures.no_such_name  # noqa: B018


def test_no_module_of_bench_is_left_at_an_old_path() -> None:
    import pkgutil
    names = {m.name for m in pkgutil.iter_modules(bench.__path__, "tap_bench.bench.")}
    assert names == {"tap_bench.bench.cache", "tap_bench.bench.episodes",
                     "tap_bench.bench.measures", "tap_bench.bench.suite",
                     "tap_bench.bench.gate", "tap_bench.bench.report",
                     "tap_bench.bench.run", "tap_bench.bench.scores"}
    assert not names & set(bench.MOVED)
