"""Scripted scenarios: the cut-in and lead-braking envs provoke their context reliably."""

from __future__ import annotations

import pytest

from tap_bench.errors import FileFormatError
from tap_bench.labelling import tap
from tap_bench.sim import rollout
from tap_bench.sim.scenario_env import get_scenario
from tap_bench.sim.scripts import Script


@pytest.mark.parametrize(("env", "context"), [("cut_in", "Cut-in"),
                                              ("lead_braking", "Lead Braking")])
def test_scripted_env_provokes_its_context_for_idm(env, context):
    trajectories, episodes = rollout(env, "idm", [0, 1, 2, 3], progress=False)
    labels = tap(trajectories, interactions="ego").labels("maneuver")
    ego = labels[labels["track_id"] == "ego"]
    assert len(ego) == 4 and ego["interaction"].str.contains(context).all()
    assert not episodes["crashed"].any()  # IDM copes with both


def test_script_is_checked():
    assert get_scenario("cut_in").script.kind == "cut_in"
    with pytest.raises(FileFormatError, match=r"(?i)did you mean .cut_in."):
        Script.from_dict({"kind": "cutin", "at": 3, "gap": 20})
    with pytest.raises(FileFormatError, match="needs 'gap'"):
        Script.from_dict({"kind": "cut_in", "at": 3})
    with pytest.raises(FileFormatError, match=r"(?i)did you mean 'duration'"):
        Script.from_dict({"kind": "lead_braking", "at": 3, "gap": 20, "durations": 2})
    with pytest.raises(FileFormatError, match="at must be"):
        Script.from_dict({"kind": "cut_in", "at": -1, "gap": 20})
    with pytest.raises(FileFormatError, match="blocker belongs"):
        Script.from_dict({"kind": "lead_braking", "at": 3, "gap": 20, "blocker": True})


def test_vary_draws_each_field_per_seed_within_its_range():
    import numpy as np

    script = Script.from_dict({"kind": "lead_braking", "at": 4, "gap": 30, "clear": 100,
                               "vary": {"at": [3, 5], "gap": [22, 38],
                                        "deceleration": [4.5, 7.5]}})
    draws = [script.drawn(np.random.default_rng(seed)) for seed in range(50)]
    for name, (lo, hi) in script.vary.items():
        values = np.array([getattr(d, name) for d in draws])
        assert (values >= lo).all() and (values <= hi).all()
        assert values.std() > (hi - lo) / 6  # spread over the range, not one value
    assert all(d.duration == 2.0 and d.vary is None for d in draws)  # not named: fixed
    again = script.drawn(np.random.default_rng(7))
    assert again == draws[7]  # the same seed, the same episode
    assert Script.from_dict(script.to_dict()) == script  # round trip through the file
    with pytest.raises(FileFormatError, match=r"(?i)did you mean 'deceleration'"):
        Script.from_dict({"kind": "lead_braking", "at": 3, "gap": 20,
                          "vary": {"decel": [1, 2]}})
    with pytest.raises(FileFormatError, match="low <= high"):
        Script.from_dict({"kind": "lead_braking", "at": 3, "gap": 20, "vary": {"gap": [30, 20]}})
    with pytest.raises(FileFormatError, match="at must be"):  # every drawable value checked
        Script.from_dict({"kind": "lead_braking", "at": 3, "gap": 20, "vary": {"at": [-1, 2]}})


@pytest.mark.parametrize("env", ["cut_in", "lead_braking"])
def test_scripted_scenes_vary_with_their_seed(env):
    """Issue 25: the shipped interaction scenes gave IDM bit-identical episodes on every
    seed (the clearing leaves the ego alone with the scripted vehicle)."""
    from tap_bench.bench.episodes import episode_table
    from tap_bench.bench.scores.verdict import one_outcome_cells

    trajectories, episodes = rollout(env, "idm", [0, 1, 2, 3], progress=False)
    labels = tap(trajectories, interactions="ego").labels("maneuver")
    table = episode_table(labels=labels, trajectories=trajectories, episodes=episodes,
                          level="maneuver", policy="idm")
    assert one_outcome_cells(table.assign(env=env)).empty
    assert table["mean_speed"].round(6).nunique() == 4
