"""Training: a few dozen steps give a model that loads by name and by file and drives, with
its learning curve (table and plot) beside it; the curve measures what it says."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pandas as pd
import pytest

from tap_bench.rl.curve import CURVE_COLUMNS, CurveConfig, coverage_reference, curve_row
from tap_bench.sim import make_env
from tap_bench.sim.policies import get_definition, load_policy
from tap_bench.sim.rollout import rollout
from tap_bench.sim.scenario_env import get_scenario

# Stable-Baselines3 (and torch) are imported by the tests that run, not when the suite is
# collected: a pytest worker that runs none of this file's tests does not pay for them.
pytestmark = pytest.mark.skipif(importlib.util.find_spec("stable_baselines3") is None,
                                reason="needs stable-baselines3 (the sb3 extra)")

TINY = {"ppo": {"n_steps": 16, "batch_size": 16, "n_epochs": 1},
        "dqn": {"learning_starts": 8, "buffer_size": 200}, "a2c": {"n_steps": 4}}
TINY_CURVE = CurveConfig(points=1, seeds="500-501", reference="vocabulary")


@pytest.mark.parametrize(("algo", "n_envs"), [("ppo", 2), ("dqn", 1), ("dqn", 2)])
def test_a_short_training_gives_a_loadable_model_and_its_learning_curve(tmp_path, algo,
                                                                       n_envs, write_scenario):
    from tap_bench.rl.training import train

    short = write_scenario("short", duration=5)  # 3 vehicles, 5 decisions an episode
    output = tmp_path / f"{algo}-tiny.zip"
    result = train(algo, short, timesteps=32, seed=3, output=output, n_envs=n_envs,
                   hyperparameters=TINY[algo], curve=TINY_CURVE, log_dir=tmp_path / "log")
    assert result.model_path.is_file() and result.definition_path.is_file()
    assert result.timesteps >= 32 and result.steps_per_second > 0
    assert result.episodes >= 4  # 5-decision episodes, or shorter when the ego crashes
    doc = json.loads(result.definition_path.read_text())
    assert doc["params"]["timesteps"] == 32 and doc["params"]["seed"] == 3
    assert doc["params"]["observation"] == {"type": "Kinematics"}
    assert doc["params"]["train_seconds"] <= result.seconds

    # the curve: the untrained agent and the end of training, on the curve's seeds
    curve = pd.read_csv(result.curve_path)
    assert list(curve.columns) == list(CURVE_COLUMNS)
    assert curve["timesteps"].tolist() == [0, result.timesteps]
    assert (curve["episodes"] == 2).all()
    assert curve["coverage"].between(0, 1).all() and (curve["n_distinct"] >= 1).all()
    assert (curve["crash_low"] <= curve["crash_rate"]).all()
    assert (curve["crash_rate"] <= curve["crash_high"]).all()
    assert result.plot_path.read_bytes()[:4] == b"\x89PNG"
    with open(tmp_path / "log" / "progress.csv") as handle:
        logged = pd.read_csv(handle)
    assert "tap/coverage" in logged.columns

    definition = get_definition(result.definition_path)
    assert definition.kind == "sb3" and definition.name == f"{algo}-tiny"
    # the .zip alone finds its definition beside it (the observation config is there)
    by_zip = get_definition(result.model_path)
    assert by_zip.name == definition.name
    assert by_zip.params["observation"] == definition.params["observation"]
    with pytest.warns(UserWarning, match="pickles"):
        _, episodes = rollout("highway", result.model_path, [0, 1], duration=3,
                              progress=False)
    assert episodes["status"].tolist() == ["ok", "ok"], episodes["error"].tolist()
    assert episodes["policy"].tolist() == [f"{algo}-tiny"] * 2


def test_ctrl_c_saves_the_model_and_the_curve_trained_so_far(tmp_path, write_scenario,
                                                          monkeypatch):
    from tap_bench.rl.callbacks import CoverageCallback
    from tap_bench.rl.training import train

    step = CoverageCallback._on_step

    def interrupted(self):  # Ctrl-C once 32 steps are done
        if self.num_timesteps >= 32:
            raise KeyboardInterrupt
        return step(self)

    monkeypatch.setattr(CoverageCallback, "_on_step", interrupted)
    short = write_scenario("short", duration=5)
    result = train("ppo", short, timesteps=10_000, seed=0, output=tmp_path / "ppo-cut.zip",
                   hyperparameters=TINY["ppo"], curve=TINY_CURVE)
    doc = json.loads(result.definition_path.read_text())
    assert doc["params"]["timesteps"] == result.timesteps < 10_000
    assert doc["params"]["interrupted_of"] == 10_000
    assert result.curve["timesteps"].tolist() == [0, result.timesteps]
    # the episodes ended (5 decisions or fewer each, 2 envs): counted, not SB3's own count,
    # which on-policy algorithms do not keep (0)
    assert result.episodes >= result.timesteps // 10
    with pytest.warns(UserWarning, match="pickles"):
        load_policy(result.model_path).reset(
            make_env(short), seed=0)


def test_idm_covers_its_own_rollouts_completely_and_crashes_less_than_lane_keeping():
    scenario = get_scenario("highway").with_overrides(duration=10)
    config = CurveConfig(points=1, seeds="0-2", reference="idm", n_resamples=200)
    reference = coverage_reference(config, scenario)
    assert reference.kind == "corpus" and reference.n_trajectories == 3
    idm = curve_row(load_policy("idm"), scenario, reference, config, timesteps=7, seconds=1.0,
                    train_return=np.nan)
    assert idm["timesteps"] == 7 and idm["episodes"] == 3
    # the same policy on the same seeds shows exactly the reference's labels
    assert idm["coverage"] == idm["weighted_coverage"] == 1.0
    assert idm["crash_rate"] == 0.0 and idm["crash_low"] == 0.0 and idm["crash_high"] > 0.3
    keeping = curve_row(load_policy("lane-keeping"), scenario, reference, config,
                        timesteps=7, seconds=1.0, train_return=np.nan)
    assert keeping["crash_rate"] > idm["crash_rate"]
    assert keeping["return_mean"] < idm["return_mean"]


def test_a_label_table_is_a_reference_and_bad_settings_are_refused(tmp_path):
    labels = pd.DataFrame({"scenario_id": ["a", "b", "c"], "track_id": ["1", "1", "2"],
                           "level": "maneuver", "object_type": "vehicle",
                           "sdl": ["Straight | Cruise", "Straight | Cruise", "Left Merge"]})
    path = tmp_path / "womd_labels.csv"
    labels.to_csv(path, index=False)
    reference = coverage_reference(CurveConfig(reference=str(path)), get_scenario("highway"))
    assert list(reference.items) == ["Left Merge", "Straight | Cruise"]
    np.testing.assert_allclose(reference.weights, [1 / 3, 2 / 3])
    with pytest.raises(ValueError, match="points"):
        CurveConfig(points=0)
    with pytest.raises(ValueError, match="at least 2"):
        CurveConfig(seeds="5")


def test_bad_training_arguments_are_refused_before_any_work(tmp_path):
    from tap_bench.rl.training import train

    with pytest.raises(ValueError, match=r"\.zip"):
        train("ppo", "highway", timesteps=10, seed=0, output=tmp_path / "m.pt")
    with pytest.raises(ValueError, match="n_envs"):
        train("ppo", "highway", timesteps=10, seed=0, output=tmp_path / "m.zip", n_envs=0)
    with pytest.raises(ValueError, match="timesteps"):
        train("ppo", "highway", timesteps=0, seed=0, output=tmp_path / "m.zip")


def test_keep_best_saves_the_weights_of_the_best_evaluation(tmp_path, write_scenario):
    """The saved model drives the curve's seeds exactly as at its best evaluation."""
    from stable_baselines3 import DQN

    from tap_bench.rl.curve import GreedyModelPolicy
    from tap_bench.rl.training import train

    short = write_scenario("short", duration=5)
    config = CurveConfig(points=4, seeds="500-503", reference="vocabulary")
    result = train("dqn", short, timesteps=120, seed=1, output=tmp_path / "best.zip", n_envs=1,
                   hyperparameters={**TINY["dqn"], "learning_rate": 5e-3}, curve=config,
                   keep="best")
    curve = result.curve
    best = curve.loc[curve["return_mean"].idxmax()]  # the first of equal maxima
    assert result.kept_timesteps == best["timesteps"]
    doc = json.loads(result.definition_path.read_text())["params"]
    assert doc["kept"] == "best" and doc["kept_timesteps"] == best["timesteps"]
    assert doc["timesteps"] == result.timesteps  # the steps trained, whichever weights kept
    model = DQN.load(result.model_path, device="cpu")
    again = curve_row(GreedyModelPolicy(model, "best", {"type": "Kinematics"}),
                      get_scenario(short), coverage_reference(config, get_scenario(short)),
                      config, timesteps=0, seconds=0.0, train_return=float("nan"))
    assert again["return_mean"] == pytest.approx(best["return_mean"], abs=1e-9)
    # the definition loads as a policy, and says which weights it holds
    policy = load_policy(result.definition_path)
    assert policy.training["kept"] == "best"
    assert policy.training["kept_timesteps"] == best["timesteps"]
    # the curve did change: otherwise "best" could not be told from "last"
    assert curve["return_mean"].nunique() > 1


def test_keep_best_needs_the_curve_and_keep_takes_two_values(tmp_path):
    from tap_bench.rl.training import train

    with pytest.raises(ValueError, match="curve"):
        train("dqn", "highway", timesteps=10, seed=0, output=tmp_path / "m.zip", keep="best")
    with pytest.raises(ValueError, match="keep"):
        train("dqn", "highway", timesteps=10, seed=0, output=tmp_path / "m.zip",
              keep="first")


@pytest.mark.slow
def test_a_longer_training_on_the_fast_variant_learns_to_crash_less(tmp_path):
    from tap_bench.rl.training import train

    config = CurveConfig(points=1, seeds="500-509", reference="vocabulary")
    result = train("ppo", "highway", timesteps=3000, seed=0, output=tmp_path / "ppo.zip",
                   curve=config)
    first, last = result.curve.iloc[0], result.curve.iloc[-1]
    assert last["return_mean"] > first["return_mean"]


def test_a_model_for_another_action_space_is_refused_clearly(tmp_path):
    import gymnasium as gym

    from tap_bench.errors import TapBenchError
    from tap_bench.sim.sb3 import algorithm_class

    env = gym.make("tap_bench/highway-v0", record=False)
    model = algorithm_class("ppo")("MlpPolicy", env, n_steps=16, batch_size=16, seed=0,
                                   device="cpu")
    path = tmp_path / "ppo-highway-untrained.zip"
    model.save(path)
    policy = load_policy(path)
    intersection = gym.make("tap_bench/intersection-v0", config={"observation": {
        "type": "Kinematics"}})
    with pytest.warns(UserWarning, match="pickles"), \
            pytest.raises(TapBenchError, match="action space"):
        policy.reset(intersection, seed=0)


def test_overlapped_gradient_steps_run_while_the_envs_simulate_and_none_is_lost(
        write_scenario, tmp_path, monkeypatch):
    """DQN over several envs takes its gradient steps after the next actions are sent; it
    takes as many as the plain loop, and the last ones before the training ends. SB3's
    default logger (an empty SB3-<date> folder in the temporary folder) is not used."""
    import tempfile

    from stable_baselines3 import DQN
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.vec_env import DummyVecEnv, VecEnvWrapper

    from tap_bench.rl.overlap import FlushPendingCallback, OverlapVecEnv, overlapping
    from tap_bench.rl.training import HYPERPARAMETERS
    from tap_bench.sim.scenario_env import ScenarioEnv

    scenario = get_scenario(write_scenario("short", duration=5))
    events: list[str] = []
    monkeypatch.delenv("SB3_LOGDIR", raising=False)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))

    class Spy(VecEnvWrapper):  # what the workers are asked, in order
        def reset(self):
            return self.venv.reset()

        def step_async(self, actions):
            events.append("sent")
            self.venv.step_async(actions)

        def step_wait(self):
            events.append("waited")
            return self.venv.step_wait()

    def learner(overlap: bool):
        venv = DummyVecEnv([lambda: ScenarioEnv(scenario, record=False, fast=True)] * 2)
        venv.seed(0)
        env, cls, callbacks = Spy(venv), DQN, []
        if overlap:
            env = OverlapVecEnv(env)
            cls = overlapping(DQN, env)
            callbacks = [FlushPendingCallback(env)]
        model = cls("MlpPolicy", env, seed=0, device="cpu",
                    **{**HYPERPARAMETERS["dqn"], **TINY["dqn"]})
        real_train = DQN.train

        def noted(self, gradient_steps, batch_size=100):
            events.append("train")
            real_train(self, gradient_steps, batch_size)

        DQN.train = noted
        model.set_logger(Logger(None, []))  # no log: SB3's default writes a folder
        try:
            model.learn(total_timesteps=40, callback=CallbackList(callbacks))
        finally:
            DQN.train = real_train
        return model

    plain = learner(overlap=False)
    plain_events, events[:] = list(events), []
    overlapped = learner(overlap=True)
    assert plain._n_updates == overlapped._n_updates > 10
    assert plain_events.count("train") == events.count("train")
    # plain: sent, waited, train; overlapped: sent, train, waited (the gradient steps run
    # while the step is simulated), and the last gradient steps before the end
    assert "waited,train,sent" in ",".join(plain_events)
    assert "sent,train,waited" in ",".join(events)
    assert "waited,train,sent" not in ",".join(events)
    assert events[-1] == "train"
    assert not list(tmp_path.glob("SB3-*"))


@pytest.mark.slow
def test_a_plain_script_without_a_main_guard_trains_on_two_envs(tmp_path, write_scenario):
    """The worker processes do not run the caller's script again. Slow (a fresh interpreter
    importing torch and SB3, and a forkserver preloading them: about 6 CPU s); the fast
    suite checks the parts: test_only_a_script_without_a_main_guard_is_hidden_from_the_workers
    (what hides an unguarded script from the workers, which train wraps the workers' start
    in) and test_a_training_is_the_same_wherever_its_envs_are_stepped (training with envs in
    worker processes)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    short = write_scenario("short", duration=5)
    script = tmp_path / "train_it.py"
    script.write_text(
        "from tap_bench.rl.training import train\n"
        "print('script ran')\n"
        f"result = train('ppo', {str(short)!r}, timesteps=32, seed=0, n_envs=2,\n"
        f"               hyperparameters={TINY['ppo']!r}, output={str(tmp_path / 'm.zip')!r})\n"
        "print('trained', result.timesteps)\n")
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), os.environ.get(
        "PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          env=env, cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("script ran") == 1
    assert "trained 32" in done.stdout and "RuntimeError" not in done.stderr


@pytest.mark.parametrize(("source", "guarded"), [
    ("train()\n", False),
    ("def main():\n    train()\n\nif __name__ == '__main__':\n    main()\n", True),
    ("if '__main__' == __name__:\n    train()\n", True),
    ("def f():\n    if __name__ == '__main__':\n        pass\ntrain()\n", False),
    ("if __name__ != '__main__':\n    pass\ntrain()\n", False),
    ("this is not python(\n", True),  # unreadable: multiprocessing's usual behaviour
])
def test_only_a_script_without_a_main_guard_is_hidden_from_the_workers(tmp_path, monkeypatch,
                                                                       source, guarded):
    import sys
    import types

    from tap_bench.rl.training import _has_main_guard, _main_not_rerun

    script = tmp_path / "script.py"
    script.write_text(source)
    main = types.ModuleType("__main__")
    main.__file__ = str(script)
    main.__spec__ = None
    monkeypatch.setitem(sys.modules, "__main__", main)
    assert _has_main_guard(main) is guarded
    with _main_not_rerun():
        assert (getattr(main, "__file__", None) == str(script)) is guarded
    assert main.__file__ == str(script) and main.__spec__ is None  # restored
    with pytest.raises(KeyError), _main_not_rerun():
        raise KeyError("inside")
    assert main.__file__ == str(script)
    interactive = types.ModuleType("__main__")  # python -c, a REPL: no file at all
    monkeypatch.setitem(sys.modules, "__main__", interactive)
    assert _has_main_guard(interactive)


def test_the_curve_has_points_plus_one_rows_and_its_last_one_is_the_saved_model(
        tmp_path, write_scenario):
    """Steps that do not divide into the points, and PPO's rollouts running past the
    timesteps asked for: still the start, points - 1 evaluations during training and one of
    the weights as saved."""
    from stable_baselines3 import PPO

    from tap_bench.rl.curve import GreedyModelPolicy
    from tap_bench.rl.training import train

    short = write_scenario("short", duration=5)
    config = CurveConfig(points=3, seeds="500-502", reference="vocabulary")
    result = train("ppo", short, timesteps=50, seed=2, output=tmp_path / "p.zip", n_envs=2,
                   hyperparameters=TINY["ppo"], curve=config)
    steps = result.curve["timesteps"].tolist()
    assert len(steps) == config.points + 1, steps
    assert steps[0] == 0 and steps[-1] == result.timesteps >= 50
    assert [s // 17 for s in steps[1:-1]] == [1, 2]  # on the grid of ceil(50 / 3) steps
    model = PPO.load(result.model_path, device="cpu")
    again = curve_row(GreedyModelPolicy(model, "p", {"type": "Kinematics"}),
                      get_scenario(short), coverage_reference(config, get_scenario(short)),
                      config, timesteps=0, seconds=0.0, train_return=float("nan"))
    assert again["return_mean"] == pytest.approx(result.curve["return_mean"].iloc[-1],
                                                 abs=1e-9)
    doc = json.loads(result.definition_path.read_text())["params"]
    assert doc["curve"] == {"points": 3, "seeds": "500-502", "reference": "vocabulary",
                            "level": "maneuver"}


def test_the_recorded_command_repeats_the_curve_options_that_decide_the_model():
    import argparse

    from tap_bench.cli.train import _curve_options

    def args(**changes):
        base = dict(no_curve=False, curve_points=10, curve_seeds="500-519", reference="idm",
                    level="maneuver")
        return argparse.Namespace(**{**base, **changes})

    assert _curve_options(args()) == []
    assert _curve_options(args(curve_points=3, reference="vocabulary")) == [
        "--curve-points", "3", "--reference", "vocabulary"]
    assert _curve_options(args(no_curve=True, curve_points=3)) == ["--no-curve"]


def test_train_prints_each_phase_when_not_on_a_terminal(tmp_path, write_scenario, capsys):
    """Issue 25: a 2048-step training was silent for 485 s off a terminal (342 s of it the
    curve's evaluations); every phase now gets a line, as demo and bench run print theirs."""
    from tap_bench.cli import main

    short = write_scenario("short", duration=5)
    code = main(["train", "--algo", "dqn", "--env", str(short), "--timesteps", "20",
                 "--n-envs", "1", "--curve-points", "2", "--curve-seeds", "500-501",
                 "--reference", "vocabulary", "-o", str(tmp_path / "tiny.zip")])
    out = capsys.readouterr().out
    assert code == 0, out
    lines = out.splitlines()
    first = {key: next(i for i, line in enumerate(lines) if key in line) for key in (
        "the coverage reference", "starting 1 training env", "training DQN for 20 steps",
        "evaluation 1 of 3 at 0 steps", "trained 10 of 20 steps", "evaluation 3 of 3 at 20",
        "saving the model", "wrote")}
    assert list(first) == sorted(first, key=first.get)  # in the order they happen
    assert sum("learning curve: 0 steps: return" in line for line in lines) == 1
    assert sum(line.startswith("learning curve: evaluation") for line in lines) == 3


def test_the_workers_forkserver_preloads_their_modules_and_the_setting_is_restored(
        monkeypatch):
    """The forkserver imports what every training env worker needs once, before it forks
    them (rather than each worker importing torch, SB3 and highway-env), as well as
    ``__main__``; the preload list is back as it was afterwards, also after an error."""
    import importlib
    import multiprocessing.forkserver

    from tap_bench.rl.training import WORKER_MODULES, _workers_preloaded
    from tap_bench.sim.womd_scene import WomdScenes

    for name in WORKER_MODULES:  # every name is a module that imports
        importlib.import_module(name)
    server = multiprocessing.forkserver._forkserver
    monkeypatch.setattr(server, "_preload_modules", ["__main__", "mine"])
    with _workers_preloaded(get_scenario("highway")):
        assert server._preload_modules == ["__main__", "mine", *WORKER_MODULES]
    assert server._preload_modules == ["__main__", "mine"]
    scenes = WomdScenes.__new__(WomdScenes)
    with pytest.raises(KeyError), _workers_preloaded(scenes):
        assert server._preload_modules[-1] == "tap_bench.sim.womd_env"
        raise KeyError("inside")
    assert server._preload_modules == ["__main__", "mine"]


@pytest.mark.parametrize(("algo", "n_envs"), [("dqn", 2), ("dqn", 3), ("ppo", 2), ("a2c", 2)])
def test_a_training_is_the_same_wherever_its_envs_are_stepped(tmp_path, write_scenario, algo,
                                                             n_envs):
    """The same seed gives the same weights (within 1e-6) with the envs in SB3's worker
    processes (SubprocVecEnv), stepped one after the other in this process (SB3's
    DummyVecEnv), and env 0 in this process with the others in workers (tap-bench's
    SharedVecEnv) (``in_process`` False, True, "one"; DQN's overlapped gradient steps in all
    three): only the speed differs."""
    import torch
    from stable_baselines3 import A2C, DQN, PPO

    from tap_bench.rl.training import train

    short = write_scenario("short", duration=5)
    weights, lines = [], []
    for in_process in (False, True, "one"):
        result = train(algo, short, timesteps=60, seed=3, n_envs=n_envs,
                       in_process=in_process, hyperparameters=TINY[algo],
                       output=tmp_path / f"m{in_process}.zip", announce=lines.append)
        loaded = {"dqn": DQN, "ppo": PPO, "a2c": A2C}[algo].load(result.model_path,
                                                                 device="cpu")
        weights.append(loaded.policy.state_dict())
    for other in weights[1:]:
        assert other.keys() == weights[0].keys()
        # a tolerance, not bits: the envs answer alike, so the weights agree far within it
        assert all(torch.allclose(weights[0][k], other[k], rtol=0, atol=1e-6)
                   for k in weights[0])
    starting = [line for line in lines if "training env(s)" in line]
    assert "in worker processes" in starting[0]
    assert "in this process ..." in starting[1]
    assert f"one in this process, {n_envs - 1} in worker process" in starting[2]



def test_a2c_trains_and_the_hyperparameters_stay_as_given(tmp_path, write_scenario):
    """SB3's A2C adds its RMSprop optimizer (a class) to the ``policy_kwargs`` it is given,
    in place: the model gets a copy, so the defaults and the caller's dict stay as they were
    and the definition records them as given (it could not be written as JSON)."""
    import copy

    from stable_baselines3 import A2C

    from tap_bench.rl.training import HYPERPARAMETERS, train

    defaults = copy.deepcopy(HYPERPARAMETERS)
    short = write_scenario("short", duration=5)
    given = {"n_steps": 4, "policy_kwargs": {"net_arch": [8]}}
    for hyperparameters in (TINY["a2c"], given):  # the default policy_kwargs, then the caller's
        mine = copy.deepcopy(hyperparameters)
        result = train("a2c", short, timesteps=8, seed=0, n_envs=1,
                       hyperparameters=hyperparameters, output=tmp_path / "a2c.zip",
                       overwrite=True)
        assert hyperparameters == mine and HYPERPARAMETERS == defaults
        doc = json.loads(result.definition_path.read_text())
        assert doc["params"]["hyperparameters"] == {**defaults["a2c"], **mine}
        assert A2C.load(result.model_path, device="cpu").n_steps == 4


def test_hyperparameters_json_cannot_hold_are_recorded_by_name(tmp_path, write_scenario):
    """SB3 takes classes and functions among its hyperparameters (an activation, a learning
    rate schedule) and numpy numbers: the model is saved and the definition records them
    by their qualified names and values (writing it failed after the whole training, the
    model written without its definition, and a re-run then refused the model's name)."""
    import numpy as np
    import torch
    from stable_baselines3 import PPO

    from tap_bench.rl.training import train

    def schedule(progress: float) -> float:
        return 1e-3 * progress

    result = train("ppo", write_scenario("short", duration=5), timesteps=16, seed=0,
                   n_envs=1, output=tmp_path / "m.zip",
                   hyperparameters={**TINY["ppo"], "n_epochs": np.int64(1),
                                    "learning_rate": schedule,
                                    "policy_kwargs": {"activation_fn": torch.nn.Tanh,
                                                      "net_arch": [8]}})
    recorded = json.loads(result.definition_path.read_text())["params"]["hyperparameters"]
    assert recorded["policy_kwargs"] == {"activation_fn": "torch.nn.modules.activation.Tanh",
                                         "net_arch": [8]}
    assert recorded["learning_rate"] == f"{__name__}.{schedule.__qualname__}"
    assert recorded["n_epochs"] == 1
    model = PPO.load(result.model_path, device="cpu")
    assert model.policy.activation_fn is torch.nn.Tanh

@pytest.mark.parametrize(("idle", "cores", "expected"), [
    (0.2, 2, True), (1.4, 2, True), (1.6, 2, "one"), (2.0, 2, "one"), (2.4, 8, "one"),
    (2.6, 8, False), (7.9, 8, False), (None, 2, "one"), (None, 8, False), (None, 1, True)])
def test_by_default_the_envs_run_where_the_idle_cores_make_them_fastest(
        monkeypatch, tmp_path, idle, cores, expected):
    """in_process=None, 2 envs: in this process with fewer than 1.5 idle cores, env 0 in
    this process and the other in a worker with fewer than 2.5, else each in a worker; where
    the idle time cannot be read, the cores this process may run on count as idle. Given, it
    is obeyed."""
    from tap_bench.rl import training

    chosen = []

    def vec_env(scenario, *, n_envs, fast, seed, in_process=False, scenes=None, egos="sdc"):
        chosen.append(in_process)
        raise KeyboardInterrupt  # stands for the training: nothing more is needed

    monkeypatch.setattr(training, "idle_cores", lambda: idle)
    monkeypatch.setattr(training, "cpu_quota", lambda: None)  # the machine's own quota
    monkeypatch.setattr(training, "_usable_cores", lambda: cores)
    monkeypatch.setattr(training, "_vec_env", vec_env)
    lines = []
    given = False if expected is True else True
    for in_process in (None, given):
        with pytest.raises(KeyboardInterrupt):
            training.train("dqn", "highway", timesteps=10, seed=0, n_envs=2,
                           in_process=in_process, output=tmp_path / "m.zip",
                           announce=lines.append)
    assert chosen == [expected, given]
    starting = [line for line in lines if "training env(s)" in line]
    where = {True: " in this process,", "one": ": one in this process, 1 in worker process,",
             False: " in worker processes,"}[expected]
    assert where in starting[0]
    assert (idle is None) == ("cores idle" not in starting[0])
    assert training.envs_where(idle, 2, cores) == expected



@pytest.mark.parametrize(("idle", "n_envs", "cores", "expected"), [
    (1.4, 3, 2, True), (1.4, 16, 64, True), (None, 4, 1, True),  # no second core free
    (2.0, 3, 2, "one"), (2.0, 4, 4, "one"), (3.4, 4, 4, "one"), (14.0, 16, 64, "one"),
    (None, 3, 2, "one"), (None, 4, 4, "one"),
    (4.6, 4, 8, False), (60.0, 16, 64, False), (None, 8, 64, False)])
def test_with_more_envs_the_default_keeps_the_free_cores_busy(idle, n_envs, cores, expected):
    """More than 2 envs: all in this process only when no second core is free (the rule of
    2 envs, below 1.5 idle cores); with 2 or more free, the envs run in parallel, env 0 in
    this process up to n_envs + 0.5 free cores. 16 envs on 14 idle cores of a 64-core node
    went one after the other on one core."""
    from tap_bench.rl.training import envs_where

    assert envs_where(idle, n_envs, cores) == expected

def test_bad_in_process_values_are_refused(tmp_path):
    from tap_bench.errors import ParameterError
    from tap_bench.rl.training import train

    for bad in ("yes", "two", 1, 0.5):
        with pytest.raises(ParameterError, match="in_process"):
            train("dqn", "highway", timesteps=10, seed=0, in_process=bad,
                  output=tmp_path / "m.zip")


def test_idle_cores_reads_the_machines_idle_time():
    import os
    import sys

    from tap_bench.rl.training import idle_cores

    idle = idle_cores(0.05)
    if not sys.platform.startswith("linux"):
        assert idle is None
        return
    assert 0.0 <= idle <= os.cpu_count()


@pytest.mark.parametrize("affinity", [{1}, {0, 1}, None])
def test_idle_cores_counts_the_cores_this_process_may_run_on(monkeypatch, affinity):
    """A process given some cores of a machine (taskset, a cpuset, a batch scheduler's job)
    counts the idle time of its own cores, not of the machine's: here core 0 stays idle and
    core 1 busy over the sample; review4. Without an affinity (not Linux) the all-CPU line
    and every core count."""
    import io

    from tap_bench.rl import training

    snapshots = iter([
        "cpu  100 0 100 200 0 0 0 0 0 0\ncpu0 0 0 0 100 0 0 0 0 0 0\n"
        "cpu1 100 0 100 100 0 0 0 0 0 0\nintr 1 2 3\n",
        "cpu  150 0 150 300 0 0 0 0 0 0\ncpu0 0 0 0 200 0 0 0 0 0 0\n"
        "cpu1 150 0 150 100 0 0 0 0 0 0\nintr 1 2 3\n"])
    monkeypatch.setattr(training, "open", lambda path, encoding=None: io.StringIO(
        next(snapshots)), raising=False)
    monkeypatch.setattr(training.time, "sleep", lambda seconds: None)
    if affinity is None:
        monkeypatch.delattr(training.os, "sched_getaffinity", raising=False)
        monkeypatch.setattr(training.os, "cpu_count", lambda: 2)
    else:
        monkeypatch.setattr(training.os, "sched_getaffinity", lambda pid: affinity)
    expected = {frozenset({1}): 0.0, frozenset({0, 1}): 1.0, None: 1.0}
    assert training.idle_cores() == expected[None if affinity is None else frozenset(affinity)]


def test_idle_cores_without_a_readable_stat_file_is_none(monkeypatch):
    from tap_bench.rl import training

    def missing(path, encoding=None):
        raise FileNotFoundError(2, "No such file or directory", path)

    monkeypatch.setattr(training, "open", missing, raising=False)
    assert training.idle_cores(0.0) is None


def test_the_learning_curve_evaluates_an_agent_trained_on_intersection(tmp_path):
    """intersection-v0's own observation has a key its class takes through **kwargs
    ("flatten"); the trained model's definition repeats it and the curve's evaluation applies
    it: every evaluation episode failed on it ("unknown Kinematics parameter 'flatten'")."""
    from tap_bench.rl.training import train

    result = train("dqn", "intersection", timesteps=20, seed=0, n_envs=1,
                   hyperparameters={"learning_starts": 10}, output=tmp_path / "m.zip",
                   curve=CurveConfig(points=1, seeds="500-501", reference="vocabulary"))
    assert list(result.curve["timesteps"]) == [0, 20]
    assert (result.curve["n"] == 2).all()


def test_the_cpu_quota_of_the_control_group_is_read_along_its_path(tmp_path):
    """cgroup v2: the smallest cpu.max along the process's path ("max" is none); v1: the cpu
    controller's cfs quota over its period (-1 is none); nothing readable: None."""
    from tap_bench.rl.training import cpu_quota

    v2 = tmp_path / "v2"
    (v2 / "a" / "b").mkdir(parents=True)
    (v2 / "cpu.max").write_text("max 100000\n")
    (v2 / "a" / "cpu.max").write_text("300000 100000\n")
    (v2 / "a" / "b" / "cpu.max").write_text("150000 100000\n")
    membership = tmp_path / "cgroup"
    membership.write_text("0::/a/b\n")
    assert cpu_quota(v2, membership) == 1.5
    membership.write_text("0::/a\n")
    assert cpu_quota(v2, membership) == 3.0
    membership.write_text("0::/\n")
    assert cpu_quota(v2, membership) is None

    v1 = tmp_path / "v1"
    (v1 / "cpu,cpuacct" / "docker" / "x").mkdir(parents=True)
    (v1 / "cpu,cpuacct" / "cpu.cfs_quota_us").write_text("-1\n")
    (v1 / "cpu,cpuacct" / "cpu.cfs_period_us").write_text("100000\n")
    (v1 / "cpu,cpuacct" / "docker" / "x" / "cpu.cfs_quota_us").write_text("200000\n")
    (v1 / "cpu,cpuacct" / "docker" / "x" / "cpu.cfs_period_us").write_text("100000\n")
    membership.write_text("4:memory:/docker/x\n3:cpu,cpuacct:/docker/x\n0::/\n")
    assert cpu_quota(v1, membership) == 2.0
    membership.write_text("3:cpu,cpuacct:/docker/y\nnot a cgroup line\n")
    assert cpu_quota(v1, membership) is None
    assert cpu_quota(tmp_path / "absent", tmp_path / "absent") is None


def test_a_cpu_quota_caps_the_idle_cores_the_default_counts(monkeypatch, tmp_path):
    """A container limited to 2 CPUs on an idle 16-core host: 2 envs run one here and one in
    a worker (not 2 workers and the learner on a 2-CPU quota), and the start line says why."""
    from tap_bench.rl import training

    chosen = []

    def vec_env(scenario, *, n_envs, fast, seed, in_process=False, scenes=None, egos="sdc"):
        chosen.append(in_process)
        raise KeyboardInterrupt  # stands for the training: nothing more is needed

    monkeypatch.setattr(training, "idle_cores", lambda: 15.8)
    monkeypatch.setattr(training, "_usable_cores", lambda: 16)
    monkeypatch.setattr(training, "cpu_quota", lambda: 2.0)
    monkeypatch.setattr(training, "_vec_env", vec_env)
    lines = []
    with pytest.raises(KeyboardInterrupt):
        training.train("dqn", "highway", timesteps=10, seed=0, n_envs=2,
                       output=tmp_path / "m.zip", announce=lines.append)
    assert chosen == ["one"]
    starting = next(line for line in lines if "training env(s)" in line)
    assert "2.0 of 2 cores idle (the CPU quota of its control group)" in starting


def test_the_default_place_of_the_envs_over_drawn_machines():
    """envs_where over 2,000 drawn (idle cores, usable cores, envs): one after the other in
    this process exactly below 1.5 free cores, each in a worker exactly from n_envs + 0.5,
    else env 0 here; more free cores never move the envs back towards this process; an
    unknown idle time counts the usable cores."""
    from tap_bench.rl.training import envs_where

    order = {True: 0, "one": 1, False: 2}
    rng = np.random.default_rng(24)
    for _ in range(2000):
        n_envs, cores = int(rng.integers(2, 65)), float(rng.integers(1, 129))
        idle = float(rng.uniform(0, cores))
        where = envs_where(idle, n_envs, cores)
        assert where == (True if idle < 1.5 else "one" if idle < n_envs + 0.5 else False)
        more = envs_where(idle + float(rng.uniform(0, 4)), n_envs, cores)
        assert order[more] >= order[where]
        assert envs_where(None, n_envs, cores) == envs_where(cores, n_envs, cores)
