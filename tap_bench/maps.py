"""The map table: road geometry as polylines, one row per point.

A highway-env scenario's road network (:func:`tap_bench.sim.roads.road_table`) and a WOMD
scenario's map features (:func:`tap_bench.womd.map_features.read_womd_maps`) both become this
table, which the replay viewer draws under the vehicles::

    map_id      str    what the geometry belongs to: an env name (``highway``) for
                       highway-env, where every seed drives on the same road, or a WOMD
                       ``scenario_id``
    feature_id  int    one polyline (or polygon); its points are consecutive rows, in order
    kind        str    ``lane`` (a lane's centre line), ``road_line`` (a painted line),
                       ``road_edge`` (the edge of the drivable surface), ``crosswalk``
                       (a closed polygon)
    style       str    ``solid`` or ``dashed`` for painted lines; ``""`` otherwise
    width       float  lane width [m] (NaN when the source does not say: WOMD lanes)
    x, y        float  [m], in the trajectory table's (WOMD's) axes: y to the left

Polylines are sampled finely enough to draw (straight lanes by their two ends, curves every
:data:`SAMPLE_STEP` metres or so); a consumer that needs a region clips them.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from tap_bench.errors import FileFormatError

__all__ = ["KINDS", "MAP_COLUMNS", "SAMPLE_STEP", "STYLES", "check_map_table", "empty_map"]

MAP_COLUMNS = ("map_id", "feature_id", "kind", "style", "width", "x", "y")
"""Columns of the map table, in order."""
KINDS = ("lane", "road_line", "road_edge", "crosswalk")
"""The kinds of map feature, in drawing order (lanes under lines under edges)."""
STYLES = ("solid", "dashed", "")
"""Line styles of painted lines; ``""`` for the other kinds."""
SAMPLE_STEP = 2.0  # [m] spacing of points on curved lanes: under 1 cm off a 15 m radius


def empty_map() -> pd.DataFrame:
    """A map table with no rows."""
    return pd.DataFrame({"map_id": pd.Series(dtype=object),
                         "feature_id": pd.Series(dtype=np.int64),
                         "kind": pd.Series(dtype=object), "style": pd.Series(dtype=object),
                         "width": pd.Series(dtype=float), "x": pd.Series(dtype=float),
                         "y": pd.Series(dtype=float)})


def check_map_table(table: pd.DataFrame, source: str = "map table") -> pd.DataFrame:
    """Check a map table against the contract of this module and return it.

    Raises:
        FileFormatError: a column is missing, a kind or style is unknown, or a coordinate is
            not finite; the message names the column, the first bad row and the fix.
    """
    missing = [c for c in MAP_COLUMNS if c not in table.columns]
    if missing:
        raise FileFormatError(f"{source}: missing column(s) {', '.join(missing)}; a map table "
                              f"has {', '.join(MAP_COLUMNS)} (tap_bench.maps).")
    for col, allowed in (("kind", KINDS), ("style", STYLES)):
        bad = ~table[col].isin(allowed).to_numpy()
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise FileFormatError(f"{source}: row {row}: {col} {table[col].iloc[row]!r} is not "
                                  f"one of {', '.join(map(repr, allowed))}.")
    for col in ("x", "y"):
        bad = ~np.isfinite(table[col].to_numpy(float))
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise FileFormatError(f"{source}: row {row}: {col} is {table[col].iloc[row]}; map "
                                  "points need finite coordinates [m]. Drop the point.")
    return table
