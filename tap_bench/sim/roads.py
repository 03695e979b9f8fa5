"""The road network of a highway-env scenario as a map table (:mod:`tap_bench.maps`).

Every lane becomes a ``lane`` polyline (its centre line, with its width) and up to two
``road_line`` polylines (its painted sides: highway-env's STRIPED lines are ``dashed``,
CONTINUOUS and CONTINUOUS_LINE ``solid``, NONE is not drawn), in Waymo axes like the
trajectory table (y and the lateral offset change sign). highway-env builds the same road
for every seed of a scenario, so one table per env serves all its episodes; the runner
records it once per env in ``roads.parquet``.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
from highway_env.road.lane import StraightLane

from tap_bench.maps import MAP_COLUMNS, SAMPLE_STEP, empty_map
from tap_bench.sim.scenario_env import get_scenario, make_env
from tap_bench.sim.scenario_format import Scenario

__all__ = ["network_table", "road_table"]

_STYLE = {1: "dashed", 2: "solid", 3: "solid"}  # highway-env LineType -> style; 0 NONE


def _stations(lane) -> np.ndarray:
    """Longitudinal positions [m] to sample a lane at: its ends, and every SAMPLE_STEP on
    lanes that are not straight."""
    length = float(lane.length)
    if isinstance(lane, StraightLane):
        return np.array([0.0, length])
    n = max(int(np.ceil(length / SAMPLE_STEP)), 1)
    return np.linspace(0.0, length, n + 1)


def network_table(network, map_id: str) -> pd.DataFrame:
    """The map table of a highway-env ``RoadNetwork`` (``env.unwrapped.road.network``).

    Args:
        network: the road network.
        map_id: the ``map_id`` of every row (the env name).
    """
    frames = []
    feature = 0
    for lane in network.lanes_list():
        s = _stations(lane)
        width = float(lane.width_at(0.0))
        for kind, side in (("lane", None), ("road_line", 0), ("road_line", 1)):
            if side is None:
                style, lateral = "", np.zeros(len(s))
            else:
                style = _STYLE.get(int(lane.line_types[side]))
                if style is None:
                    continue
                # highway-env draws side k at lateral (k - 0.5) * width
                lateral = np.array([(side - 0.5) * lane.width_at(si) for si in s])
            xy = np.array([lane.position(si, li) for si, li in zip(s, lateral, strict=True)])
            frames.append(pd.DataFrame({
                "map_id": map_id, "feature_id": feature, "kind": kind, "style": style,
                "width": width if kind == "lane" else np.nan,
                "x": xy[:, 0], "y": -xy[:, 1]}))  # Waymo axes: y to the left
            feature += 1
    if not frames:
        return empty_map()
    out = pd.concat(frames, ignore_index=True)[list(MAP_COLUMNS)]
    out["feature_id"] = out["feature_id"].astype(np.int64)
    return out


def road_table(scenario: Scenario | str) -> pd.DataFrame:
    """The map table of a scenario's road (``map_id`` is the scenario name).

    Builds the env and resets it once (seed 0): the road does not depend on the seed.
    """
    scenario = get_scenario(scenario)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = make_env(scenario, record=False)
        try:
            env.reset(seed=0)
            return network_table(env.unwrapped.road.network, scenario.name)
        finally:
            env.close()
