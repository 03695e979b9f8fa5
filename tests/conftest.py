"""Every test session gets its own tap-bench cache folder (episodes of ``bench run``,
highway-env's defaults): runs in one session never reuse episodes another session, or the
developer's own runs, left in ``~/.cache/tap-bench``."""

from __future__ import annotations

import os
import shutil
import tempfile

_CACHE = tempfile.mkdtemp(prefix="tap-bench-test-cache-")


def pytest_configure(config) -> None:
    os.environ["TAP_BENCH_CACHE"] = _CACHE


def pytest_unconfigure(config) -> None:
    shutil.rmtree(_CACHE, ignore_errors=True)
