"""Hand-made label tables and point trajectories shared by the similarity tests."""

from __future__ import annotations

import numpy as np
import pandas as pd

from tap_bench.synthetic import from_controls

CRUISE = "Straight | Maintain Medium Speed"
LEFT_MERGE = "Straight > Left Merge > Straight | Maintain Medium Speed"
GRADUAL_LEFT = "Straight > Gradual Left Turn > Straight | Maintain Medium Speed"
STOP_AND_GO = "Straight | Decelerate Slow Speed > Stopped > Accelerate Slow Speed"


def label_rows(rows: list[tuple[str, str, str]], level: str = "action", *,
               t_end: float = 9.1, **extra) -> pd.DataFrame:
    """A label table from (scenario_id, track_id, sdl) triples, one segment each, from 0 s
    to ``t_end`` (exclusive)."""
    sdl = [r[2] for r in rows]
    out = pd.DataFrame({
        "scenario_id": [r[0] for r in rows], "track_id": [r[1] for r in rows],
        "segment": 0, "level": level,
        "lateral": [s.split(" | ")[0] for s in sdl],
        "longitudinal": [s.split(" | ")[1] for s in sdl],
        "sdl": sdl, "t_start": 0.0, "t_end": t_end,
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


SPEEDS = (3.0, 8.0, 13.0, 18.0, 23.0, 28.0, 33.0)  # 5 m/s apart, away from the band edges
MISMATCH = (1, 3, 4)  # clusters whose partner turns


def pairs_of_cruises() -> pd.DataFrame:
    """Seven clusters of two 9.1 s trajectories, 5 m/s apart from cluster to cluster.

    In each cluster a base cruises straight; its partner either cruises 0.1 m/s faster (the
    same SDL label) or, in clusters 1, 3 and 4, makes a 1.5 s gradual left turn at the same
    speed (another label). Each trajectory's nearest other trajectory, by ADE and by DTW, is
    its partner: 6 of 14 neighbours have a different label.
    """
    frames = []
    n = 91
    for c, v in enumerate(SPEEDS):
        frames.append(from_controls(np.full(n, v), np.zeros(n), scenario_id=f"c{c}",
                                    track_id="base"))
        if c in MISMATCH:
            yaw = np.zeros(n)
            yaw[40:55] = 0.05  # > 0.0283 straight, < 0.0754 gradual (rad/s)
            partner = from_controls(np.full(n, v), yaw, scenario_id=f"c{c}",
                                    track_id="partner")
        else:
            partner = from_controls(np.full(n, v + 0.1), np.zeros(n), scenario_id=f"c{c}",
                                    track_id="partner")
        frames.append(partner)
    table = pd.concat(frames, ignore_index=True)
    table["object_type"] = "vehicle"
    return table


def triples() -> tuple[pd.DataFrame, pd.DataFrame]:
    """Four triples of 2 s trajectories where ADE and DTW disagree, labelled by hand.

    In triple c the reference R follows a curve (y = 5c (k/19)^2 after k metres); T is R
    one step late (its first point repeated, its last dropped): DTW(R, T) is R's last step
    (1 m on the straight), ADE about 0.95 m;
    O is R shifted 0.3 m to the left after the start: ADE(R, O) = 0.285 m, DTW 5.7 m. R and
    O carry one label, T another. Nearest neighbours: R -> O by ADE, T by DTW; T -> R; O ->
    R. So ADE sees 1 different label per triple (T's), DTW 2 (R's and T's).
    """
    tracks, rows = {}, []
    k = np.arange(20.0)
    for c in range(4):
        r = np.stack([k, 5 * c * (k / 19) ** 2], axis=1)
        t = np.vstack([r[:1], r[:-1]])
        o = r + np.array([0.0, 0.3])
        o[0] = 0.0
        for name, pts, text in (("R", r, "Straight | Maintain Slow Speed"),
                                ("T", t, "Straight | Accelerate Slow Speed"),
                                ("O", o, "Straight | Maintain Slow Speed")):
            tracks[(f"triple{c}", name)] = pts
            rows.append((f"triple{c}", name, text))
    return table_from_points(tracks), label_rows(rows, t_end=2.0)
