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
