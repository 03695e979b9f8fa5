"""Fixtures of the fault-injection suite: every test is checked for orphan processes and for
temporary debris, and runs the command line in this process (``cli``) or in a child
(``cli_process``) the way a user would."""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import pytest

from tap_bench.cli import main

sys.path.insert(0, str(Path(__file__).resolve().parent))  # for fault_helpers

PROJECT_ROOT = Path(__file__).resolve().parents[2]
DEBRIS = (".tmp", ".old", ".bak")
"""Name endings of tap-bench's temporary files and folders."""


_HELPERS = ("multiprocessing.forkserver", "multiprocessing.resource_tracker")
"""multiprocessing's per-process helpers: they live as long as this process, one of each,
and end with it (they are not orphans; ``cli_process`` checks that they end)."""


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _children(pid: int) -> set[int]:
    """Every live descendant of ``pid`` but multiprocessing's helpers (from /proc; each
    process's stat read as bytes, its state and parent split off: about 2.3 ms for 100
    processes where pathlib's glob and the whole split took 5-6, twice a test here)."""
    parents: dict[int, int] = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat", "rb") as stream:
                stat = stream.read()
        except OSError:
            continue
        fields = stat.rsplit(b")", 1)[-1].split(None, 2)
        if len(fields) > 1 and fields[0] != b"Z":  # zombies are reaped by their parent
            parents[int(name)] = int(fields[1])
    found, todo = set(), [pid]
    while todo:
        p = todo.pop()
        for child, parent in parents.items():
            # a helper and what it started are left out (its command line read only here,
            # for a descendant, not for every process of the machine)
            if parent == p and child not in found and not any(
                    h in _cmdline(child) for h in _HELPERS):
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


@pytest.fixture(autouse=True)
def no_orphans_and_no_debris(tmp_path, monkeypatch):
    """After each test: no process left behind, no temporary file or folder of tap-bench
    (``.*.tmp``, ``.*.old``, ``.*.bak``) in the test's folder or beside the project, and
    every temporary file or folder this process made (``tempfile.mkstemp`` / ``mkdtemp``,
    wherever: /tmp, /dev/shm, beside an output) removed again."""
    made: list[str] = []
    real_mkdtemp, real_mkstemp = tempfile.mkdtemp, tempfile.mkstemp

    def mkdtemp(*args, **kwargs):
        path = real_mkdtemp(*args, **kwargs)
        made.append(path)
        return path

    def mkstemp(*args, **kwargs):
        fd, path = real_mkstemp(*args, **kwargs)
        made.append(path)
        return fd, path

    monkeypatch.setattr(tempfile, "mkdtemp", mkdtemp)
    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)
    before = _children(os.getpid())
    project = _debris(PROJECT_ROOT / "results") | _debris(PROJECT_ROOT / "policies")
    yield
    deadline = time.monotonic() + 10
    left = _children(os.getpid()) - before
    while left and time.monotonic() < deadline:  # executors shut down asynchronously
        time.sleep(0.1)
        left = _children(os.getpid()) - before
    assert not left, f"orphan processes left: {sorted(left)}"
    assert not _debris(tmp_path), f"temporary debris: {sorted(_debris(tmp_path))}"
    kept = [p for p in made if os.path.lexists(p)]
    assert not kept, f"temporary files or folders left: {kept}"
    assert (_debris(PROJECT_ROOT / "results") | _debris(PROJECT_ROOT / "policies")) <= project


@pytest.fixture
def cli(capsys):
    """Run ``tap-bench ARGS`` in this process: (exit code, stdout, stderr)."""

    def run(*args: str) -> tuple[int, str, str]:
        code = main([str(a) for a in args])
        out = capsys.readouterr()
        return code, out.out, out.err

    return run
