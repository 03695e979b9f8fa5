"""Scaling out: WOMD ingestion, labelling and fitting on shard sets, on any backend.

``shards`` (ingest and label shard sets into partitioned Parquet) and ``fitting`` (per-shard
one-second samples merged into the exact summary). Where the work runs (local processes or a
Ray cluster) is :mod:`tap_bench.execution`; rollouts and suite runs take its backends
directly (``rollout(..., backend=...)``, ``run_suite(..., backend=...)``).
"""

from tap_bench.distributed.fitting import ShardSamples, distributed_fit_report, shard_samples
from tap_bench.distributed.shards import (
    ShardReport,
    ingest_shards,
    label_shards,
    parquet_shards,
)

__all__ = [
    "ingest_shards", "label_shards", "parquet_shards", "ShardReport",
    "distributed_fit_report", "shard_samples", "ShardSamples",
]
