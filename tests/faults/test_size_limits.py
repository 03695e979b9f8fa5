"""Limits on every size, checked before the work: each refusal names the parameter, the
value and the limit (bootstrap resamples, gate permutations, training envs, vehicles,
lanes, episode duration, scenarios in a WOMD viewer), and the viewer of WOMD files reads
only the scenarios it shows."""

from __future__ import annotations

import warnings

import pytest
from fault_helpers import label_table

from tap_bench.bench.suite import MAX_PERMUTATIONS, suite_from_dict
from tap_bench.errors import ParameterError, TapBenchError
from tap_bench.sim.scenario_env import get_scenario
from tap_bench.sim.scenario_format import MAX_DURATION, SIZE_LIMITS
from tap_bench.stats.bootstrap import MAX_RESAMPLES, BootstrapConfig


def _named(err: BaseException, parameter: str, value: str, limit: str) -> None:
    text = str(err)
    assert parameter in text and value in text and limit in text, text


def test_bootstrap_resamples_are_bounded():
    with pytest.raises(ParameterError) as err:
        BootstrapConfig(n_resamples=10**9)
    _named(err.value, "n_resamples", "1,000,000,000", f"{MAX_RESAMPLES:,}")
    assert BootstrapConfig(n_resamples=MAX_RESAMPLES).n_resamples == MAX_RESAMPLES
    with pytest.raises(TapBenchError) as err:
        suite_from_dict({"name": "s", "envs": ["merge"], "policies": ["idm"], "seeds": "0-1",
                         "bootstrap": {"n_resamples": 10**9}})
    _named(err.value, "n_resamples", "1,000,000,000", f"{MAX_RESAMPLES:,}")


def test_resamples_on_the_command_line_are_named_as_typed(tmp_path, cli):
    a, b = tmp_path / "a.parquet", tmp_path / "b.parquet"
    label_table("a", range(6)).to_parquet(a)
    label_table("b", range(6)).to_parquet(b)
    code, _, err = cli("compare", a, b, "-o", tmp_path / "out", "--resamples", "1000000000")
    assert code == 2 and "Traceback" not in err
    _named(err, "--resamples", "1,000,000,000", f"{MAX_RESAMPLES:,}")
    assert not (tmp_path / "out").exists()


def test_gate_permutations_are_bounded():
    with pytest.raises(TapBenchError) as err:
        suite_from_dict({"name": "s", "envs": ["merge"], "policies": ["idm"], "seeds": "0-1",
                         "gate": {"n_permutations": 10**9}})
    _named(err.value, "n_permutations", "1,000,000,000", f"{MAX_PERMUTATIONS:,}")


def test_training_envs_are_bounded_before_any_process(tmp_path, cli):
    from tap_bench.rl.training import MAX_N_ENVS

    code, _, err = cli("train", "--algo", "dqn", "--env", "highway", "--timesteps", "10",
                       "--n-envs", "1000", "-o", tmp_path / "m.zip")
    assert code == 2 and "Traceback" not in err
    _named(err, "n_envs", "1000", str(MAX_N_ENVS))
    assert "--n-envs" in err and not list(tmp_path.iterdir())


@pytest.mark.parametrize("key", sorted(SIZE_LIMITS))
def test_scene_sizes_are_bounded(key):
    limit = SIZE_LIMITS[key]
    with pytest.raises(ParameterError) as err:
        get_scenario("highway").with_overrides({key: 100_000})
    _named(err.value, key, "100000", f"{limit:,}")
    get_scenario("highway").with_overrides({key: 3})  # a normal size is fine


@pytest.mark.parametrize("duration", [1e9, MAX_DURATION + 1])
def test_episode_duration_is_bounded(duration, tmp_path, cli):
    with pytest.raises(ParameterError) as err:
        get_scenario("merge").with_overrides(duration=duration)
    _named(err.value, "duration", f"{duration!r}", f"{MAX_DURATION:g}")
    code, _, err_text = cli("rollout", "--env", "merge", "--policy", "idm", "--seeds", "0",
                            "--duration", str(duration), "-o", tmp_path / "t.parquet")
    assert code == 2 and "Traceback" not in err_text and "duration" in err_text


def test_the_womd_viewer_reads_only_the_scenarios_it_shows(tmp_path, cli, monkeypatch,
                                                           womd_dir):
    from tap_bench.bench.report.viewer import build

    shards = [womd_dir / "motion_data_one_example.tfrecord",
              womd_dir / "motion_data_one_scenario.tfrecord",
              womd_dir / "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl",
              womd_dir / "womd_scenario_input.tfrecord"]
    ids = ["a3bb37c25ce56418", "637f20cafde22ff8", "eb4b91b10ca94ff2"]
    read = []
    original = build.iter_womd

    def counting(paths, **kwargs):
        for table in original(paths, **kwargs):
            read.append(table["scenario_id"].iat[0])
            yield table

    monkeypatch.setattr(build, "iter_womd", counting)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        page = build.write_womd_viewer(shards, tmp_path / "viewer", max_scenarios=2)
    assert page.is_file()
    assert read == ids  # the third only tells that there is more
    assert any("first 2 scenarios" in str(w.message) for w in caught)
    index = (tmp_path / "viewer" / "data" / "index.js").read_text()
    shown = [f'"id":"{sid}"' in index for sid in ids]
    assert shown == [True, True, False]
    for bad in (0, build.MAX_VIEW_SCENARIOS + 1):
        with pytest.raises(ParameterError) as err:
            build.write_womd_viewer(shards, tmp_path / "v2", max_scenarios=bad)
        _named(err.value, "max_scenarios", str(bad), str(build.MAX_VIEW_SCENARIOS))
    code, _, err = cli("view", *shards, "-o", tmp_path / "v3", "--no-open",
                       "--max-scenarios", "100000")
    assert code == 2 and "--max-scenarios" in err and "Traceback" not in err
