"""Speed of CRC-32C: the crc32c package and tap-bench's numpy table fallback [MB/s].

    nice -n 10 python benchmarks/bench_womd_crc.py
"""

from __future__ import annotations

import time

import numpy as np
from machine import report

from tap_bench.womd.checksum import crc32c_numpy

try:
    from crc32c import crc32c as crc32c_package
except ImportError:  # pragma: no cover
    crc32c_package = None

SEED = 0
SIZES = (1 << 10, 1 << 16, 1 << 20, 1 << 24)  # a small record .. a big one [B]


def best_rate(fn, data: bytes, repeat: int) -> float:
    """Best of ``repeat`` runs, in MB/s."""
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        fn(data)
        best = min(best, time.perf_counter() - start)
    return len(data) / 1e6 / best


def main() -> None:
    rng = np.random.default_rng(SEED)
    figures = {}
    for size in SIZES:
        data = rng.integers(0, 256, size, dtype=np.uint8).tobytes()
        if crc32c_package is not None:
            assert crc32c_package(data) == crc32c_numpy(data)
            figures[f"package_MB_per_s_{size}B"] = round(best_rate(crc32c_package, data, 20), 1)
        figures[f"numpy_fallback_MB_per_s_{size}B"] = round(
            best_rate(crc32c_numpy, data, 3 if size > 1 << 20 else 10), 1)
    report("womd_crc", figures, seed=SEED)


if __name__ == "__main__":
    main()
