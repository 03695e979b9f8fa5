"""Threshold fitting on sharded data: per-shard samples reduced to the exact summary.

J(Theta) is computed exactly from the sorted one-second samples
(:class:`tap_bench.objective.SortedSamples`), and no smaller summary keeps it exact: the
mean pairwise distance of a partition needs the rank of every sample. So each task computes
its shard's one-second samples (SPEC section 3; a window's mean depends on its own track
only) and returns them sorted, 24 bytes per one-second window; the driver merges the sorted
runs (numpy's stable sort is a run-detecting merge sort: O(n log k) for k shards) and fits.
The merged arrays are those the local fit sorts, so the thresholds are bit-identical to
``fit_report`` on the whole table.

Memory: the driver holds the samples of the whole data set (24 B per window, about 1.6 GB
for 68 M windows); :class:`SortedSamples` takes at most 2^26 samples per distribution.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from tap_bench.distributed.shards import parquet_shards
from tap_bench.errors import TapBenchError
from tap_bench.execution import DEFAULT_RETRIES, Backend
from tap_bench.fitting import DISTRIBUTIONS, fit_report
from tap_bench.kinematics import one_second_samples
from tap_bench.tableio import read_table

__all__ = ["ShardSamples", "dataset_name", "distributed_fit_report", "shard_samples"]

def _sorted_samples(path: str) -> dict[str, np.ndarray]:
    """One shard's one-second samples, each distribution sorted, (n_windows,) float64."""
    samples = one_second_samples(read_table(path), source=path)
    return {k: np.sort(samples[k], kind="stable") for k in DISTRIBUTIONS}


@dataclass(frozen=True)
class ShardSamples:
    """The merged one-second samples of a shard set.

    Attributes:
        samples: ``{"w": |w| [rad/s], "a" [m/s^2], "v" [m/s]}``, each (n,) sorted float64.
        shards: the shards read.
        failed: ``(shard, error)`` of the shards that failed on every attempt.
    """

    samples: dict[str, np.ndarray]
    shards: tuple[str, ...]
    failed: tuple[tuple[str, str], ...]


def shard_samples(paths: str | os.PathLike | Iterable[str | os.PathLike], backend: Backend,
                  *, retries: int = DEFAULT_RETRIES, progress: bool | None = None
                  ) -> ShardSamples:
    """The one-second samples of every Parquet shard, one task per shard, merged sorted.

    Raises:
        TapBenchError: every shard failed.
    """
    shards = [str(p) for p in parquet_shards(paths)]
    outcomes = backend.map(_sorted_samples, shards, retries=retries, unit="shard",
                           desc=f"samples ({backend.name})", progress=progress)
    runs = [o.value for o in outcomes if o.ok]
    failed = tuple((s, o.error) for s, o in zip(shards, outcomes, strict=True) if not o.ok)
    if not runs:
        raise TapBenchError(f"every shard failed; the first: {failed[0][0]}: {failed[0][1]}")
    merged = {k: np.sort(np.concatenate([r[k] for r in runs]), kind="stable")
              for k in DISTRIBUTIONS}
    return ShardSamples(merged, tuple(shards), failed)


def distributed_fit_report(paths: str | os.PathLike | Iterable[str | os.PathLike],
                           backend: Backend, *, dataset: str | None = None,
                           retries: int = DEFAULT_RETRIES, progress: bool | None = None,
                           **fit_options: Any):
    """:func:`tap_bench.fitting.fit_report` on a shard set, samples computed on ``backend``.

    Args:
        paths: a directory of Parquet shards, files or glob patterns.
        backend: where the per-shard samples are computed.
        dataset: the name kept in the provenance (default: the paths); failed shards are
            named there too.
        retries: retries of a failed shard.
        progress: progress bar over shards.
        fit_options: passed to :func:`~tap_bench.fitting.fit_report` (methods, select,
            epochs, seed, ...).

    Returns:
        (:class:`~tap_bench.fitting.FitReport`, :class:`ShardSamples`). A shard that failed
        on every attempt is left out and listed, in ``ShardSamples.failed`` and in the
        provenance's dataset name.
    """
    merged = shard_samples(paths, backend, retries=retries, progress=progress)
    name = dataset_name(dataset or (str(paths) if isinstance(paths, str | os.PathLike)
                                    else ", ".join(map(str, paths))), merged)
    return fit_report(merged.samples, dataset=name, **fit_options), merged


def dataset_name(name: str, merged: ShardSamples) -> str:
    """``name``, followed by the shards left out when some failed (for the provenance)."""
    if not merged.failed:
        return name
    return (f"{name} ({len(merged.shards) - len(merged.failed)} of {len(merged.shards)} "
            "shards; failed: " + ", ".join(s for s, _ in merged.failed) + ")")
