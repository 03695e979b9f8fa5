"""Bad parameters on the command line end in one message and exit 2, never a traceback."""

from __future__ import annotations

import json

import pytest

from tap_bench.cli import main
from tap_bench.errors import ParameterError


@pytest.mark.parametrize(("argv", "names"), [
    (["rollout", "--env", "merge", "--policy", "idm", "--seeds", "9-3", "-o", "{o}"],
     "runs backwards"),
    (["rollout", "--env", "merge", "--policy", "idm", "--seeds", "0", "--workers", "0",
      "-o", "{o}"], "workers"),
    (["rollout", "--env", "merge", "--policy", "idm", "--seeds", "0", "--duration", "nan",
      "-o", "{o}"], "duration"),
    (["rollout", "--env", "merge", "--policy", "idm", "--seeds", "0", "--retries", "-1",
      "-o", "{o}"], "--retries"),
    (["train", "--env", "highway", "--algo", "dqn", "--timesteps", "-5", "-o", "{o}.zip"],
     "timesteps"),
])
def test_bad_values_are_messages_with_exit_2(argv, names, tmp_path, capsys):
    argv = [a.replace("{o}", str(tmp_path / "out.parquet")) for a in argv]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert names in err and "Traceback" not in err


def test_compare_with_zero_resamples(tmp_path, capsys):
    from tap_bench.sim.rollout import rollout
    from tap_bench.tableio import write_table

    a, _ = rollout("merge", "idm", [0], duration=2, progress=False)
    write_table(a, tmp_path / "a.parquet")
    code = main(["compare", str(tmp_path / "a.parquet"), str(tmp_path / "a.parquet"),
                 "--resamples", "0", "-o", str(tmp_path / "cmp")])
    err = capsys.readouterr().err
    assert code == 2 and "--resamples" in err


def test_a_suite_with_a_bad_version_is_named(tmp_path, capsys):
    path = tmp_path / "s.json"
    path.write_text(json.dumps({"name": "s", "version": "abc", "envs": ["merge"],
                                "policies": ["idm"], "seeds": "0-1"}))
    code = main(["bench", "run", "--suite", str(path), "-o", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2 and "version" in err and "'abc'" in err


def test_parameter_error_names_parameter_value_and_what_is_allowed():
    err = ParameterError("workers", 0, "a positive integer")
    assert str(err) == "workers must be a positive integer, got 0."
    assert isinstance(err, ValueError)
    import pickle

    again = pickle.loads(pickle.dumps(err))
    assert str(again) == str(err) and again.parameter == "workers"


def test_a_warning_is_one_line_without_the_code_that_raised_it(tmp_path):
    """A user sees the warning's kind and message, not a line of tap-bench's source."""
    import os
    import subprocess
    import sys

    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "README.md").write_text("not a scene\n")
    env = dict(os.environ, PYTHONWARNINGS="default")
    out = subprocess.run([sys.executable, "-m", "tap_bench", "rollout", "--womd",
                          str(tmp_path / "scenes"), "--policy", "idm", "-o",
                          str(tmp_path / "out.parquet"), "--no-progress"],
                         capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    lines = out.stderr.splitlines()
    assert out.returncode == 2, out.stderr
    warned = [ln for ln in lines if "README.md: skipped" in ln]
    assert warned == [f"tap-bench: UserWarning: {tmp_path / 'scenes' / 'README.md'}: skipped, "
                      "not a TFRecord nor a file a reader claims by its name."], out.stderr
    assert len(lines) == 2, out.stderr  # the warning and the error, nothing else


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "two"])
def test_a_reward_setting_must_be_a_finite_number(value):
    from tap_bench.cli.train import _rewards

    assert _rewards(["progress_gain_reward=2"]) == {"progress_gain_reward": 2.0}
    with pytest.raises(SystemExit, match="is not a finite number"):
        _rewards([f"progress_gain_reward={value}"])


def test_hyperparameters_are_the_algorithm_s_settings_as_json_values():
    """gamma=0.95 reaches the training as a number; a key PPO does not take, one tap-bench
    sets itself (seed: --seed) and a value that is not JSON are refused with the fix."""
    pytest.importorskip("stable_baselines3")
    from tap_bench.cli.train import _hyperparameters

    assert _hyperparameters("ppo", ["gamma=0.95", 'policy_kwargs={"net_arch": [64]}']) == {
        "gamma": 0.95, "policy_kwargs": {"net_arch": [64]}}
    assert _hyperparameters("ppo", []) == {}
    with pytest.raises(SystemExit, match=r"'gama' is not a setting of PPO; use one of .*gamma"):
        _hyperparameters("ppo", ["gama=0.95"])
    with pytest.raises(SystemExit, match="'seed' is not a setting of PPO"):
        _hyperparameters("ppo", ["seed=3"])
    with pytest.raises(SystemExit, match="'buffer_size' is not a setting of PPO"):
        _hyperparameters("ppo", ["buffer_size=100"])
    assert _hyperparameters("dqn", ["buffer_size=100"]) == {"buffer_size": 100}
    with pytest.raises(SystemExit, match="'high' is not a JSON value"):
        _hyperparameters("ppo", ["gamma=high"])
    with pytest.raises(SystemExit, match="write KEY=VALUE"):
        _hyperparameters("ppo", ["gamma"])


@pytest.mark.parametrize(("algo", "item", "message"), [
    ("ppo", "gamma=-5", r"gamma=-5: gamma is the discount factor .*; give a value in \[0, 1\]"),
    ("ppo", "gamma=1.5", r"give a value in \[0, 1\]"),
    ("ppo", "gamma=true", "gamma of PPO takes a finite number"),
    ("ppo", "gamma=null", "gamma of PPO takes a finite number"),
    ("ppo", "gamma=NaN", "gamma of PPO takes a finite number"),
    ("ppo", "n_steps=0", r"n_steps=0: n_steps is the steps per env between updates; give a "
     r"value in \[1, inf\)"),
    ("ppo", "n_steps=1.5", "n_steps of PPO takes a whole number"),
    ("ppo", 'learning_rate="fast"', "learning_rate of PPO takes a finite number"),
    ("ppo", "learning_rate=0", r"give a value in \(0, inf\)"),
    ("ppo", "normalize_advantage=1", "normalize_advantage of PPO takes true or false"),
    ("ppo", "policy_kwargs=[64]", "policy_kwargs of PPO takes a mapping or null"),
    ("ppo", 'rollout_buffer_class="RolloutBuffer"', "is a class or a function, which a JSON "
     "value cannot give"),
    ("dqn", "train_freq=[4]", r"train_freq of DQN takes a whole number or a list of 2 "
     r"\(int, str\)"),
    ("dqn", "exploration_final_eps=2", r"give a value in \[0, 1\]"),
    # policy_kwargs: the arguments of the MlpPolicy trained (activation_fn="tanh" and a
    # misspelt key ended in tracebacks when the model was built)
    ("ppo", 'policy_kwargs={"activation_fn": "tanh"}', "activation_fn of PPO's MlpPolicy is "
     "a class or a function, which a JSON value cannot give"),
    ("ppo", 'policy_kwargs={"netarch": [64]}', r"'netarch' is not a setting of PPO's "
     r"MlpPolicy; use one of .*net_arch"),
    ("ppo", 'policy_kwargs={"net_arch": [64, "x"]}', r"net_arch of PPO's MlpPolicy takes a "
     r"list \(each item a whole number\) or a mapping"),
    ("dqn", 'policy_kwargs={"net_arch": {"pi": [64]}}', r"net_arch of DQN's MlpPolicy takes a "
     r"list \(each item a whole number\) or null\."),
])
def test_a_hyperparameter_of_the_wrong_type_or_range_is_refused_before_training(
        algo, item, message):
    """Values SB3 would take and train on to no purpose (gamma -5 or 1.5, true for a number)
    or fail on after the envs started, with a traceback (n_steps 0 or 1.5, a text for the
    learning rate, null for gamma), are refused naming the item and what it takes."""
    pytest.importorskip("stable_baselines3")
    from tap_bench.cli.train import _hyperparameters

    with pytest.raises(SystemExit, match=message):
        _hyperparameters(algo, [item])


def test_hyperparameters_of_their_type_pass_and_a_setting_given_twice_is_refused():
    pytest.importorskip("stable_baselines3")
    from tap_bench.cli.train import _hyperparameters

    assert _hyperparameters("ppo", ["learning_rate=1", "clip_range_vf=null", "gamma=1",
                                    "sde_sample_freq=-1"]) == {
        "learning_rate": 1.0, "clip_range_vf": None, "gamma": 1.0, "sde_sample_freq": -1}
    assert _hyperparameters("dqn", ['train_freq=[4, "step"]']) == {"train_freq": (4, "step")}
    arch = '{"net_arch": {"pi": [64], "vf": [32]}, "ortho_init": false}'
    assert _hyperparameters("a2c", [f"policy_kwargs={arch}"]) == {
        "policy_kwargs": {"net_arch": {"pi": [64], "vf": [32]}, "ortho_init": False}}
    with pytest.raises(SystemExit, match=r"gamma=0\.8: 'gamma' is given twice"):
        _hyperparameters("ppo", ["gamma=0.9", "gamma=0.8"])


def test_the_hyperparameters_reach_the_training_and_its_recorded_command(monkeypatch, tmp_path):
    pytest.importorskip("stable_baselines3")
    import tap_bench.rl.training as training
    from tap_bench.cli import main

    seen = {}

    def fake_train(algo, env, **kw):
        seen.update(kw)
        raise SystemExit(0)

    monkeypatch.setattr(training, "train", fake_train)
    with pytest.raises(SystemExit):
        main(["train", "--algo", "ppo", "--env", "highway", "--hyperparameters", "gamma=0.9",
              "--timesteps", "64", "--no-curve", "-o", str(tmp_path / "m.zip")])
    assert seen["hyperparameters"] == {"gamma": 0.9}
    assert "--hyperparameters gamma=0.9 --timesteps 64" in seen["command"]


@pytest.mark.parametrize("seed", ["-1", "4294967296", "x"])
def test_a_training_seed_numpy_cannot_take_is_refused_by_the_option(seed, capsys):
    """``--seed -1`` failed with numpy's traceback once the training envs had started."""
    from tap_bench.cli import main

    argv = ["train", "--algo", "ppo", "--env", "highway", "--timesteps", "8", "-o",
            "never.zip", "--seed", seed]
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    assert (f"argument --seed: {seed!r} is not a seed: give a whole number from 0 to "
            "4294967295") in capsys.readouterr().err


def test_an_unknown_algorithm_is_refused_before_anything_is_said(monkeypatch, capsys):
    pytest.importorskip("stable_baselines3")
    from tap_bench.cli import main

    assert main(["train", "--algo", "pp0", "--env", "womd", "--womd", "x.tfrecord",
                 "--timesteps", "8", "-o", "never.zip"]) == 2
    out = capsys.readouterr()
    assert "unknown algorithm 'pp0'. Did you mean 'ppo'?" in out.err and out.out == ""
