"""Fixtures for the WOMD tests: the real sample files (skipped when absent) and small
hand-made trajectory tables."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[2]
WOMD_DIR = (PROJECT_ROOT / ".." / "shared" / "data" / "womd").resolve()


@pytest.fixture
def womd_dir() -> Path:
    """The folder of real WOMD samples (``../shared/data/womd``); skips when absent."""
    if not (WOMD_DIR / "motion_data_one_scenario.tfrecord").is_file():
        pytest.skip(f"real WOMD samples not found in {WOMD_DIR}")
    return WOMD_DIR


@pytest.fixture
def two_cars_and_a_walker() -> pd.DataFrame:
    """Two scenarios of 2 s: in ``s1`` an ego car driving +x at 10 m/s, a car turning left
    with a 5-step gap, and a pedestrian; in ``s2`` one parked car."""
    t = np.round(np.arange(20) * 0.1, 10)
    rows = []
    for i, tt in enumerate(t):
        rows.append(("s1", "100", tt, 10 * tt, 0.0, 0.0, 10.0, 0.0, "vehicle", True, True))
        heading = 0.2 * tt
        rows.append(("s1", "7", tt, 5 * tt, 3.0 + tt, heading, 5 * np.cos(heading),
                     5 * np.sin(heading), "vehicle", False, not 5 <= i < 10))
        rows.append(("s1", "8", tt, 1.0, 1.0 + 1.2 * tt, np.pi / 2, 0.0, 1.2, "pedestrian",
                     False, True))
        rows.append(("s2", "1", tt, 2.0, -4.0, -1.0, 0.0, 0.0, "vehicle", False, True))
    table = pd.DataFrame(rows, columns=["scenario_id", "track_id", "t", "x", "y", "heading",
                                        "vx", "vy", "object_type", "is_ego", "valid"])
    table["speed"] = np.hypot(table["vx"], table["vy"])
    return table
