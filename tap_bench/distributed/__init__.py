"""Scaling out: the same rollouts, ingestion, labelling and fitting on a Ray cluster.

``backend`` (where work runs: :class:`LocalBackend`, :class:`RayBackend`), ``rollouts``
(batches of seeds per task), ``shards`` (ingest and label shard sets into partitioned
Parquet) and ``fitting`` (per-shard one-second samples merged into the exact summary).
Ray is imported only when a :class:`RayBackend` is made (``pip install 'tap-bench[ray]'``).
"""

from tap_bench.distributed.backend import (
    BACKENDS,
    Backend,
    LocalBackend,
    Outcome,
    RayBackend,
    make_backend,
)
from tap_bench.distributed.fitting import ShardSamples, distributed_fit_report, shard_samples
from tap_bench.distributed.rollouts import distributed_rollout
from tap_bench.distributed.shards import (
    ShardReport,
    ingest_shards,
    label_shards,
    parquet_shards,
)

__all__ = [
    # where work runs
    "BACKENDS", "Backend", "LocalBackend", "Outcome", "RayBackend", "make_backend",
    # the work
    "distributed_rollout", "ingest_shards", "label_shards", "parquet_shards", "ShardReport",
    "distributed_fit_report", "shard_samples", "ShardSamples",
]
