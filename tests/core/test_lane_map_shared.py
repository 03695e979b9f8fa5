"""One lane map for a batch (issue 21): built once (``LaneMap.of_maps``), shared by the
interaction axis and the measures, it gives the same points as a lane map each call builds
for itself, bit for bit, and the second call searches no lane again."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.measures import ego_steps
from tap_bench.labelling import tap
from tap_bench.pathframe import LANE_MATCH_DISTANCE, LANE_MATCH_HEADING, LaneMap, _wrap


def _match_lane_by_lane(lanes: LaneMap, scene: int, x0: float, y0: float, h0: float):
    """The lane search as it was before lanes were shared: one lane at a time."""
    best, best_d = None, LANE_MATCH_DISTANCE
    for lane in np.flatnonzero(lanes.scene == scene).tolist():
        lx, ly = lanes._polyline(lane)
        ax, ay = lx[:-1], ly[:-1]
        ux, uy = np.diff(lx), np.diff(ly)
        len2 = np.maximum(ux * ux + uy * uy, 1e-12)
        t = np.clip(((x0 - ax) * ux + (y0 - ay) * uy) / len2, 0.0, 1.0)
        dist = np.hypot(ax + t * ux - x0, ay + t * uy - y0)
        ok = np.abs(_wrap(np.arctan2(uy, ux) - h0)) <= LANE_MATCH_HEADING
        if not ok.any():
            continue
        j = int(np.flatnonzero(ok)[np.argmin(dist[ok])])
        if dist[j] <= best_d:
            seg = np.r_[0.0, np.cumsum(np.sqrt(len2))]
            best, best_d = (lane, float(seg[j] + t[j] * np.sqrt(len2[j]))), dist[j]
    return best


def _network(rng: np.random.Generator, map_id: str) -> pd.DataFrame:
    """A map of generated lanes: arcs of 15-500 m radius (left and right) and straights,
    chained end to start, with branches, parallel lanes 3.5 m apart and a duplicate (two
    lanes equally near: the last wins)."""
    rows, feature = [], 0
    x0, y0, h0 = 0.0, 0.0, rng.uniform(-np.pi, np.pi)
    for _ in range(6):
        radius = rng.choice([np.inf, 15.0, 40.0, 120.0, 500.0])
        side = rng.choice([-1, 1])
        length = rng.uniform(20.0, 80.0)
        s = np.arange(0.0, length + 1e-9, 2.0)
        if np.isfinite(radius):
            a = h0 + side * s / radius
            cx, cy = x0 - side * radius * np.sin(h0), y0 + side * radius * np.cos(h0)
            x, y = cx + side * radius * np.sin(a), cy - side * radius * np.cos(a)
            h_end = a[-1]
        else:
            x, y, h_end = x0 + s * np.cos(h0), y0 + s * np.sin(h0), h0
        copies = [0.0, 3.5] + ([0.0] if rng.random() < 0.3 else [])
        for offset in copies:  # a parallel lane (and sometimes a duplicate of the first)
            nx, ny = -np.sin(h0) * offset, np.cos(h0) * offset
            rows.append(pd.DataFrame({"map_id": map_id, "feature_id": feature, "kind": "lane",
                                      "style": "", "width": np.nan, "x": x + nx,
                                      "y": y + ny}))
            feature += 1
        x0, y0, h0 = x[-1], y[-1], h_end
    return pd.concat(rows, ignore_index=True)


@pytest.mark.parametrize("seed", range(12))
def test_the_lane_search_equals_the_lane_by_lane_one(seed):
    rng = np.random.default_rng(seed)
    table = pd.concat([_network(rng, "a"), _network(rng, "b")], ignore_index=True)
    lanes = LaneMap.of_maps(table)
    pts = table[["x", "y"]].to_numpy()
    found = 0
    for _ in range(150):
        px, py = pts[rng.integers(len(pts))] + rng.normal(0.0, 1.5, 2)
        h = rng.uniform(-np.pi, np.pi) if rng.random() < 0.3 else None
        scene = int(rng.integers(2))
        if h is None:  # along the nearest lane's direction, give or take 20 degrees
            h = float(np.arctan2(*(pts[min(len(pts) - 1, rng.integers(len(pts)) + 1)]
                                   - pts[rng.integers(len(pts))])[::-1]))
        mine = lanes._match(scene, float(px), float(py), float(h))
        assert mine == _match_lane_by_lane(lanes, scene, float(px), float(py), float(h))
        found += mine is not None
    assert found > 0


@pytest.mark.parametrize("seed", range(8))
def test_shared_chains_give_the_points_a_fresh_lane_map_gives(seed):
    # any order of reaches, ahead and behind, through one shared lane map: the points of a
    # lane map that has seen nothing before, bit for bit
    rng = np.random.default_rng(100 + seed)
    table = _network(rng, "a")
    shared = LaneMap.of_maps(table)
    pts = table[["x", "y"]].to_numpy()
    for _ in range(20):
        k = int(rng.integers(len(pts) - 1))
        x0, y0 = pts[k]
        h0 = float(np.arctan2(pts[k + 1, 1] - y0, pts[k + 1, 0] - x0))
        kappa = float(rng.uniform(-0.05, 0.05))
        for reach in rng.permutation([20.0, 60.0, 150.0, 400.0]):
            sign = 1.0 if rng.random() < 0.6 else -1.0
            u = sign * np.r_[1000.0, np.arange(reach, 0.0, -2.0)]
            got = shared.follow(0, x0, y0, h0, kappa, u)
            fresh = LaneMap.of_maps(table).follow(0, x0, y0, h0, kappa, u)
            assert (got is None) == (fresh is None)
            if got is not None:
                np.testing.assert_array_equal(got[0], fresh[0])
                np.testing.assert_array_equal(got[1], fresh[1])


def _rollouts() -> pd.DataFrame:
    from tap_bench.sim.rollout import rollout

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return pd.concat([rollout(env, "idm", [0, 1], progress=False)[0]
                          for env in ("roundabout", "intersection")], ignore_index=True)


def _roads(envs) -> pd.DataFrame:
    from tap_bench.sim.roads import road_table
    from tap_bench.sim.scenario_env import get_scenario

    return pd.concat([road_table(get_scenario(env)).assign(map_id=env) for env in envs],
                     ignore_index=True)


def test_labels_and_measures_are_the_same_with_one_lane_map_and_the_measures_search_nothing(
        monkeypatch):
    table = _rollouts()
    road = _roads(["roundabout", "intersection"])
    own = tap(table, "paper", interactions="ego", map_table=road)
    own_steps = ego_steps(table, road)
    shared = LaneMap.of_maps(road)
    with_shared = tap(table, "paper", interactions="ego", map_table=shared)
    searched = []
    original = LaneMap._match

    def counting(self, *args):
        searched.append(args)
        return original(self, *args)

    monkeypatch.setattr(LaneMap, "_match", counting)
    steps = ego_steps(table, shared)
    assert searched == []  # every path end was matched and chained by tap()'s call
    pd.testing.assert_frame_equal(with_shared.labels("all"), own.labels("all"))
    pd.testing.assert_frame_equal(with_shared.segments("trend"), own.segments("trend"))
    for name in ("leader_row", "gap", "closing", "headway", "ttc"):
        np.testing.assert_array_equal(getattr(steps, name), getattr(own_steps, name))
    # the lane map was used: along the arc some leader differs
    arc = ego_steps(table)
    assert not np.array_equal(arc.leader_row, steps.leader_row) or \
        not np.array_equal(np.nan_to_num(arc.gap), np.nan_to_num(steps.gap))
