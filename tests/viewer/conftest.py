"""Fixtures of the viewer and report tests: a short real run (rollouts, labels, scores,
report and viewer), the real WOMD samples, and helpers of the browser tests (the headless
Chromium itself, ``browser``, is the suite's: tests/conftest.py).

Screenshots go to ``$TAP_BENCH_SCREENSHOTS`` (default ``<tmp>/tap-bench-screenshots``) for a
person to look at.
"""

from __future__ import annotations

import os
import tempfile
import warnings
from pathlib import Path

import pytest

TINY_SUITE = {
    "name": "tiny", "version": 0,
    "description": "two envs x two policies x three seeds, 6 s episodes: fast browser tests",
    "envs": ["highway", "roundabout"], "policies": ["idm", "random"], "seeds": "0-2",
    "reference_policy": "idm", "level": "maneuver", "thresholds": "paper",
    "env_overrides": {"highway": {"duration": 6, "config": {"vehicles_count": 8}},
                      "roundabout": {"duration": 6}},
    "bootstrap": {"n_resamples": 200, "level": 0.95, "seed": 0},
}


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory) -> Path:
    """A finished run folder of :data:`TINY_SUITE` (report and viewer included)."""
    from tap_bench.bench.run.runner import run_suite
    from tap_bench.bench.suite import suite_from_dict

    suite = suite_from_dict(TINY_SUITE, source="TINY_SUITE")
    folder = tmp_path_factory.mktemp("viewer") / "tiny"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run_suite(suite, folder, workers=1, progress=False).folder


@pytest.fixture(scope="session")
def screenshots() -> Path:
    """Where the browser tests write their screenshots."""
    folder = Path(os.environ.get("TAP_BENCH_SCREENSHOTS",
                                 Path(tempfile.gettempdir()) / "tap-bench-screenshots"))
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def console_errors(driver) -> list[str]:
    """The browser console's errors since the last call (SEVERE entries)."""
    return [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE"]


def open_page(driver, path: Path, fragment: str = "") -> None:
    """Load a page from disk and wait until the viewer (if any) has opened its episode."""
    driver.get(path.resolve().as_uri() + fragment)
    driver.execute_async_script(
        "const done = arguments[arguments.length - 1];"
        "const wait = () => (typeof TAPVIEW === 'undefined') ? done(null) :"
        "  TAPVIEW.state.ready ? TAPVIEW.state.ready.then(() => done(true), e => done(String(e)))"
        "  : setTimeout(wait, 20);"
        "wait();")
