"""On highway's straight road no vehicle turns: a lane change, its overshoot and the
correction back are merges, never a Turn. Seeds 5 and 17 (a lane change cut off by the end
of the episode while it turned back) are merges now; IDM seed 25 is not yet: the ego
changes lane (y -4 -> -7.96 m), swings back 1 m and settles (-8.14 -> -8.0 m), and the
settling is labelled "Gradual Right Turn" (heading within -0.095..0.046 rad)."""

from __future__ import annotations

import pytest

import tap_bench as tb
from tap_bench.sim.rollout import rollout


def _ego_turns(seeds: list[int]) -> list[str]:
    table = rollout("highway", "idm", seeds).trajectories
    labels = tb.label(table, "paper")
    egos = table.loc[table["is_ego"], ["scenario_id", "track_id"]].drop_duplicates()
    ego_labels = labels.merge(egos, on=["scenario_id", "track_id"])
    return [s for s in ego_labels["sdl"] if "Turn" in s]


def test_an_ego_lane_change_cut_off_while_it_turns_back_is_a_merge():
    assert _ego_turns([5, 17]) == []


@pytest.mark.xfail(strict=True, reason="a lane change's overshoot and settling on a straight "
                   "road is labelled a Turn (found by the attack; not fixed)")
def test_an_ego_lane_change_that_overshoots_and_settles_is_a_merge():
    assert _ego_turns([25]) == []
