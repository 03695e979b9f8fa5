"""``tap-bench demo``: the README's main job on built-in defaults, no data to download.

Runs the ``demo`` suite (``envs/suites/demo.json``: highway, merge and roundabout, shortened;
IDM/MOBIL default, aggressive and defensive, and random; 12 seeds), labels every vehicle with
TAP, scores the policies against IDM/MOBIL and writes a run folder with its HTML report.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

from tap_bench.bench.run.folder import RunResult

__all__ = ["DEMO_OUTPUT", "DEMO_SUITE", "run_demo", "timing_split"]

DEMO_SUITE = "demo"
DEMO_OUTPUT = Path("results") / "demo"


def timing_split(result: RunResult) -> dict[str, float]:
    """Wall time of the run split into rollouts, labelling, scoring and report [s].

    Rollouts and labelling run together in the worker processes, so their wall time is
    shared out in proportion to the CPU seconds the workers spent on each.
    """
    t = result.summary["timings"]
    cpu_roll = t.get("rollout_cpu_in_workers", 0.0)
    cpu_label = t.get("labelling_cpu_in_workers", 0.0) + t.get("measures_cpu_in_workers", 0.0)
    wall = t.get("rollouts_wall", 0.0)
    share = cpu_roll / (cpu_roll + cpu_label) if cpu_roll + cpu_label > 0 else 1.0
    return {"rollout": wall * share, "labelling": wall * (1 - share),
            "scoring": t.get("scoring", 0.0), "report": t.get("writing_and_report", 0.0),
            "total": t.get("total", 0.0)}


def run_demo(output: str | os.PathLike = DEMO_OUTPUT, *, workers: int = 2,
             progress: bool | None = None,
             announce: Callable[[str], None] | None = None) -> RunResult:
    """Run the demo suite into ``output`` (replacing an earlier demo there); ``announce``
    gets a line per phase (the estimate, scoring, writing), terminal or not."""
    from tap_bench.bench.run.runner import run_suite

    start = time.perf_counter()
    result = run_suite(DEMO_SUITE, output, workers=workers, overwrite=True, progress=progress,
                       announce=announce)
    result.summary["timings"].setdefault("total", time.perf_counter() - start)
    return result
