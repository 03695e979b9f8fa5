"""The WOMD IDM ego's own decision and move against highway-env's ``IDMVehicle``.

``WomdIDMVehicle`` decides (``act``, ``steering_control``) and moves (``step``) with
tap-bench's own code (``sim.driver_models``). highway-env's ``IDMVehicle`` is the
reference: the same scenes driven with its ``act``, its ``steering_control`` and its
``step`` in their place must give the same decisions, crashes and statuses, and positions
within 1e-6 m, on every real scene at hand (the samples; the development scenes in the slow
suite), with log and idm traffic. A tolerance, not bit identity: the two sum in different
orders.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle

import tap_bench  # noqa: F401  (registers the envs)
from tap_bench.sim.policies import load_policy
from tap_bench.sim.womd_env import make_womd_env
from tap_bench.sim.womd_road import WomdIDMVehicle

SAMPLES = ["motion_data_one_scenario.tfrecord", "womd_scenario_input.tfrecord",
           "motion_data_one_example.tfrecord", "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl"]


def _drive(files: list[str], traffic: str) -> tuple[pd.DataFrame, list[dict]]:
    """Every scene of ``files`` driven by the IDM ego: the trajectory table and each
    episode's info."""
    env = make_womd_env(files, traffic=traffic)
    policy = load_policy("idm")
    tables, infos = [], []
    for seed in range(len(env.unwrapped.catalog)):
        obs, _ = env.reset(seed=seed)
        policy.reset(env, seed=seed)
        done = False
        while not done:
            obs, _, terminated, truncated, _ = env.step(policy.act(obs))
            done = terminated or truncated
        tables.append(env.trajectories(policy="idm"))
        info = env.episode_info()
        infos.append({k: info[k] for k in ("crash_with", "crash_at_fault", "off_road",
                                           "route_progress", "traffic_collisions")})
    env.close()
    return pd.concat(tables, ignore_index=True), infos


def _highway_envs(monkeypatch) -> None:
    """Put highway-env's own decision and move in the IDM ego's place (the hidden vehicle's
    wait for its step stays tap-bench's: highway-env has no such vehicle)."""
    own_step = WomdIDMVehicle.step

    def act(self, action=None):
        if not self.hidden:
            IDMVehicle.act(self, action)

    def step(self, dt):
        if self.hidden:
            return own_step(self, dt)
        IDMVehicle.step(self, dt)
        self.speed = max(self.speed, 0.0)

    monkeypatch.setattr(WomdIDMVehicle, "act", act)
    monkeypatch.setattr(WomdIDMVehicle, "step", step)
    monkeypatch.setattr(WomdIDMVehicle, "steering_control",
                        ControlledVehicle.steering_control)


@pytest.mark.parametrize("scenes", ["samples",
                                    pytest.param("development", marks=pytest.mark.slow)])
@pytest.mark.parametrize("traffic", ["log", "idm"])
def test_the_idm_egos_own_act_and_step_equal_highway_envs(womd_dir, scenes, traffic,
                                                           monkeypatch):
    files = [str(womd_dir / f) for f in SAMPLES]
    if scenes == "development":
        files = [str(womd_dir.parent / "womd-dev" / "dev.tfrecord")]
        if not Path(files[0]).is_file():
            pytest.skip(f"development scenes not found: {files[0]}")
    ours, our_infos = _drive(files, traffic)
    with monkeypatch.context() as m:
        _highway_envs(m)
        theirs, their_infos = _drive(files, traffic)
    # the same crashes, fault, off road and progress (NaN where the ego did not move)
    pd.testing.assert_frame_equal(pd.DataFrame(our_infos), pd.DataFrame(their_infos),
                                  check_exact=False, rtol=0, atol=1e-9)
    assert len(ours) == len(theirs) and len(ours) > 1000
    keys = ["scenario_id", "track_id", "t"]
    pd.testing.assert_frame_equal(ours[keys], theirs[keys])
    for column in ("x", "y"):
        assert np.nanmax(np.abs(ours[column].to_numpy() - theirs[column].to_numpy())) < 1e-6
    assert np.nanmax(np.abs(np.angle(np.exp(1j * (ours["heading"].to_numpy()
                                                  - theirs["heading"].to_numpy()))))) < 1e-6


def test_the_obstacles_asked_again_within_a_step_are_those_computed_afresh(womd_dir,
                                                                           monkeypatch):
    """The IDM ego's accelerations behind what it finds on its way are computed once per
    step and state (``_obstacle_accelerations``' memo); every answer, the memo's included,
    equals the searches run again from nothing (stop points and signs remember what they
    decided the first time, so running them again answers the same)."""
    own = WomdIDMVehicle._obstacle_accelerations
    asked = {"calls": 0, "again": 0}

    def checked(self, p, v, v0):
        again = self.__dict__.get("_obstacle_memo") is not None
        got = own(self, p, v, v0)
        self.__dict__.pop("_obstacle_memo")
        fresh = own(self, p, v, v0)
        assert len(got) == len(fresh)
        assert all(a == b or (a != a and b != b) for a, b in zip(got, fresh, strict=True))
        asked["calls"] += 1
        asked["again"] += again
        return got

    monkeypatch.setattr(WomdIDMVehicle, "_obstacle_accelerations", checked)
    files = [str(womd_dir / f) for f in SAMPLES[:2]]
    _drive(files, "log")
    assert asked["calls"] > 100 and asked["again"] > 50


def test_the_obstacles_ahead_in_one_pass_are_the_searches_one_after_the_other(womd_dir,
                                                                              monkeypatch):
    """WomdRoad.obstacles_ahead (one compiled pass) answers what leader_ahead,
    corridor_leader and the IDM ego's _standing_obstacles answer one after the other, at
    every step of two sample scenes: the same leader and distance,
    corridor, and the same gaps in the same order; the walkers it searched afresh searched
    afresh again (what it remembered for the step is forgotten first)."""
    from tap_bench.sim.womd_road import WomdRoad

    own = WomdRoad.obstacles_ahead
    asked = {"calls": 0, "leader": 0, "standing": 0, "walkers": 0}

    def checked(self, vehicle):
        before = vehicle.__dict__.get("_walker_distance")
        got = own(self, vehicle)
        if got is None:
            return got
        if vehicle.__dict__.get("_walker_distance") is not before:  # searched afresh
            asked["walkers"] += 1
            if before is None:
                vehicle.__dict__.pop("_walker_distance")
            else:
                vehicle.__dict__["_walker_distance"] = before
        want = (*self.leader_ahead(vehicle), self.corridor_leader(vehicle),
                vehicle._standing_obstacles())
        assert got[0] is want[0] and got[1] == want[1] and got[2] == want[2]
        assert got[3] == want[3]
        asked["calls"] += 1
        asked["leader"] += got[0] is not None
        asked["standing"] += bool(got[3])
        return got

    monkeypatch.setattr(WomdRoad, "obstacles_ahead", checked)
    _drive([str(womd_dir / f) for f in SAMPLES[:2]], "log")
    assert asked["calls"] > 100 and min(asked.values()) > 10, asked
