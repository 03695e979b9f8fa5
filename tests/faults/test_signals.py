"""SIGTERM ends a run as Ctrl-C does (clean exit, no partial output, no orphan worker); a run
killed by SIGKILL leaves no worker behind either."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="uses /proc")


def _descendants(pid: int) -> list[int]:
    """Live (not zombie) descendants of ``pid``, from /proc."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z":
            children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    out, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


START_WITHIN = 180.0
"""Seconds the run may take to start its workers: generous for a loaded machine, bounded."""
EXIT_WITHIN = 120.0
"""Seconds the run may take to exit after a signal, and its workers after it."""


def _sigint_default() -> None:
    """In the run's process before it starts: SIGINT's default action, as in a terminal's
    foreground job. A process whose SIGINT is ignored passes that on to what it starts (a
    pytest worker where some code ignored it did: the run never saw Ctrl-C)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@contextlib.contextmanager
def _running(tmp_path: Path) -> Iterator[tuple[subprocess.Popen, Path, list[int]]]:
    """A long `bench run` with 2 workers, in a process group of its own, once its workers
    are busy: (the run, its output folder, the workers' pids). Whatever the test does, the
    group and every worker are killed when it ends: a failed or timed-out test leaves no
    orphan behind (under load one once did)."""
    suite = tmp_path / "slow.json"
    suite.write_text(json.dumps({
        "name": "slow", "envs": ["highway"], "policies": ["idm", "random"], "seeds": "0-199",
        "env_overrides": {"highway": {"duration": 60}}}))
    out = tmp_path / "runs" / "run"
    # a cache of its own: episodes an earlier test of the session cached would let the run
    # finish before the signal (or without starting workers)
    # PYTHONFAULTHANDLER: a run that does not exit is sent SIGABRT and prints every thread's
    # stack (see _exit_or_stacks)
    env = {**os.environ, "TAP_BENCH_CACHE": str(tmp_path / "cache"), "PYTHONFAULTHANDLER": "1"}
    run = subprocess.Popen(
        [sys.executable, "-m", "tap_bench", "bench", "run", "--suite", str(suite), "-o", str(out),
         "--workers", "2", "--no-progress"], stderr=subprocess.PIPE, text=True, env=env,
        start_new_session=True, preexec_fn=_sigint_default)
    try:
        deadline = time.time() + START_WITHIN
        while time.time() < deadline and run.poll() is None and len(_descendants(run.pid)) < 2:
            time.sleep(0.2)
        time.sleep(1.0)  # workers busy with episodes
        workers = _descendants(run.pid)
        assert len(workers) >= 2, f"the run did not start its workers in {START_WITHIN:.0f} s"
        yield run, out, workers
    finally:
        # the run's own group: the run and its workers (which stay in it), orphaned or not
        with contextlib.suppress(OSError):
            os.killpg(run.pid, signal.SIGKILL)
        with contextlib.suppress(subprocess.TimeoutExpired):
            run.communicate(timeout=EXIT_WITHIN)


def _exit_or_stacks(run: subprocess.Popen, how: str) -> str:
    """The run's stderr once it exits; when it has not exited within EXIT_WITHIN, the test
    fails with the stack of every thread of the run (faulthandler on SIGABRT), so that a
    rare hang under load says where it waits."""
    try:
        return run.communicate(timeout=EXIT_WITHIN)[1]
    except subprocess.TimeoutExpired:
        run.send_signal(signal.SIGABRT)
        try:
            err = run.communicate(timeout=30)[1]
        except subprocess.TimeoutExpired:
            err = "(no output within 30 s of SIGABRT)"
        pytest.fail(f"the run did not exit within {EXIT_WITHIN:.0f} s of {how}; its threads:\n"
                    f"{err[-8000:]}")


def _gone(workers: list[int]) -> bool:
    deadline = time.time() + EXIT_WITHIN
    while time.time() < deadline and any(_alive(w) for w in workers):
        time.sleep(0.2)
    return not any(_alive(w) for w in workers)


def _shared_memory() -> set[str]:
    return set(os.listdir("/dev/shm")) if os.path.isdir("/dev/shm") else set()


@pytest.mark.parametrize("how", ["SIGTERM", "SIGINT"])
def test_a_terminated_run_exits_cleanly_and_leaves_nothing(tmp_path, how):
    """No output, no worker, no resource tracker's semaphore left in /dev/shm."""
    before = _shared_memory()
    with _running(tmp_path) as (run, out, workers):
        run.send_signal(getattr(signal, how))
        err = _exit_or_stacks(run, how)
        assert run.returncode == 130, err
        assert "interrupted" in err and "Traceback" not in err
        assert _gone(workers), "worker processes outlived the run"
        assert not out.exists()
        assert list((tmp_path / "runs").iterdir()) == [] if (tmp_path / "runs").exists() \
            else True
    assert _left_in_shared_memory(before, [run.pid, *workers]) == set()


def _left_in_shared_memory(before: set[str], pids: list[int],
                           wait: float = EXIT_WITHIN) -> set[str]:
    """What the run left in /dev/shm: its ingest spool folders (named with the pid of the
    process that made them) and semaphores that are still there once the processes running
    beside this test (another pytest worker, another user's job) have had the time to remove
    theirs. An entry of another process seen in passing is not the run's: counting every new
    entry failed this test once when another process ingested at the same moment."""
    def suspects() -> set[str]:
        new = _shared_memory() - before
        ours = {n for n in new if any(n.startswith(f"tap-bench-ingest-{pid}-") for pid in pids)}
        others = {n for n in new if n.startswith("sem.") or
                  ("tap-bench" in n and not n.startswith("tap-bench-ingest-"))}
        return ours | others

    left = suspects()
    deadline = time.time() + wait
    while left and time.time() < deadline:
        time.sleep(0.5)
        left = suspects()  # a passing entry of another process is gone by now
    return left


@pytest.mark.skipif(not os.access("/dev/shm", os.W_OK), reason="no writable /dev/shm")
def test_only_the_runs_own_leftovers_in_shared_memory_count():
    """Another process's ingest spool seen during the run is not the run's; the run's own
    (its pid in the name) is, and so is a semaphore that stays."""
    before = _shared_memory()
    other = Path("/dev/shm") / f"tap-bench-ingest-{os.getppid()}-passing"
    ours = Path("/dev/shm") / f"tap-bench-ingest-{os.getpid()}-left"
    other.mkdir()
    ours.mkdir()
    try:
        assert _left_in_shared_memory(before, [os.getpid()], wait=0.6) == {ours.name}
        other.rmdir()
    finally:
        for folder in (other, ours):
            with contextlib.suppress(OSError):
                folder.rmdir()


def test_a_killed_run_leaves_no_worker(tmp_path):
    with _running(tmp_path) as (run, out, workers):
        run.kill()
        run.wait(timeout=EXIT_WITHIN)
        assert _gone(workers), "worker processes outlived a SIGKILLed run"
        assert not out.exists()
