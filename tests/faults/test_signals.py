"""SIGTERM ends a run as Ctrl-C does (clean exit, no partial output, no orphan worker); a run
killed by SIGKILL leaves no worker behind either."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
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


def _start_run(tmp_path: Path) -> tuple[subprocess.Popen, Path]:
    suite = tmp_path / "slow.json"
    suite.write_text(json.dumps({
        "name": "slow", "envs": ["highway"], "policies": ["idm", "random"], "seeds": "0-199",
        "env_overrides": {"highway": {"duration": 60}}}))
    out = tmp_path / "runs" / "run"
    # a cache of its own: episodes an earlier test of the session cached would let the run
    # finish before the signal (or without starting workers)
    env = {**os.environ, "TAP_BENCH_CACHE": str(tmp_path / "cache")}
    run = subprocess.Popen(
        [sys.executable, "-m", "tap_bench", "bench", "run", "--suite", str(suite), "-o", str(out),
         "--workers", "2", "--no-progress"], stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.time() + 90
    while time.time() < deadline and len(_descendants(run.pid)) < 2:
        time.sleep(0.2)
    time.sleep(1.0)  # workers busy with episodes
    return run, out


@pytest.mark.parametrize("how", ["SIGTERM", "SIGINT"])
def test_a_terminated_run_exits_cleanly_and_leaves_nothing(tmp_path, how):
    run, out = _start_run(tmp_path)
    workers = _descendants(run.pid)
    assert len(workers) >= 2, "the run did not start its workers"
    run.send_signal(getattr(signal, how))
    _, err = run.communicate(timeout=60)
    assert run.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    deadline = time.time() + 20
    while time.time() < deadline and any(_alive(w) for w in workers):
        time.sleep(0.2)
    assert not any(_alive(w) for w in workers), "worker processes outlived the run"
    assert not out.exists()
    assert list((tmp_path / "runs").iterdir()) == [] if (tmp_path / "runs").exists() else True


def test_a_killed_run_leaves_no_worker(tmp_path):
    run, out = _start_run(tmp_path)
    workers = _descendants(run.pid)
    assert len(workers) >= 2
    run.kill()
    run.wait(timeout=30)
    deadline = time.time() + 20
    while time.time() < deadline and any(_alive(w) for w in workers):
        time.sleep(0.2)
    assert not any(_alive(w) for w in workers), "worker processes outlived a SIGKILLed run"
    assert not out.exists()


def test_no_resource_tracker_or_semaphore_is_left(tmp_path):
    before = set(os.listdir("/dev/shm")) if os.path.isdir("/dev/shm") else set()
    run, _ = _start_run(tmp_path)
    run.send_signal(signal.SIGTERM)
    run.communicate(timeout=60)
    after = set(os.listdir("/dev/shm")) if os.path.isdir("/dev/shm") else set()
    assert {n for n in after - before if "tap-bench" in n or n.startswith("sem.")} == set()
