"""How long a suite run should take, said before its episodes start (:class:`RunPlan`): the
per-episode times of earlier runs kept in the episode cache, or of a first episode of each env
timed now (part of :mod:`tap_bench.bench.run.runner`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from tap_bench.bench.run.plan import _Task

__all__ = ["CACHED_EPISODE_S", "RunPlan", "estimate"]

CACHED_EPISODE_S = 0.03
"""Estimate of a cached episode's worker time (read, verify, label and measure, in batches)
when no run has measured it yet [s] (``benchmarks/bench_incremental.py`` measures it;
docs/benchmark.md, "Incremental runs")."""


@dataclass(frozen=True)
class RunPlan:
    """What a run will do and how long it should take, said before it starts.

    Attributes:
        episodes: episodes of the suite.
        cached: episodes found in the cache (checked when read).
        simulate: episodes to simulate.
        workers: processes the episodes are spread over.
        seconds: estimated wall time of the episodes' work [s] (NaN when unknown).
        overhead_seconds: estimated rest of the run: worker start-up, scoring, the report
            [s] (NaN when no run has measured it).
        basis: where the per-episode times come from, in words.
    """

    episodes: int
    cached: int
    simulate: int
    workers: int
    seconds: float
    overhead_seconds: float
    basis: str

    def describe(self, suite: str) -> str:
        """One line for the user: ``suite default: 750 episodes (600 cached, 150 to
        simulate) on 2 workers: about 4 min (...)``."""
        if math.isfinite(self.seconds):
            known = math.isfinite(self.overhead_seconds)
            total = self.seconds + (self.overhead_seconds if known else 0.0)
            when = f"about {_duration(total)}" + ("" if known else
                                                  " plus start-up, scoring and the report")
        else:
            when = "no estimate yet"
        return (f"suite {suite}: {self.episodes} episodes ({self.cached} cached, "
                f"{self.simulate} to simulate) on {self.workers} worker(s): {when} "
                f"({self.basis})")


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def estimate(tasks: Sequence[_Task], cached: Sequence[bool], workers: int,
             known: Mapping[str, Any], measured: Mapping[str, float]) -> RunPlan:
    """How long the episodes of ``tasks`` should take on ``workers`` processes: a cached one
    (``cached``) at its env's mean time in the cache (``known["cached"]``, else their mean,
    else :data:`CACHED_EPISODE_S`), one to simulate at its env's time timed now
    (``measured``) or by earlier runs (``known["simulated"]``) [s]; the rest of the run
    from ``known["overhead"]`` [s]. The estimate is NaN when an env to simulate has no
    time."""
    import numpy as np

    simulated = {**known.get("simulated", {}), **measured}
    per_hit = known.get("cached", {})
    fallback_hit = (float(np.mean(list(per_hit.values()))) if per_hit
                    else CACHED_EPISODE_S)
    total, unknown = 0.0, 0
    for task, hit in zip(tasks, cached, strict=True):
        if hit:
            total += per_hit.get(task.env, fallback_hit)
        elif task.env in simulated:
            total += simulated[task.env]
        else:
            unknown += 1
    n_hit = sum(cached)
    if unknown:
        seconds = float("nan")
    else:
        seconds = total / max(1, min(workers, len(tasks)))
    parts = []
    if measured:
        parts.append(f"timed a first episode of {', '.join(sorted(measured))}")
    if known.get("simulated") or known.get("cached"):
        parts.append("per-episode times of earlier runs in the cache")
    if unknown:
        parts.append(f"{unknown} episode(s) of envs whose first episode failed")
    return RunPlan(len(tasks), n_hit, len(tasks) - n_hit, workers, seconds,
                   float(known.get("overhead", float("nan"))),
                   "; ".join(parts) or "cached episodes only")
