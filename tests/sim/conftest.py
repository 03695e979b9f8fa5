"""The simulation tests need tap-bench's Gymnasium ids registered (the shared fixtures,
``write_scenario`` among them, are in the root conftest)."""

from __future__ import annotations

import sys
from pathlib import Path

import tap_bench  # noqa: F401  (registers the tap_bench/... ids)

sys.path.insert(0, str(Path(__file__).resolve().parent))  # for womd_records
