"""What every benchmark prints beside its figures: the machine, the load and the versions.

Usage in a benchmark script::

    from machine import report
    report("label_speed", {"seconds": 0.8, "trajectories": 25889}, seed=0)

prints the figures with the machine description and writes them as JSON under
``benchmarks/out/<name>.json`` so closing notes and docs can quote them.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
"""This repository's checkout (the one the benchmarks are in)."""

PACKAGES = ("tap-bench", "numpy", "pandas", "pyarrow", "gymnasium", "highway-env", "protobuf",
            "crc32c", "rapidfuzz", "stable-baselines3", "torch", "numba", "ray")


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def describe_machine() -> dict:
    """The machine, its current load and the versions of the packages that matter."""
    versions = {}
    for pkg in PACKAGES:
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            continue
    try:
        load = os.getloadavg()
    except OSError:
        load = (float("nan"),) * 3
    return {
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "load_avg_1m": round(load[0], 2),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "versions": versions,
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
    }


def report(name: str, figures: dict, **context) -> dict:
    """Print ``figures`` with the machine and write them to ``benchmarks/out/<name>.json``."""
    record = {"benchmark": name, "figures": figures, "context": context,
              "machine": describe_machine()}
    print(json.dumps(record, indent=2, default=str))
    out = Path(__file__).parent / "out"
    out.mkdir(exist_ok=True)
    tmp = out / f".{name}.json.tmp"
    tmp.write_text(json.dumps(record, indent=2, default=str))
    os.replace(tmp, out / f"{name}.json")
    return record


def export(ref: str, folder: Path) -> Path:
    """The tree of git ``ref`` of this repository, written to ``folder``."""
    folder.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    return folder
