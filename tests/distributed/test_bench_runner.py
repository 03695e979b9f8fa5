"""``bench run`` with a Ray backend: the rollout chunks run as Ray tasks, same episodes."""

from __future__ import annotations

import warnings

import pandas as pd


def test_a_suite_run_on_ray_gives_the_episodes_of_a_local_run(ray_backend, tmp_path):
    from tap_bench.bench.run.runner import run_suite
    from tap_bench.bench.suite import suite_from_dict

    suite = suite_from_dict({"name": "tiny", "envs": ["merge"], "policies": ["idm"],
                             "seeds": "0-1", "env_overrides": {"merge": {"duration": 3}},
                             "bootstrap": {"n_resamples": 100}})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        local = run_suite(suite, tmp_path / "local", workers=1, progress=False, report=False)
        on_ray = run_suite(suite, tmp_path / "ray", progress=False, report=False,
                           backend=ray_backend)
    cols = ["env", "policy", "seed", "status", "sdl", "mean_speed", "rms_jerk", "crashed"]
    assert (on_ray.episodes["status"] == "ok").all()
    pd.testing.assert_frame_equal(on_ray.episodes[cols], local.episodes[cols])


def test_a_suite_of_recorded_scenes_runs_on_ray_as_locally(ray_backend, tmp_path, womd_dir):
    from tap_bench.bench.run.runner import run_suite
    from tap_bench.bench.suite import suite_from_dict

    suite = suite_from_dict({
        "name": "womd-tiny", "policies": ["log", "idm"], "reference_policy": "log",
        "envs": [{"womd": str(womd_dir / "womd_scenario_input.tfrecord"), "traffic": "idm"}],
        "seeds": "all", "bootstrap": {"n_resamples": 100}})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        local = run_suite(suite, tmp_path / "local", workers=1, progress=False, report=False)
        on_ray = run_suite(suite, tmp_path / "ray", progress=False, report=False,
                           backend=ray_backend)
    cols = ["env", "policy", "seed", "scenario_id", "status", "sdl", "route_progress",
            "log_ade", "crashed"]
    assert (on_ray.episodes["status"] == "ok").all()
    pd.testing.assert_frame_equal(on_ray.episodes[cols], local.episodes[cols])
