"""Generated WOMD files for the scale tests: straight-lane scenes (tests/sim/womd_records)
with many parked cars beside the road, so a scene's trajectory table has thousands of rows
while its episode stays quick."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from womd_records import T, record, straight_lane, straight_scene, womd_file


def crowded_scene(sid: str, angle: float, parked: int) -> pd.DataFrame:
    """:func:`straight_scene` heading ``angle`` with ``parked`` cars standing 40 m to the
    left of the lane (replayed: they never move)."""
    table = straight_scene(sid, angle=angle)
    c, s = np.cos(angle), np.sin(angle)
    rows = [table]
    for k in range(parked):
        lon, lat = 6.0 * k, 40.0
        rows.append(pd.DataFrame({
            "scenario_id": sid, "track_id": str(100 + k), "t": T,
            "x": lon * c - lat * s, "y": lon * s + lat * c, "heading": angle, "vx": 0.0,
            "vy": 0.0, "valid": True, "object_type": "vehicle", "is_ego": False,
            "length": 4.5, "width": 2.0, "height": 1.5}))
    return pd.concat(rows, ignore_index=True)


def scene_files(folder: Path, n: int, *, per_file: int = 4, parked: int = 0) -> list[str]:
    """``n`` scenes ``s000`` ... in files of ``per_file`` scenes, each heading another way."""
    folder.mkdir(parents=True, exist_ok=True)
    files, batch = [], []
    for i in range(n):
        angle = (i * 0.7) % (2 * np.pi)
        batch.append(record(crowded_scene(f"s{i:03d}", angle, parked),
                            lane=straight_lane(angle)))
        if len(batch) == per_file or i == n - 1:
            files.append(womd_file(folder / f"scenes-{len(files):03d}.tfrecord", *batch))
            batch = []
    return files
