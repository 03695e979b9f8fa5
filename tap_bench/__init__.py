"""tap-bench: a scenario benchmark toolkit built on TAP, the Trajectory-to-Action Pipeline."""

from __future__ import annotations

__version__ = "0.1.0"

from tap_bench.errors import (
    FileFormatError,
    LabelTableError,
    ShortSegmentWarning,
    TapBenchError,
    ThresholdsError,
    TrajectoryTableError,
    UnknownNameError,
)
from tap_bench.tableio import read_table, write_table
from tap_bench.trajectories import validate_trajectories

__all__ = [
    # errors
    "FileFormatError",
    "LabelTableError",
    "ShortSegmentWarning",
    "TapBenchError",
    "ThresholdsError",
    "TrajectoryTableError",
    "UnknownNameError",
    # data contracts and files
    "read_table",
    "validate_trajectories",
    "write_table",
]
