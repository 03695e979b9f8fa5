"""``tap-bench realism`` end to end on a real scene, and the constant-velocity traffic."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from tap_bench.cli import main
from tap_bench.sim.womd_scene import CURRENT_STEP

DEV = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "womd-dev" / \
    "dev.tfrecord"
SMALL = "tfrecord-00012-of-00150_204.json"  # 17 tracks


@pytest.fixture(scope="module")
def dev_file() -> str:
    if not DEV.is_file():
        pytest.skip(f"the development scenes are not in {DEV}")
    return str(DEV.resolve())


def _realism(tmp_path: Path, dev_file: str, traffic: str, name: str, *extra: str) -> dict:
    out = tmp_path / f"{name}.json"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        code = main(["realism", "--womd", dev_file, "--scenario", SMALL, "--traffic",
                     traffic, "--rollouts", "2", "--resamples", "100", "-o", str(out),
                     *extra])
    assert code == 0
    return json.loads(out.read_text())


def test_the_log_scores_above_constant_velocity(tmp_path, dev_file, capsys):
    log = _realism(tmp_path, dev_file, "log", "log")
    cv = _realism(tmp_path, dev_file, "constant-velocity", "cv")
    assert log["scenes"] == cv["scenes"] == 1
    assert log["agents"] == cv["agents"] > 0
    assert 0 < cv["meta_metric"] < log["meta_metric"] <= 1
    # the log against itself: no collision, off-road or red light it did not have
    for feature in ("collision_indication", "offroad_indication", "traffic_light_violation"):
        assert log["overall"][feature]["value"] > 0.99
    assert set(log["by_object_type"]) <= {"vehicle", "pedestrian", "cyclist"}
    assert "meta-metric" in capsys.readouterr().out


def test_constant_velocity_traffic_keeps_the_velocity_at_the_current_time(dev_file):
    from tap_bench.sim.policies import load_policy
    from tap_bench.sim.womd_env import make_womd_env

    env = make_womd_env([dev_file], traffic="constant-velocity")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        obs, _ = env.reset(options={"scenario_id": SMALL})
        policy = load_policy("log")
        policy.reset(env, seed=0)
        for _ in range(6):
            obs, *_ = env.step(policy.act(obs))
    scene = env.scene
    rec = env.recorded_states()
    k = env.unwrapped.clock[0]
    moved = 0
    for row in np.flatnonzero(scene.valid[:, CURRENT_STEP]):
        if row == scene.ego:
            continue
        dt = scene.times[k] - scene.times[CURRENT_STEP]
        dt_sim = 0.1 * (k - CURRENT_STEP)  # the simulation's step
        assert dt == pytest.approx(dt_sim, abs=0.01)
        assert rec["x"][row, k] == pytest.approx(
            scene.x[row, CURRENT_STEP] + scene.vx[row, CURRENT_STEP] * dt_sim, abs=1e-6)
        assert rec["y"][row, k] == pytest.approx(
            scene.y[row, CURRENT_STEP] + scene.vy[row, CURRENT_STEP] * dt_sim, abs=1e-6)
        assert rec["heading"][row, k] == pytest.approx(scene.heading[row, CURRENT_STEP],
                                                       abs=1e-6)
        moved += np.hypot(scene.vx[row, CURRENT_STEP], scene.vy[row, CURRENT_STEP]) > 0.5
    assert moved > 0


def test_the_same_seed_gives_the_same_score_bit_for_bit(tmp_path, dev_file):
    # idm traffic draws its drivers per rollout (named streams): two runs agree to the bit
    first = _realism(tmp_path, dev_file, "idm", "a")
    again = _realism(tmp_path, dev_file, "idm", "b")
    for run in (first, again):
        run.pop("cpu_seconds")
        run.pop("wall_seconds")
    assert json.dumps(first, sort_keys=True) == json.dumps(again, sort_keys=True)
    assert 0 < first["meta_metric"] <= 1
