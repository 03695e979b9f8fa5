"""Hand-made label tables and point trajectories shared by the similarity tests."""

from __future__ import annotations

import numpy as np
import pandas as pd

CRUISE = "Straight | Maintain Medium Speed"
LEFT_MERGE = "Straight > Left Merge > Straight | Maintain Medium Speed"
GRADUAL_LEFT = "Straight > Gradual Left Turn > Straight | Maintain Medium Speed"
STOP_AND_GO = "Straight | Decelerate Slow Speed > Stopped > Accelerate Slow Speed"


def label_rows(rows: list[tuple[str, str, str]], level: str = "action", **extra) -> pd.DataFrame:
    """A label table from (scenario_id, track_id, sdl) triples, one segment each."""
    sdl = [r[2] for r in rows]
    out = pd.DataFrame({
        "scenario_id": [r[0] for r in rows], "track_id": [r[1] for r in rows],
        "segment": 0, "level": level,
        "lateral": [s.split(" | ")[0] for s in sdl],
        "longitudinal": [s.split(" | ")[1] for s in sdl],
        "sdl": sdl, "t_start": 0.0, "t_end": 9.1,
    })
    for col, values in extra.items():
        out[col] = values
    return out


def table_from_points(tracks: dict[tuple[str, str], np.ndarray], *, speed: float = 10.0,
                      heading: float = 0.0) -> pd.DataFrame:
    """A 10 Hz trajectory table from (scenario, track) -> (n, 2) points."""
    frames = []
    for (scenario, track), pts in tracks.items():
        n = len(pts)
        frames.append(pd.DataFrame({
            "scenario_id": scenario, "track_id": track, "t": np.round(np.arange(n) * 0.1, 10),
            "x": pts[:, 0], "y": pts[:, 1], "heading": heading, "speed": speed}))
    return pd.concat(frames, ignore_index=True)
