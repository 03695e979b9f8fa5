"""What the fault tests share: small tables, a WOMD shard, and the command line in a child
process whose descendants are all checked to be gone (importable: conftest puts this folder
on sys.path)."""

from __future__ import annotations

import contextlib
import json
import os
import select
import shlex
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pandas as pd

PROJECT_ROOT = Path(__file__).resolve().parents[2]
RUN_TAG = os.environ.get("PYTEST_XDIST_TESTRUNUID", uuid.uuid4().hex)[:8]
"""A tag of this test run for the user modules the tests write, the same in every
pytest-xdist worker (test ids name them, and the workers must collect the same ids)."""



RUN_TIMEOUT = 300
"""Seconds a command of :func:`run_process` or :func:`command_server` may take."""


def label_table(policy: str, seeds, label=lambda s: "Straight | Maintain Speed"):
    """The ego labels of one policy's episodes on ``seeds`` in env ``highway``."""
    return pd.DataFrame({"scenario_id": [f"{policy}-{s}" for s in seeds], "track_id": "ego",
                         "sdl": [label(s) for s in seeds], "lateral": "Straight",
                         "longitudinal": "Maintain Speed", "seed": list(seeds),
                         "policy": policy, "env": "highway"})


def womd_shard(path: Path, scenario_id: str = "s0") -> Path:
    """A TFRecord of one small Scenario (two cars, 2 s)."""
    import numpy as np

    from tap_bench.womd.writer import write_womd

    t = np.round(np.arange(20) * 0.1, 10)
    rows = [{"scenario_id": scenario_id, "track_id": track, "t": tt, "x": 10 * tt, "y": y,
             "heading": 0.0, "vx": 10.0, "vy": 0.0, "speed": 10.0, "object_type": "vehicle",
             "valid": True} for track, y in (("1", 0.0), ("2", 3.5)) for tt in t]
    write_womd(pd.DataFrame(rows), path)
    return path


def _marked(marker: str) -> set[int]:
    """Live processes whose environment holds ``marker`` (a child and all it started)."""
    found = set()
    for entry in Path("/proc").glob("[0-9]*"):
        try:
            if marker.encode() in (entry / "environ").read_bytes():
                found.add(int(entry.name))
        except OSError:
            continue
    return found


def run_process(*args: str, cwd: Path | None = None, shell_pipe: str | None = None
                ) -> subprocess.CompletedProcess:
    """``python -m tap_bench ARGS`` in a child process with this checkout first on the
    path (piped into ``shell_pipe``, a shell command, when given). Afterwards no process
    the child started may be alive, wherever it was re-parented (found by a marker in the
    environment)."""
    marker = f"TAP_BENCH_FAULT_TEST={uuid.uuid4().hex}"
    env = {**os.environ, "PYTHONPATH": f"{PROJECT_ROOT}{os.pathsep}"
           f"{os.environ.get('PYTHONPATH', '')}", marker.split("=")[0]: marker.split("=")[1]}
    command = [sys.executable, "-m", "tap_bench", *map(str, args)]
    if shell_pipe:
        command = ["bash", "-o", "pipefail", "-c",
                   " ".join(shlex.quote(c) for c in command) + " | " + shell_pipe]
    result = subprocess.run(command, capture_output=True, env=env, cwd=cwd,
                            timeout=RUN_TIMEOUT)
    deadline = time.monotonic() + 10
    while _marked(marker) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _marked(marker), f"processes outlived tap-bench {args}: {_marked(marker)}"
    return result


_SERVER = r"""
import json, os, sys, traceback

from tap_bench.cli import main  # what every run imports, once
import tap_bench.bench.run.runner, tap_bench.sim.rollout, tap_bench.labelling  # noqa: F401

for line in sys.stdin:
    request = json.loads(line)
    pid = os.fork()
    if pid == 0:  # one run: a process of its own that has imported nothing of the user's
        code = 1
        try:
            os.chdir(request["cwd"])
            sys.path[0] = request["cwd"]  # as python -m puts its working folder first
            for fd, name in ((1, "stdout"), (2, "stderr")):
                os.dup2(os.open(request[name], os.O_WRONLY | os.O_CREAT | os.O_TRUNC), fd)
            sys.argv = ["tap_bench", *request["args"]]
            code = main(request["args"])
        except SystemExit as stop:
            code = stop.code if isinstance(stop.code, int) else 1
        except BaseException:
            traceback.print_exc()
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code if isinstance(code, int) else 1)
    _, status = os.waitpid(pid, 0)
    print(os.waitstatus_to_exitcode(status), flush=True)
"""


@contextlib.contextmanager
def command_server(folder: Path) -> Iterator:
    """``run(*args, cwd=...)``: ``python -m tap_bench ARGS`` as :func:`run_process` runs it,
    each run in a process of its own forked from one that has imported tap-bench's command
    line, runner, simulation and labelling (about 1.3 CPU s a run where each child imported
    them): a user's module (a plugin, a module loaded by name) is imported afresh by each
    run, never by the server. The server's environment is :func:`run_process`'s; when the
    block ends it is stopped and no process it started may be alive. ``folder`` holds the
    runs' outputs (``run-N.stdout``, ``run-N.stderr``)."""
    marker = f"TAP_BENCH_FAULT_TEST={uuid.uuid4().hex}"
    env = {**os.environ, "PYTHONPATH": f"{PROJECT_ROOT}{os.pathsep}"
           f"{os.environ.get('PYTHONPATH', '')}", marker.split("=")[0]: marker.split("=")[1]}
    server = subprocess.Popen([sys.executable, "-c", _SERVER], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, env=env, cwd=folder, text=True)
    runs = []

    def run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
        n = len(runs)
        out, err = folder / f"run-{n}.stdout", folder / f"run-{n}.stderr"
        server.stdin.write(json.dumps({"args": list(map(str, args)), "cwd": str(cwd),
                                       "stdout": str(out), "stderr": str(err)}) + "\n")
        server.stdin.flush()
        if not select.select([server.stdout], [], [], RUN_TIMEOUT)[0]:  # as run_process's
            for pid in _marked(marker):
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)
            raise AssertionError(f"tap-bench {args} did not end within {RUN_TIMEOUT} s")
        line = server.stdout.readline()
        assert line, "the command server died"
        runs.append(args)
        deadline = time.monotonic() + 10  # nothing the run started outlives it
        while _marked(marker) - {server.pid} and time.monotonic() < deadline:
            time.sleep(0.1)
        left = _marked(marker) - {server.pid}
        assert not left, f"processes outlived tap-bench {args}: {left}"
        return subprocess.CompletedProcess(["tap_bench", *map(str, args)], int(line),
                                           out.read_bytes(), err.read_bytes())

    try:
        yield run
    finally:
        with contextlib.suppress(OSError):  # a server killed on a timeout
            server.stdin.close()
        try:
            server.wait(timeout=60)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
    deadline = time.monotonic() + 10
    while _marked(marker) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _marked(marker), f"processes outlived the runs {runs}: {_marked(marker)}"
