"""What the fault tests share: small tables, a WOMD shard, and the command line in a child
process whose descendants are all checked to be gone (importable: conftest puts this folder
on sys.path)."""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pandas as pd

PROJECT_ROOT = Path(__file__).resolve().parents[2]
RUN_TAG = os.environ.get("PYTEST_XDIST_TESTRUNUID", uuid.uuid4().hex)[:8]
"""A tag of this test run for the user modules the tests write, the same in every
pytest-xdist worker (test ids name them, and the workers must collect the same ids)."""



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
    result = subprocess.run(command, capture_output=True, env=env, cwd=cwd, timeout=300)
    deadline = time.monotonic() + 10
    while _marked(marker) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _marked(marker), f"processes outlived tap-bench {args}: {_marked(marker)}"
    return result
