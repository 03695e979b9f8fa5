"""On highway's straight road no vehicle turns: a lane change, its overshoot and the
correction back are merges, never a Turn. Seeds 5 and 17: a lane change cut off by the end
of the episode while it turned back. IDM seed 25: the ego changes lane (y -4 -> -7.96 m),
swings back 1 m and settles (-8.14 -> -8.0 m); the settling turn starts where the merge
ends, mid-swing, and is a wiggle measured from the heading where the merge started.
IDM-aggressive: seed 25, a right lane change from the first step whose first turn the
low-pass joined to the overshoot after it (a pair that moved the other way than its first
turn); seeds 0 and 44, a lane change and its return at once (the middle turn back at the
lane's heading with under 1 s of it left); seed 43, a lane change cut off by the end of the
episode after its heading peaked. docs/tap.md gives the rules and the figures."""

from __future__ import annotations

import pytest

import tap_bench as tb
from tap_bench.sim.rollout import rollout


def _ego_turns(seeds: list[int], policy: str = "idm") -> list[str]:
    """The label sequences of the egos of ``policy`` on highway ``seeds`` that hold a Turn."""
    table = rollout("highway", policy, seeds).trajectories
    labels = tb.label(table, "paper")
    egos = table.loc[table["is_ego"], ["scenario_id", "track_id"]].drop_duplicates()
    ego_labels = labels.merge(egos, on=["scenario_id", "track_id"])
    return [f"{sid}: {s}" for sid, s in zip(ego_labels["scenario_id"], ego_labels["sdl"],
                                            strict=True)
            if "Turn" in s]


def test_an_ego_lane_change_cut_off_while_it_turns_back_is_a_merge():
    assert _ego_turns([5, 17]) == []


@pytest.mark.parametrize(("policy", "seed"), [("idm", 25), ("idm-aggressive", 29)])
def test_an_ego_lane_change_that_overshoots_and_settles_is_a_merge(policy, seed):
    assert _ego_turns([seed], policy) == []


def test_the_aggressive_egos_that_turned_are_merges():
    assert _ego_turns([0, 25, 43, 44], "idm-aggressive") == []


@pytest.mark.slow
@pytest.mark.parametrize("policy", ["idm", "idm-aggressive", "idm-defensive"])
def test_no_ego_on_the_straight_highway_turns(policy):
    assert _ego_turns(list(range(24, 60)), policy) == []
