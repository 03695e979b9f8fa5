"""Rollouts on Ray, one episode per task: the tables of the local rollout of the same seeds."""

from __future__ import annotations

import pandas as pd

from tap_bench.sim.rollout import rollout


def test_ray_rollout_gives_the_tables_of_the_local_rollout(ray_backend):
    seeds = [4, 1, 2]
    local = rollout("merge", "idm", seeds, duration=3, progress=False)
    on_ray = rollout("merge", "idm", seeds, backend=ray_backend, duration=3, progress=False)
    assert list(on_ray.episodes["seed"]) == seeds and len(on_ray.trajectories) > 0
    pd.testing.assert_frame_equal(on_ray.trajectories, local.trajectories)
    pd.testing.assert_frame_equal(on_ray.episodes, local.episodes)
