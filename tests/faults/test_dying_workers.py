"""A worker process that dies costs only the task it ran: a suite run keeps every other
episode (the killer policy listed first), and an ingest keeps every other file."""

from __future__ import annotations

import json
import warnings

import pytest

from tap_bench.bench.run.runner import run_suite
from tap_bench.bench.suite import suite_from_dict


def tiny(policies, seeds="0-3"):
    return suite_from_dict({"name": "tiny", "envs": ["merge"], "policies": policies,
                            "seeds": seeds, "env_overrides": {"merge": {"duration": 3}},
                            "bootstrap": {"n_resamples": 200}}, check_names=False)


KILLER = '''
import os
from tap_bench.sim.policies import LaneKeepingPolicy

class KillsOnSeed(LaneKeepingPolicy):
    """Keeps its lane; its worker process dies in the episode of seed 1."""

    def reset(self, env, *, seed):
        self._seed = seed
        super().reset(env, seed=seed)

    def act(self, observation):
        if self._seed == 1:
            os._exit(9)
        return super().act(observation)
'''


@pytest.mark.slow  # 13 CPU s: four worker processes start (two for the retries). Fast:
# tests/execution/test_local_backend.py::test_a_worker_that_always_dies_costs_only_its_own_item
# (the killer first, the backend every run uses) and tests/sim/test_sim_rollout.py::
# test_a_dying_worker_loses_only_its_episode (an episode whose worker dies is its error row)
def test_a_policy_that_kills_its_worker_costs_only_its_own_episodes(tmp_path, monkeypatch):
    # The killer is listed first: under the old pool every pending episode failed with it,
    # healthy IDM ones included.
    (tmp_path / "killer_policy.py").write_text(KILLER)
    monkeypatch.syspath_prepend(str(tmp_path))
    definition = tmp_path / "killer.json"
    definition.write_text(json.dumps({"name": "killer", "kind": "import",
                                      "params": {"factory": "killer_policy:KillsOnSeed"}}))
    suite = tiny([str(definition), "idm"], seeds="0-3")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_suite(suite, tmp_path / "run", workers=2, progress=False, report=False)
    eps = result.episodes.set_index(["policy", "seed"])["status"]
    assert eps.loc[("idm", slice(None))].eq("ok").all()
    assert eps.loc[("killer", 1)] == "error"
    assert eps.loc[("killer", [0, 2, 3])].eq("ok").all()
    failed = result.episodes[result.episodes["status"] != "ok"]
    assert "died" in failed["error"].iloc[0]
