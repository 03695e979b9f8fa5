"""Fixtures of the fault-injection suite: every test is checked for orphan processes and for
temporary debris, and runs the command line in this process (``cli``) or in a child
(``cli_process``) the way a user would."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from tap_bench.cli import main

PROJECT_ROOT = Path(__file__).resolve().parents[2]
WOMD_DIR = (PROJECT_ROOT / ".." / "shared" / "data" / "womd").resolve()
DEBRIS = (".tmp", ".old", ".bak")
"""Name endings of tap-bench's temporary files and folders."""


def _children(pid: int) -> set[int]:
    """Every live descendant of ``pid`` (from /proc; empty where there is none)."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").glob("[0-9]*"):
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[-1].split()
        if fields and fields[0] != "Z":  # zombies are reaped by their parent
            parents[int(entry.name)] = int(fields[1])
    found, todo = set(), [pid]
    while todo:
        p = todo.pop()
        for child, parent in parents.items():
            if parent == p and child not in found:
                found.add(child)
                todo.append(child)
    return found


def _debris(folder: Path) -> set[str]:
    if not folder.is_dir():
        return set()
    out = set()
    for p in folder.rglob("*"):
        if p.name.startswith(".") and p.name.endswith(DEBRIS):
            out.add(str(p))
    return out


def _shared_temp() -> set[str]:
    names = set()
    for folder in (Path(tempfile.gettempdir()), Path("/dev/shm")):
        if folder.is_dir():
            names |= {str(p) for p in folder.glob("tap-bench-*")}
    return names


@pytest.fixture(autouse=True)
def no_orphans_and_no_debris(tmp_path):
    """After each test: no process left behind, no temporary file or folder of tap-bench
    (``.*.tmp``, ``.*.old``, ``.*.bak``) in the test's folder or beside the project, no
    ``tap-bench-*`` spool in the temporary folder or /dev/shm."""
    before = _children(os.getpid())
    shared = _shared_temp()
    project = _debris(PROJECT_ROOT / "results") | _debris(PROJECT_ROOT / "policies")
    yield
    deadline = time.monotonic() + 10
    left = _children(os.getpid()) - before
    while left and time.monotonic() < deadline:  # executors shut down asynchronously
        time.sleep(0.1)
        left = _children(os.getpid()) - before
    assert not left, f"orphan processes left: {sorted(left)}"
    assert not _debris(tmp_path), f"temporary debris: {sorted(_debris(tmp_path))}"
    assert _shared_temp() <= shared, f"spool left: {sorted(_shared_temp() - shared)}"
    assert (_debris(PROJECT_ROOT / "results") | _debris(PROJECT_ROOT / "policies")) <= project


@pytest.fixture
def cli(capsys):
    """Run ``tap-bench ARGS`` in this process: (exit code, stdout, stderr)."""

    def run(*args: str) -> tuple[int, str, str]:
        code = main([str(a) for a in args])
        out = capsys.readouterr()
        return code, out.out, out.err

    return run


def run_process(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """``python -m tap_bench ARGS`` in a child process with this checkout first on the path."""
    env = {**os.environ, "PYTHONPATH": f"{PROJECT_ROOT}{os.pathsep}"
           f"{os.environ.get('PYTHONPATH', '')}"}
    return subprocess.run([sys.executable, "-m", "tap_bench", *map(str, args)],
                          capture_output=True, env=env, cwd=cwd, timeout=300)


@pytest.fixture
def womd_dir() -> Path:
    """The folder of real WOMD samples (``../shared/data/womd``); skips when absent."""
    if not (WOMD_DIR / "motion_data_one_scenario.tfrecord").is_file():
        pytest.skip(f"real WOMD samples not found in {WOMD_DIR}")
    return WOMD_DIR
