"""A tap-bench command run in a child process that kills itself (SIGKILL: no cleanup runs)
at a chosen point of its progress: just before or just after the n-th call of a named
function (``"tap_bench.tableio:_commit"``, ``"tap_bench.bench.cache:EpisodeCache.put"``).

The kill tests kill by progress, never by time: a test that waits some time and then kills
finds the run finished on a fast machine, or not yet started on a slow one. A child that
returns instead of dying never reached its kill point, which the tests check."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parents[2]

KILLED_CHILD = """
import functools, importlib, os, signal, sys
target, when, n, setup = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
module, _, attribute = target.partition(":")
owner = importlib.import_module(module)
*path, name = attribute.split(".")
for part in path:
    owner = getattr(owner, part)
real = getattr(owner, name)
calls = 0

@functools.wraps(real)
def killing(*args, **kwargs):
    global calls
    calls += 1
    if calls == n and when == "before":
        os.kill(os.getpid(), signal.SIGKILL)
    result = real(*args, **kwargs)
    if calls == n and when == "after":
        os.kill(os.getpid(), signal.SIGKILL)
    return result

setattr(owner, name, killing)
exec(setup)
from tap_bench.cli import main
sys.exit(main(sys.argv[5:]))
"""


def child_env() -> dict[str, str]:
    """The environment of a child: this checkout first on the path, idle OpenMP threads
    asleep."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(PROJECT_ROOT), os.environ.get("PYTHONPATH", "")]), "OMP_WAIT_POLICY": "PASSIVE"}


def run_killed(args: list[str], target: str, when: str, n: int, setup: str = "",
               cwd: Path | None = None) -> None:
    """Run ``tap-bench args`` in a child (after the Python statements ``setup``) that
    SIGKILLs itself ``when`` ("before" or "after") the ``n``-th call of ``target``
    ("module:attribute.path"); fail unless it died so."""
    assert when in ("before", "after"), when
    proc = subprocess.run([sys.executable, "-c", KILLED_CHILD, target, when, str(n), setup,
                           *args], env=child_env(), cwd=cwd, capture_output=True, text=True)
    assert proc.returncode == -signal.SIGKILL, (
        f"the run was to be killed {when} call {n} of {target}; it exited "
        f"{proc.returncode}:\n{proc.stderr[-3000:]}")
