"""Speed and memory of WOMD ingestion, on Scenario shards built by the writer.

Builds about 300 MB of Scenario records (synthetic vehicles, 100 tracks x 91 steps per
scenario, 5 % invalid steps) under a scratch folder, then measures:

- decoding into the trajectory table (Arrow, and pandas) in one process [MB/s per core];
- the same with two worker processes (``workers=2``);
- ``ingest_womd`` to Parquet with 1 and 2 workers (reading, decoding, writing);
- peak memory (RSS) while streaming a shard set three times the size of the budget
  (1.2 GB) with ``iter_womd``, and of the main process of ``ingest_womd(workers=2)``.

The machine is shared: besides wall-clock rates, each figure is also given per CPU-second
(input bytes / CPU time of every process involved), which is the rate of one core whatever
else runs beside; the 1-minute load average is recorded with the figures.

    nice -n 10 python benchmarks/bench_womd_ingest.py [--scratch DIR] [--mb 300]
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from machine import report

from tap_bench.sources.ingest import IngestReport, _iter_tables, ingest_womd, iter_womd
from tap_bench.womd.scenario import decode_scenario
from tap_bench.womd.tfrecord import iter_records
from tap_bench.womd.writer import write_womd

SEED = 0
TRACKS = 100
STEPS = 91
SCENARIOS_PER_SHARD = 90  # about 50 MB a shard
MEMORY_BUDGET_MB = 400
"""RSS [MB] the reading process must stay under while it reads 1.2 GB (three times as much)."""


def synthetic_shard(rng: np.random.Generator, shard: int) -> pd.DataFrame:
    n = SCENARIOS_PER_SHARD * TRACKS
    speed = np.clip(rng.normal(12, 5, (n, 1)) + np.cumsum(rng.normal(0, 0.2, (n, STEPS)),
                                                           axis=1), 0, None)
    heading = rng.uniform(-np.pi, np.pi, (n, 1)) + np.cumsum(
        rng.normal(0, 0.01, (n, STEPS)), axis=1)
    heading = np.remainder(heading + np.pi, 2 * np.pi) - np.pi
    vx, vy = speed * np.cos(heading), speed * np.sin(heading)
    x = rng.uniform(-5e3, 5e3, (n, 1)) + np.cumsum(vx, axis=1) * 0.1
    y = rng.uniform(-5e3, 5e3, (n, 1)) + np.cumsum(vy, axis=1) * 0.1
    valid = rng.random((n, STEPS)) > 0.05
    track = np.arange(n)
    scenario = np.repeat([f"shard{shard}-{i:04d}" for i in range(SCENARIOS_PER_SHARD)],
                         TRACKS * STEPS)
    table = pd.DataFrame({
        "scenario_id": scenario,
        "track_id": np.repeat((track % TRACKS).astype(str), STEPS),
        "t": np.tile(np.arange(STEPS) / 10, n),
        "x": np.where(valid, x, np.nan).ravel(), "y": np.where(valid, y, np.nan).ravel(),
        "heading": heading.ravel(), "vx": vx.ravel(), "vy": vy.ravel(),
        "speed": speed.ravel(), "valid": valid.ravel(),
        "object_type": "vehicle", "is_ego": np.repeat(track % TRACKS == 0, STEPS),
        "length": 4.5, "width": 2.0, "height": 1.6,
    })
    return table


def build_shards(folder: Path, megabytes: int) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    n_shards = max(1, round(megabytes / 50))
    paths = [folder / f"synthetic-{k:03d}.tfrecord" for k in range(n_shards)]
    rng = np.random.default_rng(SEED)
    for k, path in enumerate(paths):
        table = synthetic_shard(rng, k)
        if not path.exists():
            write_womd(table, path)
    return paths


def rate(nbytes: int, seconds: float) -> float:
    return round(nbytes / 1e6 / seconds, 1)


def cpu_seconds() -> float:
    """CPU time of this process and of its finished children [s]."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def timed(figures: dict, name: str, nbytes: int, fn, workers: int = 1) -> object:
    """Run ``fn``; record its wall-clock and per-CPU-second rates [MB/s]. With workers,
    ``fn`` returns an IngestReport whose decode CPU time (in the workers, which are not
    this process's children but the forkserver's) is added to this process's."""
    wall, cpu = time.perf_counter(), cpu_seconds()
    result = fn()
    wall, cpu = time.perf_counter() - wall, cpu_seconds() - cpu
    if workers > 1:
        cpu += result.decode_cpu_seconds
    figures[f"{name}_MB_per_s"] = rate(nbytes, wall)
    figures[f"{name}_MB_per_cpu_s"] = rate(nbytes, cpu)
    return result


def decode_one_process(paths: list[Path], to_pandas: bool) -> int:
    scenarios = 0
    for path in paths:
        for record in iter_records(path):
            table = decode_scenario(record)
            if to_pandas:
                table.to_pandas(split_blocks=True)  # as iter_womd and read_womd do
            scenarios += 1
    return scenarios


def decode_workers(paths: list[Path], workers: int) -> IngestReport:
    report = IngestReport()
    for _ in _iter_tables(paths, format="scenario", object_types=None, on_error="stop",
                          check_crc=True, workers=workers, report=report, log=None):
        pass
    return report


def status_mb(key: str) -> float:
    """A memory figure of this process from /proc/self/status (VmRSS, VmHWM) [MB]."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(f"{key}:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def ingest_memory(folder: Path, workers: int) -> None:
    """Child process: ingest every file of ``folder`` to Parquet, print the peak RSS of this
    (the main) process [MB]."""
    with tempfile.TemporaryDirectory() as out:
        ingest_womd(sorted(folder.iterdir()), Path(out) / "all.parquet", format="scenario",
                    workers=workers)
    print(f"{status_mb('VmHWM'):.1f}")


def stream_memory(folder: Path) -> None:
    """Child process: stream every file of ``folder`` with iter_womd, print RSS samples."""
    files = sorted(folder.iterdir())
    samples = []
    for i, table in enumerate(iter_womd(files, format="scenario")):
        del table
        if i % 50 == 0:
            samples.append(round(status_mb("VmRSS"), 1))
    print(f"{status_mb('VmHWM'):.1f} {' '.join(map(str, samples))}")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scratch", default=os.path.join(tempfile.gettempdir(),
                                                          "tap-bench-womd-bench"))
    parser.add_argument("--mb", type=int, default=300, help="size of the shard set [MB]")
    parser.add_argument("--stream-memory", help=argparse.SUPPRESS)
    parser.add_argument("--ingest-memory", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.stream_memory:
        stream_memory(Path(args.stream_memory))
        return
    if args.ingest_memory:
        ingest_memory(Path(args.ingest_memory), workers=2)
        return
    scratch = Path(args.scratch)
    paths = build_shards(scratch / "shards", args.mb)
    nbytes = sum(p.stat().st_size for p in paths)
    figures: dict[str, object] = {"input_MB": round(nbytes / 1e6, 1), "files": len(paths)}

    for path in paths:  # warm the page cache: measure decoding, not the disk
        path.read_bytes()
    figures["scenarios"] = timed(figures, "decode_arrow_1_process", nbytes,
                                 lambda: decode_one_process(paths, to_pandas=False))
    timed(figures, "decode_pandas_1_process", nbytes,
          lambda: decode_one_process(paths, to_pandas=True))
    # Starting two workers (a forkserver that imports tap-bench, then two forks) is a
    # fixed cost per run: timed alone on one small scenario, and left out of the steady rate.
    tiny = scratch / "tiny.tfrecord"
    if not tiny.exists():
        write_womd(synthetic_shard(np.random.default_rng(SEED), 0).iloc[:TRACKS * STEPS], tiny)
    start = time.perf_counter()
    decode_workers([tiny], 2)
    startup = time.perf_counter() - start
    figures["workers_2_startup_s"] = round(startup, 2)
    timed(figures, "decode_arrow_2_workers", nbytes, lambda: decode_workers(paths, 2), 2)
    figures["decode_arrow_2_workers_steady_MB_per_s"] = round(
        nbytes / 1e6 / (nbytes / 1e6 / figures["decode_arrow_2_workers_MB_per_s"] - startup), 1)
    for workers in (1, 2):
        out = scratch / f"ingest-{workers}.parquet"
        timed(figures, f"ingest_parquet_{workers}_workers", nbytes,
              lambda out=out, workers=workers: ingest_womd(paths, out, format="scenario",
                                                           workers=workers), workers)
        out.unlink()
    figures["ingest_parquet_2_workers_steady_MB_per_s"] = round(
        nbytes / 1e6 / (nbytes / 1e6 / figures["ingest_parquet_2_workers_MB_per_s"] - startup), 1)

    # Memory: stream four times the shard set (symlinks), in a fresh process.
    many = scratch / "many"
    many.mkdir(exist_ok=True)
    for copy in range(4):
        for path in paths:
            link = many / f"{copy}-{path.name}"
            if not link.exists():
                link.symlink_to(path)
    output = subprocess.run([sys.executable, __file__, "--stream-memory", str(many)],
                            check=True, capture_output=True, text=True).stdout.split()
    figures["streamed_MB"] = round(4 * nbytes / 1e6, 1)
    figures["stream_peak_rss_MB"] = float(output[0])
    figures["stream_rss_samples_MB"] = [float(v) for v in output[1:]]
    output = subprocess.run([sys.executable, __file__, "--ingest-memory", str(many)],
                            check=True, capture_output=True, text=True).stdout.split()
    figures["ingest_2_workers_main_peak_rss_MB"] = float(output[0])
    figures["memory_budget_MB"] = MEMORY_BUDGET_MB
    figures["within_budget"] = max(figures["stream_peak_rss_MB"],
                                   figures["ingest_2_workers_main_peak_rss_MB"]
                                   ) < MEMORY_BUDGET_MB
    report("womd_ingest", figures, seed=SEED, tracks_per_scenario=TRACKS, steps=STEPS)


if __name__ == "__main__":
    main()
