"""Which side of a WOMD road edge the road lies on, checked on data (issue 32, SPEC 8).

For every vehicle moving at >= 2 m/s at a valid step of every real scene found
(../shared/data/womd and ../shared/data/womd-dev; absent files skipped), its centre's
nearest road-edge segment, where it is within 5 m and the centre projects inside the
segment: is the vehicle on the left of the edge's direction (the road to the left) or on
its right? Also the human's (the SDC's) box at the current time (1.0 s) against the edges
(:class:`tap_bench.sim.road_edges.RoadEdges`, positive off the road), per scene.

Usage: ``python benchmarks/womd_edge_side.py [FILES ...]``
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np
from machine import report
from womd_measures_table import FILES

from tap_bench.sim.road_edges import RoadEdges
from tap_bench.sim.womd_scene import CURRENT_STEP, load_scene, scene_catalog

NEAR = 5.0  # [m] a vehicle centre this close to an edge counts
MOVING = 2.0  # [m/s]


def side_counts(scene) -> tuple[int, int]:
    """(left, right): samples of moving vehicles near an edge, by the edge's side."""
    edges = RoadEdges.from_polylines(scene.road.road_edges)
    if not len(edges):
        return 0, 0
    moving = scene.valid & (scene.speed >= MOVING) & (scene.object_types == "vehicle")[:, None]
    pts = np.c_[scene.x[moving], scene.y[moving]]
    left = right = 0
    for chunk in np.array_split(pts, max(1, len(pts) // 200)):
        ab = edges.b - edges.a
        n2 = (ab ** 2).sum(axis=1)
        px = chunk[:, :1] - edges.a[None, :, 0]
        py = chunk[:, 1:] - edges.a[None, :, 1]
        u = (px * ab[:, 0] + py * ab[:, 1]) / n2
        d = np.hypot(px - np.clip(u, 0, 1) * ab[:, 0], py - np.clip(u, 0, 1) * ab[:, 1])
        k = d.argmin(axis=1)
        r = np.arange(len(chunk))
        ok = (d[r, k] <= NEAR) & (u[r, k] >= 0) & (u[r, k] <= 1)
        cross = ab[k, 0] * py[r, k] - ab[k, 1] * px[r, k]
        left += int((ok & (cross > 0)).sum())
        right += int((ok & (cross < 0)).sum())
    return left, right


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("files", nargs="*")
    args = parser.parse_args()
    files = [str(f) for f in (args.files or FILES) if Path(f).exists()]
    warnings.simplefilter("ignore")
    total_left = total_right = 0
    scenes = {}
    for ref in scene_catalog(files):
        try:
            scene = load_scene(ref)
        except Exception as err:
            scenes[str(ref)] = {"error": str(err)}
            continue
        left, right = side_counts(scene)
        total_left += left
        total_right += right
        e, k = scene.ego, CURRENT_STEP
        edges = RoadEdges.from_polylines(scene.road.road_edges)
        start = edges.box_distance(scene.x[e, k], scene.y[e, k], scene.heading[e, k],
                                   scene.length[e], scene.width[e])
        path = [edges.box_distance(scene.x[e, j], scene.y[e, j], scene.heading[e, j],
                                   scene.length[e], scene.width[e])
                for j in range(k, scene.n_steps) if scene.valid[e, j]]
        scenes[scene.scenario_id] = {"edges": len(scene.road.road_edges), "segments": len(edges),
                                     "left": left, "right": right,
                                     "human_start_m": round(start, 2),
                                     "human_max_m": round(float(np.nanmax(path)), 2)
                                     if np.isfinite(path).any() else None}
        print(scene.scenario_id, scenes[scene.scenario_id], flush=True)
    print(f"road on the left of the edge in {total_left} of {total_left + total_right} samples "
          f"of moving vehicles within {NEAR} m of an edge")
    report("womd_edge_side", {"left": total_left, "right": total_right, "scenes": scenes},
           files=files)


if __name__ == "__main__":
    main()
