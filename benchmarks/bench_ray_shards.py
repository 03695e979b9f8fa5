"""Ingest plus labelling of about 1 GB of writer-made WOMD shards: local vs Ray workers.

Builds ``--mb`` MB of ``Scenario`` TFRecords with the writer (the synthetic shards of
``bench_womd_ingest.py``: 90 scenarios of 100 vehicles x 91 steps per 50 MB shard, 5 %
invalid steps) under a scratch folder, then runs the same work, WOMD files -> Parquet parts
-> action-level label parts, one task per shard, on:

- ``local-1``: :class:`LocalBackend` in this process (the one-machine baseline);
- ``local-2``: :class:`LocalBackend` with 2 processes;
- ``ray-1``, ``ray-2``: :class:`RayBackend` on a local Ray cluster of 1 and 2 CPUs.

For each: wall-clock throughput [MB/s of input]; the sum of the tasks' wall times in the
workers and the rate of one busy worker [MB per worker-second]; and the tasks' CPU time
(all threads of the worker process) with the rate per CPU-second, the per-core rate the
100-node estimate in docs/distributed.md starts from (a worker in this process may use
Arrow's threads beyond one core; Ray and pool workers run with OMP_NUM_THREADS=1). The
outputs of every backend are checked equal (same label rows). The machine is shared: the
load average is recorded.

    nice -n 10 python benchmarks/bench_ray_shards.py [--scratch DIR] [--mb 1000]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import pandas as pd
from bench_womd_ingest import build_shards
from machine import report

from tap_bench.distributed import ingest_shards, label_shards
from tap_bench.execution import LocalBackend, RayBackend


def run(backend, shards: list[Path], out: Path) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    ingested = ingest_shards(shards, out / "womd", backend, progress=False)
    t1 = time.perf_counter()
    labelled = label_shards(out / "womd", out / "labels", backend, progress=False)
    t2 = time.perf_counter()
    assert not ingested.failed and not labelled.failed, (ingested.failed, labelled.failed)
    nbytes = ingested.bytes_read
    worker_s = sum(s["seconds"] for s in ingested.shards + labelled.shards)
    cpu_s = sum(s["cpu_seconds"] for s in ingested.shards + labelled.shards)
    return {
        "wall_s": round(t2 - t0, 2),
        "ingest_wall_s": round(t1 - t0, 2),
        "label_wall_s": round(t2 - t1, 2),
        "MB_per_s": round(nbytes / 1e6 / (t2 - t0), 2),
        "task_seconds_in_workers": round(worker_s, 2),
        "MB_per_worker_s": round(nbytes / 1e6 / worker_s, 2),
        "trajectory_rows": ingested.rows,
        "label_rows": labelled.rows,
        "rows_per_worker_s": round(ingested.rows / worker_s),
        "task_cpu_seconds": round(cpu_s, 2),
        "MB_per_cpu_s": round(nbytes / 1e6 / cpu_s, 2),
        "rows_per_cpu_s": round(ingested.rows / cpu_s),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scratch", type=Path,
                        default=Path(tempfile.gettempdir()) / "tap-bench-ray-bench")
    parser.add_argument("--mb", type=int, default=1000)
    args = parser.parse_args()
    shards = build_shards(args.scratch / "womd-shards", args.mb)
    nbytes = sum(p.stat().st_size for p in shards)
    figures: dict = {"input_MB": round(nbytes / 1e6, 1), "shards": len(shards)}
    runs: dict[str, dict] = {}
    for name in ("local-1", "local-2", "ray-1", "ray-2"):
        if name.startswith("local"):
            backend = LocalBackend(int(name[-1]))
        else:
            backend = RayBackend(num_cpus=int(name[-1]), object_store_memory=200 << 20)
        try:
            runs[name] = run(backend, shards, args.scratch / name)
        finally:
            if isinstance(backend, RayBackend):
                backend.shutdown()
        print(name, runs[name], flush=True)
    reference = pd.read_parquet(args.scratch / "local-1" / "labels")
    keys = ["scenario_id", "track_id", "segment"]
    reference = reference.sort_values(keys).reset_index(drop=True)
    for name in runs:
        got = pd.read_parquet(args.scratch / name / "labels")
        pd.testing.assert_frame_equal(got.sort_values(keys).reset_index(drop=True), reference)
    figures["runs"] = runs
    figures["outputs_equal"] = True
    report("ray_shards", figures, seed=0)


if __name__ == "__main__":
    main()
